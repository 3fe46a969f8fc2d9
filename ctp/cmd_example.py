"""``ctp example``: write a generated sample pair (``ctp_core.samples``) to try ``ctp align`` and the service on.

Prints the paths written (target first) on stdout, and on stderr the ``ctp align`` line that places the
sample's source by its prompt. Exit codes: 0 written; 2 bad usage (an unknown sample).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from ctp_core.samples import SAMPLES, get_sample


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", nargs="?", default="cup-on-table", choices=sorted(SAMPLES),
                        metavar="|".join(sorted(SAMPLES)),
                        help="which sample pair (default: %(default)s)")
    parser.add_argument("--dir", type=Path, default=Path("."), metavar="DIR",
                        help="folder to write into (default: here)")


def run(args: argparse.Namespace) -> int:
    sample = get_sample(args.name)
    target, source = sample.write(args.dir)
    print(target)
    print(source)
    command = ["ctp", "align", str(target), str(source), "--prompt", sample.prompt, "--target-name",
               sample.target_name, "--source-name", sample.source_name, "--preset", "test", "--model", "random:tiny"]
    print(f"{sample.name}: {sample.prompt!r}; try:\n  {shlex.join(command)}", file=sys.stderr)
    return 0
