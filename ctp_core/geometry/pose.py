"""Pose theta = (t, q, log s) of the source, batched over restarts.

A pose maps the *source local frame* (source file frame, centred at its AABB centre and scaled by the
normalisation factor, see ``frames``) to the *normalised frame* (target AABB centred, longest side 2):
``x_norm = s * R(q) @ x_local + t``. q is stored unnormalised (w, x, y, z) and normalised in the forward
pass so Adam can move it freely; log s keeps the scale positive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch


def normalise_quaternion(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) -> unit quaternions, w first; the sign is kept (q and -q are the same rotation)."""
    return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) unit or not, w first -> (..., 3, 3) rotation matrices."""
    w, x, y, z = normalise_quaternion(q).unbind(-1)
    two = 2.0
    rows = [
        1 - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y),
        two * (x * y + w * z), 1 - two * (x * x + z * z), two * (y * z - w * x),
        two * (x * z - w * y), two * (y * z + w * x), 1 - two * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quaternion(m: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> unit quaternion (w, x, y, z) with w >= 0 (numpy, for reports)."""
    m = np.asarray(m, dtype=np.float64)
    trace = np.trace(m)
    if trace > 0:
        s = math.sqrt(trace + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k]) * 2
        q = [0.0] * 4
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def quaternion_product(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a*b of (..., 4) quaternions, w first (rotation b then a)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)


def upright_twist(q: torch.Tensor, q_up: torch.Tensor) -> torch.Tensor:
    """(B, 4) each rotation of ``q`` (B, 4) brought to the nearest that keeps a source standing: its own upright
    turn ``q_up`` (4,) followed by a turn about +Y only (the twist about +Y of ``q`` after ``q_up`` undone, the
    swing dropped). Unit, w first."""
    q = normalise_quaternion(q)
    inverse = q_up * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=q_up.dtype, device=q_up.device)
    rel = quaternion_product(q, inverse.expand_as(q))
    twist = torch.stack([rel[:, 0], torch.zeros_like(rel[:, 0]), rel[:, 2], torch.zeros_like(rel[:, 0])], dim=-1)
    norm = twist.norm(dim=-1, keepdim=True)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=q.dtype, device=q.device).expand_as(twist)
    twist = torch.where(norm > 1e-6, twist / norm.clamp_min(1e-12), identity)  # upside down: any turn, none
    return normalise_quaternion(quaternion_product(twist, q_up.expand_as(q)))


def random_quaternions(n: int, generator: torch.Generator) -> torch.Tensor:
    """Uniformly distributed rotations (Shoemake), (n, 4) w first."""
    u1, u2, u3 = torch.rand(3, n, generator=generator, dtype=torch.float64)
    a, b = torch.sqrt(1 - u1), torch.sqrt(u1)
    q = torch.stack([
        b * torch.cos(2 * math.pi * u3), a * torch.sin(2 * math.pi * u2),
        a * torch.cos(2 * math.pi * u2), b * torch.sin(2 * math.pi * u3),
    ], dim=-1)
    return q.float()


def apply_pose(points: torch.Tensor, t: torch.Tensor, q: torch.Tensor, log_s: torch.Tensor) -> torch.Tensor:
    """Source local frame -> normalised frame for a batch of poses.

    points (N, 3) shared by all poses; t (B, 3), q (B, 4), log_s (B,) -> (B, N, 3).
    """
    rot = quaternion_to_matrix(q)  # (B, 3, 3)
    scale = log_s.exp().reshape(-1, 1, 1)
    return scale * torch.einsum("bij,nj->bni", rot, points) + t[:, None, :]


def pose_matrix(t: torch.Tensor, q: torch.Tensor, log_s: torch.Tensor) -> torch.Tensor:
    """(B, 4, 4) similarity, source local frame -> normalised frame."""
    rot = quaternion_to_matrix(q) * log_s.exp().reshape(-1, 1, 1)
    out = torch.zeros(t.shape[0], 4, 4, dtype=t.dtype, device=t.device)
    out[:, :3, :3] = rot
    out[:, :3, 3] = t
    out[:, 3, 3] = 1.0
    return out


@dataclass
class Poses:
    """A batch of poses, source local -> normalised (see ``pose``)."""

    t: torch.Tensor  # (B, 3)
    q: torch.Tensor  # (B, 4)
    log_s: torch.Tensor  # (B,)

    def __len__(self) -> int:
        return self.t.shape[0]

    def detached(self) -> Poses:
        return Poses(self.t.detach().clone(), self.q.detach().clone(), self.log_s.detach().clone())

    def where(self, mask: torch.Tensor, other: Poses) -> Poses:
        """Per restart: self where mask, else other."""
        pick = lambda a, b: torch.where(mask.reshape(-1, *[1] * (a.dim() - 1)), a, b)  # noqa: E731
        return Poses(pick(self.t, other.t), pick(self.q, other.q), pick(self.log_s, other.log_s))

    def select(self, index: torch.Tensor | slice | list[int]) -> Poses:
        return Poses(self.t[index], self.q[index], self.log_s[index])

    @staticmethod
    def cat(parts: list[Poses]) -> Poses:
        return Poses(torch.cat([p.t for p in parts]), torch.cat([p.q for p in parts]),
                     torch.cat([p.log_s for p in parts]))

    def matrices(self) -> np.ndarray:
        return pose_matrix(self.t, self.q, self.log_s).detach().cpu().double().numpy()
