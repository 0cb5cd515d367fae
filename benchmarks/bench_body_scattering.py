"""Cost of the light a body scatters into its own shadows: frame time with it off and on.

Scene: the demo's Eros-like asteroid (``examples/eros_like.toml`` without its boulders: Perlin
base stretched 2.6 : 1 : 0.95, craters from 150 m; magnitude 256; --quick: 48) turning under
a fixed sun
by 1.14 degrees a frame (the demo's approach: an 18,972 s spin, a frame a minute), seen from
three radii at the demo's 1024 x 1024 with 3 x 3 samples a pixel (--quick: 256 x 256, one
sample). Scattered light (:mod:`render.body_scattering`) is off or on
(``RenderOptions.scattering``); each round renders the same run of frames with each setting,
the settings alternating (benchmarks/_common.alternate), and each round turns the body on from
where the last left it, so the scattered light is recomputed as in a real run whenever the
body-frame sun crosses to the next lattice point. The view factors, computed once per body,
are timed on their own. ``--body PATH`` renders a native ``.npz`` instead (e.g. the demo's
``demo-output/asteroid/body/body.npz``).
Reported: median frame time off and on, their ratio, and the one-time cost. Target: the
scattered light adds at most 10 % to a frame.

Usage::

    .venv/bin/python benchmarks/bench_body_scattering.py [--quick] [--body PATH]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _common import alternate, logger, machine_facts  # noqa: E402

log = logger("bench-body-scattering")
#: Target: scattered light adds at most this fraction to a frame.
TARGET_OVERHEAD = 0.10
#: The demo approach's spin per frame (degrees): 360 * 60 s / 18,972 s.
SPIN_PER_FRAME_DEG = 360.0 * 60.0 / 18972.0
ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    parser.add_argument("--body", type=Path, default=None, help="a native .npz to render")
    args = parser.parse_args(argv)
    import tomllib

    from asteroid.build import build
    from asteroid.recipe import Recipe
    from render.asteroid_scene import AsteroidScene
    from render.camera import Intrinsics, look_at
    from render.renderer import Lighting, Renderer, RenderOptions, View

    magnitude, size, antialias, frames, rounds = ((48, 256, 1, 4, 2) if args.quick
                                                  else (256, 1024, 3, 5, 2))
    t0 = time.perf_counter()
    if args.body is not None:
        scene = AsteroidScene(args.body, boulders=False)
        magnitude = scene.body.magnitude
    else:
        table = tomllib.loads((ROOT / "examples" / "eros_like.toml").read_text())
        table.pop("boulders", None)
        table["magnitude"] = magnitude
        scene = AsteroidScene(build(Recipe.from_dict(table)).body, boulders=False)
    log(f"body of magnitude {magnitude} ready in {time.perf_counter() - t0:.1f} s")
    light = Lighting((0.6, -0.7, 0.35), albedo=0.25, brdf="lommel-seeliger")
    k = Intrinsics.from_fov(size, size, 40.0)
    reach = scene.reach
    view = View(look_at((0.6 * reach, -3.0 * reach, 1.0 * reach), (0.0, 0.0, 0.0)), k, 0.0)
    renderer = Renderer()
    options = {name: RenderOptions(scattering=on, antialias=antialias, lod_pixels=3.0)
               for name, on in (("off", False), ("on", True))}
    def spin(i: int) -> tuple:
        a = math.radians(SPIN_PER_FRAME_DEG * i) / 2.0
        return (math.cos(a), 0.0, 0.0, math.sin(a))

    def first(name):
        t0 = time.perf_counter()
        scene.set_body_rotation(spin(0))
        renderer.render(scene, view, light, options[name])
        return time.perf_counter() - t0

    first_off = first("off")  # uploads, shaders
    t0 = time.perf_counter()
    pairs = scene.body_light().pairs
    view_factors_s = time.perf_counter() - t0
    first_on = first("on")
    log(f"first frame off {first_off:.2f} s; view factors {view_factors_s:.2f} s ({pairs} "
        f"pairs); first frame on {first_on:.2f} s")

    def run(name):
        done = {"rounds": 0}  # each setting's round r renders frames r N .. (r + 1) N - 1

        def call():
            mean = 0.0
            start = 1 + done["rounds"] * frames
            for i in range(start, start + frames):
                scene.set_body_rotation(spin(i))
                mean += float(renderer.render(scene, view, light, options[name]).radiance.mean())
            done["rounds"] += 1
            return mean / frames
        return call

    measured = alternate({"off": run("off"), "on": run("on")}, rounds)
    off = measured.timings["off"]["median_s"] / frames
    on = measured.timings["on"]["median_s"] / frames
    overhead = on / off - 1.0
    out = dict(
        magnitude=magnitude, size=size, antialias=antialias, frames_per_round=frames,
        rounds=rounds, spin_per_frame_deg=SPIN_PER_FRAME_DEG,
        frame_off_s=off, frame_on_s=on, overhead=overhead,
        one_time_view_factors_s=view_factors_s, first_frame_off_s=first_off,
        first_frame_on_s=first_on, pairs=int(pairs), body=str(args.body) if args.body else None,
        mean_radiance={"off": measured.results["off"], "on": measured.results["on"]},
        timings=measured.timings, target_overhead=TARGET_OVERHEAD,
        target_met=bool(overhead <= TARGET_OVERHEAD), machine=machine_facts())
    log(f"frame off {off:.3f} s, on {on:.3f} s: +{100 * overhead:.1f} %")
    json.dump(out, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0 if np.isfinite(overhead) else 1


if __name__ == "__main__":
    sys.exit(main())
