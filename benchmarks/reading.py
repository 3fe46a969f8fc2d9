"""How the rules provider reads the relation of the phrases in ``tests/reading_phrases.csv``: relation, figure, side.

Each row is a prompt with the expected reading: the relation (a reading of two joined by ``+``, "front+facing"),
which object is its figure (``source`` or ``target``) and the side of the ground the figure is on (``front``,
``behind``, ``left``, ``right``; empty where none is named). Prints the accuracy of each column and of all three
together, per origin (the public vocabularies the wordings come from: SpatialSense, Rel3D, Sr3D, Holodeck,
LayoutVLM; the issue's examples; paraphrases) and overall; ``--errors`` lists the misses. An expected relation is
compared as a reading (``RelationReading.parse``: "facing" said alone is near+facing).

    python benchmarks/reading.py [--errors] [--phrases benchmarks/reading_heldout.csv]
    python benchmarks/reading.py --phrases tests/reading_phrases_vsr.csv     # one phrase per VSR relation
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from pathlib import Path

from ctp_core.priors import get_provider
from ctp_core.reading.relation import RelationReading

PHRASES = Path(__file__).resolve().parent.parent / "tests" / "reading_phrases.csv"
COLUMNS = ("relation", "figure", "side")


def read(row: dict) -> dict:
    """The provider's reading of one row, in the file's columns."""
    prior = get_provider("rules").estimate(row["target"], row["source"], row["prompt"])
    reading = prior.reading
    return {"relation": reading.name, "figure": "source" if reading.source_is_figure else "target",
            "side": reading.side or ""}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--errors", action="store_true", help="list the rows read otherwise")
    parser.add_argument("--phrases", type=Path, default=PHRASES, help="the phrase list (default: the dev list; "
                        "benchmarks/reading_heldout.csv was written after the rules were frozen)")
    args = parser.parse_args()
    rows = list(csv.DictReader(args.phrases.open()))
    right: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for row in rows:
        got = read(row)
        expected = {**row, "relation": RelationReading.parse(row["relation"]).name}
        ok = {c: got[c] == expected[c] for c in COLUMNS}
        ok["all"] = all(ok.values())
        for origin in (row["origin"], "overall"):
            right[origin]["rows"] += 1
            for c, v in ok.items():
                right[origin][c] += v
        if args.errors and not ok["all"]:
            print(f"  {row['prompt']!r}: expected {[row[c] for c in COLUMNS]}, read {[got[c] for c in COLUMNS]}")
    print(f"{'origin':<14}{'rows':>5}" + "".join(f"{c:>10}" for c in (*COLUMNS, "all")))
    for origin, counts in sorted(right.items(), key=lambda item: item[0] == "overall"):
        print(f"{origin:<14}{counts['rows']:>5}"
              + "".join(f"{100 * counts[c] / counts['rows']:>9.0f}%" for c in (*COLUMNS, "all")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
