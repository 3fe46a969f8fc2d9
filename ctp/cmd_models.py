"""``ctp models``: the guidance models in the local cache the loader reads (``ctp_core.guide.store``).

``list`` prints one line per cached model (spec, size, the weights' sha256, ready or incomplete, the default
marked); ``pull [NAME]`` (default: the default CLIP model, the one ``auto`` uses) downloads what it needs, with a
progress bar on a terminal and one final line elsewhere, resumable and verified; ``rm NAME`` deletes it. Errors
are one line (``ctp.cli``): unreachable or offline exits 3, a name that is no Hub model id exits 2.
"""

from __future__ import annotations

import argparse
import sys
import time

from ctp_core.config import DEFAULT_MODEL

DEFAULT_NAME = DEFAULT_MODEL.removeprefix("hf:")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", required=True)
    actions.add_parser("list", help="cached models: spec, size, the weights' sha256, ready or not, the default")
    pull = actions.add_parser("pull", help="download a model into the cache (resumable, verified)")
    pull.add_argument("name", nargs="?", default=DEFAULT_NAME, metavar="NAME",
                      help="Hugging Face model id, ORG/NAME or hf:ORG/NAME (default: %(default)s, auto's model)")
    pull.add_argument("--revision", default="main", help="branch, tag or commit (default: %(default)s)")
    rm = actions.add_parser("rm", help="delete a model from the cache")
    rm.add_argument("name", metavar="NAME", help="Hugging Face model id (ORG/NAME or hf:ORG/NAME)")


def run(args: argparse.Namespace) -> int:
    from ctp_core.guide import store

    if args.action == "list":
        models = store.cached()
        for m in models:
            state = "ready" if m.ready else "incomplete"
            print(f"{m.spec}  {_size(m.size)}  sha256 {m.sha256 or '-'}  {state}{'  (default)' if m.default else ''}")
        if not any(m.default and m.ready for m in models):
            print(f"(the default model {DEFAULT_MODEL} is not cached: `ctp models pull` gets it; until then model "
                  "auto runs without a guide)")
        return 0
    if args.action == "rm":
        freed = store.remove(args.name)
        print(f"removed {store.repo_id(args.name)} ({_size(freed)})")
        return 0
    bar = _Bar(sys.stderr, store.repo_id(args.name))
    model = store.pull(args.name, revision=args.revision, on_progress=bar)
    bar.close()
    print(f"pulled {model.spec} ({_size(model.size)}, sha256 {model.sha256}) into {store.cache_root()}")
    return 0


class _Bar:
    """A redrawn progress line on a terminal (at most ten a second); nothing elsewhere, where the final line says
    what was pulled."""

    def __init__(self, stream, what: str):
        self.stream, self.what, self.tty = stream, what, stream.isatty()
        self._drawn = 0.0

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if not self.tty or (now - self._drawn < 0.1 and done < total):
            return
        self._drawn = now
        filled = int(20 * done / total) if total else 20
        self.stream.write(f"\r[{'#' * filled}{'.' * (20 - filled)}] {_size(done)} / {_size(total)} {self.what}\033[K")
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self._drawn:
            self.stream.write("\n")
            self.stream.flush()


def _size(n: int) -> str:
    return f"{n / 1e6:.1f} MB"
