"""Adam with cosine warm restarts, written out for the optimiser's few pose tensors.

The update is ``torch.optim.Adam``'s (its defaults: betas (0.9, 0.999), eps 1e-8, no weight decay) as its
single-tensor CPU path computes it, operation for operation, and the learning rate follows
``torch.optim.lr_scheduler.CosineAnnealingWarmRestarts`` (eta_min 0): on the CPU the poses come out bit for bit
the same. Why not torch.optim itself: its first optimiser in a process imports ``torch._dynamo`` (two to five
seconds on the reference machine) for nothing three small tensors need, and a command-line placement pays that
in every process.
"""

from __future__ import annotations

import math

import torch

BETAS = (0.9, 0.999)
EPS = 1e-8


class Adam:
    """Adam over parameter groups of one tensor and one base learning rate each, the rate on a cosine schedule
    with warm restarts (first period ``t0`` steps, each next ``t_mult`` times longer)."""

    def __init__(self, groups: list[tuple[torch.Tensor, float]], t0: int, t_mult: int = 1):
        self.params = [p for p, _ in groups]
        self.base_lrs = [float(lr) for _, lr in groups]
        self.lrs = list(self.base_lrs)  # each group's current rate
        self._steps = [0] * len(groups)
        self._exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self._exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self._t_i, self._t_cur, self._t_mult = t0, 0, t_mult

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update of every parameter that has a gradient, at the current rates."""
        beta1, beta2 = BETAS
        for i, param in enumerate(self.params):
            grad = param.grad
            if grad is None:
                continue
            self._steps[i] += 1
            step = float(self._steps[i])
            exp_avg, exp_avg_sq = self._exp_avg[i], self._exp_avg_sq[i]
            exp_avg.lerp_(grad, 1 - beta1)
            exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            bias_correction1 = 1 - beta1**step
            bias_correction2 = 1 - beta2**step
            step_size = self.lrs[i] / bias_correction1
            denom = (exp_avg_sq.sqrt() / bias_correction2**0.5).add_(EPS)
            param.addcdiv_(exp_avg, denom, value=-step_size)

    def schedule(self) -> None:
        """Advance the cosine schedule by one step (after ``step``)."""
        self._t_cur += 1
        if self._t_cur >= self._t_i:
            self._t_cur = self._t_cur % self._t_i
            self._t_i = self._t_i * self._t_mult
        cosine = 1 + math.cos(math.pi * self._t_cur / self._t_i)
        self.lrs = [base * cosine / 2 for base in self.base_lrs]
