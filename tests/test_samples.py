"""The generated sample pairs load through the same loader as uploads and are small."""

from __future__ import annotations

import pytest

from ctp_core.io import load_mesh
from ctp_core.samples import SAMPLES, get_sample


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_samples_are_small_loadable_glbs(name, tmp_path):
    sample = get_sample(name)
    paths = sample.write(tmp_path)
    assert [p.name for p in paths] == [sample.target_file, sample.source_file]
    target, source = (load_mesh(p) for p in paths)
    assert all(p.stat().st_size < 64_000 for p in paths)
    assert target.extents.max() > 2 * source.extents.max()  # a table under a cup, a bowl round an apple
    assert abs(target.bounds[0][1]) < 1e-6 and abs(source.bounds[0][1]) < 1e-6  # bases at y = 0


def test_unknown_sample_names_the_known_ones():
    with pytest.raises(KeyError, match="cup-on-table"):
        get_sample("teapot")
