"""Scale mode finds the scale (``ctp_core.search.scaling``): every start's scale from the priors' size ratio or
the geometry, never from the incoming pose or the files' sizes; the search's ladder; the objective's scale term;
the report's ``extra.scale``.

End to end: generated pairs at real sizes (a cup on a table, a ball in a bowl, a cap on a sphere "head"), the
source file scaled by 0.01 or 100 and the whole pair at either absolute unit extreme (x 1e-4, x 1e4), aligned
geometry-only with preset ``test``; the answer's scale must undo the source's factor within ``TOLERANCE``. The
geometry's lower bounds (a ring hung on a peg, a lid on a jar) with the source file scaled by 0.01 or 100.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh
from test_ordering import said

from ctp_core.align import align, prepare, propose
from ctp_core.config import AlignConfig
from ctp_core.export import report
from ctp_core.pairs import prepare_pair
from ctp_core.priors import ScenePrior
from ctp_core.reading.relation import RelationReading
from ctp_core.search import coarse_to_fine, scaling

# |ln(found / true)| allowed: ln 1.5, about the rules provider's size-ratio error at its 68th percentile
# (scaling.PRIOR_SIGMA): where the priors set the scale, no better can be asked of them
TOLERANCE = math.log(1.5)


def _cup(radius: float, height: float, wall: float) -> trimesh.Trimesh:
    """An open-topped cylinder cup (a wall ring and a bottom), standing on y = 0, +Y up."""
    ring = trimesh.creation.annulus(r_min=radius - wall, r_max=radius, height=height, sections=48)
    ring.apply_translation([0, 0, height / 2])
    bottom = trimesh.creation.cylinder(radius=radius, height=wall, sections=48)
    bottom.apply_translation([0, 0, wall / 2])
    cup = trimesh.util.concatenate([ring, bottom])
    cup.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))  # z up -> y up
    return cup


def _table() -> trimesh.Trimesh:
    top = trimesh.creation.box(extents=[1.2, 0.04, 0.8])
    top.apply_translation([0, 0.73, 0])
    legs = []
    for x in (-0.55, 0.55):
        for z in (-0.35, 0.35):
            leg = trimesh.creation.box(extents=[0.05, 0.71, 0.05])
            leg.apply_translation([x, 0.355, z])
            legs.append(leg)
    return trimesh.util.concatenate([top, *legs])


def _pair(name: str) -> tuple[trimesh.Trimesh, trimesh.Trimesh, str, str, str]:
    """(target, source at its true size, target name, source name, prompt), metres."""
    if name == "cup on a table":
        return _table(), _cup(0.04, 0.1, 0.004), "table", "cup", "a cup on a table"
    if name == "ball in a bowl":
        ball = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
        return _cup(0.1, 0.08, 0.006), ball, "bowl", "ball", "a ball in a bowl"
    if name == "cap on a head":
        cap = _cup(0.09, 0.06, 0.006)
        cap.apply_transform(trimesh.transformations.rotation_matrix(math.pi, [1, 0, 0]))  # the opening down
        return trimesh.creation.icosphere(subdivisions=3, radius=0.1), cap, "head", "cap", "a cap on a head"
    if name == "ring on a peg":  # the ring's hole 0.08 across, the peg 0.075 thick: it just passes over
        peg = trimesh.creation.cylinder(radius=0.0375, height=0.15, sections=48)
        peg.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))  # lying along x
        ring = trimesh.creation.torus(major_radius=0.05, minor_radius=0.01)  # in the x-y plane: it hangs
        return peg, ring, "peg", "ring", "a ring hanging on the peg"
    if name == "lid on a jar":  # the lid 0.104 across, the jar's opening 0.092
        lid = trimesh.creation.cylinder(radius=0.052, height=0.005, sections=48)
        lid.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))  # z up -> y up
        return _cup(0.05, 0.1, 0.004), lid, "jar", "lid", "a lid on the jar"
    raise ValueError(name)


def _scaled(mesh: trimesh.Trimesh, factor: float) -> trimesh.Trimesh:
    return trimesh.Trimesh(np.asarray(mesh.vertices) * factor, mesh.faces, process=False)


def _config(**changes) -> AlignConfig:
    # the default preset's proposal count: the test preset's 12 leave two or three per rung of the ladder
    return AlignConfig.from_preset("test", scale=True, threads=1, loss={"lambda_clip": 0.0}, search={"candidates": 144},
                                   **changes)


def _true_scale(name: str) -> float:
    """The scale that puts the cap snugly on the head: a cylinder cap of inner radius a and depth d rests on a
    sphere of radius R where its rim meets it, R - d below the top at full depth, so it is worn at
    s = 2 R d / (a^2 + d^2) (the cap as made: a = 0.084, d = 0.054); the others as made, 1."""
    if name == "cap on a head":
        a, d, r = 0.084, 0.054, 0.1
        return 2 * r * d / (a * a + d * d)
    return 1.0


@pytest.mark.parametrize("name", ["cup on a table", "ball in a bowl", "cap on a head"])
@pytest.mark.parametrize(("factor", "units"), [(0.01, 1e-4), (100.0, 1e4), (0.01, 1e4), (100.0, 1e-4)])
def test_generated_pairs_recover_the_scale(name, factor, units):
    target, source, target_name, source_name, prompt = _pair(name)
    target, source = _scaled(target, units), _scaled(source, units * factor)
    # the incoming pose says the source's given size is right: scale mode must not believe it
    result = align(target, source, prompt, _config(), target_name=target_name, source_name=source_name,
                   init=np.eye(4))
    found = result.scale * factor  # the answer's scale of the source at its true size
    data = json.loads(json.dumps(report(result)))["extra"]["scale"]
    assert data["final"] == pytest.approx(result.scale)
    assert data["names"] == {"target": target_name, "source": source_name, "on": None}
    if name == "ball in a bowl":
        # the priors' ball is a football (0.9 of the bowl): the cavity bounds it, and the ball fits in the bowl
        assert data["constraint"]["kind"].startswith("in")
        assert data["final"] <= data["constraint"]["scale"] * 1.05
        inner = 2 * (0.1 - 0.006) * units
        assert 2 * 0.05 * units * factor * result.scale <= inner * 1.05
        return
    if name == "cap on a head":
        assert data["from"] == "geometry" and data["constraint"]["kind"].startswith("wear")
    else:
        assert data["from"] == "priors" and data["size_ratio"] == pytest.approx(0.1)
    assert abs(math.log(found / _true_scale(name))) <= TOLERANCE, (found, data)


def test_the_incoming_scale_is_never_used():
    """Two incoming poses 10^4 apart in scale give the same starts and the same answer."""
    target, source, target_name, source_name, prompt = _pair("cup on a table")
    config = _config()
    answers, starts = [], []
    for factor in (0.01, 100.0):
        init = np.diag([factor, factor, factor, 1.0])
        run = prepare(target, source, prompt, config, target_name=target_name, source_name=source_name)
        starts.append(sorted(float(s) for s in propose(run, init).poses.log_s))
        answers.append(align(target, source, prompt, config, target_name=target_name, source_name=source_name,
                             init=init).scale)
    assert starts[0] == starts[1]
    assert answers[0] == pytest.approx(answers[1], rel=1e-4)


def test_an_assembly_step_finds_its_scale():
    """A scale-mode step of ``assemble``: the priors read the object it relates to (the table, not the scene) and
    the stage's report says where its scale came from."""
    from ctp_core.assembly.assemble import Step, assemble
    from ctp_core.export import assembly_report

    table, cup, *_ = _pair("cup on a table")
    rigid = AlignConfig.from_preset("test", threads=1, loss={"lambda_clip": 0.0})
    assembly = assemble(table, [Step(_scaled(cup, 100.0), "cup", "a cup on a table", config=_config())], rigid,
                        base_name="table")
    stage = json.loads(json.dumps(assembly_report(assembly)))["stages"][0]
    assert stage["extra"]["scale"]["names"]["target"] == "table" and stage["extra"]["scale"]["from"] == "priors"
    assert abs(math.log(stage["transform"]["scale"] * 100.0)) <= TOLERANCE


def test_the_files_sizes_set_nothing_in_scale_mode():
    """Rigid, plausible real sizes let the mesh extents set the size ratio; in scale mode they do not."""
    target, source, target_name, source_name, prompt = _pair("cup on a table")
    rigid = prepare(target, source, prompt, AlignConfig.from_preset("test", loss={"lambda_clip": 0.0}),
                    target_name=target_name, source_name=source_name)
    scaled = prepare(target, source, prompt, _config(), target_name=target_name, source_name=source_name)
    assert "mesh extents" in rigid.prior.reason and "mesh extents" not in scaled.prior.reason
    assert scaled.prior.size_ratio == pytest.approx(0.1)


def _plan(relation: str | None, size_ratio: float = 0.5, name: str = "ball in a bowl",
          guided: bool = True) -> scaling.ScalePlan:
    target, source, *_ = _pair(name)
    pair = prepare_pair(target, source, samples=1000, seed=0)
    reading = None if relation is None else RelationReading.parse(relation)
    prior = ScenePrior(size_ratio, False, 0.2, "rules", "test", reading=reading)
    return scaling.plan(pair, prior, {"target": "bowl", "source": "ball", "on": None}, seed=0, guided=guided)


def test_the_ladder_spans_the_priors_error_around_the_ratio():
    plan = _plan(None)
    assert len(plan.rungs) == scaling.RUNGS and plan.rungs[0] == plan.centre == plan.ratio_log_s
    assert min(plan.rungs) == pytest.approx(plan.centre - scaling.LADDER_WIDTH)
    assert max(plan.rungs) == pytest.approx(plan.centre + scaling.LADDER_WIDTH)
    assert (plan.low, plan.high) == (pytest.approx(min(plan.rungs)), pytest.approx(max(plan.rungs)))
    # the ratio as a scale: the source's longest side that ratio of the target's (0.5 x 0.2 m over the ball's 0.1)
    assert math.exp(plan.ratio_log_s) == pytest.approx(1.0, rel=0.02)


def test_in_drops_the_rungs_the_cavity_cannot_hold():
    plan = _plan("in", size_ratio=2.0)  # a ball twice the bowl cannot be in it
    assert plan.bound is not None and plan.bound.cuts == "upper"
    assert max(plan.rungs) == pytest.approx(plan.bound.log_s) == pytest.approx(plan.high)
    assert plan.centre == pytest.approx(plan.high)
    # the bowl's inside, 0.188 across, over the ball's 0.1 (probes keep off the walls: within 5 %)
    assert math.exp(plan.bound.log_s) == pytest.approx(1.88, rel=0.05)


def test_without_a_guide_the_search_proposes_at_the_centre_alone():
    """The geometry cannot tell sizes apart: the search's proposals all take the centre, the band stays the ladder's
    (the refinement may still move within it)."""
    guided, alone = _plan(None), _plan(None, guided=False)
    assert alone.rungs == (alone.centre,) == (guided.centre,)
    assert (alone.low, alone.high) == (guided.low, guided.high)


def test_a_guide_the_gate_silences_places_as_the_geometry_does(monkeypatch):
    """A guide with no say (``GuideSay`` override 0) cannot choose among the ladder's rungs, and across them the
    geometry would pick the one where the relation holds most easily: the run searches again as without a guide,
    every proposal at the centre, and its answer is the geometry's."""
    target, source, target_name, source_name, prompt = _pair("ball in a bowl")
    source = _scaled(source, 100.0)
    geometry = align(target, source, prompt, _config(), target_name=target_name, source_name=source_name)
    monkeypatch.setattr(coarse_to_fine, "guide_noise", lambda *args: said(0.0, spread=0.0, noise=1.0))
    guided = AlignConfig.from_preset("test", scale=True, threads=1, model="random:tiny", search={"candidates": 144})
    silenced = align(target, source, prompt, guided, target_name=target_name, source_name=source_name)
    assert silenced.guide_say["chose"] == "geometry"
    assert silenced.scaling["ladder"] == geometry.scaling["ladder"] == [pytest.approx(geometry.scaling["initial"])]
    np.testing.assert_allclose(silenced.source_to_target, geometry.source_to_target, atol=1e-6)


@pytest.mark.parametrize("name", ["ring on a peg", "lid on a jar"])
def test_hang_and_lid_bounds_raise_a_too_small_ratio(name):
    """The priors' ratio puts the ring too small for its loop to pass over the peg (the hook's widest plumb line
    runs obliquely through the loop: the bound is a little under the snug 0.075 / 0.08) and the lid too small to
    cover the jar's opening: the ladder's floor and its centre rise to the bound."""
    relation, snug = ("hang", 0.075 / 0.08) if name == "ring on a peg" else ("on", 0.092 / 0.104)
    plan = _plan(relation, size_ratio=0.4, name=name, guided=False)
    assert plan.bound is not None and plan.bound.cuts == "lower" and plan.bound.reason.startswith(relation)
    assert 0.85 * snug <= math.exp(plan.bound.log_s) <= 1.05 * snug
    assert plan.centre == plan.low == pytest.approx(plan.bound.log_s)
    assert plan.bound.log_s > plan.ratio_log_s
    assert plan.to_dict()["from"] == "geometry"


def test_a_flat_thing_far_smaller_than_the_opening_is_no_lid():
    """A coin "on" a cup: the opening is far wider than the priors' coin (past their 90th percentile): the bound is
    left out and reported, the priors decide."""
    target, _, *_ = _pair("lid on a jar")
    coin = trimesh.creation.cylinder(radius=0.0125, height=0.002, sections=32)
    coin.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))
    pair = prepare_pair(target, coin, samples=1000, seed=0)
    prior = ScenePrior(0.25, False, 0.2, "rules", "test", reading=RelationReading.parse("on"))
    plan = scaling.plan(pair, prior, {}, seed=0)
    assert plan.bound is None and plan.rejected.startswith("on: a lid") and plan.centre == plan.ratio_log_s


@pytest.mark.parametrize("name", ["ring on a peg", "lid on a jar"])
@pytest.mark.parametrize("factor", [0.01, 100.0])
def test_a_ring_and_a_lid_find_a_scale_that_passes_and_covers(name, factor):
    """End to end from the files' names (the rules provider: a ring a third of a peg, a lid 0.6 of a jar, both too
    small here): the answer's ring passes over the peg's crest, its lid covers the opening, within ``TOLERANCE``
    of the size they were made at."""
    target, source, target_name, source_name, prompt = _pair(name)
    result = align(target, _scaled(source, factor), prompt, _config(), target_name=target_name,
                   source_name=source_name, init=np.eye(4))
    found = result.scale * factor
    data = result.scaling
    assert data["from"] == "geometry" and data["constraint"]["side"] == "lower"
    assert data["priors_scale"] * factor < 0.8  # the priors alone: too small to pass or to cover
    # at or above the bound, less the wall's give (the contact terms pull a source smaller against its 100 per
    # squared log unit: a few per cent)
    assert found >= data["constraint"]["scale"] * factor * 0.9
    assert abs(math.log(found)) <= TOLERANCE, (found, data)


def test_the_scale_term_holds_the_band():
    plan = _plan(None)
    log_s = torch.tensor([plan.centre, plan.high, plan.high + 0.1, plan.low - 0.1], requires_grad=True)
    term = plan.term(log_s)
    values = term.detach()
    assert float(values[0]) == 0.0
    assert float(values[2]) > 0.9 and float(values[3]) > 0.9  # the wall: 100 per squared log unit beyond
    assert float(plan.term(log_s.detach(), geometric=0.0)[1]) == pytest.approx(
        scaling.PRIOR_FLOOR * 0.5 * (scaling.LADDER_WIDTH / scaling.PRIOR_SIGMA) ** 2)
    term.sum().backward()
    assert log_s.grad[2] > 0 and log_s.grad[3] < 0  # back toward the band


def test_cli_align_scale_says_where_the_scale_came_from(tmp_path, capsys):
    from ctp.cli import main

    table, cup, *_ = _pair("cup on a table")
    table.export(tmp_path / "table.glb")
    _scaled(cup, 0.01).export(tmp_path / "cup.glb")
    code = main(["align", str(tmp_path / "table.glb"), str(tmp_path / "cup.glb"), "--prompt", "a cup on a table",
                 "--scale", "--preset", "test", "--no-guidance", "--candidates", "144", "--quiet",
                 "--out", str(tmp_path / "scene.glb"), "--report", str(tmp_path / "report.json")])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["scale_from"] == "priors: size ratio 0.1" and summary["initial_scale"] > 50
    assert abs(math.log(summary["scale"] * 0.01)) <= TOLERANCE
    assert json.loads((tmp_path / "report.json").read_text())["extra"]["scale"]["final"] == pytest.approx(
        summary["scale"], rel=1e-5)
