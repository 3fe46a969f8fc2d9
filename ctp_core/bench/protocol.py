"""The perturbation protocol (../shared/docs/method.md, "Benchmark protocol"): where each run starts.

Every pose here is a 4x4 *source file frame -> target file frame* similarity, the same convention as
``case.json``'s reference and ``AlignResult.source_to_target``. Draws are seeded by (seed, case id)
only, so every method, and every rerun, starts case k's init i from the same pose, and adding a case
does not shift the others.
"""

from __future__ import annotations

import zlib
from typing import Literal

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

Protocol = Literal["rigid", "scale"]
PROTOCOLS: tuple[str, ...] = ("rigid", "scale")
TRANSLATION_RANGE = 10.0  # translate by U(-10 L, 10 L) per axis, L the source's AABB sides
SCALE_RANGE = (0.01, 100.0)  # scale protocol: isotropic factor U(0.01, 100)


def case_rng(seed: int, case_id: str, stream: str = "init") -> np.random.Generator:
    """A generator owned by one case (and one use of it), independent of every other case."""
    return np.random.default_rng([seed, zlib.crc32(case_id.encode()), zlib.crc32(stream.encode())])


def _translation(v: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v
    return m


def _linear(a: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = a
    return m


def perturb(base: np.ndarray, source_bounds: np.ndarray, protocol: Protocol, rng: np.random.Generator) -> np.ndarray:
    """One perturbed start: the base-posed source turned and (scale protocol) scaled about its own centre,
    then moved by U(-10 L, 10 L) per axis, L the sides of its AABB in the target file frame.

    ``base`` is the reference arrangement (or the file pose, identity, when there is none);
    ``source_bounds`` (2, 3) is the source AABB in its file frame. Euler angles are independent
    U(-180°, 180°) about x, y, z.
    """
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
    posed = trimesh.bounds.corners(source_bounds) @ base[:3, :3].T + base[:3, 3]
    centre = (posed.min(axis=0) + posed.max(axis=0)) / 2
    sides = posed.max(axis=0) - posed.min(axis=0)
    shift = rng.uniform(-TRANSLATION_RANGE, TRANSLATION_RANGE, 3) * sides
    turn = Rotation.from_euler("xyz", rng.uniform(-180.0, 180.0, 3), degrees=True).as_matrix()
    factor = rng.uniform(*SCALE_RANGE) if protocol == "scale" else 1.0
    about_centre = _translation(centre + shift) @ _linear(factor * turn) @ _translation(-centre)
    return about_centre @ base


def initial_poses(base: np.ndarray | None, source_bounds: np.ndarray, *, protocol: Protocol, count: int,
                  seed: int, case_id: str) -> list[np.ndarray]:
    """``count`` protocol starts for one case, deterministic by (seed, case id)."""
    base = np.eye(4) if base is None else np.asarray(base, dtype=np.float64)
    rng = case_rng(seed, case_id)
    return [perturb(base, source_bounds, protocol, rng) for _ in range(count)]


def random_starts(target_bounds: np.ndarray, source_bounds: np.ndarray, scale: float, count: int,
                  rng: np.random.Generator, distance: tuple[float, float] = (2.0, 4.0)) -> list[np.ndarray]:
    """Starts with no knowledge of the answer (the method's "Initialise"): the source centre at a random
    direction and 2-4 target radii from the target centre, uniformly random rotation, given scale.

    Bounds are AABBs in each object's file frame; the target radius is half its AABB diagonal.
    """
    target_bounds, source_bounds = np.asarray(target_bounds, float), np.asarray(source_bounds, float)
    centre, radius = target_bounds.mean(axis=0), np.linalg.norm(np.ptp(target_bounds, axis=0)) / 2
    source_centre = source_bounds.mean(axis=0)
    starts = []
    for _ in range(count):
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        place = centre + direction * rng.uniform(*distance) * radius
        turn = Rotation.random(random_state=rng).as_matrix()
        starts.append(_translation(place) @ _linear(scale * turn) @ _translation(-source_centre))
    return starts
