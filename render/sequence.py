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
from concurrent.futures import Future, ThreadPoolExecutor
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
from terrain.io import write_png

__all__ = ["check_frame_memory", "expose_sample", "frame_motion", "load_scene",
           "render_sample", "run_sequence", "shoot_sample"]

log = logging.getLogger(__name__)

#: Peak bytes per image pixel of one frame: float colour, range and normal attachments, the
#: surface pass's position (16) and a body's per-vertex values (8), depth and stencil (8) on
#: the GPU side, their float32 read-backs, the sensor's working copies and the image.
FRAME_BYTES_PER_PIXEL = 124
#: Bytes reserved per shadow-map texel: a 32-bit depth texel, and as much again allowed for
#: the driver's own copies.
SHADOW_BYTES_PER_TEXEL = 8
#: Peak bytes per sample of an antialiased frame (``RenderOptions.antialias``), on top: the
#: attachments, depth, stencil and read-backs at the sample resolution.
SAMPLE_BYTES_PER_PIXEL = 84
#: Bytes per image pixel of the frame a sequence writes while it renders the next one
#: (:func:`run_sequence`): its image, range, normals, radiance and body ids.
WRITE_BEHIND_BYTES_PER_PIXEL = 24


def check_frame_memory(scenario: Scenario, *, write_behind: bool = False) -> None:
    """Refuse a frame size whose buffers would not fit in memory, before any allocation.

    Parameters
    ----------
    scenario : render.scenario.Scenario
        Its image size and shadow-map size are checked.
    write_behind : bool
        Also the outputs of the previous frame, written meanwhile (:func:`run_sequence`).

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
    behind = k.width * k.height * WRITE_BEHIND_BYTES_PER_PIXEL if write_behind else 0
    memory.require(k.width * k.height * FRAME_BYTES_PER_PIXEL + samples + behind
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
        :class:`render.asteroid_scene.AsteroidScene` (a native body) or a
        :class:`render.mesh_scene.MeshBodyScene` (a body kept as its own mesh).
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
    from render.mesh_scene import MeshBodyScene, is_mesh_body

    assert spec.body is not None  # required of an asteroid scene by SceneSpec.from_mapping
    if is_mesh_body(scenario.resolve(spec.body)):  # a body kept as its own mesh
        return MeshBodyScene(scenario.resolve(spec.body), boulders=spec.boulders, albedo=albedo)
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
    if exposure is None:
        exposure = ExposureControl(scenario.sensor)
    frame, truth, irradiance = shoot_sample(renderer, scene, scenario, sample, index, samples,
                                            motion=motion, exposure=exposure)
    image, truth = expose_sample(exposure, frame, truth, irradiance)
    return image, frame, truth


def shoot_sample(renderer: Renderer, scene: Scene, scenario: Scenario, sample: Sample,
                 index: int, samples: Sequence[Sample] | None = None, *,
                 motion: Motion | None = None,
                 exposure: ExposureControl | None = None) -> tuple[Frame, FrameTruth, float]:
    """Render one trajectory sample, before the sensor exposes it (:func:`render_sample`).

    Parameters are those of :func:`render_sample`; ``exposure`` is only read here (the
    exposure a blurred frame integrates). Without motion blur or a rolling shutter the frame
    does not depend on it, so a sequence exposes a frame while it renders the next.

    Returns
    -------
    frame : render.renderer.Frame
        Radiance (the I/F the sensor integrates), range and normals at the frame time.
    truth : render.rundir.FrameTruth
        The frame's truth entry, without exposure (:func:`expose_sample` adds it).
    spectral_irradiance : float
        The sun's at the frame time (W m^-2 nm^-1), for :func:`expose_sample`.
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
    if scenario.lamp is not None:
        from render.lamp import lamp_if

        frame.radiance = np.asarray(frame.radiance, dtype=np.float32) + lamp_if(
            scenario.lamp, frame.range, frame.normals, sample.pose, scenario.intrinsics,
            lighting)
    if scenario.stars is not None:
        from render.stars import add_stars, world_to_icrf

        rotation, et = world_to_icrf(scenario, sample.time, scene)
        radiance = np.array(frame.radiance, dtype=np.float32, copy=True)
        stars = add_stars(radiance, ~np.isfinite(frame.range), scenario.stars, rotation, et,
                          sample.pose, scenario.intrinsics, lighting.spectral_irradiance)
        frame.radiance = radiance
        frame.drawn = dict(frame.drawn, stars=dict(stars, world_to_icrf=rotation.tolist(),
                                                   et=et))
    from render.binary_scene import BinaryScene

    bodies = None
    if isinstance(scene, BinaryScene):  # several bodies: which pixel shows which, and where
        frame.body_ids = scene.body_ids(view, frame)
        bodies = scene.bodies_truth(sample.time)
    truth = FrameTruth(index, sample.time, sample.pose, scenario.intrinsics,
                       lighting.sun, tuple(sample.body_rotation), frame.drawn, motion=moving,
                       sky=None if sky is None else sky.as_dict(), bodies=bodies)
    return frame, truth, lighting.spectral_irradiance


def expose_sample(exposure: ExposureControl, frame: Frame, truth: FrameTruth,
                  spectral_irradiance: float) -> tuple[np.ndarray, FrameTruth]:
    """Expose a frame :func:`shoot_sample` rendered: its image, and its truth with exposure.

    Parameters
    ----------
    exposure : render.sensor.ExposureControl
        The sensor's auto-exposure loop (updated by this frame: frames are exposed in order).
    frame : render.renderer.Frame
        The frame (its radiance is the I/F the sensor integrates).
    truth : render.rundir.FrameTruth
        Its truth entry, without exposure.
    spectral_irradiance : float
        The sun's at the frame time (W m^-2 nm^-1).

    Returns
    -------
    image : (h, w) uint8 or uint16
        The digital image.
    truth : render.rundir.FrameTruth
        The frame's truth entry, with its exposure.
    """
    image, record = exposure.expose(frame.radiance, truth.index, intrinsics=truth.intrinsics,
                                    spectral_irradiance=spectral_irradiance)
    return image, replace(truth, exposure=record)


def _label_frame(writer: RunWriter, labeller, scenario: Scenario, frame: Frame,
                 truth: FrameTruth, pending: tuple | None) -> tuple | None:
    """Write a frame's labels, and the previous frame's flow to it (see :mod:`render.labels`).

    Returns what the next frame needs to give this one its flow (None without flow).
    """
    from render.dataset import write_flow, write_frame_labels

    labels = labeller.label(frame, truth.pose, truth.intrinsics, scenario.lighting)
    writer.add_labels(truth.index, write_frame_labels(writer.dir, truth.index, labels))
    if pending is not None and pending[0] == truth.index - 1:
        index, prev, range_m, pose, rotation = pending
        labeller.add_flow(prev, range_m, pose, rotation, frame.range, truth.pose,
                          truth.body_rotation, truth.intrinsics)
        writer.add_labels(index, write_flow(writer.dir, index, prev))
    assert scenario.labels is not None  # the caller labels only where it asks for labels
    if not scenario.labels.flow:
        return None
    return (truth.index, labels, frame.range, truth.pose, truth.body_rotation)


def run_sequence(scenario: Scenario, run_dir: str | Path, *, resume: bool = False,
                 progress: Progress | None = None, renderer: Renderer | None = None,
                 scene: Scene | None = None) -> dict:
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
    renderer : render.renderer.Renderer, optional
        Renders the frames (default: a new one).
    scene : render.scene.Scene, optional
        The scenario's scene, already loaded (default: :func:`load_scene`); a campaign's
        worker loads it once for all its cases.

    Returns
    -------
    dict
        The run's manifest (also written to ``manifest.json``).
    """
    run_dir = Path(run_dir)
    check_frame_memory(scenario, write_behind=True)
    RunWriter.check(run_dir, resume=resume)
    renderer = Renderer() if renderer is None else renderer
    scene = load_scene(scenario) if scene is None else scene
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
    if scenario.labels is not None:
        manifest["labels"] = scenario.labels.as_dict()
    from render.binary_scene import BinaryScene
    if isinstance(scene, BinaryScene):
        manifest["binary"] = scene.describe()
    writer = RunWriter(run_dir, manifest, scenario.path, resume=resume)
    done = writer.done()
    labeller = None
    if scenario.labels is not None:
        from render.labels import Labeller

        labeller = Labeller(scene, scenario.labels)
    pending = None  # the previous frame, waiting for this one to give its flow
    t0 = time.perf_counter()
    rendered = 0
    control = ExposureControl(scenario.sensor)
    # A frame's files are encoded and written on a thread while the next frame renders
    # (compression, PNG encoding and fsync release the GIL); one frame at a time, in frame
    # order, so the truth file still lists exactly the frames whose files are complete.
    # Where the next frame does not depend on this one's exposure (no motion blur, no rolling
    # shutter: shoot_sample), the sensor exposes it there too; frames are exposed in order.
    # Labels read and extend the truth entries: a labelled frame waits for its write.
    # Leaving the pool waits for the frame in flight, also when an error ends the loop.
    behind_exposure = (frame_motion(scenario, samples, 0) is None
                       and not scenario.sensor.rolling and labeller is None)

    def develop(frame: Frame, truth: FrameTruth, irradiance: float, radiance,
                image: np.ndarray | None = None) -> None:
        if image is None:
            image, truth = expose_sample(control, frame, truth, irradiance)
        writer.write_frame(truth, image,
                           frame.range if scenario.outputs["range"] else None,
                           frame.normals if scenario.outputs["normals"] else None, radiance,
                           body_ids=frame.body_ids if scenario.outputs.get("body_ids", True)
                           else None)

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="run-writer") as behind:
        writing: Future | None = None
        for i, sample in enumerate(samples):
            if i in done:
                pending = None
                continue
            before = writer.exposure_before(i)  # resuming: the loop goes on where it stopped
            if before is not None:
                if writing is not None:
                    writing.result()  # an earlier frame's exposure must not come after it
                control.value = before.get("exposure_time", before.get("exposure"))
            frame, truth, irradiance = shoot_sample(renderer, scene, scenario, sample, i,
                                                    samples, exposure=control)
            radiance = (scenario.lighting_at(sample.time, scene).radiance(frame.radiance)
                        if scenario.outputs.get("radiance") else None)
            if writing is not None:
                writing.result()  # raises what the previous frame's raised
            image = None
            if not behind_exposure:
                image, truth = expose_sample(control, frame, truth, irradiance)
            writing = behind.submit(develop, frame, truth, irradiance, radiance, image)
            if labeller is not None:
                writing.result()
                pending = _label_frame(writer, labeller, scenario, frame, truth, pending)
            rendered += 1
            if progress is not None:
                progress(i + 1, len(samples),
                         f"{rendered / max(time.perf_counter() - t0, 1e-9):.2f} frame/s")
        if writing is not None:
            writing.result()
    elapsed = time.perf_counter() - t0
    facts: dict = {}
    if scenario.events is not None:
        facts["events"] = record_events(renderer, scene, scenario, samples, run_dir)
    if labeller is not None:
        from render.dataset import write_exports

        write_exports(run_dir)
    if scenario.radar or scenario.lidar is not None:
        from render.instruments import record_lidar, record_radar

        if scenario.radar:
            facts["radar"] = record_radar(renderer, scene, scenario.radar, scenario.lighting,
                                          scenario.options, samples, run_dir / "radar.npz",
                                          scenario=scenario.name, seed=scenario.seed)
        if scenario.lidar is not None:
            facts["lidar"] = record_lidar(renderer, scene, scenario.lidar, scenario.lighting,
                                          scenario.options, samples, run_dir / "lidar.npz",
                                          seed=scenario.seed, scenario=scenario.name)
    writer.finish(render_seconds=elapsed, frames_rendered_this_run=rendered, **facts)
    log.info("rendered %d frames in %.1f s", rendered, elapsed)
    return writer.manifest


def record_events(renderer: Renderer, scene: Scene, scenario: Scenario,
                  samples: Sequence[Sample], run_dir: Path) -> dict:
    """Run the scenario's event camera over the whole trajectory into ``run_dir``.

    Between two frames the camera moves with the trajectory's velocities at the earlier one
    (:func:`render.motion.trajectory_velocities`, as motion blur does), so the event camera
    sees the scene at any instant the adaptive stepping asks for. Writes ``events.npz`` (see
    :mod:`render.events`) and ``events_preview.png`` (the events of the whole run).

    Returns
    -------
    dict
        The event statistics recorded in the manifest.
    """
    from render.events import event_frame, simulate, write_events

    camera = scenario.events
    if camera is None:
        raise InvalidParameterError("the scenario has no [events] table")
    times = [s.time for s in samples]
    if len(samples) < 2:
        raise InvalidParameterError("an event camera needs a trajectory of at least two frames")

    def render_at(t: float) -> np.ndarray:
        i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(samples) - 2))
        motion = trajectory_velocities(samples, i)
        dt = t - times[i]
        scene.set_body_rotation(motion.body_rotation_at(samples[i].body_rotation, dt))
        view = View(motion.pose_at(samples[i].pose, dt), scenario.intrinsics, t)
        return renderer.render(scene, view, scenario.lighting_at(t, scene),
                               scenario.options).radiance

    t0 = time.perf_counter()
    events, stats = simulate(render_at, times[0], times[-1], camera, seed=scenario.seed)
    shape = (scenario.intrinsics.height, scenario.intrinsics.width)
    write_events(run_dir / "events.npz", events, shape, camera,
                 scenario=scenario.name, seed=scenario.seed)
    write_png(event_frame(events, shape)[..., ::-1].copy(), run_dir / "events_preview.png")
    stats.update(file="events.npz", preview="events_preview.png",
                 seconds=time.perf_counter() - t0)
    return stats
