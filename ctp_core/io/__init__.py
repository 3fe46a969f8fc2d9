"""Input: one flattened, validated ``trimesh.Trimesh`` in the *file frame* from an upload or a path, and
the reference picture of an image-guided run (``load_image``).

Uploads are untrusted, so loading is also the gate: every refusal is a ``MeshError`` with a stable
code (the service and CLI turn codes into messages). Nothing named *inside* a file is ever fetched
from the file system or the network: glTF URIs other than ``data:`` are refused before trimesh sees
the file, and an OBJ's MTL and textures resolve only among the members of its own zip (or, for a
path on disk, inside the OBJ's own folder).
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import math
import posixpath
import stat
import struct
import zipfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import trimesh
from PIL import Image

from ctp_core.errors import ImageError, MeshError

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
    # glTF scene graph, checked in the JSON before any geometry is built: flattening costs grow with the
    # cube of the depth (a 25 kB chain of 500 nodes took trimesh 10 s), so a file over these is refused.
    max_nodes: int = 10_000
    max_depth: int = 128


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
    label = label_of(data, filename, name)

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
        return _load_scene(payload, ext, assets, limits, label)

    return _guarded(read, label), label


def label_of(data: str | Path | bytes, filename: str | None = None, name: str | None = None) -> str:
    """What messages about an upload call it: its name, else its file name, else its path, else "upload"."""
    return name or filename or (str(data) if isinstance(data, str | Path) else "upload")


def _guarded(work, label: str):
    """Run ``work``; anything but a MeshError (trimesh, PIL and numpy raise many kinds) becomes mesh_unreadable."""
    try:
        return work()
    except (MeshError, MemoryError):  # out of memory is the caller's to report (ctp_core.io.loader)
        raise
    except Exception as exc:
        raise MeshError(f"{label}: could not read the mesh ({type(exc).__name__}: {exc})",
                        code="mesh_unreadable") from exc


def load_image(data: str | Path | bytes, *, max_pixels: int | None = None, name: str = "image") -> np.ndarray:
    """A reference picture (PNG or JPEG, a path or an upload's bytes) as (H, W, 3) uint8 RGB.

    The one image loader of the CLI, the API's check and the worker, so all three refuse the same files
    with the same ``ImageError``: ``invalid_image`` whatever the decoder raised, ``image_too_large`` over
    ``max_pixels`` (checked from the header, before decoding).
    """
    try:
        with Image.open(io.BytesIO(data) if isinstance(data, bytes | bytearray) else Path(data)) as img:
            if max_pixels is not None and img.width * img.height > max_pixels:
                raise ImageError(f"{name}: {img.width} x {img.height} pixels is over the {max_pixels}-pixel limit",
                                 code="image_too_large", field=name)
            return np.asarray(img.convert("RGB"), dtype=np.uint8)
    except ImageError:
        raise
    except FileNotFoundError:
        raise ImageError(f"{name}: no such file: {data}", field=name) from None
    except Exception as exc:  # PIL raises many kinds (UnidentifiedImageError, truncated data, bombs)
        raise ImageError(f"{name}: not a readable PNG or JPEG image", field=name) from exc


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
        raise MeshError(f"{label}: cannot read {path} ({exc.strerror})", code="mesh_unreadable") from exc


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
        if stat.S_ISLNK(info.external_attr >> 16):  # read in memory, it could not escape; refused all the same
            raise MeshError(f"{label}: zip member {info.filename!r} is a symbolic link", code="mesh_zip_invalid")
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


def _gltf_json(payload: bytes, ext: str, label: str) -> tuple[dict, int | None]:
    """The JSON of a .gltf, or of a .glb's first chunk, and the length of the GLB's binary chunk (parsed
    here so URIs and budgets can be vetted before trimesh builds anything)."""
    binary = None
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
        at = 20 + chunk_length
        if at + 8 <= len(payload) and payload[at + 4:at + 8] == b"BIN\0":
            binary = min(struct.unpack_from("<I", payload, at)[0], len(payload) - at - 8)
    try:
        tree = json.loads(text)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise MeshError(f"{label}: glTF JSON is corrupt ({type(exc).__name__}: {exc})", code="mesh_unreadable") from exc
    if not isinstance(tree, dict):
        raise MeshError(f"{label}: glTF JSON is not an object", code="mesh_unreadable")
    return tree, binary


_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _gltf_budget(tree: dict, binary: int | None, assets: _Assets, limits: MeshLimits, label: str) -> None:
    """Check a glTF's JSON against the budgets, before trimesh builds anything from it.

    The node hierarchy must be a forest (one parent per node, no cycles) within ``max_nodes`` and
    ``max_depth``; the faces of every mesh instance reachable from a scene count against ``max_faces``;
    each accessor must fit in its buffer view, each view in its buffer, each buffer in the bytes given
    (a ``data:`` URI must decode to exactly its ``byteLength``). Malformed JSON (wrong types) is
    ``mesh_unreadable``, a graph over budget ``mesh_too_complex``, too many faces ``mesh_too_large``.
    """
    vet = _GltfVet(tree, label)
    buffers, views, accessors = vet.items("buffers"), vet.items("bufferViews"), vet.items("accessors")
    nodes, meshes, scenes = vet.items("nodes"), vet.items("meshes"), vet.items("scenes")
    sizes = _gltf_buffer_sizes(vet, buffers, binary, assets)
    _gltf_views_fit(vet, views, sizes)
    _gltf_accessors_fit(vet, accessors, views, limits)
    if len(nodes) > limits.max_nodes:
        raise MeshError(f"{label}: {len(nodes):,} scene nodes, over the limit of {limits.max_nodes:,}",
                        code="mesh_too_complex")
    parent = _gltf_parents(vet, nodes)
    _gltf_depths_fit(len(nodes), parent, limits, label)
    for s, scene in enumerate(scenes):
        roots = scene.get("nodes", [])
        if not isinstance(roots, list) or any(vet.index(r, len(nodes), f"scenes[{s}].nodes") in parent for r in roots):
            raise vet.bad(f"scenes[{s}].nodes must list nodes without a parent")
    faces = [_mesh_faces(mesh, accessors, vet.bad) for mesh in meshes]
    # a forest: every node is at most one instance of its mesh
    instanced = sum(faces[vet.index(n["mesh"], len(meshes), "node mesh")] for n in nodes if "mesh" in n) or sum(faces)
    if instanced > limits.max_faces:
        raise MeshError(f"{label}: {instanced:,} faces with instances counted, over the limit of "
                        f"{limits.max_faces:,}; decimate it first", code="mesh_too_large")


class _GltfVet:
    """The type and range checks of one glTF's JSON (``tree``); each refusal is ``mesh_unreadable``, naming what
    is wrong."""

    def __init__(self, tree: dict, label: str):
        self.tree, self.label = tree, label

    def bad(self, what: str) -> MeshError:
        return MeshError(f"{self.label}: invalid glTF: {what}", code="mesh_unreadable")

    def items(self, key: str) -> list[dict]:
        """The top-level list ``key`` (empty when absent), which must hold objects."""
        value = self.tree.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self.bad(f"{key} is not a list of objects")
        return value

    def index(self, value, size: int, what: str) -> int:
        """``value`` as an index into a list of ``size``."""
        if type(value) is not int or not 0 <= value < size:
            raise self.bad(f"{what} {value!r} is out of range")
        return value

    def natural(self, item: dict, key: str, what: str, default: int | None = None) -> int:
        """``item[key]`` (else ``default``) as a non-negative integer."""
        value = item.get(key, default)
        if type(value) is not int or value < 0:
            raise self.bad(f"{what}.{key} must be a non-negative integer")
        return value


def _gltf_buffer_sizes(vet: _GltfVet, buffers: list[dict], binary: int | None, assets: _Assets) -> list[int]:
    """The declared byte length of each buffer, checked against the bytes it has: the GLB's binary chunk (the first
    buffer only), a ``data:`` URI's decoded bytes (exactly), or a member of the same zip."""
    sizes = []
    for i, buffer in enumerate(buffers):
        declared = vet.natural(buffer, "byteLength", f"buffers[{i}]")
        uri = buffer.get("uri")
        if uri is None:
            if i != 0 or binary is None or declared > binary:
                raise vet.bad(f"buffers[{i}] declares {declared} bytes that the file does not hold")
        elif isinstance(uri, str) and uri.startswith("data:"):
            decoded = _data_uri_size(uri, vet.label)
            if decoded != declared:
                raise vet.bad(f"buffers[{i}] declares byteLength {declared} but its data: URI holds {decoded} bytes")
        elif isinstance(uri, str) and len(assets[uri]) < declared:  # a member of the same zip
            raise vet.bad(f"buffers[{i}] declares {declared} bytes, {uri!r} holds {len(assets[uri])}")
        sizes.append(declared)
    return sizes


def _gltf_views_fit(vet: _GltfVet, views: list[dict], sizes: list[int]) -> None:
    """Each buffer view ends within its buffer (``sizes``: the buffers' byte lengths)."""
    for i, view in enumerate(views):
        buffer = vet.index(view.get("buffer"), len(sizes), f"bufferViews[{i}].buffer")
        end = (vet.natural(view, "byteOffset", f"bufferViews[{i}]", 0)
               + vet.natural(view, "byteLength", f"bufferViews[{i}]"))
        if end > sizes[buffer]:
            raise vet.bad(f"bufferViews[{i}] ends at byte {end}, past its buffer ({sizes[buffer]} bytes)")


def _gltf_accessors_fit(vet: _GltfVet, accessors: list[dict], views: list[dict], limits: MeshLimits) -> None:
    """Each accessor has a known element type and its elements (with the view's stride) end within its buffer view;
    one without a view (zeros) has no more elements than the face budget allows."""
    for i, accessor in enumerate(accessors):
        count = vet.natural(accessor, "count", f"accessors[{i}]")
        width = _COMPONENT_BYTES.get(accessor.get("componentType"), 0) * _TYPE_COMPONENTS.get(accessor.get("type"), 0)
        if not width:
            raise vet.bad(f"accessors[{i}] has an unknown componentType or type")
        if "bufferView" not in accessor:
            if count > 3 * limits.max_faces:
                raise vet.bad(f"accessors[{i}] has {count} elements and no data")
            continue
        view = views[vet.index(accessor["bufferView"], len(views), f"accessors[{i}].bufferView")]
        stride = vet.natural(view, "byteStride", f"bufferViews[{accessor['bufferView']}]", width) or width
        end = vet.natural(accessor, "byteOffset", f"accessors[{i}]", 0) + (stride * (count - 1) + width if count else 0)
        if end > view["byteLength"]:
            raise vet.bad(f"accessors[{i}] needs {end} bytes, its buffer view has {view['byteLength']}")


def _gltf_parents(vet: _GltfVet, nodes: list[dict]) -> dict[int, int]:
    """The parent of each node that has one; a node listed as the child of two, or of itself, is refused."""
    parent: dict[int, int] = {}
    for i, node in enumerate(nodes):
        children = node.get("children", [])
        if not isinstance(children, list):
            raise vet.bad(f"nodes[{i}].children is not a list")
        for child in children:
            if vet.index(child, len(nodes), f"nodes[{i}].children") in parent or child == i:
                raise vet.bad(f"node {child} has several parents (the scene graph must be a tree)")
            parent[child] = i
    return parent


def _gltf_depths_fit(count: int, parent: dict[int, int], limits: MeshLimits, label: str) -> None:
    """No node of ``count`` is deeper than ``max_depth`` below its root, and no chain of parents is a cycle."""
    depths = [0] * count  # 1 for a root; found by walking up, each node once
    too_deep = MeshError(f"{label}: the scene graph is over {limits.max_depth} nodes deep", code="mesh_too_complex")
    for start in range(count):
        chain, at = [], start
        while not depths[at]:
            chain.append(at)
            if len(chain) > limits.max_depth:  # a cycle never reaches a root, so it ends here too
                raise too_deep
            if at not in parent:
                break
            at = parent[at]
        depth = depths[at]  # 0 when the walk ended at a root not yet seen (then the last of chain)
        for node in reversed(chain):
            depth += 1
            if depth > limits.max_depth:
                raise too_deep
            depths[node] = depth


def _mesh_faces(mesh: dict, accessors: list[dict], bad) -> int:
    """Triangles of one glTF mesh as its accessors declare them (points and lines count none)."""
    primitives = mesh.get("primitives", [])
    if not isinstance(primitives, list) or not all(isinstance(p, dict) for p in primitives):
        raise bad("mesh primitives are not a list of objects")
    total = 0
    for primitive in primitives:
        attributes = primitive.get("attributes", {})
        which = primitive.get("indices", attributes.get("POSITION") if isinstance(attributes, dict) else None)
        if which is None:
            continue
        if type(which) is not int or not 0 <= which < len(accessors):
            raise bad(f"primitive accessor {which!r} is out of range")
        count, mode = accessors[which]["count"], primitive.get("mode", 4)
        total += count // 3 if mode == 4 else max(count - 2, 0) if mode in (5, 6) else 0
    return total


def _data_uri_size(uri: str, label: str) -> int:
    """Decoded size of a base64 ``data:`` URI (what trimesh will decode)."""
    header, _, body = uri.partition(",")
    if not header.endswith(";base64"):
        return len(unquote(body).encode("latin-1", "replace"))
    try:
        return len(base64.b64decode(body, validate=False))
    except (binascii.Error, ValueError) as exc:
        raise MeshError(f"{label}: invalid glTF: a data: URI is not base64 ({exc})", code="mesh_unreadable") from exc


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


def _load_scene(payload: bytes, ext: str, assets: _Assets, limits: MeshLimits, label: str) -> trimesh.Scene:
    """The scene trimesh builds from a vetted payload; a glTF's keeps its node order (``node_order``)."""
    tree = None
    if ext in (".glb", ".gltf"):
        tree, binary = _gltf_json(payload, ext, label)
        for uri in _uris(tree):
            if not uri.startswith("data:") and uri not in assets:
                raise MeshError(f"{label}: glTF references an external file or URL ({uri[:80]!r}); "
                                "upload a self-contained .glb", code="mesh_external_reference")
        _gltf_budget(tree, binary, assets, limits, label)
    if ext == ".obj" and not payload.strip():
        raise MeshError(f"{label}: the file is empty", code="mesh_empty")
    # process=False: keep the file's vertices as they are so NaN/inf are refused, not silently dropped.
    scene = trimesh.load(io.BytesIO(payload), file_type=ext[1:], resolver=assets, force="scene", process=False)
    scene.metadata["file_format"] = ext[1:]  # what says which way is up (``orientation``)
    if tree is not None:
        scene.metadata["node_order"] = [n.get("name") for n in tree.get("nodes", []) if isinstance(n, dict)]
    return scene


def _instances(scene: trimesh.Scene, limits: MeshLimits, label: str) -> list[tuple[str, np.ndarray, trimesh.Trimesh]]:
    """(node, transform, mesh) of every triangle mesh instance, checked against the limits and for NaN;
    the meshes' base colour factors baked into their textures."""
    others = [k for k, g in scene.geometry.items() if not isinstance(g, trimesh.Trimesh)]
    if others:
        scene.delete_geometry(others)
    world = _world_matrices(scene.graph)
    keys = {node: scene.graph.transforms.node_data[node]["geometry"] for node in scene.graph.nodes_geometry}
    instances = [(node, world(node), scene.geometry[key]) for node, key in keys.items() if key in scene.geometry]
    faces = sum(len(g.faces) for _, _, g in instances)
    if faces == 0:
        raise MeshError(f"{label}: no triangles in the file", code="mesh_empty")
    if faces > limits.max_faces:
        raise MeshError(f"{label}: {faces:,} faces, over the limit of {limits.max_faces:,}; decimate it first",
                        code="mesh_too_large")
    for _, matrix, geometry in instances:
        if not (np.isfinite(matrix).all() and np.isfinite(geometry.vertices).all()):
            raise MeshError(f"{label}: vertices or transforms contain NaN or infinity", code="mesh_invalid_values")
    for geometry in scene.geometry.values():
        _bake_base_colour_factor(geometry)
    return instances


def _flatten(scene: trimesh.Scene, limits: MeshLimits, label: str) -> trimesh.Trimesh:
    """Apply node transforms and concatenate every triangle mesh instance (points and lines dropped). A glTF whose
    nodes turn the object about its up keeps the front they give it (``node_front``) in ``metadata["front"]``."""
    instances = _instances(scene, limits, label)
    mesh = trimesh.util.concatenate([geometry.copy().apply_transform(matrix) for _, matrix, geometry in instances])
    mesh = _checked(mesh, label)
    mesh.metadata["file_format"] = scene.metadata.get("file_format")
    if scene.metadata.get("file_format") in ("glb", "gltf"):
        front = node_front(instances)
        if front is not None:
            mesh.metadata["front"] = front.tolist()
    return mesh


_Y_AXIS, _Z_AXIS = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
_NODE_AXIS_COS = math.cos(math.radians(10.0))  # a node axis this close to the scene's up is the object's up


def node_front(instances: list[tuple[str, np.ndarray, trimesh.Trimesh]]) -> np.ndarray | None:
    """The front a glTF's nodes give the object, in the flattened file frame (horizontal, unit), where it is not
    the file's +Z; None where it is, or where the nodes say none.

    An asset's front is its own +Z (glTF 2.0, 3.4) and its node's turn carries it: a desk modelled facing +Z and
    turned 90 degrees about +Y by its node faces +X once flattened. The node that decides is the largest instance's
    (by area). Its own axis that ends up along the scene's +Y is the object's up: its +Y, the front then its +Z; or
    its +Z (an export from a Z-up tool behind a -90 degree turn about X), the front then its -Y, as in
    ``orientation``'s rule for Z-up files; any other (the object tipped by its node) gives no front."""
    if not instances:
        return None
    _, matrix, _ = max(instances, key=lambda item: item[2].area * abs(np.linalg.det(item[1][:3, :3])) ** (2 / 3))
    linear = np.asarray(matrix, dtype=np.float64)[:3, :3]
    scale = abs(np.linalg.det(linear)) ** (1 / 3)
    if not scale > 0:
        return None
    rotation = linear / scale
    up = rotation.T @ _Y_AXIS  # the node's own axis that ends up along the scene's +Y
    if up @ _Y_AXIS > _NODE_AXIS_COS:
        own = _Z_AXIS
    elif up @ _Z_AXIS > _NODE_AXIS_COS:
        own = -_Y_AXIS
    else:
        return None
    front = rotation @ own
    front[1] = 0.0
    if np.linalg.norm(front) < 0.5:
        return None
    front /= np.linalg.norm(front)
    return None if front @ _Z_AXIS > math.cos(math.radians(1.0)) else front


def _separate(scene: trimesh.Scene, limits: MeshLimits, label: str) -> trimesh.Scene:
    """One node per instance, its mesh moved by the node transform (file frame), in the file's node order."""
    order = {name: i for i, name in enumerate(scene.metadata.get("node_order", []))}
    instances = sorted(_instances(scene, limits, label), key=lambda item: (order.get(item[0], len(order)), item[0]))
    out = trimesh.Scene()
    for node, matrix, geometry in instances:
        mesh = geometry.copy()
        mesh.apply_transform(matrix)
        mesh.metadata["file_format"] = scene.metadata.get("file_format")
        out.add_geometry(_checked(mesh, f"{label}: {node}"), node_name=node, geom_name=node)
    return out


def merge_digits(extent: float) -> int:
    """Decimal digits vertices are merged at (``trimesh`` ``merge_vertices``): trimesh's 8 (1e-8) for a mesh of
    extent 1 cm or more, finer below so that the tolerance stays a millionth of the mesh (down to 1e-24)."""
    if not (math.isfinite(extent) and 0 < extent < 1e-2):
        return 8
    return min(30, math.ceil(6 - math.log10(extent)))


def _checked(mesh: trimesh.Trimesh, label: str) -> trimesh.Trimesh:
    if not np.isfinite(mesh.vertices).all():
        raise MeshError(f"{label}: vertices overflow once node transforms are applied", code="mesh_invalid_values")
    # what trimesh's default processing does: shared vertices where UVs agree, at trimesh's absolute 1e-8
    # (8 digits) for any mesh of 1 cm or more; a smaller one merges at a millionth of its size instead (at 1e-8 a
    # 0.3 µm sphere kept 26 of its 642 vertices)
    mesh.merge_vertices(digits_vertex=merge_digits(float(mesh.extents.max()) if len(mesh.vertices) else 0.0))
    if not mesh.area > 0 or not mesh.extents.max() > 0:
        raise MeshError(f"{label}: the mesh has no surface area", code="mesh_empty")
    return mesh


def _world_matrices(graph: trimesh.scene.transforms.SceneGraph) -> Callable[[str], np.ndarray]:
    """A node's 4x4 from the scene's base frame, composed once per node down the tree.

    trimesh's own lookup (``graph[node]``) orders each node's chain with numpy's ``multi_dot``, whose
    chain-order search is cubic in the depth: 60 s for a 2000-node chain a client can send in 100 kB.
    """
    forest = graph.transforms
    world = {graph.base_frame: np.eye(4)}

    def of(node: str) -> np.ndarray:
        chain = []
        while node not in world:
            chain.append(node)
            node = forest.parents[node]
        matrix = world[node]
        for child in reversed(chain):
            edge = forest.edge_data[(forest.parents[child], child)]
            matrix = matrix @ edge["matrix"] if "matrix" in edge else matrix
            world[child] = matrix
        return matrix

    return of


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
