"""Scale mode (``AlignConfig.scale``): the scale every start takes, the scales the search tries and how far the
refinement may move it.

Every start's scale comes from the priors' size ratio (source/target longest side, clamped to [0.1, 10] as
the method does, ../shared/docs/method.md), never from an incoming pose or the files' sizes: in scale mode the
source's given size is what is unknown (the benchmark's scale protocol scales it by U(0.01, 100)), so
``align.prepare`` does not let the mesh extents set the ratio either. The ratio is an estimate: on the labelled triples
(``benchmarks/priors_labels.jsonl``) the rules provider's |ln(estimate / label)| is ``PRIOR_SIGMA`` at its 68th
percentile and ``LADDER_WIDTH`` at its 90th (docs/priors.md). With a guide, the search proposes at ``RUNGS``
scales evenly spread over ``LADDER_WIDTH`` either side of the ratio's scale (``plan``) and the guide picks among
them; without one, at the centre alone: the geometry cannot tell which size is right, and across rungs it picked
the rung where the relation holds most easily (a smaller source "in", a larger one "on"), not the right one, while
the ladder left the centre a fifth of the proposals (docs/engine.md, "Scale mode"). The refinement
optimises log-scale from there; the objective's ``scale`` term (``ScalePlan.term``) is the estimate's own
uncertainty, ((log s - centre) / PRIOR_SIGMA)^2 / 2, which decides where the geometry alone judges (soft-ICP at
contact favours a smaller source) and is a tie-break where a guide does, plus a steep wall beyond the band.

Where the geometry bounds the scale, it decides over the priors (``Bound``, ``geometric_bound``):
- ``in`` (the target has a cavity): the source fits the cavity: its two shortest sides at most the cavity's two
  horizontal sides. An upper bound: the rungs above it are dropped (the bound kept as one), the wall starts there.
- ``hang`` (the source has a hook point, ``attached.hook_points``): its loop takes the part it hangs on:
  the widest hook clearance at least the target's thinnest up-facing part (``attached.peg_thickness``).
  A lower bound: the rungs below it are raised to it, the wall starts there.
- ``on``, a lid (the source flat, the target open at its top): the source's footprint (its two horizontal sides,
  upright) covers the opening's two horizontal sides, as a lid covers a jar's rim. A lower bound, as ``hang``.
- ``wear`` (the source has a cavity: a hat, a crown, a cap): it fits what wears it: as wide inside (its upright
  frame, horizontally) as the target's top part as deep as that cavity. A fit: the ladder centres there instead of
  on the priors' ratio and spans the scales that fit within ``FIT_TOLERANCE``.
A lower bound or a fit farther above (a fit: either side of) the priors' ratio than ``LADDER_WIDTH`` is left out
(reported): two estimates that disagree past the priors' 90th percentile mean the bound's model does not apply (a
comb "on its head" is no hollow thing worn over the top; a coin on a cup is no lid), and the priors decide. The
bounds are for the source the figure (``ScenePrior.source_is_figure``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from ctp_core.pairs import PreparedPair
from ctp_core.priors import ScenePrior
from ctp_core.relations.registry import SPECS
from ctp_core.relations.spec import Bound

PRIOR_SIGMA = 0.42  # the rules provider's size-ratio error, |ln(estimate / label)|, 68th percentile
LADDER_WIDTH = 1.08  # ... its 90th percentile: the ladder spans the ratio's scale times exp(+-LADDER_WIDTH)
RUNGS = 5  # scales the search tries (an odd count: the centre is one)
PRIOR_WEIGHT = 1.0  # the ``scale`` term's prior half where the geometry alone judges: it decides the size
PRIOR_FLOOR = 1e-3  # ... where a guide judges fully: a tie-break, far under what a guide's term moves between sizes
WALL = 100.0  # the ``scale`` term's weight per squared log-unit beyond the ladder's ends (or a geometric bound)
# width of what wears it (the ladder and the scale term's sigma come from that band, not the priors' error)
@dataclass(frozen=True)
class ScalePlan:
    """The run's scales (log pose scale, source local -> normalised, which is also the source file -> target file
    scale) and where they came from."""

    ratio_log_s: float  # the priors' size ratio as a scale
    centre: float  # the ladder's centre: the ratio's scale, or a geometric fit
    rungs: tuple[float, ...]  # what the search proposes at, the centre first
    low: float  # the refinement's band: beyond it the ``scale`` term's wall
    high: float
    size_ratio: float
    reason: str  # the priors' reason
    names: dict[str, str | None]  # the names the priors read (target, source, on)
    bound: Bound | None = None
    sigma: float = PRIOR_SIGMA  # the centre's uncertainty (log): the priors' error, or half a fit's band
    relation: str | None = None  # the priors' reading, by its name (the report's)
    rejected: str | None = None  # a geometric fit left out, and why

    def term(self, log_s: torch.Tensor, geometric: float = 1.0) -> torch.Tensor:
        """(B,) the objective's ``scale`` term: w x ((log s - centre) / sigma)^2 / 2, plus ``WALL`` x the
        squared distance beyond the band (``low``, ``high``). ``geometric``: how far the geometry judges alone (1
        without a guide, 0 with one whose say is full: ``Scorer.preference_weight``); w runs from
        ``PRIOR_FLOOR`` to ``PRIOR_WEIGHT`` with it: soft-ICP and the relation's terms at contact favour a smaller
        source, and nothing but a guide sees which size is right."""
        weight = PRIOR_FLOOR + (PRIOR_WEIGHT - PRIOR_FLOOR) * geometric
        beyond = log_s - log_s.clamp(self.low, self.high)
        return weight * 0.5 * ((log_s - self.centre) / self.sigma) ** 2 + WALL * beyond**2

    def at_centre(self) -> ScalePlan:
        """This plan as without a guide: the search at the centre alone (the geometry cannot tell which size is
        right; across rungs it would pick where the relation holds most easily), the band kept."""
        return replace(self, rungs=(self.centre,))

    def to_dict(self) -> dict:
        """The report's ``extra.scale`` (before the final scale is known)."""
        return {"initial": math.exp(self.centre), "from": "priors" if self.centre == self.ratio_log_s else "geometry",
                "size_ratio": self.size_ratio, "priors_scale": math.exp(self.ratio_log_s),
                "names": self.names, "priors_reason": self.reason,
                "constraint": None if self.bound is None else {"kind": self.bound.reason,
                                                              "scale": math.exp(self.bound.log_s),
                                                              "side": self.bound.cuts},
                "sigma": self.sigma, "relation": self.relation, "rejected": self.rejected,
                "ladder": [math.exp(r) for r in sorted(self.rungs)], "band": [math.exp(self.low), math.exp(self.high)]}


def ratio_scale(pair: PreparedPair, size_ratio: float) -> float:
    """The log pose scale that makes the source's longest side ``size_ratio`` times the related object's (the
    target's, or in a scene of placed objects the one it relates to: the priors read that one's name)."""
    target = (pair.target_vertices if pair.attach is None else pair.anchor.points).cpu()
    source = pair.source_vertices.cpu()
    target_side = float((target.max(0).values - target.min(0).values).max())
    source_side = float((source.max(0).values - source.min(0).values).max())
    return math.log(size_ratio * target_side / max(source_side, 1e-30))


def geometric_bound(pair: PreparedPair, prior: ScenePrior, seed: int, ratio: float) -> Bound | None:
    """The geometry's bound on the scale for the priors' relation (the source the figure; its spec's ``bound``,
    looking twice the ladder's width either side of the priors' scale ``ratio``), or None."""
    reading = prior.reading
    if reading is None or not reading.source_is_figure:
        return None
    bound = SPECS[reading.position].bound
    return None if bound is None else bound(pair, seed, ratio, 2 * LADDER_WIDTH)


def plan(pair: PreparedPair, prior: ScenePrior, names: dict[str, str | None], seed: int,
         guided: bool = True) -> ScalePlan:
    """The run's ``ScalePlan``: the priors' ratio, the geometry's bound for its relation, the ladder. ``guided``:
    a guide will judge the candidates; without one the search proposes at the centre alone (``searched``)."""
    ratio = ratio_scale(pair, prior.size_ratio)
    bound = geometric_bound(pair, prior, seed, ratio)
    if bound is not None and bound.cuts != "upper" and (
            abs(bound.log_s - ratio) if bound.cuts == "fit" else bound.log_s - ratio) > LADDER_WIDTH:
        # two estimates that disagree past the priors' 90th percentile: the bound's model does not apply (a comb or
        # a flower "on its head" is no hollow thing worn over the top; a coin on a cup is no lid), the priors decide
        low, high = math.exp(ratio - LADDER_WIDTH), math.exp(ratio + LADDER_WIDTH)
        why = f"{bound.reason} at {math.exp(bound.log_s):.3g}, outside the priors' band ({low:.3g} to {high:.3g})"
        return replace(plan(pair, replace(prior, reading=None), names, seed, guided),
                       relation=None if prior.reading is None else prior.reading.name, rejected=why)
    sigma = PRIOR_SIGMA
    if bound is not None and bound.band is not None:  # a fit: its own band, not the priors' error
        centre, (low, high) = bound.log_s, bound.band
        rungs = sorted({centre, *np.linspace(low, high, RUNGS).tolist()})
        sigma = max((high - low) / 2, 1e-3)
    else:
        centre, low, high = ratio, ratio - LADDER_WIDTH, ratio + LADDER_WIDTH
        rungs = np.linspace(low, high, RUNGS).tolist()
        if bound is not None and bound.cuts == "upper":  # "in": the rungs above go, the wall starts there
            high = min(high, bound.log_s)
            low = min(low, high)
        elif bound is not None:  # "hang", "on": the rungs below go, the wall starts there
            low = max(low, bound.log_s)
            high = max(high, low)
        centre = min(max(centre, low), high)
        rungs = sorted({min(max(r, low), high) for r in rungs})
    searched = sorted(rungs, key=lambda r: (abs(r - centre), r))  # the centre first
    laddered = ScalePlan(ratio, centre, tuple(searched), low, high, prior.size_ratio, prior.reason, names, bound,
                         sigma=sigma, relation=None if prior.reading is None else prior.reading.name)
    return laddered if guided else laddered.at_centre()
