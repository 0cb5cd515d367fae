"""Radar, LIDAR and event-camera benchmark: the cost of a request of each, one JSON document.

A synthetic lunar terrain (RMD relief with craters, 513^2 at 2 m) seen from 600 m, 30 degrees
off nadir, moving at 30 m/s and turning at 2 deg/s. The baseline, measured interleaved in the
same run, is the plain camera frame (range, normals and I/F at 512 x 512; 128 x 128 with
--quick): what the renderer pays for one image.

* ``radar``: one radar measurement (a 4-degree Gaussian beam sampled by 64 x 64 rays, the
  range x Doppler histogram of 64 x 128 bins); ``radar_4_beams``: a four-beam velocimeter.
* ``lidar_flash``: a 64 x 64 flash LIDAR, 4 x 4 sub-rays a pixel (a 256 x 256 frame) with
  returns and the link budget; ``lidar_flash_divergent``: footprints twice the pixel's
  width (6 x 6 sub-rays a side per IFOV disk, overlapping); ``lidar_scan``: a 32 x 32 raster
  scan at 10 kHz during the motion (its slices each render a flash).
* ``events``: the event camera over 0.1 s (0.02 s with --quick) of the motion at the
  baseline's resolution:
  events per simulated second, per second of wall time, and the cost per rendered instant.

Each figure is a median over repeats; ratios are each over the plain frame.

Usage::

    .venv/bin/python benchmarks/bench_sensors_extra.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from _common import alternate, logger, machine_facts, peak_rss_bytes

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-sensors-extra")
SEED = 29


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="128 x 128 frames, fewer repeats")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from render.camera import Intrinsics, look_at
    from render.events import EventCamera, simulate
    from render.instruments import renderer_look
    from render.lidar import Lidar, flash, scan
    from render.motion import Motion
    from render.radar import RadarBeam, measure
    from render.renderer import Lighting, Renderer, RenderOptions, View
    from render.terrain_scene import TerrainScene
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack

    size = 128 if args.quick else 512
    repeat = 2 if args.quick else 5
    span = 0.02 if args.quick else 0.1
    base = synthesize_tile(513, resolution=2.0, relief=40.0, seed=SEED).tile
    stack = build_stack(base, (513.0, 513.0), levels=1, layer_size=513, seed=SEED,
                        population=Population(dmin=2.0, dmax=300.0, density=1e5))
    scene = TerrainScene(stack, curvature=False)
    renderer = Renderer()
    k = Intrinsics.from_fov(size, size, 45.0)
    pose = look_at((513.0 - 350.0, 513.0, 600.0), (513.0, 513.0, 0.0))
    light = Lighting.from_angles(120.0, 20.0)
    options = RenderOptions(shadows=True, shadow_size=1024)
    motion = Motion(velocity=(30.0, 0.0, 0.0), angular_velocity=(0.0, 0.0, math.radians(2.0)))
    look = renderer_look(renderer, scene, light, options, 0.0)
    look_albedo = renderer_look(renderer, scene, light, options, 0.0, albedo=True)
    beam = RadarBeam()
    beams = [RadarBeam(direction=d, width=3.0) for d in
             ((0.3, 0.0, 1.0), (-0.3, 0.0, 1.0), (0.0, 0.3, 1.0), (0.0, -0.3, 1.0))]
    lid = Lidar(width=64, height=64, fov=10.0)
    lid_div = Lidar(width=64, height=64, fov=10.0, divergence=2 * 10.0 / 64, supersample=3)
    lid_scan = Lidar(mode="scan", width=32, height=32, fov=10.0, supersample=2)
    camera = EventCamera(contrast_on=0.2, contrast_off=0.2, max_step=0.01)
    renderer.render(scene, View(pose, k), light, options)   # warm-up: uploads, shadow map

    def events():
        def render_at(t):
            return renderer.render(scene, View(motion.pose_at(pose, t), k, t), light,
                                   options).radiance
        t0 = time.perf_counter()
        ev, stats = simulate(render_at, 0.0, span, camera, seed=SEED)
        return ev, stats, time.perf_counter() - t0

    rss0 = peak_rss_bytes()
    log(f"{size}^2 baseline; radar, LIDAR flash/scan, events; {repeat} rounds interleaved")
    timed = alternate(dict(
        plain_render=lambda: renderer.render(scene, View(pose, k), light, options),
        radar=lambda: measure(beam, look, pose, motion.velocity),
        radar_4_beams=lambda: [measure(b, look, pose, motion.velocity) for b in beams],
        lidar_flash=lambda: flash(lid, look_albedo, pose, seed=SEED),
        lidar_flash_divergent=lambda: flash(lid_div, look_albedo, pose, seed=SEED),
        lidar_scan=lambda: scan(lid_scan, look_albedo, pose, 0.0, motion, seed=SEED),
        events=events,
    ), repeat)
    t = timed.timings
    base_s = t["plain_render"]["median_s"]

    def ratio(name, **extra):
        return dict(t[name], ratio_to_plain_render=t[name]["median_s"] / base_s, **extra)

    ev, stats, wall = timed.results["events"]
    img = timed.results["lidar_flash"]
    out = dict(
        benchmark="sensors_extra", frame=[size, size], repeat=repeat,
        plain_render=t["plain_render"],
        radar=ratio("radar", rays=beam.pixels ** 2,
                    range_m=timed.results["radar"].range),
        radar_4_beams=ratio("radar_4_beams"),
        lidar_flash=ratio("lidar_flash", pixels=64 * 64, sub_rays=256 * 256,
                          dropout_fraction=float((img.range != img.range).mean())),
        lidar_flash_divergent=ratio("lidar_flash_divergent"),
        lidar_scan=ratio("lidar_scan", points=32 * 32,
                         slices=timed.results["lidar_scan"].slices,
                         seconds_per_point=t["lidar_scan"]["median_s"] / 1024),
        events=ratio("events", simulated_s=span, events=int(stats["events"]),
                     instants=int(stats["instants"]),
                     events_per_simulated_second=stats["events"] / span,
                     events_per_wall_second=stats["events"] / wall,
                     seconds_per_instant=t["events"]["median_s"] / stats["instants"],
                     instant_ratio_to_plain_render=t["events"]["median_s"] / stats["instants"]
                     / base_s),
        peak_rss_mib=round(peak_rss_bytes() / 1024**2, 1),
        peak_rss_increment_mib=round((peak_rss_bytes() - rss0) / 1024**2, 1),
        machine=machine_facts(load_average=list(os.getloadavg())),
    )
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
