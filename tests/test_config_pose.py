import numpy as np
import pytest
import torch

from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.geometry import pose


def test_presets_differ_in_budget_and_overrides_merge():
    paper, default, test = (AlignConfig.from_preset(n) for n in ("paper", "default", "test"))
    assert (paper.optim.steps, paper.camera.views, paper.optim.phases, paper.optim.restarts) == (2000, 8, 3, 5)
    assert test.optim.steps < default.optim.steps < paper.optim.steps
    descent = AlignConfig.from_preset("descent")  # the earlier default: local descent from random starts
    assert (descent.optim.steps, descent.camera.views, descent.optim.restarts) == (120, 4, 4)
    assert default.search.enabled and test.search.enabled and not descent.search.enabled
    assert not paper.search.enabled
    cfg = AlignConfig.from_preset("test", optim={"restarts": 3}, seed=7)
    assert cfg.optim.restarts == 3 and cfg.seed == 7 and cfg.optim.steps == test.optim.steps


@pytest.mark.parametrize("overrides, field", [
    ({"optim": {"restarts": 0}}, "optim.restarts"),
    ({"contact_ratio": 1.5}, "contact_ratio"),
    ({"bogus": 1}, "bogus"),
    ({"penetration": "sometimes"}, "penetration"),
])
def test_bad_options_raise_config_error_naming_the_field(overrides, field):
    with pytest.raises(ConfigError) as err:
        AlignConfig.from_preset("default", **overrides)
    assert err.value.code == "invalid_option" and err.value.field == field


def test_unknown_preset():
    with pytest.raises(ConfigError, match="unknown preset"):
        AlignConfig.from_preset("fastest")


def test_quaternion_matrix_round_trip_and_orthonormal():
    q = pose.random_quaternions(16, torch.Generator().manual_seed(1))
    m = pose.quaternion_to_matrix(q)
    eye = torch.eye(3).expand(16, 3, 3)
    torch.testing.assert_close(m @ m.transpose(1, 2), eye, atol=1e-5, rtol=0)
    assert torch.allclose(torch.linalg.det(m), torch.ones(16), atol=1e-5)
    for qi, mi in zip(q, m, strict=True):
        back = pose.matrix_to_quaternion(mi.double().numpy())
        assert min(np.abs(back - qi.numpy()).max(), np.abs(back + qi.numpy()).max()) < 1e-4


def test_apply_pose_matches_pose_matrix():
    gen = torch.Generator().manual_seed(2)
    pts = torch.randn(10, 3, generator=gen)
    t, q, log_s = torch.randn(3, 3, generator=gen), torch.randn(3, 4, generator=gen), torch.randn(3, generator=gen)
    posed = pose.apply_pose(pts, t, q, log_s)
    m = pose.pose_matrix(t, q, log_s)
    expected = pts @ m[:, :3, :3].transpose(1, 2) + m[:, None, :3, 3]
    torch.testing.assert_close(posed, expected, atol=1e-5, rtol=1e-5)
