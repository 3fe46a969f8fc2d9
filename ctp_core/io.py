"""Mesh input: one flattened, validated ``trimesh.Trimesh`` in the *file frame* from an upload or a path.

Uploads are untrusted, so loading is also the gate: every refusal is a ``MeshError`` with a stable
code (the service and CLI turn codes into messages). Nothing named *inside* a file is ever fetched
from the file system or the network: glTF URIs other than ``data:`` are refused before trimesh sees
the file, and an OBJ's MTL and textures resolve only among the members of its own zip (or, for a
path on disk, inside the OBJ's own folder).
"""

from __future__ import annotations

import io
import json
import posixpath
import struct
import zipfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import trimesh
from PIL import Image

from ctp_core.errors import MeshError

SUPPORTED_EXTENSIONS = (".glb", ".gltf", ".obj", ".ply", ".stl", ".zip")
_MESH_EXTENSIONS = tuple(e for e in SUPPORTED_EXTENSIONS if e != ".zip")
_CHUNK = 1 << 20


@dataclass(frozen=True)
class MeshLimits:
    """Budgets an upload must fit (defaults suit a CPU worker; the service may lower them)."""

    max_faces: int = 500_000  # after flattening, instances counted
    max_bytes: int = 100 * 2**20  # the file as uploaded
    max_unzipped_bytes: int = 400 * 2**20  # all zip members read, in total (zip-bomb guard)
    max_zip_members: int = 256


def load_mesh(data: str | Path | bytes, *, filename: str | None = None, limits: MeshLimits = MeshLimits(),
              name: str | None = None) -> trimesh.Trimesh:
    """Load ``data`` (a path, or the bytes of a file whose format ``filename`` names) as one mesh.

    The scene graph is flattened with its node transforms applied, so the vertices are in the file
    frame a viewer shows; visuals (base-colour texture + UVs, vertex colours, material colour) are
    kept because the guidance model sees colour. ``name`` labels messages and ``metadata["name"]``.
    """
    scene, label = _read(data, filename, limits, name)
    mesh = _guarded(lambda: _flatten(scene, limits, label), label)
    mesh.metadata["name"] = name or mesh.metadata.get("name")
    return mesh


def load_objects(data: str | Path | bytes, *, filename: str | None = None, limits: MeshLimits = MeshLimits(),
                 name: str | None = None) -> trimesh.Scene:
    """Load ``data`` as its separate objects: one node per mesh instance, named as in the file.

    The same gate as ``load_mesh`` (``limits`` count the faces of all objects), but not flattened:
    each node's geometry is its mesh with the node transform applied (file frame), keeping its own
    materials. Nodes keep the file's order (a glTF's node list), so a result scene of ``ctp assemble``
    or ``POST /align`` reads back as the objects it placed, base first.
    """
    scene, label = _read(data, filename, limits, name)
    return _guarded(lambda: _separate(scene, limits, label), label)


def _read(data: str | Path | bytes, filename: str | None, limits: MeshLimits,
          name: str | None) -> tuple[trimesh.Scene, str]:
    """The vetted, unflattened scene of an upload, and the label its messages use."""
    label = name or filename or (str(data) if isinstance(data, str | Path) else "upload")

    def read() -> trimesh.Scene:
        if isinstance(data, str | Path):
            path = Path(data)
            ext = _extension(filename or path.name, label)
            size = _file_size(path, label)
            if size > limits.max_bytes:
                raise _too_big(label, size, limits)
            payload = path.read_bytes()
            # an OBJ on disk may use its MTL and textures beside it; glTF references are never followed
            assets = _Assets.from_folder(path.parent, limits) if ext == ".obj" else _Assets.empty()
        else:
            if filename is None:
                raise MeshError(f"{label}: a filename is needed to tell the format of raw bytes",
                                code="mesh_unknown_format")
            ext = _extension(filename, label)
            payload = bytes(data)
            if len(payload) > limits.max_bytes:
                raise _too_big(label, len(payload), limits)
            assets = _Assets.empty()
        if ext == ".zip":
            member, payload, assets = _open_zip(payload, limits, label)
            ext = _extension(member, label)
        scene = _load_scene(payload, ext, assets, label)
        if ext in (".glb", ".gltf"):
            scene.metadata["node_order"] = [n.get("name") for n in _gltf_json(payload, ext, label).get("nodes", [])
                                            if isinstance(n, dict)]
        return scene

    return _guarded(read, label), label


def _guarded(work, label: str):
    """Run ``work``; anything but a MeshError (trimesh, PIL and numpy raise many kinds) becomes mesh_unreadable."""
    try:
        return work()
    except MeshError:
        raise
    except Exception as exc:
        raise MeshError(f"{label}: could not read the mesh ({type(exc).__name__}: {exc})",
                        code="mesh_unreadable") from exc


def validate_upload(data: bytes, filename: str, limits: MeshLimits) -> trimesh.Trimesh:
    """The check the service runs before enqueueing: a full load, so the worker cannot meet a surprise."""
    return load_mesh(data, filename=filename, limits=limits, name=filename)


def _extension(filename: str, label: str) -> str:
    ext = Path(filename).suffix.lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise MeshError(f"{label}: unsupported format {ext or '(no extension)'!r}; "
                        f"use one of {', '.join(SUPPORTED_EXTENSIONS)}", code="mesh_unknown_format")
    return ext


def _file_size(path: Path, label: str) -> int:
    try:
        return path.stat().st_size
    except OSError as exc:
        raise MeshError(f"{label}: cannot read the file ({exc.strerror})", code="mesh_unreadable") from exc


def _too_big(label: str, size: int, limits: MeshLimits) -> MeshError:
    return MeshError(f"{label}: file is {size / 2**20:.1f} MiB, over the {limits.max_bytes / 2**20:.0f} MiB limit",
                     code="mesh_file_too_large")


class _Assets(Mapping):
    """Files an OBJ/MTL or glTF may reference, by name relative to the mesh file, confined to one root.

    A read-only mapping, which trimesh accepts as a resolver. Names are normalised (``\\`` to ``/``,
    ``./``, URL escapes) and any name that leaves the root is simply absent, as is anything beyond the
    byte budget, so a reference can never reach outside the upload. Zip members are listed; a folder
    on disk is only looked up on demand (listing a user's Downloads folder would be absurd).
    """

    def __init__(self, find: Callable[[str], str | None], read: Callable[[str], bytes],
                 names: tuple[str, ...] = (), base: str = ""):
        self._find, self._read, self._names, self._base = find, read, names, base

    @classmethod
    def empty(cls) -> _Assets:
        return cls(lambda name: None, lambda key: b"")

    @classmethod
    def from_members(cls, names: list[str], read: Callable[[str], bytes]) -> _Assets:
        """Zip members; case-insensitive lookup, since archives made on Windows rarely match case."""
        by_lower = {n.lower(): n for n in names}
        return cls(lambda name: by_lower.get(name.lower()), read, tuple(names))

    @classmethod
    def from_folder(cls, folder: Path, limits: MeshLimits) -> _Assets:
        """Files in or under ``folder`` (symlinks out of it are absent), read within the byte budget."""
        root = folder.resolve()
        budget = [limits.max_unzipped_bytes]

        def find(name: str) -> str | None:
            target = (root / name).resolve()
            return name if target.is_relative_to(root) and target.is_file() else None

        return cls(find, lambda key: _read_capped((root / key).open("rb"), budget, key))

    def relative_to(self, member: str) -> _Assets:
        """The same files, seen from the folder of ``member`` (references are relative to the mesh)."""
        return _Assets(self._find, self._read, self._names, posixpath.dirname(member))

    def _key(self, name: str) -> str | None:
        clean = posixpath.normpath(posixpath.join(self._base, unquote(str(name)).replace("\\", "/")))
        if clean.startswith(("../", "/")) or clean == "..":
            return None
        return self._find(clean)

    def __getitem__(self, name: str) -> bytes:
        key = self._key(name)
        if key is None:
            raise KeyError(name)
        return self._read(key)

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and self._key(name) is not None

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)


def _read_capped(stream, budget: list[int], name: str) -> bytes:
    """Read a stream while decrementing the shared byte budget; a bomb stops at the budget, not at EOF."""
    parts = []
    with stream:
        while chunk := stream.read(_CHUNK):
            budget[0] -= len(chunk)
            if budget[0] < 0:
                raise MeshError(f"{name}: unpacked content exceeds the size limit", code="mesh_zip_invalid")
            parts.append(chunk)
    return b"".join(parts)


def _open_zip(payload: bytes, limits: MeshLimits, label: str) -> tuple[str, bytes, _Assets]:
    """Validate a zip and return (mesh member name, its bytes, the other members as assets)."""
    try:
        archive = zipfile.ZipFile(io.BytesIO(payload))
        infos = [i for i in archive.infolist() if not i.is_dir()]
    except (zipfile.BadZipFile, ValueError) as exc:
        raise MeshError(f"{label}: not a valid zip archive ({exc})", code="mesh_zip_invalid") from exc
    if len(infos) > limits.max_zip_members:
        raise MeshError(f"{label}: zip has {len(infos)} members, over the limit of {limits.max_zip_members}",
                        code="mesh_zip_invalid")
    for info in infos:
        parts = info.filename.replace("\\", "/").split("/")
        if info.filename.startswith(("/", "\\")) or ".." in parts or ":" in parts[0]:
            raise MeshError(f"{label}: zip member {info.filename!r} points outside the archive",
                            code="mesh_zip_invalid")
        if info.flag_bits & 0x1:
            raise MeshError(f"{label}: zip member {info.filename!r} is encrypted", code="mesh_zip_invalid")
    declared = sum(i.file_size for i in infos)
    if declared > limits.max_unzipped_bytes:
        raise MeshError(f"{label}: zip unpacks to {declared / 2**20:.0f} MiB, over the "
                        f"{limits.max_unzipped_bytes / 2**20:.0f} MiB limit", code="mesh_zip_invalid")

    names = [i.filename.replace("\\", "/") for i in infos
             if not i.filename.startswith("__MACOSX/") and not posixpath.basename(i.filename).startswith("._")]
    meshes = [n for n in names if Path(n).suffix.lower() in _MESH_EXTENSIONS]
    if len(meshes) != 1:
        found = "no mesh file" if not meshes else f"several mesh files ({', '.join(meshes[:5])})"
        raise MeshError(f"{label}: zip holds {found}; put exactly one of "
                        f"{', '.join(_MESH_EXTENSIONS)} with its materials and textures in it", code="mesh_zip_invalid")
    budget = [limits.max_unzipped_bytes]
    by_name = {i.filename.replace("\\", "/"): i for i in infos}
    assets = _Assets.from_members(names, lambda n: _read_capped(archive.open(by_name[n]), budget, n))
    return meshes[0], assets[meshes[0]], assets.relative_to(meshes[0])


def _gltf_json(payload: bytes, ext: str, label: str) -> dict:
    """The JSON of a .gltf, or of a .glb's first chunk (parsed here so URIs can be vetted first)."""
    if ext == ".gltf":
        text = payload
    else:
        if len(payload) < 20:
            raise MeshError(f"{label}: truncated GLB", code="mesh_unreadable")
        magic, version, length = struct.unpack_from("<4sII", payload, 0)
        chunk_length, chunk_type = struct.unpack_from("<I4s", payload, 12)
        if magic != b"glTF" or version != 2 or chunk_type != b"JSON":
            raise MeshError(f"{label}: not a glTF 2.0 binary file", code="mesh_unreadable")
        if length > len(payload) or 20 + chunk_length > len(payload):
            raise MeshError(f"{label}: truncated GLB ({len(payload)} of {length} bytes)", code="mesh_unreadable")
        text = payload[20:20 + chunk_length]
    try:
        tree = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MeshError(f"{label}: glTF JSON is corrupt ({exc})", code="mesh_unreadable") from exc
    if not isinstance(tree, dict):
        raise MeshError(f"{label}: glTF JSON is not an object", code="mesh_unreadable")
    return tree


def _uris(node) -> Iterator[str]:
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "uri" and isinstance(value, str):
                yield value
            else:
                yield from _uris(value)
    elif isinstance(node, list):
        for value in node:
            yield from _uris(value)


def _load_scene(payload: bytes, ext: str, assets: _Assets, label: str) -> trimesh.Scene:
    if ext in (".glb", ".gltf"):
        for uri in _uris(_gltf_json(payload, ext, label)):
            if not uri.startswith("data:") and uri not in assets:
                raise MeshError(f"{label}: glTF references an external file or URL ({uri[:80]!r}); "
                                "upload a self-contained .glb", code="mesh_external_reference")
    if ext == ".obj" and not payload.strip():
        raise MeshError(f"{label}: the file is empty", code="mesh_empty")
    # process=False: keep the file's vertices as they are so NaN/inf are refused, not silently dropped.
    return trimesh.load(io.BytesIO(payload), file_type=ext[1:], resolver=assets, force="scene", process=False)


def _instances(scene: trimesh.Scene, limits: MeshLimits, label: str) -> list[tuple[str, np.ndarray, trimesh.Trimesh]]:
    """(node, transform, mesh) of every triangle mesh instance, checked against the limits and for NaN."""
    others = [k for k, g in scene.geometry.items() if not isinstance(g, trimesh.Trimesh)]
    if others:
        scene.delete_geometry(others)
    instances = [(node, *scene.graph[node]) for node in scene.graph.nodes_geometry]
    instances = [(node, matrix, scene.geometry[key]) for node, matrix, key in instances if key in scene.geometry]
    faces = sum(len(g.faces) for _, _, g in instances)
    if faces == 0:
        raise MeshError(f"{label}: no triangles in the file", code="mesh_empty")
    if faces > limits.max_faces:
        raise MeshError(f"{label}: {faces:,} faces, over the limit of {limits.max_faces:,}; decimate it first",
                        code="mesh_too_large")
    for _, matrix, geometry in instances:
        if not (np.isfinite(matrix).all() and np.isfinite(geometry.vertices).all()):
            raise MeshError(f"{label}: vertices or transforms contain NaN or infinity", code="mesh_invalid_values")
    return instances


def _flatten(scene: trimesh.Scene, limits: MeshLimits, label: str) -> trimesh.Trimesh:
    """Apply node transforms and concatenate every triangle mesh instance (points and lines dropped)."""
    _instances(scene, limits, label)
    for geometry in scene.geometry.values():
        _bake_base_colour_factor(geometry)
    mesh = scene.to_geometry()
    return _checked(mesh, label)


def _separate(scene: trimesh.Scene, limits: MeshLimits, label: str) -> trimesh.Scene:
    """One node per instance, its mesh moved by the node transform (file frame), in the file's node order."""
    order = {name: i for i, name in enumerate(scene.metadata.get("node_order", []))}
    instances = sorted(_instances(scene, limits, label), key=lambda item: (order.get(item[0], len(order)), item[0]))
    out = trimesh.Scene()
    for node, matrix, geometry in instances:
        mesh = geometry.copy()
        mesh.apply_transform(matrix)
        out.add_geometry(_checked(mesh, f"{label}: {node}"), node_name=node, geom_name=node)
    return out


def _checked(mesh: trimesh.Trimesh, label: str) -> trimesh.Trimesh:
    if not np.isfinite(mesh.vertices).all():
        raise MeshError(f"{label}: vertices overflow once node transforms are applied", code="mesh_invalid_values")
    mesh.merge_vertices()  # what trimesh's default processing does: shared vertices where UVs agree
    if not mesh.area > 0 or not mesh.extents.max() > 0:
        raise MeshError(f"{label}: the mesh has no surface area", code="mesh_empty")
    return mesh


def _bake_base_colour_factor(mesh: trimesh.Trimesh) -> None:
    """Multiply a PBR material's base colour factor into its texture, in place.

    Flattening packs several materials into one atlas, and trimesh 5.2's packer multiplies the texture
    by the uint8 factor unscaled (255 x texel wraps round: inverted colours). A texture with no factor
    packs correctly. The factor is linear (glTF), the texture sRGB, so the factor is taken to sRGB
    first (exact for a pure power-law transfer, close for sRGB).
    """
    material = getattr(mesh.visual, "material", None)
    if not isinstance(material, trimesh.visual.material.PBRMaterial) or material.baseColorTexture is None:
        return
    factor = material.baseColorFactor
    if factor is None:
        return
    srgb = trimesh.visual.color.linear_to_srgb(np.asarray(factor[:3], dtype=np.float64) / 255.0)
    texels = np.asarray(material.baseColorTexture.convert("RGB"), dtype=np.float64) * srgb
    material.baseColorTexture = Image.fromarray(texels.round().clip(0, 255).astype(np.uint8))
    material.baseColorFactor = None
