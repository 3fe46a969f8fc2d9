"""Progress events: what a run reports while it works, and how it is asked to stop.

The optimiser calls ``on_event(ProgressEvent)``; the CLI draws a bar from it and the worker publishes
it. ``should_cancel()`` is polled between steps.
"""

from __future__ import annotations

from collections.abc import Callable
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
    best_objective: float | None = None
    message: str = ""
    stage: StageName = "refine"

    @property
    def fraction(self) -> float:
        return min(1.0, self.step / max(1, self.steps))


ProgressCallback = Callable[[ProgressEvent], None]
CancelCheck = Callable[[], bool]
