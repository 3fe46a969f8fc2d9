"""The search stage alone (``proposals``, ``coarse_to_fine``) and inside align: proposals, relation weights, the shared
scorer, cancel, counts."""

import math

import numpy as np
import pytest
import torch
import trimesh
from test_ordering import said

from ctp_core import contact, export, metrics, objective, pairs
from ctp_core.align import align, prepare, propose, refine
from ctp_core.config import AlignConfig, schedule
from ctp_core.errors import Canceled
from ctp_core.geometry import pose, sampling
from ctp_core.guide import goals
from ctp_core.guide.loaders import get_guide
from ctp_core.reading.records import RELATIONS
from ctp_core.reading.relation import RelationReading
from ctp_core.search import coarse_to_fine, ordering, proposals

CONFIG = AlignConfig.from_preset("test", model="random:tiny", search={"candidates": 40}, loss={"samples": 1500})


def _cup() -> trimesh.Trimesh:
    """An open-topped cup, one closed solid with a cavity (a cylinder minus a smaller one from the top)."""
    outer = trimesh.creation.cylinder(radius=0.5, height=0.8, sections=32)
    inner = trimesh.creation.cylinder(radius=0.4, height=0.8, sections=32)
    inner.apply_translation((0, 0, 0.1))
    cup = trimesh.boolean.difference([outer, inner], engine="manifold")
    cup.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # axis along +Y
    return cup


@pytest.fixture(scope="module")
def meshes():
    table = trimesh.creation.box(extents=(2.0, 0.2, 1.2))
    block = trimesh.creation.box(extents=(0.3, 0.2, 0.4))
    block.apply_translation((4.0, 2.0, -3.0))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    ball.apply_translation((-3.0, 1.0, 2.0))
    return {"box on table": (table, block), "ball and cup": (_cup(), ball)}


def _proposals(target, source, config=CONFIG):
    pair = pairs.prepare_pair(target, source, samples=config.loss.samples, seed=0)
    props = proposals.propose(pair, config, proposals.region_weights(None), 0.0, torch.Generator().manual_seed(0))
    return pair, props


@pytest.mark.parametrize("name", ["box on table", "ball and cup"])
def test_proposals_touch_and_do_not_penetrate(meshes, name):
    """Exact signed distances (both targets are closed): no source sample deeper than 1 % of the target's
    size, and nearly all proposals but the lateral gaps and those on the floor within 1 % of touching."""
    target, source = meshes[name]
    assert target.is_volume
    pair, props = _proposals(target, source)
    points = trimesh.sample.sample_surface(source, 300, seed=0)[0]
    size = float(target.extents.max())
    touching = 0
    for matrix, region in zip(props.poses.matrices(), props.region, strict=True):
        m = pair.source_to_target(matrix)
        depth = trimesh.proximity.signed_distance(target, points @ m[:3, :3].T + m[:3, 3]).max()  # > 0 inside
        assert depth <= 0.01 * size, (region, depth)
        if region not in ("gap", "floor"):
            touching += depth >= -0.01 * size
    contacts = sum(r not in ("gap", "floor") for r in props.region)
    assert touching >= 0.85 * contacts  # sampled distances leave a few short of contact
    assert {"top", "side", "bottom", "drop", "floor"} <= set(props.region)
    if name == "ball and cup":
        assert "inside" in props.region


@pytest.mark.parametrize("figure", [True, False])
@pytest.mark.parametrize("relation", [None, *RELATIONS])
def test_a_relation_weight_never_zeroes_a_region(relation, figure):
    role = "figure" if figure else "ground"
    weights = proposals.region_weights(None if relation is None else RelationReading.parse(relation, role))
    assert set(weights) == set(proposals.REGIONS) and min(weights.values()) >= 1.0
    available = {"top": 300, "side": 900, "bottom": 300, "inside": 40, "gap": 450, "drop": 375, "floor": 190}
    counts = proposals.allocate(available, weights, 64, CONFIG.search.min_share)
    assert all(counts[r] >= 1 for r in available)
    plain = proposals.allocate(available, proposals.region_weights(None), 64, CONFIG.search.min_share)
    assert all(counts[r] >= min(plain[r], max(1, int(CONFIG.search.min_share * plain[r]))) for r in available)


def test_the_prompt_relation_shifts_proposals_without_removing_any(meshes):
    target, source = meshes["ball and cup"]
    pair = pairs.prepare_pair(target, source, samples=CONFIG.loss.samples, seed=0)
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    plain = proposals.propose(pair, CONFIG, proposals.region_weights(None), 0.0, gen())
    inside = proposals.propose(pair, CONFIG, proposals.region_weights(RelationReading.parse("in")), 0.0, gen())
    assert inside.region.count("inside") > plain.region.count("inside")
    assert set(inside.region) == set(plain.region)


def _spire() -> trimesh.Trimesh:
    """A box with a thin cone standing on it: its tip is a tiny part of its area."""
    box = trimesh.creation.box(extents=(2.0, 1.0, 2.0))
    cone = trimesh.creation.cone(radius=0.15, height=1.0, sections=24)
    cone.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # tip along +Y
    cone.apply_translation((0.4, 0.5, -0.3))
    return trimesh.util.concatenate([box, cone])


def test_drops_reach_a_summit_that_area_sampling_misses():
    """Lowered from above onto the summits: some proposals sit on the spire's tip (the source's lowest point
    within 0.1 of it, 3 % of the target's size), though the cone's top is under 0.5 % of the surface."""
    target, source = _spire(), trimesh.creation.icosphere(subdivisions=1, radius=0.08)
    source.apply_translation((5.0, 5.0, 5.0))
    pair, props = _proposals(target, source)
    tip = pair.target_to_normalised.apply(np.array([[0.4, 1.5, -0.3]]))[0]
    peaks = sampling.summits(pair.anchor.points.numpy().astype(np.float64), 0.3)
    assert np.linalg.norm(pair.anchor.points[peaks[0]].numpy() - tip) < 0.2  # the highest summit: the cone's top
    lowest = []
    for matrix, region in zip(props.poses.matrices(), props.region, strict=True):
        if region == "drop":
            posed = pair.source_samples.numpy() @ matrix[:3, :3].T + matrix[:3, 3]
            lowest.append(posed[np.argmin(posed[:, 1])])
    near_tip = np.linalg.norm(np.array(lowest) - tip, axis=1) < 0.1  # resting on the tip (the ball's radius: 0.08)
    assert near_tip.any()


def test_floor_proposals_stand_on_the_targets_floor_beside_or_under_it(meshes):
    target, source = meshes["box on table"]
    pair, props = _proposals(target, source)
    floor = float(pair.target_vertices[:, 1].min())
    tol = 0.01 * 2 * pair.target_radius
    heights = [float((pair.source_samples.numpy() @ m[:3, :3].T + m[:3, 3])[:, 1].min())
               for m, r in zip(props.poses.matrices(), props.region, strict=True) if r == "floor"]
    assert heights and all(abs(h - floor) < tol for h in heights)  # none pushed onto the table: free as put


def test_the_callers_start_is_a_candidate_only_near_the_target(meshes):
    target, source = meshes["box on table"]
    pair = pairs.prepare_pair(target, source, samples=CONFIG.loss.samples, seed=0)
    weights = proposals.region_weights(None)
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
    near = pose.Poses(torch.tensor([[0.0, 0.4, 0.0]]), q, torch.zeros(1))
    far = pose.Poses(torch.tensor([[0.0, 40.0, 0.0]]), q, torch.zeros(1))
    with_near = proposals.propose(pair, CONFIG, weights, 0.0, torch.Generator().manual_seed(0), init=near)
    with_far = proposals.propose(pair, CONFIG, weights, 0.0, torch.Generator().manual_seed(0), init=far)
    assert with_near.region[0] == "init" and "init" not in with_far.region
    assert len(with_near.poses) == len(with_far.poses) + 1


def test_the_scorer_scores_n_candidates_then_m_restarts(meshes):
    target, source = meshes["box on table"]
    pair, props = _proposals(target, source)
    guide = get_guide("random:tiny")
    text = goals.TextGoal("a box on the table")
    text.prepare(pair, guide)
    scorer = objective.Scorer(pair, CONFIG, 0.2, guide=guide, goal=text)
    weights = schedule.phases(CONFIG, allow_penetration=False)[-1]
    many = scorer.evaluate(props.poses, weights)
    few = scorer.evaluate(props.poses.select(slice(0, 3)), weights)
    n, views = len(props.poses), CONFIG.camera.eval_views
    assert many.objective.shape == (n,) and few.objective.shape == (3,)
    torch.testing.assert_close(few.objective, many.objective[:3], atol=1e-5, rtol=0)
    assert scorer.clip_images == (n + 3) * views
    assert not few.objective.is_inference()  # usable by the optimiser outside inference mode


@pytest.mark.parametrize("zoom", [0.0, 0.5])
def test_search_counts_every_encoder_image_including_the_oracles(meshes, monkeypatch, zoom):
    monkeypatch.setattr(ordering, "CHANCE_DECADES", -10.0)  # the gate trusts the tiny random guide: every stage encodes
    config = CONFIG.model_copy(update={"search": CONFIG.search.model_copy(update={"fine_zoom": zoom})})
    target, source = meshes["box on table"]
    pair, props = _proposals(target, source, config)
    reference = np.eye(4)
    reference[:3, 3] = -source.bounds.mean(0) + (0, 0.2, 0)
    oracle = goals.ReferenceGoal(reference)
    guide = get_guide("random:tiny")
    oracle.prepare(pair, guide)
    scorer = objective.Scorer(pair, config, 0.2, guide=guide, goal=oracle)
    weights = schedule.phases(config, allow_penetration=False)[-1]
    events = []
    ranked = coarse_to_fine.search(scorer, props, weights, k=2, on_event=events.append)
    cfg = config.search
    n, fine = len(props.poses), min(cfg.fine, len(props.poses))
    assert 0 < ranked.swept <= cfg.sweep * len(props.rotations)  # every orientation at the best site(s)
    # candidates x views (coarse and sweep, the guide's noise probes), the shared coarse reference views once,
    # the places and turns its choice is checked on from the held-out views and those views' references once, the
    # turns drawn for that at the coarse views, the fine ones each
    coarse = (n + ranked.swept + min(coarse_to_fine.GATE_PROBES, n)) * cfg.coarse_views
    held_out = len(coarse_to_fine.HELD_OUT_VIEWS)
    rows = [n for n in (ranked.say.places, ranked.say.turns + 1) if n >= coarse_to_fine.AGREE_ROWS]  # tables tested
    checks = (sum(rows) + 1) * held_out + ranked.say.drawn * cfg.coarse_views  # + the drawn turns at the coarse views
    assert ranked.say.amount == 1.0 and ranked.say.places >= 3
    refs = cfg.fine_views if cfg.fine_zoom == 0 else fine * cfg.fine_views  # shared fine views without zoom
    assert scorer.clip_images == coarse + cfg.coarse_views + checks + fine * cfg.fine_views + refs
    assert ranked.scored == n + ranked.swept + fine
    assert len(ranked.poses) == 2 and ranked.objectives.argsort().tolist() == [0, 1]  # best first
    planned = n + cfg.sweep * len(props.rotations) + fine
    assert all(e.stage == "search" for e in events) and events[-1].step == events[-1].steps == planned
    assert [e.step for e in events] == sorted(e.step for e in events)


def _small_ball_on_table():
    """A big table and a ball a twentieth of its length resting on it at x = 0.5 (file frame): the reference."""
    table = trimesh.creation.box(extents=(2.0, 0.2, 1.2))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    ball.apply_translation((-3.0, 1.0, 2.0))
    reference = np.eye(4)
    reference[:3, 3] = np.array([0.5, 0.15, 0.2]) - ball.bounds.mean(0)
    return table, ball, reference


def test_tiles_only_where_the_source_is_small_and_each_frames_its_sources(meshes):
    pair, props = _proposals(*meshes["box on table"])
    assert coarse_to_fine.tiles_of(pair, CONFIG, props.poses) is None  # the block is a fifth of the table: no tiles
    table, ball, _ = _small_ball_on_table()
    pair, props = _proposals(table, ball)
    tile, centres, radius = coarse_to_fine.tiles_of(pair, CONFIG, props.poses)
    assert len(centres) > 1 and tile.shape == (len(props.poses),)
    reach = (props.poses.t - centres[tile]).norm(dim=-1) + pair.source_radius
    assert bool((reach <= radius + 1e-5).all())  # every source wholly inside its tile's framed radius


def test_tile_scores_rank_the_change_a_source_makes_in_its_tiles_views():
    """Pixels guide, oracle target: the reference pose changes its tile's views toward the reference (negative),
    a ball elsewhere on the table away from it (positive), and a source that draws nothing is not judged (inf)."""
    from ctp_core.bench.guides import PixelGuide

    table, ball, reference = _small_ball_on_table()
    pair = pairs.prepare_pair(table, ball, samples=CONFIG.loss.samples, seed=0)
    guide, oracle = PixelGuide(size=32), goals.ReferenceGoal(reference)
    oracle.prepare(pair, guide)
    scorer = objective.Scorer(pair, CONFIG, 0.2, guide=guide, goal=oracle)
    weights = schedule.phases(CONFIG, allow_penetration=False)[-1]
    elsewhere = reference.copy()
    elsewhere[:3, 3] += (-1.0, 0.0, -0.3)
    matrices = [pair.local_to_normalised(m) for m in (reference, elsewhere)]
    scale = float(np.cbrt(np.linalg.det(matrices[0][:3, :3])))
    t = torch.tensor(np.array([m[:3, 3] for m in matrices]), dtype=torch.float32)
    q = torch.tensor(np.array([pose.matrix_to_quaternion(m[:3, :3] / scale) for m in matrices]), dtype=torch.float32)
    poses = pose.Poses(t, q, torch.full((2,), math.log(scale)))
    poses = pose.Poses.cat([poses, pose.Poses(t[:1] + torch.tensor([[0.0, -0.15, 0.0]]), q[:1],
                                                        poses.log_s[:1])])  # inside the table top: hidden
    keys = coarse_to_fine.tile_score(scorer, poses, weights, coarse_to_fine.tiles_of(pair, CONFIG, poses), batch=8)
    assert keys.value[0] < 0 < keys.value[1] and torch.isinf(keys.value[2])


def _small_ball_oracle():
    """The small ball on the big table, its proposals, and a scorer guided by the oracle through random:tiny."""
    table, ball, reference = _small_ball_on_table()
    pair, props = _proposals(table, ball)
    guide, oracle = get_guide("random:tiny"), goals.ReferenceGoal(reference)
    oracle.prepare(pair, guide)
    scorer = objective.Scorer(pair, CONFIG, 0.2, guide=guide, goal=oracle)
    return pair, props, guide, scorer, schedule.phases(CONFIG, allow_penetration=False)[-1]


def test_the_tile_stage_counts_its_images_and_adds_its_restarts(monkeypatch):
    # a guide the gate trusts (random:tiny's spread is within its noise here: no tile stage then)
    monkeypatch.setattr(coarse_to_fine, "guide_noise", lambda *args: ordering.GuideSay(1.0, 0.0))
    pair, props, guide, scorer, weights = _small_ball_oracle()
    events = []
    ranked = coarse_to_fine.search(scorer, props, weights, k=2, on_event=events.append)
    cfg, n = CONFIG.search, len(props.poses)
    tiles = len(coarse_to_fine.tiles_of(pair, CONFIG, props.poses)[1])
    fine = min(cfg.fine, n)
    coarse = (n + ranked.swept) * cfg.coarse_views + cfg.coarse_views
    tiled = n * cfg.coarse_views + 2 * tiles * cfg.coarse_views  # each tile: its reference and its empty views
    assert scorer.clip_images == coarse + tiled + fine * cfg.fine_views + cfg.fine_views
    assert ranked.scored == n + ranked.swept + n + fine and "tiles" in ranked.stages
    assert 2 < len(ranked.poses) <= 2 + cfg.tile_restarts  # the fine stage's 2, then the tile stage's
    planned = n + cfg.sweep * len(props.rotations) + n + fine
    assert events[-1].step == events[-1].steps == planned
    assert [e.step for e in events] == sorted(e.step for e in events)


def test_the_sweep_tries_every_orientation_at_the_best_site(meshes):
    target, source = meshes["box on table"]
    pair, props = _proposals(target, source)
    objectives = ordering.Key.plain(torch.arange(len(props.poses), dtype=torch.float32))  # the first is the best
    swept = coarse_to_fine.sweep(props, pair, objectives, 1, 0.1)
    assert 0 < len(swept) <= len(props.rotations)
    turns = torch.nn.functional.normalize(swept.q, dim=-1) @ torch.nn.functional.normalize(props.rotations, dim=-1).T
    assert (turns.abs().max(dim=1).values > 0.9999).all()  # each is one of the source's orientations
    assert (swept.t - props.poses.t[0]).norm(dim=-1).max() < 2 * pair.target_radius  # at that site


def test_diverse_top_skips_near_duplicates():
    t = torch.tensor([[0.0, 0, 0], [0.01, 0, 0], [1.0, 0, 0]])
    q = torch.tensor([[1.0, 0, 0, 0]] * 3)
    poses = pose.Poses(t, q, torch.zeros(3))
    objectives = ordering.Key.plain(torch.tensor([0.0, 0.1, 0.2]))
    assert coarse_to_fine.diverse_top(poses, objectives, 2, 0.1, 30.0) == [0, 2]
    assert coarse_to_fine.diverse_top(poses, objectives, 3, 0.1, 30.0) == [0, 2, 1]


def _turned(pair, poses, index, degrees, axis=(0.0, 1.0, 0.0)):
    """Pose ``index`` of ``poses`` turned by ``degrees`` about ``axis`` (normalised frame) in place."""
    half = math.radians(degrees) / 2
    turn = torch.tensor([math.cos(half), *(math.sin(half) * torch.tensor(axis)).tolist()])
    return pose.Poses(poses.t[index:index + 1], pose.quaternion_product(turn[None], poses.q[index:index + 1]),
                      poses.log_s[index:index + 1])


def test_a_turn_that_looks_the_same_is_no_choice(meshes):
    """``looks_apart``: a box turned by a half turn about any of its axes looks as it did, a quarter turn about its
    up does not (its sides differ); an upright cylinder looks the same at any turn about its axis; another size
    is another choice."""
    target, source = meshes["box on table"]
    pair, props = _proposals(target, source)
    q = props.poses.q[:1]
    apart = [bool(coarse_to_fine.looks_apart(pair, q, _turned(pair, props.poses, 0, d, axis).q[0], torch.zeros(1),
                                              torch.zeros(())).all()) for d, axis in
             [(180, (0.0, 1.0, 0.0)), (180, (1.0, 0.0, 0.0)), (90, (0.0, 1.0, 0.0)), (30, (0.0, 1.0, 0.0))]]
    assert apart == [False, False, True, True]
    assert bool(coarse_to_fine.looks_apart(pair, q, q[0], torch.zeros(1), torch.tensor(0.5)).all())
    can = trimesh.creation.cylinder(radius=0.2, height=0.5, sections=64)
    can.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # its axis along +Y
    can_pair, can_props = _proposals(target, can)
    up = torch.as_tensor(can_pair.source_upright.up, dtype=torch.float32)
    standing = pose.quaternion_to_matrix(can_props.poses.q) @ up
    i = int(torch.argmax(standing[:, 1]))  # a proposal standing on its end: its axis along +Y
    assert float(standing[i, 1]) > 0.99
    assert not coarse_to_fine.looks_apart(can_pair, can_props.poses.q[i:i + 1], _turned(
        can_pair, can_props.poses, i, 70).q[0], torch.zeros(1), torch.zeros(())).any()


def test_the_turns_drawn_for_the_check_touch_and_differ(meshes):
    """``turns_at``: a box resting on a table turned about the up in eighths of a full turn, lowered into contact:
    the half turn and the turns a half turn from a kept one look the same (a box's symmetry), so 3 remain; each
    rests on the table (the relation holds, nothing intersects), turned about the up only."""
    run = prepare(*meshes["box on table"], "a box on the table", CONFIG, target_name="table", source_name="box")
    props = propose(run)
    terms = run.scorer.geometry(props.poses, run.plan[0])
    i = int(torch.nonzero(ordering.holding(terms) & torch.tensor([r == "top" for r in props.region]))[0, 0])
    turned = coarse_to_fine.turns_at(run.pair, props, i)
    assert len(turned) == 3
    assert bool(ordering.holding(run.scorer.geometry(turned, run.plan[0])).all())
    up = torch.tensor([0.0, 1.0, 0.0])
    ups = pose.quaternion_to_matrix(turned.q) @ (pose.quaternion_to_matrix(props.poses.q[i]).T @ up)
    assert torch.allclose(ups, up.expand_as(ups), atol=1e-4)  # the box's own up stays the table's up
    assert (turned.t - props.poses.t[i]).norm(dim=-1).max() < 0.5 * run.pair.source_diagonal


def test_the_check_draws_turns_where_one_place_holds_and_names_the_decision(meshes):
    """Where the relation holds at one place only, the places cannot be checked; the guide's turns there are drawn
    and checked from the views it has not seen (``agreement_views``), and the say names what its favourite does
    that the geometry's does not (``decision``)."""
    run = prepare(*meshes["box on table"], "a box on the table", CONFIG, target_name="table", source_name="box")
    props = propose(run)
    phase, pair, config = run.plan[0], run.pair, run.config
    cameras = coarse_to_fine.coarse_cameras(pair, config, 0.0)
    checks = coarse_to_fine.agreement_cameras(pair, config, 0.0)
    terms = coarse_to_fine.terms_of(run.scorer, props.poses, phase, cameras, batch=8)
    distinct = coarse_to_fine.distinct_of(pair, config, 0.0)
    held = ordering.holding(terms)
    one = torch.zeros_like(held)
    one[int(torch.nonzero(held & torch.tensor([r == "top" for r in props.region]))[0, 0])] = True
    before = run.scorer.clip_images
    stage = coarse_to_fine.Stage(run.scorer, phase, cameras, None, checks, distinct, name="box")
    checked = coarse_to_fine.agreement_views(stage, props, terms, one)
    assert len(checked.places) == 1 and checked.places.shape[1] == 1  # one place: not tested
    assert checked.drawn == 3 and len(checked.turns) == 4 and checked.turns.shape[1] == 1 + len(checks.eye[0])
    # the three turns at the coarse views, the four choices at the held-out ones (a prompt's goal: encoded once)
    assert run.scorer.clip_images - before == 3 * config.search.coarse_views + 4 * len(checks.eye[0])
    say = coarse_to_fine.guide_noise(stage, props, terms.but(rel=torch.where(one, 0.0, 1.0)))
    assert say.places == 1 and say.turns == 3 and say.drawn == 3 and say.agree is not None
    geometry = props.poses.select(torch.nonzero(one)[0])
    assert coarse_to_fine.decision(pair, geometry, geometry, distinct, "box") == ""
    assert coarse_to_fine.decision(pair, _turned(pair, geometry, 0, 90), geometry, distinct, "box") \
        == "turned the box 90 degrees"
    moved = pose.Poses(geometry.t + torch.tensor([[2.0 * pair.source_diagonal, 0.0, 0.0]]), geometry.q,
                       geometry.log_s + 0.5)
    assert coarse_to_fine.decision(pair, moved, geometry, distinct, "box") == "moved the box 2.0 of its sizes and " \
        "sized it x1.65"


def test_the_fine_shortlist_keeps_distinct_places_before_turns():
    """Ten turns at one place rank best (the sweep's pattern); half the shortlist still goes to other places."""
    angles = torch.arange(10) * 0.6
    q_turns = torch.stack([torch.cos(angles / 2), 0 * angles, torch.sin(angles / 2), 0 * angles], dim=1)
    t = torch.cat([torch.zeros(10, 3), torch.tensor([[float(i), 0.0, 0.0] for i in range(1, 6)])])
    q = torch.cat([q_turns, torch.tensor([[1.0, 0, 0, 0]]).repeat(5, 1)])
    poses = pose.Poses(t, q, torch.zeros(15))
    objectives = ordering.Key.plain(torch.arange(15, dtype=torch.float32))  # the ten turns first
    picked = coarse_to_fine.shortlist_of(poses, objectives, 6, 0.1, 30.0)
    assert len(picked) == len(set(picked)) == 6
    assert len({tuple(poses.t[i].tolist()) for i in picked}) >= 3  # best turn at the first place + 2 others
    assert coarse_to_fine.diverse_top(poses, objectives, 6, 0.1, 30.0) == [0, 1, 2, 3, 4, 5]  # without: one place


def test_the_answer_is_the_best_restart_that_stays_near_the_target(meshes):
    """A restart whose source drifted out of reach (a guide can prefer an absent source) is not chosen over one
    near the target, whatever their objectives; when none is near, the lowest objective still wins."""
    target, source = meshes["box on table"]
    pair = pairs.prepare_pair(target, source, samples=CONFIG.loss.samples, seed=0)
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(2, 1)
    poses = pose.Poses(torch.tensor([[0.0, 30.0, 0.0], [0.0, 0.3, 0.0]]), q, torch.zeros(2))
    clear = contact.clearance(pair, pair.index, poses)
    assert clear[0] > contact.REACH >= clear[1]
    terms = objective.Terms.zeros(2).but(objective=torch.tensor([-1.0, 0.0]), clip=torch.tensor([-1.0, 0.0]))
    weights = schedule.phases(CONFIG, allow_penetration=False)[-1]
    for guided in (False, True):
        rule = {"guided": guided, "touches": False, "share": CONFIG.search.min_share}
        limit = contact.touch_limit(pair, poses)
        assert ordering.select_answer(terms, clear, limit, weights, **rule) == 1
        assert ordering.select_answer(terms, torch.tensor([9.0, 9.0]), limit, weights, **rule) == 0


def test_with_a_guide_the_answer_leaves_out_soft_icp_among_restarts_that_touch():
    """At contact the soft-ICP term is sample noise x its weight: a guided answer is the lowest guide and
    penetration terms among the near restarts that touch (where the relation touches)."""
    weights = schedule.phases(CONFIG, allow_penetration=False)[-1]
    assert weights.lambda_icp > 0 and weights.lambda_pen > 0
    terms = objective.Terms.zeros(4).but(  # the fourth is deep inside
        clip=torch.tensor([-0.99, -0.98, -0.999, -0.9995]), pen=torch.tensor([0.0, 0.0, 0.0, 1.0]),
        sunk=torch.tensor([0.0, 0.0, 0.0, 2 * ordering.SUNK]),
        icp=torch.tensor([1.0, 0.0, 0.0, 0.0]) * 0.05 / weights.lambda_icp)  # noise that outweighs the guide
    terms = terms.but(objective=objective.combine(terms, weights))
    clear = torch.tensor([0.01, 0.0, 0.5, 0.0])  # the third floats half a diagonal off
    limit = torch.full((4,), contact.TOUCH)
    plain = {"guided": False, "touches": True, "share": CONFIG.search.min_share}
    guided = {"guided": True, "share": CONFIG.search.min_share}
    assert ordering.select_answer(terms, clear, limit, weights, **plain) == 2
    assert ordering.select_answer(terms, clear, limit, weights, **guided, touches=True) == 0
    assert ordering.select_answer(terms, clear, limit, weights, **guided, touches=False) == 2
    assert ordering.select_answer(terms, clear, limit + 0.5, weights, **guided, touches=True) == 2  # in reach
    apart = torch.tensor([0.5, 0.5, 0.5, 0.5])  # none touches: the objective decides
    assert ordering.select_answer(terms, apart, limit, weights, **guided, touches=True) == 2


def test_the_touch_limit_grows_with_the_target_sample_spacing(meshes):
    """A small source on a big target can touch it farther from the nearest target sample than TOUCH diagonals."""
    target, source = meshes["box on table"]
    q, t = torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.zeros(1, 3)
    limits = []
    for samples in (200, 5000):
        pair = pairs.prepare_pair(target, source, samples=samples, seed=0)
        limits.append(float(contact.touch_limit(pair, pose.Poses(t, q, torch.zeros(1)))[0]))
        spacing = pair.sample_spacing(samples) / (2 * pair.source_radius)
        assert limits[-1] == pytest.approx(contact.TOUCH + spacing, rel=1e-5)
    assert limits[0] > limits[1] > contact.TOUCH


def test_cancel_during_search(meshes):
    calls = {"n": 0}

    def cancel():
        calls["n"] += 1
        return calls["n"] > 1  # the first batch runs, the second is refused

    events = []
    with pytest.raises(Canceled):
        align(*meshes["box on table"], "a box on the table", CONFIG, on_event=events.append, should_cancel=cancel)
    assert events and all(e.stage == "search" for e in events)
    assert 0 < max(e.step for e in events) < events[0].steps


def test_stages_are_callable_alone(meshes):
    run = prepare(*meshes["box on table"], "a box on the table", CONFIG, target_name="table", source_name="box")
    props = propose(run)
    assert run.prior.reading.name == "on" and len(props.poses) >= CONFIG.search.candidates // 2  # wedged ones dropped
    off = CONFIG.model_copy(update={"search": CONFIG.search.model_copy(update={"enabled": False})})
    assert propose(prepare(*meshes["box on table"], None, off)).region == ["random"] * off.optim.restarts


def test_refinement_progress_counts_the_restarts_it_was_given(meshes):
    """The search may keep fewer starts than ``optim.restarts`` (or add the tile stage's): progress says how many
    are refined, not how many were configured."""
    run = prepare(*meshes["box on table"], "a box on the table", CONFIG, target_name="table", source_name="box")
    starts = propose(run).poses.select(slice(0, 3))
    events = []
    outcome = refine(run, starts, on_event=events.append)
    assert CONFIG.optim.restarts != 3 and len(outcome.objectives) == 3
    assert events and {e.restarts for e in events} == {3}


def test_align_end_to_end_with_the_default_preset(meshes):
    """The real default (search, then refinement), shrunk only in counts and image sizes for CI."""
    cfg = AlignConfig.from_preset(
        "default", model="random:tiny", camera={"image_size": 64}, loss={"samples": 600},
        search={"candidates": 32, "coarse_image_size": 64, "fine": 6, "fine_image_size": 64, "batch": 16},
    )
    events = []
    result = align(*meshes["box on table"], "a box on the table", cfg, target_name="table", source_name="box",
                   on_event=events.append)
    search_events = [e for e in events if e.stage == "search"]
    assert search_events and search_events[-1].step == search_events[-1].steps
    assert events[-1].kind == "done" and events[-1].stage == "refine"
    assert result.timings["search_candidates"] >= 32 and len(result.restarts) == cfg.optim.restarts
    placed = result.source.copy()
    placed.apply_transform(result.source_to_target)
    table = meshes["box on table"][0]
    assert metrics.contact_distance(table, placed) <= 0.02
    assert metrics.intersection_over_union(table, placed).iou <= 0.02
    assert result.clip_images > cfg.search.candidates * cfg.search.coarse_views


def test_random_init_mode_draws_uniform_orientations_without_resting_poses(meshes, monkeypatch):
    target, source = meshes["box on table"]
    pair = pairs.prepare_pair(target, source, samples=CONFIG.loss.samples, seed=0)
    config = CONFIG.model_copy(update={"optim": CONFIG.optim.model_copy(update={"init_rotation": "random"})})
    monkeypatch.setattr(proposals, "_stable_poses", lambda *a: pytest.fail("resting poses computed in random mode"))
    q = proposals.orientations(pair, config, torch.Generator().manual_seed(0))
    cfg = config.search
    assert q.shape == (cfg.yaw_steps * (2 + cfg.stable_poses), 4)
    torch.testing.assert_close(q.norm(dim=1), torch.ones(len(q)))
    assert (q[:, [0, 2]].norm(dim=1) < 0.999).any()  # not only turns about +Y


def _terms(rel: list[float], objective_: list[float]) -> objective.Terms:
    return objective.Terms.zeros(len(rel)).but(rel=torch.tensor(rel), icp=torch.tensor(objective_),
                                               objective=torch.tensor(objective_))


def test_the_encoder_shortlist_takes_distinct_places_where_the_relation_holds_and_a_share_of_the_rest():
    """Ten poses a unit apart: the first six hold the relation. Five slots: the four best that hold, and one
    reserved (ceil(0.08 x 5)) for the best that fails, so a misread prompt keeps the right answer reachable;
    where too few hold, the others fill the slots."""
    poses = pose.Poses(torch.tensor([[float(i), 0.0, 0.0] for i in range(10)]),
                       torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(10, 4), torch.zeros(10))
    weights = schedule.phases(CONFIG, allow_penetration=False)[0]
    rel = [0.0] * 6 + [1.0] * 4
    key = [5.0, 4.0, 3.0, 2.0, 1.0, 0.0, 9.0, 8.0, 7.0, 6.0]  # lower is better
    picked = coarse_to_fine.encoder_shortlist(poses, _terms(rel, key), weights, 5, (0.5, 30.0), 0.08)
    assert sorted(picked) == [2, 3, 4, 5, 9]
    few = coarse_to_fine.encoder_shortlist(poses, _terms([0.0, 0.0] + [1.0] * 8, key), weights, 5, (0.5, 30.0), 0.08)
    assert sorted(few) == [0, 1, 3, 4, 5]  # both that hold, the three best others
    # near-duplicates (the same place and turn) do not take two slots while distinct places remain
    dup = pose.Poses.cat([poses.select([5, 5, 4]), poses.select([0])])
    picked = coarse_to_fine.encoder_shortlist(dup, _terms([0.0] * 4, [0.0, 0.0, 1.0, 2.0]), weights, 3, (0.5, 30.0),
                                              0.08)
    assert sorted(picked) == [0, 2, 3]


def _text_scorer(pair, config, relation=None):
    guide, text = get_guide("random:tiny"), goals.TextGoal("a box on the table")
    text.prepare(pair, guide)
    return objective.Scorer(pair, config, 0.2, guide=guide, goal=text,
                            reading=None if relation is None else RelationReading.parse(relation))


def test_the_guide_sees_only_the_shortlist_and_the_turns_the_geometry_allows(meshes, monkeypatch):
    """``search.shortlist`` of the proposals reach the encoder (screened by the geometry, ``Scorer.screen``),
    ``sweep_keep`` turns per site: the images are counted exactly (a text goal encodes no images)."""
    monkeypatch.setattr(coarse_to_fine, "guide_noise", lambda *args: ordering.GuideSay(1.0, 0.0))  # a guide with signal
    config = CONFIG.model_copy(update={"search": CONFIG.search.model_copy(update={"shortlist": 10,
                                                                                  "sweep_keep": 5})})
    pair, props = _proposals(*meshes["box on table"], config)
    assert len(props.poses) > 10
    scorer = _text_scorer(pair, config, relation="on")
    weights = schedule.phases(config, allow_penetration=False)[0]
    ranked = coarse_to_fine.search(scorer, props, weights, k=2)
    cfg = config.search
    assert ranked.swept == cfg.sweep * cfg.sweep_keep
    fine = min(cfg.fine, 10 + ranked.swept)
    assert scorer.clip_images == (10 + ranked.swept) * cfg.coarse_views + fine * cfg.fine_views
    assert ranked.scored == 10 + ranked.swept + fine
    assert ranked.screened == len(props.poses) + cfg.sweep * len(props.rotations)  # every proposal and turn
    # the shortlisted are those the relation admits, but for the share kept for the others
    held = int(ordering.holding(scorer.screen(props.poses, weights)).sum())
    shortlisted = ranked.stages["coarse"][0].select(slice(0, 10))  # the coarse stage's first 10, then the sweep
    assert held >= 10 > int(ordering.holding(scorer.screen(shortlisted, weights)).sum()) >= 9


def test_a_guide_without_signal_encodes_nothing_after_the_coarse_stage(meshes, monkeypatch):
    """Gate override 0 (its spread within its noise): the geometry ranks, so the sweep, the fine stage, the
    refinement's gradient and the selection's views encode no image."""
    monkeypatch.setattr(coarse_to_fine, "guide_noise", lambda *args: said(0.0, spread=0.0, noise=1.0))
    run = prepare(*meshes["box on table"], "a box on the table", CONFIG, target_name="table", source_name="box")
    props = propose(run)
    ranked = coarse_to_fine.search(run.scorer, props, run.plan[0], k=2)
    coarse = len(props.poses) * CONFIG.search.coarse_views
    assert not run.scorer.with_say(ranked.say).guided and run.scorer.clip_images == coarse and ranked.swept > 0
    outcome = refine(run, ranked.poses, ranked.say)
    assert outcome.clip_images == coarse and len(outcome.objectives) == 2


def test_a_phase_starts_from_the_guide_terms_the_last_one_measured(meshes):
    """The evaluation views are fixed, so a phase's start (the last phase's best poses) is not encoded again:
    eval images = restarts x views x (1 + the evaluations in each phase), and the terms are the same."""
    config = CONFIG.model_copy(update={"search": CONFIG.search.model_copy(update={"enabled": False})})
    run = prepare(*meshes["box on table"], "a box on the table", config, target_name="table", source_name="box")
    starts = propose(run).poses
    outcome = refine(run, starts)
    opt, views = config.optim, config.camera
    per_phase = math.ceil(opt.steps / opt.phases / opt.eval_every)
    assert opt.phases == 2 and len(starts) == opt.restarts
    expected = opt.restarts * views.eval_views * (1 + opt.phases * per_phase) + opt.steps * opt.restarts * views.views
    assert outcome.clip_images == expected
    scorer, last = run.scorer, run.plan[-1]
    again = scorer.evaluate(outcome.poses, last, outcome.terms.clip)
    fresh = scorer.evaluate(outcome.poses, last)
    torch.testing.assert_close(again.objective, fresh.objective, atol=1e-5, rtol=0)


def test_the_tile_stage_encodes_across_tiles_in_full_batches():
    """All tiles' goal views in one encoder call, their empty views and the poses ``batch`` at a time across
    tiles (it was a few small calls per tile: ~100 on a table of 34 tiles)."""
    pair, props, guide, scorer, weights = _small_ball_oracle()
    tiles = coarse_to_fine.tiles_of(pair, CONFIG, props.poses)
    count, n, batch = len(tiles[1]), len(props.poses), 16
    assert count > 2
    calls = []
    encode = guide.encode_images
    guide.encode_images = lambda images: calls.append(len(images)) or encode(images)
    try:
        keys = coarse_to_fine.tile_score(scorer, props.poses, weights, tiles, batch=batch)
    finally:
        guide.encode_images = encode
    views = CONFIG.search.coarse_views
    assert len(calls) == 1 + math.ceil(count / batch) + math.ceil(n / batch)
    assert sum(calls) == (2 * count + n) * views and len(keys) == n


def test_the_fast_preset_places_in_contact_within_its_encoder_budget(meshes):
    """``fast``: the relation and the geometry choose, the guide glances: no gradient images, and at most the
    shortlist (and the gate's probes) at the coarse views, its best few places and turns from the views that
    check its choice, the fine few, and each restart's start and end on the evaluation views. ``default`` takes
    no gradient either; ``descent`` and ``paper`` descend the guide."""
    assert not AlignConfig.from_preset("default").needs_image_gradient
    assert all(AlignConfig.from_preset(name).needs_image_gradient for name in ("descent", "paper"))
    cfg = AlignConfig.from_preset("fast", model="random:tiny", loss={"samples": 600},
                                  search={"coarse_image_size": 64, "fine_image_size": 64})
    result = align(*meshes["box on table"], "a box on the table", cfg, target_name="table", source_name="box")
    s, cam, opt = cfg.search, cfg.camera, cfg.optim
    # its best places and turns from the views that check them, and the turns drawn for that at the coarse views
    checks = (2 * coarse_to_fine.AGREE_CHOICES * len(coarse_to_fine.HELD_OUT_VIEWS)
              + (coarse_to_fine.TURN_DRAWS - 1) * s.coarse_views)
    budget = ((s.shortlist + coarse_to_fine.GATE_PROBES) * s.coarse_views + checks + s.fine * s.fine_views
              + opt.restarts * cam.eval_views * (1 + opt.phases))
    assert 0 < result.clip_images <= budget
    placed = result.source.copy()
    placed.apply_transform(result.source_to_target)
    table = meshes["box on table"][0]
    assert metrics.contact_distance(table, placed) <= 0.02
    assert metrics.intersection_over_union(table, placed).iou <= 0.02


def test_progress_reads_the_relation_the_guide_and_the_gap(meshes, monkeypatch):
    """What the page and the CLI show instead of the objective: the search says where the relation holds among the
    candidates scored and one restart count (planned, then kept); the refinement, in how many restarts it holds,
    the best restart's guide match (a cosine) and its gap to the target."""
    monkeypatch.setattr(coarse_to_fine, "guide_noise", lambda *args: ordering.GuideSay(1.0, 0.0))  # a guide with signal
    run = prepare(*meshes["box on table"], "a box on the table", CONFIG, target_name="table", source_name="box")
    events = []
    ranked = coarse_to_fine.search(run.scorer, propose(run), run.plan[0], k=2, on_event=events.append)
    assert {e.restarts for e in events[:-1]} == {2} and events[-1].restarts == len(ranked.poses)
    counted = [e for e in events if e.relation_holds is not None]
    assert counted and all(e.relation == "on" and 0 <= e.relation_holds <= e.relation_checked for e in counted)
    refined = []
    refine(run, ranked.poses, ranked.say, on_event=refined.append)
    steps = [e for e in refined if e.kind in ("step", "phase_end")]
    assert steps and all(e.relation == "on" and e.relation_checked == len(ranked.poses) for e in steps)
    assert all(-1 <= e.guide_match <= 1 and 0 <= e.contact_gap < 0.2 for e in steps)


@pytest.mark.parametrize(("say", "chose"), [(said(0.0, noise=1.0), "geometry"), (said(0.5, noise=1.0), "both"),
                                             (ordering.GuideSay(1.0, 0.0), "guide")])
def test_the_report_and_the_progress_say_who_chose_among_the_poses_that_hold(meshes, monkeypatch, say, chose):
    """The guide's say as the search measured it (``ordering.GuideSay``) reaches the search's progress message and
    the report: who ordered the poses where the relation holds, and why, in one line."""
    monkeypatch.setattr(coarse_to_fine, "guide_noise", lambda *args: say)
    events = []
    result = align(*meshes["box on table"], "a box on the table", CONFIG, target_name="table", source_name="box",
                   on_event=events.append)
    said = export.report(result)["guide_say"]
    assert said["chose"] == chose and said["override"] == round(say.amount, 3)
    assert said["summary"].endswith({"geometry": "the geometry chose", "guide": "the guide chose",
                                     "both": "the usual arrangement weighing 0.50"}[chose])
    assert said["summary"] in [e.message for e in events if e.stage == "search"][-1]


def test_a_run_without_a_guide_reports_no_say(meshes):
    config = CONFIG.model_copy(update={"loss": CONFIG.loss.model_copy(update={"lambda_clip": 0.0})})
    result = align(*meshes["box on table"], "a box on the table", config, target_name="table", source_name="box")
    assert export.report(result)["guide_say"] is None


def test_without_a_guide_the_fine_stage_ranks_the_coarse_terms_as_scoring_them_again_would(meshes, monkeypatch):
    """No view changes a geometric term: the fine stage scores nothing again, and its ranking is the one scoring the
    shortlist at the fine views gives."""
    target, source = meshes["box on table"]
    pair, props = _proposals(target, source)
    scorer = objective.Scorer(pair, CONFIG, 0.2)
    phase = schedule.phases(CONFIG, allow_penetration=False)[0]
    cameras = coarse_to_fine.coarse_cameras(pair, CONFIG, 0.0)
    terms = coarse_to_fine.terms_of(scorer, props.poses, phase, cameras, batch=CONFIG.search.batch)
    coarse = coarse_to_fine.ranking_key(scorer, terms, phase)
    distinct = coarse_to_fine.distinct_of(pair, CONFIG, 0.0)
    plan = coarse_to_fine._Plan.of(scorer, props, 2, None, 0.0, 1)
    shortlist = coarse_to_fine.shortlist_of(props.poses, coarse, plan.fine_count, *distinct)
    fine_poses = props.poses.select(shortlist)
    rescored = coarse_to_fine.score(scorer, fine_poses, phase, coarse_to_fine.fine_cameras(pair, CONFIG, fine_poses),
                                    batch=CONFIG.search.batch).average(coarse.select(shortlist))
    calls = []
    monkeypatch.setattr(objective.Scorer, "score", lambda *args, **kwargs: calls.append(args))
    stage = coarse_to_fine.Stage(scorer, phase, cameras, None, None, distinct)
    kept, ranked = coarse_to_fine._fine(stage, props.poses, terms, coarse, plan)
    assert not calls and len(shortlist) > 1
    assert torch.equal(kept.t, fine_poses.t)
    assert torch.equal(ranked.tier, rescored.tier) and torch.equal(ranked.value, rescored.value)
    assert ranked.argsort().tolist() == rescored.argsort().tolist()
