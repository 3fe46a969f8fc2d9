"""Per-phase settings (../shared/docs/method.md, "Optimise" and "Camera scheduling").

Phases let the geometric terms grow (log-spaced weights) while the cameras move from the target's
centre toward the posed source and come closer, so a small source fills more pixels late in the run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctp_core.config import AlignConfig


@dataclass(frozen=True)
class Phase:
    index: int  # 1-based
    steps: int
    lambda_clip: float
    lambda_icp: float
    lambda_pen: float
    sigma_icp: float
    look_at_beta: float  # 0: look at the target centre; 1: at the posed source centroid
    zoom: float  # camera distance factor
    lambda_rel: float = 0.0  # the relation term (``objective.Scorer``: zeros without a known relation)


def log_spaced(first: float, last: float, count: int) -> list[float]:
    """count values from first to last, evenly spaced in log (linear if either end is 0)."""
    if count == 1:
        return [float(last)]
    if first <= 0 or last <= 0:
        return [float(v) for v in np.linspace(first, last, count)]
    return [float(v) for v in np.geomspace(first, last, count)]


def split_steps(total: int, phases: int) -> list[int]:
    """Spread ``total`` steps over phases as evenly as possible (earlier phases get the remainder)."""
    base, extra = divmod(total, phases)
    return [base + (1 if i < extra else 0) for i in range(phases)]


def phases(config: AlignConfig, allow_penetration: bool) -> list[Phase]:
    """The phase plan of a run; ``allow_penetration`` sets lambda_pen = 0 for the whole run."""
    count = config.optim.phases
    cam = config.camera
    icp = log_spaced(*config.loss.lambda_icp, count)
    sigma = log_spaced(*config.loss.sigma_icp, count)
    pen = [0.0] * count if allow_penetration else log_spaced(*config.loss.lambda_pen, count)
    rel = log_spaced(*config.loss.lambda_rel, count) if config.relation else [0.0] * count
    if cam.schedule and count > 1:
        betas = list(np.linspace(0.0, cam.look_at_beta_last, count))
        zooms = [cam.zoom_last ** (i / (count - 1)) for i in range(count)]
    else:
        betas, zooms = [0.0] * count, [1.0] * count
    return [
        Phase(i + 1, steps, config.loss.lambda_clip, icp[i], pen[i], sigma[i], float(betas[i]), float(zooms[i]),
              rel[i])
        for i, steps in enumerate(split_steps(config.optim.steps, count))
    ]
