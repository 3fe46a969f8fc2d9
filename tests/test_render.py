import math

import numpy as np
import pytest
import torch
import trimesh

from ctp_core import render
from ctp_core.geometry.pose import apply_pose, quaternion_to_matrix
from ctp_core.render.cameras import Cameras, orbit
from ctp_core.render.structures import MeshArrays


def _cameras(az, el, dist=2.6, fov=45.0, size=96, at=(0.0, 0.0, 0.0)):
    n = len(az)
    full = lambda v: torch.full((1, n), float(v))  # noqa: E731
    return orbit(torch.tensor([at]), torch.tensor([az], dtype=torch.float32), torch.tensor([el], dtype=torch.float32),
                 full(dist), full(fov), size)


def _render_mesh(tm: trimesh.Trimesh, colors: np.ndarray | None = None) -> render.RenderMesh:
    if colors is None:  # colour by position so that rotations and shifts change the image
        v = tm.vertices
        colors = 0.15 + 0.7 * (v - v.min(0)) / np.maximum(np.ptp(v, 0), 1e-9)
    return render.RenderMesh(torch.as_tensor(tm.faces), torch.as_tensor(colors, dtype=torch.float32))


def _verts(tm: trimesh.Trimesh, dtype=torch.float32) -> torch.Tensor:
    return torch.as_tensor(tm.vertices, dtype=dtype)[None]


def _ellipsoid(subdivisions: int) -> trimesh.Trimesh:
    tm = trimesh.creation.icosphere(subdivisions)
    tm.apply_scale([0.5, 0.3, 0.25])
    return tm


# -- 1. rasterize's coverage agrees with trimesh ray casting through pixel centres ------------------------------

def _ray_coverage(tm, az, el, dist, fov, size, at):
    """Independent pinhole camera written from the documented conventions, numpy + embree."""
    a, e = math.radians(az), math.radians(el)
    at = np.asarray(at, float)
    eye = at + dist * np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    forward = (at - eye) / np.linalg.norm(at - eye)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    focal = size / 2 / math.tan(math.radians(fov) / 2)
    rows, cols = np.mgrid[0:size, 0:size]
    x = (cols.ravel() + 0.5 - size / 2) / focal
    y = -(rows.ravel() + 0.5 - size / 2) / focal
    dirs = forward + x[:, None] * right + y[:, None] * up
    hit = tm.ray.intersects_first(np.repeat(eye[None], len(dirs), 0), dirs)
    return (hit >= 0).reshape(size, size)


def _inconsistent(tm: trimesh.Trimesh) -> trimesh.Trimesh:
    faces = tm.faces.copy()
    faces[::2] = faces[::2, ::-1]  # every other face wound the other way
    return trimesh.Trimesh(tm.vertices, faces, process=False)


def _asymmetric() -> trimesh.Trimesh:
    post = trimesh.creation.box([0.25, 1.2, 0.25])
    post.apply_translation([0.45, 0.1, -0.2])
    foot = trimesh.creation.box([0.9, 0.2, 0.5])
    foot.apply_translation([0.1, -0.4, 0.1])
    return trimesh.util.concatenate([post, foot, trimesh.creation.uv_sphere(0.2, (12, 12))])


@pytest.mark.parametrize("name", ["asymmetric", "torus", "inconsistent_ellipsoid"])
def test_coverage_matches_ray_casting(name):
    tm = {
        "asymmetric": _asymmetric,
        "torus": lambda: trimesh.creation.torus(0.6, 0.2, 40, 20),
        "inconsistent_ellipsoid": lambda: _inconsistent(_ellipsoid(3)),
    }[name]()
    views = [(0, 0, 2.6, 45), (70, 25, 2.4, 50), (160, -30, 3.0, 35), (250, 60, 2.8, 60), (320, 10, 2.2, 55)]
    size, at = 96, (0.05, 0.1, -0.05)
    cams = orbit(torch.tensor([at]), *(torch.tensor([[v[i] for v in views]], dtype=torch.float32) for i in range(4)),
                 size)
    with torch.no_grad():  # the silhouette pass: rasterize alone, no shading
        mask = render.rasterize(_render_mesh(tm), _verts(tm), cams).mask[0].numpy()
    for i, (az, el, dist, fov) in enumerate(views):
        expected = _ray_coverage(tm, az, el, dist, fov, size, at)
        iou = (mask[i] & expected).sum() / (mask[i] | expected).sum()
        assert expected.sum() > 300, "the object should fill a fair part of the view"
        assert iou >= 0.98, f"view {i}: IoU {iou:.4f}"


def test_winding_does_not_change_the_image():
    tm = _ellipsoid(2)
    flipped = _inconsistent(tm)
    cams = _cameras([30, 200], [20, -40], size=64)
    a = render.render(_render_mesh(tm), _verts(tm), cams)
    b = render.render(_render_mesh(flipped, _render_mesh(tm).colors.numpy()), _verts(flipped), cams)
    assert torch.allclose(a, b, atol=1e-4)
    assert (a < 0.99).any(), "the object is visible"


def test_batch_of_poses_renders_like_separate_calls():
    tm = _ellipsoid(2)
    mesh, verts = _render_mesh(tm), _verts(tm)
    moved = torch.cat([verts, verts + torch.tensor([0.2, -0.1, 0.0])])
    cams = orbit(torch.zeros(2, 3), torch.tensor([[0.0, 90.0], [45.0, 300.0]]), torch.tensor([[10.0, 30.0]] * 2),
                 torch.full((2, 2), 2.6), torch.full((2, 2), 45.0), 48)
    both = render.render(mesh, moved, cams)
    assert both.shape == (2, 2, 3, 48, 48)
    for b in range(2):
        row = Cameras(cams.eye[b:b + 1], cams.at[b:b + 1], cams.fov_deg[b:b + 1], cams.image_size)
        assert torch.allclose(both[b], render.render(mesh, moved[b:b + 1], row)[0], atol=1e-5)
    assert not torch.allclose(both[0, 0], both[1, 0], atol=1e-2)


@pytest.mark.parametrize("shift", [(0.0, 0.0, 5.0), (10.0, 0.0, 0.0)], ids=["behind_camera", "off_screen"])
def test_nothing_visible_renders_background(shift):
    tm = _ellipsoid(2)
    verts = (_verts(tm) + torch.tensor(shift)).requires_grad_(True)
    img = render.render(_render_mesh(tm), verts, _cameras([0, 20], [0, 10], size=32), background=0.8)
    assert torch.equal(img, torch.full_like(img, 0.8))
    img.sum().backward()
    assert verts.grad is None or torch.equal(verts.grad, torch.zeros_like(verts))


def test_empty_mesh_renders_background():
    mesh = render.RenderMesh(torch.zeros(0, 3, dtype=torch.long), torch.zeros(0, 3))
    img = render.render(mesh, torch.zeros(2, 0, 3), orbit(torch.zeros(2, 3), *(torch.zeros(2, 1),) * 2,
                                                          torch.full((2, 1), 3.0), torch.full((2, 1), 45.0), 16))
    assert img.shape == (2, 1, 3, 16, 16) and torch.equal(img, torch.ones_like(img))


def _facing_quad() -> trimesh.Trimesh:
    """A 2 x 2 quad in the z = 0 plane, facing +Z (the camera at azimuth 0, elevation 0)."""
    return trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False)


def test_lambert_shading_from_the_camera():
    """A white plane facing the camera is fully lit; tilted away from the key light it gets darker."""
    quad = _facing_quad()
    mesh = _render_mesh(quad, np.ones((4, 3)))
    cams = _cameras([0], [0], dist=3.0, size=32)
    lights = render.Lights()
    key = np.array(lights.direction) / np.linalg.norm(lights.direction)
    centre = lambda verts: render.render(mesh, verts, cams, background=0.0)[0, 0, :, 16, 16]  # noqa: E731
    assert torch.allclose(centre(_verts(quad)), torch.full((3,), lights.ambient + (1 - lights.ambient) * key[2]),
                          atol=1e-4)
    tilt = math.radians(60)
    rot = torch.tensor([[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]])
    lit = float(centre(_verts(quad) @ rot.T.float())[0])
    normal = rot.numpy() @ np.array([0, 0, 1.0])
    assert lit == pytest.approx(lights.ambient + (1 - lights.ambient) * max(0.0, normal @ key), abs=1e-4)


def test_lights_are_a_parameter():
    """Full ambient shows the albedo; a key light from below leaves a face turned up at the ambient level."""
    quad = trimesh.Trimesh([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], [[0, 1, 2], [0, 2, 3]], process=False)
    mesh = _render_mesh(quad, np.tile([[0.8, 0.4, 0.2]], (4, 1)))
    cams = _cameras([0], [40], dist=3.0, size=32)  # looking down at the horizontal quad
    centre = lambda lights: render.render(mesh, _verts(quad), cams, lights=lights)[0, 0, :, 16, 16]  # noqa: E731
    assert torch.allclose(centre(render.Lights(ambient=1.0)), torch.tensor([0.8, 0.4, 0.2]), atol=1e-5)
    below = centre(render.Lights(ambient=0.5, direction=(0.0, -1.0, 0.0)))
    assert torch.allclose(below, 0.5 * torch.tensor([0.8, 0.4, 0.2]), atol=1e-5)
    assert (centre(render.Lights()) > 1.5 * below).all()  # the default key light reaches it


def test_fragments_depth_barycentrics_and_stages():
    """A quad facing the camera at distance 3: depth 3 on every covered pixel, barycentrics on the simplex,
    and render() is antialias(shade(rasterize()))."""
    quad = _facing_quad()
    mesh, verts, cams = _render_mesh(quad), _verts(quad), _cameras([0, 30], [0, 0], dist=3.0, size=32)
    fragments = render.rasterize(mesh, verts, cams)
    assert fragments.pix_to_face.shape == (1, 2, 32, 32) and fragments.mask.sum() == len(fragments.pixels)
    assert torch.allclose(fragments.dense(fragments.depth, 3.0)[0, 0], torch.full((32, 32), 3.0), atol=1e-5)
    assert (fragments.depth[fragments.pixel_faces >= 2] > 3.0 - 1.0).all()  # the turned view sees it obliquely
    assert torch.allclose(fragments.bary_coords.sum(-1), torch.ones(len(fragments.pixels)), atol=1e-6)
    assert (fragments.bary_coords > -1e-6).all()
    staged = render.antialias(mesh, fragments, render.shade(mesh, fragments)).clamp(0, 1).permute(0, 1, 4, 2, 3)
    assert torch.equal(staged, render.render(mesh, verts, cams))


# -- 2. finite differences vs autograd -------------------------------------------------------------

def _pose_loss_setup():
    """A posed ellipsoid beside a fixed box (occlusion and silhouettes), 3 views, float64."""
    source = _ellipsoid(3)
    box = trimesh.creation.box([0.8, 0.3, 0.8])
    box.apply_translation([0.0, -0.6, 0.0])  # below the ellipsoid: intersection lines are not antialiased
    mesh = render.join([_render_mesh(box), _render_mesh(source)], [len(box.vertices), len(source.vertices)])
    local = torch.as_tensor(source.vertices, dtype=torch.float64)
    fixed = torch.as_tensor(box.vertices, dtype=torch.float64)[None]
    cams = _cameras([20, 140, 260], [25, 15, 40], size=80)

    def images(t, q, log_s):
        return render.render(mesh, torch.cat([fixed, apply_pose(local, t, q, log_s)], 1), cams)

    return images


def _quat(rotvec: torch.Tensor) -> torch.Tensor:
    angle = rotvec.norm()
    return torch.cat([torch.cos(angle / 2)[None], torch.sin(angle / 2) * rotvec / angle])[None]


def test_gradient_matches_finite_differences():
    images = _pose_loss_setup()
    log_s = torch.zeros(1, dtype=torch.float64)
    axis = torch.tensor([0.3, 1.0, 0.2], dtype=torch.float64)
    shift_t = torch.tensor([0.12, 0.06, -0.1], dtype=torch.float64)
    shift_r = axis / axis.norm() * math.radians(16)
    with torch.no_grad():
        target = images(shift_t[None], _quat(shift_r), log_s)

    def loss(params: torch.Tensor) -> torch.Tensor:  # params: translation (3), rotation vector (3)
        return (images(params[None, :3], _quat(params[3:]), log_s) - target).square().mean()

    x0 = torch.cat([shift_t / 2, shift_r / 2]).requires_grad_(True)
    (grad,) = torch.autograd.grad(loss(x0), x0)
    # Central differences over ~0.4 px of motion (0.01 units; 0.02 rad on a 0.5 radius): the image is
    # continuous, but flat-shading creases make it kinked below a pixel, which tiny steps would measure.
    steps = torch.tensor([0.01] * 3 + [0.02] * 3, dtype=torch.float64)
    fd = torch.stack([(loss(x0.detach() + h * e) - loss(x0.detach() - h * e)) / (2 * h)
                      for h, e in zip(steps, torch.eye(6, dtype=torch.float64), strict=True)])
    assert torch.isfinite(grad).all()
    for part, sl in (("translation", slice(0, 3)), ("rotation", slice(3, 6))):
        cos = torch.nn.functional.cosine_similarity(grad[sl], fd[sl], dim=0).item()
        ratio = (grad[sl].norm() / fd[sl].norm()).item()
        assert cos >= 0.98, f"{part}: cosine {cos:.4f} (autograd {grad[sl].tolist()}, fd {fd[sl].tolist()})"
        assert 0.7 < ratio < 1.4, f"{part}: |autograd| / |fd| = {ratio:.3f}"


def test_silhouette_gradient_without_colour_cues():
    """A flat-coloured object on a flat background: only the antialiased edges can carry the gradient."""
    tm = _ellipsoid(3)
    mesh = _render_mesh(tm, np.full((len(tm.vertices), 3), 0.2))
    cams = _cameras([0], [0], size=64)
    verts = _verts(tm, torch.float64)
    target = render.render(mesh, verts + torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64), cams).detach()
    t = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    (render.render(mesh, verts + t, cams) - target).square().mean().backward()
    assert t.grad[0] < 0, "moving towards the target (+x) must lower the loss"
    assert abs(t.grad[0]) > 5 * abs(t.grad[1])


def test_intersection_line_carries_the_gradient():
    """A cube pushed into a bigger one: FD and autograd agree, including the intersection line's motion."""
    big, small = trimesh.creation.box([1.0, 1.0, 1.0]), trimesh.creation.box([0.5, 0.5, 0.5])
    small.apply_translation([0.15, 0.1, 0.55])  # half inside the big cube's +Z face
    mesh = render.join([_render_mesh(big, np.tile([[0.9, 0.3, 0.2]], (8, 1))),
                        _render_mesh(small, np.tile([[0.2, 0.7, 0.3]], (8, 1)))], [8, 8])
    fixed = torch.as_tensor(big.vertices, dtype=torch.float64)[None]
    moving = torch.as_tensor(small.vertices, dtype=torch.float64)[None]
    cams = _cameras([25, -40], [30, 15], size=64)

    def loss(t: torch.Tensor) -> torch.Tensor:
        return (render.render(mesh, torch.cat([fixed, moving + t], 1), cams) - target).square().mean()

    with torch.no_grad():
        target = render.render(mesh, torch.cat([fixed, moving + torch.tensor([0.05, -0.04, -0.12])], 1), cams)
    x0 = torch.tensor([0.02, -0.02, -0.06], dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(loss(x0), x0)
    fd = torch.stack([(loss(x0.detach() + 0.01 * e) - loss(x0.detach() - 0.01 * e)) / 0.02
                      for e in torch.eye(3, dtype=torch.float64)])
    cos = torch.nn.functional.cosine_similarity(grad, fd, dim=0).item()
    assert cos >= 0.98, f"cosine {cos:.4f} (autograd {grad.tolist()}, fd {fd.tolist()})"


# -- 3. pose recovery from multi-view image MSE ----------------------------------------------------

def test_pose_recovery():
    tm = _ellipsoid(2)
    mesh = _render_mesh(tm)
    local = torch.as_tensor(tm.vertices, dtype=torch.float32)
    size = float(np.linalg.norm(np.ptp(tm.vertices, 0)))  # object size: bbox diagonal
    cams = _cameras([0, 90, 180, 270], [30, 10, 30, 10], dist=2.2, size=64)
    axis = torch.tensor([0.3, 1.0, 0.2])
    true_t = torch.tensor([[0.7, 0.35, -0.62]]) / math.sqrt(0.7**2 + 0.35**2 + 0.62**2) * 0.2 * size
    true_q = _quat(axis / axis.norm() * math.radians(20.0)).float()
    true_log_s = torch.tensor([math.log(1.15)])
    with torch.no_grad():
        target = render.render(mesh, apply_pose(local, true_t, true_q, true_log_s), cams)

    t = torch.zeros(1, 3, requires_grad=True)
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0]], requires_grad=True)
    log_s = torch.zeros(1, requires_grad=True)
    opt = torch.optim.Adam([t, q, log_s], lr=0.02)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, 200, eta_min=1e-4)
    for _ in range(200):
        opt.zero_grad()
        (render.render(mesh, apply_pose(local, t, q, log_s), cams) - target).square().mean().backward()
        opt.step()
        sched.step()

    with torch.no_grad():
        t_err = ((t - true_t).norm() / size).item()
        relative = quaternion_to_matrix(q)[0].T @ quaternion_to_matrix(true_q)[0]
        angle = math.degrees(math.acos(min(1.0, max(-1.0, (relative.trace().item() - 1) / 2))))
        s_err = abs(log_s.exp().item() / 1.15 - 1)
    assert t_err < 0.01, f"translation error {t_err:.4%} of the object size"
    assert angle < 1.0, f"rotation error {angle:.3f} deg"
    assert s_err < 0.01, f"scale error {s_err:.4%}"


# -- 4. textures and join --------------------------------------------------------------------------

QUADRANTS = {"top_left": (1, 0, 0), "top_right": (0, 1, 0), "bottom_left": (0, 0, 1), "bottom_right": (1, 1, 0)}


def _textured_quad() -> MeshArrays:
    """A 2 x 2 quad in the z = 0 plane facing +Z, UV-mapped to a texture with four coloured quadrants."""
    tex = np.zeros((16, 16, 3), np.float32)  # row 0 is the top of the image
    tex[:8, :8], tex[:8, 8:] = QUADRANTS["top_left"], QUADRANTS["top_right"]
    tex[8:, :8], tex[8:, 8:] = QUADRANTS["bottom_left"], QUADRANTS["bottom_right"]
    return MeshArrays(
        vertices=np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32),
        faces=np.array([[0, 1, 2], [0, 2, 3]]),
        colors=np.ones((4, 3), np.float32),
        uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
        texture=tex,
    )


def _quadrant_colours(img: torch.Tensor, lo: int, hi: int) -> dict[str, torch.Tensor]:
    """Mean colour of the four quadrants of the pixel window [lo, hi) x [lo, hi), normalised by its max.

    Each quadrant keeps 2 px from the window border and 6 px from the centre lines (texel blending, the
    object in front in the join test).
    """
    mid = (lo + hi) // 2
    parts = {"top_left": img[:, lo + 2:mid - 6, lo + 2:mid - 6], "top_right": img[:, lo + 2:mid - 6, mid + 6:hi - 2],
             "bottom_left": img[:, mid + 6:hi - 2, lo + 2:mid - 6],
             "bottom_right": img[:, mid + 6:hi - 2, mid + 6:hi - 2]}
    return {k: v.mean((1, 2)) / v.mean((1, 2)).max() for k, v in parts.items()}


def test_texture_is_rendered_upright_with_finite_gradients():
    arrays = _textured_quad()
    mesh = render.RenderMesh.from_arrays(arrays)
    cams = _cameras([0], [0], dist=3.0, fov=45.0, size=64)  # quad spans pixels ~[9, 55)
    verts = torch.as_tensor(arrays.vertices)[None].requires_grad_(True)
    img = render.render(mesh, verts, cams)
    for name, colour in _quadrant_colours(img[0, 0].detach(), 12, 52).items():
        assert torch.allclose(colour, torch.tensor(QUADRANTS[name], dtype=torch.float32), atol=0.05), name
    (img - 0.5).square().mean().backward()
    assert torch.isfinite(verts.grad).all() and verts.grad.abs().sum() > 0


def test_large_texture_is_downsampled():
    arrays = _textured_quad()
    arrays.texture = np.kron(arrays.texture, np.ones((64, 64, 1), np.float32))  # 1024 x 1024
    mesh = render.RenderMesh.from_arrays(arrays, max_texture_size=256)
    assert mesh.texture.shape == (3, 256, 256)
    assert torch.allclose(mesh.texture[:, 10, 10], torch.tensor(QUADRANTS["top_left"], dtype=torch.float32))


def test_join_textured_and_untextured():
    quad = _textured_quad()
    quad.uv = quad.uv + np.float32(1.0)  # tiled UVs in [1, 2]: they must repeat within the quad's atlas tile
    cube = trimesh.creation.box([0.2, 0.2, 0.2])
    cube.apply_translation([0.0, 0.0, 0.5])  # in front of the quad's centre (pixels ~29-35), towards the camera
    green = np.tile([[0.1, 0.8, 0.2]], (len(cube.vertices), 1))
    parts = [render.RenderMesh.from_arrays(quad), _render_mesh(cube, green)]
    mesh = render.join(parts, [4, len(cube.vertices)])
    assert mesh.textured and len(mesh.faces) == 2 + 12 and mesh.faces.max() == 4 + len(cube.vertices) - 1
    verts = torch.cat([torch.as_tensor(quad.vertices), torch.as_tensor(cube.vertices, dtype=torch.float32)])[None]
    img = render.render(mesh, verts, _cameras([0], [0], dist=3.0, fov=45.0, size=64))[0, 0]
    for name, colour in _quadrant_colours(img, 12, 52).items():
        assert torch.allclose(colour, torch.tensor(QUADRANTS[name], dtype=torch.float32), atol=0.05), name
    centre = img[:, 30:34, 30:34].mean((1, 2))
    assert torch.allclose(centre / centre.max(), torch.tensor([0.125, 1.0, 0.25]), atol=0.02)  # cube colour


def test_face_neighbours_encode_winding():
    quad = torch.tensor([[0, 1, 2], [0, 2, 3]])  # consistent: the shared edge 0-2 runs both ways
    assert render.face_neighbours(quad).tolist() == [[-1, 1, -1], [-1, -1, 0]]
    flipped = torch.tensor([[0, 1, 2], [0, 3, 2]])
    assert render.face_neighbours(flipped).tolist() == [[-1, -2 - 1, -1], [-1, -2 - 0, -1]]
    split = torch.tensor([[0, 1, 2], [4, 2, 3]])  # vertex 4 duplicates vertex 0 (a UV seam)
    welded = torch.tensor([0, 1, 2, 3, 0])
    assert render.face_neighbours(split).tolist() == [[-1, -1, -1], [-1, -1, -1]]
    assert render.face_neighbours(split, welded).tolist() == [[-1, 1, -1], [-1, -1, 0]]


def test_join_without_textures_keeps_colours():
    a, b = _ellipsoid(1), trimesh.creation.box([0.2, 0.2, 0.2])
    mesh = render.join([_render_mesh(a), _render_mesh(b)], [len(a.vertices), len(b.vertices)])
    assert not mesh.textured
    assert torch.equal(mesh.faces[len(a.faces):], torch.as_tensor(b.faces) + len(a.vertices))
    assert mesh.colors.shape == (len(a.vertices) + len(b.vertices), 3)


# -- devices ---------------------------------------------------------------------------------------

def test_cuda_matches_cpu():
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device on this machine")
    tm = _ellipsoid(3)
    mesh, verts, cams = _render_mesh(tm), _verts(tm), _cameras([10, 130], [20, -10], size=64)
    cpu = render.render(mesh, verts, cams)
    gpu_mesh = render.RenderMesh(mesh.faces.cuda(), mesh.colors.cuda())
    gpu_verts = verts.cuda().requires_grad_(True)
    gpu = render.render(gpu_mesh, gpu_verts, cams.to("cuda"))
    gpu.square().mean().backward()
    assert torch.allclose(cpu, gpu.detach().cpu(), atol=1e-4)
    assert torch.isfinite(gpu_verts.grad).all()
