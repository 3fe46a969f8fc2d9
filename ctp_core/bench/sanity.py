"""Geometry-only sanity of the optimiser, measurable without vision-language weights.

With lambda_clip = 0 and the source started two target radii away, the geometric terms alone must bring
the source into contact without interpenetration, where the prompt's relation asks for
contact (its contact ratio above 0); where it does not ("a ball under the table", "a cup beside the box":
soft-ICP attaches nothing), they must bring it to where that relation holds, without interpenetration. Used
by a test over ``shared/bench/synthetic`` and by ``benchmarks/align_bench.py``.
"""

from __future__ import annotations

import time

import numpy as np

from ctp_core import metrics
from ctp_core.align import align
from ctp_core.bench.cases import Case
from ctp_core.config import AlignConfig

CONTACT_LIMIT = 0.01  # closest surface distance / target AABB diagonal
INTERSECTION_LIMIT = 0.01  # Vol(A & B) / Vol(A | B)


def geometry_contact(case: Case, *, preset: str = "descent", seed: int = 0, steps: int = 90,
                     restarts: int = 2) -> dict:
    """Run the geometry-only optimiser on a case and measure contact and intersection."""
    target, source = case.load()
    allow = case.penetration_expected
    config = AlignConfig.from_preset(
        preset, seed=seed, penetration="allow" if allow else "forbid",
        loss={"lambda_clip": 0.0}, optim={"steps": steps, "restarts": restarts, "init_distance": (2.0, 2.0)},
    )
    start = time.perf_counter()
    result = align(target, source, case.prompt, config, target_name=case.target_name,
                   source_name=case.source_name)
    placed = source.copy()
    placed.apply_transform(result.source_to_target)
    size = float(np.linalg.norm(target.extents))
    contact = metrics.contact_distance(target, placed) / size
    overlap = metrics.intersection_over_union(target, placed)
    touches = result.priors["contact_ratio"] > 0
    holds = result.relation["holds"] if result.relation else None
    return {
        "case": case.id, "penetration_allowed": allow, "contact": contact, "intersection": overlap.iou,
        "intersection_method": overlap.method, "contact_ratio": result.priors["contact_ratio"],
        "relation_holds": holds,
        "passed": allow or (overlap.iou <= INTERSECTION_LIMIT and (contact <= CONTACT_LIMIT if touches else
                                                                   bool(holds))),
        "seconds": round(time.perf_counter() - start, 2),
    }
