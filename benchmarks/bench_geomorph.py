"""Geomorphing benchmark: frame time with continuous levels of detail against switching.

Renders the default lunar descent scene (the one ``bench_render.py`` builds: a 1025^2 base at
1 km, 11 nested 1025^2 layers to about 0.5 m) at 1024 x 1024 along a 10 km -> 20 m descent,
with shadows, once with ``RenderOptions(geomorph=True)`` and once with ``geomorph=False``
(the baseline, measured in the same run: the same scene, frames, triangles budget and
shadow maps, levels of detail switching). The two are interleaved frame by frame, so a load
change on a shared machine hits both alike. Also an asteroid approach (a synthetic body with
boulders, passing from imposter to close range) the same way. Target (the consistency
issue): median frame time with geomorphing at most 1.2 times without.

Usage::

    .venv/bin/python benchmarks/bench_geomorph.py [--quick] [--frames N]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import logger, machine_facts, peak_rss_bytes  # noqa: E402
from bench_render import build_scene  # noqa: E402

log = logger("bench-geomorph")
#: The issue's bound on the frame-time ratio.
TARGET_RATIO = 1.2


def _interleaved(renderer, scene, views, light, options_on, options_off) -> dict:
    """Median frame times with and without geomorphing, alternating which goes first."""
    from render.renderer import View

    times = {True: [], False: []}
    tris = {True: [], False: []}
    for i, (pose, k, rotation) in enumerate(views):
        order = (True, False) if i % 2 == 0 else (False, True)
        for on in order:
            if rotation is not None:
                scene.set_body_rotation(rotation)
            t0 = time.perf_counter()
            frame = renderer.render(scene, View(pose, k), light,
                                    options_on if on else options_off)
            times[on].append(time.perf_counter() - t0)
            tris[on].append(frame.drawn["triangles"])
    out = {}
    for on, key in ((True, "geomorph"), (False, "switching")):
        out[key] = dict(median_s=statistics.median(times[on]), min_s=min(times[on]),
                        max_s=max(times[on]), frames_s=times[on],
                        median_triangles=int(statistics.median(tris[on])))
    out["ratio"] = out["geomorph"]["median_s"] / out["switching"]["median_s"]
    return out


def terrain(tmp: Path, quick: bool, frames: int, size: int) -> dict:
    from render.camera import Intrinsics
    from render.context import create_context
    from render.renderer import Lighting, Renderer, RenderOptions, View
    from render.terrain_scene import TerrainScene
    from render.trajectory import descent

    stack_dir, _ = build_scene(tmp, quick)
    renderer = Renderer(create_context())
    scene = TerrainScene(stack_dir)
    scene.upload(renderer.gpu)
    k = Intrinsics.from_fov(size, size, 60.0)
    site = scene.site
    ground = scene.height_at(*site)
    samples = descent(frames, (site[0], site[1], ground), start_altitude=10000.0,
                      end_altitude=20.0, duration=100.0, ground_track=(4000.0, -3000.0),
                      height_at=scene.height_at)
    light = Lighting.from_angles(60.0, 7.0)
    on, off = RenderOptions(geomorph=True), RenderOptions(geomorph=False)
    # warm-up: shader compilation, vertex arrays and the shadow maps of both
    renderer.render(scene, View(samples[0].pose, k), light, on)
    out = _interleaved(renderer, scene, [(s.pose, k, None) for s in samples], light, on, off)
    out["scene"] = dict(layers=len(scene.stack.tiles), full_triangles=scene.triangles_full)
    return out


def asteroid(tmp: Path, quick: bool, frames: int, size: int) -> dict:
    import numpy as np
    from click.testing import CliRunner

    from render.asteroid_scene import AsteroidScene
    from render.camera import Intrinsics, look_at
    from render.context import create_context
    from render.renderer import Lighting, Renderer, RenderOptions
    from render.trajectory import axis_angle
    from terrain.cli.commands import main

    body = tmp / "body.npz"
    magnitude = 64 if quick else 256
    r = CliRunner().invoke(main, ["asteroid", "build", "-o", str(body), "--magnitude",
                                  str(magnitude), "--radius", "3000", "--base", "perlin",
                                  "--seed", "7", "--boulders", "c=0.05,k=-3,dmin=8,dmax=120"])
    if r.exit_code != 0:
        raise RuntimeError(f"asteroid build failed: {r.output}")
    renderer = Renderer(create_context())
    scene = AsteroidScene(body)
    k = Intrinsics.from_fov(size, size, 40.0)
    light = Lighting((0.6, -0.7, 0.35), albedo=0.25, brdf="lommel-seeliger")
    views = []
    for i, d in enumerate(np.geomspace(120000.0, 6000.0, frames)):
        q = tuple(axis_angle((0.0, 0.0, 1.0), 0.02 * i).tolist())
        views.append((look_at((d, -0.4 * d, 0.3 * d), (0.0, 0.0, 0.0)), k, q))
    on, off = RenderOptions(geomorph=True), RenderOptions(geomorph=False)
    out = _interleaved(renderer, scene, views, light, on, off)
    out["body"] = dict(magnitude=magnitude, boulders=len(scene.boulders or []))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small scenes and images")
    parser.add_argument("--frames", type=int, default=None, help="frames per sequence")
    args = parser.parse_args(argv)
    quick = args.quick
    size = 256 if quick else 1024
    frames = args.frames or (4 if quick else 12)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        log("terrain descent")
        ter = terrain(Path(tmp), quick, frames, size)
        log(f"terrain: {ter['geomorph']['median_s']:.3f} s with geomorphing, "
            f"{ter['switching']['median_s']:.3f} s switching (ratio {ter['ratio']:.3f})")
        log("asteroid approach")
        ast = asteroid(Path(tmp), quick, frames, size)
        log(f"asteroid: {ast['geomorph']['median_s']:.3f} s with geomorphing, "
            f"{ast['switching']['median_s']:.3f} s switching (ratio {ast['ratio']:.3f})")
    from render.context import describe

    out = dict(benchmark="geomorph", quick=quick, image=[size, size], frames=frames,
               terrain=ter, asteroid=ast, target_ratio=TARGET_RATIO,
               targets=None if quick else dict(terrain_ratio_ok=ter["ratio"] <= TARGET_RATIO,
                                               asteroid_ratio_ok=ast["ratio"] <= TARGET_RATIO),
               renderer=describe(), peak_rss_bytes=peak_rss_bytes(),
               total_s=time.perf_counter() - t0, machine=machine_facts())
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
