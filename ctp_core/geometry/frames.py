"""Named coordinate frames and the similarities between them.

Every transform in the engine is a ``Similarity`` that says which frame it maps from and to, and
composition checks that the frames chain, so a missing or doubled step fails loudly instead of
silently misplacing the source. The frames:

- ``target_file`` / ``source_file``: as uploaded, scene graph flattened (``io.load_mesh``).
- ``scene`` (``SCENE``): an assembly's frame (``assemble``), the base's file frame. Stage k aligns its source
  against the objects placed so far, all in this frame, so each stage's target file frame *is* the
  scene frame and its answer maps source file -> scene.
- ``target_upright``: the target file frame turned by its canonical rotation (``canonical``); equal to
  the file frame when the upload is already upright.
- ``normalised``: the target's upright AABB centred at the origin with longest side 2. Cameras,
  renders and losses live here.
- ``source_local``: the source centred at its AABB centre, scaled by the *same* factor as the target,
  so the files' relative size is kept. A pose (``pose``) maps source local -> normalised.
- ``camera``: OpenGL-style, x right, y up, looking down -z (``cameras``).

The answer of a run is ``source_file -> target_file``: ``target_to_normalised⁻¹ @ pose @ source_to_local``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TARGET_FILE = "target_file"
SOURCE_FILE = "source_file"
TARGET_UPRIGHT = "target_upright"
NORMALISED = "normalised"
SOURCE_LOCAL = "source_local"
SCENE = "scene"


@dataclass(frozen=True)
class Similarity:
    """``p_to = matrix @ [p_from; 1]`` with ``matrix[:3, :3] = s * R`` (isotropic scale, rotation)."""

    matrix: np.ndarray  # (4, 4) float64
    from_frame: str
    to_frame: str

    def __post_init__(self) -> None:
        matrix = np.array(self.matrix, dtype=np.float64)  # own copy: frozen means frozen
        if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
            raise ValueError(f"a similarity needs a finite (4, 4) matrix, got shape {matrix.shape}")
        matrix.setflags(write=False)
        object.__setattr__(self, "matrix", matrix)

    @classmethod
    def from_parts(cls, rotation: np.ndarray, translation: np.ndarray, scale: float, from_frame: str,
                   to_frame: str) -> Similarity:
        """``p_to = scale * rotation @ p_from + translation``."""
        matrix = np.eye(4)
        matrix[:3, :3] = float(scale) * np.asarray(rotation, dtype=np.float64)
        matrix[:3, 3] = translation
        return cls(matrix, from_frame, to_frame)

    @property
    def scale(self) -> float:
        return float(np.cbrt(abs(np.linalg.det(self.matrix[:3, :3]))))

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation part (the scale divided out)."""
        return self.matrix[:3, :3] / self.scale

    @property
    def translation(self) -> np.ndarray:
        return self.matrix[:3, 3].copy()

    def inverse(self) -> Similarity:
        """``to_frame -> from_frame``, in closed form ((sR)⁻¹ = Rᵀ/s) rather than a general inverse."""
        inv_linear = self.rotation.T / self.scale
        matrix = np.eye(4)
        matrix[:3, :3] = inv_linear
        matrix[:3, 3] = -inv_linear @ self.matrix[:3, 3]
        return Similarity(matrix, self.to_frame, self.from_frame)

    def __matmul__(self, other: Similarity) -> Similarity:
        """``self @ other``: apply ``other`` first; its ``to_frame`` must be this one's ``from_frame``."""
        if not isinstance(other, Similarity):
            return NotImplemented
        if other.to_frame != self.from_frame:
            raise ValueError(
                f"frames do not chain: ({other.from_frame} -> {other.to_frame}) then "
                f"({self.from_frame} -> {self.to_frame})"
            )
        return Similarity(self.matrix @ other.matrix, other.from_frame, self.to_frame)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points in ``from_frame`` -> (N, 3) in ``to_frame``."""
        points = np.asarray(points, dtype=np.float64)
        return points @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def apply_directions(self, directions: np.ndarray) -> np.ndarray:
        """(N, 3) unit directions (normals) in ``from_frame`` -> unit directions in ``to_frame``."""
        return np.asarray(directions, dtype=np.float64) @ self.rotation.T


SIMILARITY_TOLERANCE = 1e-4  # ``checked_similarity``: how far from a rotation times one scale a given 4x4 may be


def checked_similarity(matrix, from_frame: str, to_frame: str) -> Similarity:
    """A 4x4 from outside (a client's, row-major nested lists) as a ``Similarity``, or ``ValueError`` saying what
    is wrong with it: not 4x4, not finite, a last row other than 0 0 0 1, a mirror or a degenerate one, a shear or
    an uneven scale. Within ``SIMILARITY_TOLERANCE`` its linear part is snapped to the nearest rotation times one
    scale, so rounding by a browser or JSON never leaves a slightly skewed matrix in a scene."""
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("a 4x4 matrix is 4 rows of 4 numbers") from None
    if m.shape != (4, 4):
        raise ValueError(f"a 4x4 matrix is 4 rows of 4 numbers, got shape {m.shape}")
    if not np.isfinite(m).all():
        raise ValueError("the matrix holds NaN or infinity")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=SIMILARITY_TOLERANCE):
        raise ValueError(f"the last row of a similarity is 0 0 0 1, got {m[3].tolist()}")
    linear = m[:3, :3]
    det = float(np.linalg.det(linear))
    if not det > 0:
        raise ValueError("the matrix mirrors or flattens the object (determinant <= 0)")
    scale = float(np.cbrt(det))
    u, _, vt = np.linalg.svd(linear / scale)
    rotation = u @ vt
    if np.abs(linear / scale - rotation).max() > SIMILARITY_TOLERANCE:
        raise ValueError("the matrix shears or scales unevenly: only a rotation, one scale and a translation are "
                         "allowed")
    return Similarity.from_parts(rotation, m[:3, 3], scale, from_frame, to_frame)


def checked_direction(direction) -> np.ndarray:
    """A direction from outside (3 numbers, any length but 0) as a unit vector, or ``ValueError``."""
    try:
        d = np.asarray(direction, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("a direction is 3 numbers") from None
    if d.shape != (3,) or not np.isfinite(d).all() or not np.linalg.norm(d) > 0:
        raise ValueError("a direction is 3 finite numbers, not all 0")
    return d / np.linalg.norm(d)


def rotate(rotation: np.ndarray, from_frame: str, to_frame: str) -> Similarity:
    """A pure rotation between two frames sharing an origin (e.g. target file -> target upright)."""
    return Similarity.from_parts(rotation, np.zeros(3), 1.0, from_frame, to_frame)


def normalisation(target_bounds: np.ndarray, *, from_frame: str = TARGET_UPRIGHT) -> Similarity:
    """Target ``from_frame`` -> normalised: AABB centred at the origin, longest side 2.

    ``target_bounds`` (2, 3) is the target's AABB *in* ``from_frame``. The pipeline normalises after
    the upright rotation (the default frame); pass ``from_frame=TARGET_FILE`` when there is none.
    """
    lo, hi = np.asarray(target_bounds, dtype=np.float64)
    longest = float((hi - lo).max())
    if not np.isfinite(longest) or longest <= 0:
        raise ValueError(f"cannot normalise a target with degenerate bounds {lo} .. {hi}")
    factor = 2.0 / longest
    return Similarity.from_parts(np.eye(3), -factor * (lo + hi) / 2, factor, from_frame, NORMALISED)


def source_local(source_bounds: np.ndarray, norm: Similarity) -> Similarity:
    """Source file -> source local: centred at the source AABB centre, scaled by ``norm.scale``.

    Using the target's factor keeps the relative size of the two files (rigid mode needs it).
    """
    lo, hi = np.asarray(source_bounds, dtype=np.float64)
    factor = norm.scale
    return Similarity.from_parts(np.eye(3), -factor * (lo + hi) / 2, factor, SOURCE_FILE, SOURCE_LOCAL)


def target_to_normalised(target_vertices: np.ndarray, upright: np.ndarray) -> Similarity:
    """Target file -> normalised through the upright rotation (3, 3, target file -> target upright).

    The AABB is taken of the *rotated vertices*, not of the rotated file AABB, so a tilted upload is
    framed tightly.
    """
    turn = rotate(upright, TARGET_FILE, TARGET_UPRIGHT)
    rotated = turn.apply(target_vertices)
    return normalisation(np.array([rotated.min(0), rotated.max(0)])) @ turn


def source_to_target(pose: np.ndarray, target_to_norm: Similarity, source_to_local: Similarity) -> Similarity:
    """A pose (4, 4, source local -> normalised) as the answer: source file -> target file."""
    posed = Similarity(pose, SOURCE_LOCAL, NORMALISED)
    return target_to_norm.inverse() @ posed @ source_to_local


# Z-up world (Blender's) -> glTF's Y-up: (x, y, z) -> (x, z, -y), as glTF exporters write positions with +Y up
Y_UP = np.array([[1.0, 0.0, 0.0, 0.0],
                 [0.0, 0.0, 1.0, 0.0],
                 [0.0, -1.0, 0.0, 0.0],
                 [0.0, 0.0, 0.0, 1.0]])


def z_up(matrix) -> np.ndarray:
    """A 4x4 between glTF (Y-up) frames written between the same frames with +Z up (Blender's axes):
    ``Y_UP⁻¹ @ matrix @ Y_UP``. The Blender add-on applies the same turn with ``mathutils``
    (``integrations/blender/frames.py``: it stays stdlib-only, so it keeps its own copy of ``Y_UP``)."""
    return Y_UP.T @ np.asarray(matrix, dtype=np.float64) @ Y_UP
