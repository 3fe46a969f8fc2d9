"""The one place that orders poses: which pose beats which, in the search, the guide's shortlist, the refinement,
the selection, the alternatives and the scattered copies.

Every order is lexicographic (``Key``): first the *tier*, then the *value* (lower is better in both).

- The tier is the prompt's relation: the poses where it holds and nothing intersects (``holding``) come first.
  With a guide, the guide's favourites among the others (``ceil(amount x share x others)``: ``rank_key``)
  join them, so a misread prompt cannot make the right answer unreachable.
- The value is the guide's term where the guide has earned a say (``GuideSay``: its spread over the search's
  candidates against its noise, and whether views it has not seen agree with its choice, each against what
  chance gives on them: ``chance``), plus the usual arrangement as far as the guide's say leaves it
  (``GuideSay.weigh``); otherwise the geometric objective.

The say is measured once, by the search (``coarse_to_fine.search`` returns it in ``Ranked.say``), and handed to every
later order as an argument: the refinement's scorer (``objective.Scorer.with_say``), the selection
(``select_answer``) and the report. ``improves`` is the refinement's order between a restart's new pose and its
best so far; ``alternatives_key`` the order of the placements a person picks among.

The answer is the restart ``select_answer`` returns, the only function that decides it: not always the lowest
objective (the relation orders first, a restart far from the target is left out, and with a guide soft-ICP does
not count among the restarts that touch). The optimiser's progress readout (``optimise.Optimiser.answer``), the
report's ``best_restart`` and the first alternative are that restart. ``split_shortlist`` is the order of the
candidates the guide sees (``coarse_to_fine.encoder_shortlist``), ``spaced_key`` that of the placements a scattered copy
takes the first of (``assembly.copies``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from ctp_core.config import share_of
from ctp_core.config.schedule import Phase
from ctp_core.contact import REACH
from ctp_core.objective import Terms, combine, geometric_objective
from ctp_core.relations import predicates
from ctp_core.search import chance

CHANCE_DECADES = 2.0  # ``GuideSay``: evidence (-log10 p) a guide's tests must pass for any say: noise does once in 100
FULL_DECADES = 1.0  # ... and this many decades past it for the full say
LEAD_MAX = 1.0  # ... plus one decade per unit of the geometry's lead, at most this many
TIE_NOISE = 4.0  # ``GuideSay.tie``: the usual arrangement's unit where the guide orders, in the guide's noises
SUNK = 0.01  # source diagonals of penetration (``sunk``) past which a pose intersects: a sphere pressed into a
# plane by a tenth of its diagonal (forward and enclosed halves ~ depth^2 / radius / 2 each side summed)


@dataclass(frozen=True)
class Key:
    """(B,) lexicographic sort keys: ``tier`` (int64) first, then ``value`` (float64); lower is better.

    A value of +inf excludes a pose whatever its tier (after every finite key); -inf puts it first whatever its
    tier (the alternatives' answer). Sorting is stable: equal keys keep their index order."""

    tier: torch.Tensor
    value: torch.Tensor

    @staticmethod
    def plain(value: torch.Tensor) -> Key:
        """One tier: ``value`` alone orders (a stage without a relation, a list in a given order)."""
        return Key(torch.zeros(value.shape, dtype=torch.int64, device=value.device), value.double())

    @staticmethod
    def cat(keys: list[Key]) -> Key:
        return Key(torch.cat([k.tier.cpu() for k in keys]), torch.cat([k.value.cpu() for k in keys]))

    def __len__(self) -> int:
        return len(self.value)

    def select(self, index: torch.Tensor | list[int] | slice) -> Key:
        return Key(self.tier[index], self.value[index])

    def excluding(self, mask: torch.Tensor) -> Key:
        """These keys with ``mask``'s poses excluded (value +inf)."""
        mask = mask.to(self.value.device)
        return Key(self.tier, torch.where(mask, torch.full_like(self.value, torch.inf), self.value))

    def first(self, index: int) -> Key:
        """These keys with pose ``index`` ahead of every other (value -inf)."""
        value = self.value.clone()
        value[index] = -torch.inf
        return Key(self.tier, value)

    def average(self, other: Key) -> Key:
        """Two stages' keys of the same poses ranked together: the values' mean, the tiers' sum (a pose outside
        the pool in one stage ranks after those in neither and before those outside it in both)."""
        return Key(self.tier.cpu() + other.tier.cpu(), 0.5 * (self.value.cpu() + other.value.cpu()))

    def finite(self) -> torch.Tensor:
        """(B,) bool: the poses not excluded."""
        return torch.isfinite(self.value)

    def argsort(self) -> torch.Tensor:
        """(B,) indices, best first."""
        infinite = torch.isinf(self.value)
        # +-inf values rank outside every tier (as they are: excluded or first), finite ones by their tier
        rank = torch.where(infinite, torch.where(self.value > 0, 1, -1) * (1 << 62), self.tier.to(torch.int64))
        by_value = torch.argsort(self.value, stable=True)
        return by_value[torch.argsort(rank[by_value], stable=True)]

    def argmin(self) -> int:
        return int(self.argsort()[0])


@dataclass(frozen=True)
class GuideSay:
    """How far a guide may override the relation and the usual arrangement, earned in each run by showing on the
    search's own candidates what noise would not show there (``coarse_to_fine.guide_noise``; the tests in
    ``chance``):

    - spread (``spread_p``): its scores' spread over the candidates against its noise (the changes of a few
      candidates' scores when moved by a negligible amount), an F test;
    - agreement (``agree_p``): where each view's favourite among its choices that hold (its best places, and its
      turns at its favourite's place: two tables, the stronger at the price of both) ranks in the other views'
      orders (``agree``), against the same views' scores shuffled; a consistent function of the image passes the
      first test, noise included (a random encoder is one); only a guide that sees where and how the source
      belongs agrees with itself from other sides.

    The evidence is the weaker test's, in decades (-log10 p): the say is 0 until it passes ``CHANCE_DECADES``
    (noise does one run in 100) plus the geometry's ``lead`` (its best pose's lead in its own spread units, at most
    ``LEAD_MAX``: a sure geometry asks for more), and full ``FULL_DECADES`` past that.
    """

    spread: float
    noise: float
    spread_p: float = 0.0
    agree_p: float = 0.0
    agree: float | None = None
    lead: float = 0.0
    # the guide's choices the agreement was checked on (``coarse_to_fine.agreement_views``): its distinct places,
    # the turns (and sizes) at its favourite's place besides it, and the turns drawn (and scored) for the check
    places: int = 0
    turns: int = 0
    drawn: int = 0
    decided: str = ""  # what its favourite does that the geometry's does not ("turned the hat 90 degrees"); "": none

    @property
    def ratio(self) -> float:
        return self.spread / self.noise if self.noise > 0 else math.inf

    @property
    def evidence(self) -> float:
        """The weaker test's evidence against chance, in decades."""
        return min(chance.decades(self.spread_p), chance.decades(self.agree_p))

    @property
    def needed(self) -> float:
        """The evidence that starts a say: chance's one run in 100, one more decade per unit of the geometry's
        lead."""
        return CHANCE_DECADES + min(self.lead, LEAD_MAX)

    @property
    def amount(self) -> float:
        return float(min(1.0, max(0.0, (self.evidence - self.needed) / FULL_DECADES)))

    @property
    def tie(self) -> float:
        """What one unit of ``prefer`` is worth where the guide orders (``rank_key``, ``select_answer``): a
        difference of the guide's term well past its noise (``TIE_NOISE`` x the noise)."""
        return TIE_NOISE * self.noise

    def weigh(self, guide: torch.Tensor, prefer: torch.Tensor) -> float:
        """What one unit of ``prefer`` (the usual arrangement, already x (1 - amount): ``Scorer.preference_weight``)
        is worth against the ``guide``'s term where the guide orders these poses: between the say's ends the two
        count in units of their own spread over them, weighted amount : 1 - amount (a guide with a say of
        0.25 must beat the usual arrangement by three of its spreads per spread of the arrangement); never less
        than ``tie``, which breaks what the guide cannot tell (at amount 1 ``prefer`` is 0 and counts nothing)."""
        spreads = [float(x.double().std()) if len(x) > 1 else 0.0 for x in (guide, prefer)]
        if not 0 < self.amount < 1 or min(spreads) <= 0:
            return self.tie
        return max(self.tie, spreads[0] * (1 - self.amount) / (self.amount * spreads[1]))

    @property
    def chooser(self) -> str:
        """Who orders the poses where the relation holds: ``geometry`` (amount 0: the usual arrangement),
        ``guide`` (amount 1: the usual arrangement only breaks its ties) or ``both`` (between: the usual
        arrangement weighs 1 - amount, ``Scorer.preference_weight``)."""
        return "geometry" if self.amount <= 0 else "guide" if self.amount >= 1 else "both"

    def summary(self) -> str:
        """The say in one line, for the progress readout, the report and the page: what the guide decided (or would
        have), what chance gives each test in words, the geometry's lead, who chose."""
        if not self.decided:
            choice = "the guide's favourite is the geometry's"
        else:
            choice = f"the guide {'' if self.amount > 0 else 'would have '}{self.decided}"
        among = f"its {self.places} best place{'s' if self.places != 1 else ''}" + (
            f" and {self.turns} turn{'s' if self.turns != 1 else ''} at its favourite" if self.turns else "") + (
            f"; {self.drawn} turns drawn for the check" if self.drawn else "")
        agree = ("too few choices hold for views it has not seen to check it" if self.agree is None else
                 f"views it had not seen agree{', chance' if self.amount > 0 else ' as well by chance'} "
                 f"{chance.odds(self.agree_p)} (each favourite {self.agree:.0%} down the others' orders, 50% by "
                 f"chance; {among})")
        spread = (f"its spread {self.ratio:.1f}x its noise, chance {chance.odds(self.spread_p)}"
                  if self.noise > 0 else "its scores have no measurable noise")
        lead = f"; the geometry's best leads by {self.lead:.1f} of its spreads" if self.lead >= 0.05 else ""
        return f"{choice}: {agree}; {spread}{lead}" + {
            "geometry": ": no say, the geometry chose", "guide": ": the guide chose",
            "both": f": the guide chose, the usual arrangement weighing {1 - self.amount:.2f}"}[self.chooser]

    def to_dict(self) -> dict[str, float | str | None]:
        return {"spread": self.spread, "noise": self.noise, "spread_p": self.spread_p, "agree": self.agree,
                "agree_p": self.agree_p, "places": self.places, "turns": self.turns,
                "drawn": self.drawn, "decided": self.decided, "lead": round(self.lead, 3),
                "evidence": round(min(self.evidence, 99.0), 3),
                "needed": round(self.needed, 3), "override": round(self.amount, 3), "chose": self.chooser,
                "summary": self.summary()}


TRUSTED = GuideSay(spread=1.0, noise=0.0)  # a say not measured (yet): the guide trusted fully (p 0: amount 1, tie 0)


def holding(terms: Terms) -> torch.Tensor:
    """(B,) bool: where the relation holds (``predicates.holds`` of the ``rel`` term: zero, so everywhere, without
    a relation), steadily where it asks that (the ``stable`` term: a report's ``valid`` asks it too), and the pose
    does not intersect the target (``sunk`` at most ``SUNK``; 0 where penetration is allowed).
    Intersecting is worse than the relation failing: without the second rule a pose pulled into the target's wall
    by a containment relation would outrank every clean pose beside it."""
    held = predicates.holds(terms.rel)
    held = held & predicates.holds(terms.stable).to(held.device)  # a figure asked to stand steadily: 0 where it does
    return held & ~intersecting(terms).to(held.device)


def intersecting(terms: Terms) -> torch.Tensor:
    """(B,) bool: where the pose is sunk into the target past ``SUNK``."""
    return terms.sunk > SUNK


def rank_key(terms: Terms, phase: Phase, *, share: float, guide_key: torch.Tensor | None = None,
             amount: float = 1.0, geometric: torch.Tensor | None = None, tie: float = 0.0) -> Key:
    """The relation first, then a value.

    Without a guide (``guide_key`` None) or with ``amount`` 0: tier 0 where the relation holds (``holding``),
    1 elsewhere; value the geometric objective (``geometric``, else ``combine`` without the guide's term). With a
    guide: tier 0 over the *pool*, the poses where the relation holds plus the ``ceil(amount x share x
    others)`` others that the guide ranks best (``share``: the search's ``min_share``, the principle of the
    region weights); value the guide's key plus ``tie`` per unit of ``prefer`` (``GuideSay.weigh``: the usual
    arrangement weighs as much as the guide's say leaves it, and breaks what the guide cannot tell).
    """
    holds = holding(terms).to(terms.objective.device)
    if guide_key is None or amount <= 0:
        if geometric is None:
            geometric = geometric_objective(terms, phase)
        return Key((~holds).long(), usual_first(geometric, terms, phase, holds))
    key = guide_key.double() + tie * terms.prefer.double()
    pool = holds.clone()
    others = torch.nonzero(~holds)[:, 0]
    admit = share_of(len(others), amount * share)
    if admit:
        pool[others[torch.argsort(key[others])[:admit]]] = True
    return Key((~pool).long(), key)


def usual_first(geometric: torch.Tensor, terms: Terms, phase: Phase, holds: torch.Tensor
                ) -> torch.Tensor:
    """(B,) float64: what orders poses where the geometry alone chooses: among those that hold (``holds``) the
    usual arrangement (``prefer``) one to one against the geometric objective in units of the relation's weight
    (``lambda_rel``); the others by the objective alone (where nothing holds, the least violation comes first, not
    the usual place). In the objective the usual arrangement weighs ``PREFER`` of the relation, which is right for
    the gradient (it must not pull a pose off the relation) but lets soft-ICP, which favours corners and edges where
    more samples fall near the source, decide among poses that all hold; ordered here, among them the usual place
    comes first and the geometry breaks what it cannot tell. Where the phase does not weigh the relation
    (``lambda_rel`` 0): the objective as it is."""
    if not phase.lambda_rel:
        return geometric.double()
    usual = geometric.double() / phase.lambda_rel + terms.prefer.to(geometric.device).double()
    return torch.where(holds.to(geometric.device), usual, geometric.double())


def search_key(terms: Terms, phase: Phase, say: GuideSay | None, *, guided: bool, share: float,
               guide_key: torch.Tensor | None = None) -> Key:
    """What the search ranks a stage's candidates by (``rank_key``): with a guide (``guided``) that ``say`` lets
    override (None: not measured yet, trusted), its term (``guide_key``: the tile stage's change); otherwise the
    geometric objective.

    Why the guide's term alone and not a weighted sum: the proposals touch without interpenetrating by
    construction, so among them the geometric terms measure how the target's samples happen to fall (soft-ICP
    at contact is about sigma² and varies with sample density), not contact; its spread over touching
    candidates can exceed the guide's by orders of magnitude, and any weighted sum would rank as geometry alone.
    The refinement and the final selection use the whole objective.
    """
    say = say or TRUSTED
    key = (terms.clip if guide_key is None else guide_key) if guided and say.amount > 0 else None
    tie = 0.0
    if key is not None:
        held = holding(terms).to(key.device)
        tie = say.weigh(key[held], terms.prefer.to(key.device)[held])
    return rank_key(terms, phase, guide_key=key, amount=say.amount, share=share, tie=tie)


def improves(now: Terms, best: Terms) -> torch.Tensor:
    """(B,) whether each restart's new pose replaces its best: the relation first (``holding``), then the lower
    objective. Without the first rule a pose that holds is traded for one where the relation fails that has a
    little less penetration, weighted more than the relation's violation."""
    held, was = holding(now), holding(best)
    return (held & ~was) | ((held == was) & (now.objective < best.objective))


def select_answer(terms: Terms, clear: torch.Tensor, limit: torch.Tensor, phase: Phase, *,
                  guided: bool, touches: bool, share: float, say: GuideSay | None = None) -> int:
    """The answer among refined poses: those within ``REACH`` of the target (any when none is: an image guide can
    prefer a source gone out of view, an absent source differing less from the goal than a misplaced one); with
    a guide, among them those that touch (``touches``: the relation's contact ratio is > 0), the lowest
    objective without its soft-ICP term (the guide's and the penetration's); otherwise, or when none touches,
    the lowest objective. The relation orders first, as in the search (``rank_key``): the restarts where it
    holds, plus, with a guide, a share of the others (``say``'s amount x ``share``, at least one when the
    amount is > 0); a ``say`` with amount 0 (a guide with no signal) selects as without a guide; None (not
    measured) trusts the guide fully. An admitted restart that fails the relation still pays its weighted
    relation term in the objective (``lambda_rel`` x its score): the guide overrides the relation at the
    selection only by more than that.

    Why not soft-ICP: at contact it measures how the samples fall, not contact, and its differences between
    touching restarts can outweigh the guide's; the search ranks its candidates by the guide the same way
    (``search_key``). Penetration likewise counts only past ``SUNK``: at contact the two halves see a few
    samples a hair inside, which times ``lambda_pen`` can outweigh the guide. The usual arrangement
    (``prefer``, already x (1 - amount): ``Scorer.preference_weight``) counts ``GuideSay.weigh`` per unit over the
    restarts that hold (as much as the guide's say leaves it, at least a difference a full say would trust),
    not its objective weight, which would outweigh any guide.
    ``clear`` and ``limit``: per pose, in source diagonals (``contact.clearance``, ``contact.touch_limit``).
    """
    say = say or TRUSTED
    amount = say.amount
    key = terms.objective
    if guided and amount <= 0:  # a guide without signal: the geometry alone
        guided, key = False, geometric_objective(terms, phase)
    clear, limit = clear.to(key.device), limit.to(key.device)
    near = clear <= REACH
    pool = near if near.any() else torch.ones_like(near)
    if guided:
        fit = pool & ((clear <= limit) | (not touches))
        if fit.any():
            # penetration counts where the pose intersects, not at contact
            pen = torch.where(intersecting(terms).to(terms.pen.device), terms.pen, torch.zeros_like(terms.pen))
            zeros = torch.zeros_like(key)
            key = combine(terms.but(icp=zeros, pen=pen, prefer=zeros), phase)
            prefer, judged = terms.prefer, fit & holding(terms).to(fit.device)
            pool, key = fit, key + say.weigh(key[judged], prefer[judged]) * prefer
    key = torch.where(pool, key.double(), torch.full_like(key, torch.inf, dtype=torch.float64))
    ranked = rank_key(terms.but(objective=key), phase, guide_key=key if guided else None,
                      amount=amount, share=share, geometric=key)
    return ranked.argmin()


def alternatives_key(terms: Terms, objectives: torch.Tensor, far: torch.Tensor, best: int) -> Key:
    """The order of the refined placements a person picks among (``align.alternatives``): the answer ``best``
    first, then those where the relation holds and nothing intersects (``holding``), then by the objective on
    the evaluation views (not the selection's own key, which leaves soft-ICP out among touching poses with a
    guide); those ``far`` from the target excluded."""
    holds = holding(terms)
    key = Key((~holds).long().cpu(), objectives.double().cpu()).excluding(far.cpu())
    return key.first(best)


def split_shortlist(terms: Terms, phase: Phase, k: int, share: float,
                    pick: Callable[[Key, int], list[int]]) -> list[int]:
    """``k`` poses chosen by the geometry alone, the relation first (the guide's shortlist,
    ``coarse_to_fine.encoder_shortlist``): ``pick(key, n)`` (up to ``n`` indices best first by ``key``; the caller's
    diversity) takes them from the poses where the relation holds (``holding``), in ``rank_key``'s geometric
    order, but for ``share_of(k, share)`` slots that go to the poses where it fails (a misread prompt must not make
    the right answer unreachable: the principle of ``rank_key``'s pool); slots one side cannot fill go to the
    other. Where it holds nowhere, every slot goes to the others. Indices ``pick`` returns from the other side
    (duplicates filling its count) are dropped."""
    key = rank_key(terms, phase, share=share)
    held = holding(terms)
    others = int((~held).sum())
    reserve = min(others, share_of(k, share)) if held.any() else others
    inside = [i for i in pick(key.excluding(~held), k - reserve) if held[i]]
    rest = [i for i in pick(key.excluding(held), k - len(inside)) if not held[i]]
    return inside + rest


def spaced_key(holds: torch.Tensor, gaps: torch.Tensor, spacing: float) -> Key:
    """The order of placements given in their own order (``AlignResult.alternatives``: the answer first) that a
    scattered copy takes the first of (``assembly.copies``): those where the relation holds (``holds``, their
    verdicts) and whose ``gaps`` to the earlier copies are at least ``spacing``, in their order; then those where
    it holds, the widest gap first; then the others in their order (the answer first)."""
    holds, gaps = holds.cpu().bool(), gaps.cpu().double()
    apart = holds & (gaps >= spacing)
    tier = torch.where(apart, 0, torch.where(holds, 1, 2)).long()
    value = torch.where(holds & ~apart, -gaps, torch.arange(len(gaps), dtype=torch.float64))
    return Key(tier, value)
