"""The command line's messages, as a new user meets them: one line each, the documented exit codes (2 bad
usage or input, 3 model unavailable), missing files reported before the engine is imported, a progress
line whose figures mean something, and one-line refusals from ``ctp serve``."""

from __future__ import annotations

import io
import shlex
import subprocess
import sys

import pytest
import trimesh

from ctp.cli import main
from ctp.cmd_align import ProgressBar
from ctp.cmd_serve import _say_if_default_model_missing
from ctp_core.io.examples import get_example
from ctp_core.progress import ProgressEvent
from service.embedded import EmbeddedRedis
from tests.conftest import REPO


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    return get_example("cup-on-table").write(tmp_path_factory.mktemp("pair"))


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_missing_input_is_reported_with_its_path_before_the_engine_loads(tmp_path):
    code = ("import sys; from ctp.cli import main; rc = main(sys.argv[1:]); "
            "print(sorted(m for m in ('torch', 'trimesh', 'ctp_core.align') if m in sys.modules)); sys.exit(rc)")
    run = subprocess.run([sys.executable, "-c", code, "align", str(tmp_path / "table.glb"), "cup.glb",
                          "--prompt", "a cup on the table"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert run.stderr.strip() == f"error: mesh_unreadable: target: no such file: {tmp_path / 'table.glb'}"
    assert run.stdout.strip() == "[]"  # nothing heavy was imported to find that out


def test_missing_image_and_directory_inputs(pair, tmp_path, capsys):
    assert main(["align", *map(str, pair), "--image", str(tmp_path / "ref.png")]) == 2
    assert one_line(capsys) == f"error: invalid_image: image: no such file: {tmp_path / 'ref.png'}"
    assert main(["align", str(tmp_path), str(pair[1]), "--prompt", "x"]) == 2
    assert one_line(capsys) == f"error: mesh_unreadable: target: not a file: {tmp_path}"


@pytest.mark.parametrize("spec", ["clip-vit", "onnx:model", "random:ViT-Z-99"])
def test_malformed_model_is_bad_usage(pair, capsys, spec):
    assert main(["align", *map(str, pair), "--prompt", "x", "--preset", "test", "--model", spec, "--quiet"]) == 2
    assert one_line(capsys).startswith("error: invalid_option: ")


def test_unavailable_model_exits_3_without_a_contradiction(pair, capsys):
    assert main(["align", *map(str, pair), "--prompt", "x", "--preset", "test", "--model",
                 "hf:/nonexistent/ctp-weights", "--quiet"]) == 3
    assert one_line(capsys) == ("error: model_unavailable: no transformers model directory at "
                                "/nonexistent/ctp-weights (expected config.json from save_pretrained)")


def test_weights_missing_offline_say_so_without_a_contradiction(pair, capsys, monkeypatch):
    monkeypatch.delenv("CTP_ALLOW_DOWNLOAD", raising=False)
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    assert main(["align", *map(str, pair), "--prompt", "x", "--preset", "test", "--model",
                 "hf:ctp-tests/never-cached", "--quiet"]) == 3
    line = one_line(capsys)
    assert line.startswith("error: model_unavailable: weights for 'ctp-tests/never-cached' are not in the Hugging")
    assert "downloads are off" in line and "connect" not in line  # transformers' "couldn't connect" tail is gone


def test_bad_usage_is_one_line_exit_2(capsys):
    assert main(["align"]) == 2
    line = one_line(capsys)
    assert line.startswith("error: usage: ctp align: the following arguments are required: TARGET, SOURCE")
    assert main(["example", "teapot"]) == 2
    assert "invalid choice: 'teapot'" in one_line(capsys)


def test_example_writes_the_sample_pair_and_says_what_to_run(tmp_path, capsys):
    assert main(["example", "apple-in-bowl", "--dir", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    assert out.split() == [str(tmp_path / "bowl.glb"), str(tmp_path / "apple.glb")]
    assert (tmp_path / "bowl.glb").stat().st_size > 0
    assert "ctp align" in err and "'an apple in a bowl'" in err and "--target-name bowl" in err


def test_example_suggests_a_command_that_runs_and_names_the_result_nodes(tmp_path, capsys):
    assert main(["example", "--dir", str(tmp_path)]) == 0
    command = shlex.split(capsys.readouterr().err.splitlines()[-1])
    assert command[:2] == ["ctp", "align"] and "--model" not in command  # the README's: the machine's best guide
    assert main([*command[1:], "--quiet"]) == 0
    scene = trimesh.load(tmp_path / "scene.glb", force="scene")
    assert set(scene.graph.nodes_geometry) == {"table", "cup"}


def event(kind: str, step: int, **readout) -> ProgressEvent:
    return ProgressEvent(kind=kind, phase=1, phases=2, step=step, steps=10, restarts=2, elapsed_s=1.0, eta_s=9.0,
                         best_objective=266.8, **readout)


def test_progress_shows_the_readout_not_the_objective():
    stream = io.StringIO()
    bar = ProgressBar(stream)
    bar(event("phase_start", 0))
    bar(event("step", 5, relation="on", relation_holds=2, relation_checked=3, guide_match=0.2468,
              contact_gap=0.0104))  # not drawn off a terminal, but remembered
    bar(event("phase_end", 5))
    lines = stream.getvalue().splitlines()
    assert lines[0] == ProgressBar.LEGEND and "match" in lines[0] and "gap" in lines[0]
    assert lines[1] == "phase_start: [....................] phase 1/2 step 0/10 eta    9s"
    assert lines[2] == "phase_end: [##########..........] phase 1/2 step 5/10 eta    9s holds 2/3 match 0.247 gap 1.0%"
    assert "266" not in stream.getvalue()


def test_a_second_serve_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("REDIS_URL", raising=False)
    monkeypatch.setenv("CTP_REDIS_DIR", str(tmp_path))
    with EmbeddedRedis(tmp_path):  # the first `make serve`
        assert main(["serve", "--port", "1"]) == 1
    line = one_line(capsys)
    assert line.startswith("error: redis_unavailable: another embedded Redis uses") and "already running" in line


def test_serve_says_in_one_line_how_to_get_past_missing_default_weights(capsys):
    _say_if_default_model_missing("random:tiny")
    assert capsys.readouterr().err == ""
    _say_if_default_model_missing("hf:/nonexistent/ctp-weights")
    line = one_line(capsys)
    assert "hf:/nonexistent/ctp-weights" in line and "provide its weights" in line and "CTP_MODEL=auto" in line
    _say_if_default_model_missing("hf:acme/clip")  # a Hub model: one command gets it
    line = one_line(capsys)
    assert "`ctp models pull acme/clip` gets it (or CTP_ALLOW_DOWNLOAD=1)" in line and "CTP_MODEL=auto" in line
    _say_if_default_model_missing("auto")  # the default, without weights (the session's cache is empty)
    line = one_line(capsys)
    assert line.startswith("ctp: jobs run without a guide: the default model hf:openai/clip-vit-base-patch32 is not "
                           "here (weights for ") and line.endswith(
        "`ctp models pull openai/clip-vit-base-patch32` gets the model (each next job uses it)")
