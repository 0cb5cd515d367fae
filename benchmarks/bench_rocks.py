"""Rocks and centimetre layers: placement speed and memory, extra levels, frame time.

Four measurements, each in its own child process (so peak memory is its own), each with a
baseline measured in the same run, interleaved with it where the two are separate calls:

``place``
    Rocks placed per second on a 4097 x 4097 tile (5 cm pixels, 205 m across; Golombek-Rapp
    k = 0.05, every rock of two pixels and more): generation (position-keyed cells) and the
    heights rasteriser (:func:`terrain.surface.rocks.add_rocks`), with peak memory. Baselines: the
    same number of rocks' 15 parameters drawn from NumPy's sequential ``Generator`` (what
    position keying costs over an unkeyed draw), and a child that only reads the tile
    (memory).
``layers``
    Layers per second of a layer stack built as the demo builds it (1025 x 1025 layers from a
    1 km base) to 15 levels with the lunar default rocks: the extra centimetre levels 12-15
    against the standard levels 1-11 of the same build (baseline), and the rock pass.
``stack``
    The rock pass of a demo-like stack (1 km per pixel base, 1025 x 1025 layers, 15 levels to
    3 cm, the demo's crater population): every layer that resolves rocks gets them over its
    whole extent (:func:`terrain.stack.build._add_layer_rocks`, generation, base levels and
    rasterising) with the lunar default ``viper-nominal`` and its crater block fields,
    against, interleaved in the same run, the same pass with the Mars model the demo used
    before (``golombek-rapp-mars:k=0.02``) and with ``viper-nominal`` without block fields.
    Also the largest rock, rocks >= 1 m per km^2 of the 1 m layer, and the drawn N(>=D)
    against the VIPER law on the layers' own area.
``frame``
    Frame time at 1024 x 1024 with shadows on the last 100 m of a descent onto a rocky site
    (layers down to 3 cm) against the same views of the same stack without rocks, frame by
    frame, alternating which goes first.

Usage::

    .venv/bin/python benchmarks/bench_rocks.py [--quick] [--only place layers stack frame]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import (  # noqa: E402
    alternate,
    logger,
    machine_facts,
    order,
    peak_rss_bytes,
    run_child,
    summary,
)

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
    placed = {}

    def place():
        _, cat = add_rocks(tile, model, seed=SEED)
        placed["rocks"] = len(cat)

    def plain():  # as many rocks as place() placed: it runs first, in the first round
        rng = np.random.default_rng(SEED)
        rng.random((placed["rocks"], 15))

    timed = alternate(dict(
        add_rocks=place,
        generate=lambda: model.generate(SEED, tile.bounds, min_diameter=2 * res),
        numpy_generator_draw=plain), spec["repeat"])
    return dict(rocks=placed["rocks"], **timed.timings,
                rocks_per_s=placed["rocks"] / timed.timings["add_rocks"]["median_s"],
                generate_ratio_to_numpy_draw=timed.ratio("generate", "numpy_generator_draw"),
                peak_rss_bytes=timed.peak_after_first_bytes)


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


def child_stack(spec: dict) -> dict:
    import numpy as np

    from terrain.core.tile import DEMTile
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import _add_layer_rocks
    from terrain.stack.plan import layer_plan
    from terrain.surface.rocks import RockModel

    size, levels = spec["size"], spec["levels"]
    base = synthesize_tile(size, resolution=1000.0, relief=2500.0, seed=SEED).tile
    site = (size * 500.0, size * 500.0)
    _, _, shapes, transforms = layer_plan(base, site, levels, size)
    finest = 1000.0 / 2**levels
    population = Population(dmin=1.0, dmax=15000.0, density=1e5)

    def tiles():  # flat layers: the rock pass costs the same on any ground
        return [DEMTile(np.zeros(sh, np.float32), np.ones(sh, bool), tr, base.crs, base.nodata)
                for sh, tr in zip(shapes, transforms, strict=True)]

    models = {name: RockModel.from_spec(text, defaults=dict(dmin=2 * finest))
              for name, text in spec["models"].items()}
    small = tiles()[-1:]
    for model in models.values():  # compile outside the timing
        _add_layer_rocks(small, model, SEED, population)
    catalogs = {}

    def call(name):
        def run():
            catalogs[name] = _add_layer_rocks(tiles(), models[name], SEED, population)
        return run

    timed = alternate({name: call(name) for name in models}, spec["repeat"])
    out: dict = dict(layers=levels + 1, layer_size=size, **timed.timings,
                     peak_rss_bytes=timed.peak_after_first_bytes)
    first = list(models)[0]
    for name, cat in catalogs.items():
        res = np.array([t.a for t in transforms])
        one_m = int(np.flatnonzero(2 * res <= 1.0 + 1e-9)[0])  # the widest layer holding 1 m
        left, top = transforms[one_m].c, transforms[one_m].f
        side = shapes[one_m][0] * res[one_m]
        inside = ((cat.x_m >= left) & (cat.x_m <= left + side) & (cat.y_m <= top)
                  & (cat.y_m >= top - side))
        out[f"{name}_rocks"] = len(cat)
        out[f"{name}_largest_m"] = float(cat.diameter_m.max()) if len(cat) else 0.0
        out[f"{name}_per_km2_ge_1m_in_{res[one_m]:.3g}m_layer"] = float(
            np.count_nonzero(inside & (cat.diameter_m >= 1.0)) / (side * side) * 1e6)
        out[f"{name}_per_layer"] = np.bincount(cat.layer, minlength=levels + 1).tolist()
    out["time_ratio_to_" + "_and_".join(list(models)[1:])] = [
        timed.ratio(first, other) for other in list(models)[1:]]
    return out


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
    options = RenderOptions(shadows=True)
    scenes, counts = {}, {}
    for key, model in (("without_rocks", None), ("with_rocks", rocks)):
        stack = build_stack(base, site, levels=spec["levels"], layer_size=size, seed=SEED,
                            rocks=model)
        scenes[key] = TerrainScene(stack, curvature=False)
        counts[key] = 0 if stack.rocks is None else len(stack.rocks)
    # the same views of both (the ground of the stack without rocks)
    scene = scenes["without_rocks"]
    samples = descent(spec["frames"], (*scene.site, scene.height_at(*scene.site)),
                      start_altitude=100.0, end_altitude=20.0, duration=10.0,
                      ground_track=(40.0, -30.0))
    for scene in scenes.values():  # warm: uploads, programs, shadow maps
        renderer.render(scene, View(samples[0].pose, k), light, options)
    times = {key: [] for key in scenes}
    for i, s in enumerate(samples):  # frame by frame, alternating which goes first
        for key in order(list(scenes), i):
            t0 = time.perf_counter()
            renderer.render(scenes[key], View(s.pose, k), light, options)
            times[key].append(time.perf_counter() - t0)
    out = {key: dict(summary(times[key]), rocks=counts[key]) for key in scenes}
    out["ratio_with_to_without"] = out["with_rocks"]["median_s"] / out["without_rocks"]["median_s"]
    out["renderer"] = describe()
    out["peak_rss_bytes"] = peak_rss_bytes()
    return out


CHILDREN = {"place": child_place, "layers": child_layers, "stack": child_stack,
            "frame": child_frame}


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
    rocks = "golombek-rapp-mars:k=0.05"
    specs = {
        "place": [dict(kind="place", name="place", size=513 if q else 4097, resolution=0.05,
                       rocks=rocks, repeat=1 if q else 3),
                  dict(kind="place", name="place_baseline_read_only", size=513 if q else 4097,
                       resolution=0.05, rocks=rocks, repeat=1, baseline=True)],
        "layers": [dict(kind="layers", name="layers", size=129 if q else 1025,
                        levels=7 if q else 11, extra=4, rocks="viper-nominal", repeat=1)],
        "stack": [dict(kind="stack", name="stack", size=257 if q else 1025,
                       levels=15, repeat=1 if q else 3, models={
                           "viper_nominal": "viper-nominal",
                           "golombek_rapp_mars_k002": "golombek-rapp-mars:k=0.02",
                           "viper_nominal_no_blocks": "viper-nominal:craters=off"})],
        "frame": [dict(kind="frame", name="frame", layer_size=257 if q else 1025,
                       levels=2 if q else 4, image=256 if q else 1024, frames=3 if q else 8,
                       rocks="golombek-rapp-mars:k=0.05", repeat=1)],
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
