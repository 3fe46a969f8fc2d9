"""Blender's frame (+Z up) and glTF's (+Y up) in one place: where the service's answer becomes a ``matrix_world``.

Each object is exported at a frame (object -> Blender's world axes; ``scene.export_pair``: the target at its
``matrix_world``, the source at its own scale) and turned by ``Y_UP``, as the glTF exporter does. So the target's
file frame is Blender's world turned by ``Y_UP``, and the report's transform (``"from_frame": "source_file"``,
``"to_frame": "target_file"``) maps the source's export frame, turned, into it."""

from __future__ import annotations

from collections.abc import Sequence

from mathutils import Matrix

# Blender world -> glTF: (x, y, z) -> (x, z, -y), as the glTF exporter writes positions with +Y up
Y_UP = Matrix(((1.0, 0.0, 0.0, 0.0),
               (0.0, 0.0, 1.0, 0.0),
               (0.0, -1.0, 0.0, 0.0),
               (0.0, 0.0, 0.0, 1.0)))


def placed_world(transform: Sequence[Sequence[float]], exported: Matrix) -> Matrix:
    """The source's new ``matrix_world``: the report's 4x4 (row-major, glTF frames) after the frame the source was
    exported at, back in Blender's axes. Its own scale is in that frame and stays; ``matrix_world``'s setter works
    out the local matrix under whatever parent the object has."""
    return Y_UP.inverted() @ Matrix(transform) @ Y_UP @ exported
