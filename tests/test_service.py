"""The HTTP service against a real Redis, a real uvicorn and a real ``ctp worker``: the contract
(openapi.yaml), validation of bad uploads before queueing, auth and per-key limits, and one job end to
end with the tiny random model."""

from __future__ import annotations

import io
import json
import struct
import zipfile

import numpy as np
import pytest
import trimesh
import yaml
from PIL import Image

from tests.conftest import REPO, Api, park_worker, service_env, wait_for

FAST = {"preset": "test", "model": "random:tiny"}


def glb(mesh: trimesh.Trimesh) -> bytes:
    return mesh.export(file_type="glb")


def ply(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary little-endian PLY, written by hand so huge meshes cost only numpy time."""
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\nproperty float x\n"
              f"property float y\nproperty float z\nelement face {len(faces)}\n"
              "property list uchar int vertex_indices\nend_header\n").encode()
    face_rows = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face_rows["n"], face_rows["i"] = 3, faces
    return header + np.asarray(vertices, "<f4").tobytes() + face_rows.tobytes()


def grid_mesh(n: int) -> tuple[np.ndarray, np.ndarray]:
    """An n x n vertex grid: 2 (n-1)^2 faces."""
    ij = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    vertices = np.column_stack([ij, np.zeros(len(ij))]).astype(np.float32)
    a = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.column_stack([a, a + n, a + 1]), np.column_stack([a + 1, a + n, a + n + 1])])
    return vertices, faces.astype(np.int32)


def gltf_with_uri(uri: str) -> bytes:
    triangle = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    return json.dumps({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "buffers": [{"uri": uri, "byteLength": len(triangle)}],
        "bufferViews": [{"buffer": 0, "byteLength": len(triangle)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
    }).encode()


def obj_zip_bomb(unpacked_bytes: int) -> bytes:
    """An OBJ in a zip that deflates ~1000:1 (a zip bomb in miniature)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("bomb.obj", b"v 0 0 0\n" * (unpacked_bytes // 8))
    return out.getvalue()


def obj_zip_with_symlink() -> bytes:
    """An OBJ zip whose MTL member is a symbolic link (to a path outside the archive)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as z:
        z.writestr("model.obj", b"mtllib model.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        link = zipfile.ZipInfo("model.mtl")
        link.external_attr = (0o120777 << 16)  # S_IFLNK
        z.writestr(link, "/etc/passwd")
    return out.getvalue()


def deep_chain_glb(depth: int) -> bytes:
    """One triangle under a chain of ``depth`` nodes: 25 kB at 500 nodes once took trimesh 10 s to flatten."""
    triangle = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    nodes = [{"children": [i + 1], "translation": [0.001, 0, 0]} for i in range(depth - 1)] + [{"mesh": 0}]
    tree = json.dumps({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "buffers": [{"byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
    }).encode()
    tree += b" " * (-len(tree) % 4)
    body = struct.pack("<I4s", len(tree), b"JSON") + tree + struct.pack("<I4s", 36, b"BIN\0") + triangle
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


BOX = glb(trimesh.creation.box())
BALL = glb(trimesh.creation.icosphere(subdivisions=2, radius=0.3))


def submit(api: Api, target=("box.glb", BOX), source=("ball.glb", BALL), prompt="a ball on top of a box",
           options=FAST, headers=None, **extra):
    files = {"target": target, "source": source}
    data = {"options": options if isinstance(options, str) else json.dumps(options), **extra}
    if prompt is not None:
        data["prompt"] = prompt
    return api.client.post("/align", files=files, data=data, headers=headers)


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "svc", max_unzipped_bytes=4 * 2**20, max_active_jobs=50)


def test_served_schema_equals_openapi_yaml(api):
    committed = yaml.safe_load((REPO / "openapi.yaml").read_text())
    served = api.client.get("/openapi.json").json()
    assert served == committed, "openapi.yaml is stale: regenerate with `python -m service.openapi > openapi.yaml`"


def test_every_schema_property_is_documented(api):
    schemas = api.client.get("/openapi.json").json()["components"]["schemas"]
    undocumented = [f"{name}.{prop}" for name, schema in schemas.items() if name not in ("HTTPValidationError",
                    "ValidationError") for prop, spec in schema.get("properties", {}).items()
                    if "description" not in spec and "$ref" not in spec]
    assert not undocumented


def test_without_a_worker_readyz_and_align_say_no_worker(private_redis):
    lonely = Api(service_env(private_redis.url, "no-workers-here"))
    try:
        assert lonely.client.get("/healthz").json() == {"status": "ok"}
        answer = lonely.client.get("/readyz")
        assert answer.status_code == 503 and answer.json()["error"]["code"] == "no_worker"
        refused = submit(lonely)
        assert (refused.status_code, refused.json()["error"]["code"]) == (503, "no_worker")
        assert "ctp worker" in refused.json()["error"]["message"]
        assert submit(lonely, prompt="").json()["error"]["code"] == "invalid_prompt"  # bad input is still 4xx
    finally:
        lonely.stop()


BAD_INPUTS = {
    "corrupt glb": (dict(target=("box.glb", b"glTF" + bytes(range(256)) * 40)), 422, "mesh_unreadable", "target"),
    "empty glb": (dict(source=("ball.glb", b"")), 422, "mesh_unreadable", "source"),
    "empty obj": (dict(source=("ball.obj", b"")), 422, "mesh_empty", "source"),
    "wrong extension": (dict(target=("box.docx", BOX)), 415, "mesh_unknown_format", "target"),
    "gltf external uri": (dict(target=("box.gltf", gltf_with_uri("https://example.com/box.bin"))), 422,
                          "mesh_external_reference", "target"),
    "gltf local file uri": (dict(source=("ball.gltf", gltf_with_uri("../../etc/passwd"))), 422,
                            "mesh_external_reference", "source"),
    "gltf data uri shorter than its byteLength": (
        dict(target=("box.gltf", gltf_with_uri("data:application/octet-stream;base64,AAAA"))), 422,
        "mesh_unreadable", "target"),
    "obj zip with a symlink member": (dict(source=("ball.zip", obj_zip_with_symlink())), 422, "mesh_zip_invalid",
                                      "source"),
    "deep node chain": (dict(target=("box.glb", deep_chain_glb(5000))), 413, "mesh_too_complex", "target"),
    "obj zip bomb": (dict(source=("ball.zip", obj_zip_bomb(16 * 2**20))), 422, "mesh_zip_invalid", "source"),
    "10 MB random bytes": (dict(target=("box.ply", np.random.default_rng(0).bytes(10 * 2**20))), 422,
                           "mesh_unreadable", "target"),
    "nan vertices": (dict(target=("box.ply", ply(np.array([[0, 0, 0], [np.nan, 1, 0], [0, 1, 1]]),
                                                 np.array([[0, 1, 2]])))), 422, "mesh_invalid_values", "target"),
    "2M faces": (dict(source=("ball.ply", ply(*grid_mesh(1001)))), 413, "mesh_too_large", "source"),
    "empty prompt": (dict(prompt=""), 422, "invalid_prompt", "prompt"),
    "blank prompt": (dict(prompt="   "), 422, "invalid_prompt", "prompt"),
    "overlong prompt": (dict(prompt="a" * 501), 422, "invalid_prompt", "prompt"),
    "NUL in prompt": (dict(prompt="a ball\x00 on a box"), 422, "invalid_prompt", "prompt"),
    "ESC in prompt": (dict(prompt="a ball \x1b[31mon a box"), 422, "invalid_prompt", "prompt"),
    "BEL in a name": (dict(source_name="ball\x07"), 422, "invalid_name", "source_name"),
    "seed beyond 64 bits": (dict(options={**FAST, "seed": 2**64 + 1}), 400, "invalid_options", "options"),
    "seed beyond the engine's range": (dict(options={**FAST, "seed": 2**40}), 422, "invalid_option",
                                       "options.seed"),
    "option NaN": (dict(options='{"contact_ratio": NaN}'), 400, "invalid_options", "options"),
    "option overflowing float": (dict(options='{"contact_ratio": 1e999}'), 400, "invalid_options", "options"),
    "deeply nested options": (dict(options="[" * 100_000 + "]" * 100_000), 400, "invalid_options", "options"),
    "options nested past the limit": (dict(options='{"seed": ' + "[" * 20 + "]" * 20 + "}"), 400,
                                      "invalid_options", "options"),
    "unknown priors provider": (dict(options={**FAST, "hparams_provider": "oracle"}), 422, "invalid_option",
                                 "options.hparams_provider"),
    "no prompt or image": (dict(prompt=None), 400, "missing_field", "prompt"),
    "unknown option": (dict(options={**FAST, "temperature": 1}), 422, "unknown_option", "options.temperature"),
    "option wrong type": (dict(options={**FAST, "seed": "seven"}), 422, "invalid_option", "options.seed"),
    "option bool for int": (dict(options={**FAST, "steps": True}), 422, "invalid_option", "options.steps"),
    "option out of range": (dict(options={**FAST, "contact_ratio": 1.5}), 422, "invalid_option",
                            "options.contact_ratio"),
    # A cross-field rule of AlignConfig: no single option is at fault.
    "steps below phases": (dict(options={**FAST, "steps": 1}), 422, "invalid_option", "options"),
    "upright judge not a bool": (dict(options={**FAST, "upright_judge": "yes"}), 422, "invalid_option",
                                 "options.upright_judge"),
    "unknown preset": (dict(options={"preset": "turbo"}), 422, "invalid_option", "options.preset"),
    "model not served": (dict(options={**FAST, "model": "hf:someone/huge"}), 422, "invalid_option", "options.model"),
    "options not an object": (dict(options=[1, 2]), 400, "invalid_options", "options"),
    "queue not a queue name": (dict(options={**FAST, "queue": "GPU 2"}), 422, "invalid_option", "options.queue"),
    "queue not a string": (dict(options={**FAST, "queue": 1}), 422, "invalid_option", "options.queue"),
    "unknown form field": (dict(colour="red"), 400, "unknown_field", "colour"),
}


def test_inspect_reads_one_mesh_as_a_job_would(api):
    """``POST /inspect``: the size in the file's units, the faces, and the up and front a job will use (a PLY
    states no up: a cone standing on its tip, upside down in the file, keeps the file's +Y by the stated rule, and
    ``up: auto`` turns it over, as ``-y`` does; a GLB box keeps glTF's +Y up and +Z front); nothing is queued."""
    cone = trimesh.creation.cone(radius=0.05, height=0.3, sections=24)  # its tip up the file's z
    cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # tip down the file's -y
    answer = api.client.post("/inspect", files={"mesh": ("cone.ply", cone.export(file_type="ply"))})
    assert answer.status_code == 200, answer.text
    seen = answer.json()
    assert (seen["file"], seen["faces"], seen["vertices"]) == ("cone.ply", len(cone.faces), len(cone.vertices))
    np.testing.assert_allclose(seen["extents"], cone.extents, rtol=1e-5)
    assert seen["size"] == pytest.approx(0.3, rel=1e-5) and not seen["turned"], seen
    assert seen["up"] == pytest.approx([0, 1, 0]) and "PLY states no up" in seen["reason"]
    assert not seen["front_trusted"] and seen["front_reason"]
    for up in ("auto", "-y"):
        turned = api.client.post("/inspect", files={"mesh": ("cone.ply", cone.export(file_type="ply"))},
                                 data={"up": up}).json()
        assert turned["turned"] and turned["up"] == pytest.approx([0, -1, 0], abs=1e-3), turned
    box = api.client.post("/inspect", files={"mesh": ("box.glb", BOX)}).json()
    assert not box["turned"] and box["up"] == pytest.approx([0, 1, 0]) and box["faces"] == 12
    assert box["front"] == pytest.approx([0, 0, 1]) and "glTF" in box["reason"]
    for bad in ({"up": "upward"}, {"up": "+y", "front": "-y"}):
        refused = api.client.post("/inspect", files={"mesh": ("box.glb", BOX)}, data=bad)
        assert (refused.status_code, refused.json()["error"]["code"]) == (422, "invalid_option"), refused.text

    from service.client import Client, ServiceError

    with Client(api.url) as client:  # the Python client says the same
        assert client.inspect(("box.glb", BOX)) == box
        with pytest.raises(ServiceError) as refused:
            client.inspect(("box.docx", BOX))
    assert (refused.value.status, refused.value.code, refused.value.field) == (415, "mesh_unknown_format", "mesh")


@pytest.mark.parametrize("case", ["corrupt glb", "wrong extension", "gltf external uri", "nan vertices", "2M faces"])
def test_inspect_refuses_what_a_job_would_with_the_same_code(api, case):
    kwargs, status, code, _ = BAD_INPUTS[case]
    (name, data), = kwargs.values()
    answer = api.client.post("/inspect", files={"mesh": (name, data)})
    assert (answer.status_code, answer.json()["error"]["code"], answer.json()["error"]["field"]) == (
        status, code, "mesh"), answer.text
    stray = api.client.post("/inspect", files={"mesh": ("box.glb", BOX)}, data={"prompt": "a box"})
    assert (stray.status_code, stray.json()["error"]["code"]) == (400, "unknown_field")


@pytest.mark.parametrize(("fields", "field"), [({"up": "up"}, "up"), ({"front": "+q"}, "front"),
                                             ({"up": "+y", "front": "-y"}, "front")])
def test_inspect_refuses_an_up_or_front_a_job_would_refuse(api, fields, field):
    answer = api.client.post("/inspect", files={"mesh": ("box.glb", BOX)}, data=fields)
    assert (answer.status_code, answer.json()["error"]["code"], answer.json()["error"]["field"]) == (
        422, "invalid_option", field), answer.text


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_is_refused_with_its_code(api, case):
    kwargs, status, code, field = BAD_INPUTS[case]
    answer = submit(api, **kwargs)
    assert answer.status_code == status, answer.text
    assert answer.json()["error"]["code"] == code
    assert answer.json()["error"]["field"] == field
    assert api.client.get("/healthz").status_code == 200


def test_malformed_requests(api):
    not_multipart = api.client.post("/align", json={"prompt": "x"})
    assert (not_multipart.status_code, not_multipart.json()["error"]["code"]) == (400, "invalid_request")
    text_for_file = api.client.post("/align", data={"target": "box", "prompt": "x"}, files={"source": ("b.glb", BALL)})
    assert (text_for_file.status_code, text_for_file.json()["error"]) == (
        400, {"code": "invalid_field", "message": "target must be a file upload, not text", "field": "target"})
    missing = api.client.post("/align", data={"prompt": "x"}, files={"target": ("b.glb", BOX)})
    assert (missing.status_code, missing.json()["error"]["field"]) == (400, "source")
    bad_json = api.client.post("/align", data={"prompt": "x", "options": "{seed: 1"},
                               files={"target": ("a.glb", BOX), "source": ("b.glb", BALL)})
    assert (bad_json.status_code, bad_json.json()["error"]["code"]) == (400, "invalid_options")


def test_request_and_upload_size_limits(private_redis):
    small = Api(service_env(private_redis.url, "small", max_request_bytes=200_000, max_upload_bytes=50_000))
    try:
        big_mesh = glb(trimesh.creation.icosphere(subdivisions=5))  # ~0.5 MB
        answer = submit(small, target=("big.glb", big_mesh))
        assert (answer.status_code, answer.json()["error"]["code"]) == (413, "request_too_large")

        def chunks():  # no Content-Length: the limit must hold while a well-formed body streams in
            yield b'--b\r\nContent-Disposition: form-data; name="target"; filename="a.glb"\r\n\r\n'
            yield b"x" * 150_000
            yield b"x" * 150_000

        streamed = small.client.post("/align", content=chunks(),
                                     headers={"Content-Type": "multipart/form-data; boundary=b"})
        assert (streamed.status_code, streamed.json()["error"]["code"]) == (413, "request_too_large")
        medium = glb(trimesh.creation.icosphere(subdivisions=4))  # ~120 kB: under the request, over the file limit
        answer = submit(small, source=("medium.glb", medium))
        assert (answer.status_code, answer.json()["error"]) == (
            413, {"code": "mesh_file_too_large", "message": answer.json()["error"]["message"], "field": "source"})
    finally:
        small.stop()


def test_api_keys_isolate_jobs_and_cap_active_jobs(private_redis):
    """A parked worker on this queue (alive, consuming nothing): jobs stay queued, which is what the
    per-key cap counts."""
    env = service_env(private_redis.url, "keyed", api_keys="alpha,beta", max_active_jobs=2,
                      cors_origins="https://app.example")
    keyed = Api(env)
    alpha, beta = ({"Authorization": f"Bearer {k}"} for k in ("alpha", "beta"))
    leave = park_worker(env)
    try:
        assert keyed.client.get("/healthz").status_code == 200  # probes need no key
        preflight = keyed.client.options("/align", headers={"Origin": "https://app.example",
                                                             "Access-Control-Request-Method": "POST",
                                                             "Access-Control-Request-Headers": "authorization"})
        assert preflight.headers["access-control-allow-origin"] == "https://app.example"
        foreign = keyed.client.get("/healthz", headers={"Origin": "https://evil.example"})
        assert "access-control-allow-origin" not in foreign.headers
        anonymous = submit(keyed)
        assert (anonymous.status_code, anonymous.json()["error"]["code"]) == (401, "unauthorized")
        assert submit(keyed, headers={"Authorization": "Bearer gamma"}).status_code == 401
        first = submit(keyed, headers=alpha)
        assert first.status_code == 202 and first.json()["status"] == "queued"
        job = first.json()["id"]
        assert keyed.client.get(f"/jobs/{job}", headers=alpha).json()["status"] == "queued"
        other = keyed.client.get(f"/jobs/{job}", headers=beta)
        assert (other.status_code, other.json()["error"]["code"]) == (404, "job_not_found")
        assert keyed.client.delete(f"/jobs/{job}", headers=beta).status_code == 404
        assert keyed.client.get(f"/jobs/{job}/result.glb", headers=beta).status_code == 404
        not_ready = keyed.client.get(f"/jobs/{job}/result.glb", headers=alpha)
        assert (not_ready.status_code, not_ready.json()["error"]["code"]) == (409, "job_not_ready")

        assert submit(keyed, headers=alpha).status_code == 202
        third = submit(keyed, headers=alpha)
        assert (third.status_code, third.json()["error"]["code"]) == (429, "too_many_jobs")
        assert submit(keyed, headers=beta).status_code == 202  # the cap is per key

        canceled = keyed.client.delete(f"/jobs/{job}", headers=alpha)  # queued: canceled at once
        assert canceled.status_code == 200 and canceled.json()["status"] == "canceled"
        again = keyed.client.delete(f"/jobs/{job}", headers=alpha)
        assert (again.status_code, again.json()["error"]["code"]) == (409, "job_finished")
        assert submit(keyed, headers=alpha).status_code == 202  # the canceled job freed its slot
    finally:
        leave()
        keyed.stop()


def test_unknown_job_is_404(api):
    for path in ("/jobs/0123456789abcdef0123456789abcdef", "/jobs/nope/report.json", "/jobs/../etc/events"):
        answer = api.client.get(path)
        assert answer.status_code == 404
        assert answer.json()["error"]["code"] in ("job_not_found", "not_found")


def test_readyz_lists_the_models_a_worker_can_run(api, worker):
    answer = api.client.get("/readyz")
    assert answer.status_code == 200
    assert answer.json() == {"status": "ready", "redis": True, "workers": 1, "models": ["random:tiny"],
                             "queues": {"default": ["random:tiny"]}, "since_s": None, "guide": "random:tiny",
                             "why": "named by CTP_MODEL", "get_model": None}


def test_end_to_end_with_progress_events(api, worker):
    accepted = submit(api)
    assert accepted.status_code == 202, accepted.text
    links = accepted.json()["links"]
    events = []
    with api.client.stream("GET", links["events"], timeout=120) as stream:
        kind = None
        for line in stream.iter_lines():
            if line.startswith("event: "):
                kind = line.removeprefix("event: ")
            elif line.startswith("data: "):
                events.append((kind, json.loads(line.removeprefix("data: "))))
    assert events[-1][0] == "end" and all(k == "progress" for k, _ in events[:-1])
    final = events[-1][1]
    assert final["status"] == "succeeded", final
    running = [e["progress"] for _, e in events if e["status"] == "running"]
    for stage in ("search", "refine"):  # the search counts candidates scored, then the refinement its steps
        steps = [p["step"] for p in running if p["stage"]["name"] == stage]
        assert steps == sorted(steps), stage  # step events are thinned: a short search may publish none
    assert max(p["step"] for p in running if p["stage"]["name"] == "refine") > 0
    assert {e["progress"]["phase"] for _, e in events} >= {1, 2}  # the test preset has two phases
    assert final["started_at"] <= final["finished_at"] and final["progress"]["fraction"] == 1.0

    scene = trimesh.load(io.BytesIO(api.client.get(links["result"]).content), file_type="glb")
    assert list(scene.geometry) == ["box", "ball"]  # named by the uploads' file names
    assert len(scene.geometry["box"].faces) == len(trimesh.creation.box().faces)
    report = api.client.get(links["report"]).json()
    matrix = np.array(report["transform"]["matrix"])
    np.testing.assert_allclose(scene.graph["ball"][0], matrix, atol=1e-5)
    preview = Image.open(io.BytesIO(api.client.get(links["preview"]).content))
    assert preview.format == "PNG" and preview.width > 0
    job = api.client.get(accepted.json()["links"]["self"]).json()
    assert job["status"] == "succeeded"
    # the best distinct placements, the answer first: each one's GLB, their views side by side
    alternatives = job["alternatives"]
    assert [a["index"] for a in alternatives] == list(range(len(alternatives))) and len(alternatives) >= 2
    assert [a["objective"] for a in alternatives] == [a["objective"] for a in report["alternatives"]]
    assert alternatives[0]["relation_holds"] == report["relation"]["holds"]
    assert api.client.get(links["result"], params={"alternative": 0}).content == api.client.get(links["result"]).content
    second = trimesh.load(io.BytesIO(api.client.get(links["result"], params={"alternative": 1}).content),
                          file_type="glb")
    np.testing.assert_allclose(second.graph["ball"][0], report["alternatives"][1]["transform"]["matrix"], atol=1e-5)
    past = api.client.get(links["result"], params={"alternative": len(alternatives)})
    assert (past.status_code, past.json()["error"]["code"]) == (404, "alternative_not_found")
    wrong = api.client.get(links["report"], params={"alternative": 1})
    assert (wrong.status_code, wrong.json()["error"]["code"]) == (400, "invalid_request")
    strip = Image.open(io.BytesIO(api.client.get(f"{links['self']}/alternatives.png").content))
    assert strip.size == (160 * len(alternatives), 160)
    again = api.client.delete(links["cancel"])
    assert (again.status_code, again.json()["error"]["code"]) == (409, "job_finished")


def test_image_guided_job(api, worker):
    picture = io.BytesIO()
    Image.new("RGB", (64, 48), (200, 30, 30)).save(picture, format="PNG")
    accepted = api.client.post("/align", data={"options": json.dumps(FAST)}, files={
        "target": ("box.glb", BOX), "source": ("ball.glb", BALL), "image": ("ref.png", picture.getvalue())})
    assert accepted.status_code == 202, accepted.text
    job = wait_for(lambda: (j := api.client.get(f"/jobs/{accepted.json()['id']}").json())["status"]
                   in ("succeeded", "failed") and j, 120, "the image-guided job")
    assert job["status"] == "succeeded", job
    assert job["image_guided"] and job["prompt"] is None
    bad = api.client.post("/align", data={"prompt": "x"}, files={
        "target": ("box.glb", BOX), "source": ("ball.glb", BALL), "image": ("ref.png", b"not a picture")})
    assert (bad.status_code, bad.json()["error"]["code"]) == (422, "invalid_image")
    assert bad.json()["error"]["message"] == "image: not a readable PNG or JPEG image"  # no <_io.BytesIO ...>
