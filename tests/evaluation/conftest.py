"""Fixtures of the evaluation tests: a rendered sequence of known motion, small DEMs, meshes.

The planar sequence is rendered here, independently of the GL renderer: a textured plane
z = 0 (the hillshade of a fractional Brownian DEM as its albedo) seen by a pinhole camera
moving along a known path. Every pixel is the mean of 3 x 3 rays, each intersected with the
plane analytically and looking the texture up bilinearly; the range image is the exact
distance along each pixel's central ray. So the truth written with the frames is exact, and
the tracking error it measures is the tracker's alone.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from render.camera import Intrinsics, Pose, look_at
from render.rundir import FrameTruth, RunWriter

#: Side of the textured plane (metres) and its texture's pixel (metres).
PLANE_SIZE = 128.0
TEXTURE_RESOLUTION = 0.25
#: Sub-pixel rays per pixel side.
SUPERSAMPLE = 3


def plane_texture(seed: int = 5) -> np.ndarray:
    """(512, 512) float32 albedo: the low-sun hillshade of a fractal DEM."""
    from evaluation.spectrum import fractional_brownian_surface
    from terrain.surface.hillshade import hillshade

    n = int(PLANE_SIZE / TEXTURE_RESOLUTION)
    dem = fractional_brownian_surface(n, 0.7, resolution=TEXTURE_RESOLUTION, rms=3.0,
                                      seed=seed)
    return hillshade(dem, azimuth=300.0, altitude=35.0).astype(np.float32)


#: Frames over which the camera path below covers its whole length.
PATH_STEPS = 11


def camera_path(n_frames: int) -> list[Pose]:
    """A descent of 11 steps of 0.6 m east, 0.4 m north and 0.8 m down, slowly turning.

    The path is the same whatever ``n_frames``; more frames sample it more finely.
    """
    poses = []
    for i in range(n_frames):
        k = i * PATH_STEPS / max(n_frames - 1, 1)
        p = np.array([40.0 + 0.6 * k, 50.0 + 0.4 * k, 50.0 - 0.8 * k])
        heading = math.radians(20.0 + 1.5 * k)
        target = p + np.array([6.0 * math.cos(heading), 6.0 * math.sin(heading), -p[2]])
        poses.append(look_at(p, target, up=(0.0, 1.0, 0.0)))
    return poses


def render_plane(texture: np.ndarray, pose: Pose, k: Intrinsics) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """Image (uint8) and range (float32 metres) of the textured plane z = 0."""
    import cv2

    rot = pose.rotation
    c = np.asarray(pose.position)
    v, u = np.mgrid[0:k.height, 0:k.width].astype(np.float64)
    acc = np.zeros((k.height, k.width))
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    top = PLANE_SIZE
    for du in offsets:
        for dv in offsets:
            d = np.stack([(u + du - k.cx) / k.fx, (v + dv - k.cy) / k.fy, np.ones_like(u)], -1)
            dw = d @ rot.T
            t = -c[2] / dw[..., 2]
            x = c[0] + t * dw[..., 0]
            y = c[1] + t * dw[..., 1]
            col = (x / TEXTURE_RESOLUTION - 0.5).astype(np.float32)
            row = ((top - y) / TEXTURE_RESOLUTION - 0.5).astype(np.float32)
            acc += cv2.remap(texture, col, row, cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REFLECT)
    image = np.clip(np.rint(acc / SUPERSAMPLE**2), 0, 255).astype(np.uint8)
    d = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)], -1) @ rot.T
    t = -c[2] / d[..., 2]
    rng = (t * np.linalg.norm(d, axis=-1)).astype(np.float32)
    rng[t <= 0] = np.nan
    return image, rng


def write_planar_run(run_dir, *, n_frames: int = 12, width: int = 320, height: int = 240,
                     truth_pose=None, seed: int = 5) -> Path:
    """Render the planar descent into a run directory (render.rundir format).

    ``truth_pose(k, pose) -> Pose`` may falsify the pose written as truth (the images are
    always rendered with the real one). Frames from ``n_frames // 2`` on are marked as
    drawing layers 0 and 1 instead of 0 alone (a resolution change in the truth, not in the
    image).
    """
    texture = plane_texture(seed)
    k = Intrinsics.from_fov(width, height, 50.0)
    writer = RunWriter(run_dir, dict(scene="textured plane z = 0 (evaluation tests)",
                                     frames=n_frames, resolution=[width, height],
                                     seed=seed))
    for i, pose in enumerate(camera_path(n_frames)):
        image, rng = render_plane(texture, pose, k)
        written = pose if truth_pose is None else truth_pose(i, pose)
        levels = [0] if i < n_frames // 2 else [0, 1]
        drawn = {"layers": [{"level": lv, "triangles": 1000 + i} for lv in levels],
                 "triangles": 1000 + i}  # the counts change every frame, the layers once
        truth = FrameTruth(i, 0.1 * i, written, k, (0.0, 0.0, 1.0), drawn=drawn)
        writer.write_frame(truth, image, rng, None)
    writer.finish()
    return Path(run_dir)


def copy_with_truth(run_dir, out, change) -> Path:
    """Copy a run directory, passing every frame's truth through ``change(FrameTruth)``."""
    import json

    shutil.copytree(run_dir, out)
    path = Path(out) / "truth.json"
    frames = [FrameTruth.from_dict(d) for d in json.loads(path.read_text(encoding="utf-8"))]
    path.write_text(json.dumps([change(t).as_dict() for t in frames], indent=1),
                    encoding="utf-8")
    return Path(out)


@pytest.fixture(scope="session")
def planar_run(tmp_path_factory) -> Path:
    """A 12-frame planar descent with exact truth (shared, read-only)."""
    return write_planar_run(tmp_path_factory.mktemp("runs") / "planar")


@pytest.fixture
def run_without_truth(planar_run, tmp_path) -> Path:
    """A copy of the planar run without truth.json."""
    out = tmp_path / "no_truth"
    shutil.copytree(planar_run, out)
    (out / "truth.json").unlink()
    return out
