"""Depth testing keeps the nearer of two surfaces a hair apart, from centimetres to 10 km.

A descent sees terrain from 10 km down to centimetres: the depth buffer must order surfaces
whose distances differ by a few parts per million at every range, in either drawing order.
The range image tells which surface won (each fragment's range is its own, computed from its
position, not from the depth buffer).
"""

from __future__ import annotations

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.mesh_scene import MeshScene
from render.renderer import Lighting, RenderOptions, View

#: Relative separation of the two surfaces: one part per million of their distance (float32
#: ranges still tell the two apart: its resolution is 0.12 parts per million).
GAP = 1e-6


def _square(z: float, half: float) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("distance", [0.02, 1.0, 150.0, 10_000.0])
@pytest.mark.parametrize("front_first", [True, False])
def test_the_nearer_surface_wins_in_either_order(renderer, distance, front_first):
    far = distance * (1.0 + GAP)
    near_v, near_f = _square(distance, distance)
    far_v, far_f = _square(far, distance)
    first, second = ((near_v, near_f), (far_v, far_f)) if front_first else \
        ((far_v, far_f), (near_v, near_f))
    vertices = np.vstack([first[0], second[0]])
    faces = np.vstack([first[1], second[1] + 4])
    scene = MeshScene(vertices, faces)
    pose = look_at((0.0, 0.0, 0.0), (0.0, 0.0, distance), up=(0.0, 1.0, 0.0))
    k = Intrinsics.from_fov(16, 16, 40.0)
    frame = renderer.render(scene, View(pose, k), Lighting((0.0, 0.0, -1.0)),
                            RenderOptions(shadows=False))
    # every pixel shows the near square: its range is distance / cos(angle off axis)
    u, v = np.meshgrid(np.arange(16.0), np.arange(16.0))
    expected = distance * np.sqrt(1.0 + ((u - k.cx) / k.fx) ** 2 + ((v - k.cy) / k.fy) ** 2)
    # nearer the near square's range than the far square's, at every pixel
    assert np.all(np.abs(frame.range - expected) < np.abs(frame.range - expected * (1 + GAP)))
