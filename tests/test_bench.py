"""The benchmark harness: case discovery, the perturbation protocol, b1, and ``ctp bench`` end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ctp_core.bench import baselines, cases, protocol
from ctp_core.errors import ConfigError


def _write_case(folder: Path, case_id: str, target: trimesh.Trimesh, source: trimesh.Trimesh,
                reference: np.ndarray | None, prompt: str) -> Path:
    folder.mkdir(parents=True)
    target.export(folder / "target.glb")
    source.export(folder / "source.glb")
    data = {"id": case_id, "prompt": prompt, "origin": "synthetic",
            "target": {"file": "target.glb", "name": "block"}, "source": {"file": "source.glb", "name": "cap"},
            "reference": None if reference is None else {"source_to_target": reference.tolist(), "scale": 1.0},
            "relation": "on_top", "penetration_expected": False}
    (folder / "case.json").write_text(json.dumps(data))
    return folder


def _translation(x, y, z) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


@pytest.fixture(scope="module")
def bench_dir(tmp_path_factory) -> Path:
    """Two generated cases with a known arrangement, nested one level deeper to exercise the recursive search."""
    root = tmp_path_factory.mktemp("cases")
    block = trimesh.creation.box((1.0, 0.6, 0.8))
    cap = trimesh.creation.cylinder(radius=0.2, height=0.3, sections=24)
    cap.apply_translation((3.0, 1.0, -2.0))  # file pose far from the answer, as in the real cases
    on_top = _translation(-3.0, -1.0 + 0.3 + 0.15, 2.0)
    _write_case(root / "set" / "a", "gen-cap-on-block", block, cap, on_top, "a cap on top of a block")
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    cone = trimesh.creation.cone(radius=0.25, height=0.4, sections=16)
    beside = trimesh.transformations.rotation_matrix(0.4, [0, 0, 1])
    beside[:3, 3] = (0.8, -0.3, 0.1)
    _write_case(root / "set" / "b", "gen-cone-by-ball", ball, cone, beside, "a cone beside a ball")
    return root


def test_discover_finds_nested_cases_and_selects_by_id(bench_dir):
    found = cases.discover(bench_dir)
    assert [c.id for c in found] == ["gen-cap-on-block", "gen-cone-by-ball"]
    assert found[0].reference.shape == (4, 4) and found[0].target_file.exists()
    assert [c.id for c in cases.discover(bench_dir, ["gen-cone-by-ball"])] == ["gen-cone-by-ball"]
    with pytest.raises(ConfigError, match="unknown case"):
        cases.discover(bench_dir, ["nope"])


def test_discover_refuses_duplicate_ids(tmp_path):
    box = trimesh.creation.box()
    for name in ("x", "y"):
        _write_case(tmp_path / name, "same", box, box, None, "p")
    with pytest.raises(ConfigError, match="duplicate"):
        cases.discover(tmp_path)


def test_protocol_is_deterministic_per_case():
    bounds = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5]])
    ref = _translation(5, 0, 0)
    first = protocol.initial_poses(ref, bounds, protocol="rigid", count=3, seed=7, case_id="a")
    again = protocol.initial_poses(ref, bounds, protocol="rigid", count=3, seed=7, case_id="a")
    other = protocol.initial_poses(ref, bounds, protocol="rigid", count=3, seed=7, case_id="b")
    reseeded = protocol.initial_poses(ref, bounds, protocol="rigid", count=3, seed=8, case_id="a")
    assert all(np.array_equal(x, y) for x, y in zip(first, again, strict=True))
    assert not np.allclose(first[0], other[0]) and not np.allclose(first[0], reseeded[0])
    assert len({m.tobytes() for m in first}) == 3  # the inits of one case differ from each other


def test_protocol_ranges():
    bounds = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5]])
    sides, centre = np.array([1.0, 2.0, 0.5]), np.array([0.5, 1.0, 0.25])
    ref = _translation(5, 0, 0)
    rigid = protocol.initial_poses(ref, bounds, protocol="rigid", count=200, seed=0, case_id="c")
    shifts = np.array([(m[:3, :3] @ centre + m[:3, 3]) - (centre + ref[:3, 3]) for m in rigid])
    assert np.all(np.abs(shifts) <= 10 * sides + 1e-9)  # the centre moves by U(-10 L, 10 L) per axis
    assert np.all(np.abs(shifts).max(axis=0) > 7 * sides)  # and uses the range
    for m in rigid:
        assert np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-9)  # rigid: rotation only
    angles = [math.degrees(math.acos(np.clip((np.trace(m[:3, :3]) - 1) / 2, -1, 1))) for m in rigid]
    assert max(angles) > 150  # Euler angles over ±180° reach large turns
    scaled = protocol.initial_poses(ref, bounds, protocol="scale", count=200, seed=0, case_id="c")
    scales = np.array([np.cbrt(np.linalg.det(m[:3, :3])) for m in scaled])
    assert np.all((scales >= 0.01) & (scales <= 100)) and scales.max() > 50


def test_random_starts_sit_two_to_four_radii_out():
    target, source = np.array([[-1.0, -1, -1], [1, 1, 1]]), np.array([[2.0, 2, 2], [2.5, 3, 2.2]])
    starts = protocol.random_starts(target, source, 1.5, 50, np.random.default_rng(0))
    radius = math.sqrt(3)
    centre = source.mean(axis=0)
    distances = [np.linalg.norm(m[:3, :3] @ centre + m[:3, 3]) / radius for m in starts]
    assert min(distances) >= 2 - 1e-9 and max(distances) <= 4 + 1e-9
    assert all(np.cbrt(np.linalg.det(m[:3, :3])) == pytest.approx(1.5) for m in starts)


def test_shrinkwrap_lands_on_the_surface_without_penetrating():
    from ctp_core import metrics

    target = trimesh.creation.box((2.0, 1.0, 2.0))
    source = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    above = _translation(0.1, 3.0, -0.2)  # the nearest target point is on the top face
    inside = _translation(0.0, 0.3, 0.0)  # starts half inside, just under the top face
    for pose in baselines.shrinkwrap(target, source, [above, inside]):
        placed = source.copy()
        placed.apply_transform(pose)
        assert metrics.intersection_over_union(target, placed).iou < 1e-3
        assert metrics.contact_distance(target, placed) < 0.01
        assert pose[1, 3] == pytest.approx(0.7, abs=0.02)  # resting on the top face (y = 0.5)


def _bench(*args: str) -> int:
    from ctp.cli import main

    return main(["bench", *args, "--model", "random:tiny", "--preset", "test", "--quiet"])


def _finite(value) -> bool:
    return bool(np.all(np.isfinite(np.asarray(value, dtype=float))))


def test_ctp_bench_end_to_end(bench_dir, tmp_path):
    out = tmp_path / "out"
    code = _bench(str(bench_dir), "--method", "ctp,geometry", "--method", "b1,b2", "--guide", "oracle",
                  "--metrics-model", "random:tiny", "--out", str(out))
    assert code == 0
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert sorted((r["case"], r["method"]) for r in rows) == sorted(
        (c, m) for c in ("gen-cap-on-block", "gen-cone-by-ball") for m in ("ctp", "geometry", "b1", "b2"))
    for case in cases.discover(bench_dir):
        source = case.load()[1]
        start = protocol.initial_poses(case.reference, source.bounds, protocol="rigid", count=1, seed=0,
                                       case_id=case.id)[0]
        for row in (r for r in rows if r["case"] == case.id):  # every method starts from the protocol pose
            assert np.allclose(row["initial_pose"], start)
    for row in rows:
        assert row["status"] == "ok", row.get("error")
        metrics = row["metrics"]
        for key in ("iou", "contact", "adds", "translation_error", "rotation_error_deg", "scale_error"):
            assert _finite(metrics[key]), (row["method"], key)
        assert 0.0 <= metrics["iou"] <= 1.0 and metrics["iou_method"] == "exact"
        assert metrics["scale_error"] == pytest.approx(0.0, abs=1e-5)  # rigid protocol keeps the scale
        assert _finite(metrics["semantic"]["random:tiny"])
        assert np.asarray(row["source_to_target"]).shape == (4, 4) and _finite(row["source_to_target"])
        assert row["time_s"] > 0
        guided = row["method"] in ("ctp", "b2")
        assert (row["guide"], row["encoder"]) == (("oracle", "random:tiny") if guided else (None, None))
        assert (row["clip_images"] > 0) == guided
    summary = (out / "summary.md").read_text()
    for label in ("| b1 |", "| b2 oracle/random:tiny |", "| ctp oracle/random:tiny (test) |", "| geometry (test) |"):
        assert label in summary
    for name in ("tradeoff.png", "pose_cdf.png", "time_per_case.png"):
        assert (out / name).stat().st_size > 1000

    lines = (out / "results.jsonl").read_text()
    assert _bench(str(bench_dir), "--method", "b1", "--out", str(out), "--resume") == 0
    assert (out / "results.jsonl").read_text() == lines  # b1 rows were done: nothing reran
    assert len((out / "commands.txt").read_text().splitlines()) == 2
    (out / "summary.md").unlink()
    assert _bench(str(bench_dir), "--out", str(out), "--summary-only") == 0
    assert "| geometry (test) |" in (out / "summary.md").read_text()


def test_guides_needing_a_reference_skip_cases_without_one(tmp_path):
    box = trimesh.creation.box()
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    _write_case(tmp_path / "cases" / "n", "no-reference", box, ball, None, "a ball on a box")
    out = tmp_path / "out"
    assert _bench(str(tmp_path / "cases"), "--method", "b1,b2", "--guide", "oracle", "--out", str(out)) == 0
    rows = {r["method"]: r for r in map(json.loads, (out / "results.jsonl").read_text().splitlines())}
    assert rows["b1"]["status"] == "ok" and "adds" not in rows["b1"]["metrics"]  # no reference: no pose error
    assert rows["b2"]["status"] == "skipped" and "reference" in rows["b2"]["error"]


def test_one_skipped_case_never_costs_the_run_its_summary(bench_dir, tmp_path):
    """A folder where one case has no reference: the oracle skips it (its guide description is None) while the
    other case's rows carry one; the summary is still written, the skipped row among its notes."""
    cases_dir = tmp_path / "cases"
    (cases_dir / "a").mkdir(parents=True)
    for name in ("target.glb", "source.glb", "case.json"):
        (cases_dir / "a" / name).write_bytes((bench_dir / "set" / "a" / name).read_bytes())
    _write_case(cases_dir / "n", "no-reference", trimesh.creation.box(), trimesh.creation.icosphere(1, 0.3), None,
                "a ball on a box")
    out = tmp_path / "out"
    assert _bench(str(cases_dir), "--method", "b1,b2", "--guide", "oracle", "--out", str(out)) == 0
    rows = {(r["case"], r["method"]): r for r in map(json.loads, (out / "results.jsonl").read_text().splitlines())}
    assert rows[("no-reference", "b2")]["status"] == "skipped"
    assert rows[("gen-cap-on-block", "b2")]["guide_description"]
    summary = (out / "summary.md").read_text()
    assert "no-reference init 0" in summary and "skipped" in summary


def test_relations_are_judged_in_the_reference_frame_with_valid_and_placement_at_k(tmp_path):
    """A table authored on its legs in a GLB, and a cup on its top: the run's own frame cannot make a cup at the
    foot of a leg hold "on"; ``valid`` needs no intersection, ``placement_at_k`` any alternative that places."""
    from ctp_core.bench import harness

    table = trimesh.util.concatenate(
        [trimesh.creation.box((1.6, 0.06, 0.9)).apply_translation((0, 0.72, 0))]
        + [trimesh.creation.box((0.06, 0.7, 0.06)).apply_translation((x, 0.35, z)) for x in (-0.75, 0.75)
           for z in (-0.4, 0.4)])
    cup = trimesh.creation.cylinder(radius=0.08, height=0.2, sections=24)
    cup.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))  # standing, along +Y
    on_top = _translation(0.0, 0.75 + 0.1, 0.0)
    _write_case(tmp_path / "c", "table-cup", table, cup, on_top, "a cup on the table")
    case = cases.discover(tmp_path)[0]
    data = harness._load(case, harness.BenchOptions(preset="test"), need_guide=False)
    pair = harness._judge(data)[0]
    assert not pair.target_upright.changed and "reference" in pair.target_upright.reason
    assert pair.front_trusted and np.allclose(pair.target_front, [0, 0, 1])  # glTF's front, for directional relations
    right = harness.evaluate(data, on_top)
    assert right["relation"] == "on" and right["relation_holds"] and right["valid"]
    assert right["placement_success"] and right["placement_at_k"]
    under_the_top = _translation(0.6, 0.1, 0.3)  # at a leg's foot: on the table only if it were upside down
    wrong = harness.evaluate(data, under_the_top, [under_the_top, on_top])
    assert not wrong["relation_holds"] and not wrong["valid"]
    assert not wrong["placement_success"] and wrong["placement_at_k"] and wrong["alternatives"] == 2
    # the same pose with an intersection over the placement threshold is not valid
    assert not harness.relation_metrics(data, on_top, iou=0.05)["valid"]


@pytest.mark.parametrize("name", ["no-guidance", "no-icp", "no-pen", "no-phases", "no-camera-schedule",
                                  "selection-only", "no-relation", "paper"])
def test_every_ablation_changes_its_switch(name):
    from ctp_core.bench.harness import BenchOptions

    base = BenchOptions(preset="test").config("ctp")
    config = BenchOptions(preset="test", ablation=name).config("ctp")
    changed = {
        "no-guidance": config.loss.lambda_clip == 0.0,
        "no-icp": config.loss.lambda_icp == (0.0, 0.0),
        "no-pen": config.loss.lambda_pen == (0.0, 0.0),
        "no-phases": config.optim.phases == 1,
        "no-camera-schedule": config.camera.schedule is False,
        "selection-only": config.loss.selection_only is True,
        "no-relation": config.relation is False and base.relation is True,
        "paper": config.preset == "paper" and config.optim.steps > base.optim.steps,
    }
    assert changed[name]
    assert config != base


def test_bench_configs_follow_protocol_and_method():
    from ctp_core.bench.harness import BenchOptions

    options = BenchOptions(preset="test", protocol="scale", model="random:tiny", seed=3)
    ctp, geometry = options.config("ctp"), options.config("geometry")
    assert ctp.scale and ctp.model == "random:tiny" and ctp.seed == 3 and ctp.loss.lambda_clip > 0
    assert geometry.loss.lambda_clip == 0.0 and geometry.scale
    with pytest.raises(ConfigError):
        BenchOptions(methods=["nope"])


def test_image_guide_is_a_render_of_the_reference(bench_dir):
    from ctp_core.bench import guides

    case = cases.discover(bench_dir, ["gen-cap-on-block"])[0]
    target, source = case.load()
    image = guides.reference_image(target, source, case.reference, np.random.default_rng(1), image_size=64)
    again = guides.reference_image(target, source, case.reference, np.random.default_rng(1), image_size=64)
    assert image.shape == (64, 64, 3) and image.dtype == np.uint8
    assert np.array_equal(image, again)
    assert (image < 250).any(axis=-1).mean() > 0.05  # the objects cover part of the white background


def test_pixels_guide_is_labelled_and_reports_placement_success(bench_dir, tmp_path):
    """The upper-bound instrument: no encoder, its own label in rows and summary, placement next to success."""
    out = tmp_path / "out"
    assert _bench(str(bench_dir), "--cases", "gen-cap-on-block", "--method", "ctp,b2", "--guide", "pixels",
                  "--out", str(out)) == 0
    rows = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    for row in rows:
        assert row["status"] == "ok", row.get("error")
        assert (row["guide"], row["encoder"]) == ("pixels", "none (pixels)")
        assert "upper-bound" in row["guide_description"]
        m = row["metrics"]
        assert m["placement_success"] == (m["centroid_error"] <= 0.5 and m["iou"] <= 0.02)
        # the relation the priors read from the prompt, judged on the answer (ctp_core/relations/predicates.py)
        assert m["relation"] is None or isinstance(m["relation_holds"], bool)
    summary = (out / "summary.md").read_text()
    assert "| ctp pixels (upper bound, no encoder) (test) |" in summary and "placement" in summary
    assert "relation holds" in summary and "stable" in summary


def test_pixel_guide_embeds_renders_as_images():
    import torch

    from ctp_core.bench.guides import PixelGuide

    guide = PixelGuide(size=8)
    white = torch.ones(1, 3, 32, 32)
    dot, shifted = white.clone(), white.clone()
    dot[..., 4:12, 4:12] = 0.2
    shifted[..., 20:28, 20:28] = 0.2
    images = torch.cat([dot, shifted]).requires_grad_(True)
    emb = guide.encode_images(images)
    assert emb.shape == (2, guide.embed_dim)
    assert guide.score(dot, emb[0])[0] == pytest.approx(1.0, abs=1e-6)
    assert guide.score(shifted, emb[0])[0] < 0.1  # no overlap: far apart as images
    (emb[0] @ emb[1]).backward()
    assert images.grad.abs().sum() > 0  # the optimiser can follow it


def test_placement_success_is_rotation_free():
    from ctp_core import metrics

    points = np.random.default_rng(0).normal(size=(500, 3))
    reference = np.eye(4)
    turned = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
    errors = metrics.pose_errors(points, turned, reference)
    assert errors["rotation_error_deg"] == pytest.approx(90.0) and errors["centroid_error"] < 0.1
    assert metrics.placement_success(errors["centroid_error"], 0.0)
    assert not metrics.placement_success(errors["centroid_error"], 0.05)
    assert not metrics.placement_success(0.6, 0.0)


def test_scale_protocol_finds_the_scale_and_the_baselines_keep_theirs(bench_dir, tmp_path):
    """Scale protocol: geometry's answer takes its scale from the priors (the start is scaled by U(0.01, 100));
    b1 keeps the scale it is given; the summary labels the protocol and gives the scale error."""
    out = tmp_path / "out"
    assert _bench(str(bench_dir), "--cases", "gen-cap-on-block", "--method", "geometry,b1", "--protocol", "scale",
                  "--out", str(out)) == 0
    rows = {r["method"]: r for r in map(json.loads, (out / "results.jsonl").read_text().splitlines())}
    start = np.asarray(rows["b1"]["initial_pose"])
    given = float(np.cbrt(np.linalg.det(start[:3, :3])))
    assert abs(math.log(given)) > 0.5  # the protocol's factor is not near 1 here, so the two tell apart
    assert rows["b1"]["metrics"]["scale_error"] == pytest.approx(abs(math.log(given)), abs=1e-6)
    geometry = rows["geometry"]
    assert geometry["status"] == "ok" and geometry["metrics"]["scale_error"] < abs(math.log(given))
    summary = (out / "summary.md").read_text()
    assert "(test, scale protocol) |" in summary and "scale err" in summary


def test_ctp_bench_places_several_copies_and_reports_each_and_the_set(bench_dir, tmp_path):
    """``--count 2``: two caps on the block, the first judged against the reference as one placement, each copy's
    verdict and the set's measures in the row and the summary; what the harness cannot place is refused (exit 2)."""
    out = tmp_path / "copies"
    assert _bench(str(bench_dir), "--cases", "gen-cap-on-block", "--method", "geometry", "--count", "2",
                  "--out", str(out)) == 0
    (row,) = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert row["status"] == "ok", row.get("error")
    assert row["copies"] == "2 auto" and row["copy_set"]["arrangement"] == "scatter"
    per_copy = row["copy_set"]["per_copy"]
    assert [c["name"] for c in per_copy] == ["cap_1", "cap_2"] and all(c["holds"] for c in per_copy), per_copy
    assert row["copy_set"]["set"]["count"] == 2 and row["copy_set"]["set"]["none_intersect"]
    assert "placement_success" in row["metrics"]  # the first copy, against the reference
    summary = (out / "summary.md").read_text()
    assert "| copies hold | sets apart |" in summary and "geometry (test, 2 auto copies)" in summary
    assert "100% (2/2) | 100% (1/1)" in summary
    for bad in (["--count", "13"], ["--count", "2", "--method", "b1"], ["--count", "2", "--method", "ctp", "--guide",
                                                                        "oracle"]):
        assert _bench(str(bench_dir), "--method", "geometry", *bad, "--out", str(tmp_path / "bad")) == 2
