"""The goal: what the guide compares the rendered views with: a text, an image, or the reference arrangement.

The optimiser asks a goal for embeddings given the step's cameras, so a goal may be per view:
the oracle (``ReferenceGoal``) renders the known arrangement with the same cameras, which gives the
problem a known optimum and lets the benchmark measure the optimiser with any encoder (random
encoders carry no view-invariant semantics, so per-view matching is the form that works for them).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch

from ctp_core import render
from ctp_core.guide.guidance import Guide
from ctp_core.pairs import PreparedPair
from ctp_core.render.cameras import Cameras


class Goal(Protocol):
    description: str

    def prepare(self, pair: PreparedPair, guide: Guide) -> None:
        """Compute whatever is fixed for the run (text/image embedding, reference vertices)."""

    def embeddings(self, cameras: Cameras) -> torch.Tensor:
        """(D,) for a fixed goal, or (B, C, D) matching the cameras' batch for a per-view one."""


class TextGoal:
    def __init__(self, prompt: str):
        self.prompt = prompt
        self.description = f"text: {prompt!r}"

    def prepare(self, pair: PreparedPair, guide: Guide) -> None:
        self._embedding = guide.encode_text([self.prompt])[0]

    def embeddings(self, cameras: Cameras) -> torch.Tensor:
        return self._embedding


class ImageGoal:
    """Image-guided alignment: the embedding of a reference picture replaces the text's."""

    def __init__(self, image: np.ndarray):
        self.image = image
        self.description = f"image: {image.shape[1]}x{image.shape[0]}"

    def prepare(self, pair: PreparedPair, guide: Guide) -> None:
        self._embedding = guide.encode_reference_image(self.image)

    def embeddings(self, cameras: Cameras) -> torch.Tensor:
        return self._embedding


class ReferenceGoal:
    """The oracle: per view, the embedding of the reference arrangement seen by the same camera."""

    def __init__(self, source_to_target: np.ndarray):
        self.source_to_target = np.asarray(source_to_target, dtype=np.float64)
        self.description = "oracle: reference arrangement rendered per view"

    def prepare(self, pair: PreparedPair, guide: Guide) -> None:
        self._vertices = pair.scene_at(pair.local_to_normalised(self.source_to_target))
        self._mesh = pair.mesh
        self._guide = guide

    @torch.no_grad()
    def embeddings(self, cameras: Cameras) -> torch.Tensor:
        batch, views = cameras.fov_deg.shape
        images = render.render(self._mesh, self._vertices.expand(batch, -1, -1), cameras)
        flat = images.reshape(batch * views, *images.shape[2:])
        return self._guide.encode_images(flat).reshape(batch, views, -1)
