"""How often a guide gets a say, and what it changes (``GuideSay``, ``search.chance``), over ``ctp bench`` runs.

Per guided run folder (``ctp bench --out``): the cases with a reference, how many the guide had a say on (the
report's ``guide_say.override`` > 0) and a full say, the largest, the placements, and the cases it gained and lost
against ``--geometry`` (a run without a guide over the same cases): the same table as docs/benchmarks.md's
say-tables (``docs_tables.say_table``), for any folders (held-out runs, a tree under test). With ``--cases``, each
case's say and the gate's own line (what chance gives each test, who chose).

    ctp bench ../shared/bench --with-reference --method geometry --seed 0 --out /tmp/geometry
    ctp bench ../shared/bench --with-reference --method ctp --guide text --model random:ViT-B-32 --seed 0 \\
        --out /tmp/noise                                            # a guide of noise: it should never get a say
    python benchmarks/guide_say.py --geometry /tmp/geometry /tmp/noise --cases

Measurement only: nothing here runs a benchmark.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from docs_tables import load_run, say_table  # a sibling script (benchmarks/ is on sys.path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="guided ctp bench output folders")
    parser.add_argument("--geometry", type=Path, required=True, help="a ctp bench --method geometry folder")
    parser.add_argument("--cases", action="store_true", help="also each case's say and the gate's line")
    args = parser.parse_args(argv)
    runs = [load_run(folder, stored=False) for folder in args.runs]
    print(say_table(runs, load_run(args.geometry, stored=False)))
    if args.cases:
        for run in runs:
            for row in sorted(run.rows, key=lambda r: r["case"]):
                said = (row.get("extra") or {}).get("guide_say") or {}
                placed = (row.get("metrics") or {}).get("placement_success")
                print(f"{run.name}\t{row['case']}\tsay {said.get('override')}\tplaced {placed}\t{said.get('summary')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
