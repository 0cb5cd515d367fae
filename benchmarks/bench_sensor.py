"""Camera benchmark: the detector chain and motion blur per 1024 x 1024 frame, one JSON document.

A synthetic lunar terrain (RMD relief with a crater population, 513^2 at 2 m) is rendered with
Hapke photometry at 1024 x 1024 from 600 m up, looking 30 degrees off nadir. Each figure is a
median over repeated frames, against the baseline measured in the same run: the plain render
(the draw and the read-back of the I/F, range and normal images), what every frame pays. The
six calls are timed in rounds, interleaved (each round in the reverse order of the last), so
that a change in machine load hits all alike.

* ``plain_render``: the baseline; ``plain_render_lunar_lambert``: the same frame with
  lunar-Lambert instead of Hapke (what the Hapke shader costs).
* ``simple_sensor``: today's I/F-calibrated sensor (exposure factor, Gaussian PSF, shot and
  read noise) on the rendered I/F, alone.
* ``detector_chain``: the full data-sheet chain on the rendered I/F, alone: a two-Gaussian
  PSF, photons to electrons, natural vignetting, frame-transfer smear, PRNU, dark current,
  Poisson shot noise, full-well clipping, read noise, gain, bias, 12-bit quantisation.
* ``motion_blur``: a whole blurred exposure (the sub-frames the camera's motion needs, at
  most 0.5 px apart, averaged) with the camera moving at 30 m/s and turning at 2 deg/s for
  20 ms; ``rolling_shutter``: the same with a 20 us line time (1024 rows read in 20 ms).

Ratios are each figure over the plain render. There is no target in the issue; the JSON says
what a frame costs with each effect on.

Usage::

    .venv/bin/python benchmarks/bench_sensor.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import replace
from pathlib import Path

from _common import alternate, logger, machine_facts, peak_rss_bytes

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-sensor")
SEED = 16


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="256 x 256 frames, fewer repeats")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import numpy as np

    from render.camera import Intrinsics, look_at
    from render.motion import Motion, render_exposure
    from render.renderer import Lighting, Renderer, RenderOptions, View
    from render.sensor import Sensor
    from render.terrain_scene import TerrainScene
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack

    size = 256 if args.quick else 1024
    repeat = 3 if args.quick else 5
    base = synthesize_tile(513, resolution=2.0, relief=40.0, seed=SEED).tile
    site = (513.0, 513.0)
    stack = build_stack(base, site, levels=1, layer_size=513, seed=SEED,
                        population=Population(dmin=2.0, dmax=300.0, density=1e5))
    scene = TerrainScene(stack, curvature=False)
    renderer = Renderer()
    k = Intrinsics.from_fov(size, size, 45.0)
    pose = look_at((513.0 - 350.0, 513.0, 600.0), (513.0, 513.0, 0.0))
    view = View(pose, k)
    light = Lighting.from_angles(120.0, 20.0, brdf="hapke")
    options = RenderOptions(shadows=True, shadow_size=2048, lod_pixels=1.5)
    # warm-up: uploads, shadow maps; its I/F is what the sensors expose
    rad = renderer.render(scene, view, light, options).radiance
    ll = Lighting.from_angles(120.0, 20.0, brdf="lunar-lambert")
    renderer.render(scene, view, ll, options)
    simple = Sensor(bits=8, exposure=5.0, psf_sigma=0.5, gain=20.0, read_noise=1.0, seed=SEED)
    chain = Sensor.from_mapping(dict(
        bits=12, exposure_time=0.02, aperture=0.01, transmission=0.85, qe=0.6, wavelength=643.0,
        bandwidth=40.0, dark_current=200.0, prnu=0.01, read_noise=15.0, full_well=30000.0,
        gain=8.0, bias=50.0, psf=[[0.8, 0.7], [0.2, 3.0]], natural_vignetting=True,
        transfer_time=0.001), seed=SEED)
    motion = Motion(velocity=(30.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, math.radians(2.0)))
    rolling = replace(chain, line_time=20e-3 / size)
    rss0 = peak_rss_bytes()
    log(f"{size}^2: plain render, lunar-Lambert, two sensors, motion blur, rolling shutter, "
        f"interleaved, {repeat} rounds")
    timed = alternate(dict(
        plain_render=lambda: renderer.render(scene, view, light, options),
        plain_render_lunar_lambert=lambda: renderer.render(scene, view, ll, options),
        simple_sensor=lambda: simple.expose(rad, 0),
        detector_chain=lambda: chain.expose(rad, 1, intrinsics=k,
                                            spectral_irradiance=light.spectral_irradiance),
        motion_blur=lambda: render_exposure(renderer, scene, view, light, options, chain,
                                            motion),
        rolling_shutter=lambda: render_exposure(renderer, scene, view, light, options,
                                                rolling, motion),
    ), repeat)
    plain, lunar_lambert = timed.timings["plain_render"], \
        timed.timings["plain_render_lunar_lambert"]
    simple_t, chain_t = timed.timings["simple_sensor"], timed.timings["detector_chain"]
    blur_t, roll_t = timed.timings["motion_blur"], timed.timings["rolling_shutter"]
    frame, image = timed.results["plain_render"], timed.results["detector_chain"]
    blur_info, roll_info = timed.results["motion_blur"][2], timed.results["rolling_shutter"][2]
    base_s = plain["median_s"]
    out = dict(
        benchmark="sensor", frame=[size, size], repeat=repeat,
        plain_render=plain,
        plain_render_lunar_lambert=dict(lunar_lambert, ratio_to_plain_render=(
            lunar_lambert["median_s"] / plain["median_s"])),
        simple_sensor=dict(simple_t, ratio_to_plain_render=simple_t["median_s"] / base_s),
        detector_chain=dict(chain_t, ratio_to_plain_render=chain_t["median_s"] / base_s,
                            saturated_fraction=float(np.mean(image >= 4095)),
                            median_dn=float(np.median(image))),
        motion_blur=dict(blur_t, ratio_to_plain_render=blur_t["median_s"] / base_s,
                         subframes=blur_info["samples"]),
        rolling_shutter=dict(roll_t, ratio_to_plain_render=roll_t["median_s"] / base_s,
                             subframes=roll_info["samples"]),
        triangles=frame.drawn.get("triangles"),
        peak_rss_mib=round(peak_rss_bytes() / 1024**2, 1),
        peak_rss_increment_mib=round((peak_rss_bytes() - rss0) / 1024**2, 1),
        machine=machine_facts(load_average=list(os.getloadavg())),
    )
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
