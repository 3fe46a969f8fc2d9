"""A small differentiable rasterizer in pure PyTorch (nvdiffrast-style), batched over restarts and views.

Why our own: nvdiffrast and kaolin are CUDA-only and PyTorch3D's CPU path is ~70x slower (see
../shared/docs/renderer-study.md, outside the repository); this runs wherever torch runs, CPU or CUDA, with
the same code.

Stages, as in PyTorch3D (rasterizer -> ``Fragments`` -> shader), for verts (B, V, 3) in the *normalised*
frame and B x C cameras (N = B * C images); ``render`` is their composition:

``rasterize`` -> ``Fragments`` (what was found per pixel; no shading):
1. Per face instance m = n * F + f (image n, face f), in the *camera* frame: three "edge planes"
   e_i(p) = d(p) . (V_j x V_k) / det(V0, V1, V2), affine in the pixel position p, where d(p) is the ray
   through p (z = -1). They are the perspective-correct barycentrics divided by the depth: e_i >= 0 inside
   the triangle, whatever its winding, and sum_i e_i = 1 / depth. Differentiable w.r.t. the vertices.
2. Hard z-buffer without gradient: enumerate the (face instance, pixel centre) pairs inside each face,
   row by row of its screen bounding box (scanline spans), and take the nearest per pixel with one
   ``scatter_reduce`` (amax) on a 64-bit key (1/depth bits, face instance). No back-face culling: uploads
   are not reliably wound, so only the depth test decides. At the covered pixels, the barycentrics and
   depth are recomputed from the edge planes with gradient.

``shade`` (``Lights``):
3. Interpolate vertex colours and UVs at the covered pixels (texture lookup with ``grid_sample``) and
   multiply by the face's flat Lambert shading.

``antialias``:
4. Analytic antialiasing after nvdiffrast's ``antialias``: for each horizontally or vertically adjacent
   pixel pair showing different faces, find where the segment between the two pixel centres leaves the
   front surface (walking across the mesh's interior edges to a silhouette edge, or to the line where two
   intersecting surfaces cross) and blend the pair's colours in proportion. The blend is continuous in
   the vertex positions, so silhouettes, intersection lines and flat-shading creases carry gradients.

Shading: flat (one normal per face), because low-poly uploads (a 20-face star) have no meaningful vertex
normals; two-sided (the normal is flipped to face the camera); by default a key light from the camera,
raised a little, plus ambient (``Lights``). Faces with a vertex closer than ``NEAR_PLANE`` to the camera plane
are dropped.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ctp_core.render.cameras import Cameras, view_to_pixels
from ctp_core.render.structures import MeshArrays

NEAR_PLANE = 1e-2  # normalised-frame units; faces reaching closer to the camera plane are not drawn
SPAN_TOL = 1e-4  # pixels of slack in the scanline spans, so centres on shared edges never fall in a crack


@dataclass
class RenderMesh:
    """Topology and appearance on one device; vertex positions are passed to ``render`` separately."""

    faces: Tensor  # (F, 3) long
    colors: Tensor  # (V, 3) float in [0, 1]
    uv: Tensor | None = None  # (V, 2), v = 0 at the image bottom (trimesh convention)
    texture: Tensor | None = None  # (3, H, W) in [0, 1]; multiplies the colour
    neighbours: Tensor | None = None  # (F, 3) long, see ``face_neighbours``; computed when None
    tiles: Tensor | None = None  # (F, 4) texel rectangle x0, y0 (from the top), width, height; None: all

    def __post_init__(self) -> None:
        if self.neighbours is None:  # from vertex indices; from_arrays also joins vertices split at seams
            self.neighbours = face_neighbours(self.faces)

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
        # Vertices split at UV or colour seams still join their faces: weld by position for the topology.
        _, welded = np.unique(np.asarray(arrays.vertices), axis=0, return_inverse=True)
        neighbours = face_neighbours(faces, torch.as_tensor(welded.reshape(-1), device=device))
        if arrays.uv is None or arrays.texture is None:
            return cls(faces, colors, neighbours=neighbours)
        texture = torch.as_tensor(arrays.texture, dtype=torch.float32, device=device).permute(2, 0, 1)
        height, width = texture.shape[1:]
        if max(height, width) > max_texture_size:
            factor = max_texture_size / max(height, width)
            size = (max(1, round(height * factor)), max(1, round(width * factor)))
            texture = F.interpolate(texture[None], size=size, mode="bilinear", antialias=True)[0].clamp(0, 1)
        uv = torch.as_tensor(arrays.uv, dtype=torch.float32, device=device)
        return cls(faces, colors, uv, texture.contiguous(), neighbours)


def join(meshes: Sequence[RenderMesh], vertex_counts: Sequence[int]) -> RenderMesh:
    """One mesh from parts whose vertices will be concatenated in this order.

    Faces are offset by the preceding vertex counts. If any part is textured, the textures are packed
    side by side into one atlas (untextured parts get a white patch) and each face records its part's
    tile: UVs stay as they were and repeat-wrap inside the tile at lookup, so tiled UVs outside [0, 1]
    keep working.
    """
    offsets = torch.tensor([0, *vertex_counts[:-1]]).cumsum(0).tolist()
    faces = torch.cat([m.faces + off for m, off in zip(meshes, offsets, strict=True)])
    face_offsets = torch.tensor([0, *(len(m.faces) for m in meshes[:-1])]).cumsum(0).tolist()
    neighbours = torch.cat([torch.where(m.neighbours >= 0, m.neighbours + off,
                                        torch.where(m.neighbours < -1, m.neighbours - off, -1))
                            for m, off in zip(meshes, face_offsets, strict=True)])
    colors = torch.cat([m.colors for m in meshes])
    if not any(m.textured for m in meshes):
        return RenderMesh(faces, colors, neighbours=neighbours)
    like = dict(dtype=colors.dtype, device=colors.device)
    white = torch.ones(3, 4, 4, **like)
    atlas = [m.texture if m.textured else white for m in meshes]
    height = max(t.shape[1] for t in atlas)
    uvs, tiles, x = [], [], 0
    for mesh, count, tile in zip(meshes, vertex_counts, atlas, strict=True):
        h, w = tile.shape[1:]
        if mesh.textured:
            uvs.append(mesh.uv)
            tiles.append(_tiles(mesh).to(**like) + torch.tensor([x, 0, 0, 0], **like))
        else:
            uvs.append(torch.full((count, 2), 0.5, **like))
            tiles.append(torch.tensor([[x, 0, w, h]], **like).expand(len(mesh.faces), 4))
        x += w
    atlas = torch.cat([F.pad(t, (0, 0, 0, height - t.shape[1]), value=1.0) for t in atlas], dim=2)
    return RenderMesh(faces, colors, torch.cat(uvs), atlas, neighbours, torch.cat(tiles))


def _tiles(mesh: RenderMesh) -> Tensor:
    """(F, 4) texel rectangle of each face's texture: the whole texture unless ``tiles`` says otherwise."""
    if mesh.tiles is not None:
        return mesh.tiles
    h, w = mesh.texture.shape[1:]
    return torch.tensor([[0, 0, w, h]], dtype=mesh.texture.dtype, device=mesh.texture.device).expand(
        len(mesh.faces), 4)


def face_neighbours(faces: Tensor, vertex_ids: Tensor | None = None) -> Tensor:
    """(F, 3) the face across the edge opposite each corner: g if it is wound like this face, -2 - g if
    it is wound the other way (uploads are not reliably wound), -1 on boundary and non-manifold edges.

    ``vertex_ids`` (V,) maps vertices to welded ids (equal positions share one) when given.
    """
    ids = faces if vertex_ids is None else vertex_ids[faces]
    a, b = ids[:, [1, 2, 0]].flatten(), ids[:, [2, 0, 1]].flatten()  # edge i runs between the other corners
    key = torch.minimum(a, b) * (int(ids.max()) + 1 if len(ids) else 1) + torch.maximum(a, b)
    key, order = key.sort()
    same = key[1:] == key[:-1]
    pair = same.clone()  # runs of exactly two half-edges are manifold edges
    pair[1:] &= ~same[:-1]
    pair[:-1] &= ~same[1:]
    j = pair.nonzero()[:, 0]
    h0, h1 = order[j], order[j + 1]
    flipped = (a[h0] < b[h0]) == (a[h1] < b[h1])  # consistent winding runs a shared edge both ways
    out = torch.full((len(key),), -1, dtype=torch.long, device=faces.device)
    out[h0] = torch.where(flipped, -2 - h1 // 3, h1 // 3)
    out[h1] = torch.where(flipped, -2 - h0 // 3, h0 // 3)
    return out.view(-1, 3)


@dataclass(frozen=True)
class Lights:
    """Flat, two-sided lighting: ambient plus one directional key light that moves with the camera."""

    ambient: float = 0.35  # light on faces turned away from the key light; the key light adds up to 1 - ambient
    direction: tuple[float, float, float] = (0.0, 0.3, 1.0)  # camera frame, towards the light: raised ~17 degrees


@dataclass
class Fragments:
    """What ``rasterize`` found, for the later stages (PyTorch3D's ``Fragments``, kept sparse).

    Face instance m = n * F + f: face f of the mesh in image n = b * C + c. Per pixel, the nearest instance;
    at the P covered pixels, its barycentrics and depth; per instance, what shading and antialiasing use.
    Tensors marked "gradient" carry it w.r.t. the vertices.
    """

    pix_to_face: Tensor  # (B, C, H, W) long: face instance per pixel, -1 where nothing is drawn
    pixels: Tensor  # (P,) covered pixels, flat indices into pix_to_face, ascending
    pixel_faces: Tensor  # (P,) the face instance at each covered pixel
    bary_coords: Tensor  # (P, 3) perspective-correct barycentrics of the pixel centre; gradient
    depth: Tensor  # (P,) camera-frame depth (-z) at the pixel centre; gradient
    planes: Tensor  # (M, 3, 3) edge planes, rows a, b, c over edges i: e_i(x, y) = a_i x + b_i y + c_i; gradient
    facing: Tensor  # (M,) int8: sign of the winding seen from the camera, 0 for dropped faces
    normals: Tensor  # (M, 3) camera frame, unnormalised, turned towards the camera (two-sided); gradient

    @property
    def mask(self) -> Tensor:
        """(B, C, H, W) bool: pixel centres covered by any face (hard: the silhouette before antialiasing)."""
        return self.pix_to_face >= 0

    def dense(self, values: Tensor, fill: float) -> Tensor:
        """Values at the covered pixels (P, ...) -> (B, C, H, W, ...), ``fill`` where nothing is drawn."""
        flat = torch.full((self.pix_to_face.numel(), *values.shape[1:]), fill, dtype=values.dtype,
                          device=values.device)
        return flat.index_put((self.pixels,), values).view(*self.pix_to_face.shape, *values.shape[1:])


def render(mesh: RenderMesh, verts: Tensor, cameras: Cameras, *, background: float = 1.0,
           lights: Lights = Lights()) -> Tensor:
    """verts (B, V, 3) normalised frame -> images (B, C, 3, H, W) in [0, 1]; differentiable w.r.t. verts."""
    fragments = rasterize(mesh, verts, cameras)
    images = antialias(mesh, fragments, shade(mesh, fragments, lights, background=background))
    # A pixel blended from several sides can overshoot slightly (as in nvdiffrast); keep the [0, 1] contract.
    return images.clamp(0, 1).permute(0, 1, 4, 2, 3)


def rasterize(mesh: RenderMesh, verts: Tensor, cameras: Cameras) -> Fragments:
    """verts (B, V, 3) normalised frame -> the nearest face per pixel of B x C images (steps 1-2 above).

    Costs no shading: under ``torch.no_grad`` it is the cheap silhouette (``mask``) or depth pass.
    """
    batch, views = cameras.fov_deg.shape
    size = cameras.image_size
    planes, facing, normals, bbox = _face_instances(mesh.faces, verts, cameras)
    pix_to_face = _nearest_faces(planes.detach(), bbox, batch * views, size)
    pixels = (pix_to_face >= 0).nonzero()[:, 0]
    pixel_faces = pix_to_face.index_select(0, pixels)
    x, y = _pixel_centres(pixels, size, verts.dtype)
    e = _edge_values(planes.index_select(0, pixel_faces), x, y)
    inverse_depth = e.sum(-1, keepdim=True)  # sum_i e_i = 1 / depth
    return Fragments(pix_to_face.view(batch, views, size, size), pixels, pixel_faces, e / inverse_depth,
                     inverse_depth[:, 0].reciprocal(), planes, facing, normals)


def shade(mesh: RenderMesh, fragments: Fragments, lights: Lights = Lights(), *, background: float = 1.0) -> Tensor:
    """(B, C, H, W, 3) images, channels last as the rasterizer's grid: albedo times flat Lambert (step 3).

    Albedo is the interpolated vertex colour, times the texture where there is one; not antialiased.
    """
    normals = fragments.normals
    light = torch.tensor(lights.direction, dtype=normals.dtype, device=normals.device)
    lambert = (normals * (light / light.norm())).sum(-1) / normals.norm(dim=-1).clamp_min(1e-20)
    factor = lights.ambient + (1 - lights.ambient) * lambert.clamp_min(0)  # (M,) per face instance
    faces = fragments.pixel_faces
    colour = _albedo(mesh, faces % len(mesh.faces), fragments.bary_coords) * factor.index_select(0, faces)[:, None]
    return fragments.dense(colour, background)


def antialias(mesh: RenderMesh, fragments: Fragments, images: Tensor) -> Tensor:
    """Blend adjacent pixels across visibility boundaries (nvdiffrast ``antialias``), with gradient (step 4).

    images (B, C, H, W, 3) as ``shade`` gives them. For a pair (inside pixel of the front surface, outside
    pixel) whose segment crosses the boundary at fraction t from the inside centre, the front surface
    covers t - 1/2 of a pixel beyond the midpoint: the outside pixel moves towards the inside colour when
    t > 1/2, the inside one towards the outside colour when t < 1/2, by |t - 1/2| of the colour
    difference. This is continuous as a boundary passes a pixel centre.

    The boundary is found by walking from the front face along the segment (``_walk_to_surface_end``):
    - an edge where the surface ends (boundary, fold) or meets the face the other pixel shows: the edge;
    - the surface goes on under the other pixel, whose face is nearer there: the two surfaces intersect,
      and the boundary is where their depth planes cross (1/depth is affine in the pixel, so this is a
      line too). nvdiffrast leaves these unblended; here an object pushed into another still gets a
      gradient from the intersection line.
    """
    size = fragments.pix_to_face.shape[-1]
    grid = fragments.pix_to_face.view(-1, size, size)
    fid = grid.view(-1)
    img = images.reshape(-1, images.shape[-1])
    across = (grid[:, :, :-1] != grid[:, :, 1:]).flatten().nonzero()[:, 0]
    down = (grid[:, :-1, :] != grid[:, 1:, :]).flatten().nonzero()[:, 0]
    first = torch.cat([across + across.div(size - 1, rounding_mode="floor"),
                       down + down.div((size - 1) * size, rounding_mode="floor") * size])
    horizontal = torch.arange(len(first), device=first.device) < len(across)
    second = first + torch.where(horizontal, 1, size)
    planes = fragments.planes
    depth = planes.sum(-1)  # (M, 3): 1/depth = a x + b y + c, with gradient
    with torch.no_grad():
        m0, m1 = fid.index_select(0, first), fid.index_select(0, second)
        x0, y0 = _pixel_centres(first, size, planes.dtype)
        step_x, step_y = horizontal.to(planes.dtype), (~horizontal).to(planes.dtype)  # first -> second
        mid = torch.stack([x0 + step_x / 2, y0 + step_y / 2, torch.ones_like(x0)], -1)
        inv0 = (depth.detach().index_select(0, m0.clamp_min(0)) * mid).sum(-1)
        inv1 = (depth.detach().index_select(0, m1.clamp_min(0)) * mid).sum(-1)
        front0 = (m1 < 0) | ((m0 >= 0) & (inv0 >= inv1))  # the nearer plane at the midpoint is in front
        inside, outside = torch.where(front0, first, second), torch.where(front0, second, first)
        face, other = torch.where(front0, m0, m1), torch.where(front0, m1, m0)
        back = (~front0).to(planes.dtype)  # the segment runs inside -> outside: second -> first if back
        segment = torch.stack([x0 + step_x * back, y0 + step_y * back, step_x * (1 - 2 * back),
                               step_y * (1 - 2 * back)], -1)
        face, edge, ends, covers = _walk_to_surface_end(planes.detach(), fragments.facing, mesh.neighbours, face,
                                                        other, segment)
        at_edge = ends.nonzero()[:, 0]
        at_crossing = (covers & (other >= 0)).nonzero()[:, 0]
    # The boundary as a line l(x, y) = a x + b y + c, >= 0 on the inside centre and < 0 on the outside one.
    edge_lines = planes.index_select(0, face[at_edge]).gather(2, edge[at_edge, None, None].expand(-1, 3, 1))[..., 0]
    crossing_lines = depth.index_select(0, face[at_crossing]) - depth.index_select(0, other[at_crossing])
    lines, pairs = torch.cat([edge_lines, crossing_lines]), torch.cat([at_edge, at_crossing])
    x_in, y_in, dx, dy = segment.index_select(0, pairs).unbind(-1)
    a, b, c = lines.unbind(-1)
    value, slope = a * x_in + b * y_in + c, a * dx + b * dy
    with torch.no_grad():  # depth planes extended from one pixel to the next need not cross between them
        keep = ((slope < 0) & (value >= 0) & (value + slope < 0)).nonzero()[:, 0]
    a, b, value, slope, pairs = (v.index_select(0, keep) for v in (a, b, value, slope, pairs))
    t = -value / slope
    # A straight boundary moved by d changes the image by d per unit length through its horizontal pairs
    # alone, and again through its vertical pairs alone; share it between the two by cos^2 / sin^2 of its
    # normal (nvdiffrast picks one by slope, which jumps as an edge turns through 45 degrees).
    a2, b2 = a.square(), b.square()
    weight = torch.where(horizontal.index_select(0, pairs), a2, b2) / (a2 + b2) * (t.clamp(0, 1) - 0.5)
    inside, outside = inside.index_select(0, pairs), outside.index_select(0, pairs)
    delta = weight[:, None] * (img.index_select(0, inside) - img.index_select(0, outside))
    return img.index_add(0, torch.where(weight > 0, outside, inside), delta).view_as(images)


def _face_instances(faces: Tensor, verts: Tensor, cameras: Cameras) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per face instance (see ``Fragments``), camera frame of its image: edge planes, facing, normals, and
    bbox (M, 4), the inclusive pixel index range x0, y0, x1, y1 of candidate centres (empty if dropped)."""
    size = cameras.image_size
    focal = cameras.focal_px().to(verts.dtype)  # (B, C)
    view = cameras.to_view(verts[:, None])  # (B, C, V, 3) camera frame
    images, count = view.shape[0] * view.shape[1], view.shape[2]
    corners = (torch.arange(images, device=faces.device)[:, None] * count + faces.flatten()).flatten()
    tri = view.reshape(-1, 3).index_select(0, corners).view(-1, 3, 3)  # (M, 3 vertices, 3)
    v0, v1, v2 = tri.unbind(1)
    edges = torch.stack([torch.linalg.cross(v1, v2), torch.linalg.cross(v2, v0), torch.linalg.cross(v0, v1)], 1)
    det = (v0 * edges[:, 0]).sum(-1)  # (M,) triple product; its sign is the winding seen from the camera
    f = focal[..., None].expand(-1, -1, len(faces)).reshape(-1, 1)  # (M, 1)

    with torch.no_grad():
        pix = view_to_pixels(tri.detach().view(*view.shape[:2], -1, 3), focal, size).view(-1, 3, 3)
        x, y, depth = pix.unbind(-1)  # (M, 3) each
        area2 = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
        # Faces under ~1e-6 px² cover no pixel centre; dropping them (and exact-zero triple products, which
        # float32 cancellation gives for tiny faces) keeps 1/det out of the backward pass.
        keep = (depth.amin(-1) > NEAR_PLANE) & (area2.abs() > 1e-6) & (det.detach() != 0)
        lo = torch.stack([x.amin(-1), y.amin(-1)], -1).clamp(-1, size + 1)
        hi = torch.stack([x.amax(-1), y.amax(-1)], -1).clamp(-1, size + 1)
        first = torch.ceil(lo - 0.5).long().clamp_min(0)
        last = torch.floor(hi - 0.5).long().clamp_max(size - 1)
        last = torch.where(keep[:, None], last, first - 1)
        bbox = torch.cat([first, last], -1)

    # d(x, y) = ((x - s/2) / f, -(y - s/2) / f, -1), so d . E = E_x/f x - E_y/f y + (E_y - E_x) s/(2f) - E_z.
    ex, ey, ez = (edges / torch.where(keep, det, torch.ones_like(det))[:, None, None]).unbind(-1)
    planes = torch.stack([ex / f, -ey / f, (ey - ex) * (size / 2) / f - ez], 1)

    # (v1 - v0) x (v2 - v0), flipped towards the camera: two-sided lighting
    normals = -torch.sign(det)[:, None] * edges.sum(1)
    return planes, (torch.sign(det.detach()) * keep).to(torch.int8), normals, bbox


@torch.no_grad()
def _nearest_faces(planes: Tensor, bbox: Tensor, images: int, size: int) -> Tensor:
    """Nearest face instance per pixel, (images * size * size,) long, -1 where nothing is drawn.

    Scanline enumeration: each bounding-box row of a face gets the exact span of pixel centres inside
    it (the three edge planes are affine along the row), so only covered (face, pixel) pairs are made.
    """
    height = (bbox[:, 3] - bbox[:, 1] + 1).clamp_min(0) * (bbox[:, 2] >= bbox[:, 0])
    live = height.nonzero()[:, 0]
    height = height.index_select(0, live)
    owner = torch.repeat_interleave(height)  # (R,) live face of each bounding-box row
    row = torch.arange(len(owner), device=owner.device) - (height.cumsum(0) - height).index_select(0, owner)
    face_table = torch.cat([planes.index_select(0, live).flatten(1), bbox.index_select(0, live).to(planes.dtype)], 1)
    table = face_table.index_select(0, owner)  # (R, 13): a0 a1 a2 b0 b1 b2 c0 c1 c2 x0 y0 x1 y1
    y = table[:, 10] + row.to(planes.dtype) + 0.5
    a, rest = table[:, 0:3], torch.addcmul(table[:, 6:9], table[:, 3:6], y[:, None])  # e_i = a_i x + rest_i
    bound = -rest / a
    lo = torch.where(a > 0, bound, -torch.inf).amax(-1)
    hi = torch.where(a < 0, bound, torch.inf).amin(-1)
    # SPAN_TOL px of slack so a pixel centre on an edge shared by two faces is never missed by both.
    first = torch.maximum(torch.ceil(lo - 0.5 - SPAN_TOL), table[:, 9])
    last = torch.minimum(torch.floor(hi - 0.5 + SPAN_TOL), table[:, 11])
    blocked = ((a == 0) & (rest < 0)).any(-1)
    count = torch.where(blocked, 0, (last - first + 1).clamp_min(0)).long()
    # Per candidate: its row's first centre x, 1/depth = (sum a) x + (sum rest), and the row's pixel base.
    m = live.index_select(0, owner)
    base = (m // max(1, len(planes) // images)) * (size * size) + (y - 0.5).long() * size
    spans = count.nonzero()[:, 0]
    count = count.index_select(0, spans)
    cand = torch.repeat_interleave(count)  # (K,) row span of each candidate
    local = torch.arange(len(cand), device=cand.device) - (count.cumsum(0) - count).index_select(0, cand)
    x = first.index_select(0, spans).index_select(0, cand) + local.to(planes.dtype)
    depth = torch.stack([a.sum(-1), rest.sum(-1)], -1).index_select(0, spans).index_select(0, cand)
    inv_depth = torch.addcmul(depth[:, 1], depth[:, 0], x + 0.5)
    rows = spans.index_select(0, cand)
    pixel = base.index_select(0, rows) + x.long()
    # Positive float32 bit patterns sort like the floats, so the high word orders by 1/depth (nearest
    # wins) and the low word breaks ties deterministically.
    key = (inv_depth.float().clamp_min(0).view(torch.int32).long() << 32) | m.index_select(0, rows)
    best = torch.full((images * size * size,), -1, dtype=torch.long, device=planes.device)
    best.scatter_reduce_(0, pixel, key, "amax")
    return torch.where(best >= 0, best & 0xFFFFFFFF, -1)


def _pixel_centres(pixel: Tensor, size: int, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
    """Flat pixel indices (n * size + y) * size + x -> pixel-centre coordinates x + 0.5, y + 0.5."""
    within = pixel % (size * size)
    row = within.div(size, rounding_mode="floor")
    return (within - row * size).to(dtype) + 0.5, row.to(dtype) + 0.5


def _edge_values(planes: Tensor, x: Tensor, y: Tensor) -> Tensor:
    """(T, 3, 3) edge planes at points (T,) -> (T, 3) e_i = a_i x + b_i y + c_i."""
    return torch.addcmul(planes[:, 2], planes[:, 0], x[:, None]).addcmul_(planes[:, 1], y[:, None])


def _albedo(mesh: RenderMesh, face: Tensor, bary: Tensor) -> Tensor:
    """(P, 3) vertex colour, times the texture where there is one, at barycentrics (P, 3) of faces (P,)."""
    # One gather of a per-face table: corner colours (9), and with a texture corner UVs (6) and tile (4).
    parts = [mesh.colors.to(bary.dtype).index_select(0, mesh.faces.flatten()).view(-1, 9)]
    if mesh.textured:
        parts += [mesh.uv.to(bary.dtype).index_select(0, mesh.faces.flatten()).view(-1, 6), _tiles(mesh).to(bary.dtype)]
    table = torch.cat(parts, 1).index_select(0, face)
    colour = (table[:, :9].view(-1, 3, 3) * bary[..., None]).sum(1)
    if not mesh.textured:
        return colour
    uv = (table[:, 9:15].view(-1, 3, 2) * bary[..., None]).sum(1)
    uv = torch.where((uv < 0) | (uv > 1), uv - torch.floor(uv), uv)  # repeat; 1.0 stays at the far edge
    x0, y0, w, h = table[:, 15:].unbind(-1)
    # Texel coordinates inside the face's tile, kept half a texel from its border so that bilinear taps
    # never reach a neighbouring tile of the atlas.
    x = torch.minimum(torch.maximum(x0 + uv[:, 0] * w, x0 + 0.5), x0 + w - 0.5)
    y = torch.minimum(torch.maximum(y0 + (1 - uv[:, 1]) * h, y0 + 0.5), y0 + h - 0.5)
    height, width = mesh.texture.shape[1:]
    grid = torch.stack([x * (2 / width) - 1, y * (2 / height) - 1], -1)  # grid_sample: (-1, -1) = top-left
    texel = F.grid_sample(mesh.texture.to(bary.dtype)[None], grid[None, None], mode="bilinear",
                          padding_mode="border", align_corners=False)[0, :, 0].T
    return colour * texel


_HOPS = 8


def _walk_to_surface_end(planes: Tensor, facing: Tensor, neighbours: Tensor, face: Tensor, other: Tensor,
                         segment: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Follow pixel-pair segments across interior edges, from ``face`` (instances) until they end.

    segment (T, 4): start x, y (the inside centre) and the step dx, dy to the other centre; ``other`` is
    the instance shown there (-1: none). Returns, per segment, the last face reached and the edge it
    leaves by, ``ends`` (it leaves before the other centre by an edge that ends the visible surface or
    leads to ``other``) and ``covers`` (the surface reaches the other centre: ``other`` is in front there).
    Walks longer than ``_HOPS`` faces give neither.
    """
    faces_per_image = len(neighbours)
    image_start = face - face % faces_per_image
    face = face.clone()
    ends = torch.zeros_like(face, dtype=torch.bool)
    covers = torch.zeros_like(ends)
    edge = torch.zeros_like(face)
    todo = torch.arange(len(face), device=face.device)
    for hop in range(_HOPS + 1):
        f, seg = face.index_select(0, todo), segment.index_select(0, todo)
        rows = planes.index_select(0, f)
        e = _edge_values(rows, seg[:, 0], seg[:, 1])
        step = rows[:, 0] * seg[:, 2:3] + rows[:, 1] * seg[:, 3:4]
        leaving = step < 0
        t, k = torch.where(leaving, -e / torch.where(leaving, step, -1.0), 2.0).min(-1)
        code = neighbours.view(-1).index_select(0, (f % faces_per_image) * 3 + k)
        nb = torch.where(code >= 0, code, -2 - code) + image_start.index_select(0, todo)
        nb = torch.where(code == -1, -1, nb)
        # The surface folds away (a silhouette) where the neighbour's winding, corrected for faces wound
        # against each other, is seen the other way round from this face's.
        relative = facing.index_select(0, nb.clamp_min(0)) * torch.where(code < -1, -1, 1).to(facing.dtype)
        silhouette = (code == -1) | (relative != facing.index_select(0, f))
        reaches_other = nb == other.index_select(0, todo)
        edge[todo] = k
        ends[todo] = (t <= 1) & (silhouette | reaches_other)
        covers[todo] = t > 1
        go_on = (t <= 1) & ~silhouette & ~reaches_other
        if hop == _HOPS or not go_on.any():
            break
        todo = todo[go_on]
        face[todo] = nb[go_on]
    return face, edge, ends, covers
