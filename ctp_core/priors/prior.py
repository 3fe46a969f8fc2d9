"""The scene prior: the three numbers the hyperparameter step gives the optimiser, and who gave them.

``size_ratio`` is source/target bounding-box size (longest side over longest side), the initial scale
in scale mode; ``penetration`` says the arrangement needs one solid inside the other (lambda_pen = 0);
``contact_ratio`` is the fraction of the source surface touching the target (the soft-ICP ratio r). Beside the
numbers, the relation the prompt names (``reading``), which reports write as three fields (``to_dict``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Protocol

from ctp_core.reading.relation import RelationReading

SIZE_RANGE = (0.1, 10.0)  # the paper clamps guessed size ratios here: beyond it a guess is noise


@dataclass(frozen=True)
class ScenePrior:
    size_ratio: float  # source/target bbox size; clamped to SIZE_RANGE unless given explicitly
    penetration: bool
    contact_ratio: float  # [0, 1] -> soft-ICP ratio r
    provider: str  # "rules", "openai", "rules (fallback: <why>)", or with "; explicit: <fields>"
    reason: str  # short, for humans
    # the relation read from the prompt (who plays the figure, the place on the ground the prompt names); None when
    # the provider does not say. The search weights where it proposes poses by it (never excluding a region).
    reading: RelationReading | None = None

    def to_dict(self) -> dict:
        """The prior as reports write it: the reading as its name, the source's role and the place."""
        values = {key: value for key, value in asdict(self).items() if key != "reading"}
        reading = self.reading
        return {**values, "relation": None if reading is None else reading.name,
                "source_is_figure": True if reading is None else reading.source_is_figure,
                "place": None if reading is None else reading.place}


def to_report(values: dict) -> dict:
    """Priors (``ScenePrior.to_dict``, maybe with more keys) as reports and ``ctp priors`` write them: the
    provider under ``source``, the spelling the report has always had (kept for compatibility)."""
    return {("source" if key == "provider" else key): value for key, value in values.items()}


class PriorProvider(Protocol):
    """Anything that turns (target name, source name, prompt) into a ``ScenePrior``; never raises."""

    name: str

    def estimate(self, target_name: str, source_name: str, prompt: str) -> ScenePrior: ...


def clamp_size(value: float) -> float:
    """A guessed size ratio in SIZE_RANGE (NaN and non-positive values are not guesses: ValueError)."""
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"size ratio must be a positive number, got {value!r}")
    return min(max(value, SIZE_RANGE[0]), SIZE_RANGE[1])


def clamp_contact(value: float) -> float:
    """A contact ratio in [0, 1]."""
    if not math.isfinite(value):
        raise ValueError(f"contact ratio must be a number, got {value!r}")
    return min(max(value, 0.0), 1.0)
