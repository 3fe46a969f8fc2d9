"""The one place that orders poses (``ordering``): holding and intersecting, the lexicographic key, the gate, the
share of failing poses a guide may admit, the refinement's ``improves``, the answer's selection and the
alternatives' order. Small hand-made terms; the weights are all 1 so every objective is easy to add up."""

from __future__ import annotations

import math

import pytest
import torch

from ctp_core.config import AlignConfig, share_of
from ctp_core.config.schedule import Phase
from ctp_core.contact import REACH, TOUCH
from ctp_core.objective import Terms, combine
from ctp_core.search import chance, coarse_to_fine, ordering
from ctp_core.search.ordering import CHANCE_DECADES, FULL_DECADES, LEAD_MAX, SUNK, TIE_NOISE, GuideSay, Key

WEIGHTS = Phase(index=1, steps=1, lambda_clip=1.0, lambda_icp=1.0, lambda_pen=1.0, sigma_icp=0.1, look_at_beta=0.0,
                zoom=1.0, lambda_rel=1.0)
SHARE = AlignConfig.from_preset("test").search.min_share
HELD, FAILED = 0.0, 0.5  # ``rel`` scores: the relation holds (at most ``predicates.HOLDS``), fails



def said(say: float, *, spread: float = 1.0, noise: float = 0.01) -> GuideSay:
    """A gate whose tests earned ``say`` (0 to 1): both p-values at the evidence that gives it."""
    p = 1.0 if say <= 0 else 10 ** -(CHANCE_DECADES + say * FULL_DECADES)
    return GuideSay(spread, noise, spread_p=p, agree_p=p, agree=0.1)

def _terms(rel, icp, clip=None, sunk=None) -> Terms:
    terms = Terms.zeros(len(rel)).but(rel=torch.tensor(rel), icp=torch.tensor(icp))
    if clip is not None:
        terms = terms.but(clip=torch.tensor(clip))
    if sunk is not None:
        terms = terms.but(sunk=torch.tensor(sunk))
    return terms.but(objective=combine(terms, WEIGHTS))


def test_holding_needs_the_relation_and_no_intersection():
    terms = _terms([HELD, HELD, FAILED, FAILED], [0.0] * 4, sunk=[0.0, 2 * SUNK, 0.0, 2 * SUNK])
    assert ordering.intersecting(terms).tolist() == [False, True, False, True]
    assert ordering.holding(terms).tolist() == [True, False, False, False]
    at_the_limit = terms.but(sunk=torch.full((4,), SUNK))  # "past SUNK" intersects, SUNK itself does not
    assert not ordering.intersecting(at_the_limit).any()
    bare = Terms.zeros(2)  # no relation, no penetration: every pose holds
    assert ordering.holding(bare).tolist() == [True, True] and not ordering.intersecting(bare).any()


def test_the_key_orders_by_tier_then_value_and_inf_excludes():
    key = Key(torch.tensor([1, 0, 0, 1]), torch.tensor([-5.0, 3.0, 1.0, 0.0], dtype=torch.float64))
    assert key.argsort().tolist() == [2, 1, 0, 3]  # a tier-0 pose with a worse value beats a tier-1 one
    assert key.argmin() == 2
    excluded = key.excluding(torch.tensor([False, False, True, False]))
    assert excluded.argsort().tolist() == [1, 0, 3, 2] and excluded.finite().tolist() == [True, True, False, True]
    assert key.first(3).argsort().tolist()[0] == 3  # -inf ahead of every tier
    assert key.select([3, 0]).value.tolist() == [0.0, -5.0]
    both = Key.cat([key.select([0]), Key.plain(torch.tensor([7.0]))])
    assert both.tier.tolist() == [1, 0] and both.argsort().tolist() == [1, 0]


def test_the_key_orders_as_the_packed_float_keys_did():
    """The old keys were ``value + 1e6 x tier`` in float64; for values far below 1e6 the order is the same."""
    generator = torch.Generator().manual_seed(0)
    value = (torch.rand(500, generator=generator, dtype=torch.float64) - 0.5) * 100
    tier = torch.randint(0, 3, (500,), generator=generator)
    value[::37] = torch.inf  # excluded poses tie after every finite one, whatever their tier
    packed = value + 1e6 * tier.double()
    assert Key(tier, value).argsort().tolist() == torch.argsort(packed, stable=True).tolist()


def test_averaged_stages_add_their_tiers():
    fine = Key(torch.tensor([0, 1, 0]), torch.tensor([1.0, -9.0, 2.0], dtype=torch.float64))
    coarse = Key(torch.tensor([0, 1, 1]), torch.tensor([3.0, -9.0, -9.0], dtype=torch.float64))
    both = fine.average(coarse)
    assert both.tier.tolist() == [0, 2, 1] and both.value.tolist() == [2.0, -9.0, -3.5]
    assert both.argsort().tolist() == [0, 2, 1]  # outside the pool in one stage: after those in it in both


def test_without_a_guide_a_holding_pose_beats_a_failing_one_with_a_better_objective():
    terms = _terms([FAILED, HELD, HELD], [-10.0, 2.0, 1.0])  # the failing pose's objective is the best by far
    key = ordering.rank_key(terms, WEIGHTS, share=SHARE)
    assert key.tier.tolist() == [1, 0, 0] and key.argsort().tolist() == [2, 1, 0]
    # a guided key with a gate of override 0 ranks as the geometry does
    silent = ordering.search_key(terms, WEIGHTS, said(0.0), guided=True, share=SHARE)
    assert silent.argsort().tolist() == [2, 1, 0]


@pytest.mark.parametrize(("decades", "lead", "amount", "chooser"), [
    (1.0, 0.0, 0.0, "geometry"), (2.0, 0.0, 0.0, "geometry"), (2.5, 0.0, 0.5, "both"), (3.0, 0.0, 1.0, "guide"),
    (4.0, 0.0, 1.0, "guide"), (3.0, 0.5, 0.5, "both"), (3.0, 1.0, 0.0, "geometry"), (3.5, 5.0, 0.5, "both")])
def test_the_say_grows_past_chance_once_in_100_and_a_sure_geometry_asks_for_more(decades, lead, amount, chooser):
    """Evidence against chance in decades (-log10 p): none until chance's one run in 100, the full say a decade
    past it; each unit of the geometry's lead (at most ``LEAD_MAX``) asks for one more decade."""
    p = 10 ** -decades
    say = GuideSay(spread=0.1, noise=0.01, spread_p=p, agree_p=p, agree=0.1, lead=lead)
    assert say.amount == pytest.approx(amount, abs=1e-6) and say.chooser == chooser
    assert say.tie == pytest.approx(TIE_NOISE * 0.01)
    said = say.to_dict()
    assert said["chose"] == chooser and said["agree_p"] == p and said["lead"] == lead


def test_the_weaker_test_decides_and_says_what_chance_gives_it():
    spread_only = GuideSay(spread=0.1, noise=0.01, spread_p=1e-4, agree_p=0.25, agree=0.31)
    assert spread_only.amount == 0.0  # a consistent function of the image, views that agree by chance: no say
    assert "one time in 4" in spread_only.summary() and spread_only.summary().endswith("no say, the geometry chose")
    assert GuideSay(spread=0.1, noise=0.01, spread_p=0.3, agree_p=1e-4, agree=0.0).amount == 0.0
    few = GuideSay(spread=0.1, noise=0.01, spread_p=1e-4, agree_p=1.0)  # too few poses hold to test the agreement
    assert few.amount == 0.0 and "too few choices hold" in few.summary()
    sure = GuideSay(spread=0.1, noise=0.01, spread_p=1e-5, agree_p=1e-4, agree=0.0, lead=0.4)
    assert "less than one time in 10,000" in sure.summary() and "leads by 0.4" in sure.summary()


def test_a_gate_without_measurable_noise_trusts_the_guide():
    say = GuideSay(spread=0.1, noise=0.0)
    assert say.ratio == math.inf and say.amount == 1.0 and say.chooser == "guide"
    assert "no measurable noise" in say.summary()


@pytest.mark.parametrize("say", [1.0, 0.5, 0.1])
def test_a_guide_admits_a_share_of_the_failing_poses_it_likes_best(say):
    """``ceil(override x share x others)`` of the poses where the relation fails join the pool, the guide's best
    among them; the rest rank after every pooled pose."""
    failing = 25
    clip = [-0.5, -0.4] + [-0.9 + 0.01 * i for i in range(failing)]  # the guide prefers the failing ones
    terms = _terms([HELD] * 2 + [FAILED] * failing, [0.0] * (2 + failing), clip)
    say = said(say, noise=1.0)
    key = ordering.search_key(terms, WEIGHTS, say, guided=True, share=SHARE)
    admitted = share_of(failing, say.amount * SHARE)
    assert admitted == math.ceil(say.amount * SHARE * failing) >= 1
    assert int((key.tier == 0).sum()) == 2 + admitted
    pooled = key.argsort().tolist()[: 2 + admitted]
    assert sorted(pooled) == [0, 1, *range(2, 2 + admitted)]  # the guide's best failing ones, by index here
    assert pooled[:admitted] == list(range(2, 2 + admitted))  # and they rank by the guide among the pool


def test_the_share_keeps_at_least_one_of_a_non_empty_count():
    assert share_of(0, 0.08) == 0 and share_of(1, 0.08) == 1 and share_of(25, 0.08) == 2 and share_of(5, 1.0) == 5


def test_the_tie_lets_the_usual_arrangement_break_only_what_the_guide_cannot_tell():
    terms = _terms([HELD, HELD], [0.0, 0.0], clip=[-0.997, -0.993])
    terms = terms.but(prefer=torch.tensor([0.9, 0.2]))  # the guide's favourite is the less usual arrangement
    sure, unsure = said(1.0, spread=0.02, noise=5e-4), said(1 / 3, spread=0.02, noise=0.01)
    assert ordering.search_key(terms, WEIGHTS, sure, guided=True, share=SHARE).argsort().tolist() == [0, 1]
    assert ordering.search_key(terms, WEIGHTS, unsure, guided=True, share=SHARE).argsort().tolist() == [1, 0]


def test_improves_puts_the_relation_before_the_objective():
    best = _terms([FAILED, HELD, HELD, FAILED], [0.0, 0.0, 0.0, 0.0])
    now = _terms([HELD, FAILED, HELD, FAILED], [5.0, -5.0, -1.0, -1.0])
    # holds now, failed before (worse objective): yes; fails now, held before (better objective): no;
    # both hold: the lower objective; both fail: the lower objective
    assert ordering.improves(now, best).tolist() == [True, False, True, True]
    sunk = now.but(sunk=torch.tensor([2 * SUNK, 0.0, 0.0, 0.0]))  # intersecting: not holding
    assert ordering.improves(sunk, best).tolist() == [False, False, True, True]


def test_the_selection_without_a_guide_takes_the_best_holding_near_pose():
    terms = _terms([FAILED, HELD, HELD], [-10.0, 1.0, 2.0])
    clear, limit = torch.tensor([0.0, 0.0, 0.0]), torch.full((3,), TOUCH)
    assert ordering.select_answer(terms, clear, limit, WEIGHTS, guided=False, touches=True, share=SHARE) == 1
    away = torch.tensor([0.0, REACH + 1.0, 0.0])  # the best holding pose drifted off: the next one
    assert ordering.select_answer(terms, away, limit, WEIGHTS, guided=False, touches=True, share=SHARE) == 2


def test_the_guided_selection_leaves_soft_icp_out_unless_the_gate_says_the_guide_has_no_signal():
    terms = _terms([HELD, HELD], [0.5, 0.0], clip=[-0.9, -0.8])  # the guide's favourite has worse soft-ICP
    clear, limit = torch.zeros(2), torch.full((2,), TOUCH)
    rule = {"touches": True, "share": SHARE}
    assert ordering.select_answer(terms, clear, limit, WEIGHTS, guided=True, **rule) == 0  # gate None: trusted
    assert ordering.select_answer(terms, clear, limit, WEIGHTS, guided=True, say=GuideSay(1.0, 0.01), **rule) == 0
    silent = said(0.0)  # override 0: the geometry alone, as without a guide
    assert ordering.select_answer(terms, clear, limit, WEIGHTS, guided=True, say=silent, **rule) == 1
    assert ordering.select_answer(terms, clear, limit, WEIGHTS, guided=False, **rule) == 1


def test_the_guided_selection_admits_a_failing_restart_only_by_the_share():
    """One failing restart the guide likes best, two holding ones: admitted (the share keeps at least one) where
    the guide is trusted, and then it still pays its weighted relation term in the objective."""
    terms = _terms([FAILED, HELD, HELD], [0.0, 0.0, 0.0], clip=[-2.0, -0.9, -0.8])
    clear, limit = torch.zeros(3), torch.full((3,), TOUCH)
    rule = {"guided": True, "touches": True, "share": SHARE}
    assert ordering.select_answer(terms, clear, limit, WEIGHTS, **rule) == 0  # -2 + 0.5 beats -0.9
    terms = _terms([FAILED, HELD, HELD], [0.0, 0.0, 0.0], clip=[-1.2, -0.9, -0.8])
    assert ordering.select_answer(terms, clear, limit, WEIGHTS, **rule) == 1  # -1.2 + 0.5 does not


def test_the_alternatives_put_the_answer_first_then_the_holding_ones_and_leave_out_the_far():
    terms = _terms([FAILED, HELD, HELD, FAILED, HELD], [0.0] * 5)
    objectives = torch.tensor([-3.0, 2.0, 1.0, -1.0, -9.0])
    far = torch.tensor([False, False, False, False, True])
    key = ordering.alternatives_key(terms, objectives, far, best=3)
    assert key.argsort().tolist() == [3, 2, 1, 0, 4]
    assert key.finite().tolist() == [True, True, True, False, False]  # the answer's -inf, the far pose's inf


def test_agreement_is_zero_where_the_views_share_a_favourite_and_one_half_by_chance():
    """Where each view's favourite ranks in the other views' order (0: first; the share ranked before it); tied
    scores share their middle rank."""
    same = torch.tensor([[0.0, 0.1], [1.0, 0.5], [2.0, 0.7], [3.0, 0.2]])
    assert float(chance.agreement(same)) == 0.0
    opposed = torch.tensor([[0.0, 3.0], [1.0, 2.0], [2.0, 1.0], [3.0, 0.0]])
    assert float(chance.agreement(opposed)) == 1.0
    assert float(chance.agreement(torch.ones(5, 4))) == 0.5  # a guide that cannot tell its candidates apart
    generator = torch.Generator().manual_seed(0)
    assert float(chance.agreement(torch.rand(300, 40, 3, generator=generator)).mean()) == pytest.approx(0.5, abs=0.03)
    observed, p = chance.agreement_chance(same[:2])
    assert observed is None and float(p) == 1.0 and float(chance.agreement_chance(same[:, :1])[1]) == 1.0


def test_full_agreement_has_its_exact_chance_and_a_sure_geometry_yields_to_a_guide_every_view_agrees_with():
    """Every view preferring the same of N choices happens by chance once in N^(C-1) (C views): exact, where the
    permutation draws could not show less than 1 in ``DRAWS`` + 1. With the views that check the guide's choice
    (``HELD_OUT_VIEWS`` besides the one it chose by) and its 8 best, that is evidence enough for the full say over
    the surest geometry (``LEAD_MAX``), even at the price of two tables; partial agreement keeps the draws'
    estimate."""
    views = 1 + len(coarse_to_fine.HELD_OUT_VIEWS)
    generator = torch.Generator().manual_seed(3)
    order = torch.randn(coarse_to_fine.AGREE_CHOICES, 1, generator=generator)
    full = order + 1e-3 * torch.randn(coarse_to_fine.AGREE_CHOICES, views, generator=generator)
    agree, p = chance.agreement_chance(full)
    assert float(agree) == 0.0 and float(p) == pytest.approx(coarse_to_fine.AGREE_CHOICES ** -(views - 1))
    _, p = chance.either([(agree, p), (agree, p)])
    say = GuideSay(1.0, 1e-3, spread_p=1e-9, agree_p=float(p), agree=0.0, lead=LEAD_MAX + 1.0)
    assert say.needed == CHANCE_DECADES + LEAD_MAX and say.amount == 1.0
    partial = full.clone()
    partial[int(order.argmin()), 1] = partial[:, 1].max() + 1.0  # one view puts the favourite last
    agree, p = chance.agreement_chance(partial)
    assert float(agree) > 0 and float(p) >= 1 / (chance.DRAWS + 1)


@pytest.mark.parametrize("views", [2, 4, 7])
@pytest.mark.parametrize("count", [3, 5, 8, 16, 40])
def test_noise_earns_no_say_in_99_percent_of_runs_and_a_strong_guide_the_full_say(count, views):
    """Pure noise on ``count`` candidates and ``views`` views (1,000 seeded score tables per case, 10,000 in all,
    each with its own noise probes): the say is 0 in at least 99 %; a guide whose views share their order (plus
    a little noise) and whose spread is far past its probes' changes earns the full say where the test can show
    it (enough views and candidates)."""
    generator = torch.Generator().manual_seed(1000 * count + views)
    tables = torch.randn(1000, count, views, generator=generator)
    _, agree_p = chance.agreement_chance(tables, seed=count)
    changes = torch.randn(1000, 4, generator=generator) - torch.randn(1000, 4, generator=generator)
    says = [GuideSay(1.0, 1.0, spread_p=chance.spread_chance(tables[i, :, 0], changes[i]), agree_p=float(agree_p[i]))
            .amount for i in range(len(tables))]
    assert sum(say == 0 for say in says) >= 0.99 * len(says)
    order = torch.randn(count, 1, generator=generator)
    strong = order + 0.01 * torch.randn(count, views, generator=generator)
    agree, p = chance.agreement_chance(strong)
    say = GuideSay(1.0, 1e-3, spread_p=chance.spread_chance(strong[:, 0], 1e-3 * torch.randn(4, generator=generator)),
                agree_p=float(p), agree=float(agree))
    assert float(agree) == 0.0
    full = count ** -(views - 1)  # the favourites coincide by chance once in N^(C-1)
    if full > 10 ** -CHANCE_DECADES:  # two views, or 3 candidates at 4: no say
        assert say.amount == 0.0
    else:  # some say (5 candidates at 4 views), the full say a decade past it (16 at 4, 8 at 7)
        assert say.amount > 0 and (say.amount == 1.0) == (full <= 10 ** -(CHANCE_DECADES + FULL_DECADES))


def _places_and_turns(tables: int, places: int, turns: int, effect: float, generator: torch.Generator
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Pure-noise score tables as ``coarse_to_fine.agreement_views`` builds them, ``tables`` of each, at the view
    it chose by and the ``HELD_OUT_VIEWS``:
    the guide's best of ``places`` distinct places, and its best 8 of ``turns`` turns at its favourite's place by
    the first column (twelve drawn, say, some failing the relation), where each view sees each place with its own
    ``effect`` (what any encoder sees of a place: the turns at one place look alike) plus each choice's noise."""
    views = 1 + len(coarse_to_fine.HELD_OUT_VIEWS)
    place = effect * torch.randn(tables, places, views, generator=generator)
    spots = place + torch.randn(tables, places, views, generator=generator)
    here = place[:, :1] + torch.randn(tables, turns, views, generator=generator)
    best = torch.argsort(here[..., 0], dim=1)[:, :8]
    return spots, here.gather(1, best[..., None].expand(-1, -1, views))


@pytest.mark.parametrize("effect", [0.0, 3.0])
@pytest.mark.parametrize(("places", "turns"), [(1, 11), (2, 8), (3, 6), (5, 4), (8, 3)])
def test_noise_earns_no_say_on_its_places_and_turns_in_99_percent_of_runs(places, turns, effect):
    """The 10,000 tables above again for the guide's choices of place and of turn at one place (1,000 per case):
    each table tested alone and the stronger taken at the number of tables' price (``chance.either``), pure
    noise earns a say in at most 1 % of runs, whatever a place adds to every turn's score there; a guide that
    knows only the turn earns one from the turns. Mixed into one table, the turns at one place would rank
    together by chance and pass as agreement more often than 1 in 100 (why ``agreement_views`` keeps them apart)."""
    generator = torch.Generator().manual_seed(100 * places + turns + int(effect))
    spots, here = _places_and_turns(1000, places, turns, effect, generator)
    tested = [chance.agreement_chance(table, seed=places) for table in (spots, here)]
    changes = torch.randn(1000, 4, generator=generator) - torch.randn(1000, 4, generator=generator)
    says = []
    for i in range(1000):
        agree, p = chance.either([(None if a is None else a[i], q[i]) for a, q in tested])
        says.append(GuideSay(1.0, 1.0, spread_p=chance.spread_chance(spots[i, :, 0], changes[i]), agree_p=float(p),
                             agree=None if agree is None else float(agree)).amount)
    assert sum(say == 0 for say in says) >= 0.99 * len(says)
    if effect and places >= 2 and turns >= 6:
        mixed = torch.cat([spots[:, 1:], here], dim=1)
        _, p = chance.agreement_chance(mixed, seed=places)
        assert float((p <= 0.01).double().mean()) > 0.015
    known = min(turns, 8)
    knows = torch.randn(known, 1, generator=generator) + 0.01 * torch.randn(known, spots.shape[-1],
                                                                           generator=generator)
    agree, p = chance.either([chance.agreement_chance(spots[0]), chance.agreement_chance(knows)])
    say = GuideSay(1.0, 1e-3, spread_p=1e-6, agree_p=float(p), agree=None if agree is None else float(agree))
    # full agreement on N turns: chance 1 in N^6, x 2 tables: some say from 3 (``AGREE_ROWS``), the full say from 4
    assert (say.amount > 0) == (known >= coarse_to_fine.AGREE_ROWS) and (say.amount == 1.0) == (known >= 4)


def test_the_say_in_words_names_what_the_guide_decided():
    """``GuideSay.summary``: what its favourite does that the geometry's does not (``decided``), the guide's doing
    where it has a say and what it would have done where it has none; the choices it was checked on."""
    turned = "turned the hat 90 degrees to face forward"
    say = GuideSay(0.1, 0.01, spread_p=1e-6, agree_p=5e-4, agree=0.0, places=3, turns=5, drawn=4, decided=turned)
    assert say.summary().startswith("the guide turned the hat 90 degrees to face forward: views it had not seen "
                                    "agree, chance one time in 2,000")
    assert "its 3 best places and 5 turns at its favourite; 4 turns drawn for the check" in say.summary()
    none = GuideSay(0.1, 0.01, spread_p=1e-6, agree_p=0.2, agree=0.4, places=8, decided=turned)
    assert none.summary().startswith("the guide would have turned the hat") and "as well by chance one time in 5" \
        in none.summary() and none.summary().endswith("no say, the geometry chose")
    assert GuideSay(0.1, 0.01, spread_p=1e-6, agree_p=0.2).summary().startswith(
        "the guide's favourite is the geometry's")
    assert say.to_dict()["decided"] == turned and say.to_dict()["turns"] == 5


def test_the_spread_test_asks_more_than_the_noise_of_a_few_probes():
    generator = torch.Generator().manual_seed(3)
    scores = torch.randn(60, generator=generator)
    assert chance.spread_chance(scores, 0.05 * torch.randn(4, generator=generator)) < 1e-3  # spread 20x the noise
    assert chance.spread_chance(scores, torch.randn(4, generator=generator)) > 0.01  # spread as large as the noise
    assert chance.spread_chance(scores, torch.zeros(4)) == 0.0 and chance.spread_chance(scores[:1], torch.ones(4)) == 1


def test_the_geometry_leads_by_its_best_poses_gap_in_its_spreads():
    assert chance.lead(torch.tensor([0.0, 1.0, 1.0, 1.0])) == pytest.approx(2.0)  # std 0.5
    assert chance.lead(torch.tensor([0.0, 0.0, 1.0, 1.0])) == 0.0  # a tie at the top: no lead
    assert chance.lead(torch.tensor([0.0, 1.0])) == 0.0 and chance.lead(torch.zeros(5)) == 0.0


def test_between_the_says_ends_the_guide_and_the_usual_arrangement_count_in_their_spreads():
    """``GuideSay.weigh``: with a say of 0.25 the guide must beat the usual arrangement by three of its spreads per
    spread of the arrangement (weights override : 1 - override); at the ends, and where either does not vary,
    ``tie``; never less than ``tie``."""
    guide = torch.tensor([0.0, 1.0, 2.0, 3.0]) * 0.01  # the guide prefers pose 0
    prefer = torch.tensor([3.0, 2.0, 1.0, 0.0]) * 0.75  # the usual arrangement pose 3 (already x (1 - 0.25))
    quarter = said(0.25, spread=7e-4, noise=4e-4)  # tie 0.0016
    assert quarter.amount == pytest.approx(0.25)
    weight = quarter.weigh(guide, prefer)
    assert weight > quarter.tie and int(torch.argmin(guide + weight * prefer)) == 3  # the arrangement's pick
    assert float((weight * prefer).std()) / float(guide.std()) == pytest.approx(3.0)
    assert int(torch.argmin(guide + quarter.tie * prefer)) == 0  # the tie alone would leave the guide's
    three_quarters = said(0.75, spread=1.3e-3, noise=4e-4)  #: a third of a spread per spread
    assert float((three_quarters.weigh(guide, prefer / 3) * prefer / 3).std()) / float(guide.std()) == \
        pytest.approx(1 / 3)
    full = GuideSay(spread=1.0, noise=0.01)
    assert full.weigh(guide, prefer) == full.tie and quarter.weigh(guide, torch.zeros(4)) == quarter.tie
