"""``ctp bench``: run the evaluation harness over benchmark case folders (``ctp_core.bench``).

Writes ``OUT/results.jsonl`` (one row per case x init x method), ``OUT/summary.md`` and PNG plots.
Exit codes: 0 done (rows may still record per-case errors); 1 no run succeeded; 2 bad usage or
input; 3 the guided methods' vision-language model is unavailable; 130 interrupted.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import get_args

from ctp.cli import EXIT_FAILED
from ctp_core.config import Runtime
from ctp_core.errors import ConfigError

COMMANDS = "commands.txt"


def _list(value: str) -> list[str]:
    return [v.strip() for v in value.split(",") if v.strip()]


class _Extend(argparse.Action):
    """Repeatable option that also takes comma lists: ``--method ctp,b1 --method b2``."""

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, (getattr(namespace, self.dest) or []) + _list(values))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ctp_core.bench.guides import GUIDES
    from ctp_core.bench.harness import ABLATIONS, METHODS
    from ctp_core.bench.protocol import PROTOCOLS
    from ctp_core.reading.counts import CHOICES

    parser.add_argument("cases_dir", type=Path, help="folder searched recursively for <case>/case.json")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--cases", action=_Extend, help="case ids (case.json 'id'), comma list; default all")
    parser.add_argument("--with-reference", action="store_true",
                        help="only cases with a reference arrangement (the ones pose errors exist for)")
    parser.add_argument("--method", action=_Extend, dest="methods",
                        help=f"{' | '.join(METHODS)}; repeatable or a comma list (default ctp)")
    parser.add_argument("--protocol", choices=PROTOCOLS, default="rigid",
                        help="rigid: perturb pose; scale: also scale U(0.01, 100) and optimise scale")
    parser.add_argument("--inits", type=int, default=1, help="protocol starts per case (default 1)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="default",
                        help="AlignConfig preset for ctp/geometry (default; fast; descent; paper; test)")
    parser.add_argument("--model", help="encoder of ctp's guide and b2's selection (default: the default CLIP "
                        "model; never auto's per-machine pick)")
    parser.add_argument("--guide", choices=GUIDES, default="text",
                        help="text: the prompt; image: a reference render; oracle: the reference per view; "
                        "pixels: an upper-bound instrument, the oracle compared as images with no encoder")
    parser.add_argument("--metrics-model", action=_Extend, dest="metrics_models", default=[],
                        help="encoder(s) for the semantic metric, repeatable or comma list")
    parser.add_argument("--ablation", choices=sorted(ABLATIONS), help="change ctp/geometry's configuration")
    parser.add_argument("--count", type=int, default=1,
                        help="copies of the source per run (ctp and geometry, text guide; the first is judged "
                        "against the reference, the set by its own measures)")
    parser.add_argument("--arrangement", choices=CHOICES, default="auto",
                        help="how the copies stand: auto (the prompt's cue), scatter, around, row, stack")
    parser.add_argument("--jobs", type=int, default=1, help="cases run in parallel processes")
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--threads", type=int, help="torch CPU threads per run")
    parser.add_argument("--runtime", choices=get_args(Runtime),
                        help="where forward-only encoding runs (scoring, selection, metrics; default auto)")
    parser.add_argument("--resume", action="store_true", help="keep finished rows of OUT/results.jsonl")
    parser.add_argument("--summary-only", action="store_true",
                        help="only rewrite summary.md and the plots from OUT/results.jsonl (e.g. after an interrupt)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


class CaseBar:
    """Progress over cases on stderr: a redrawn line on a terminal, one line per case otherwise."""

    def __init__(self, stream=None, enabled: bool = True):
        stream = stream if stream is not None else sys.stderr  # as it is now, not at import (a test's capture)
        self.stream, self.enabled, self.tty = stream, enabled, stream.isatty()
        self.started = time.perf_counter()

    def __call__(self, done: int, total: int, case_id: str) -> None:
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.started
        eta = f"{elapsed / done * (total - done):6.0f}s" if done else "     ?"
        filled = int(30 * done / max(1, total))
        line = f"[{'#' * filled}{'.' * (30 - filled)}] {done}/{total} cases eta {eta} {case_id}"
        self.stream.write(("\r" + line + ("\n" if done == total else "")) if self.tty else line + "\n")
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    from ctp_core.bench import cases, harness, summary

    options = harness.BenchOptions(
        methods=args.methods or ["ctp"], protocol=args.protocol, inits=args.inits, seed=args.seed,
        preset=args.preset, model=args.model, guide=args.guide, metrics_models=args.metrics_models,
        ablation=args.ablation, device=args.device, threads=args.threads, runtime=args.runtime, count=args.count,
        arrangement=args.arrangement)
    options.config("ctp")  # a bad preset or model spec fails here, before any case runs
    if args.summary_only:
        rows = harness.read_results(args.out / harness.RESULTS)
    else:
        found = cases.discover(args.cases_dir, args.cases)
        if args.with_reference:
            found = [c for c in found if c.reference is not None]
        if not found:
            raise ConfigError(f"no cases to run under {args.cases_dir}", field="cases_dir")
        _log_command(args)
        rows = harness.run_bench(found, options, args.out, jobs=args.jobs, resume=args.resume,
                                 on_case=CaseBar(enabled=not args.quiet))
    log = args.out / COMMANDS
    path = summary.write_summary(rows, args.out, commands=log.read_text().splitlines() if log.exists() else [])
    failed = sum(r.get("status") != "ok" for r in rows)
    print(f"{len(rows)} runs over {len({r['case'] for r in rows})} cases ({failed} not ok): {path}")
    return EXIT_FAILED if rows and failed == len(rows) else 0


def _log_command(args: argparse.Namespace) -> None:
    """Append this invocation to OUT/commands.txt: the summary shows every command behind its rows."""
    if sys.argv[1:2] == ["bench"]:
        line = "ctp " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    else:  # called in-process (ctp.cli.main(argv)): the parsed arguments are what is known
        line = "ctp bench (in-process) " + " ".join(f"{k}={v}" for k, v in sorted(vars(args).items()))
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / COMMANDS).open("a") as f:
        f.write(line + "\n")

