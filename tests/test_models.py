"""``ctp models`` and model ``auto``: pulling a model from a loopback server that speaks the Hub's HTTP API (a
small random CLIP in a Hugging Face repository's layout; never the real hub), resuming a broken download,
refusing a corrupt one, failing in one line when the Hub cannot be reached; and ``auto`` picking the default model
where its weights are in the cache, running without a guide (and saying so) where they are not."""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from ctp.cmd_models import _Bar
from ctp_core.config import DEFAULT_MODEL, AlignConfig
from ctp_core.errors import ModelError
from ctp_core.guide import checkpoints, store
from ctp_core.guide.selection import NONE, resolve, unguided
from ctp_core.io.examples import get_example
from tests.conftest import REPO
from tests.test_guidance import _save_tiny_hf_clip

REPO_ID = "ctp-test/tiny-clip"
COMMIT = "c" * 40


class FakeHub:
    """The two routes of the Hub that ``store.pull`` uses, over a folder of files, on 127.0.0.1; the
    ``.safetensors`` files are LFS files (sha256), the others plain git files (blob id). ``cut``: the first answer
    for that file stops after this many bytes; ``corrupt``: that file is served altered; ``ranges``: the Range
    headers received."""

    def __init__(self, files: dict[str, bytes]):
        self.files, self.cut, self.corrupt, self.ranges = files, {}, set(), []
        hub = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                path = self.path.split("?")[0]
                if path == f"/api/models/{REPO_ID}/revision/main":
                    return self._send(200, json.dumps({"sha": COMMIT, "siblings": hub.siblings()}).encode())
                prefix = f"/{REPO_ID}/resolve/{COMMIT}/"
                name = path.removeprefix(prefix)
                if not path.startswith(prefix) or name not in hub.files:
                    return self._send(404, b"{}")
                data = hub.files[name]
                if name in hub.corrupt:
                    data = bytes([data[0] ^ 1]) + data[1:]
                start = 0
                if "Range" in self.headers:
                    hub.ranges.append(self.headers["Range"])
                    start = int(self.headers["Range"].removeprefix("bytes=").rstrip("-"))
                body = data[start:]
                self.send_response(206 if start else 200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                cut = hub.cut.pop(name, None)
                self.wfile.write(body if cut is None else body[:cut])  # a cut answer ends short: the client sees it

            def _send(self, status: int, body: bytes):
                self.send_response(status)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def siblings(self) -> list[dict]:
        out = []
        for name, data in self.files.items():
            entry = {"rfilename": name, "size": len(data),
                     "blobId": hashlib.sha1(f"blob {len(data)}\0".encode() + data).hexdigest()}  # noqa: S324
            if name.endswith(".safetensors"):
                entry["lfs"] = {"sha256": hashlib.sha256(data).hexdigest(), "size": len(data), "pointerSize": 134}
            out.append(entry)
        return out


@pytest.fixture(autouse=True)
def hub_settings(monkeypatch):
    """The Hub settings of the machine running the tests do not reach the pulls here (each test sets its own)."""
    for name in ("HF_HUB_OFFLINE", "HF_ENDPOINT", "HF_TOKEN", "CTP_ALLOW_DOWNLOAD"):
        monkeypatch.delenv(name, raising=False)


@pytest.fixture(scope="module")
def tiny_files(tmp_path_factory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("tiny-clip")
    _save_tiny_hf_clip(folder)
    files = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    files["flax_model.msgpack"] = b"another framework's weights: not pulled"
    return files


@pytest.fixture
def hub(tiny_files):
    server = FakeHub(tiny_files)
    yield server
    server.server.shutdown()
    server.server.server_close()


def ctp(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ctp", *args], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300)


def hf_env(home: Path, **extra: str) -> dict[str, str]:
    import os

    env = {k: v for k, v in os.environ.items() if not k.startswith(("CTP_", "HF_"))}
    return {**env, "HF_HOME": str(home), "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", **extra}


def test_pull_from_a_loopback_hub_then_list_load_and_remove(hub, tmp_path, tiny_files):
    env = hf_env(tmp_path / "hf", HF_ENDPOINT=hub.url)
    pulled = ctp("models", "pull", REPO_ID, env=env)
    assert pulled.returncode == 0, pulled.stderr
    assert pulled.stderr == ""  # not a terminal: no progress bar, only the final line
    sha = hashlib.sha256(tiny_files["model.safetensors"]).hexdigest()
    cache = tmp_path / "hf" / "hub"
    [line] = pulled.stdout.strip().splitlines()
    assert line.startswith(f"pulled hf:{REPO_ID} (") and line.endswith(f" MB, sha256 {sha}) into {cache}")
    snapshot = cache / f"models--{REPO_ID.replace('/', '--')}" / "snapshots" / COMMIT
    assert sorted(p.name for p in snapshot.iterdir()) == sorted(n for n in tiny_files if n != "flax_model.msgpack")
    assert (snapshot / "model.safetensors").is_symlink()
    assert checkpoints.missing(f"hf:{REPO_ID}", cache_dir=str(cache), offline=True) is None

    from ctp_core.guide.loaders import load_guide

    assert load_guide(f"hf:{REPO_ID}", offline=True, cache_dir=str(cache)).embed_dim == 16  # what the loader reads

    listed = ctp("models", "list", env=env)
    assert listed.returncode == 0, listed.stderr
    assert f"hf:{REPO_ID}" in listed.stdout and f"sha256 {sha}  ready" in listed.stdout
    assert "ctp models pull" in listed.stdout  # the default model is not cached
    again = ctp("models", "pull", REPO_ID, env=env)  # everything verified already: nothing fetched
    assert again.returncode == 0 and hub.ranges == []
    removed = ctp("models", "rm", f"hf:{REPO_ID}", env=env)
    assert removed.returncode == 0 and not snapshot.exists()
    gone = ctp("models", "rm", REPO_ID, env=env)
    assert gone.returncode == 2 and gone.stderr.startswith("error: model_not_cached: ")


def test_a_broken_download_resumes_where_it_stopped(hub, tmp_path, tiny_files):
    hub.cut["model.safetensors"] = 1000
    with pytest.raises(ModelError, match="run it again to resume") as broken:
        store.pull(REPO_ID, cache_dir=tmp_path, endpoint=hub.url)
    assert broken.value.code == "model_unreachable"
    seen: list[tuple[int, int]] = []
    model = store.pull(REPO_ID, cache_dir=tmp_path, endpoint=hub.url,
                             on_progress=lambda done, total: seen.append((done, total)))
    assert hub.ranges == ["bytes=1000-"]
    assert model.ready and model.sha256 == hashlib.sha256(tiny_files["model.safetensors"]).hexdigest()
    assert seen[-1][0] == seen[-1][1] == sum(len(v) for k, v in tiny_files.items() if k != "flax_model.msgpack")


def test_a_corrupt_download_is_refused_and_not_kept(hub, tmp_path):
    hub.corrupt.add("model.safetensors")
    with pytest.raises(ModelError, match="does not match the Hub's checksum") as refused:
        store.pull(REPO_ID, cache_dir=tmp_path, endpoint=hub.url)
    assert refused.value.code == "model_corrupt"
    assert checkpoints.missing(f"hf:{REPO_ID}", cache_dir=str(tmp_path), offline=True) is not None
    assert not list(tmp_path.rglob("*.incomplete"))


def test_offline_or_unreachable_is_one_line_and_a_failure(tmp_path):
    from service.embedded import free_port

    unreachable = ctp("models", "pull", env=hf_env(tmp_path, HF_ENDPOINT=f"http://127.0.0.1:{free_port()}"))
    assert unreachable.returncode == 3
    assert unreachable.stderr.startswith("error: model_unreachable: cannot reach http://127.0.0.1:")
    assert len(unreachable.stderr.strip().splitlines()) == 1
    offline = ctp("models", "pull", env=hf_env(tmp_path, HF_HUB_OFFLINE="1"))
    assert offline.returncode == 3 and "HF_HUB_OFFLINE is set" in offline.stderr
    assert ctp("models", "pull", "/some/folder", env=hf_env(tmp_path)).returncode == 2


def test_choosing_and_pulling_import_no_torch():
    code = "import sys; from ctp_core.guide import selection, store; print('torch' in sys.modules)"
    run = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.stdout.strip() == "False", run.stderr


def test_the_progress_bar_redraws_on_a_terminal_only():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    tty, pipe = Tty(), io.StringIO()
    for stream in (tty, pipe):
        bar = _Bar(stream, "acme/clip")
        bar(5_000_000, 10_000_000)
        bar(10_000_000, 10_000_000)
        bar.close()
    assert tty.getvalue().startswith("\r[##########..........] 5.0 MB / 10.0 MB acme/clip")
    assert tty.getvalue().endswith("10.0 MB / 10.0 MB acme/clip\033[K\n")
    assert pipe.getvalue() == ""


def test_auto_runs_without_a_guide_where_the_default_model_is_missing():
    config = AlignConfig.from_preset("test")
    assert config.model == "auto"
    choice = unguided("weights for 'x' are not in the cache. Provide them")
    ran, stated = resolve(config, choice=choice)
    assert (ran.loss.lambda_clip, ran.upright_judge, ran.uses_model) == (0.0, False, False)
    assert stated.guide == NONE and stated.get_model == "ctp models pull openai/clip-vit-base-patch32"
    for asked, kwargs in (("image guidance", {"image": True}), ("the upright judge", {})):
        judged = config.merged({"upright_judge": True}) if not kwargs else config
        with pytest.raises(ModelError, match=f"asks for {asked}.*`ctp models pull openai/clip-vit-base-patch32`"):
            resolve(judged, choice=choice, **kwargs)
    named = config.merged({"model": "random:tiny"})
    assert resolve(named, choice=choice) == (named, resolve(named)[1])  # an explicit model is never replaced
    assert resolve(named)[1].guide == "random:tiny"


def test_ctp_align_with_default_options_states_its_guide(tmp_path):
    """``ctp align`` as a new user runs it (no --model): without the default model's weights no guide, with them
    (a small random CLIP saved as that repository in the real cache layout) that model; the summary and the
    report say which and why."""
    get_example("cup-on-table").write(tmp_path / "try")
    args = ("align", "try/table.glb", "try/cup.glb", "--prompt", "a cup on the table", "--preset", "test", "--quiet",
            "--out", "try/scene.glb", "--report", "try/report.json")

    def run(home: Path) -> tuple[dict, str]:
        done = subprocess.run([sys.executable, "-m", "ctp", *args], cwd=tmp_path, env=hf_env(home), capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        summary = json.loads(done.stdout)
        report = json.loads((tmp_path / "try" / "report.json").read_text())
        assert (report["guide"], report["guide_why"]) == (summary["guide"], summary["guide_why"])
        return summary, done.stderr

    bare, said = run(tmp_path / "empty")
    assert bare["guide"] == "none" and bare["model"] is None
    assert "not in the Hugging Face cache" in bare["guide_why"]
    assert said.startswith("note: no guide: the default model hf:openai/clip-vit-base-patch32 is not here") and \
        said.rstrip().endswith("`ctp models pull openai/clip-vit-base-patch32` gets the model")
    cache = tmp_path / "hf" / "hub"
    snapshot = cache / f"models--{DEFAULT_MODEL.removeprefix('hf:').replace('/', '--')}" / "snapshots" / COMMIT
    snapshot.mkdir(parents=True)
    _save_tiny_hf_clip(snapshot)
    (snapshot.parents[1] / "refs").mkdir()
    (snapshot.parents[1] / "refs" / "main").write_text(COMMIT)
    cached, said = run(tmp_path / "hf")
    assert "note:" not in said
    assert cached["guide"] == cached["model"] == DEFAULT_MODEL and cached["guide_why"].startswith("auto: ")
