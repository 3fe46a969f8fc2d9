"""Speed and gradient quality of the differentiable renderer (ctp_core.render); prints one JSON line.

Scene (as in docs/renderer-study.md): a fixed torus (10 000 faces) and a posed ellipsoid (5 120 faces),
both with per-vertex colour gradients, seen by 8 ring cameras (45 degree azimuth steps, elevation 20/40,
distance 2.6, fov 45) at 224 x 224. The ellipsoid sits in the top of the upright ring, passing through
its tube, so silhouettes, occlusions and intersection lines all carry the gradient. The pose is
x = s R(q) x_local + t (ctp_core.geometry.pose), all 8 parameters requiring grad in the timed steps.

- forward_ms: render under no_grad; forward_backward_ms: render -> MSE -> backward. Medians of
  ``--repeats`` runs after one warm-up.
- fd_cosine_translation / fd_cosine_rotation: autograd vs central finite differences of the MSE to a
  target rendered with the pose shifted by 20 % of the object size and 20 degrees, at the halfway pose
  (steps 0.01 units and 0.02 rad, about a third of a pixel).
- recovery_*: Adam (lr 0.01, ``--steps`` steps) from the identity pose to the target pose
  (translation 20 % of the object size, rotation 20 degrees about (0.3, 1, 0.2), scale 1.15), by image MSE.
- peak_rss_mb: peak resident memory of the process (torch alone is ~280 MB).

Usage: OMP_WAIT_POLICY=PASSIVE python benchmarks/render_bench.py [--size 224] [--views 8] [--steps 200]
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import statistics
import time

import numpy as np
import torch
import trimesh

from ctp_core import render
from ctp_core.geometry.pose import apply_pose, quaternion_to_matrix
from ctp_core.render.cameras import orbit


def scene(views: int, size: int, dtype: torch.dtype):
    """(images(t, q, log_s), object size, face count) for the torus + ellipsoid scene."""
    torus = trimesh.creation.torus(0.6, 0.18, 100, 50)
    ellipsoid = trimesh.creation.icosphere(4)
    ellipsoid.apply_scale([0.5, 0.3, 0.25])
    colours = [_gradient_colours(torus), 0.5 + 0.5 * _gradient_colours(ellipsoid)]
    parts = [render.RenderMesh(torch.as_tensor(m.faces), torch.as_tensor(c, dtype=torch.float32))
             for m, c in zip((torus, ellipsoid), colours, strict=True)]
    mesh = render.join(parts, [len(torus.vertices), len(ellipsoid.vertices)])
    fixed = torch.as_tensor(torus.vertices, dtype=dtype)[None]
    local = torch.as_tensor(ellipsoid.vertices, dtype=dtype)
    offset = torch.tensor([0.0, 0.5, 0.0], dtype=dtype)  # ellipsoid centre, in the ring's top
    azimuth = torch.arange(views, dtype=torch.float32)[None] * 45.0
    elevation = torch.tensor([[20.0, 40.0] * ((views + 1) // 2)])[:, :views]
    cams = orbit(torch.zeros(1, 3), azimuth, elevation, torch.full((1, views), 2.6), torch.full((1, views), 45.0),
                 size)

    def images(t: torch.Tensor, q: torch.Tensor, log_s: torch.Tensor) -> torch.Tensor:
        posed = apply_pose(local, t + offset, q, log_s)
        return render.render(mesh, torch.cat([fixed.expand(len(t), -1, -1), posed], 1), cams)

    size_of_object = float(np.linalg.norm(np.ptp(ellipsoid.vertices, 0)))
    return images, size_of_object, len(mesh.faces)


def _gradient_colours(mesh: trimesh.Trimesh) -> np.ndarray:
    v = mesh.vertices
    return (v - v.min(0)) / np.ptp(v, 0)


def quaternion(rotvec: torch.Tensor) -> torch.Tensor:
    angle = rotvec.norm()
    return torch.cat([torch.cos(angle / 2)[None], torch.sin(angle / 2) * rotvec / angle])[None]


def truth(object_size: float, dtype: torch.dtype):
    direction = torch.tensor([0.7, 0.35, -0.62], dtype=dtype)
    axis = torch.tensor([0.3, 1.0, 0.2], dtype=dtype)
    t = direction / direction.norm() * 0.2 * object_size
    rotvec = axis / axis.norm() * math.radians(20.0)
    return t, rotvec, math.log(1.15)


def timings(images, repeats: int) -> tuple[float, float]:
    t = torch.zeros(1, 3, requires_grad=True)
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0]], requires_grad=True)
    log_s = torch.zeros(1, requires_grad=True)
    with torch.no_grad():
        target = images(t + 0.1, q, log_s)

    def forward() -> None:
        with torch.no_grad():
            images(t, q, log_s)

    def step() -> None:
        (images(t, q, log_s) - target).square().mean().backward()

    return _median_ms(forward, repeats), _median_ms(step, repeats)


def _median_ms(fn, repeats: int) -> float:
    fn()  # warm-up
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - start)
    return 1000 * statistics.median(runs)


def fd_cosines(images, object_size: float) -> tuple[float, float]:
    """Cosine of autograd vs central differences, translation and rotation-vector parts (float64)."""
    shift_t, shift_r, _ = truth(object_size, torch.float64)
    log_s = torch.zeros(1, dtype=torch.float64)
    with torch.no_grad():
        target = images(shift_t[None], quaternion(shift_r), log_s)

    def loss(x: torch.Tensor) -> torch.Tensor:
        return (images(x[None, :3], quaternion(x[3:]), log_s) - target).square().mean()

    x0 = torch.cat([shift_t / 2, shift_r / 2]).requires_grad_(True)
    (grad,) = torch.autograd.grad(loss(x0), x0)
    steps = [0.01] * 3 + [0.02] * 3
    fd = torch.stack([(loss(x0.detach() + h * e) - loss(x0.detach() - h * e)) / (2 * h)
                      for h, e in zip(steps, torch.eye(6, dtype=torch.float64), strict=True)])
    cos = torch.nn.functional.cosine_similarity
    return cos(grad[:3], fd[:3], dim=0).item(), cos(grad[3:], fd[3:], dim=0).item()


def recovery(images, object_size: float, steps: int) -> dict:
    true_t, true_r, true_log_s = truth(object_size, torch.float32)
    true_q = quaternion(true_r)
    with torch.no_grad():
        target = images(true_t[None], true_q, torch.tensor([true_log_s]))
    t = torch.zeros(1, 3, requires_grad=True)
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0]], requires_grad=True)
    log_s = torch.zeros(1, requires_grad=True)
    opt = torch.optim.Adam([t, q, log_s], lr=0.01)
    start = time.perf_counter()
    for _ in range(steps):
        opt.zero_grad()
        (images(t, q, log_s) - target).square().mean().backward()
        opt.step()
    wall = time.perf_counter() - start
    with torch.no_grad():
        relative = quaternion_to_matrix(q)[0].T @ quaternion_to_matrix(true_q)[0]
        cos_angle = min(1.0, max(-1.0, (relative.trace().item() - 1) / 2))
        return {
            "recovery_translation_pct": round(100 * (t[0] - true_t).norm().item() / object_size, 4),
            "recovery_rotation_deg": round(math.degrees(math.acos(cos_angle)), 4),
            "recovery_scale_pct": round(100 * abs(math.exp(log_s.item() - true_log_s) - 1), 4),
            "recovery_steps": steps,
            "recovery_s": round(wall, 1),
        }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=224, help="image size in pixels")
    parser.add_argument("--views", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per measurement")
    parser.add_argument("--steps", type=int, default=200, help="Adam steps of the recovery test (0: skip)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    images, object_size, faces = scene(args.views, args.size, torch.float32)
    forward_ms, step_ms = timings(images, args.repeats)
    images64, _, _ = scene(args.views, args.size, torch.float64)
    fd_t, fd_r = fd_cosines(images64, object_size)
    out = {
        "faces": faces, "views": args.views, "resolution": args.size, "threads": torch.get_num_threads(),
        "forward_ms": round(forward_ms, 1), "forward_backward_ms": round(step_ms, 1),
        "fd_cosine_translation": round(fd_t, 5), "fd_cosine_rotation": round(fd_r, 5),
    }
    if args.steps:
        out.update(recovery(images, object_size, args.steps))
    out["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
