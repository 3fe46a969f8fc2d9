"""A small differentiable rasterizer in pure PyTorch (nvdiffrast-style), batched over restarts and views.

Why our own: nvdiffrast and kaolin are CUDA-only and PyTorch3D's CPU path is ~70x slower (see
docs/renderer-study.md); this runs wherever torch runs, CPU or CUDA, with the same code.

Pipeline, for verts (B, V, 3) in the *normalised* frame and B x C cameras (N = B * C images):

1. Per face instance m = n * F + f (image n, face f), in the *camera* frame: three "edge planes"
   e_i(p) = d(p) . (V_j x V_k) / det(V0, V1, V2), affine in the pixel position p, where d(p) is the ray
   through p (z = -1). They are the perspective-correct barycentrics divided by the depth: e_i >= 0 inside
   the triangle, whatever its winding, and sum_i e_i = 1 / depth. Differentiable w.r.t. the vertices.
2. Hard z-buffer without gradient: enumerate (face instance, pixel centre) pairs inside each face's
   screen bounding box, keep the inside ones and take the nearest per pixel with one ``scatter_reduce``
   (amax) on a 64-bit key (1/depth bits, face instance). No back-face culling: uploads are not reliably
   wound, so only the depth test decides.
3. At covered pixels, recompute the barycentrics from the edge planes with gradient, interpolate vertex
   colours and UVs (texture lookup with ``grid_sample``) and multiply by the face's flat Lambert shading.
4. Analytic antialiasing as nvdiffrast's ``antialias``: for each horizontally or vertically adjacent
   pixel pair showing different faces, find where the front face's edge crosses the segment between the
   two pixel centres and blend the pair's colours in proportion. The blend is continuous in the vertex
   positions, so silhouettes (and flat-shading creases) carry gradients.

Shading: flat (one normal per face), because low-poly uploads (a 20-face star) have no meaningful vertex
normals; two-sided (the normal is flipped to face the camera); a key light from the camera, raised a
little, plus ambient. Faces with a vertex closer than ``NEAR`` to the camera plane are dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from ctp_core.cameras import Cameras, view_to_pixels
from ctp_core.structures import MeshArrays

AMBIENT = 0.35  # light on faces turned away from the key light; the key light adds up to 1 - AMBIENT
KEY_LIGHT = (0.0, 0.3, 1.0)  # camera frame, towards the light: from the camera, raised ~17 degrees
NEAR = 1e-2  # normalised-frame units; faces reaching closer to the camera plane are not drawn
INSIDE_TOL = 1e-5  # relative barycentric slack so pixel centres on shared edges never fall in a crack


@dataclass
class RenderMesh:
    """Topology and appearance on one device; vertex positions are passed to ``render`` separately."""

    faces: Tensor  # (F, 3) long
    colors: Tensor  # (V, 3) float in [0, 1]
    uv: Tensor | None = None  # (V, 2), v = 0 at the image bottom (trimesh convention)
    texture: Tensor | None = None  # (3, H, W) in [0, 1]; multiplies the colour

    @property
    def textured(self) -> bool:
        return self.uv is not None and self.texture is not None

    @classmethod
    def from_arrays(cls, arrays: MeshArrays, device: torch.device | str = "cpu",
                    max_texture_size: int = 1024) -> RenderMesh:
        """Tensors from ``MeshArrays``; textures larger than ``max_texture_size`` are downsampled.

        A 224-px render samples a few hundred texels across an object at most, so bigger textures cost
        memory and time for nothing. A texture without UVs (or UVs without texture) is dropped.
        """
        faces = torch.as_tensor(arrays.faces, dtype=torch.long, device=device)
        colors = torch.as_tensor(arrays.colors, dtype=torch.float32, device=device)
        if arrays.uv is None or arrays.texture is None:
            return cls(faces, colors)
        texture = torch.as_tensor(arrays.texture, dtype=torch.float32, device=device).permute(2, 0, 1)
        height, width = texture.shape[1:]
        if max(height, width) > max_texture_size:
            factor = max_texture_size / max(height, width)
            size = (max(1, round(height * factor)), max(1, round(width * factor)))
            texture = F.interpolate(texture[None], size=size, mode="bilinear", antialias=True)[0].clamp(0, 1)
        uv = torch.as_tensor(arrays.uv, dtype=torch.float32, device=device)
        return cls(faces, colors, uv, texture.contiguous())


def join(meshes: Sequence[RenderMesh], vertex_counts: Sequence[int]) -> RenderMesh:
    """One mesh from parts whose vertices will be concatenated in this order.

    Faces are offset by the preceding vertex counts. If any part is textured, the textures are packed
    side by side into one atlas (untextured parts get a white patch) and the UVs are remapped into their
    tile, inset by half a texel so bilinear lookups never bleed into a neighbour.
    """
    offsets = torch.tensor([0, *vertex_counts[:-1]]).cumsum(0).tolist()
    faces = torch.cat([m.faces + off for m, off in zip(meshes, offsets, strict=True)])
    colors = torch.cat([m.colors for m in meshes])
    if not any(m.textured for m in meshes):
        return RenderMesh(faces, colors)
    white = torch.ones(3, 4, 4, dtype=colors.dtype, device=colors.device)
    tiles = [m.texture if m.textured else white for m in meshes]
    height, width = max(t.shape[1] for t in tiles), sum(t.shape[2] for t in tiles)
    atlas = torch.ones(3, height, width, dtype=colors.dtype, device=colors.device)
    uvs, x = [], 0
    for mesh, count, tile in zip(meshes, vertex_counts, tiles, strict=True):
        h, w = tile.shape[1:]
        atlas[:, :h, x:x + w] = tile
        uv = _wrap_uv(mesh.uv) if mesh.textured else torch.full((count, 2), 0.5, dtype=colors.dtype,
                                                                 device=colors.device)
        u = uv[:, 0].clamp(0.5 / w, 1 - 0.5 / w)
        v = uv[:, 1].clamp(0.5 / h, 1 - 0.5 / h)
        uvs.append(torch.stack([(x + u * w) / width, 1 - (1 - v) * h / height], dim=-1))
        x += w
    return RenderMesh(faces, colors, torch.cat(uvs), atlas)


def render(mesh: RenderMesh, verts: Tensor, cameras: Cameras, *, background: float = 1.0) -> Tensor:
    """verts (B, V, 3) normalised frame -> images (B, C, 3, H, W) in [0, 1]; differentiable w.r.t. verts."""
    batch, views = cameras.fov_deg.shape
    size = cameras.image_size
    planes, shade, bbox = _face_planes(mesh.faces, verts, cameras)
    fid = _rasterize(planes.detach(), bbox, len(mesh.faces), size)
    covered = (fid >= 0).nonzero()[:, 0]
    m = fid[covered]
    table = torch.cat([planes.flatten(1), shade[:, None]], dim=1)[m]  # one gather: 9 plane coefficients + shade
    e = (table[:, :9].view(-1, 3, 3) * _pixel_centres(covered, size).to(verts.dtype)[:, None, :]).sum(-1)
    bary = e / e.sum(-1, keepdim=True)
    colour = _albedo(mesh, m % len(mesh.faces), bary, verts.dtype) * table[:, 9:]
    img = torch.full((batch * views * size * size, 3), background, dtype=verts.dtype, device=verts.device)
    img = _antialias(img.index_put((covered,), colour), fid, planes, size)
    # A pixel blended from several sides can overshoot slightly (as in nvdiffrast); keep the [0, 1] contract.
    return img.clamp(0, 1).view(batch, views, size, size, 3).permute(0, 1, 4, 2, 3)


@torch.no_grad()
def coverage(mesh: RenderMesh, verts: Tensor, cameras: Cameras) -> Tensor:
    """(B, C, H, W) bool: pixel centres covered by any face (hard, no antialiasing, no gradient)."""
    batch, views = cameras.fov_deg.shape
    size = cameras.image_size
    planes, _, bbox = _face_planes(mesh.faces, verts, cameras)
    return (_rasterize(planes, bbox, len(mesh.faces), size) >= 0).view(batch, views, size, size)


def _face_planes(faces: Tensor, verts: Tensor, cameras: Cameras) -> tuple[Tensor, Tensor, Tensor]:
    """Edge planes (M, 3, 3), flat shading (M,) and pixel bounding boxes (M, 4) of all face instances.

    planes[m, i] = (a, b, c) with e_i(x, y) = a x + b y + c at pixel position (x, y). bbox[m] is the
    inclusive range x0, y0, x1, y1 of pixel indices whose centres may be inside; empty for dropped faces.
    """
    size = cameras.image_size
    focal = cameras.focal_px().to(verts.dtype)  # (B, C)
    view = cameras.to_view(verts[:, None])  # (B, C, V, 3) camera frame
    tri = view[:, :, faces].flatten(0, 2)  # (M, 3 vertices, 3)
    v0, v1, v2 = tri.unbind(1)
    edges = torch.stack([torch.linalg.cross(v1, v2), torch.linalg.cross(v2, v0), torch.linalg.cross(v0, v1)], 1)
    det = (v0 * edges[:, 0]).sum(-1)  # (M,) triple product; its sign is the winding seen from the camera
    f = focal[..., None].expand(-1, -1, len(faces)).reshape(-1, 1)  # (M, 1)

    with torch.no_grad():
        pix = view_to_pixels(tri.detach().view(*view.shape[:2], -1, 3), focal, size).view(-1, 3, 3)
        x, y, depth = pix.unbind(-1)  # (M, 3) each
        area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
        keep = (depth.amin(-1) > NEAR) & (area2.abs() > 1e-9)
        lo = torch.stack([x.amin(-1), y.amin(-1)], -1).clamp(-1, size + 1)
        hi = torch.stack([x.amax(-1), y.amax(-1)], -1).clamp(-1, size + 1)
        first = torch.ceil(lo - 0.5).long().clamp_min(0)
        last = torch.floor(hi - 0.5).long().clamp_max(size - 1)
        last = torch.where(keep[:, None], last, first - 1)
        bbox = torch.cat([first, last], -1)

    # d(x, y) = ((x - s/2) / f, -(y - s/2) / f, -1), so d . E = E_x/f x - E_y/f y + (E_y - E_x) s/(2f) - E_z.
    ex, ey, ez = (edges / torch.where(keep, det, torch.ones_like(det))[:, None, None]).unbind(-1)
    planes = torch.stack([ex / f, -ey / f, (ey - ex) * (size / 2) / f - ez], -1)

    normal = edges.sum(1)  # (v1 - v0) x (v2 - v0), camera frame
    facing = -torch.sign(det)[:, None]  # flips the normal towards the camera: two-sided lighting
    light = torch.tensor(KEY_LIGHT, dtype=verts.dtype, device=verts.device)
    lambert = (facing * normal * (light / light.norm())).sum(-1) / normal.norm(dim=-1).clamp_min(1e-20)
    shade = AMBIENT + (1 - AMBIENT) * lambert.clamp_min(0)
    return planes, shade, bbox


@torch.no_grad()
def _rasterize(planes: Tensor, bbox: Tensor, faces_per_image: int, size: int) -> Tensor:
    """Nearest face instance per pixel, (N * size * size,) long, -1 where nothing is drawn."""
    width = bbox[:, 2] - bbox[:, 0] + 1
    count = width.clamp_min(0) * (bbox[:, 3] - bbox[:, 1] + 1).clamp_min(0)
    live = count.nonzero()[:, 0]
    count = count[live]
    start = count.cumsum(0) - count
    info = torch.stack([live, bbox[live, 0], bbox[live, 1], width[live], start], -1)[
        torch.repeat_interleave(count)]  # (K, 5): one row per (face instance, pixel) candidate
    local = torch.arange(len(info), device=info.device) - info[:, 4]
    row = local.div(info[:, 3], rounding_mode="floor")
    px, py = info[:, 1] + local - row * info[:, 3], info[:, 2] + row
    m = info[:, 0]
    centres = torch.stack([px + 0.5, py + 0.5, torch.ones_like(px)], -1).to(planes.dtype)
    e = (planes[m] * centres[:, None, :]).sum(-1)  # (K, 3)
    inv_depth = e.sum(-1)
    hit = (e.amin(-1) >= -INSIDE_TOL * inv_depth) & (inv_depth > 0)
    m, inv_depth = m[hit], inv_depth[hit]
    pixel = (m // faces_per_image * size + py[hit]) * size + px[hit]
    # Positive float32 bit patterns sort like the floats, so the high word orders by 1/depth (nearest
    # wins) and the low word breaks ties deterministically.
    key = (inv_depth.float().view(torch.int32).long() << 32) | m
    images = len(planes) // faces_per_image
    best = torch.full((images * size * size,), -1, dtype=torch.long, device=planes.device)
    best.scatter_reduce_(0, pixel, key, "amax")
    return torch.where(best >= 0, best & 0xFFFFFFFF, -1)


def _pixel_centres(pixel: Tensor, size: int) -> Tensor:
    """Flat pixel indices (n * size + y) * size + x -> (P, 3) homogeneous centres (x + 0.5, y + 0.5, 1)."""
    within = pixel % (size * size)
    row = within.div(size, rounding_mode="floor")
    return torch.stack([within - row * size + 0.5, row + 0.5, torch.ones_like(row)], -1).float()


def _albedo(mesh: RenderMesh, face: Tensor, bary: Tensor, dtype: torch.dtype) -> Tensor:
    """(P, 3) vertex colour, times the texture where there is one, at barycentrics (P, 3) of faces (P,)."""
    corners = mesh.faces[face]  # (P, 3)
    colour = (mesh.colors.to(dtype)[corners] * bary[..., None]).sum(1)
    if not mesh.textured:
        return colour
    uv = _wrap_uv((mesh.uv.to(dtype)[corners] * bary[..., None]).sum(1))
    grid = torch.stack([uv[:, 0] * 2 - 1, 1 - uv[:, 1] * 2], -1)  # grid_sample: y = -1 is the top row
    texel = F.grid_sample(mesh.texture.to(dtype)[None], grid[None, None], mode="bilinear",
                          padding_mode="border", align_corners=False)[0, :, 0].T
    return colour * texel


def _wrap_uv(uv: Tensor) -> Tensor:
    """Repeat-wrap coordinates outside [0, 1]; those inside, 1.0 included, are kept (no seam at u = 1)."""
    outside = (uv < 0) | (uv > 1)
    return torch.where(outside, uv - torch.floor(uv), uv)


def _antialias(img: Tensor, fid: Tensor, planes: Tensor, size: int) -> Tensor:
    """Blend adjacent pixels across the front face's edges (nvdiffrast ``antialias``), with gradient.

    img (N * size * size, 3) flat images; fid the face instance per pixel; planes (M, 3, 3) edge planes.
    For a pair (inside pixel of the front face, outside pixel) whose segment the front face's edge crosses
    at fraction t from the inside centre, the face covers t - 1/2 of a pixel beyond the midpoint: the
    outside pixel moves towards the inside colour when t > 1/2, the inside one towards the outside colour
    when t < 1/2, by |t - 1/2| of the colour difference. This is continuous as an edge passes a centre.
    """
    grid = fid.view(-1, size, size)
    across = (grid[:, :, :-1] != grid[:, :, 1:]).flatten().nonzero()[:, 0]
    down = (grid[:, :-1, :] != grid[:, 1:, :]).flatten().nonzero()[:, 0]
    first = torch.cat([across + across.div(size - 1, rounding_mode="floor"),
                       down + down.div((size - 1) * size, rounding_mode="floor") * size])
    second = first + torch.cat([torch.ones_like(across), torch.full_like(down, size)])
    m0, m1 = fid[first], fid[second]
    centre0, centre1 = _pixel_centres(first, size).to(planes.dtype), _pixel_centres(second, size).to(planes.dtype)
    with torch.no_grad():  # which face is in front: the nearer plane at the midpoint of the two centres
        depth_planes = planes.detach().sum(1)  # (M, 3): 1/depth as an affine function of the pixel
        mid = (centre0 + centre1) / 2
        inv0 = (depth_planes[m0.clamp_min(0)] * mid).sum(-1)
        inv1 = (depth_planes[m1.clamp_min(0)] * mid).sum(-1)
        front0 = (m1 < 0) | ((m0 >= 0) & (inv0 >= inv1))
    inside, outside = torch.where(front0, first, second), torch.where(front0, second, first)
    c_in, c_out = torch.where(front0[:, None], centre0, centre1), torch.where(front0[:, None], centre1, centre0)
    rows = planes[torch.where(front0, m0, m1)]  # (Q, 3, 3) with gradient
    e_in, e_out = (rows * c_in[:, None, :]).sum(-1), (rows * c_out[:, None, :]).sum(-1)
    crosses = e_out < 0  # edge i separates the two centres
    t = torch.where(crosses, e_in / torch.where(crosses, e_in - e_out, torch.ones_like(e_in)), 2.0).amin(-1)
    found = crosses.any(-1)  # none: a pair split by an intersection line, not by an edge of the front face
    weight = (t[found].clamp(0, 1) - 0.5)[:, None]
    inside, outside = inside[found], outside[found]
    delta = weight * (img[inside] - img[outside])
    return img.index_add(0, torch.where(weight[:, 0] > 0, outside, inside), delta)
