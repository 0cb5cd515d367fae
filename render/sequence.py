"""Rendering a scenario: one frame, or a whole sequence into a run directory.

The run directory layout and the truth entries are those of :mod:`render.rundir`. Frames are
independent of each other (every random draw is keyed by frame index and pixel), so a run can
resume after an interruption by skipping the frames its truth file already lists, and the
same scenario and seed give the same bytes whatever order frames are rendered in.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

from render.context import describe
from render.motion import Motion, render_exposure, trajectory_velocities
from render.renderer import Renderer, View
from render.rundir import FrameTruth, RunWriter
from render.scenario import Scenario
from render.scene import Scene
from terrain.errors import InvalidParameterError
from terrain.progress import Progress

__all__ = ["check_frame_memory", "frame_motion", "load_scene", "render_sample", "run_sequence"]

log = logging.getLogger(__name__)

#: Peak bytes per image pixel of one frame: float colour, range and normal attachments and
#: depth on the GPU side, their float32 read-backs, the sensor's working copies and the image.
FRAME_BYTES_PER_PIXEL = 96


def check_frame_memory(scenario: Scenario) -> None:
    """Refuse a frame size whose buffers would not fit in memory, before any allocation."""
    from terrain import memory

    k = scenario.intrinsics
    shadow = scenario.options.shadow_size if scenario.options.shadows else 0
    memory.require(k.width * k.height * FRAME_BYTES_PER_PIXEL + shadow * shadow * 8,
                   f"rendering {k.width}x{k.height} frames")


def load_scene(scenario: Scenario) -> Scene:
    """The scene a scenario names (a terrain layer stack or an asteroid body)."""
    spec = scenario.scene
    albedo = None if spec.albedo_map is None else scenario.resolve(spec.albedo_map)
    if spec.type == "terrain":
        from render.terrain_scene import TerrainScene

        return TerrainScene(scenario.resolve(spec.stack), curvature=spec.curvature,
                            radius=spec.radius, albedo_map=albedo)
    from render.asteroid_scene import AsteroidScene

    return AsteroidScene(scenario.resolve(spec.body), boulders=spec.boulders,
                         imposter_pixels=spec.imposter_pixels, albedo=albedo)


def frame_motion(scenario: Scenario, samples, index: int):
    """The :class:`render.motion.Motion` of frame ``index``: the scenario's ``[motion]``
    velocities where given, the trajectory's (central differences) otherwise; None when the
    scenario asks for no motion blur and has no rolling shutter."""
    spec = scenario.motion or {}
    if not spec.get("blur"):
        return None
    given = spec["motion"]
    from_traj = trajectory_velocities(samples, index) if samples else Motion()
    fields = {k: getattr(given if k in spec.get("given", ()) else from_traj, k)
              for k in ("velocity", "angular_velocity", "body_angular_velocity")}
    return replace(given, **fields)


def render_sample(renderer: Renderer, scene: Scene, scenario: Scenario, sample, index: int,
                  samples=None, *, motion=None):
    """Render one trajectory sample: (digital image, Frame, FrameTruth).

    ``samples`` (the whole trajectory) supplies the velocities of motion blur (see
    :func:`frame_motion`); ``motion`` (a :class:`render.motion.Motion`) overrides them for
    this frame. The frame's radiance is the I/F the sensor integrated; range and normals
    are those at the frame time.
    """
    view = View(sample.pose, scenario.intrinsics, sample.time)
    if motion is None:
        motion = frame_motion(scenario, samples, index)
    sensor, lighting = scenario.sensor, scenario.lighting
    moving = None
    if motion is None and not sensor.rolling:
        scene.set_body_rotation(sample.body_rotation)
        frame = renderer.render(scene, view, lighting, scenario.options)
    else:
        motion = motion or Motion()
        rad, frame, info = render_exposure(renderer, scene, view, lighting, scenario.options,
                                           sensor, motion, sample.body_rotation)
        frame.radiance = rad
        moving = dict(motion.as_dict(), exposure_time=sensor.integration_time,
                      line_time=sensor.line_time, samples=info["samples"])
    image = sensor.expose(frame.radiance, frame=index, intrinsics=scenario.intrinsics,
                          spectral_irradiance=lighting.spectral_irradiance)
    truth = FrameTruth(index, sample.time, sample.pose, scenario.intrinsics,
                       lighting.sun, tuple(sample.body_rotation), frame.drawn, motion=moving)
    return image, frame, truth


def run_sequence(scenario: Scenario, run_dir, *, resume: bool = False,
                 progress: Progress | None = None) -> dict:
    """Render every frame of ``scenario`` into ``run_dir`` (see :mod:`render.rundir`)."""
    run_dir = Path(run_dir)
    check_frame_memory(scenario)
    RunWriter.check(run_dir, resume=resume)
    renderer = Renderer()
    scene = load_scene(scenario)
    samples = scenario.samples(scene)
    if not samples:
        raise InvalidParameterError("the scenario's trajectory has no frames")
    manifest = dict(scenario=scenario.name, scene=scenario.scene.type, frames=len(samples),
                    resolution=[scenario.intrinsics.width, scenario.intrinsics.height],
                    seed=scenario.seed, sensor=scenario.sensor.as_dict(),
                    lighting=dict(sun=list(scenario.lighting.sun),
                                  albedo=scenario.lighting.albedo,
                                  reflectance=scenario.lighting.brdf,
                                  **({"hapke": scenario.lighting.hapke.as_dict()}
                                     if scenario.lighting.brdf == "hapke" else {}),
                                  distance_au=scenario.lighting.distance,
                                  spectral_irradiance=scenario.lighting.spectral_irradiance),
                    renderer=describe())
    writer = RunWriter(run_dir, manifest, scenario.path, resume=resume)
    done = writer.done()
    t0 = time.perf_counter()
    rendered = 0
    for i, sample in enumerate(samples):
        if i in done:
            continue
        image, frame, truth = render_sample(renderer, scene, scenario, sample, i, samples)
        writer.write_frame(truth, image,
                           frame.range if scenario.outputs["range"] else None,
                           frame.normals if scenario.outputs["normals"] else None,
                           scenario.lighting.radiance(frame.radiance)
                           if scenario.outputs.get("radiance") else None)
        rendered += 1
        if progress is not None:
            progress(i + 1, len(samples),
                     f"{rendered / max(time.perf_counter() - t0, 1e-9):.2f} frame/s")
    elapsed = time.perf_counter() - t0
    writer.finish(render_seconds=elapsed, frames_rendered_this_run=rendered)
    log.info("rendered %d frames in %.1f s", rendered, elapsed)
    return writer.manifest
