"""The result tables of docs/benchmarks.md, generated from the stored benchmark runs.

A stored run is a folder ``benchmarks/results/RUN/`` holding

- ``results.jsonl``: the rows ``ctp bench`` wrote (``ctp_core.bench.harness``; one row per case x init x variant),
- ``commands.txt``: the ``ctp bench`` command(s) behind the rows, as ``ctp bench`` logs them (paths relative to the
  repository root, so that they reproduce the run from there),
- ``run.json``: ``{"machine": "...", "date": "YYYY-MM-DD"}`` and optionally ``"note"``: what the rows cannot say
  (the machine kind the run took its times on, and when).

In docs/benchmarks.md the text between ``<!-- bench-table:RUN -->`` and ``<!-- /bench-table -->`` is RUN's table:
its command, machine kind and date, then per variant and per case set (the rows' ``origin``) the counts of
placement, placement@k, success, relation holds and valid, with ADD-S and time medians. The text between
``<!-- say-table:BASE:RUN,RUN,... -->`` and ``<!-- /say-table -->`` is the guide's say in guided runs
(``say_table``): how often each guide had a say, and the placements it gained and lost against BASE, a run
without a guide over the same cases; then each run's command, machine kind and date. Regenerate with

    python benchmarks/docs_tables.py            # rewrites the regions (make docs-bench)
    python benchmarks/docs_tables.py --check    # exit 1 if a region is stale or names no stored run

Nothing here runs a benchmark: a table changes only when a stored run does.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"
DOC = REPO / "docs" / "benchmarks.md"
REGION = re.compile(r"(<!-- bench-table:([\w.-]+) -->\n)(.*?)(<!-- /bench-table -->)", re.S)
SAY_REGION = re.compile(r"(<!-- say-table:([\w.-]+):([\w.,-]+) -->\n)(.*?)(<!-- /say-table -->)", re.S)
# the fields that name a row (``harness.row_key``): a resumed run may have written a row twice, the last one counts
ROW_KEY = ("case", "init", "method", "protocol", "seed", "ablation", "preset", "guide", "encoder", "copies")


@dataclass(frozen=True)
class Run:
    name: str
    rows: list[dict]
    commands: list[str]
    machine: str
    date: str
    note: str = ""
    where: str = ""  # the folder as a reader finds it: ``benchmarks/results/NAME/`` for a stored run


def load_run(folder: Path, *, stored: bool = True) -> Run:
    """One stored run; a missing file or a ``run.json`` without ``machine`` and ``date`` is an error. Not
    ``stored`` (a ``ctp bench --out`` folder as it is): ``run.json`` is optional, machine and date unknown."""
    folder = Path(folder)
    meta = json.loads((folder / "run.json").read_text()) if stored or (folder / "run.json").exists() else {
        "machine": "this machine", "date": "not stored"}
    missing = [key for key in ("machine", "date") if not meta.get(key)]
    if missing:
        raise ValueError(f"{folder / 'run.json'}: missing {', '.join(missing)}")
    rows: dict[tuple, dict] = {}
    for line in (folder / "results.jsonl").read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            rows[tuple(row.get(k) for k in ROW_KEY)] = row
    commands = [c for c in (folder / "commands.txt").read_text().splitlines() if c.strip()]
    return Run(folder.name, list(rows.values()), commands, str(meta["machine"]), str(meta["date"]),
               str(meta.get("note", "")), f"benchmarks/results/{folder.name}/" if stored else f"{folder}/")


def stored_runs(root: Path = RESULTS) -> dict[str, Run]:
    """Every run folder under ``root`` (those with a ``results.jsonl``), by name."""
    root = Path(root)
    if not root.is_dir():
        return {}
    return {p.parent.name: load_run(p.parent) for p in sorted(root.glob("*/results.jsonl"))}


def _count(rows: list[dict], key: str) -> str:
    """``hits/judged`` over the ok rows where the metric applies (not None); "–" where no row has it."""
    values = [r["metrics"][key] for r in rows if r["metrics"].get(key) is not None]
    return f"{sum(bool(v) for v in values)}/{len(values)}" if values else "–"


def _median(values: list[float], digits: int) -> str:
    return f"{statistics.median(values):.{digits}f}" if values else "–"


def _cells(group: list[dict]) -> list[str]:
    ok = [r for r in group if r.get("status") == "ok"]
    adds = [float(r["metrics"]["adds"]) for r in ok if r["metrics"].get("adds") is not None]
    times = [float(r["time_s"]) for r in ok if r.get("time_s") is not None]
    return [f"{len(ok)}/{len(group)}", str(sum(bool(r.get("has_reference")) for r in group)),
            _count(ok, "placement_success"), _count(ok, "placement_at_k"), _count(ok, "success"),
            _count(ok, "relation_holds"), _count(ok, "valid"), _median(adds, 3), _median(times, 1)]


def _variant(row: dict) -> str:
    from ctp_core.bench.summary import variant  # the label summary.md groups the same rows under

    return variant(row)


def table(run: Run) -> str:
    """The Markdown of one run's region: what ran, where and when, then one line per variant and case set."""
    head = ["variant", "set", "ok/runs", "with reference", "placement", "placement@k", "success", "relation holds",
            "valid", "ADD-S median", "time s median"]
    lines = [f"Run `{run.name}` (`{run.where}`), {run.date}, on {run.machine}"
             f"{'; ' + run.note if run.note else ''}. From the repository root:", "", "```",
             *run.commands, "```", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    variants: dict[str, list[dict]] = defaultdict(list)
    for row in run.rows:
        variants[_variant(row)].append(row)
    for name, group in sorted(variants.items()):
        sets: dict[str, list[dict]] = defaultdict(list)
        for row in group:
            sets[row.get("origin") or row["case"].split("-")[0]].append(row)
        for set_name, rows in sorted(sets.items(), key=lambda item: item[0].lower()):
            lines.append("| " + " | ".join([name, set_name, *_cells(rows)]) + " |")
        if len(sets) > 1:
            lines.append("| " + " | ".join([name, "**all**", *_cells(group)]) + " |")
    return "\n".join(lines) + "\n"


def say_table(runs: list[Run], base: Run) -> str:
    """The Markdown of a say-table region: per guided run, the cases with a reference, how many the guide had a
    say on (``guide_say.override`` > 0) and a full say, the largest, the placements, those gained and lost
    against ``base`` (a run without a guide over the same cases) and the successes (ADD-S); then where each run
    comes from."""
    head = ["run", "guide", "cases", "a say", "full say", "largest say", "placement", "gained", "lost", "success"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    before = _placed(base.rows)
    for run in runs:
        ok = [r for r in run.rows if r.get("status") == "ok" and r["metrics"].get("placement_success") is not None]
        says = [float(((r.get("extra") or {}).get("guide_say") or {}).get("override") or 0.0) for r in ok]
        placed = _placed(ok)
        gained = sorted(c for c, hit in placed.items() if hit and before.get(c) is False)
        lost = sorted(c for c, hit in placed.items() if not hit and before.get(c))
        guides = ", ".join(sorted({f"{r.get('guide')}" + (f"/{r['encoder']}" if r.get("encoder") else "")
                                   for r in ok}))
        lines.append("| " + " | ".join([
            f"`{run.name}`", guides, str(len(ok)), str(sum(v > 0 for v in says)), str(sum(v >= 1 for v in says)),
            f"{max(says, default=0.0):.2f}", f"{sum(placed.values())}/{len(placed)}", ", ".join(gained) or "–",
            ", ".join(lost) or "–", _count(ok, "success")]) + " |")
    lines.append("")
    for run in [base, *runs]:
        lines.append(f"- `{run.name}` (`{run.where}`), {run.date}, on {run.machine}"
                     f"{'; ' + run.note if run.note else ''}: `" + "`; `".join(run.commands) + "`")
    return "\n".join(lines) + "\n"


def _placed(rows: list[dict]) -> dict[str, bool]:
    """case -> placed, over the ok rows with a reference (the last row of a case counts)."""
    return {r["case"]: bool(r["metrics"]["placement_success"]) for r in rows
            if r.get("status") == "ok" and r["metrics"].get("placement_success") is not None}


def rewrite(text: str, runs: dict[str, Run]) -> str:
    """``text`` with every bench-table and say-table region replaced by its runs' table; a region naming no stored
    run is an error."""
    named = {m.group(2) for m in REGION.finditer(text)}
    for m in SAY_REGION.finditer(text):
        named |= {m.group(2), *m.group(3).split(",")}
    unknown = sorted(named - set(runs))
    if unknown:
        raise KeyError(f"table regions name runs that are not stored: {', '.join(unknown)}")
    text = REGION.sub(lambda m: m.group(1) + table(runs[m.group(2)]) + m.group(4), text)
    return SAY_REGION.sub(lambda m: m.group(1) + say_table([runs[n] for n in m.group(3).split(",")],
                                                           runs[m.group(2)]) + m.group(5), text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--doc", type=Path, default=DOC, help="the page to rewrite (default docs/benchmarks.md)")
    parser.add_argument("--results", type=Path, default=RESULTS, help="the stored runs (default benchmarks/results)")
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if a region is stale")
    args = parser.parse_args(argv)
    runs = stored_runs(args.results)
    text = args.doc.read_text()
    new = rewrite(text, runs)
    shown = {m.group(2) for m in REGION.finditer(text)}
    for m in SAY_REGION.finditer(text):
        shown |= {m.group(2), *m.group(3).split(",")}
    for name in sorted(set(runs) - shown):
        print(f"note: stored run {name} has no region in {args.doc}: add <!-- bench-table:{name} --> "
              "<!-- /bench-table --> where it belongs", file=sys.stderr)
    if args.check:
        if new != text:
            print(f"{args.doc} is stale: run python benchmarks/docs_tables.py", file=sys.stderr)
            return 1
        return 0
    if new != text:
        args.doc.write_text(new)
    print(f"{args.doc}: {len(shown)} table(s) from {len(runs)} stored run(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
