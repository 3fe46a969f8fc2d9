"""The generated example pairs load through the same loader as uploads, are small and name their nodes."""

from __future__ import annotations

import pytest
import trimesh

from ctp_core.io import load_mesh
from ctp_core.io.examples import EXAMPLES, get_example, write_table_setting


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_examples_are_small_loadable_glbs(name, tmp_path):
    example = get_example(name)
    paths = example.write(tmp_path)
    assert [p.name for p in paths] == [example.target_file, example.source_file]
    target, source = (load_mesh(p) for p in paths)
    assert all(p.stat().st_size < 64_000 for p in paths)
    assert target.extents.max() > 2 * source.extents.max()  # a table under a cup, a bowl round an apple
    assert abs(target.bounds[0][1]) < 1e-6 and abs(source.bounds[0][1]) < 1e-6  # bases at y = 0


def test_unknown_example_names_the_known_ones():
    with pytest.raises(KeyError, match="cup-on-table"):
        get_example("teapot")


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_example_nodes_are_named_as_the_objects(name, tmp_path):
    example = get_example(name)
    for path, role in zip(example.write(tmp_path), (example.target_name, example.source_name), strict=True):
        assert trimesh.load(path, force="scene").graph.nodes_geometry == [role]


def test_table_setting_nodes_are_named_as_their_files(tmp_path):
    write_table_setting(tmp_path)
    for name in ("table", "plate", "cup"):
        assert trimesh.load(tmp_path / f"{name}.glb", force="scene").graph.nodes_geometry == [name]
