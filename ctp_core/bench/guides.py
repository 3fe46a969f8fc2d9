"""What guides a benchmark run, and how b2 scores with the same guide.

- ``text``: the case prompt (the product's use).
- ``image``: one picture of the reference arrangement from a random view (image-guided alignment).
- ``oracle``: per view, the reference arrangement rendered with the same camera
  (``targets.ReferenceTarget``). The problem then has a known optimum, so pose error measures the
  optimiser with whatever encoder is at hand, random ones included (issue 6).

Renders here use ``scene.prepare_pair(canonicalise=False)``: the normalised frame of the *file-frame*
target (AABB centred, longest side 2), so a view depends on the arrangement only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
import trimesh

from ctp_core import render, scene
from ctp_core.bench.cases import Case
from ctp_core.cameras import framing_cameras
from ctp_core.errors import ConfigError
from ctp_core.guidance import Guide

GUIDES: tuple[str, ...] = ("text", "image", "oracle")
IMAGE_AZIMUTHS = 36  # the image guide's view: one of 36 azimuths, elevation U(20°, 50°)


@dataclass
class GuideInputs:
    """The keyword arguments ``align`` gets for one guide kind, and a line for reports."""

    kind: str
    prompt: str
    image: np.ndarray | None = None  # (H, W, 3) uint8
    guidance: object | None = None  # a ctp_core.targets object
    description: str = ""


def _pair_and_pose(target: trimesh.Trimesh, source: trimesh.Trimesh,
                   source_to_target: np.ndarray) -> tuple[scene.PreparedPair, torch.Tensor]:
    """The pair in the file-frame normalised frame and its scene vertices (1, V, 3) at one pose."""
    pair = scene.prepare_pair(target, source, samples=100, seed=0, canonicalise=False)
    return pair, pair.scene_at(pair.local_to_normalised(source_to_target))


def reference_image(target: trimesh.Trimesh, source: trimesh.Trimesh, reference: np.ndarray,
                    rng: np.random.Generator, image_size: int = 224) -> np.ndarray:
    """(H, W, 3) uint8 render of the reference arrangement from a random framing view."""
    pair, verts = _pair_and_pose(target, source, reference)
    cams = framing_cameras(verts[0], IMAGE_AZIMUTHS, image_size, elevation_deg=float(rng.uniform(20, 50)))
    k = int(rng.integers(IMAGE_AZIMUTHS))
    one = replace(cams, eye=cams.eye[:, k:k + 1], at=cams.at[:, k:k + 1], fov_deg=cams.fov_deg[:, k:k + 1])
    with torch.no_grad():
        image = render.render(pair.mesh, verts, one)[0, 0]
    return (image.permute(1, 2, 0).clamp(0, 1).numpy() * 255).round().astype(np.uint8)


def guide_inputs(kind: str, case: Case, target: trimesh.Trimesh, source: trimesh.Trimesh,
                 rng: np.random.Generator) -> GuideInputs:
    """Build one guide for a case; ``image`` and ``oracle`` need the case's reference arrangement."""
    from ctp_core import targets

    if kind not in GUIDES:
        raise ConfigError(f"guide must be one of {', '.join(GUIDES)}, got {kind!r}", field="guide")
    if kind == "text":
        return GuideInputs(kind, case.prompt, description=f"text: {case.prompt!r}")
    if case.reference is None:
        raise ConfigError(f"case {case.id} has no reference arrangement, which the {kind} guide needs",
                          field="guide")
    if kind == "image":
        image = reference_image(target, source, case.reference, rng)
        return GuideInputs(kind, case.prompt, image=image, description="image: reference arrangement, random view")
    return GuideInputs(kind, case.prompt, guidance=targets.ReferenceTarget(case.reference),
                       description="oracle: reference arrangement rendered per view")


class SelectionScore:
    """b2's criterion: mean cosine over fixed views with the guide ctp gets (higher is better).

    Text and image: each view of the candidate (views framing it) against the prompt or picture
    embedding. Oracle: each view against the reference seen by the same camera (views framing the
    reference), as ``ReferenceTarget`` does during optimisation.
    """

    def __init__(self, inputs: GuideInputs, target: trimesh.Trimesh, source: trimesh.Trimesh, guide: Guide,
                 reference: np.ndarray | None, views: int = 8, image_size: int = 224):
        self.pair = scene.prepare_pair(target, source, samples=100, seed=0, canonicalise=False)
        self.guide, self.views, self.image_size = guide, views, image_size
        self.cameras = None
        if inputs.kind == "oracle":
            ref_verts = self.pair.scene_at(self.pair.local_to_normalised(reference))
            self.cameras = framing_cameras(ref_verts[0], views, image_size)
            with torch.no_grad():
                self.embedding = guide.encode_images(render.render(self.pair.mesh, ref_verts, self.cameras)[0])
        elif inputs.kind == "image":
            self.embedding = guide.encode_reference_image(inputs.image)
        else:
            self.embedding = guide.encode_text([inputs.prompt])[0]

    def __call__(self, source_to_target: np.ndarray) -> float:
        if self.cameras is None:
            images = scene.render_pair(self.pair, self.pair.local_to_normalised(source_to_target),
                                       views=self.views, image_size=self.image_size)
            return float(self.guide.score(images, self.embedding).mean())
        with torch.no_grad():
            verts = self.pair.scene_at(self.pair.local_to_normalised(source_to_target))
            images = render.render(self.pair.mesh, verts, self.cameras)[0]
            return float((self.guide.encode_images(images) * self.embedding).sum(-1).mean())
