"""Canonical upright pose (Auto-Align): which way is up for an uploaded mesh.

Renders guide the optimiser, and a vision-language model recognises objects in their usual
orientation, so a lying or upside-down target spoils every view. Four cues, all from geometry alone:

1. **Dominant axes** (../shared/docs/method.md): RANSAC over area-weighted face normals for three orthogonal axes
   (200 tries, 5° inliers), refined by an area-weighted median (10 iterations). They make the answer
   exact (a chosen up within 5° of an axis snaps to it) and fix the turn about the up axis.
2. **Resting pose**, the cue the reference lacks (it takes the frame nearest the input, so it cannot
   fix an upside-down upload): every facet of the convex hull the object can stand on (centre of
   mass above it) is a candidate "down". A candidate scores ``p * (0.05 + fill) * h²``: ``p`` the
   chance to come to rest on it (solid angle of the facet from the centre of mass, the quasi-static
   drop model of ``trimesh.poses.compute_stable_poses``, computed directly because trimesh's sampler
   can stall on large hulls), ``fill`` the share of the facet the mesh actually touches (a real flat
   base, not a bridge over bumps), ``h`` the height it then stands (authored objects stand up).
3. **Rotational symmetry**: when the surface has an axis of (near) rotational symmetry, only the
   resting poses on that axis compete (a tree or a glass stands on its axis even with a rough base).
4. **Legs**: a resting pose that stands on three or more legs (``feet``: the surface within 2 % of the
   object's size of the floor falls apart into that many pieces, 6 % apart, and they stay apart up to a
   tenth and a quarter of its height: columns, not a lying figure's head, hands and feet) is how furniture
   and animals stand: where something has a flat base to stand on at all, a pose on legs outranks the flat
   bases, and a flat base with legs on its other side is a top (a table's, a stool's seat) that no
   authored upload rests on. A table's top is a better base than four leg tips by the other cues, so
   without this the table is turned upside down (or kept so).

An upload is left as authored (identity, ``changed=False``) unless it is clearly lying, tilted or
upside down: there must be a candidate with a real base (fill >= 0.5) or on the symmetry axis, and the
file's +Y must not be a resting pose scoring at least 1/20 of it (nor one on legs; a top with legs on its
other side does not count: a table upside down in its file). The margin is wide on purpose:
an authored table on its legs scores ~1/16 of the same table upside down (its top is a perfect
base), a bottle lying on its side ~1/11 of it standing, so no margin separates the two; keeping an
authored pose is the safer error (a flipped table ruins "a cup on the table"), and a lying upload is
still placed correctly in its own file frame. Known misses: figures that cannot stand on their own
(no resting pose has +Y up), cubes and spheres (no single up), legged things lying on a side in their file
(kept: not a top). The ``orientation`` module asks for this guess only with ``up: auto``.
Measured on ``../shared/bench`` by ``benchmarks/canonical_bench.py`` (figures in docs/engine.md).

5. **A judge** (optional, semantic): geometry cannot tell where a figure's head is (nor a table without
   legs from one on its top); a vision-language model can. ``judge`` scores candidate rotations (in
   practice: renders of the object under each, against "a photo of a NAME", ``upright.upright_judge``)
   and picks among the file's +Y, the best resting poses and the six dominant-axis directions. The
   file's +Y stays unless another candidate scores ``margin`` more.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import QhullError, cKDTree

from ctp_core.geometry import once, sampling

_INLIER_COS = np.cos(np.radians(5.0))
_SNAP_COS = np.cos(np.radians(5.0))
_AUTHORED_COS = np.cos(np.radians(8.0))  # a resting pose this close to the file's +Y is the authored one
_AXIS_COS = np.cos(np.radians(10.0))  # a resting pose this close to the symmetry axis stands on it
BASE_FILL = 0.5  # share of a facet the mesh must touch to count as a real base
_KEEP_RATIO = 0.05  # the file's +Y stays unless the best pose scores 20x more: rotate only when clear
_MAX_FACES = 20_000  # normals sampled for RANSAC: plenty for three axes, bounded time
_Y = np.array([0.0, 1.0, 0.0])
_JUDGED_POSES = 4  # best resting poses offered to a judge, besides the file's +Y and the dominant axes
_DISTINCT_COS = np.cos(np.radians(10.0))  # candidate ups closer than this are one candidate
_FOOT_BAND = 0.02  # share of the longest side: the surface this close to the floor is what touches it
_FOOT_GAP = 0.06  # share of the longest side: touching pieces further apart than this are separate feet
_FOOT_SAMPLES = 6000  # surface samples the feet are counted from (plus every vertex: a leg may end in a point)
LEGS = 3  # separate feet that make a pose "on legs"
_OPPOSITE_COS = np.cos(np.radians(15.0))  # a pose on legs this close to a base's down: that base is a top
_LEG_LEVELS = (0.1, 0.25)  # shares of the height up to which legs stay separate columns
_Z = np.array([0.0, 0.0, 1.0])

Judge = Callable[[np.ndarray], np.ndarray]
"""Scores (K,) for candidate rotations (K, 3, 3), file frame -> upright frame; higher is more upright."""


@dataclass
class Upright:
    """``rotation`` (3, 3) maps the file frame to the upright frame (+Y up), p_up = R @ p_file."""

    rotation: np.ndarray
    changed: bool
    reason: str
    axes: np.ndarray = field(default_factory=lambda: np.eye(3))  # (3, 3) dominant axes (rows), file frame
    candidates: list[dict] = field(default_factory=list)  # resting or judged poses, best first, file frame
    # the object's front, a unit vector in the file frame at right angles to ``up`` (``orientation``), whether a
    # convention or the user gave it (False: a guess, or no front at all), and why
    front: np.ndarray = field(default_factory=lambda: _Z.copy())
    front_trusted: bool = False
    front_reason: str = "no front given: the file's +Z, not trusted"
    # rotationally symmetric about its up (``orientation.orient``): a spin about it shows nothing
    symmetric: bool = False

    @property
    def up(self) -> np.ndarray:
        """The recovered up direction in the file frame."""
        return self.rotation.T @ _Y


def identity(reason: str = "not canonicalised") -> Upright:
    return Upright(np.eye(3), False, reason)


def upright_rotation(mesh: trimesh.Trimesh, seed: int = 0, judge: Judge | None = None,
                     margin: float = 0.01) -> Upright:
    """Estimate the upright frame of ``mesh`` (file frame); deterministic by ``seed`` (and the judge)."""
    candidates = unit_resting_poses(mesh)
    mesh = unit_size(mesh)
    axes = dominant_axes(mesh, seed)
    if judge is not None:
        return _judged(axes, candidates, judge, margin)
    axis = symmetry_axis(mesh, seed)
    on_axis = [] if axis is None else [c for c in candidates if abs(np.dot(c["up"], axis)) > _AXIS_COS]
    bases = on_axis or [c for c in candidates if c["fill"] >= BASE_FILL]
    if not bases:
        return Upright(np.eye(3), False, "no flat base to stand on: kept as authored", axes, candidates)
    legged = [c for c in (on_axis or candidates) if c["feet"] >= LEGS]
    best = legged[0] if legged else bases[0]
    as_file = [c for c in candidates if np.dot(c["up"], _Y) > _AUTHORED_COS]
    # kept: on legs as authored, or scoring 1/20 of the best base unless it is a top with legs on its other side
    if as_file and (as_file[0]["feet"] >= LEGS or (as_file[0]["score"] >= _KEEP_RATIO * bases[0]["score"]
                                                  and _legs_under(as_file[0], legged) is None)):
        return Upright(np.eye(3), False, "already upright: the file's +Y is a resting pose"
                       + (" on legs" if as_file[0]["feet"] >= LEGS else ""), axes, candidates)
    up = _snapped(np.asarray(best["up"]), axes)
    rotation = _standing_on(up, axes)
    if legged:
        top = as_file and _legs_under(as_file[0], legged) is not None
        reason = (f"stands on {best['feet']} legs with up {np.round(up, 3).tolist()} in the file frame; the file's "
                  + ("+Y rests on its top, the legs on the other side" if top else "+Y does not stand on legs"))
    else:
        reason = (f"rests on a base ({best['fill']:.0%} contact, p={best['probability']:.2f}) with up "
                  f"{np.round(up, 3).tolist()} in the file frame; the file's +Y "
                  + (f"scores {as_file[0]['score'] / best['score']:.0%} of it" if as_file
                     else "is not a resting pose"))
    return Upright(rotation, True, reason, axes, candidates)


def clear_up(mesh: trimesh.Trimesh, up: np.ndarray, stated: bool = False) -> tuple[bool, str]:
    """Whether ``up`` (file frame, unit) is clearly the way ``mesh`` stands, with the reason: ``up`` is one of its
    resting poses (within 8 degrees) and that pose stands on legs (a chair, a table, a stool), or on a real base
    (``BASE_FILL``: a sofa, a cabinet, a box, a mug) scoring at least 1/20 of its best base (``_KEEP_RATIO``, the
    margin ``upright_rotation`` keeps an authored pose by), or the pose it most likely comes to rest in (a rug lying
    flat: the score's height squared favours its edge), and not a top with legs on its other side (a table upside
    down). The same evidence that keeps an upload as authored: what passes stands as it is set down, and a
    placement that tips it is wrong whatever relation it satisfies. ``stated``: the file states its up (glTF's +Y
    by its spec, or an axis given): then any resting pose with that up is clear (a sofa on four short feet, which
    neither legs nor a base show), and only an up it cannot stand on (a rake on its tines) is not."""
    candidates = unit_resting_poses(mesh)
    at = [c for c in candidates if np.dot(c["up"], up) > _AUTHORED_COS]
    if not at:
        return False, "its up is none of its resting poses"
    pose = at[0]
    if pose["feet"] >= LEGS:
        return True, f"it stands on {pose['feet']} legs with that up"
    if _legs_under(pose, candidates) is not None:
        return False, "that up rests on a top with legs on its other side"
    if stated:
        return True, "its file states that up and it stands on it"
    bases = [c for c in candidates if c["fill"] >= BASE_FILL]
    likeliest = max(candidates, key=lambda c: c["probability"])
    if pose["fill"] >= BASE_FILL and (pose["score"] >= _KEEP_RATIO * bases[0]["score"] or pose is likeliest):
        return True, f"it rests on a base with that up ({pose['fill']:.0%} contact)"
    return False, "no real base or legs with that up"


def _judged(axes: np.ndarray, candidates: list[dict], judge: Judge, margin: float) -> Upright:
    """Let ``judge`` pick among the file's +Y, the best resting poses and the dominant-axis directions."""
    ups = [_Y] + [_snapped(np.asarray(c["up"]), axes) for c in candidates[:_JUDGED_POSES]]
    ups += [sign * axis for axis in axes for sign in (1.0, -1.0)]
    distinct: list[np.ndarray] = []
    for up in ups:
        if all(up @ other < _DISTINCT_COS for other in distinct):
            distinct.append(up)
    rotations = np.stack([np.eye(3)] + [_standing_on(up, axes) for up in distinct[1:]])
    scores = np.asarray(judge(rotations), dtype=np.float64)
    best = int(np.argmax(scores))
    ranked = [{"up": up.tolist(), "judge_score": float(score)} for up, score in zip(distinct, scores, strict=True)]
    ranked.sort(key=lambda c: -c["judge_score"])
    if best == 0 or scores[best] - scores[0] < margin:
        return Upright(np.eye(3), False, f"judged: the file's +Y scores {scores[0]:.4f}, no candidate "
                       f"{margin} more (best {scores[best]:.4f})", axes, ranked)
    return Upright(rotations[best], True, f"judged: up {np.round(distinct[best], 3).tolist()} in the file frame "
                   f"scores {scores[best]:.4f}, the file's +Y {scores[0]:.4f}", axes, ranked)


def symmetry_axis(mesh: trimesh.Trimesh, seed: int = 0, samples: int = 2000) -> np.ndarray | None:
    """The axis of (near) rotational symmetry, file frame, or None.

    A round object (glass, tree, candlestick, lamp) stands on its axis whatever its base looks like, so
    the axis outranks the base cue. Found as the principal axis of the surface whose two other moments
    agree (within 10 %), and accepted only if turning the surface 90° about it moves it no further
    from itself than an independent resampling does (x1.5): a box with two equal sides passes the
    moments but not the turn unless it really has the symmetry.
    """
    points, _ = sampling.surface_samples(mesh, samples, seed)
    fresh = cKDTree(sampling.surface_samples(mesh, samples, seed + 1)[0])
    centre = points.mean(0)
    values, vectors = np.linalg.eigh(np.cov((points - centre).T))
    baseline = fresh.query(points)[0].mean()
    for k in range(3):
        a, b = np.delete(values, k)
        if abs(a - b) > 0.1 * max(a, b) or abs(values[k] - (a + b) / 2) < 0.1 * max(values[k], a, b):
            continue
        turn = trimesh.transformations.rotation_matrix(np.pi / 2, vectors[:, k])[:3, :3]
        if fresh.query((points - centre) @ turn.T + centre)[0].mean() < 1.5 * baseline:
            return vectors[:, k]
    return None


def dominant_axes(mesh: trimesh.Trimesh, seed: int = 0, tries: int = 200, iterations: int = 10) -> np.ndarray:
    """(3, 3) orthonormal rows: the three orthogonal directions most face area is normal to (file frame)."""
    rng = np.random.default_rng(seed)
    normals = np.asarray(mesh.face_normals, dtype=np.float64)
    weights = np.asarray(mesh.area_faces, dtype=np.float64)
    keep = (weights > 0) & (np.linalg.norm(normals, axis=1) > 0.5)
    if not keep.any():  # every face degenerate: no direction is dominant
        return np.eye(3)
    normals, weights = normals[keep], weights[keep] / weights[keep].sum()
    if len(weights) > _MAX_FACES:  # an area-weighted draw keeps the distribution, weights become equal
        normals = normals[rng.choice(len(weights), _MAX_FACES, p=weights)]
        weights = np.full(_MAX_FACES, 1.0 / _MAX_FACES)

    best, best_support = np.eye(3), -1.0
    for _ in range(tries):
        first = normals[rng.choice(len(weights), p=weights)]
        orthogonal = weights * (np.abs(normals @ first) < np.sin(np.radians(5.0)))
        if orthogonal.sum() > 0:
            second = normals[rng.choice(len(weights), p=orthogonal / orthogonal.sum())]
        else:  # no face at right angles: any perpendicular (the support decides)
            second = np.cross(first, [1.0, 0.0, 0.0] if abs(first[0]) < 0.9 else [0.0, 1.0, 0.0])
        second = second - (second @ first) * first
        second /= np.linalg.norm(second)
        axes = np.stack([first, second, np.cross(first, second)])
        support = weights[(np.abs(normals @ axes.T) > _INLIER_COS).any(1)].sum()
        if support > best_support:
            best, best_support = axes, support

    axes = best
    for _ in range(iterations):
        refined = []
        for axis in axes:
            dots = normals @ axis
            inliers = np.abs(dots) > _INLIER_COS
            if not inliers.any():
                refined.append(axis)
                continue
            flipped = normals[inliers] * np.sign(dots[inliers])[:, None]
            median = np.array([_weighted_median(flipped[:, k], weights[inliers]) for k in range(3)])
            refined.append(median / np.linalg.norm(median))
        u, _, vt = np.linalg.svd(np.stack(refined))  # nearest orthonormal frame
        axes = u @ vt
    if np.linalg.det(axes) < 0:
        axes[2] = -axes[2]
    return axes


@once.per_content
def unit_resting_poses(mesh: trimesh.Trimesh) -> list[dict]:
    """``resting_poses`` of ``mesh`` made unit size (``unit_size``), kept within a scene by the mesh's content: a
    scene's steps find and judge an object's up again. The caller must not change what it gets."""
    return resting_poses(unit_size(mesh))


def resting_poses(mesh: trimesh.Trimesh, min_probability: float = 0.005) -> list[dict]:
    """Hull facets the object can stand on, scored (see module docstring), best first; file frame.

    Each: ``up`` (unit, file frame), ``probability``, ``fill``, ``height`` (share of the longest
    extent), ``score``, ``feet`` (separate pieces touching the floor, ``_feet``). The hull's centroid stands in
    for the centre of mass: uploads are rarely watertight, so the mesh's own volume is not to be trusted.
    """
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat hull has no centre of mass
        try:
            hull = mesh.convex_hull
        except QhullError:  # a single face, or all vertices on one plane or line: nothing to stand on
            return []
        if not hull.volume > 0:
            return []
    centre = hull.center_mass
    extent = float(mesh.extents.max())
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    face_normals = np.asarray(mesh.face_normals)
    face_areas = np.asarray(mesh.area_faces)
    surface = np.concatenate([sampling.surface_samples(mesh, _FOOT_SAMPLES, 0)[0], vertices])

    normals, areas, triangles = hull.face_normals, hull.area_faces, hull.triangles
    angles = _solid_angles(triangles, centre) / (4 * np.pi)
    unused = np.ones(len(areas), dtype=bool)
    poses = []
    for seed_face in np.argsort(-areas):
        if not unused[seed_face]:
            continue
        group = unused & (normals @ normals[seed_face] > np.cos(np.radians(3.0)))
        unused &= ~group
        probability = float(angles[group].sum())
        down = normals[group].T @ areas[group]
        down /= np.linalg.norm(down)
        if probability < min_probability or not _over_facet(centre, down, triangles[group]):
            continue
        depth = vertices @ down
        lowest = depth.max()
        on_plane = (lowest - depth[mesh.faces]).max(1) < 0.01 * extent
        touching = on_plane & (face_normals @ down > np.cos(np.radians(15.0)))
        fill = min(float(face_areas[touching].sum() / areas[group].sum()), 1.0)
        height = float(np.ptp(depth) / extent)
        poses.append(_Resting({"up": (-down).tolist(), "probability": probability, "fill": fill, "height": height,
                               "score": probability * (0.05 + fill) * height**2}, surface, down, extent))
    return sorted(poses, key=lambda p: -p["score"])


class _Resting(dict):
    """One of ``resting_poses``, its ``feet`` counted on first read (``_feet``): a round base's rim makes dozens of
    poses, and whether an up is clear (``clear_up``) reads the feet of the few opposite it."""

    def __init__(self, fields: dict, surface: np.ndarray, down: np.ndarray, extent: float):
        super().__init__(fields)
        self._counted_from = (surface, down, extent)

    def __missing__(self, key: str) -> int:
        if key != "feet":
            raise KeyError(key)
        self["feet"] = _feet(*self._counted_from)
        return self["feet"]


def _legs_under(pose: dict, pool: list[dict]) -> dict | None:
    """The first pose of ``pool`` opposite ``pose`` (its up within ``_OPPOSITE_COS`` of ``pose``'s down) that stands
    on legs, if any: then ``pose`` rests on a top (a table's, a stool's seat), and the object stands on those legs.
    Only the opposite poses' feet are counted."""
    return next((c for c in pool if np.dot(c["up"], pose["up"]) < -_OPPOSITE_COS and c["feet"] >= LEGS), None)


def _feet(points: np.ndarray, down: np.ndarray, extent: float) -> int:
    """How many legs ``points`` (surface samples, file frame) stand on along ``down``: separate pieces of the
    surface near the floor (single-linkage clusters linked within ``_FOOT_GAP``) that stay separate up to
    ``_LEG_LEVELS`` of the height, the fewest over those levels. A lying figure's head, hands and feet touch the
    floor apart too, but merge into its body a little above it; legs are columns."""
    depth = points @ down
    lowest, height = depth.max(), float(np.ptp(depth))
    fewest = len(points)
    for level in (_FOOT_BAND * extent, *(share * height for share in _LEG_LEVELS)):
        near = points[depth > lowest - level]
        links = cKDTree(near).query_pairs(_FOOT_GAP * extent, output_type="ndarray")
        graph = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(len(near),) * 2)
        fewest = min(fewest, int(connected_components(graph, directed=False)[0]))
        if fewest < LEGS:  # no legs at this level: the higher ones cannot add any
            break
    return fewest


def _solid_angles(triangles: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Solid angle of each (T, 3, 3) triangle seen from ``origin`` (Van Oosterom & Strackee)."""
    a, b, c = (triangles[:, k] - origin for k in range(3))
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    numerator = np.einsum("ij,ij->i", a, np.cross(b, c))
    denominator = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
                   + np.einsum("ij,ij->i", b, c) * la)
    return np.abs(2 * np.arctan2(numerator, denominator))


def _over_facet(centre: np.ndarray, down: np.ndarray, triangles: np.ndarray) -> bool:
    """Whether the centre of mass projects into the facet along ``down`` (it stands, not topples)."""
    plane = (triangles[:, 0] @ down).max()
    foot = centre + (plane - centre @ down) * down
    bary = trimesh.triangles.points_to_barycentric(triangles, np.repeat(foot[None], len(triangles), 0))
    return bool((bary > -1e-6).all(1).any())


def _snapped(up: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``up`` snapped onto the nearest dominant axis when within 5° of it (answers come out exact)."""
    nearest = axes[np.argmax(np.abs(axes @ up))]
    return nearest * np.sign(nearest @ up) if abs(nearest @ up) > _SNAP_COS else up


def _standing_on(up: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The rotation (file -> upright) that turns ``up`` onto +Y, squared to the dominant axes."""
    return _yaw_to_axes(turn_onto(up, _Y), axes)


def turn_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` onto unit vector ``b`` (3, 3)."""
    axis = np.cross(a, b)
    sin, cos = np.linalg.norm(axis), float(a @ b)
    if sin < 1e-12:
        if cos > 0:
            return np.eye(3)
        perpendicular = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return trimesh.transformations.rotation_matrix(np.pi, perpendicular)[:3, :3]
    return trimesh.transformations.rotation_matrix(np.arctan2(sin, cos), axis / sin)[:3, :3]


def _yaw_to_axes(rotation: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Add the smallest turn about +Y that lines a horizontal dominant axis up with ±X/±Z.

    Renders then see the object square-on, as a modeller would have placed it.
    """
    turned = axes @ rotation.T
    horizontal = [v for v in turned if abs(v[1]) < np.sin(np.radians(5.0))]
    if not horizontal:
        return rotation
    heading = np.arctan2(horizontal[0][2], horizontal[0][0])
    yaw = (heading + np.pi / 4) % (np.pi / 2) - np.pi / 4  # residual to the nearest of ±X/±Z
    return trimesh.transformations.rotation_matrix(yaw, _Y)[:3, :3] @ rotation


def unit_size(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The geometry alone, centred and scaled to a longest side of 1 (same orientations, file frame axes).

    Directions do not depend on size, but trimesh's tolerances do: the faces of a 1e-6 box have no
    normals at its own scale.
    """
    extent = float(mesh.extents.max())
    vertices = (np.asarray(mesh.vertices, dtype=np.float64) - mesh.bounds.mean(axis=0)) / (extent or 1.0)
    return trimesh.Trimesh(vertices, np.asarray(mesh.faces), process=False)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, cumulative[-1] / 2)])
