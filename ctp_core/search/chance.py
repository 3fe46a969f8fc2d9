"""What chance gives a guide on this run's own candidates: the tests behind the guide's say (``ordering.GuideSay``).

A guide earns a say over where the source goes only by showing, on the candidates the search scored, something
noise would not show there. Two statistics, each with a per-run null (no extra encode for the null itself):

- **agreement** (``agreement``): where each view's favourite ranks in every other view's order, as the share of the
  candidates that view ranks before it, averaged over the ordered pairs of views (0: every view prefers the same
  pose; 0.5 by chance). Its null (``agreement_chance``) is a permutation test: each view's scores shuffled across
  the candidates independently, ``DRAWS`` times, vectorised; the p-value is the share of shuffles that agree at
  least as well (with the observed one counted, so never below 1 / (``DRAWS`` + 1)), but for full agreement, whose
  chance is exact. Two views' favourites can at best coincide, which chance does once in N: the search checks the
  guide's choice from six views it has not seen (``coarse_to_fine.agreement_views``), where full agreement over N
  choices is chance once in N^6; its places and its turns at one place in two tables (the turns at one place look
  alike to any encoder: mixed with places they would rank together by chance), the stronger counted at the price
  of both (``either``).
- **spread** (``spread_chance``): the scores' variance over the candidates against the variance of their noise
  (half the mean square of the probes' changes, ``coarse_to_fine.guide_noise``), an F test with (N - 1, probes)
  degrees of freedom: how often noise alone would spread the candidates as far.

The **geometry's lead** (``lead``) is how far the usual arrangement's best pose stands ahead of the next, in
units of its own spread over the poses that hold: the say asks a guide for one more decade of evidence per unit
(``GuideSay.needed``) before it overrules a geometry that is sure.
"""

from __future__ import annotations

import math

import torch

DRAWS = 9999  # ``agreement_chance``: tables of the permutation null (p-values from 1e-4; 16 ms at 8 x 5, one thread)
AGREE_MIN = 3  # ``agreement``: fewer candidates than this tell nothing (chance gives any order of two)


def agreement(views: torch.Tensor) -> torch.Tensor:
    """(...,) where each view's favourite ranks in each other view's order (0: its best too, 0.5 by chance, 1: its
    worst), averaged over the ordered pairs of views. ``views``: (..., N, C) a guide's term per candidate and view,
    lower is better; N >= 2 and C >= 2. Tied scores share their middle rank (a view that cannot tell its
    candidates apart agrees as chance does, not perfectly)."""
    below = views.unsqueeze(-3) < views.unsqueeze(-2)  # [..., i, j, c]: candidate j before i in view c
    level = views.unsqueeze(-3) == views.unsqueeze(-2)
    ranks = below.sum(dim=-2).double() + 0.5 * (level.sum(dim=-2).double() - 1)
    return _favourites(ranks)


def _favourites(ranks: torch.Tensor) -> torch.Tensor:
    """``agreement`` of (..., N, C) ranks per view (0 the best)."""
    count, sides = ranks.shape[-2:]
    favourite = ranks.argmin(dim=-2)  # (..., C): each view's favourite
    # at[..., a, b]: view b's rank of view a's favourite
    at = ranks.gather(-2, favourite.unsqueeze(-1).expand(*favourite.shape, sides))
    others = ~torch.eye(sides, dtype=torch.bool, device=ranks.device)
    return at[..., others].double().mean(dim=-1) / (count - 1)


def agreement_chance(views: torch.Tensor, *, seed: int = 0, draws: int = DRAWS
                     ) -> tuple[torch.Tensor | None, torch.Tensor]:
    """(the observed ``agreement``, its p-value under the permutation null), each (...,) for ``views`` (..., N, C):
    the share of ``draws`` tables whose every view orders the candidates at random that agree at least as well,
    the observed one counted among them (never below 1 / (``draws`` + 1)); full agreement's exact chance,
    N^-(C-1), where every view prefers the same candidate. The null depends on N and C only, so
    one is drawn for a whole batch of tables. (None, 1) with fewer than ``AGREE_MIN`` candidates or one view:
    nothing to test, no evidence."""
    count, sides = views.shape[-2:]
    if count < AGREE_MIN or sides < 2:
        return None, torch.ones(views.shape[:-2], dtype=torch.float64)
    observed = agreement(views.double().cpu())
    generator = torch.Generator().manual_seed(seed)
    null = _favourites(torch.argsort(torch.rand(draws, count, sides, generator=generator), dim=1))
    at_least = (null <= observed.unsqueeze(-1) + 1e-12).sum(dim=-1)
    # full agreement (every view's favourite the same) has an exact chance, N^-(C-1), far below what the draws
    # can resolve with six views or more
    full = torch.full_like(observed, float(count) ** -(sides - 1))
    return observed, torch.where(observed <= 1e-12, full, (1 + at_least).double() / (draws + 1))


def either(tests: list[tuple[torch.Tensor | None, torch.Tensor]]) -> tuple[torch.Tensor | None, torch.Tensor]:
    """The stronger of ``agreement_chance``'s results on separate tables (a guide's places and its turns at one
    place), its p-value times the number of tables tested (Bonferroni: noise passes any of k tests at level a at
    most k x a of the time); (None, 1) where none was."""
    tested = [(agree, p) for agree, p in tests if agree is not None]
    if not tested:
        return None, torch.ones((), dtype=torch.float64)
    agree, p = min(tested, key=lambda test: float(test[1]))
    return agree, (p * len(tested)).clamp(max=1.0)


def spread_chance(scores: torch.Tensor, changes: torch.Tensor) -> float:
    """The p-value of the scores' spread over the candidates if they were noise as large as the probes show:
    ``changes`` (P,) are the differences of P candidates' scores when moved by a negligible amount, each the
    difference of two noise draws (variance twice the noise's), so sum(changes^2) / 2 estimates the noise's
    variance with P degrees of freedom and var(scores) / that is F(N - 1, P) distributed under noise. 1.0 with
    fewer than two candidates or no probe; 0.0 where the probes show no noise at all and the scores spread."""
    scores, changes = scores.double().cpu(), changes.double().cpu()
    if len(scores) < 2 or not len(changes):
        return 1.0
    spread, noise = float(scores.var()), float(changes.square().mean()) / 2
    if noise <= 0:
        return 0.0 if spread > 0 else 1.0
    # imported here: scipy.stats takes seconds to import, and a run without a guide never asks
    from scipy import stats

    return float(stats.f.sf(spread / noise, len(scores) - 1, len(changes)))


def lead(values: torch.Tensor) -> float:
    """How far the best (lowest) of ``values`` stands ahead of the next, in units of their standard deviation; 0
    with fewer than three values or none spread (two values are always one standard deviation and a half apart:
    no lead can show)."""
    values = values.double().cpu()
    if len(values) < 3 or float(values.std()) <= 0:
        return 0.0
    first, second = torch.topk(values, 2, largest=False).values.tolist()
    return (second - first) / float(values.std())


def decades(p: float) -> float:
    """-log10(p): the evidence a p-value carries, in decades (inf at 0)."""
    return math.inf if p <= 0 else -math.log10(p)


def odds(p: float) -> str:
    """A p-value in words a user reads: "one time in 4", "less than one time in 10,000", "more often than not"."""
    if p <= 1 / (DRAWS + 1):
        return f"less than one time in {DRAWS + 1:,}"
    return "more often than not" if p >= 0.5 else f"one time in {round(1 / p):,}"
