"""Benchmark of a layer stack's build with a terrain preset against today's: one JSON document.

Two configurations build the same nested stack (a synthetic 1 km base with the south-polar
roughness, the demo's expansion roughness, craters from 1 m) in child processes, alternating
in rounds so that the baseline is measured interleaved with what it is compared with:

* ``today``: the Ross/Soderblom degradation, ages uniform over 3.5 Gyr, the demo's crater
  density (N(>=D) = 0.1 D^-2 per m^2), no relaxation;
* ``preset``: the south-polar preset: topographic diffusion, each size's lifetime, the
  production limit at large sizes, craters degraded past visibility dropped, and every layer
  relaxed to the angle of repose, and every level's roughness following the preset's slope
  law (``terrain.stack.slopelaw``) where ``today`` expands with the demo's former fractal
  dimension 2.05 and height scale 0.05;
* ``preset_full96``: the preset relaxed as before its sweeps skipped settled blocks: 96
  Jacobi sweeps, each over every cell (``relax_to_repose`` with one block as large as the
  layer). Its heights are those of the former kernel up to the order each cell sums its
  moves in, but its sweeps cost more: each cell evaluates its eight pairs where the former
  kernel evaluated each pair once, so ``repose_time_ratio`` flatters the skipping; compare
  with the former kernel itself by building with the two commits, interleaved.

Each child reports its wall time (after a warm-up that compiles the numba kernels), its peak
resident set size, the crater count, and each layer's share of cells steeper than the 35 deg
angle of repose outside craters younger than 100 Myr (the check of ``evaluation.validate``,
at most 0.5 % per layer).

Usage::

    .venv/bin/python benchmarks/bench_stack.py            # 257-pixel layers, 10 levels
    .venv/bin/python benchmarks/bench_stack.py --quick    # 65-pixel layers, 6 levels
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from _common import logger, machine_facts, peak_rss_bytes, pool, run_rounds, summary

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-stack")

SEED = 2014


def _stack(spec: dict):
    from terrain.core.presets import preset
    from terrain.fractal.roughness import RoughnessChoice
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stages.dems import crater_model, population, preset_relief, repose
    from terrain.stages.specs import SynthSpec

    size = spec["size"]
    fd, relief = preset_relief(preset("south-polar"), size, 1000.0)
    base = synthesize_tile(size, resolution=1000.0, fractal_dimension=fd, relief=relief,
                           seed=SEED).tile
    if spec["name"] != "today":
        table = dict(terrain="south-polar", dmin=1.0, dmax=4000.0)
    else:
        table = dict(dmin=1.0, dmax=4000.0, density=1e5, max_age=3.5)
    s = SynthSpec.from_mapping(table)
    pop = population(s, resolution=1.0, extent=1e6, warn_small=False)
    x0, y0, x1, y1 = base.bounds
    law = spec["name"] != "today"
    relax = repose(s)
    if spec["name"] == "preset_full96":
        import functools

        import terrain.surface.repose as rp

        relax = rp.Repose(relax.angle_deg, relax.fresh_age_gyr, iterations=96)
        # one block as large as any layer: every sweep visits every cell
        rp.relax_to_repose = functools.partial(rp.relax_to_repose, block=1 << 30)
    return build_stack(base, ((x0 + x1) / 2, (y0 + y1) / 2), levels=spec["levels"],
                       layer_size=size, seed=SEED, population=pop, model=crater_model(s),
                       params=RoughnessChoice() if law else RoughnessChoice(2.05, 0.05),
                       repose=relax, slope_law=preset("south-polar") if law else None)


def steep_old_shares(stack) -> list[float]:
    """Each layer's share of cells steeper than 35 deg outside craters younger than 100 Myr."""
    import numpy as np

    from evaluation.slope import horn_slope
    from evaluation.validate import REPOSE_DEG, young_crater_mask

    shares = []
    for tile in stack.tiles:
        s = horn_slope(tile)
        keep = np.isfinite(s) & ~young_crater_mask(tile, stack.catalog)
        shares.append(float(np.mean(s[keep] > REPOSE_DEG)) if keep.any() else 0.0)
    return shares


def child(spec: dict) -> dict:
    """Build the stack once to warm up, then time one build; peak RSS around it."""
    warm = dict(spec, levels=1)
    _stack(warm)
    t0 = time.perf_counter()
    stack = _stack(spec)
    wall = time.perf_counter() - t0
    return dict(wall=summary([wall]), craters=len(stack.catalog),
                peak_rss_bytes=peak_rss_bytes(), steep_old_share=steep_old_shares(stack))


def benchmark(quick: bool, repeat: int, timeout: float) -> dict:
    """Run both configurations and compare."""
    common = dict(size=65 if quick else 257, levels=6 if quick else 10, repeat=1)
    specs = {name: dict(common, name=name) for name in ("today", "preset", "preset_full96")}
    runs = run_rounds(__file__, specs, repeat, timeout, log)
    today, preset, full96 = (pool(runs[name]) for name in specs)
    return dict(
        machine=machine_facts(), config=common, today=today, preset=preset,
        preset_full96=full96,
        time_ratio=preset["wall"]["median_s"] / today["wall"]["median_s"],
        peak_ratio=preset["peak_rss_bytes"] / today["peak_rss_bytes"],
        repose_time_ratio=preset["wall"]["median_s"] / full96["wall"]["median_s"],
        most_steep_old_share=dict(preset=max(preset["steep_old_share"]),
                                  preset_full96=max(full96["steep_old_share"])))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--quick", action="store_true", help="small stack (smoke test)")
    parser.add_argument("--repeat", type=int, default=None,
                        help="rounds (default 3, 1 with --quick)")
    parser.add_argument("--timeout", type=float, default=1800.0,
                        help="seconds allowed per child process (default 1800)")
    parser.add_argument("--child", metavar="SPEC", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        json.dump(child(json.loads(args.child)), sys.stdout)
        sys.stdout.write("\n")
        return 0
    repeat = args.repeat if args.repeat is not None else (1 if args.quick else 3)
    if repeat < 1:
        parser.error("--repeat must be >= 1")
    t0 = time.perf_counter()
    try:
        doc = benchmark(args.quick, repeat, args.timeout)
    except (RuntimeError, subprocess.TimeoutExpired, json.JSONDecodeError) as exc:
        log(f"benchmark failed: {exc}")
        json.dump(dict(error=str(exc), machine=machine_facts()), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 1
    doc["total_benchmark_s"] = time.perf_counter() - t0
    json.dump(doc, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
