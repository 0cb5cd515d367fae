"""Benchmarks for DEM enhancement: one JSON document on stdout, progress on stderr.

Targets (the DEM-enhancement issue), each against a baseline measured in the same run:

* ``expand``: one 2x fractal expansion of a 4097^2 DEM (roughness measured from it, local
  roughness map on) in <= 3 s and <= 2 GiB, and at most 15x the baseline: copying the
  8193^2 float32 result into freshly allocated memory; with it, the same expansion on one
  thread (and whether its bytes are the same).
* ``enhance``: the 11-level enhancement of a 1025^2 base at 1 km down to about 0.5 m with
  1025^2 layers and a lunar crater population, written to disk, in <= 60 s; baseline: the
  same stack with no craters, the two built in alternating rounds (one child each a round;
  2 rounds, 1 with ``--quick``).
* ``fill``: filling 1 million unknown pixels (one disc on a 2049^2 DEM); baseline: GDAL's
  inverse-distance ``fillnodata`` (rasterio) on the same gap.

Each configuration runs in its own child process (this script with ``--child``), so its peak
resident set size is its own; children warm numba up first and report that separately. The
expansion and its copy, and the two fills, alternate run by run inside their child.

Usage::

    .venv/bin/python benchmarks/bench_enhance.py          # full (a few minutes)
    .venv/bin/python benchmarks/bench_enhance.py --quick  # small sizes, seconds
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import logger, pool, run_rounds, summary
from _common import peak_rss_bytes as peak_rss

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-enhance")
SEED = 2014
GiB = 1024**3


# ------------------------------------------------------------------------------ children


def warm_up() -> float:
    import numpy as np

    from terrain.craters.population import Population
    from terrain.fractal.expand import expand
    from terrain.fractal.gapfill import fill_gaps
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack

    t0 = time.perf_counter()
    tile = synthesize_tile(33, resolution=100.0, relief=50.0, seed=1).tile
    expand(tile, 1, seed=1)
    h = tile.heights.copy()
    h[10:15, 10:15] = np.nan
    fill_gaps(tile.replace(heights=h), seed=1)
    build_stack(tile, (1600.0, 1600.0), levels=2, layer_size=17, seed=1,
                population=Population(dmin=1.0, dmax=500.0, density=1e5))
    return time.perf_counter() - t0


def child_expand(spec):
    import numpy as np

    from terrain.core.tile import DEMTile
    from terrain.fractal.expand import expand
    from terrain.fractal.rmd import synthesize

    warm = warm_up()
    size = spec["size"]
    tile = DEMTile.from_array(synthesize(size, relief=200.0, seed=SEED), resolution=2.0)
    from terrain.core.parallel import limited
    from terrain.core.parallel import threads as thread_count

    rss0 = peak_rss()
    times, copies, single = [], [], []
    threads = thread_count()
    first = None
    for i in range(spec["repeat"]):
        t0 = time.perf_counter()
        out = expand(tile, 1, seed=SEED)
        times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        copy = np.empty_like(out.heights)
        copy[...] = out.heights
        copies.append(time.perf_counter() - t0)
        shape = out.shape
        first = out.heights if first is None else first
        del out, copy
        with limited(1):  # the one-core baseline, interleaved
            t0 = time.perf_counter()
            one = expand(tile, 1, seed=SEED)
            single.append(time.perf_counter() - t0)
        same = bool(np.array_equal(one.heights, first, equal_nan=True))
        del one
        log(f"  expand {size}^2 run {i + 1}: {times[-1]:.3f} s on {threads} threads, "
            f"{single[-1]:.3f} s on one (copy {copies[-1]:.3f} s)")
    return dict(warmup_s=warm, input=[size, size], output=list(shape), wall=summary(times),
                copy_output=summary(copies), one_thread=summary(single), threads=threads,
                ratio_to_copy=statistics.median(times) / statistics.median(copies),
                speedup_over_one_thread=statistics.median(single) / statistics.median(times),
                same_bytes_on_one_thread=same,
                peak_rss_bytes=peak_rss(), peak_rss_before_bytes=rss0)


def child_enhance(spec):
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    warm = warm_up()
    base = synthesize_tile(spec["base"], resolution=1000.0, relief=3000.0, seed=SEED).tile
    site = (spec["base"] * 500.0, spec["base"] * 500.0)
    # about lunar equilibrium: N(>= 1 m) ~ 1e5 per km^2, k = -2
    pop = Population(dmin=1.0, dmax=20000.0, density=1e5, max_age=3.5) if spec["craters"] \
        else None
    rss0 = peak_rss()
    builds, totals = [], []
    for i in range(spec["repeat"]):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            stack = build_stack(base, site, levels=spec["levels"], layer_size=spec["layer"],
                                seed=SEED, population=pop)
            builds.append(time.perf_counter() - t0)
            write_stack(stack, Path(tmp) / "stack")
            totals.append(time.perf_counter() - t0)
        n = len(stack.catalog)
        finest = stack.tiles[-1].resolution
        del stack
        log(f"  enhance run {i + 1}: build {builds[-1]:.2f} s, with writing {totals[-1]:.2f} s, "
            f"{n} craters")
    return dict(warmup_s=warm, base=spec["base"], levels=spec["levels"],
                layer_size=spec["layer"], finest_resolution_m=finest, n_craters=n,
                build=summary(builds), build_and_write=summary(totals),
                peak_rss_bytes=peak_rss(), peak_rss_before_bytes=rss0)


def child_fill(spec):
    import numpy as np

    # GDAL's inverse-distance fill (rasterio.fill) is the independent baseline measured
    # against, so this benchmark imports rasterio beside terrain/io.py on purpose
    from rasterio.fill import fillnodata

    from terrain.fractal.gapfill import fill_gaps
    from terrain.fractal.synthetic import synthesize_tile

    warm = warm_up()
    size = spec["size"]
    tile = synthesize_tile(size, resolution=1.0, relief=40.0, seed=SEED).tile
    rr, cc = np.mgrid[0:size, 0:size]
    radius = (spec["pixels"] / np.pi) ** 0.5
    hole = (rr - size // 2) ** 2 + (cc - size // 2) ** 2 <= radius**2
    h = tile.heights.copy()
    h[hole] = np.nan
    cut = tile.replace(heights=h)
    rss0 = peak_rss()
    ours, gdal = [], []
    for i in range(spec["repeat"]):
        t0 = time.perf_counter()
        result = fill_gaps(cut, seed=SEED)
        ours.append(time.perf_counter() - t0)
        assert np.array_equal(result.tile.heights[~hole], tile.heights[~hole])
        del result
        t0 = time.perf_counter()
        fillnodata(h.copy(), mask=(~hole).astype("uint8"), max_search_distance=2 * radius + 10)
        gdal.append(time.perf_counter() - t0)
        log(f"  fill run {i + 1}: ours {ours[-1]:.2f} s, GDAL IDW {gdal[-1]:.2f} s")
    return dict(warmup_s=warm, unknown_pixels=int(hole.sum()), dem=[size, size],
                wall=summary(ours), gdal_fillnodata=summary(gdal),
                ratio_to_gdal=statistics.median(ours) / statistics.median(gdal),
                peak_rss_bytes=peak_rss(), peak_rss_before_bytes=rss0)


CHILDREN = {"expand": child_expand, "enhance": child_enhance, "fill": child_fill}


# ------------------------------------------------------------------------------ parent


def run_child(spec, timeout=900):
    log(f"{spec['kind']}: starting")
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child",
                           json.dumps(spec)], stdout=subprocess.PIPE, text=True, cwd=ROOT,
                          timeout=timeout, check=False)
    if proc.returncode != 0:
        return {"error": f"child exited with status {proc.returncode}"}
    return json.loads(proc.stdout)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per configuration")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        spec = json.loads(args.child)
        print(json.dumps(CHILDREN[spec["kind"]](spec)))
        return 0
    q = args.quick
    stack = dict(kind="enhance", base=257 if q else 1025, levels=4 if q else 11,
                 layer=257 if q else 1025, repeat=1)
    t0 = time.perf_counter()
    results = {}
    results["expand"] = run_child(dict(kind="expand", size=1025 if q else 4097,
                                       repeat=args.repeat))
    # with and without craters in alternating rounds (its baseline interleaved with it)
    try:
        rounds = run_rounds(__file__, dict(
            enhance=dict(stack, name="enhance", craters=True),
            enhance_no_craters=dict(stack, name="enhance_no_craters", craters=False)),
            1 if q else 2, 1800, log)
        results.update({name: pool(children) for name, children in rounds.items()})
        results["enhance"]["ratio_to_no_craters"] = (
            results["enhance"]["build_and_write"]["median_s"]
            / results["enhance_no_craters"]["build_and_write"]["median_s"])
    except (RuntimeError, subprocess.TimeoutExpired) as exc:
        results["enhance"] = {"error": str(exc)}
    results["fill"] = run_child(dict(kind="fill", size=513 if q else 2049,
                                     pixels=50_000 if q else 1_000_000, repeat=args.repeat))
    targets = None
    if not q and all("error" not in r for r in results.values()):
        targets = dict(
            expand_wall_ok=results["expand"]["wall"]["median_s"] <= 3.0,
            expand_within_15x_copy=results["expand"]["ratio_to_copy"] <= 15.0,
            expand_memory_ok=results["expand"]["peak_rss_bytes"] <= 2 * GiB,
            enhance_wall_ok=results["enhance"]["build_and_write"]["median_s"] <= 60.0,
            fill_well_under_10s=results["fill"]["wall"]["median_s"] <= 5.0,
        )
    print(json.dumps(dict(benchmark="enhance", quick=q, results=results, targets=targets,
                          total_s=time.perf_counter() - t0), indent=2))
    return 0 if all("error" not in r for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
