"""Plain array containers shared by the renderer, the losses and the exporters (no I/O here).

``MeshArrays`` carries geometry and appearance in whatever frame its producer names; the renderer
turns it into tensors. Colours are sRGB in [0, 1]; a texture multiplies the vertex colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from PIL import Image


@dataclass
class MeshArrays:
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int64
    colors: np.ndarray  # (V, 3) float32 in [0, 1]; white when the mesh has no colour
    uv: np.ndarray | None = None  # (V, 2) float32, trimesh/OpenGL convention (v = 0 at the image bottom)
    texture: np.ndarray | None = None  # (H, W, 3) float32 in [0, 1], base colour

    @classmethod
    def from_trimesh(cls, mesh: trimesh.Trimesh) -> MeshArrays:
        """Geometry and appearance of a loaded mesh, vertices kept in the mesh's own frame.

        Colour sources, in trimesh's terms: ``ColorVisuals`` give per-vertex colours (face colours are
        averaged onto vertices); ``TextureVisuals`` give UVs and the base-colour image (PBR
        ``baseColorTexture`` or the OBJ ``map_Kd`` image), with the PBR base colour factor (linear in
        glTF, converted to sRGB) as the per-vertex multiplier, or the material colour when untextured;
        otherwise white.
        """
        vertices = np.asarray(mesh.vertices, dtype=np.float32)
        faces = np.asarray(mesh.faces, dtype=np.int64)
        white = np.ones((len(vertices), 3), dtype=np.float32)
        visual = mesh.visual
        if isinstance(visual, trimesh.visual.ColorVisuals):
            if not visual.defined:
                return cls(vertices, faces, white)
            return cls(vertices, faces, _unit_rgb(visual.vertex_colors))
        material = getattr(visual, "material", None)
        if material is None:
            return cls(vertices, faces, white)
        pbr = isinstance(material, trimesh.visual.material.PBRMaterial)
        # glTF's baseColorFactor is linear and multiplies the (sRGB) texture; an MTL's Kd is sRGB and,
        # beside a map_Kd, usually an exporter default (Blender writes 0.8), so an OBJ texture is taken as is.
        factor = (None if material.baseColorFactor is None else _srgb(material.baseColorFactor)) if pbr else None
        image = material.baseColorTexture if pbr else getattr(material, "image", None)
        uv = getattr(visual, "uv", None)
        if image is None or uv is None or len(uv) != len(vertices):
            solid = factor if pbr else _unit_rgb(np.atleast_2d(material.main_color))[0]
            return cls(vertices, faces, white if solid is None else np.tile(solid, (len(vertices), 1)))
        colors = white if factor is None else np.tile(factor, (len(vertices), 1))
        return cls(vertices, faces, colors, np.asarray(uv, dtype=np.float32), _texture(image))


_MAX_TEXTURE_PIXELS = 1024 * 1024


def _unit_rgb(rgba: np.ndarray) -> np.ndarray:
    """trimesh's uint8 RGB(A) -> float32 RGB in [0, 1]."""
    return (np.asarray(rgba)[:, :3].astype(np.float32) / 255.0).clip(0.0, 1.0)


def _srgb(linear_rgba: np.ndarray) -> np.ndarray:
    """glTF's linear uint8 RGBA factor -> (3,) float32 sRGB in [0, 1], the renderer's colour space."""
    linear = np.asarray(linear_rgba, dtype=np.float64)[:3] / 255.0
    return trimesh.visual.color.linear_to_srgb(linear).astype(np.float32).clip(0.0, 1.0)


def _texture(image: Image.Image) -> np.ndarray:
    """PIL image -> (H, W, 3) float32 in [0, 1], rows top to bottom.

    Downscaled to at most 1024² pixels (aspect kept): renders are 224 px, and a budget in pixels
    rather than side length keeps detail in the wide atlases trimesh packs multi-material scenes into.
    """
    image = image.convert("RGB")
    pixels = image.width * image.height
    if pixels > _MAX_TEXTURE_PIXELS:
        factor = (_MAX_TEXTURE_PIXELS / pixels) ** 0.5
        size = (max(1, round(image.width * factor)), max(1, round(image.height * factor)))
        image = image.resize(size, Image.Resampling.BOX)
    return np.asarray(image, dtype=np.float32) / 255.0
