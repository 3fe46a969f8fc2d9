"""What guides a benchmark run, and how b2 scores with the same guide.

- ``text``: the case prompt (the product's use).
- ``image``: one picture of the reference arrangement from a random view (image-guided alignment).
- ``oracle``: per view, the reference arrangement rendered with the same camera
  (``goals.ReferenceGoal``). The problem then has a known optimum, so pose error measures the
  optimiser with whatever encoder is at hand, random ones included.
- ``pixels``: the oracle without an encoder (``PixelGuide``): per view, the image distance to the reference
  rendered by the same camera. An upper-bound instrument, never a product number: with it a miss is the
  search's or the optimiser's, not the random encoder's weak signal.

Renders here use ``pairs.prepare_pair(canonicalise=False)``: the normalised frame of the *file-frame*
target (AABB centred, longest side 2), so a view depends on the arrangement only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
import trimesh

from ctp_core import pairs, render
from ctp_core.bench.cases import Case
from ctp_core.errors import ConfigError
from ctp_core.guide import goals
from ctp_core.guide.guidance import Guide
from ctp_core.render.cameras import framing_cameras

GUIDES: tuple[str, ...] = ("text", "image", "oracle", "pixels")
PER_VIEW = ("oracle", "pixels")  # guides that compare each view with the reference seen by the same camera
PIXELS_LABEL = "pixels: upper-bound instrument, image distance to the reference per view, no encoder"
IMAGE_AZIMUTHS = 36  # the image guide's view: one of 36 azimuths, elevation U(20°, 50°)


@dataclass
class GuideInputs:
    """The keyword arguments ``align`` gets for one guide kind, and a line for reports."""

    kind: str
    prompt: str
    image: np.ndarray | None = None  # (H, W, 3) uint8
    goal: goals.Goal | None = None
    description: str = ""
    guide: object | None = None  # replaces the encoder (the pixels guide)


class PixelGuide:
    """A ``guidance.Guide`` stand-in with no encoder: an image's "embedding" is its render itself.

    The view is area-downsampled to ``size``² pixels, inverted (the white background becomes 0, so only the
    objects count) and L2-normalised; the cosine of two such vectors is 1 - d²/2 with d the L2 distance
    between the normalised images, so the CLIP loss becomes an image distance. Differentiable, so the
    optimiser follows it too.
    """

    spec = "pixels"
    autocast = False

    def __init__(self, size: int = 32, device: str = "cpu"):
        self.size = size
        self.device = torch.device(device)
        self.embed_dim = 3 * size * size

    def __repr__(self) -> str:
        return f"PixelGuide(size={self.size})"

    def encode_images(self, images: torch.Tensor) -> torch.Tensor:
        small = torch.nn.functional.interpolate(images.float(), size=(self.size, self.size), mode="area")
        return torch.nn.functional.normalize((1.0 - small).flatten(1), dim=-1)

    def score(self, images: torch.Tensor, embedding: torch.Tensor, batch_size: int = 32) -> torch.Tensor:
        with torch.inference_mode():
            out = self.encode_images(images) @ embedding.reshape(-1, 1)
        return out[:, 0].clone()

    def encode_text(self, texts: list[str]) -> torch.Tensor:
        raise ConfigError("the pixels guide compares renders with the reference; it reads no text", field="guide")

    def encode_reference_image(self, image) -> torch.Tensor:
        raise ConfigError("the pixels guide compares renders with the reference; it takes no picture", field="guide")


def _pair_and_pose(target: trimesh.Trimesh, source: trimesh.Trimesh,
                   source_to_target: np.ndarray) -> tuple[pairs.PreparedPair, torch.Tensor]:
    """The pair in the file-frame normalised frame and its scene vertices (1, V, 3) at one pose."""
    pair = pairs.prepare_pair(target, source, samples=100, seed=0, canonicalise=False)
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
    if kind == "pixels":
        return GuideInputs(kind, case.prompt, goal=goals.ReferenceGoal(case.reference),
                           description=PIXELS_LABEL, guide=PixelGuide())
    return GuideInputs(kind, case.prompt, goal=goals.ReferenceGoal(case.reference),
                       description="oracle: reference arrangement rendered per view")


class SelectionScore:
    """b2's criterion: mean cosine over fixed views with the guide ctp gets (higher is better).

    Text and image: each view of the candidate (views framing it) against the prompt or picture
    embedding. Oracle and pixels: each view against the reference seen by the same camera (views framing
    the reference), as ``ReferenceGoal`` does during optimisation.
    """

    def __init__(self, inputs: GuideInputs, target: trimesh.Trimesh, source: trimesh.Trimesh, guide: Guide,
                 reference: np.ndarray | None, views: int = 8, image_size: int = 224):
        self.pair = pairs.prepare_pair(target, source, samples=100, seed=0, canonicalise=False)
        self.guide, self.views, self.image_size = guide, views, image_size
        self.cameras = None
        if inputs.kind in PER_VIEW:
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
            images = pairs.render_pair(self.pair, self.pair.local_to_normalised(source_to_target),
                                       views=self.views, image_size=self.image_size)
            return float(self.guide.score(images, self.embedding).mean())
        with torch.no_grad():
            verts = self.pair.scene_at(self.pair.local_to_normalised(source_to_target))
            images = render.render(self.pair.mesh, verts, self.cameras)[0]
            return float((self.guide.encode_images(images) * self.embedding).sum(-1).mean())
