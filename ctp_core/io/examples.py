"""Small example pairs made in code: something to try ``ctp align``, the service and the web page on.

Each example is two coloured meshes generated here (no third-party data, nothing to license), a few kB as
GLB, with the prompt and the object names the priors should read; each file's one node is named so too. Units
are metres, +Y up, each mesh in its own file frame with its base at y = 0 (the source sits wherever it was
modelled: the engine places it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

__all__ = ["EXAMPLES", "Example", "get_example", "write_table_setting"]


def _coloured(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)))
    return mesh


def _table() -> trimesh.Trimesh:
    """A 1.2 x 0.8 m table, 0.75 m high: a top and four legs."""
    top = trimesh.creation.box((1.2, 0.05, 0.8))
    top.apply_translation((0, 0.725, 0))
    legs = []
    for x in (-0.55, 0.55):
        for z in (-0.35, 0.35):
            leg = trimesh.creation.box((0.05, 0.7, 0.05))
            leg.apply_translation((x, 0.35, z))
            legs.append(leg)
    return _coloured(trimesh.util.concatenate([top, *legs]), (150, 100, 60))


def _cup() -> trimesh.Trimesh:
    """A 9 cm high, 8 cm wide open cup: a thin-walled cylinder with a bottom."""
    outer = trimesh.creation.cylinder(radius=0.04, height=0.09, sections=24)
    inner = trimesh.creation.cylinder(radius=0.035, height=0.09, sections=24)
    inner.apply_translation((0, 0, 0.005))
    try:
        cup = outer.difference(inner)
    except Exception:  # no boolean engine: a closed cylinder still reads as a cup at this size
        cup = outer
    cup.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    cup.apply_translation((0, 0.045, 0))
    return _coloured(cup, (230, 230, 240))


def _bowl() -> trimesh.Trimesh:
    """A 20 cm wide, 12 cm deep bowl: a hollow sphere cut 2 cm above its equator."""
    outer = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.092)
    cutter = trimesh.creation.box((0.3, 0.2, 0.3))
    cutter.apply_translation((0, 0.12, 0))
    try:
        bowl = outer.difference(inner).difference(cutter)
    except Exception:
        bowl = outer
    bowl.apply_translation((0, -bowl.bounds[0][1], 0))
    return _coloured(bowl, (60, 120, 200))


def _plate() -> trimesh.Trimesh:
    """A 24 cm wide, 2 cm thick plate: a flat disc."""
    plate = trimesh.creation.cylinder(radius=0.12, height=0.02, sections=48)
    plate.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    plate.apply_translation((0, 0.01, 0))
    return _coloured(plate, (245, 245, 235))


def _apple() -> trimesh.Trimesh:
    """An 8 cm apple: a slightly squashed sphere."""
    apple = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    apple.apply_scale((1.0, 0.9, 1.0))
    apple.apply_translation((0, 0.036, 0))
    return _coloured(apple, (200, 30, 30))


@dataclass(frozen=True)
class Example:
    """A generated pair: the target stays put, the source is placed by the prompt."""

    name: str
    prompt: str
    target_name: str
    source_name: str
    make_target: Callable[[], trimesh.Trimesh]
    make_source: Callable[[], trimesh.Trimesh]

    @property
    def target_file(self) -> str:
        return f"{self.target_name}.glb"

    @property
    def source_file(self) -> str:
        return f"{self.source_name}.glb"

    def meshes(self) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
        """(target, source), each in its own file frame."""
        return self.make_target(), self.make_source()

    def files(self) -> dict[str, bytes]:
        """{file name: GLB bytes} for the target and the source."""
        target, source = self.meshes()
        return {self.target_file: _glb(target, self.target_name), self.source_file: _glb(source, self.source_name)}

    def write(self, directory: str | Path) -> list[Path]:
        """Write both GLBs into ``directory`` (created if needed); returns their paths, target first."""
        folder = Path(directory)
        folder.mkdir(parents=True, exist_ok=True)
        paths = []
        for name, data in self.files().items():
            path = folder / name
            path.write_bytes(data)
            paths.append(path)
        return paths


def _glb(mesh: trimesh.Trimesh, name: str) -> bytes:
    """``mesh`` as a GLB of one node named ``name`` (what a DCC tool or the priors read it as)."""
    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name=name, geom_name=name)
    return trimesh.exchange.gltf.export_glb(scene)


EXAMPLES: dict[str, Example] = {e.name: e for e in (
    Example("cup-on-table", "a cup on the table", "table", "cup", _table, _cup),
    Example("apple-in-bowl", "an apple in a bowl", "bowl", "apple", _bowl, _apple),
)}


def get_example(name: str) -> Example:
    """An example by name; KeyError lists the known ones."""
    try:
        return EXAMPLES[name]
    except KeyError:
        raise KeyError(f"unknown example {name!r}; known: {', '.join(EXAMPLES)}") from None


TABLE_SETTING_PLAN = """\
# ctp assemble --plan plan.yaml: a table laid with a plate, then a cup on the plate
base: table.glb
steps:
  - file: plate.glb
    prompt: a plate on the table
  - file: cup.glb
    prompt: a cup on the plate
    on: plate
"""


def write_table_setting(directory: str | Path) -> Path:
    """Write a three-object assembly (table.glb, plate.glb, cup.glb and plan.yaml); returns the plan's path."""
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    for name, make in (("table", _table), ("plate", _plate), ("cup", _cup)):
        (folder / f"{name}.glb").write_bytes(_glb(make(), name))
    plan = folder / "plan.yaml"
    plan.write_text(TABLE_SETTING_PLAN)
    return plan
