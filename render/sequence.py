"""Rendering a scenario: one frame, or a whole sequence into a run directory.

The run directory layout and the truth entries are those of :mod:`render.rundir`. Frames are
independent of each other (every random draw is keyed by frame index and pixel), so a run can
resume after an interruption by skipping the frames its truth file already lists, and the
same scenario and seed give the same bytes whatever order frames are rendered in. The one
state carried from frame to frame is an auto-exposing sensor's exposure
(:class:`render.sensor.ExposureControl`): each frame records it in its truth, and a resumed
run takes it from the last frame written.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from render.context import describe
from render.motion import Motion, render_exposure, trajectory_velocities
from render.renderer import Frame, Renderer, View
from render.rundir import FrameTruth, RunWriter
from render.scenario import Scenario
from render.scene import Scene
from render.sensor import ExposureControl
from render.trajectory import Sample
from terrain.core.errors import InvalidParameterError
from terrain.core.progress import Progress

__all__ = ["check_frame_memory", "frame_motion", "load_scene", "render_sample", "run_sequence"]

log = logging.getLogger(__name__)

#: Peak bytes per image pixel of one frame: float colour, range and normal attachments and
#: depth on the GPU side, their float32 read-backs, the sensor's working copies and the image.
FRAME_BYTES_PER_PIXEL = 96
#: Bytes reserved per shadow-map texel: a 32-bit depth texel, and as much again allowed for
#: the driver's own copies.
SHADOW_BYTES_PER_TEXEL = 8
#: Peak bytes per sample of an antialiased frame (``RenderOptions.antialias``), on top: the
#: attachments, depth and read-backs at the sample resolution.
SAMPLE_BYTES_PER_PIXEL = 56


def check_frame_memory(scenario: Scenario) -> None:
    """Refuse a frame size whose buffers would not fit in memory, before any allocation.

    Parameters
    ----------
    scenario : render.scenario.Scenario
        Its image size and shadow-map size are checked.

    Raises
    ------
    terrain.core.errors.MemoryRequestError
        When the frame's buffers would not fit (:func:`terrain.core.memory.require`).
    """
    from terrain.core import memory
    k = scenario.intrinsics
    shadow = scenario.options.shadow_size if scenario.options.shadows else 0
    a = scenario.options.antialias
    samples = k.width * k.height * a * a * SAMPLE_BYTES_PER_PIXEL if a > 1 else 0
    memory.require(k.width * k.height * FRAME_BYTES_PER_PIXEL + samples
                   + shadow * shadow * SHADOW_BYTES_PER_TEXEL,
                   f"rendering {k.width}x{k.height} frames" + (f" ({a}x{a} samples a pixel)"
                                                               if a > 1 else ""))


def load_scene(scenario: Scenario) -> Scene:
    """Load the scene a scenario names.

    A scene the scenario can build (``[scene.build]``) is built first where it is missing
    (:func:`render.scene_build.ensure_scene`).

    Parameters
    ----------
    scenario : render.scenario.Scenario
        Its ``[scene]`` record (paths relative to the scenario file).

    Returns
    -------
    render.scene.Scene
        A :class:`render.terrain_scene.TerrainScene` (a layer stack) or a
        :class:`render.asteroid_scene.AsteroidScene` (a native body).
    """
    from render.scene_build import ensure_scene

    ensure_scene(scenario)
    spec = scenario.scene
    if spec.type == "binary":
        from render.binary_scene import BinaryScene

        assert spec.primary is not None and spec.secondary is not None  # SceneSpec requires
        return BinaryScene(scenario.resolve(spec.primary), scenario.resolve(spec.secondary),
                           orbit=spec.orbit, primary_spin=spec.primary_spin,
                           secondary_spin=spec.secondary_spin, boulders=spec.boulders)
    albedo = None if spec.albedo_map is None else scenario.resolve(spec.albedo_map)
    if spec.type == "terrain":
        from render.terrain_scene import TerrainScene

        assert spec.stack is not None  # required of a terrain scene by SceneSpec.from_mapping
        return TerrainScene(scenario.resolve(spec.stack), curvature=spec.curvature,
                            radius=spec.radius, albedo_map=albedo)
    from render.asteroid_scene import AsteroidScene

    assert spec.body is not None  # required of an asteroid scene by SceneSpec.from_mapping
    return AsteroidScene(scenario.resolve(spec.body), boulders=spec.boulders,
                         imposter_pixels=spec.imposter_pixels, albedo=albedo)


def frame_motion(scenario: Scenario, samples: Sequence[Sample] | None,
                 index: int) -> Motion | None:
    """Give the motion held during frame ``index``'s exposure.

    Parameters
    ----------
    scenario : render.scenario.Scenario
        Its ``[motion]`` table: whether to blur, and the velocities it gives.
    samples : sequence of render.trajectory.Sample, optional
        The whole trajectory (velocities by central differences).
    index : int
        The frame.

    Returns
    -------
    render.motion.Motion or None
        The scenario's ``[motion]`` velocities where given, the trajectory's otherwise;
        None when the scenario asks for no motion blur.
    """
    spec = scenario.motion or {}
    if not spec.get("blur"):
        return None
    given = spec["motion"]
    from_traj = trajectory_velocities(samples, index) if samples else Motion()
    fields = {k: getattr(given if k in spec.get("given", ()) else from_traj, k)
              for k in ("velocity", "angular_velocity", "body_angular_velocity")}
    return replace(given, **fields)


def render_sample(renderer: Renderer, scene: Scene, scenario: Scenario, sample: Sample,
                  index: int, samples: Sequence[Sample] | None = None, *,
                  motion: Motion | None = None,
                  exposure: ExposureControl | None = None) -> tuple[np.ndarray, Frame,
                                                                    FrameTruth]:
    """Render one trajectory sample through the scenario's sensor.

    The lighting is the scenario's at the sample's time (a dated sun moves:
    :meth:`render.scenario.Scenario.lighting_at`).

    Parameters
    ----------
    renderer : render.renderer.Renderer
        Renders the frame.
    scene : render.scene.Scene
        The scenario's scene.
    scenario : render.scenario.Scenario
        Camera, sensor, lighting and render options.
    sample : render.trajectory.Sample
        The frame's pose, time and body rotation.
    index : int
        The frame's index (keys the sensor's noise).
    samples : sequence of render.trajectory.Sample, optional
        The whole trajectory: the velocities of motion blur (:func:`frame_motion`).
    motion : render.motion.Motion, optional
        Overrides those velocities for this frame.
    exposure : render.sensor.ExposureControl, optional
        The auto-exposure loop of a sequence (updated by this frame); without one, an
        auto-exposed frame settles at once.

    Returns
    -------
    image : (h, w) uint8 or uint16
        The digital image.
    frame : render.renderer.Frame
        Radiance (the I/F the sensor integrated), range and normals at the frame time.
    truth : render.rundir.FrameTruth
        The frame's truth entry.
    """
    view = View(sample.pose, scenario.intrinsics, sample.time)
    if motion is None:
        motion = frame_motion(scenario, samples, index)
    sky = scenario.sky_at(sample.time, scene)
    lighting = scenario.lighting if sky is None else sky.lighting(scenario.lighting)
    if exposure is None:
        exposure = ExposureControl(scenario.sensor)
    sensor = scenario.sensor
    if sensor.auto_exposure and exposure.value is not None:  # what integrates (motion blur)
        sensor = sensor.with_exposure(exposure.value)
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
    image, record = exposure.expose(frame.radiance, index, intrinsics=scenario.intrinsics,
                                    spectral_irradiance=lighting.spectral_irradiance)
    from render.binary_scene import BinaryScene

    bodies = None
    if isinstance(scene, BinaryScene):  # several bodies: which pixel shows which, and where
        frame.body_ids = scene.body_ids(view, frame)
        bodies = scene.bodies_truth(sample.time)
    truth = FrameTruth(index, sample.time, sample.pose, scenario.intrinsics,
                       lighting.sun, tuple(sample.body_rotation), frame.drawn, motion=moving,
                       sky=None if sky is None else sky.as_dict(), exposure=record,
                       bodies=bodies)
    return image, frame, truth


def run_sequence(scenario: Scenario, run_dir: str | Path, *, resume: bool = False,
                 progress: Progress | None = None) -> dict:
    """Render every frame of ``scenario`` into ``run_dir`` (see :mod:`render.rundir`).

    Parameters
    ----------
    scenario : render.scenario.Scenario
        What to render.
    run_dir : str or pathlib.Path
        The run directory (made; refused when it holds another run unless resuming).
    resume : bool
        Skip the frames the run directory's truth file already lists.
    progress : terrain.core.progress.Progress, optional
        Called as ``progress(done, total, detail)`` after every frame.

    Returns
    -------
    dict
        The run's manifest (also written to ``manifest.json``).
    """
    run_dir = Path(run_dir)
    check_frame_memory(scenario)
    RunWriter.check(run_dir, resume=resume)
    renderer = Renderer()
    scene = load_scene(scenario)
    samples = scenario.samples(scene)
    if not samples:
        raise InvalidParameterError("the scenario's trajectory has no frames")
    first = scenario.lighting_at(samples[0].time, scene)  # a dated sun: the first frame's
    manifest = dict(scenario=scenario.name, scene=scenario.scene.type, frames=len(samples),
                    resolution=[scenario.intrinsics.width, scenario.intrinsics.height],
                    seed=scenario.seed, sensor=scenario.sensor.as_dict(),
                    lighting=dict(sun=list(first.sun),
                                  albedo=first.albedo,
                                  reflectance=first.brdf,
                                  **({"hapke": first.hapke.as_dict()}
                                     if first.brdf == "hapke" else {}),
                                  distance_au=first.distance,
                                  spectral_irradiance=first.spectral_irradiance,
                                  **({"utc": scenario.ephemeris.utc}
                                     if scenario.ephemeris is not None else {})),
                    renderer=describe())
    from render.binary_scene import BinaryScene

    if isinstance(scene, BinaryScene):
        manifest["binary"] = scene.describe()
    writer = RunWriter(run_dir, manifest, scenario.path, resume=resume)
    done = writer.done()
    t0 = time.perf_counter()
    rendered = 0
    control = ExposureControl(scenario.sensor)
    for i, sample in enumerate(samples):
        if i in done:
            continue
        before = writer.exposure_before(i)  # resuming: the loop goes on where it stopped
        if before is not None:
            control.value = before.get("exposure_time", before.get("exposure"))
        image, frame, truth = render_sample(renderer, scene, scenario, sample, i, samples,
                                            exposure=control)
        writer.write_frame(truth, image,
                           frame.range if scenario.outputs["range"] else None,
                           frame.normals if scenario.outputs["normals"] else None,
                           scenario.lighting_at(sample.time, scene).radiance(frame.radiance)
                           if scenario.outputs.get("radiance") else None,
                           body_ids=frame.body_ids if scenario.outputs.get("body_ids", True)
                           else None)
        rendered += 1
        if progress is not None:
            progress(i + 1, len(samples),
                     f"{rendered / max(time.perf_counter() - t0, 1e-9):.2f} frame/s")
    elapsed = time.perf_counter() - t0
    writer.finish(render_seconds=elapsed, frames_rendered_this_run=rendered)
    log.info("rendered %d frames in %.1f s", rendered, elapsed)
    return writer.manifest
