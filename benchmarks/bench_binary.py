"""Binary-asteroid benchmark: frame time of a binary scene against one body, same triangles.

Scenes: a Didymos-like binary (a sphere of 390 m and one of 80 m on the default mutual orbit,
render.binary_scene) and, as the baseline, a single body (render.asteroid_scene) whose mesh
has about as many triangles as the two together (12 M^2 triangles per 6M^2+2 mesh:
magnitude 128 against 120 + 44; --quick: 40 against 36 + 17). Both are drawn at their finest
level (lod_pixels 0.1) from a camera that sees every triangle, with shadows on (the binary
draws two maps, each with both bodies as casters; the single body one) and off, frames
alternating between the scenes (benchmarks/_common.alternate). Reported: median frame time of
each, triangles drawn per frame, and the ratios binary / single. Target: the binary costs at
most 1.5 times the single body at the same triangle count.

Usage::

    .venv/bin/python benchmarks/bench_binary.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import alternate, logger, machine_facts  # noqa: E402

log = logger("bench-binary")
#: Target ratio of binary to single-body frame time at the same triangle count.
TARGET_RATIO = 1.5


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    args = parser.parse_args(argv)
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh
    from render.asteroid_scene import AsteroidScene
    from render.binary_scene import BinaryScene
    from render.camera import Intrinsics, look_at
    from render.renderer import Lighting, Renderer, RenderOptions, View

    single_m, primary_m, secondary_m = (40, 36, 17) if args.quick else (128, 120, 44)
    size, frames = (256, 3) if args.quick else (1024, 9)
    binary = BinaryScene(Body.sphere(SphereMesh(primary_m), 390.0),
                         Body.sphere(SphereMesh(secondary_m), 80.0), boulders=False)
    single = AsteroidScene(Body.sphere(SphereMesh(single_m), 390.0), boulders=False)
    k = Intrinsics.from_fov(size, size, 40.0)
    light = Lighting((0.3, 0.9, 0.3), albedo=0.2, brdf="lommel-seeliger")
    renderer = Renderer()
    # the whole system in view (it spans 1.4 km; the view 2.9 km at 4 km)
    camera = (0.0, -600.0, 4000.0)
    views = {"binary": View(look_at(camera, (0.0, 0.0, 0.0)), k, 0.0),
             "single": View(look_at(camera, (0.0, 0.0, 0.0)), k, 0.0)}
    scenes = {"binary": binary, "single": single}
    out: dict = {"triangles": {}, "frame_s": {}}
    for shadows in (True, False):
        options = RenderOptions(shadows=shadows, lod_pixels=0.1)
        tag = "shadows" if shadows else "no_shadows"
        for name in scenes:  # uploads and the first frame's setup, untimed
            frame = renderer.render(scenes[name], views[name], light, options)
            out["triangles"][name] = int(frame.drawn["triangles"])
        log(f"timing {frames} frames each, {tag}")
        timed = alternate({name: (lambda n=name, o=options: renderer.render(scenes[n], views[n],
                                                                      light, o))
                           for name in scenes}, frames)
        out["frame_s"][tag] = {name: timed.timings[name] for name in scenes}
        out["frame_s"][tag]["ratio"] = round(timed.timings["binary"]["median_s"]
                                             / timed.timings["single"]["median_s"], 3)
    ids = binary.body_ids(views["binary"], renderer.render(binary, views["binary"], light,
                                                            RenderOptions(lod_pixels=0.1)))
    out["pixels_by_body"] = np.bincount(ids.ravel(), minlength=3).tolist()
    ratio = out["frame_s"]["shadows"]["ratio"]
    print(json.dumps(dict(out, size=size, magnitudes=dict(single=single_m, primary=primary_m,
                                                          secondary=secondary_m),
                          target_ratio=TARGET_RATIO, meets_target=bool(ratio <= TARGET_RATIO),
                          machine=machine_facts(quick=args.quick)), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
