"""Benchmark cases on disk: one folder per case with ``target.glb``, ``source.glb`` and ``case.json``.

The format is the one of ``shared/bench/README.md``: ``reference.source_to_target`` is a row-major
4x4 (uniform scale included) mapping the *source file frame* to the *target file frame*, or null when
the true arrangement is unknown.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ctp_core.errors import ConfigError


@dataclass(frozen=True)
class Case:
    id: str
    folder: Path
    prompt: str
    target_file: Path
    source_file: Path
    target_name: str
    source_name: str
    reference: np.ndarray | None  # (4, 4) source file -> target file, or None
    relation: str
    penetration_expected: bool
    origin: str

    def load(self) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
        """(target, source) in their file frames, through the same loader as uploads."""
        from ctp_core import io

        return (io.load_mesh(self.target_file, name=f"{self.id}/target"),
                io.load_mesh(self.source_file, name=f"{self.id}/source"))


def read_case(path: Path) -> Case:
    """Parse one ``case.json`` (paths resolve against its folder)."""
    path = Path(path)
    data = json.loads(path.read_text())
    reference = data.get("reference")
    matrix = None if reference is None else np.asarray(reference["source_to_target"], dtype=np.float64)
    if matrix is not None and matrix.shape != (4, 4):
        raise ConfigError(f"{path}: reference.source_to_target must be 4x4, got {matrix.shape}", field="cases")
    return Case(
        id=str(data["id"]), folder=path.parent, prompt=str(data["prompt"]),
        target_file=path.parent / data["target"]["file"], source_file=path.parent / data["source"]["file"],
        target_name=str(data["target"].get("name", "target")), source_name=str(data["source"].get("name", "source")),
        reference=matrix, relation=str(data.get("relation", "other")),
        penetration_expected=bool(data.get("penetration_expected", False)), origin=str(data.get("origin", "")),
    )


def discover(root: Path, ids: list[str] | None = None) -> list[Case]:
    """All cases under ``root`` (searched recursively), sorted by id; ``ids`` keeps those, in that order.

    Unknown or duplicate ids are an error rather than a silently smaller benchmark.
    """
    root = Path(root)
    if not root.is_dir():
        raise ConfigError(f"cases folder {root} does not exist", field="cases_dir")
    found: dict[str, Case] = {}
    for path in sorted(root.rglob("case.json")):
        case = read_case(path)
        if case.id in found:
            raise ConfigError(f"duplicate case id {case.id!r} in {found[case.id].folder} and {case.folder}",
                              field="cases_dir")
        found[case.id] = case
    if not ids:
        return [found[k] for k in sorted(found)]
    missing = [i for i in ids if i not in found]
    if missing:
        raise ConfigError(f"unknown case id(s) {', '.join(missing)} under {root}", field="cases")
    return [found[i] for i in ids]
