"""One order (``ordering``): the restart the progress readout, the report and the page describe is the one
``ordering.select_answer`` returns, and the encoder's shortlist and the scattered copies' spacing order through
``ordering`` (``split_shortlist``, ``spaced_key``) with the results they had before.

Runs: the ``test`` preset, generated pairs, a second or a few each."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from ctp_core import align as stages
from ctp_core import contact, export, optimise
from ctp_core.assembly import copies
from ctp_core.config import AlignConfig, schedule, share_of
from ctp_core.geometry import pose
from ctp_core.io.examples import get_example
from ctp_core.objective import Terms
from ctp_core.search import coarse_to_fine, ordering

GEOMETRY = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0})
GUIDED = AlignConfig.from_preset("test", model="random:tiny")


def _stages(target, source, prompt, config, names, events):
    """``align``'s stages one by one (``prepare`` ... ``result``): the run, its outcome and the result."""
    run = stages.prepare(target, source, prompt, config, target_name=names[0], source_name=names[1])
    starts, say = stages.score(run, stages.propose(run), on_event=events.append)
    outcome = stages.refine(run, starts, say, on_event=events.append)
    return run, outcome, stages.result(run, outcome, prompt, on_event=events.append)


def _assert_the_readout_is_the_answers(run, outcome, result, events):
    """The last refinement readout (the last phase's end) and the ``done`` event describe the restart
    ``select_answer`` returned: its index, its objective, its gap to the target; the report says the same."""
    best = outcome.best
    ends = [e for e in events if e.kind == "phase_end"]
    done = [e for e in events if e.kind == "done"]
    assert ends and len(done) == 1
    last = ends[-1]
    assert last.best_objective == pytest.approx(float(outcome.objectives[best]), abs=0.0)
    assert done[0].best_objective == result.objective == pytest.approx(last.best_objective, abs=0.0)
    gap = contact.contact_gap(run.pair, outcome.poses.select(slice(best, best + 1)))
    assert last.contact_gap == pytest.approx(float(gap[0]), abs=0.0)
    if run.scorer.guided:
        assert last.guide_match == pytest.approx(-float(outcome.terms.clip[best]), abs=0.0)
    report = export.report(result)
    assert report["extra"]["best_restart"] == best == report["alternatives"][0]["restart"]
    assert report["objective"] == pytest.approx(float(outcome.objectives[best]))
    assert last.restart == best == result.best_restart == done[0].restart
    # every refinement readout names the restart it describes
    assert all(e.restart is not None for e in events if e.stage == "refine" and e.kind in ("step", "phase_end"))


def test_the_progress_and_the_report_describe_the_answer_not_the_lowest_objective(monkeypatch):
    """Geometry only, a selection that returns the restart with the *highest* objective (a stand-in for one that
    orders by the relation first, or leaves a near-target restart out): the last readout and the report follow
    the selection, not the lowest objective (the readout used to take the objective's argmin)."""
    chosen = []

    def highest(terms, *args, **kwargs):
        chosen.append(int(terms.objective.argmax()))
        return chosen[-1]

    monkeypatch.setattr(optimise, "select_answer", highest)
    example = get_example("cup-on-table")
    events = []
    run, outcome, result = _stages(example.make_target(), example.make_source(), example.prompt, GEOMETRY,
                                   (example.target_name, example.source_name), events)
    objectives = outcome.objectives
    assert len(objectives) > 1 and outcome.best == int(objectives.argmax()) != int(objectives.argmin())
    _assert_the_readout_is_the_answers(run, outcome, result, events)
    assert events[-1].kind == "done" and events[-1].best_objective == pytest.approx(float(objectives.max()))


@pytest.mark.parametrize("name", ["cup-on-table", "apple-in-bowl"])
def test_a_guided_run_reads_out_the_selected_restart(name, monkeypatch):
    """With a guide the selection leaves soft-ICP out among the restarts that touch, so its pick is often not the
    lowest objective (``ctp example``'s pairs with ``random:tiny`` at the ``test`` preset, the guide trusted,
    are such runs); the readout, the ``done`` event and the report describe its pick whichever it is."""
    monkeypatch.setattr(ordering, "CHANCE_DECADES", -10.0)  # the gate trusts the tiny random guide
    example = get_example(name)
    events = []
    run, outcome, result = _stages(example.make_target(), example.make_source(), example.prompt, GUIDED,
                                   (example.target_name, example.source_name), events)
    assert run.scorer.guided
    _assert_the_readout_is_the_answers(run, outcome, result, events)


# -- the shortlist: ``ordering.split_shortlist`` as ``coarse_to_fine.encoder_shortlist`` chose before -----------------

def _old_encoder_shortlist(poses, terms, weights, k, distinct, share):
    """``coarse_to_fine.encoder_shortlist`` as it was written before it called ``ordering``."""
    key = ordering.rank_key(terms, weights, share=share)
    held = ordering.holding(terms)
    others = int((~held).sum())
    reserve = min(others, share_of(k, share)) if held.any() else others
    inside = [i for i in coarse_to_fine.shortlist_of(poses, key.excluding(~held), k - reserve, *distinct) if held[i]]
    rest = [i for i in coarse_to_fine.shortlist_of(poses, key.excluding(held), k - len(inside), *distinct)
            if not held[i]]
    return inside + rest


def _random_candidates(seed: int, n: int):
    g = torch.Generator().manual_seed(seed)
    t = torch.randint(0, 6, (n, 3), generator=g).float() * 0.3  # on a coarse grid: near-duplicates happen
    q = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1)
    q[torch.rand(n, generator=g) < 0.3] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    held = torch.rand(n, generator=g) < [0.0, 0.2, 0.6, 1.0][seed % 4]
    rel = torch.where(held, 0.0, 0.5)
    objective = torch.randint(0, 8, (n,), generator=g).float()  # ties happen
    terms = Terms.zeros(n).but(rel=rel, sunk=torch.where(torch.rand(n, generator=g) < 0.1, 1.0, 0.0), icp=objective,
                               objective=objective)
    return pose.Poses(t, q, torch.zeros(n)), terms


@pytest.mark.parametrize("seed", range(12))
def test_the_encoder_shortlist_orders_through_ordering_as_before(seed, monkeypatch):
    weights = schedule.phases(GEOMETRY, allow_penetration=False)[0]
    poses, terms = _random_candidates(seed, 30)
    calls = []
    split = ordering.split_shortlist
    monkeypatch.setattr(coarse_to_fine, "split_shortlist", lambda *args: calls.append(args) or split(*args))
    for k in (1, 5, 12, 40):
        for share in (0.0, 0.08, 0.5):
            want = _old_encoder_shortlist(poses, terms, weights, k, (0.5, 30.0), share)
            assert coarse_to_fine.encoder_shortlist(poses, terms, weights, k, (0.5, 30.0), share) == want
    assert len(calls) == 12  # every shortlist went through ``ordering``


# -- the copies' spacing: ``ordering.spaced_key`` as ``copies._spaced`` chose before -----------------------------

def _old_spaced(gaps: list[float], holds: list[bool]) -> int:
    """``copies._spaced``'s rule as it was written before it called ``ordering``."""
    for k, (gap, held) in enumerate(zip(gaps, holds, strict=True)):
        if held and gap >= copies.SPACING:
            return k
    held = [k for k, h in enumerate(holds) if h]
    return max(held, key=lambda k: gaps[k]) if held else 0


@pytest.mark.parametrize("seed", range(40))
def test_the_spaced_key_picks_as_the_copies_did(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 8))
    gaps = [float(g) for g in rng.choice([0.0, 0.01, 0.03, copies.SPACING, 0.2, 0.7], size=n)]  # ties, the limit
    holds = [bool(h) for h in rng.random(n) < [0.0, 0.5, 1.0][seed % 3]]
    key = ordering.spaced_key(torch.tensor(holds), torch.tensor(gaps, dtype=torch.float64), copies.SPACING)
    assert key.argmin() == _old_spaced(gaps, holds), (gaps, holds)


def _box() -> trimesh.Trimesh:
    return trimesh.creation.box(extents=(1.0, 1.0, 1.0))


def _at(x: float) -> np.ndarray:
    matrix = np.eye(4)
    matrix[0, 3] = x
    return matrix


@pytest.mark.parametrize(("alternatives", "pick"), [
    ([(0.0, True), (3.0, False), (1.02, True), (4.0, True)], 3),  # the first that holds and keeps the spacing
    ([(0.0, True), (3.0, False), (1.02, True), (1.01, True)], 2),  # none keeps it: the widest gap that holds
    ([(0.0, False), (3.0, False)], 0),  # none holds: the answer
])
def test_a_scattered_copy_takes_its_alternative_through_ordering(alternatives, pick, monkeypatch):
    """Unit boxes along +X, one earlier copy at the origin: an alternative at x keeps a gap of x - 1 diagonals
    / sqrt(3); the pick is the old rule's, and it comes from ``ordering.spaced_key``."""
    box = _box()
    out = copies.Copies(target=box, source=box, target_name="t", source_name="s", prompt=None, one_prompt=None,
                        config=GEOMETRY, arrangement="scatter", counted=None, reading=None,
                        copies=[copies.Copy("s_1", _at(0.0), "t", None, 0.0, "search")])
    result = type("Result", (), {})()
    result.alternatives = [{"source_to_target": _at(x), "relation": {"holds": held}} for x, held in alternatives]
    calls = []
    spaced = ordering.spaced_key
    monkeypatch.setattr(ordering, "spaced_key", lambda *args: calls.append(args) or spaced(*args))
    assert copies._spaced(result, out) == pick
    assert len(calls) == 1
