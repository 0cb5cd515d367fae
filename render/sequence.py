"""Rendering a scenario: one frame, or a whole sequence into a run directory.

The run directory layout and the truth entries are those of :mod:`render.rundir`. Frames are
independent of each other (every random draw is keyed by frame index and pixel), so a run can
resume after an interruption by skipping the frames its truth file already lists, and the
same scenario and seed give the same bytes whatever order frames are rendered in.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from render.context import describe
from render.renderer import Renderer, View
from render.rundir import FrameTruth, RunWriter
from render.scenario import Scenario
from terrain.errors import InvalidParameterError

__all__ = ["load_scene", "render_sample", "run_sequence"]

log = logging.getLogger(__name__)


def load_scene(scenario: Scenario):
    """The scene a scenario names (a terrain layer stack or an asteroid body)."""
    spec = scenario.scene
    if spec["type"] == "terrain":
        from render.terrain_scene import TerrainScene

        stack = scenario.resolve(spec["stack"])
        return TerrainScene(stack, curvature=bool(spec.get("curvature", True)),
                            radius=spec.get("radius"))
    from render.asteroid_scene import AsteroidScene

    return AsteroidScene(scenario.resolve(spec["body"]), boulders=bool(spec.get("boulders", True)),
                         imposter_pixels=float(spec.get("imposter_pixels", 24.0)))


def render_sample(renderer: Renderer, scene, scenario: Scenario, sample, index: int):
    """Render one trajectory sample: (digital image, Frame, FrameTruth)."""
    view = View(sample.pose, scenario.intrinsics, sample.time)
    if hasattr(scene, "set_body_rotation"):
        scene.set_body_rotation(sample.body_rotation)
    frame = renderer.render(scene, view, scenario.lighting, scenario.options)
    image = scenario.sensor.expose(frame.radiance, frame=index)
    truth = FrameTruth(index, sample.time, sample.pose, scenario.intrinsics,
                       scenario.lighting.sun, tuple(sample.body_rotation), frame.drawn)
    return image, frame, truth


def run_sequence(scenario: Scenario, run_dir, *, resume: bool = False, progress=None) -> dict:
    """Render every frame of ``scenario`` into ``run_dir`` (see :mod:`render.rundir`)."""
    run_dir = Path(run_dir)
    renderer = Renderer()
    scene = load_scene(scenario)
    samples = scenario.samples(scene)
    if not samples:
        raise InvalidParameterError("the scenario's trajectory has no frames")
    manifest = dict(scenario=scenario.name, scene=scenario.scene["type"], frames=len(samples),
                    resolution=[scenario.intrinsics.width, scenario.intrinsics.height],
                    seed=scenario.seed, sensor=scenario.sensor.as_dict(),
                    lighting=dict(sun=list(scenario.lighting.sun),
                                  albedo=scenario.lighting.albedo,
                                  reflectance=scenario.lighting.brdf),
                    renderer=describe())
    writer = RunWriter(run_dir, manifest, scenario.path, resume=resume)
    done = writer.done()
    t0 = time.perf_counter()
    rendered = 0
    for i, sample in enumerate(samples):
        if i in done:
            continue
        image, frame, truth = render_sample(renderer, scene, scenario, sample, i)
        writer.write_frame(truth, image,
                           frame.range if scenario.outputs["range"] else None,
                           frame.normals if scenario.outputs["normals"] else None)
        rendered += 1
        if progress is not None:
            progress(i + 1, len(samples), rendered / max(time.perf_counter() - t0, 1e-9))
    elapsed = time.perf_counter() - t0
    writer.finish(render_seconds=elapsed, frames_rendered_this_run=rendered)
    log.info("rendered %d frames in %.1f s", rendered, elapsed)
    return writer.manifest
