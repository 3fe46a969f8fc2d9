"""Progress events: what a run reports while it works, how it is asked to stop, and the clock of its parts.

The optimiser calls ``on_event(ProgressEvent)``; the CLI draws a bar from it and the worker publishes
it. ``should_cancel()`` is polled between steps. ``Clock`` times the parts of a run (its phase timings).
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Literal

EventKind = Literal["phase_start", "step", "phase_end", "done"]
# The pipeline stage an event belongs to: the search scores candidate poses (step/steps count candidates),
# the refinement optimises the best of them (step/steps count optimisation steps).
StageName = Literal["search", "refine"]


@dataclass
class ProgressEvent:
    """What the optimiser reports; the CLI draws a bar from it and the worker publishes it."""

    kind: EventKind
    phase: int  # 1-based; 0 before the first phase
    phases: int
    step: int  # steps done so far over all phases (per restart; restarts run as one batch)
    steps: int
    restarts: int
    elapsed_s: float
    eta_s: float | None
    losses: dict[str, float] = field(default_factory=dict)  # mean over restarts of the last step
    # the search: its best candidate's objective; the refinement: the objective of ``restart``
    best_objective: float | None = None
    message: str = ""
    stage: StageName = "refine"
    # the refinement: the restart the readout describes, the answer were the run to stop now
    # (``ordering.select_answer``; the run's answer at the last phase's end and at ``done``)
    restart: int | None = None
    # what a person reads instead of the objective (whose scale changes with each phase's weights):
    relation: str | None = None  # the prompt's relation where it judges poses (None: unknown or off)
    relation_holds: int | None = None  # where it holds: of the candidates scored so far (search), of the restarts
    relation_checked: int | None = None  # ... out of this many
    guide_match: float | None = None  # ``restart``'s mean cosine to the guide's goal, evaluation views
    contact_gap: float | None = None  # ``restart``'s gap to the target, source diagonals, within the target
    # samples' spacing (0: touching)

    @property
    def fraction(self) -> float:
        return min(1.0, self.step / max(1, self.steps))


ProgressCallback = Callable[[ProgressEvent], None]
CancelCheck = Callable[[], bool]


class Clock:
    """Wall time per component (render / clip / geometry / eval / search).

    Spans do not nest: time inside an outer span (e.g. the render inside an evaluation) counts for
    the outer one only, so the parts add up to the total.
    """

    def __init__(self):
        self.totals: dict[str, float] = defaultdict(float)
        self._active = False

    @contextmanager
    def time(self, key: str):
        if self._active:
            yield
            return
        self._active = True
        start = time.perf_counter()
        try:
            yield
        finally:
            self.totals[key] += time.perf_counter() - start
            self._active = False

    def mark(self) -> dict[str, float]:
        """The totals now, for ``since``."""
        return dict(self.totals)

    def since(self, mark: dict[str, float], started: float) -> dict[str, float]:
        """Seconds per component spent since ``mark`` (those that ran), ``total`` since ``started`` (perf_counter)
        and ``other`` (the rest): one clock serves the search, then the refinement and each of its phases."""
        split = {k: v - mark.get(k, 0.0) for k, v in self.totals.items() if v > mark.get(k, 0.0)}
        total = time.perf_counter() - started
        return {**split, "total": total, "other": total - sum(split.values())}
