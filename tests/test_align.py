"""The optimiser and ``align`` end to end on generated meshes (random:tiny model, test preset)."""

import json

import numpy as np
import pytest
import torch
import trimesh

from ctp.cli import main
from ctp_core import objective
from ctp_core.align import align
from ctp_core.config import AlignConfig, schedule
from ctp_core.errors import Canceled
from ctp_core.geometry import pose
from ctp_core.guide import runtime
from ctp_core.guide.goals import TextGoal
from ctp_core.guide.guidance import cpu_has_fast_bf16
from ctp_core.guide.loaders import get_guide
from ctp_core.io.examples import get_example
from ctp_core.pairs import prepare_pair


def _coloured(mesh: trimesh.Trimesh, rgb) -> trimesh.Trimesh:
    mesh.visual.vertex_colors = np.tile(np.array([*rgb, 255], np.uint8), (len(mesh.vertices), 1))
    return mesh


@pytest.fixture(scope="module")
def meshes():
    table = _coloured(trimesh.creation.box(extents=(2.0, 0.2, 1.2)), (150, 100, 60))
    cup = _coloured(trimesh.creation.cylinder(radius=0.2, height=0.4, sections=24), (200, 30, 30))
    cup.apply_translation((5.0, 3.0, 1.0))  # the file pose is arbitrary and far away
    return table, cup


def test_clip_gradient_reaches_translation_rotation_and_scale(meshes):
    cfg = AlignConfig.from_preset("test", model="random:tiny", scale=True)
    pair = prepare_pair(*meshes, samples=200, seed=0)
    guide = get_guide("random:tiny")
    goal = TextGoal("a cup on the table")
    goal.prepare(pair, guide)
    scorer = objective.Scorer(pair, cfg, 1.0, guide=guide, goal=goal)
    phase = schedule.phases(cfg, allow_penetration=False)[0]
    t = torch.tensor([[0.2, 0.4, 0.1]], requires_grad=True)
    q = torch.tensor([[0.9, 0.1, 0.3, 0.0]], requires_grad=True)
    log_s = torch.tensor([0.1], requires_grad=True)
    from ctp_core.render.cameras import sample_training_views

    cams = sample_training_views(torch.zeros(1, 3), cfg.camera, 1.0, torch.Generator().manual_seed(0))
    scorer.clip_term(pose.Poses(t, q, log_s), cams, weight=phase.lambda_clip)
    for name, p in (("t", t), ("q", q), ("log_s", log_s)):
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0, name


def test_align_is_deterministic_and_reports_progress(meshes):
    cfg = AlignConfig.from_preset("test", model="random:tiny")
    events = []
    a = align(*meshes, "a cup on the table", cfg, target_name="table", source_name="cup", on_event=events.append)
    b = align(*meshes, "a cup on the table", cfg, target_name="table", source_name="cup")
    np.testing.assert_allclose(a.source_to_target, b.source_to_target, atol=1e-6)
    stages = [e.stage for e in events]
    assert stages[0] == "search" and stages == sorted(stages, key=("search", "refine").index)  # search, then refine
    kinds = [e.kind for e in events if e.stage == "refine"]
    assert kinds[0] == "phase_start" and kinds[-1] == "done"
    assert kinds.count("phase_end") == cfg.optim.phases
    assert events[-1].step == cfg.optim.steps and events[-1].fraction == 1.0
    assert len(a.restarts) == cfg.optim.restarts
    assert a.objective == a.restarts[a.best_restart]["objective"]  # the answer: the selection's, not the lowest
    assert a.priors["provider"] and 0 <= a.priors["contact_ratio"] <= 1
    assert a.preview.shape == (4, 224, 224, 3) and a.preview.dtype == np.uint8
    # rigid: the scale of the answer is the file-relative scale (1)
    assert a.scale == pytest.approx(1.0, rel=1e-5)


def test_cancel_between_steps(meshes):
    cfg = AlignConfig.from_preset("test", model="random:tiny")
    calls = {"n": 0}

    def cancel():
        calls["n"] += 1
        return calls["n"] > 2

    with pytest.raises(Canceled):
        align(*meshes, "a cup on the table", cfg, should_cancel=cancel)


def test_geometry_only_brings_source_into_contact(meshes):
    """lambda_clip = 0: soft-ICP + penetration alone pull the far source onto the target surface."""
    from ctp_core import metrics

    cfg = AlignConfig.from_preset("descent", loss={"lambda_clip": 0.0, "samples": 1500}, contact_ratio=0.3,
                                  penetration="forbid", optim={"restarts": 2, "steps": 150})  # 90 stop 1-2 % short
    result = align(*meshes, None, cfg)
    placed = result.source.copy()
    placed.apply_transform(result.source_to_target)
    size = float(np.linalg.norm(meshes[0].extents))
    assert metrics.contact_distance(meshes[0], placed) <= 0.01 * size
    assert metrics.intersection_over_union(meshes[0], placed).iou <= 0.01


def alternatives_touch(report: dict) -> bool:
    """Each alternative says its own contact, the answer's as the report's."""
    found = report["alternatives"]
    return found[0]["contact"] == report["contact"] and all(set(a["contact"]) == {"gap", "touching"} for a in found)


def test_cli_align_end_to_end(tmp_path, meshes, capsys):
    target, source = tmp_path / "table.glb", tmp_path / "cup.glb"
    meshes[0].export(target)
    meshes[1].export(source)
    out, report, preview = tmp_path / "scene.glb", tmp_path / "report.json", tmp_path / "preview.png"
    code = main(["align", str(target), str(source), "--prompt", "a cup on the table", "--preset", "test",
                 "--model", "random:tiny", "--out", str(out), "--report", str(report),
                 "--preview", str(preview), "--quiet", "--alternatives", "3"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["out"] == str(out)
    scene = trimesh.load(out, force="scene")
    assert list(scene.geometry) == ["table", "cup"]
    data = json.loads(report.read_text())
    np.testing.assert_allclose(np.array(data["transform"]["matrix"]), summary_matrix(summary, data), atol=1e-9)
    assert data["prompt"] == "a cup on the table" and data["model"] == data["guide"] == "random:tiny"
    assert data["relation"]["name"] == "on" and data["relation"]["role"] == "figure"  # predicates.RelationVerdict
    assert summary["relation"] == data["relation"]
    assert list(data) == ["transform", "objective", "prompt", "model", "guide", "guide_why", "seed", "preset",
                          "config", "hparams", "relation", "contact", "guide_say", "restarts", "alternatives",
                          "timings", "extra", "warnings", "versions", "created_at"]
    assert data["contact"]["touching"] and alternatives_touch(data)
    # the answer in words: the verdict, contact, where it went (units named), turned in degrees, its size
    verdict = "'on' holds" if data["relation"]["holds"] else "'on' does not hold"
    assert summary["said"].startswith(f"{verdict}") and ", touching, moved to (" in summary["said"], summary["said"]
    assert "(metres for glTF)" in summary["said"] and ("°" in summary["said"] or "not turned" in summary["said"])
    # the best distinct placements, the answer first; --alternatives 3 wrote the next two beside --out
    alternatives = data["alternatives"]
    assert alternatives[0]["restart"] == data["extra"]["best_restart"]
    assert alternatives[0]["transform"]["matrix"] == data["transform"]["matrix"]
    written = [str(tmp_path / f"scene-{k}.glb") for k in range(2, min(3, len(alternatives)) + 1)]
    assert summary.get("alternatives", []) == written and len(alternatives) >= 2
    for k, path in enumerate(written, start=1):
        placed = trimesh.load(path, force="scene").graph["cup"][0]  # named by the file's stem
        np.testing.assert_allclose(placed, alternatives[k]["transform"]["matrix"], atol=1e-6)
    assert list(data["extra"]) == ["best_restart", "on", "grounds", "guidance", "runtime", "clip_images",
                                   "phase_timings", "target_upright", "source_upright", "scale", "parts"]
    assert data["extra"]["scale"] is None  # rigid: the scale found only in scale mode (tests/test_scale_mode.py)
    assert data["extra"]["clip_images"] > 0 and len(data["extra"]["phase_timings"]) == data["config"]["optim"]["phases"]
    frame = ["rotation", "changed", "up", "front", "front_trusted", "reason", "front_reason"]
    assert list(data["extra"]["target_upright"]) == list(data["extra"]["source_upright"]) == frame
    # runtime auto: torch where the CPU has native bf16, ONNX Runtime fp32 on the others (AVX2-only EPYCs)
    expected = runtime.resolve("auto", device="cpu", bf16=cpu_has_fast_bf16())
    assert (summary["model"], summary["runtime"]) == ("random:tiny", expected)
    assert preview.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def summary_matrix(summary: dict, report: dict) -> np.ndarray:
    """The report's matrix must agree with the translation the CLI printed."""
    m = np.array(report["transform"]["matrix"])
    np.testing.assert_allclose(m[:3, 3], summary["translation"], atol=1e-5)
    return m


@pytest.mark.parametrize("argv, needle", [
    (["--preset", "nope"], "unknown preset"),
    (["--restarts", "0"], "optim.restarts"),
    (["--contact-ratio", "2"], "contact_ratio"),
])
def test_cli_bad_options_exit_2_with_one_line(tmp_path, meshes, capsys, argv, needle):
    target, source = tmp_path / "t.stl", tmp_path / "s.stl"
    meshes[0].export(target)
    meshes[1].export(source)
    code = main(["align", str(target), str(source), "--prompt", "x", "--model", "random:tiny", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and needle in err[0] and err[0].startswith("error: invalid_option")


def test_cli_refuses_unreadable_mesh(tmp_path, capsys):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"not a mesh at all")
    code = main(["align", str(bad), str(bad), "--prompt", "x", "--preset", "test", "--model", "random:tiny"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("error: mesh_") and "\n" not in err


def test_align_with_the_upright_judge(meshes):
    """The opt-in semantic judge runs inside align with the configured model and reports its choice."""
    cfg = AlignConfig.from_preset("test", model="random:tiny", upright_judge=True)
    result = align(*meshes, "a cup on the table", cfg, target_name="table")
    upright = result.target_upright
    assert upright.reason.startswith("up: auto (the guidance model's judgement): judged")
    assert np.allclose(upright.rotation @ upright.rotation.T, np.eye(3), atol=1e-9)


_TRIANGLE = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
_SQUARE = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], [[0, 1, 2], [0, 2, 3]], process=False)
DEGENERATE = {  # (target, source): no volume, no hull (qhull needs 4 points off one plane), or sub-tolerance
    "single-triangle source": (trimesh.creation.box(), _TRIANGLE),
    "single-triangle target": (_TRIANGLE, trimesh.creation.box()),
    "planar pair": (_SQUARE, _TRIANGLE),
    "micrometre pair": (trimesh.creation.box(extents=(1e-6, 1e-6, 1e-6)),
                        trimesh.creation.icosphere(subdivisions=1, radius=3e-7)),
}


@pytest.mark.parametrize("case", list(DEGENERATE))
def test_degenerate_meshes_align(case):
    """Valid but unusual inputs succeed: canonicalisation, resting poses and hulls fall back."""
    target, source = DEGENERATE[case]
    result = align(target, source, "a thing on a thing", AlignConfig.from_preset("test", model="random:tiny"))
    matrix = result.source_to_target
    assert np.isfinite(result.objective) and np.isfinite(matrix).all()
    # posed at the target's scale: the source lands within a few target sizes of it
    distance = np.linalg.norm(matrix[:3, :3] @ source.bounds.mean(0) + matrix[:3, 3]
                              - target.bounds.mean(0))
    assert distance < 10 * target.extents.max()


def test_alternatives_of_a_round_cup_differ_by_more_than_a_spin_about_its_up():
    """The example cup is round about its up (the report's source frame finds it): no two alternatives stand at
    the same place (0.25 source diagonals) with its up pointing the same way (30 degrees), which would look the
    same, a spin about its axis alone."""
    table, cup = get_example("cup-on-table").meshes()
    config = AlignConfig.from_preset("test", model="random:tiny", optim={"restarts": 6})
    result = align(table, cup, "a cup on the table", config, target_name="table", source_name="cup")
    assert result.source_upright.symmetric and not result.target_upright.symmetric
    up, diagonal = result.source_upright.up, float(np.linalg.norm(cup.extents))
    placed = [np.asarray(a["source_to_target"]) for a in result.alternatives]
    assert len(placed) >= 2
    for i, a in enumerate(placed):
        for b in placed[:i]:
            apart = np.linalg.norm(a[:3, 3] - b[:3, 3]) / diagonal
            ua, ub = (m[:3, :3] @ up / np.linalg.norm(m[:3, :3] @ up) for m in (a, b))
            assert apart >= 0.25 - 1e-6 or np.degrees(np.arccos(np.clip(ua @ ub, -1, 1))) >= 30 - 1e-3


def test_alternative_turns_of_a_symmetric_source_are_told_apart_by_its_axis():
    """``diverse_top`` with a spin axis: a quarter turn about it is the same pose, a quarter turn across it is not;
    without one every quarter turn counts."""
    from ctp_core.search.coarse_to_fine import diverse_top
    from ctp_core.search.ordering import Key

    half = np.sqrt(0.5)
    q = torch.tensor([[1.0, 0, 0, 0], [half, 0, half, 0], [half, half, 0, 0]])  # none, about +Y, about +X
    poses = pose.Poses(torch.zeros(3, 3), q, torch.zeros(3))
    best = Key.plain(torch.tensor([0.0, 1.0, 2.0]))
    assert diverse_top(poses, best, 3, 0.1, 30.0, fill=False) == [0, 1, 2]
    assert diverse_top(poses, best, 3, 0.1, 30.0, fill=False, spin_axis=torch.tensor([0.0, 1.0, 0.0])) == [0, 2]


def test_alternatives_are_distinct_placements_the_answer_first(meshes):
    """Up to ``MAX_ALTERNATIVES`` of the refined restarts, no two within the search's duplicate thresholds (0.25
    source diagonals and 30 degrees), the answer first, each with its relation verdict and a thumbnail; a
    result's alternative k has that placement as its answer."""
    from ctp_core.config import MAX_ALTERNATIVES

    config = AlignConfig.from_preset("test", model="random:tiny", optim={"restarts": 6})
    result = align(*meshes, "a cup on the table", config, target_name="table", source_name="cup")
    alternatives = result.alternatives
    assert 2 <= len(alternatives) <= MAX_ALTERNATIVES and alternatives[0]["restart"] == result.best_restart
    np.testing.assert_allclose(alternatives[0]["source_to_target"], result.source_to_target)
    diagonal = float(np.linalg.norm(result.source.extents))
    for i, a in enumerate(alternatives):
        for b in alternatives[:i]:
            ma, mb = np.asarray(a["source_to_target"]), np.asarray(b["source_to_target"])
            apart = np.linalg.norm(ma[:3, 3] - mb[:3, 3]) / diagonal
            turn = np.degrees(np.arccos(np.clip((np.trace(ma[:3, :3] @ mb[:3, :3].T) - 1) / 2, -1, 1)))
            assert apart >= 0.25 - 1e-6 or turn >= 30 - 1e-3, (apart, turn)
        assert a["relation"]["name"] == "on"
    assert result.thumbnails.shape == (len(alternatives), 160, 160, 3)
    second = result.alternative(1)
    np.testing.assert_allclose(second.source_to_target, alternatives[1]["source_to_target"])
    assert second.best_restart == alternatives[1]["restart"] and result.best_restart == alternatives[0]["restart"]
