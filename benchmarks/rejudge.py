"""Judge the answers of a ``results.jsonl`` again by this tree's relation metrics (``harness.relation_metrics``).

A run's rows carry their metrics as the harness of their day computed them; comparing two trees' runs mixes what
the engine placed with how the bench judged it. This recomputes ``relation``, ``relation_holds``, ``stable`` and
``valid`` of every ok row's answer in the reference's frame (the rows' own IoU kept) and prints, per variant, how
many rows hold, are valid and are placement successes. Reads the cases folder the rows came from.

    python benchmarks/rejudge.py RESULTS.jsonl [--cases ../shared/bench]
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from ctp_core.bench import cases, harness, summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("--cases", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "bench")
    args = parser.parse_args()
    rows = [r for r in harness.read_results(args.results) if r.get("status") == "ok"]
    found = {c.id: c for c in cases.discover(args.cases, sorted({r["case"] for r in rows}))}
    loaded: dict[str, harness._CaseData] = {}
    counts: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    per_case = []
    for row in rows:
        case = found[row["case"]]
        if case.id not in loaded:
            loaded[case.id] = harness._load(case, harness.BenchOptions(), need_guide=False)
        judged = harness.relation_metrics(loaded[case.id], np.asarray(row["source_to_target"]), row["metrics"]["iou"])
        name = summary.variant(row)
        tally = counts[name]
        tally["runs"] += 1
        tally["placement"] += bool(row["metrics"].get("placement_success"))
        tally["holds (as run)"] += bool(row["metrics"].get("relation_holds"))
        tally["holds (reference frame)"] += bool(judged["relation_holds"])
        tally["valid (reference frame)"] += bool(judged["valid"])
        per_case.append({"variant": name, "case": case.id, "relation": judged["relation"],
                         "holds_as_run": row["metrics"].get("relation_holds"), **judged})
    print(json.dumps({"variants": counts, "rows": per_case}, indent=1, default=str))


if __name__ == "__main__":
    main()
