"""The align entry point: the one function the CLI, the worker and the bench call.

``align(target, source, prompt, config)`` takes meshes in their *file frames* (as ``io.load_mesh``
returns them) and returns an ``AlignResult`` whose transform maps the source file frame to the target
file frame. Everything in between (normalisation, canonical pose, optimisation) is internal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import trimesh

from ctp_core.config import AlignConfig

EventKind = Literal["start", "phase_start", "step", "phase_end", "done"]


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

    @property
    def fraction(self) -> float:
        return min(1.0, self.step / max(1, self.steps))

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind, "phase": self.phase, "phases": self.phases, "step": self.step,
            "steps": self.steps, "restarts": self.restarts, "fraction": round(self.fraction, 4),
            "elapsed_s": round(self.elapsed_s, 3),
            "eta_s": None if self.eta_s is None else round(self.eta_s, 1),
            "losses": {k: round(v, 6) for k, v in self.losses.items()},
            "best_objective": self.best_objective, "message": self.message,
        }


@dataclass
class AlignResult:
    """The answer in file frames, plus what a report and an export need."""

    source_to_target: np.ndarray  # (4, 4): p_target_file = M @ [p_source_file; 1]
    objective: float
    target: trimesh.Trimesh  # file frame, untouched
    source: trimesh.Trimesh  # source file frame (apply source_to_target to place it)
    prompt: str | None
    config: AlignConfig
    hparams: dict[str, Any]
    restarts: list[dict[str, Any]]
    timings: dict[str, float]
    preview: np.ndarray | None = None  # (V, H, W, 3) uint8 views of the final scene
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def scale(self) -> float:
        return float(np.cbrt(abs(np.linalg.det(self.source_to_target[:3, :3]))))

    @property
    def rotation(self) -> np.ndarray:
        return self.source_to_target[:3, :3] / self.scale

    @property
    def translation(self) -> np.ndarray:
        return self.source_to_target[:3, 3].copy()


ProgressCallback = Callable[[ProgressEvent], None]
CancelCheck = Callable[[], bool]
