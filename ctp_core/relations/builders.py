"""Proposals that satisfy the prompt's relation by construction where the search's regions do not reach it.

``proposals.propose`` draws from regions (top, side, bottom, cavity, gaps, drops, floor) with the source in its
own resting frames; some relations need a pose none of them makes: a stick leaning against a box is neither
standing upright beside the box nor lying on it, and no region tilts it (docs/relations.md, "Where poses are judged
by it").

``lean``: the source standing on its longest principal axis (either end up, any turn about +Y), tilted by
``LEAN_TILTS`` about the horizontal axis along a side of the target, so its top tips toward the target; its
lowest point on the floor the target stands on, just outside a side sample (the "side" region's samples,
their outward normal made horizontal), then moved straight toward the target until it touches
(``contact.settle``'s "straight" approach). A reading that names the side leant on ("against the back of the
sofa": ``lean+behind``) draws only the side samples facing that way (``toward``; within 45 degrees).

``in``: the source standing in the target's most enclosed up-facing places (the floors of its cavities: the
share of horizontal directions around a point that meet the target, ``enclosure``, weighting the
draw), half on its longest principal axis (a candle in a holder's cup, a pencil in a mug), half in its own
resting frames (a hot dog in its bun), lowered onto the point. The regions' cavity proposals centre the source
on a point inside the target's hull: a candle standing in a shallow cup on top of a tall holder has its centre
above the rim, where no cavity point is.

``hang``: the source hung by a *hook point* on an up-facing point of a *thin* part of the target (a peg, a
branch, a rail), turned as it would hang: its centre straight below the hook point (any turn about +Y), the
hook point just above the target's point, then lowered into contact. A hook point is a sample whose normal
faces along its plumb line (toward the source's centre: the inside of a ring's loop, a hook's bend, a hanger's
crook) and whose plumb line meets the source again beyond it (the loop closes under it); the part fits when
the target's vertical thickness under its point (down to its next down-facing surface) is less than that
clearance. The regions approach the target from outside, so a ring never comes to be threaded on a peg: it
ends against the wall's side or hooked over its top edge.

``penetrate``: the source driven end first into the target: on its longest principal axis along the inward
normal of a surface sample that does not face down, ``PIERCE_DEPTH`` of its length in, raised where it would
pass below the floor; not settled (it is meant to intersect). The regions settle every proposal free of the
target, so what holds "penetrate" among them lies half sunk along a surface rather than standing in it.

The directional relations (``apart``): beside the target on the named side of it (``front``, ``behind``, ``left``,
``right``, in its own frame or the viewer's, ``axes``), ``near`` or ``far`` from it, or turned to it
alone (``facing``, ...): the source in its resting frames on the floor the target stands on, out from the
target's extent along the side's direction (any direction for near, far and orientations) by a gap in the
relation's band, level with the target across that direction (sides; its centre elsewhere); turned about +Y at
random, or so that its own front (``PreparedPair.source_front``) points as the reading's orientation says
(toward the target, away from it, along the target's front). ``above``: the source over a point of the target's
top surface, its bottom clear above the target's top. ``below`` (``beneath``): the source standing on the floor
under a down-facing point of the target lifted off it (a hung lamp's underside, a shelf board's, a desk top's), its
top clear by ``BELOW_CLEAR`` of the lowest target surface in that column (as wide as the source, as the score's
footprint); where nothing the target has is lifted high enough for the source (a block standing on the floor),
none are made. Kept where they are put (free of the target by construction: the
approach "none"; those that meet another part of it are dropped): the regions settle every proposal into contact.

``under`` is made as ``below`` is (``beneath``) and ``beside`` as the sides are (``apart``, at the ground's lateral
sides, alternately).

Each kind is made only where it is the prompt's relation (its position, the first of a reading of two) with the
source as the figure and ``config.relation`` is on, in place of as many region proposals (``extend``); otherwise
the proposals are unchanged. Each relation's builder is its spec's (``registry.SPECS``, ``Spec.builder``; a
relation without one has none), defined in the relation's kind module.
"""

from __future__ import annotations

import numpy as np
import torch

from ctp_core.config import AlignConfig, share_of
from ctp_core.contact import Proposals, Site
from ctp_core.geometry.pose import Poses
from ctp_core.pairs import PreparedPair
from ctp_core.reading.relation import RelationReading
from ctp_core.relations.registry import SPECS

SHARE = 0.25  # a relation's own proposals, as a share of ``search.candidates`` (in place of the regions')


def own_count(config: AlignConfig) -> int:
    """How many poses a relation's builder proposes: ``SHARE`` of ``search.candidates`` (``config.share_of``)."""
    return share_of(config.search.candidates, SHARE)


def extend(pair: PreparedPair, config: AlignConfig, proposals: Proposals, reading: RelationReading | None,
           seed: int) -> Proposals:
    """``proposals`` with those that satisfy the ``reading`` by construction (its position's ``Spec.builder``; see
    the module docstring) in place of as many of theirs, spread evenly over them (the caller's start kept): the
    relation's proposals take their share of ``search.candidates`` rather than adding to it, so the search costs
    what it does without them."""
    if reading is None or not reading.source_is_figure or not config.relation:
        return proposals
    build = SPECS[reading.position].builder
    if build is None or proposals.rotations is None:
        return proposals
    # one build per scale the regions' proposals take (scale mode with a guide: every rung of the ladder, so the
    # guide judges the relation's own poses at each size, not at the centre alone), sharing the relation's count
    scales = list(dict.fromkeys(proposals.poses.log_s.tolist()))
    count = share_of(max(1, config.search.candidates // len(scales)), SHARE)  # ``own_count`` of each rung's share
    built = [build(pair, proposals, seed + i, reading, log_s, count) for i, log_s in enumerate(scales)]
    built = [extra for extra in built if extra is not None and len(extra.poses)]
    if not built:
        return proposals
    proposals = proposals.select(_thinned(proposals.region, sum(len(extra.poses) for extra in built)))
    parts = [proposals, *built]
    sites = Site(*(torch.cat(columns) for columns in zip(*(vars(part.sites).values() for part in parts), strict=True)))
    return Proposals(Poses.cat([part.poses for part in parts]), [r for part in parts for r in part.region], sites,
                     proposals.rotations, proposals.index)


def _thinned(region: list[str], drop: int) -> list[int]:
    """Indices of proposals ``region`` less ``drop`` of them, evenly spread (each region keeps its share), the
    caller's start ("init") always kept; at least one."""
    kept = [i for i, r in enumerate(region) if r != "init"]
    count = max(1, len(kept) - drop)
    chosen = {kept[int(k)] for k in np.linspace(0, len(kept) - 1, count).round()} if kept else set()
    return sorted(chosen | {i for i, r in enumerate(region) if r == "init"})


