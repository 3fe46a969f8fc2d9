"""``ctp example``: write a generated example pair (``ctp_core.io.examples``) to try ``ctp align`` and the service on.

Prints the paths written (target first) on stdout, and on stderr the ``ctp align`` line that places the
example's source by its prompt (the README's Quick start, with the machine's best guide). Exit codes: 0 written;
2 bad usage (an unknown example).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from ctp_core.io.examples import EXAMPLES, get_example


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", nargs="?", default="cup-on-table", choices=sorted(EXAMPLES),
                        metavar="|".join(sorted(EXAMPLES)),
                        help="which sample pair (default: %(default)s)")
    parser.add_argument("--dir", type=Path, default=Path("."), metavar="DIR",
                        help="folder to write into (default: here)")


def run(args: argparse.Namespace) -> int:
    example = get_example(args.name)
    target, source = example.write(args.dir)
    print(target)
    print(source)
    command = ["ctp", "align", str(target), str(source), "--prompt", example.prompt, "--target-name",
               example.target_name, "--source-name", example.source_name, "--preset", "test",
               "--out", str(args.dir / "scene.glb"), "--report", str(args.dir / "report.json")]
    print(f"{example.name}: {example.prompt!r}; try:\n  {shlex.join(command)}", file=sys.stderr)
    return 0
