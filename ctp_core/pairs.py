"""A target and a source prepared for optimisation: frames, render meshes and loss samples.

The target is one mesh, or a *scene of placed objects* (a ``trimesh.Scene``, an assembly's stages so
far): each object in the target file frame (for an assembly, the *scene* frame), rendered with its own
materials, all of them seen by the penetration term, and the soft-ICP term attached to the one object
the source relates to (``on``) when one is named.

Frames (see ``frames``):
- target *file* frame -> *normalised* frame: the target's upright rotation (``canonical``), then its
  AABB centred with longest side 2. The normalised frame is where cameras, renders and losses live.
- source *file* frame -> *source local* frame: centred at the source AABB centre, scaled by the same
  factor as the target (so the files' relative size is kept).
- a pose (``pose``) maps source local -> normalised; ``source_to_target`` turns it into the answer,
  source file -> target file.
"""

from __future__ import annotations

import copy
import functools
import math
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TypeAlias, TypeVar

import numpy as np
import torch
import trimesh

from ctp_core import orientation, render
from ctp_core.errors import ConfigError
from ctp_core.geometry import field as fields
from ctp_core.geometry import frames, nearest, once, sampling
from ctp_core.geometry.pose import matrix_to_quaternion
from ctp_core.losses import SurfaceIndex
from ctp_core.orientation import canonical
from ctp_core.reading.names import ground_names
from ctp_core.render.cameras import framing_cameras
from ctp_core.render.structures import MeshArrays

Target: TypeAlias = "trimesh.Trimesh | trimesh.Scene"  # one mesh, or placed objects (target file frame)
# a surface whose normal has n_y above this faces up (the search's "top" region, the relations' supports), below
# minus this faces down, else sideways
UP_FACING = 0.5


def objects(target: Target) -> list[tuple[str, trimesh.Trimesh]]:
    """(name, mesh in the target file frame) of every object of ``target``, in the scene's order."""
    if isinstance(target, trimesh.Trimesh):
        return [(target.metadata.get("name") or "target", target)]
    placed = []
    for node in target.graph.nodes_geometry:
        matrix, key = target.graph[node]
        mesh = target.geometry.get(key)
        if isinstance(mesh, trimesh.Trimesh):
            placed.append((node, mesh if np.allclose(matrix, np.eye(4)) else _moved(mesh, _matrix_key(matrix))))
    if not placed:
        raise ValueError("the target scene holds no triangle mesh")
    return placed


def _matrix_key(matrix: np.ndarray) -> bytes:
    """A matrix as a key of ``_moved`` and ``_field`` (its float64 bytes: the matrix itself, exactly)."""
    return np.asarray(matrix, dtype=np.float64).tobytes()


@once.per_mesh
def _moved(mesh: trimesh.Trimesh, matrix: bytes) -> trimesh.Trimesh:
    """A copy of ``mesh`` moved by the 4x4 ``matrix`` (``_matrix_key``): a placed object in the target file frame,
    made once per scene for each place it is put (``once``)."""
    return mesh.copy().apply_transform(np.frombuffer(matrix, dtype=np.float64).reshape(4, 4))


def attachment(target: Target, on: str | Sequence[str] | None) -> trimesh.Trimesh:
    """The objects of ``target`` named ``on`` (the ones the source relates to), as one mesh; the whole target for
    None."""
    named = ground_names(on)
    if not named:
        return geometry(target)
    parts = objects(target)
    picked = [parts[_position([name for name, _ in parts], n)][1] for n in named]
    return picked[0] if len(picked) == 1 else triangles(picked)


def _position(names: list[str], on: str) -> int:
    if on not in names:
        raise ConfigError(f"no placed object named {on!r}; placed: {', '.join(names)}", field="on")
    return names.index(on)


def base(target: Target) -> trimesh.Trimesh:
    """The object that decides which way is up: the first of a scene (an assembly's base), or the mesh.

    Not the whole scene: objects placed on it change its resting poses (a plate resting against a table
    leg's foot can make the table rest best upside down), and the scene's up must not turn from stage to stage.
    """
    return objects(target)[0][1]


def geometry(target: Target) -> trimesh.Trimesh:
    """All triangles of ``target`` as one mesh (no visuals): what framing and the upright turn look at."""
    if isinstance(target, trimesh.Trimesh):
        return target
    return triangles([m for _, m in objects(target)])


def triangles(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """The triangles of ``meshes`` as one mesh, without their visuals."""
    parts = [trimesh.Trimesh(m.vertices, m.faces, process=False) for m in meshes]
    return parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)


@dataclass
class PreparedPair:
    target: Target  # target file frame, untouched
    source: trimesh.Trimesh  # source file frame, untouched
    target_to_normalised: frames.Similarity  # target file -> normalised
    source_to_local: frames.Similarity  # source file -> source local
    target_upright: canonical.Upright
    source_upright: canonical.Upright  # rotation source file -> its own upright frame
    mesh: render.RenderMesh  # target object(s) then source, joined (faces index target verts first)
    target_vertices: torch.Tensor  # (Vt, 3) normalised frame, every target object
    source_vertices: torch.Tensor  # (Vs, 3) source local frame
    index: SurfaceIndex  # target samples + outward normals, normalised frame, every target object
    source_samples: torch.Tensor  # (N, 3) source local frame
    source_surface: SurfaceIndex  # source samples + outward normals, source local frame (what is inside the source)
    target_outward: list[trimesh.Trimesh]  # each target object, file frame, outward winding (``outward``)
    attach: SurfaceIndex | None = None  # samples of the object(s) the source relates to; None: all of ``index``
    # samples of the target's objects that are the (closed) source's mesh again (earlier copies of it, ``twins``);
    # None: none
    twins: SurfaceIndex | None = None
    # each named ground's samples where the source relates to several objects ("between"), in the order named
    grounds: list[SurfaceIndex] = field(default_factory=list)
    # the positions in ``target_outward`` of the objects ``attach`` samples; empty: every object
    attach_objects: tuple[int, ...] = ()
    # the target's front, (3,) unit, normalised frame (its file's +Z for glTF, turned as the target is)
    target_front: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    # False where no convention gives a front (or a symmetric target): directional relations use the viewer's frame
    front_trusted: bool = True
    source_front: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))  # (3,) unit, source local
    # the source keeps its own up (``keeps_up``): every pose is its upright frame turned about +Y only; why or why not
    source_keeps_up: bool = False
    source_up_why: str = ""
    # the level the named grounds stand at (normalised frame, +Y up: what each rests on, ``support_level``, the
    # lowest of them; never under the scene's floor); None: not a scene, or no ground named (``floor``)
    ground_level: float | None = None
    _scene_floor: float | None = None  # the base's bottom (normalised frame); None: the target's lowest point
    # the floor is solid: the penetration term charges the source below ``scene_floor`` as inside it (a scene of
    # placed objects, whose floor is its base's bottom); False for one mesh
    solid_floor: bool = False

    @cached_property
    def source_up_quaternion(self) -> torch.Tensor:
        """(4,) the source's upright turn (source local -> a frame where it stands, +Y up) as a unit quaternion:
        what every pose of a source that keeps its up starts with (``pose.upright_twist``)."""
        q = matrix_to_quaternion(self.source_upright.rotation)
        return torch.as_tensor(q, dtype=torch.float32, device=self.source_vertices.device)

    @property
    def source_spin_axis(self) -> torch.Tensor | None:
        """(3,) the source's up (source local frame) where it is rotationally symmetric about it, else None: two
        poses whose turns differ by a spin about it look the same."""
        if not self.source_upright.symmetric:
            return None
        return torch.as_tensor(_unit(self.source_upright.up), dtype=torch.float32, device=self.source_vertices.device)

    @property
    def anchor(self) -> SurfaceIndex:
        """What the soft-ICP term pulls toward: the related object's samples, or the whole target's."""
        return self.index if self.attach is None else self.attach

    def anchor_samples(self, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
        """``count`` samples of each object ``anchor`` samples, their outward normals (normalised frame) and the
        spacing of the densest object's (as ``sample_spacing``): denser than the losses' where a detail (a thin
        part) needs them; made once per scene for each object (``_samples``)."""
        meshes = [self.target_outward[i] for i in self.attach_objects] or self.target_outward
        points, normals = (np.concatenate(a) for a in zip(*(_samples(m, count, seed) for m in meshes), strict=True))
        frame = self.target_to_normalised
        spacing = min(math.sqrt(m.area / count) for m in meshes) * frame.scale
        return frame.apply(points), frame.apply_directions(normals), spacing

    @cached_property
    def target_radius(self) -> float:
        """Half the target AABB diagonal in the normalised frame."""
        lo, hi = self.target_vertices.min(0).values, self.target_vertices.max(0).values
        return float((hi - lo).norm() / 2)

    @property
    def floor(self) -> float:
        """The height the target stands on (normalised frame, +Y up): what stands beside, under or leans on the
        target stands there too. Its lowest point for one mesh; in a scene with named grounds, the level the grounds
        stand at (``ground_level``: a mug on a table stands at the table's top, and a cup next to it stands there,
        not on the floor under the table); else the scene's floor (``scene_floor``)."""
        return self.scene_floor if self.ground_level is None else self.ground_level

    @cached_property
    def scene_floor(self) -> float:
        """The floor of the target (normalised frame): the bottom of its base (``base``: the object that stays put;
        the mesh itself for one mesh). Nothing placed goes below it."""
        return self._scene_floor if self._scene_floor is not None else float(self.target_vertices[:, 1].min())

    @cached_property
    def source_inside(self) -> torch.Tensor:
        """(P, 3) up to ``INSIDE_POINTS`` points well inside the source (``DistanceField.interior`` of its own
        field), source local frame: what ``objective.Scorer.interior`` charges inside its twins. Found once, as an
        ordinary tensor even where first asked under inference mode (a screen), since a refinement's gradient
        reads it too."""
        with torch.inference_mode(False):
            return self.source_surface.own_field.interior(INSIDE_POINTS)

    @cached_property
    def target_area(self) -> float:
        """The target's surface area, every object, in its file's units."""
        return float(sum(m.area for m in self.target_outward))

    def sample_spacing(self, count: int) -> float:
        """The spacing of ``count`` samples on the target's surface, normalised units: how far a point on the
        surface can be from its nearest sample."""
        return math.sqrt(self.target_area / count) * self.target_to_normalised.scale

    @cached_property
    def source_radius(self) -> float:
        """Half the AABB diagonal of the source samples in the source local frame (unscaled)."""
        lo, hi = self.source_samples.min(0).values, self.source_samples.max(0).values
        return float((hi - lo).norm() / 2)

    @cached_property
    def source_diagonal(self) -> float:
        """The AABB diagonal of the source samples in the source local frame (unscaled): the unit of the search's
        and the objective's distances ("source diagonals"); times a pose's scale, its posed source's."""
        return 2 * self.source_radius

    @cached_property
    def source_area(self) -> float:
        """The source's surface area in the source local frame (unscaled)."""
        return float(self.source.area) * self.source_to_local.scale**2

    def source_subset(self, count: int) -> torch.Tensor:
        """(min(count, N), 3) evenly spaced source samples (source local frame): a cheap stand-in for all of them."""
        n = len(self.source_samples)
        return self.source_samples[torch.linspace(0, n - 1, min(count, n)).long()]

    def scene_vertices(self, posed_source: torch.Tensor) -> torch.Tensor:
        """(B, Vs, 3) posed source -> (B, Vt + Vs, 3) vertices of the joined render mesh."""
        target = self.target_vertices.expand(posed_source.shape[0], -1, -1)
        return torch.cat([target, posed_source], dim=1)

    def scene_at(self, local_to_normalised: np.ndarray | torch.Tensor) -> torch.Tensor:
        """The joined render mesh's vertices with the source posed at a (4, 4) or (B, 4, 4) similarity.

        The pose maps the source local frame to the normalised frame; returns (B, Vt + Vs, 3), B = 1 for one pose.
        """
        m = torch.as_tensor(np.array(local_to_normalised), dtype=torch.float32, device=self.source_vertices.device)
        m = m.reshape(-1, 4, 4)
        return self.scene_vertices(self.source_vertices @ m[:, :3, :3].transpose(1, 2) + m[:, None, :3, 3])

    def local_to_normalised(self, source_to_target: np.ndarray) -> np.ndarray:
        """A source file -> target file 4x4 as a source local -> normalised 4x4."""
        file_to_file = frames.Similarity(source_to_target, frames.SOURCE_FILE, frames.TARGET_FILE)
        return (self.target_to_normalised @ file_to_file @ self.source_to_local.inverse()).matrix

    def source_to_target(self, local_to_normalised: np.ndarray) -> np.ndarray:
        """A pose (source local -> normalised 4x4) as the answer: source file -> target file."""
        return frames.source_to_target(local_to_normalised, self.target_to_normalised, self.source_to_local).matrix


def prepare_pair(target: Target, source: trimesh.Trimesh, *, samples: int, seed: int,
                 device: str = "cpu", canonicalise: bool = True, judge: canonical.Judge | None = None,
                 on: str | Sequence[str] | None = None, target_up: canonical.Upright | None = None,
                 target_axes: orientation.Axes = orientation.FROM_FILE,
                 source_axes: orientation.Axes = orientation.FROM_FILE, keep_up: bool = False) -> PreparedPair:
    """Normalise, orient and sample a pair once per run (everything later reuses it).

    Each object's up and front come from its file first (``orientation.orient`` by ``target_axes`` and
    ``source_axes``: the format's convention, an axis given, or ``auto``'s geometric guess, by ``judge`` when
    given); ``canonicalise`` False keeps the target file's +Y as up whatever they say. The target's up turns the
    normalised frame (renders show it as CLIP expects); the source's is its starting orientation. A scene
    target's up is its base's (``base``); it gets ``samples`` samples per object; ``on`` names the object (or the
    objects: "between" has two grounds) the soft-ICP term attaches to. ``target_up``: the target's upright turn
    when it is known already (a stored result's, ``adjust``): a later look at the same scene must have the same up
    as the run, which a judge may have chosen. ``keep_up``: the source keeps its own up where it is clear
    (``canonical.clear_up``; ``PreparedPair.source_keeps_up`` says whether it did and why).
    """
    whole, up_from = geometry(target), base(target)
    if target_up is None:
        axes = target_axes if canonicalise else orientation.Axes("+y", target_axes.front)
        target_up = _orient(up_from, axes, seed, judge=judge)
        if not canonicalise:
            target_up.reason = "up: the file's +Y (the upright step is off)"
    source_up = _orient(source, source_axes, seed, role="source")
    stated = source_axes.up not in ("file", "auto") or (
        source_axes.up == "file" and orientation.file_format(source) in orientation.CONVENTIONS)
    keeps, why = canonical.clear_up(source, source_up.up, stated) if keep_up else (False, "")
    target_to_norm = frames.target_to_normalised(whole.vertices, target_up.rotation)
    source_to_local = frames.source_local(source.bounds, target_to_norm)

    parts = objects(target)
    rendered = [_rendered(m, device) for m in [*(m for _, m in parts), source]]
    target_arrays, source_arrays = [a for a, _ in rendered[:-1]], rendered[-1][0]
    mesh = render.join([r for _, r in rendered], [len(a.vertices) for a, _ in rendered])

    oriented = [outward(m) for _, m in parts]
    sampled = [_samples(m, samples, seed + 2 * i) for i, m in enumerate(oriented)]
    s_pts, _ = _samples(source, samples, seed + 1)
    s_out, s_nrm = _samples(outward(source), samples, seed + 1)
    as_tensor = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
    turn = _matrix_key(target_up.rotation)

    def index(members: Sequence[int]) -> SurfaceIndex:
        """The samples of the objects ``members`` (normalised frame), their field their own fields read as one."""
        def objects_field() -> fields.FieldUnion:
            return fields.FieldUnion(tuple(
                _field(oriented[i], samples, seed + 2 * i, turn, device).scaled(target_to_norm.scale,
                                                                                target_to_norm.translation)
                for i in members))

        points, normals = (np.concatenate([sampled[i][k] for i in members]) for k in (0, 1))
        return SurfaceIndex(as_tensor(target_to_norm.apply(points)),
                            as_tensor(target_to_norm.apply_directions(normals)), objects_field)

    positions = [_position([name for name, _ in parts], n) for n in ground_names(on)]
    front, trusted = target_up.front, target_up.front_trusted
    if positions and positions[0] != 0 and isinstance(target, trimesh.Scene):
        front, trusted = ground_front(target, parts[positions[0]][0], target_up.up, seed)
    placed = [target_to_norm.apply(np.asarray(m.vertices)) for _, m in parts]
    bottoms = [float(v[:, 1].min()) for v in placed]
    ground_level = None
    if positions and len(parts) > 1:
        plain = [_plain(m) for _, m in parts]
        ground_level = min(bottoms[0] if i == 0 else support_level(  # the base stands on the floor
            plain[i], [o for k, o in enumerate(plain) if k != i], target_to_norm, target_up.up, bottoms[0])
            for i in positions)
    named = [index([i]) for i in positions] if len(parts) > 1 else []
    attach = None if not named else named[0] if len(named) == 1 else index(positions)
    target_index = index(range(len(parts)))
    if attach is not None:  # the grounds' samples are rows of every object's: their search answers for both
        starts = np.cumsum([0] + [len(p) for p, _ in sampled])
        rows = [np.arange(starts[i], starts[i + 1]) for i in range(len(sampled))]
        attach.part_of(target_index, np.concatenate([rows[i] for i in positions]),
                       [r for i, r in enumerate(rows) if i not in positions])
    # a closed source only: behind an open one (a sheet) is its whole back side, no inside
    same = [i for i, (_, m) in enumerate(parts) if len(parts) > 1 and source.is_watertight and twins(m, source)]
    return PreparedPair(
        twins=index(same) if same else None,
        target=target,
        source=source,
        target_to_normalised=target_to_norm,
        source_to_local=source_to_local,
        target_upright=target_up,
        source_upright=source_up,
        mesh=mesh,
        target_vertices=as_tensor(target_to_norm.apply(np.concatenate([a.vertices for a in target_arrays]))),
        source_vertices=as_tensor(source_to_local.apply(source_arrays.vertices)),
        index=target_index,
        source_samples=as_tensor(source_to_local.apply(s_pts)),
        source_surface=SurfaceIndex(as_tensor(source_to_local.apply(s_out)),
                                    as_tensor(source_to_local.apply_directions(s_nrm))),
        target_outward=oriented,
        attach=attach,
        grounds=named if len(named) > 1 else [],
        attach_objects=tuple(positions) if attach is not None else (),
        target_front=_unit(target_to_norm.apply_directions(front[None])[0]),
        front_trusted=trusted,
        source_front=_unit(np.asarray(source_up.front, dtype=np.float64)),
        source_keeps_up=keeps,
        source_up_why=why,
        ground_level=ground_level,
        _scene_floor=bottoms[0],
        solid_floor=isinstance(target, trimesh.Scene),
    )


def twins(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """Whether two meshes are one shape however each is placed (the same triangles' areas, in the same order: a
    copy moved and turned): where one is put on the other, every sample of its surface lies on the other's."""
    if len(a.faces) != len(b.faces) or len(a.vertices) != len(b.vertices):
        return False
    return bool(np.allclose(a.area_faces, b.area_faces, rtol=1e-6, atol=1e-12 * max(float(a.area), 1e-30)))


INSIDE_POINTS = 256  # ``PreparedPair.source_inside``: points inside the source charged inside its twins
SUPPORT_BAND = 0.02  # of a ground's height: a surface this close above its bottom still carries it (sunk a little)
SUPPORT_RAYS = 16  # the ground's lowest vertices a ray is cast down from, and its footprint's centre


def support_level(ground: trimesh.Trimesh, others: list[trimesh.Trimesh], to_normalised: frames.Similarity,
                  up: np.ndarray, floor: float) -> float:
    """The level a ground stands at (normalised frame, +Y up): the highest surface of the other objects straight
    under its lowest points (rays cast down ``up``, file frame, from ``SUPPORT_BAND`` of its height above them,
    level surfaces only; the base's level is the floor itself):
    what it rests on (a table's top under a mug, a crate's floor under a bottle in it); the floor where nothing is
    (a lamp hung over the floor: a box below it stands on the floor, not at the lamp's bottom). Never under
    ``floor``."""
    vertices = np.asarray(ground.vertices, dtype=np.float64)
    band = SUPPORT_BAND * float(np.ptp(vertices @ up))
    origins = bottom_points(vertices, up, band, SUPPORT_RAYS) + band * up
    level = floor
    for other in others:
        hits = level_hits(other, origins, up, UP_FACING)
        if len(hits):
            level = max(level, float(to_normalised.apply(hits)[:, 1].max()))
    return level


def bottom_points(vertices: np.ndarray, up: np.ndarray, band: float, count: int) -> np.ndarray:
    """(P, 3) where a thing (its ``vertices``) meets what it stands on: its ``count`` lowest vertices along ``up``
    within ``band`` (a length) of its lowest (its bottom, not a part higher up), and its footprint's centre at that
    height."""
    height = vertices @ up
    order = np.argsort(height)[:count]
    lowest = vertices[order[height[order] <= height.min() + band]]
    centre = vertices.mean(0) - ((vertices.mean(0) @ up) - height.min()) * up
    return np.vstack([lowest, centre])


def level_hits(mesh: trimesh.Trimesh, origins: np.ndarray, up: np.ndarray, level: float) -> np.ndarray:
    """(H, 3) every point where rays cast down ``up`` from ``origins`` meet ``mesh``'s level faces (|normal . up|
    over ``level``, either winding: uploads' normals are not to be trusted), not a wall grazed on the way."""
    hits, _, faces = mesh.ray.intersects_location(origins, np.tile(-up, (len(origins), 1)), multiple_hits=True)
    return hits[np.abs(np.asarray(mesh.face_normals)[faces] @ up) > level]


def ground_front(target: trimesh.Scene, name: str, up: np.ndarray, seed: int) -> tuple[np.ndarray, bool]:
    """The front of the placed object ``name`` in the target file frame (horizontal, unit) and whether it is
    trusted: its own (``orientation.orient`` of its mesh in its own file frame: the glTF's +Z, its nodes' turn)
    turned as its node places it, made square to ``up`` (the scene's, target file frame). A scene's up and front
    are its base's; a directional relation to another of its objects ("to the left of the sofa" once the sofa is
    turned to face the TV) is in that object's own frame."""
    matrix, key = target.graph[name]
    own = _orient(target.geometry[key], orientation.FROM_FILE, seed)
    linear = np.asarray(matrix, dtype=np.float64)[:3, :3]
    front = linear @ own.front
    front = front - (front @ up) * up  # a front tipped toward the up keeps its horizontal part
    if np.linalg.norm(front) < 1e-6:
        return np.array([0.0, 0.0, 1.0]), False
    return front / np.linalg.norm(front), own.front_trusted


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def _orient(mesh: trimesh.Trimesh, axes: orientation.Axes, seed: int, *, role: str = "target",
            judge: canonical.Judge | None = None) -> canonical.Upright:
    """``orientation.orient``; without a judge, found once per scene for each object (``once``) and copied out
    (``prepare_pair`` may change its reason)."""
    if judge is not None:
        return orientation.orient(mesh, axes, seed=seed, judge=judge, role=role)
    return copy.deepcopy(_oriented(mesh, axes, seed, role))


@once.per_mesh
def _oriented(mesh: trimesh.Trimesh, axes: orientation.Axes, seed: int, role: str) -> canonical.Upright:
    return orientation.orient(mesh, axes, seed=seed, role=role)


@once.per_mesh
def _rendered(mesh: trimesh.Trimesh, device: str) -> tuple[MeshArrays, render.RenderMesh]:
    """A mesh's arrays and its render mesh on ``device``, made once per scene (``once``)."""
    arrays = MeshArrays.from_trimesh(mesh)
    return arrays, render.RenderMesh.from_arrays(arrays, device=device)


@once.per_mesh
def _samples(mesh: trimesh.Trimesh, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``sampling.surface_samples``, made once per scene for each mesh, count and seed (``once``)."""
    return sampling.surface_samples(mesh, count, seed)


@once.per_mesh
def _field(mesh: trimesh.Trimesh, count: int, seed: int, turn: bytes, device: str) -> fields.DistanceField:
    """The distance field of ``_samples(mesh, count, seed)`` in the target upright frame (the file frame turned by
    the 3x3 ``turn``, ``_matrix_key``), which stays where a scene's normalised frame moves as objects are added:
    built once per scene for each object (``once``), read in each step's normalised frame (``scaled``)."""
    points, normals = _samples(mesh, count, seed)
    rotation = np.frombuffer(turn, dtype=np.float64).reshape(3, 3)
    points, normals = points @ rotation.T, normals @ rotation.T
    return fields.build(nearest.Tree(points), points, normals, device=device)


@once.per_mesh
def _plain(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """The mesh's triangles alone (no visuals, not processed), made once per scene (``once``): what rays are cast
    against (``support_level``), its intersector kept with it."""
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)


@once.per_mesh
def outward(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy with consistent, outward winding where trimesh can decide it (penetration needs "inside").

    Watertight meshes get outward normals; open ones get consistent winding, oriented by trimesh's
    heuristic, and "inside" then means behind the oriented side (documented limit). Made once per scene for
    each mesh (``once``): the copy is shared there, not to be changed.
    """
    fixed = mesh.copy()
    with np.errstate(divide="ignore", invalid="ignore"):  # trimesh divides by the volume of flat parts
        trimesh.repair.fix_normals(fixed, multibody=True)
    return fixed


def render_arrangement(target: Target, source: trimesh.Trimesh, source_to_target: np.ndarray, *,
                       views: int = 8, image_size: int = 224, device: str = "cpu") -> torch.Tensor:
    """Render target + placed source from fixed views framing the scene: (V, 3, H, W) in [0, 1].

    Used for previews and the semantic metric; the views are a function of the arrangement only.
    """
    pair = prepare_pair(target, source, samples=100, seed=0, device=device, canonicalise=False)
    return render_pair(pair, pair.local_to_normalised(source_to_target), views=views, image_size=image_size)


def preview(target: Target, source: trimesh.Trimesh, source_to_target: np.ndarray) -> np.ndarray:
    """(4, 224, 224, 3) uint8 views of an arrangement (``render_arrangement``): a scene's or a set's preview."""
    return to_uint8(render_arrangement(target, source, source_to_target, views=4))


def to_uint8(images: torch.Tensor) -> np.ndarray:
    """(V, 3, H, W) renders in [0, 1] -> (V, H, W, 3) uint8 (a preview, thumbnails)."""
    return (images.permute(0, 2, 3, 1).clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8)


@torch.no_grad()
def render_pair(pair: PreparedPair, local_to_normalised: np.ndarray, *, views: int, image_size: int) -> torch.Tensor:
    """Render a prepared pair at one pose (source local -> normalised 4x4) from framing views."""
    verts = pair.scene_at(local_to_normalised)
    cams = framing_cameras(verts[0], views, image_size)
    return render.render(pair.mesh, verts, cams)[0]


Built = TypeVar("Built")


def per_pair(build: Callable[[PreparedPair], Built]) -> Callable[[PreparedPair], Built]:
    """``build(pair)`` computed on first use and kept while the pair lives (keyed by identity: a pair is not
    hashable), for what several stages read from one pair's fixed geometry. Callers must not change what it
    returns."""
    cache: dict[int, tuple[weakref.ref, Built]] = {}

    @functools.wraps(build)
    def cached(pair: PreparedPair) -> Built:
        key = id(pair)
        hit = cache.get(key)
        if hit is not None and hit[0]() is pair:
            return hit[1]
        value = build(pair)
        cache[key] = (weakref.ref(pair), value)
        weakref.finalize(pair, cache.pop, key, None)
        return value

    return cached
