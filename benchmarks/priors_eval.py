"""Score a scene-prior provider on the hand-labelled triples in ``priors_labels.jsonl``.

Prints penetration accuracy, size-ratio MAE and contact-ratio MAE for the provider and for a random
baseline (the paper's table: LLM 98.4 %, 0.46, 0.25; random 50 %, 3.30, 0.33). Size ratios, label and
estimate alike, are clamped to [0.1, 10] before the error, as in the paper. The random baseline draws
size uniformly in [0.1, 10], contact uniformly in [0, 1] and penetration by a fair coin, averaged over
``--random-trials`` draws per triple.

    python benchmarks/priors_eval.py [--provider rules|openai] [--errors] [--origin ORIGIN] [--labels FILE]

Origins: ``bench`` (every prompt of ../shared/bench), ``hand`` (labelled before the rules were written),
``holdout`` (labelled after they were first frozen), ``batch1`` ... ``batch24`` (scenes the first sets lacked:
kitchen, bathroom, office, garden, toys, clothing, tools, vehicles, animals; each labelled, with a reason,
and committed while the rules were frozen, before they were run on it; docs/priors.md, "How well the rules
read", gives the held-out figure).
Labels: ``size_ratio`` is source/target longest side (measured on the bench's split models where both
parts come from one model, estimated from typical real sizes otherwise), ``contact_ratio`` the fraction
of the source's surface touching the target, ``penetration`` whether one solid passes into the other.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
from pathlib import Path

from ctp_core.priors import get_provider
from ctp_core.priors.prior import SIZE_RANGE, clamp_size

LABELS = Path(__file__).with_name("priors_labels.jsonl")


def load(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def score(rows: list[dict], answers: list[tuple[float, bool, float]]) -> dict[str, float]:
    """Penetration accuracy and the two MAEs of ``answers`` (size, penetration, contact) against ``rows``."""
    n = len(rows)
    return {
        "penetration_accuracy": sum(a[1] == r["penetration"] for r, a in zip(rows, answers, strict=True)) / n,
        "size_ratio_mae": sum(abs(clamp_size(a[0]) - clamp_size(r["size_ratio"]))
                              for r, a in zip(rows, answers, strict=True)) / n,
        "contact_ratio_mae": sum(abs(a[2] - r["contact_ratio"]) for r, a in zip(rows, answers, strict=True)) / n,
    }


def random_baseline(rows: list[dict], trials: int, seed: int = 0) -> dict[str, float]:
    rng = random.Random(seed)
    runs = [score(rows, [(rng.uniform(*SIZE_RANGE), rng.random() < 0.5, rng.random()) for _ in rows])
            for _ in range(trials)]
    return {k: sum(r[k] for r in runs) / trials for k in runs[0]}


def _origin_order(origin: str) -> tuple[str, int]:
    """Origins by name, numbered ones by number ("batch2" before "batch10")."""
    stem = origin.rstrip("0123456789")
    return stem, int(origin[len(stem):] or 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--labels", type=Path, default=LABELS)
    parser.add_argument("--provider", default="rules", choices=["rules", "openai"])
    parser.add_argument("--errors", action="store_true", help="list the triples the provider gets most wrong")
    parser.add_argument("--origin", help="score and list only the triples of this origin (e.g. batch3)")
    parser.add_argument("--random-trials", type=int, default=200)
    args = parser.parse_args(argv)

    rows = [r for r in load(args.labels) if args.origin in (None, r["origin"])]
    if not rows:
        print(f"no labelled triples of origin {args.origin!r} in {args.labels.name}", file=sys.stderr)
        return 2
    provider = get_provider(args.provider)
    priors = [provider.estimate(r["target"], r["source"], r["prompt"]) for r in rows]
    answers = [(p.size_ratio, p.penetration, p.contact_ratio) for p in priors]
    table = {args.provider: (len(rows), score(rows, answers)),
             "random": (len(rows), random_baseline(rows, args.random_trials))}
    origins = sorted({r["origin"] for r in rows}, key=_origin_order)
    for origin in origins if len(origins) > 1 else []:
        subset = [i for i, r in enumerate(rows) if r["origin"] == origin]
        table[f"{args.provider} ({origin} only)"] = (
            len(subset), score([rows[i] for i in subset], [answers[i] for i in subset]))

    print(f"{len(rows)} labelled triples from {args.labels.name}")
    print(f"{'provider':<24} {'n':>4} {'penetration acc':>16} {'size MAE':>9} {'contact MAE':>12}")
    for name, (n, s) in table.items():
        print(f"{name:<24} {n:>4} {s['penetration_accuracy']:>15.1%} {s['size_ratio_mae']:>9.3f} "
              f"{s['contact_ratio_mae']:>12.3f}")
    if args.errors:
        worst = sorted(zip(rows, priors, strict=True), key=lambda rp: -(
            abs(clamp_size(rp[1].size_ratio) - clamp_size(rp[0]["size_ratio"]))
            + abs(rp[1].contact_ratio - rp[0]["contact_ratio"]) + (rp[1].penetration != rp[0]["penetration"])))
        for row, prior in worst[:15]:
            print(f"- {row['prompt']!r} [{row['target']} / {row['source']}]: size {prior.size_ratio:.3g} "
                  f"(label {row['size_ratio']}), pen {prior.penetration} ({row['penetration']}), "
                  f"contact {prior.contact_ratio:.2f} ({row['contact_ratio']}) :: {prior.reason}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
