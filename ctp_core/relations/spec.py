"""What the engine knows of one relation besides its words: how the geometry judges it, the poses it builds,
what it says of the source's scale and where people usually put the figure.

``Spec`` is one relation's entry in the registry (``registry.SPECS``), under the name of its record in
``reading.records.RELATIONS`` (the words: contact shares, sizes, kind, region weights, how many grounds). The kind
modules (``resting``, ``contained``, ``attached``, ``apart``) each define the specs of their relations.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import torch

from ctp_core.contact import Proposals
from ctp_core.pairs import PreparedPair
from ctp_core.reading.records import RelationName
from ctp_core.reading.relation import RelationReading
from ctp_core.relations.measures import Context


@dataclass(frozen=True)
class Judge:
    """How the geometry judges one relation: its ``score`` (0 when it holds, ``relation_score``) and, where it holds
    in many places, its ``preference`` for the usual one (``preference``; None: it says nothing more)."""

    score: Callable[[Context], torch.Tensor]
    preference: Callable[[Context], torch.Tensor] | None = None


@dataclass(frozen=True)
class Bound:
    """What the geometry says of the scale (log pose scale, source local -> normalised)."""

    reason: str  # what bounds it: "in: fits the cavity", "hang: ...", "on: ...", "wear: ..." (the report's ``kind``)
    log_s: float
    cuts: Literal["upper", "lower", "fit"]  # the rungs above go, those below go, or the ladder's centre (the report's
    # ``side``)
    band: tuple[float, float] | None = None  # a fit's: the log scales within ``FIT_TOLERANCE`` of fitting


Builder = Callable[[PreparedPair, Proposals, int, RelationReading, float, int], Proposals | None]
# the geometry's bound on the source's scale for this relation with the source the figure: (pair, seed, the priors'
# log scale, how far either side of it to look) -> a ``Bound`` or None
ScaleBound = Callable[[PreparedPair, int, float, float], "Bound | None"]


@dataclass(frozen=True)
class Spec:
    """One relation as the engine knows it, under its record's name (``reading.records``).

    ``judge``: its score (0 when it holds) and its preference among the poses where it holds. ``builder``: the
    poses it makes by construction where the search's regions do not reach it (None: the regions do). ``bound``:
    what the geometry says of the source's scale (None: nothing). ``usual``: where people usually put the figure,
    in words (reports, docs/relations.md); the preference ranks poses toward it. ``where``: the ground's part the
    usual place is on, with its reason (``parts``: "the seat: up-facing at ..., a back rising behind it").
    """

    name: RelationName
    judge: Judge
    builder: Builder | None = None
    bound: ScaleBound | None = None
    usual: str = ""
    where: Callable[[Context], str | None] | None = None  # the part the usual place is on for this pose's pair
    # and why, in words (the verdict's ``usual``; ``parts``); None: ``usual`` says it all
