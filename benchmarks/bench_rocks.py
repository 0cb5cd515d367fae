"""Rocks and centimetre layers: placement speed and memory, extra levels, frame time.

Three measurements, each in its own child process (so peak memory is its own), each with a
baseline measured in the same run:

``place``
    Rocks placed per second on a 4097 x 4097 tile (5 cm pixels, 205 m across; Golombek-Rapp
    k = 0.05, every rock of two pixels and more): generation (position-keyed cells) and the
    heights rasteriser (:func:`terrain.surface.rocks.add_rocks`), with peak memory. Baselines: the
    same number of rocks' 15 parameters drawn from NumPy's sequential ``Generator`` (what
    position keying costs over an unkeyed draw), and a child that only reads the tile
    (memory).
``layers``
    Layers per second of a layer stack built as the demo builds it (1025 x 1025 layers from a
    1 km base) to 15 levels with rocks: the extra centimetre levels 12-15 against the
    standard levels 1-11 of the same build (baseline), and the rock pass.
``frame``
    Frame time at 1024 x 1024 with shadows on the last 100 m of a descent onto a rocky site
    (layers down to 3 cm) against the same views of the same stack without rocks.

Usage::

    .venv/bin/python benchmarks/bench_rocks.py [--quick] [--only place layers frame]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import logger, machine_facts, peak_rss_bytes, run_child, summary  # noqa: E402

SEED = 2014
log = logger("bench-rocks")


def child_place(spec: dict) -> dict:
    import numpy as np

    from terrain.fractal.synthetic import synthesize_tile
    from terrain.surface.rocks import RockModel, add_rocks

    n, res = spec["size"], spec["resolution"]
    tile = synthesize_tile(n, resolution=res, relief=2.0, seed=SEED).tile
    if spec.get("baseline"):
        return dict(peak_rss_bytes=peak_rss_bytes())
    model = RockModel.from_spec(spec["rocks"], defaults=dict(dmin=2 * res))
    add_rocks(tile.window(_small(tile)), model, seed=SEED)  # compile outside the timing
    times, counts = [], []
    for _ in range(spec["repeat"]):
        t0 = time.perf_counter()
        _, cat = add_rocks(tile, model, seed=SEED)
        times.append(time.perf_counter() - t0)
        counts.append(len(cat))
    gen = []
    for _ in range(spec["repeat"]):
        t0 = time.perf_counter()
        model.generate(SEED, tile.bounds, min_diameter=2 * res)
        gen.append(time.perf_counter() - t0)
    plain = []
    for _ in range(spec["repeat"]):
        t0 = time.perf_counter()
        rng = np.random.default_rng(SEED)
        rng.random((counts[0], 15))
        plain.append(time.perf_counter() - t0)
    t = statistics.median(times)
    return dict(rocks=counts[0], add_rocks=summary(times), generate=summary(gen),
                numpy_generator_draw=summary(plain), rocks_per_s=counts[0] / t,
                generate_ratio_to_numpy_draw=statistics.median(gen) / statistics.median(plain),
                peak_rss_bytes=peak_rss_bytes())


def _small(tile):
    from terrain.core.tile import Window

    return Window(0, 0, min(64, tile.shape[1]), min(64, tile.shape[0]))


def child_layers(spec: dict) -> dict:
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.surface.rocks import RockModel

    size, levels, extra = spec["size"], spec["levels"], spec["extra"]
    base = synthesize_tile(size, resolution=1000.0, relief=2500.0, seed=SEED).tile
    site = (size * 500.0, size * 500.0)
    stamps = []
    t0 = time.perf_counter()

    def progress(step, total, label):
        stamps.append((label, time.perf_counter() - t0))

    build_stack(base, site, levels=levels + extra, layer_size=size, seed=SEED,
                population=Population(dmin=1.0, dmax=15000.0, density=1e5),
                rocks=RockModel.from_spec(spec["rocks"], defaults=dict(
                    dmin=2 * 1000.0 / 2 ** (levels + extra))), progress=progress)
    total = time.perf_counter() - t0
    per = {}
    prev = None
    for label, t in stamps:
        if prev is not None:
            k = int(label.split()[-1]) if label.split()[-1].isdigit() else -1
            per[k] = per.get(k, 0.0) + t - prev
        prev = t
    std = [per[k] for k in range(1, levels + 1)]
    ext = [per[k] for k in range(levels + 1, levels + extra + 1)]
    rocks_s = total - stamps[-1][1]
    return dict(layers=levels + extra + 1, layer_size=size, total_s=total,
                standard_levels_s=std, extra_levels_s=ext,
                standard_layers_per_s=len(std) / sum(std),
                extra_layers_per_s=len(ext) / sum(ext),
                extra_to_standard_time_ratio=statistics.mean(ext) / statistics.mean(std),
                rocks_and_agreement_s=rocks_s, peak_rss_bytes=peak_rss_bytes())


def child_frame(spec: dict) -> dict:
    from render.camera import Intrinsics
    from render.context import create_context, describe
    from render.renderer import Lighting, Renderer, RenderOptions, View
    from render.terrain_scene import TerrainScene
    from render.trajectory import descent
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.surface.rocks import RockModel

    size, image = spec["layer_size"], spec["image"]
    base = synthesize_tile(size, resolution=0.5, relief=3.0, seed=SEED).tile
    site = (size * 0.25, size * 0.25)
    rocks = RockModel.from_spec(spec["rocks"], defaults=dict(
        dmin=2 * 0.5 / 2 ** spec["levels"]))
    ctx = create_context()
    renderer = Renderer(ctx)
    k = Intrinsics.from_fov(image, image, 60.0)
    light = Lighting.from_angles(60.0, 12.0)
    out = {}
    for key, model in (("without_rocks", None), ("with_rocks", rocks)):
        stack = build_stack(base, site, levels=spec["levels"], layer_size=size, seed=SEED,
                            rocks=model)
        scene = TerrainScene(stack, curvature=False)
        ground = scene.height_at(*scene.site)
        samples = descent(spec["frames"], (*scene.site, ground), start_altitude=100.0,
                          end_altitude=20.0, duration=10.0, ground_track=(40.0, -30.0))
        renderer.render(scene, View(samples[0].pose, k), light, RenderOptions(shadows=True))
        times = []
        for s in samples:
            t0 = time.perf_counter()
            renderer.render(scene, View(s.pose, k), light, RenderOptions(shadows=True))
            times.append(time.perf_counter() - t0)
        out[key] = dict(summary(times), rocks=0 if stack.rocks is None
                        else len(stack.rocks))
    out["ratio_with_to_without"] = out["with_rocks"]["median_s"] / out["without_rocks"]["median_s"]
    out["renderer"] = describe()
    out["peak_rss_bytes"] = peak_rss_bytes()
    return out


CHILDREN = {"place": child_place, "layers": child_layers, "frame": child_frame}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    parser.add_argument("--only", nargs="*", default=None, choices=sorted(CHILDREN))
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        spec = json.loads(args.child)
        print(json.dumps(CHILDREN[spec["kind"]](spec)))
        return 0
    q = args.quick
    rocks = "golombek:k=0.05"
    specs = {
        "place": [dict(kind="place", name="place", size=513 if q else 4097, resolution=0.05,
                       rocks=rocks, repeat=1 if q else 3),
                  dict(kind="place", name="place_baseline_read_only", size=513 if q else 4097,
                       resolution=0.05, rocks=rocks, repeat=1, baseline=True)],
        "layers": [dict(kind="layers", name="layers", size=129 if q else 1025,
                        levels=7 if q else 11, extra=4, rocks="golombek:k=0.02", repeat=1)],
        "frame": [dict(kind="frame", name="frame", layer_size=257 if q else 1025,
                       levels=2 if q else 4, image=256 if q else 1024, frames=3 if q else 8,
                       rocks="golombek:k=0.05", repeat=1)],
    }
    results = {}
    t0 = time.perf_counter()
    for name, group in specs.items():
        if args.only and name not in args.only:
            continue
        results[name] = {s["name"]: run_child(__file__, s, 3600, log) for s in group}
    place = results.get("place")
    if place:
        place["memory_over_read_only_bytes"] = (place["place"]["peak_rss_bytes"]
                                                - place["place_baseline_read_only"]
                                                ["peak_rss_bytes"])
    out = dict(benchmark="rocks", quick=q, results=results, total_s=time.perf_counter() - t0,
               machine=machine_facts())
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
