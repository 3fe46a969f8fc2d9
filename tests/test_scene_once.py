"""Made once per scene (``ctp_core.geometry.once``): a scene's steps, the checks of their candidates and the final
judgement ask again what they asked of objects that have not moved (their copies in the scene, surface samples,
render meshes, up and front, a verdict of the same scene). Each is made once within ``assemble``, and the scene
placed so is the one placed without keeping anything, bit for bit: every pose, verdict and choice."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
import trimesh

from ctp_core import pairs
from ctp_core.assembly import whole
from ctp_core.assembly.assemble import Assembly, Step, assemble
from ctp_core.config import AlignConfig
from ctp_core.geometry import field as fields
from ctp_core.geometry import once, sampling
from ctp_core.orientation import canonical
from tests.test_assemble import PLAN, table_plate_cup

CONFIG = AlignConfig.from_preset("test", model="random:tiny", seed=0, loss={"lambda_clip": 0.0}, optim={"steps": 40})


def _placed(meshes: dict[str, trimesh.Trimesh]) -> Assembly:
    """The table, a plate on it and a cup on the plate, geometry only (the test preset, a short refinement)."""
    steps = [Step(meshes[name], name, prompt, on=on) for name, prompt, on in PLAN]
    return assemble(meshes["table"], steps, CONFIG, base_name="table")


def _counted(patch: pytest.MonkeyPatch) -> tuple[Assembly, Counter, int, Counter]:
    """The scene placed with ``patch``'s changes, the surface samples it made (by the mesh sampled, the count and
    the seed), the verdicts it judged and the distance fields it built (by the samples' bytes)."""
    made: Counter = Counter()
    built: Counter = Counter()
    judged: list[int] = []
    sample, verdict, build = sampling.surface_samples, whole.verdict, fields.build

    def counted_sample(mesh: trimesh.Trimesh, count: int, seed: int):
        made.update([(id(mesh), count, seed)])
        return sample(mesh, count, seed)

    def counted_verdict(*args, **kwargs):
        judged.append(1)
        return verdict(*args, **kwargs)

    def counted_build(tree, points, normals, *args, **kwargs):
        built.update([np.asarray(points).tobytes()])
        return build(tree, points, normals, *args, **kwargs)

    with patch.context() as inner:
        inner.setattr(sampling, "surface_samples", counted_sample)
        inner.setattr(whole, "verdict", counted_verdict)
        inner.setattr(fields, "build", counted_build)
        placed = _placed(table_plate_cup())
    return placed, made, len(judged), built


@pytest.fixture(scope="module")
def runs() -> dict[str, tuple[Assembly, Counter, int, Counter]]:
    """The scene placed as it is (kept) and with nothing kept (fresh: every ``once.value`` made again)."""
    with pytest.MonkeyPatch.context() as patch:
        kept = _counted(patch)
        patch.setattr(once, "value", lambda key, build, pin=None: build())
        return {"kept": kept, "fresh": _counted(patch)}


def test_each_object_is_sampled_once_per_scene(runs):
    """Within the scene every object's samples (a target's in the scene frame with its seed, a source's in its own
    frame) are made once, though every step and every check prepares its pair afresh; without keeping them the same
    scene samples its objects again and again."""
    count = CONFIG.loss.samples  # the losses' samples (``pairs.prepare_pair``), not the other measures' few
    kept = [n for (_, samples, _), n in runs["kept"][1].items() if samples == count]
    fresh = [n for (_, samples, _), n in runs["fresh"][1].items() if samples == count]
    assert kept and max(kept) == 1  # the meshes sampled are all held by the scene's store: no identity is reused
    assert sum(fresh) > 2 * sum(kept)


def test_each_objects_distance_field_is_built_once_per_scene(runs):
    """A scene's normalised frame moves as objects are added, so a field of all its samples would be built again at
    every step; each object's own field (``pairs._field``, target upright frame) is built once and read in each
    step's frame (``field.FieldUnion``). Without keeping them the table's is built at every step."""
    kept, fresh = runs["kept"][3], runs["fresh"][3]
    assert kept and max(kept.values()) == 1
    assert max(fresh.values()) > 1


def test_the_final_judgement_judges_nothing_again(runs):
    """The final scene is the scene the last step's answer was judged in: its verdicts are not judged again."""
    kept, _, kept_judged, _ = runs["kept"]
    _, _, fresh_judged, _ = runs["fresh"]
    finals = len(kept.whole["relations"])
    assert finals == 2 and kept_judged <= fresh_judged - finals


def test_what_is_kept_places_and_judges_as_without(runs):
    """Bit for bit: every object's pose, each step's choice among its candidates, its run's answer and
    alternatives, and the final judgement."""
    kept, _, _, _ = runs["kept"]
    fresh, _, _, _ = runs["fresh"]
    for a, b in zip(kept.objects, fresh.objects, strict=True):
        assert a.name == b.name and np.array_equal(a.to_scene.matrix, b.to_scene.matrix)
    for a, b in zip(kept.results, fresh.results, strict=True):
        assert a.kept == b.kept and a.result.relation == b.result.relation
        assert np.array_equal(a.result.source_to_target, b.result.source_to_target)
        assert [np.asarray(x["source_to_target"]).tobytes() for x in a.result.alternatives] == [
            np.asarray(x["source_to_target"]).tobytes() for x in b.result.alternatives]
    assert kept.whole == fresh.whole


def test_outside_a_scene_nothing_is_kept():
    """A single pair, or any call outside ``assemble`` and ``place_copies``, makes everything afresh."""
    mesh = trimesh.creation.box()
    assert pairs.outward(mesh) is not pairs.outward(mesh)
    with once.scene():
        fixed = pairs.outward(mesh)
        assert pairs.outward(mesh) is fixed
        mesh.apply_translation((0.1, 0.0, 0.0))  # changed in place: never answered from what was kept before
        assert pairs.outward(mesh) is not fixed
        assert np.array_equal(pairs.outward(mesh).vertices, fixed.vertices + [0.1, 0.0, 0.0])


def test_copies_of_one_object_find_their_resting_poses_once(monkeypatch):
    """An object's resting poses (``canonical.unit_resting_poses``) are kept within a scene by its content: a copy
    of it asks nothing again, a changed one does, and outside a scene every call finds them afresh."""
    found: list[int] = []
    resting_poses = canonical.resting_poses
    monkeypatch.setattr(canonical, "resting_poses", lambda mesh: found.append(1) or resting_poses(mesh))
    box = trimesh.creation.box((1.0, 2.0, 3.0))
    with once.scene():
        first = canonical.unit_resting_poses(box)
        assert canonical.unit_resting_poses(box.copy()) is first and len(found) == 1
        box.apply_scale((1.0, 1.0, 2.0))
        assert canonical.unit_resting_poses(box) != first and len(found) == 2
    assert canonical.unit_resting_poses(box) == resting_poses(canonical.unit_size(box)) and len(found) == 3
