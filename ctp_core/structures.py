"""Plain array containers shared by the renderer, the losses and the exporters (no I/O here).

``MeshArrays`` carries geometry and appearance in whatever frame its producer names; the renderer
turns it into tensors. Colours are sRGB in [0, 1]; a texture multiplies the vertex colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class MeshArrays:
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int64
    colors: np.ndarray  # (V, 3) float32 in [0, 1]; white when the mesh has no colour
    uv: np.ndarray | None = None  # (V, 2) float32, trimesh/OpenGL convention (v = 0 at the image bottom)
    texture: np.ndarray | None = None  # (H, W, 3) float32 in [0, 1], base colour
