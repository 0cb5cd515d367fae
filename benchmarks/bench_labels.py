"""Label benchmark: what image-space labels cost per 1024 x 1024 frame, one JSON document.

The scene of ``bench_sensor.py`` (RMD relief with a crater population, 513^2 at 2 m, one
finer layer) with rocks, rendered at 1024 x 1024 from 600 m up, 30 degrees off nadir. Each
figure is a median over repeated frames, timed in rounds interleaved with the baseline, the
frame itself (the draw and read-back of the I/F, range and normal images, what every frame
pays):

* ``labels``: crater rims (conics and visibility of every crater above 8 px), the instance
  and semantic masks (:meth:`render.labels.Labeller.label`, hazards off);
* ``flow``: the forward flow and occlusion mask to a second pose 2 m further on;
* ``hazards``: the hazard map sampled in image space (the map itself is built once per run,
  reported as ``hazard_map_build_s``);
* ``write``: the per-frame label files (:func:`render.dataset.write_frame_labels`,
  :func:`render.dataset.write_flow`).

Ratios are each figure over the frame. There is no target in the issue; labels are off by
default, so a run that does not ask for them pays nothing.

Usage::

    .venv/bin/python benchmarks/bench_labels.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from _common import alternate, logger, machine_facts, peak_rss_bytes

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-labels")
SEED = 16


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="256 x 256 frames, fewer repeats")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from render.camera import Intrinsics, look_at
    from render.dataset import write_flow, write_frame_labels
    from render.labels import Labeller, LabelSpec, surface_points
    from render.renderer import Lighting, Renderer, RenderOptions, View
    from render.terrain_scene import TerrainScene
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.surface.rocks import RockModel

    size = 256 if args.quick else 1024
    repeat = 3 if args.quick else 5
    base = synthesize_tile(513, resolution=2.0, relief=40.0, seed=SEED).tile
    site = (513.0, 513.0)
    stack = build_stack(base, site, levels=1, layer_size=513, seed=SEED,
                        population=Population(dmin=2.0, dmax=300.0, density=1e5),
                        rocks=RockModel.from_spec("golombek-rapp-mars:k=0.05,dmin=1.5"))
    scene = TerrainScene(stack, curvature=False)
    renderer = Renderer()
    k = Intrinsics.from_fov(size, size, 45.0)
    pose = look_at((513.0 - 350.0, 513.0, 600.0), (513.0, 513.0, 0.0))
    pose2 = look_at((513.0 - 348.0, 513.0, 598.0), (513.0, 513.0, 0.0))
    view, view2 = View(pose, k), View(pose2, k)
    light = Lighting.from_angles(120.0, 20.0)
    options = RenderOptions(shadows=True, shadow_size=2048, lod_pixels=1.5)
    frame = renderer.render(scene, view, light, options)  # warm-up: uploads, shadow maps
    frame2 = renderer.render(scene, view2, light, options)
    spec = LabelSpec(min_crater_pixels=8.0)
    labeller = Labeller(scene, spec)
    hazards = Labeller(scene, replace(spec, hazards=True, lander_diameter=20.0, max_step=1.0))
    t0 = time.perf_counter()
    hazards.hazard_image(surface_points(frame.range[:1, :1], pose, k))
    build_s = time.perf_counter() - t0
    points = surface_points(frame.range, pose, k)
    labels = labeller.label(frame, pose, k, light)
    labeller.add_flow(labels, frame.range, pose, (1, 0, 0, 0), frame2.range, pose2,
                      (1, 0, 0, 0), k)
    tmp = Path(tempfile.mkdtemp(prefix="bench-labels-"))
    rss0 = peak_rss_bytes()
    log(f"{size}^2: frame, labels, flow, hazards, writing, interleaved, {repeat} rounds")

    def flow():
        labeller.add_flow(labels, frame.range, pose, (1, 0, 0, 0), frame2.range, pose2,
                          (1, 0, 0, 0), k)

    def write():
        write_frame_labels(tmp, 0, labels)
        write_flow(tmp, 0, labels)

    timed = alternate(dict(
        frame=lambda: renderer.render(scene, view, light, options),
        labels=lambda: labeller.label(frame, pose, k, light),
        flow=flow,
        hazards=lambda: hazards.hazard_image(points),
        write=write,
    ), repeat)
    t = timed.timings
    base_s = t["frame"]["median_s"]
    lab = timed.results["labels"]
    out = dict(
        benchmark="labels", frame=[size, size], repeat=repeat, frame_render=t["frame"],
        **{name: dict(t[name], ratio_to_frame=t[name]["median_s"] / base_s)
           for name in ("labels", "flow", "hazards", "write")},
        all_labels_ratio_to_frame=sum(t[n]["median_s"] for n in ("labels", "flow", "hazards",
                                                                 "write")) / base_s,
        hazard_map_build_s=build_s,
        craters_labelled=len(lab.craters),
        instances=len(lab.instances),
        rocks_in_stack=0 if stack.rocks is None else len(stack.rocks),
        triangles=frame.drawn.get("triangles"),
        peak_rss_mib=round(peak_rss_bytes() / 1024**2, 1),
        peak_rss_increment_mib=round((peak_rss_bytes() - rss0) / 1024**2, 1),
        machine=machine_facts(load_average=list(os.getloadavg())),
    )
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
