"""Radar and LIDAR through the renderer: looks at a scene, and their records in a run.

:mod:`render.radar` and :mod:`render.lidar` turn range and normal images into measurements;
this module renders those images from a scene (shadows off: range and normals do not depend
on them) and writes what a scenario's ``[radar]`` and ``[lidar]`` tables measure along a
trajectory (``radar.npz`` and ``lidar.npz``, described in ``docs/sensors.md``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from render.camera import Intrinsics, Pose
from render.lidar import Lidar, LidarImage, LidarScan, flash, scan
from render.motion import Motion, trajectory_velocities
from render.radar import RadarBeam, RadarReturn, measure
from render.renderer import Lighting, Renderer, RenderOptions, View
from render.scene import Scene
from render.trajectory import Sample
from terrain.core.outputs import atomic_path

__all__ = ["LookFrame", "record_lidar", "record_radar", "renderer_look"]

#: Smallest cosine of the (boresight) sun incidence at which a surface's albedo is read back.
MIN_COS_ALBEDO = 1e-3


@dataclass
class LookFrame:
    """Range (h, w) m, world normals (h, w, 3) and albedo relative to the scene's (h, w)."""

    range: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray | None = None


def renderer_look(renderer: Renderer, scene: Scene, lighting: Lighting, options: RenderOptions,
                  t: float, *, albedo: bool = False) -> Callable[[Pose, Intrinsics], LookFrame]:
    """Return ``look(pose, intrinsics)`` rendering the scene at time ``t``.

    With ``albedo``, the frame is lit by a Lambert sun along its own optical axis (albedo 1),
    so that its I/F divided by the cosine of that incidence is the scene's albedo map there
    (1 where the scene has none): what a laser sees of dark and bright ground.
    """
    opts = replace(options, shadows=False, antialias=1)

    def look(pose: Pose, k: Intrinsics) -> LookFrame:
        axis = pose.rotation[:, 2]
        light = (Lighting(tuple((-axis).tolist()), albedo=1.0, brdf="lambert")
                 if albedo else lighting)
        fr = renderer.render(scene, View(pose, k, t), light, opts)
        a = None
        if albedo:
            cos_s = np.clip(-(fr.normals.astype(np.float64) @ axis), MIN_COS_ALBEDO, 1.0)
            a = np.where(np.isfinite(fr.range), fr.radiance / cos_s, 0.0)
        return LookFrame(fr.range, fr.normals, a)

    return look


def record_radar(renderer: Renderer, scene: Scene, beams: Sequence[RadarBeam],
                 lighting: Lighting, options: RenderOptions, samples: Sequence[Sample],
                 path: Path, *, frames: Sequence[int] | None = None, **meta) -> dict:
    """Measure every beam at frames of a trajectory (all by default) into ``path`` (npz).

    The platform's velocity (and an asteroid's spin) at a frame come from the whole
    trajectory (:func:`render.motion.trajectory_velocities`).

    Returns
    -------
    dict
        Statistics for the manifest (seconds, file, measurements).
    """
    t0 = time.perf_counter()
    out: list[list[RadarReturn]] = []
    frames = range(len(samples)) if frames is None else frames
    for i in frames:
        s = samples[i]
        motion = trajectory_velocities(samples, i)
        scene.set_body_rotation(s.body_rotation)
        look = renderer_look(renderer, scene, lighting, options, s.time)
        out.append([measure(b, look, s.pose, motion.velocity,
                            body_angular_velocity=_spin(scene, motion)) for b in beams])
    write_radar(path, out, beams, [samples[i].time for i in frames], **meta)
    return dict(file=Path(path).name, beams=len(beams), measurements=len(frames) * len(beams),
                seconds=time.perf_counter() - t0)


def _spin(scene: Scene, motion: Motion) -> tuple:
    """Return the surface's angular velocity: an asteroid's spin, nothing for terrain."""
    return tuple(motion.body_angular_velocity) if getattr(scene, "kind", "") == "asteroid" \
        else (0.0, 0.0, 0.0)


def write_radar(path: Path, returns: list[list[RadarReturn]], beams: Sequence[RadarBeam],
                times: Sequence[float], **meta) -> Path:
    """Write radar returns (frames x beams) as ``.npz`` (atomically); see ``docs/sensors.md``."""
    def grid(name):
        return np.array([[getattr(r, name) for r in row] for row in returns], np.float64)

    arrays = dict(
        time=np.asarray(times, np.float64), range=grid("range"), velocity=grid("velocity"),
        boresight_velocity=grid("boresight_velocity"), power_outside=grid("power_outside"),
        direction=np.array([[r.direction for r in row] for row in returns], np.float64),
        beams=np.array(json.dumps(dict(beams=[b.as_dict() for b in beams], **meta))))
    for j, _ in enumerate(beams):
        arrays[f"histogram_{j}"] = np.array([row[j].histogram for row in returns], np.float32)
        arrays[f"range_edges_{j}"] = np.array([row[j].range_edges for row in returns])
        arrays[f"velocity_edges_{j}"] = returns[0][j].velocity_edges if returns else np.zeros(0)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    return path


def record_lidar(renderer: Renderer, scene: Scene, lidar: Lidar, lighting: Lighting,
                 options: RenderOptions, samples: Sequence[Sample], path: Path, *,
                 frames: Sequence[int] | None = None, seed: int = 0, **meta) -> dict:
    """Flash (or scan, from each frame's time) at frames (all by default) into ``path`` (npz).

    Returns
    -------
    dict
        Statistics for the manifest (seconds, file, dropout fraction, points).
    """
    t0 = time.perf_counter()
    flashes: list[LidarImage] = []
    scans: list[LidarScan] = []
    frames = range(len(samples)) if frames is None else frames
    for i in frames:
        s = samples[i]
        scene.set_body_rotation(s.body_rotation)
        look = renderer_look(renderer, scene, lighting, options, s.time, albedo=True)
        if lidar.mode == "flash":
            flashes.append(flash(lidar, look, s.pose, seed=seed, frame=i))
        else:
            scans.append(scan(lidar, look, s.pose, s.time, trajectory_velocities(samples, i),
                              seed=seed, frame=i))
    settings = np.array(json.dumps(dict(lidar.as_dict(), seed=seed, **meta)))
    if flashes:
        arrays = {name: np.stack([getattr(f, name) for f in flashes])
                  for name in ("range", "first", "last", "strongest", "returns", "power")}
        arrays["time"] = np.array([samples[i].time for i in frames])
        valid = np.isfinite(arrays["range"])
    else:
        arrays = {name: np.concatenate([getattr(c, name) for c in scans])
                  for name in ("time", "row", "col", "position", "direction", "range", "first",
                               "last", "strongest", "returns", "power")}
        arrays["frame"] = np.concatenate([np.full(len(c.time), i, np.int64)
                                          for i, c in zip(frames, scans, strict=True)])
        valid = np.isfinite(arrays["range"])
    arrays["lidar"] = settings
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]
    return dict(file=Path(path).name, mode=lidar.mode, measurements=int(valid.size),
                dropout_fraction=float(1.0 - valid.mean()) if valid.size else 0.0,
                slices=sum(c.slices for c in scans), seconds=time.perf_counter() - t0)
