"""Does a guide know what the geometry knows? The measurements behind the guide's say (``ordering.Gate``).

For each case with a reference (rigid protocol start, one init, as ``ctp bench``): the search's proposals, all of
them, scored at the coarse views by the guide and the geometry; printed per case as one JSON line:

- ``held`` / ``failed``: proposals where the prompt's relation holds without intersecting (``ordering.holding``)
  and the others;
- ``agreement``: how often the guide ranks a holding proposal before a failing one (the Mann-Whitney AUC, 0.5 by
  chance), over all proposals, and ``agreement_seen`` over the ones the search lets the guide see
  (``coarse_to_fine.encoder_shortlist``); ``z``: the first's distance from chance in standard errors;
- ``gate``: the run's ``Gate`` as the search measures it on what it lets the guide see (spread, noise, override);
- ``views_agree``: the rank correlation (Spearman) between the guide's term seen by the first coarse view alone
  and by the second alone, over the holding proposals it sees (what it orders), and ``views_agree_seen`` over all
  it sees: a guide that sees where the source is agrees with itself from another side;
- ``knows``: per twin shift (source diagonals), ``knows`` on what the guide sees: [right, tested] comparisons of
  twins of its favourite holding proposals, moved as far, where the relation holds against where it fails;
- ``top_agree``: where each coarse view's favourite holding proposal ranks in the other view (``top_agreement``);
- ``guide_places`` / ``geometry_places``: whether the guide's best holding proposal places, and the geometry's
  (``rank_key`` without a guide; the usual arrangement included).

Measurement only: nothing here changes a run.

    python benchmarks/guide_say.py ../shared/bench/pairbench3d ../shared/bench/synthetic --guide oracle
    python benchmarks/guide_say.py ../shared/bench --guide text --model random:ViT-B-32     # the noise control
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace

import numpy as np
import torch
from search_recall import case_parser, each_case, errors  # a sibling script (benchmarks/ is on sys.path)

from ctp_core import align, metrics
from ctp_core.bench import protocol
from ctp_core.bench.guides import guide_inputs
from ctp_core.config import AlignConfig
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import Poses
from ctp_core.guide.loaders import guide_for
from ctp_core.search import coarse_to_fine, ordering


def agreement(terms: dict[str, torch.Tensor]) -> tuple[float, int, int] | None:
    """(share, held, failed): the share of (holding, failing) pose pairs whose holding pose the guide's term ranks
    first (the Mann-Whitney AUC), with the count on each side; None with fewer than 3 on either."""
    held = ordering.holding(terms)
    good, bad = terms["clip"].double()[held], terms["clip"].double()[~held]
    if len(good) < 3 or len(bad) < 3:
        return None
    before = (good[:, None] < bad[None, :]).double().sum() + 0.5 * (good[:, None] == bad[None, :]).double().sum()
    return float(before) / (len(good) * len(bad)), len(good), len(bad)


def agreement_z(share: float, held: int, failed: int) -> float:
    """``agreement``'s distance above chance in standard errors under chance (Mann-Whitney, no ties)."""
    return (share - 0.5) / math.sqrt((held + failed + 1) / (12.0 * held * failed))


def view_term(scorer, poses, cameras, view: int, batch: int) -> torch.Tensor:
    """(N,) the guide's term of ``poses`` seen by one of the shared ``cameras`` alone."""
    one = replace(cameras, eye=cameras.eye[:, [view]], at=cameras.at[:, [view]], fov_deg=cameras.fov_deg[:, [view]],
                  up=None if cameras.up is None else cameras.up[:, [view]])
    goal = coarse_to_fine.embed_shared_goal(scorer, one)
    with torch.inference_mode():
        chunks = [poses.select(slice(lo, lo + batch)) for lo in range(0, len(poses), batch)]
        return torch.cat([scorer.clip_term(c, one.expand(len(c)), goal) for c in chunks])


def spearman(a: torch.Tensor, b: torch.Tensor) -> float | None:
    if len(a) < 3:
        return None
    ra, rb = (torch.argsort(torch.argsort(x)).double() for x in (a, b))
    return float(torch.corrcoef(torch.stack([ra, rb]))[0, 1])


def places(pair, poses, key: torch.Tensor, held: torch.Tensor, reference, points) -> bool | None:
    """Whether the best holding pose by ``key`` places (None: none holds)."""
    if not bool(held.any()):
        return None
    best = int(torch.where(held, key.double(), torch.inf).argmin())
    return bool(errors(pair, poses.select([best]), reference, points)[0, 0] <= metrics.PLACEMENT_RADIUS)


def knows(scorer, poses, terms, weights, cameras, goal, shift: float, favourites: int = 4) -> list[int]:
    """[right, tested]: the guide's ``favourites`` best holding poses, each moved ``shift`` source diagonals both
    ways along each axis; the twins split by the geometry into those where the relation still holds and those
    where it fails or they intersect; ``right`` counts the (holding, wrong) twin pairs of one favourite whose
    holding twin the guide ranks first. Both kinds are moved as far from a favourite the guide picked, so the
    regression of that pick to the mean (any consistent function, noise included, likes its favourite's twins
    less) is the same on both sides: only a guide that sees the relation tells them apart."""
    clip, held = terms["clip"], ordering.holding(terms)
    picked = torch.nonzero(held)[:, 0]
    picked = picked[torch.argsort(clip[picked])[:favourites]]
    if not len(picked):
        return [0, 0]
    axes = torch.cat([torch.eye(3), -torch.eye(3)])
    base = poses.select(picked)
    moves = (shift * scorer.pair.source_diagonal * base.log_s.exp())[:, None, None] * axes.to(base.t)[None]
    twins = Poses((base.t[:, None] + moves).reshape(-1, 3), base.q.repeat_interleave(len(axes), 0),
                  base.log_s.repeat_interleave(len(axes)))
    twin_terms = coarse_to_fine.terms_of(scorer, twins, weights, cameras, batch=len(twins), goal_embeddings=goal)
    kept = ordering.holding(twin_terms).reshape(len(picked), len(axes))
    score = twin_terms["clip"].reshape(len(picked), len(axes))
    right = tested = 0
    for row in range(len(picked)):
        good, bad = score[row][kept[row]], score[row][~kept[row]]
        right += int((good[:, None] < bad[None, :]).sum())
        tested += len(good) * len(bad)
    return [right, tested]


def top_agreement(first: torch.Tensor, second: torch.Tensor) -> float | None:
    """Where each view's favourite ranks in the other view (0: its best, 1: its worst), the mean of both: a guide
    that sees where the source is agrees with itself at the top from another side; chance is about 0.5."""
    if len(first) < 3:
        return None
    where = lambda a, b: float((b < b[int(torch.argmin(a))]).double().mean())  # noqa: E731
    return 0.5 * (where(first, second) + where(second, first))


def run_case(case, args) -> dict:
    target, source = case.load()
    init = protocol.initial_poses(case.reference, source.bounds, protocol="rigid", count=1, seed=args.seed,
                                  case_id=case.id)[0]
    inputs = guide_inputs(args.guide, case, target, source, protocol.case_rng(args.seed, case.id, "guide"))
    config = AlignConfig.from_preset(args.preset, seed=args.seed, model=args.model)
    guide = inputs.guide or guide_for(config)
    run = align.prepare(target, source, case.prompt, config, guide=guide, goal=inputs.goal,
                        target_name=case.target_name, source_name=case.source_name)
    poses = align.propose(run, init).poses
    scorer, weights = run.scorer, run.plan[0]
    cameras = coarse_to_fine.coarse_cameras(run.pair, config, float(poses.log_s.max()))  # as the search frames them
    terms = coarse_to_fine.terms_of(scorer, poses, weights, cameras, batch=config.search.batch)
    held = ordering.holding(terms)
    seen = coarse_to_fine.encoder_shortlist(poses, terms, weights, config.search.shortlist,
                                     coarse_to_fine.distinct_of(run.pair, config, float(poses.log_s[0])),
                                     config.search.min_share)
    shown_poses, shown_terms = poses.select(seen), {k: v[seen] for k, v in terms.items()}
    every, shown = agreement(terms), agreement(shown_terms)
    gate = coarse_to_fine.guide_noise(scorer, shown_poses, shown_terms, weights, cameras,
                               coarse_to_fine.embed_shared_goal(scorer, cameras))
    first, second = (view_term(scorer, shown_poses, cameras, v, config.search.batch) for v in (0, 1))
    mask = held[seen]
    goal = coarse_to_fine.embed_shared_goal(scorer, cameras)
    twins = {shift: knows(scorer, shown_poses, shown_terms, weights, cameras, goal, shift) for shift in args.shifts}
    points = sampling.surface_samples(source, 500, args.seed)[0]
    geometric = ordering.rank_key(terms, weights, share=config.search.min_share)
    relation = scorer.reading.name if scorer.reading is not None else None
    return {"case": case.id, "guide": args.guide, "model": args.model, "relation": relation,
            "held": int(held.sum()), "failed": int((~held).sum()),
            "agreement": None if every is None else round(every[0], 3),
            "z": None if every is None else round(agreement_z(*every), 2),
            "agreement_seen": None if shown is None else round(shown[0], 3),
            "seen_failed": int((~held[seen]).sum()),
            "views_agree": spearman(first[mask], second[mask]), "views_agree_seen": spearman(first, second),
            "gate": {k: (round(v, 4) if isinstance(v, float) else v) for k, v in gate.to_dict().items()},
            "knows": twins, "top_agree": top_agreement(first[mask], second[mask]),
            "guide_places": places(run.pair, poses, terms["clip"], held, case.reference, points),
            "geometry_places": places(run.pair, poses, geometric.value, held, case.reference, points)}


def main(argv: list[str] | None = None) -> int:
    parser = case_parser(__doc__.split("\n\n")[0])
    parser.add_argument("--guide", default="oracle", choices=["text", "oracle", "pixels"])
    parser.add_argument("--shifts", default="0.1,0.25,0.5", type=lambda s: [float(x) for x in s.split(",")],
                        help="the twins' shifts, source diagonals (comma-separated)")
    np.set_printoptions(precision=3)
    return each_case(parser.parse_args(argv), run_case)


if __name__ == "__main__":
    sys.exit(main())
