"""``optimise.Adam`` against torch.optim: the same poses bit for bit on the CPU, over schedule restarts."""

from __future__ import annotations

import torch

from ctp_core.optimise import Adam


def _loss(t: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """A bumpy objective, so the gradients change sign and size from step to step."""
    return torch.sin(3 * t).sum() + (q**2).sum() * t.norm() + (q[:, 0] - 0.3).abs().sum()


def test_adam_matches_torch_optim_bit_for_bit() -> None:
    generator = torch.Generator().manual_seed(0)
    t0, q0 = torch.randn(5, 3, generator=generator), torch.randn(5, 4, generator=generator)
    ours_t, ours_q = t0.clone().requires_grad_(True), q0.clone().requires_grad_(True)
    ref_t, ref_q = t0.clone().requires_grad_(True), q0.clone().requires_grad_(True)
    ours = Adam([(ours_t, 0.05), (ours_q, 0.2)], t0=3, t_mult=2)
    ref = torch.optim.Adam([{"params": [ref_t], "lr": 0.05}, {"params": [ref_q], "lr": 0.2}])
    sched = torch.optim.lr_scheduler.CosineAnnealingWarmRestarts(ref, T_0=3, T_mult=2)
    for _ in range(40):  # restarts at steps 3, 9, 21
        ours.zero_grad()
        ref.zero_grad(set_to_none=True)
        _loss(ours_t, ours_q).backward()
        _loss(ref_t, ref_q).backward()
        ours.step()
        ref.step()
        assert ours.lrs == [group["lr"] for group in ref.param_groups]
        ours.schedule()
        sched.step()
        assert torch.equal(ours_t, ref_t) and torch.equal(ours_q, ref_q)
    assert not torch.equal(ours_t, t0)  # it moved


def test_a_parameter_without_gradient_stays() -> None:
    moved, still = torch.ones(3, requires_grad=True), torch.ones(3, requires_grad=True)
    opt = Adam([(moved, 0.1), (still, 0.1)], t0=10)
    moved.sum().backward()
    opt.step()
    assert torch.equal(still, torch.ones(3)) and not torch.equal(moved.detach(), torch.ones(3))
