"""The upright judge: which way up a mesh looks like its name to the guide (``canonical.Judge``).

Used when the file's up is not trusted and the guide is asked (``AlignConfig.upright_judge``): each candidate
rotation (file frame -> upright) is rendered from framing views and scored against "a photo of a NAME".
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from ctp_core import render
from ctp_core.guide.guidance import Guide
from ctp_core.orientation import canonical
from ctp_core.render.cameras import framing_cameras
from ctp_core.render.structures import MeshArrays


def upright_judge(mesh: trimesh.Trimesh, guide: Guide, name: str, *, views: int = 4, image_size: int = 224,
                  device: str = "cpu") -> canonical.Judge:
    """A ``canonical.Judge`` that asks ``guide`` which way up ``mesh`` (file frame) looks like a NAME.

    Each candidate rotation (file -> upright) is rendered from ``views`` framing views at 30° elevation,
    all candidates in one batch; its score is the mean cosine of its views with "a photo of a NAME"
    (forward only).
    """
    arrays = MeshArrays.from_trimesh(mesh)
    shape = render.RenderMesh.from_arrays(arrays, device=device)
    centred = torch.as_tensor(arrays.vertices - mesh.bounds.mean(0), dtype=torch.float32, device=device)
    text = guide.encode_text([f"a photo of a {name}"])[0]

    @torch.no_grad()
    def judge(rotations: np.ndarray) -> np.ndarray:
        turned = centred @ torch.as_tensor(np.asarray(rotations), dtype=torch.float32, device=device).transpose(1, 2)
        images = render.render(shape, turned, framing_cameras(turned, views, image_size))
        scores = guide.score(images.flatten(0, 1), text).view(len(rotations), views).mean(1)
        return scores.double().cpu().numpy()

    return judge
