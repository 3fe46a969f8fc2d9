"""The generated example pairs load through the same loader as uploads and are small."""

from __future__ import annotations

import pytest

from ctp_core.io import load_mesh
from ctp_core.io.examples import EXAMPLES, get_example


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
