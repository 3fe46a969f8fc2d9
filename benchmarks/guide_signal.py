"""How much an image guide's score moves between the search's candidates, against its rounding.

For each case with a reference (rigid protocol start, one init, as ``ctp bench``): the search's proposals are
rendered in the coarse views and encoded by the oracle's encoder twice, in fp32 and under the guide's autocast
(bf16 on a CPU with native bf16); printed per case as one JSON line:

- ``source_change``: 1 - cos(reference view, the same view without the source), mean over the views: how far
  the whole answer moves the embedding;
- ``spread``: the standard deviation of the oracle's cosine over the proposals (fp32): what ranks them;
- ``rounding``: the largest |cos_autocast - cos_fp32| over the proposals: the noise autocast adds;
- ``rank_fp32`` / ``rank_autocast``: the best rank of a proposal that places (0: first), by each.

Measurement only: nothing here changes a run.

    python benchmarks/guide_signal.py ../shared/bench/pairbench3d ../shared/bench/synthetic --model random:ViT-B-32
"""

from __future__ import annotations

import sys
from contextlib import contextmanager

import numpy as np
import torch
from search_recall import case_parser, each_case, errors  # a sibling script (benchmarks/ is on sys.path)

from ctp_core import align, metrics, render
from ctp_core.bench import protocol
from ctp_core.bench.guides import guide_inputs
from ctp_core.config import AlignConfig
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import Poses, apply_pose
from ctp_core.guide.loaders import guide_for
from ctp_core.search import coarse_to_fine


@contextmanager
def precision(guide, autocast: bool):
    """The guide with its autocast on (as loaded: bf16 where the CPU has it natively) or off (fp32)."""
    saved = guide.autocast
    guide.autocast = autocast and saved
    try:
        yield guide
    finally:
        guide.autocast = saved


def embeddings(guide, pair, poses: Poses, cameras, batch: int = 24) -> torch.Tensor:
    """(N, C, D) unit embeddings of ``poses`` rendered in shared ``cameras``."""
    out = []
    with torch.inference_mode():
        for lo in range(0, len(poses), batch):
            chunk = poses.select(slice(lo, lo + batch))
            verts = pair.scene_vertices(apply_pose(pair.source_vertices, chunk.t, chunk.q, chunk.log_s))
            images = render.render(pair.mesh, verts, cameras.expand(len(chunk)))
            flat = guide.encode_images(images.reshape(-1, *images.shape[2:]))
            out.append(flat.reshape(len(chunk), images.shape[1], -1))
    return torch.cat(out)


def best_rank(cosine: torch.Tensor, placed: np.ndarray) -> int | None:
    hits = np.flatnonzero(placed[torch.argsort(-cosine).numpy()])
    return int(hits[0]) if len(hits) else None


def run_case(case, args) -> dict:
    target, source = case.load()
    init = protocol.initial_poses(case.reference, source.bounds, protocol="rigid", count=1, seed=args.seed,
                                  case_id=case.id)[0]
    inputs = guide_inputs("oracle", case, target, source, protocol.case_rng(args.seed, case.id, "guide"))
    config = AlignConfig.from_preset(args.preset, seed=args.seed, model=args.model)
    guide = guide_for(config)
    run = align.prepare(target, source, case.prompt, config, guide=guide, goal=inputs.goal,
                        target_name=case.target_name, source_name=case.source_name)
    proposals = align.propose(run, init)
    pair, poses = run.pair, proposals.poses
    cameras = coarse_to_fine.coarse_cameras(pair, config, float(poses.log_s[0]))
    nothing = Poses(torch.zeros(1, 3), poses.q[:1], torch.full((1,), -30.0))  # a point-sized source: not drawn
    with precision(guide, False), torch.inference_mode():
        goal_views = run.scorer.embed_goal(cameras)[0]  # (C, D): the reference seen by each view
        empty = embeddings(guide, pair, nothing, cameras)[0]
        fp32 = (embeddings(guide, pair, poses, cameras) * goal_views).sum(-1).mean(dim=1)
    with precision(guide, True):
        rounded = (embeddings(guide, pair, poses, cameras) * goal_views).sum(-1).mean(dim=1)
    points = sampling.surface_samples(source, 500, args.seed)[0]
    placed = errors(pair, poses, case.reference, points)[:, 0] <= metrics.PLACEMENT_RADIUS
    return {"case": case.id, "model": args.model, "autocast": guide.autocast, "proposals": len(poses),
            "placing": int(placed.sum()),
            "source_change": float(1 - (empty * goal_views).sum(-1).mean()),
            "spread": float(fp32.std()), "rounding": float((rounded - fp32).abs().max()),
            "rank_fp32": best_rank(fp32, placed), "rank_autocast": best_rank(rounded, placed)}


def main(argv: list[str] | None = None) -> int:
    return each_case(case_parser(__doc__.split("\n\n")[0]).parse_args(argv), run_case)


if __name__ == "__main__":
    sys.exit(main())
