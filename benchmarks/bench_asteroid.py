"""Benchmarks for craterscape's asteroid models: one JSON document on stdout.

Targets (the asteroid issue), each also <= 6 GB peak memory:

* M = 1000 (6,000,002 vertices) with a 10-octave Perlin base: <= 30 s;
* the two-phase faulting preset (fig9-faulting: 1000 faults up to 5 m, three 20 m smoothing
  passes, 20,000 faults up to 0.03 m, stretch 2 in x) at M = 400: <= 20 s;
* 10,000 craters at M = 1000: <= 120 s.

Every configuration runs in its own child process (this script re-invoked with ``--child``),
so that the peak resident set size of each is its own. A child first warms up at a tiny
magnitude (numba compiles, or loads its on-disk cache), then times one call. The
configurations run in ``--repeat`` rounds, alternating (baseline first, then the reverse
order, and so on), and each reports median, min and max over its rounds. The baseline,
interleaved with the others, is building the M = 1000 mesh itself (unit directions and the
face array): what any job at that size pays before its own work.

Usage::

    .venv/bin/python benchmarks/bench_asteroid.py            # full (a few minutes)
    .venv/bin/python benchmarks/bench_asteroid.py --quick    # small magnitudes (seconds)

Progress goes to stderr; the exit status is 0 when every child ran (targets met or not).
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
log = logger("bench-asteroid")

#: Targets from the issue.
TARGET_PERLIN_S = 30.0
TARGET_FAULTING_S = 20.0
TARGET_CRATERS_S = 120.0
TARGET_PEAK_BYTES = 6 * 1000**3
#: Fixed parameters.
SEED = 2014
PERLIN_RADIUS = 1000.0
CRATER_RADIUS = 1000.0
CRATER_COUNT = 10_000
CRATER_DMAX = 250.0


# ----------------------------------------------------------------------------------------
# child side


def _perlin():
    from asteroid.noise import PerlinNoise

    return PerlinNoise(octaves=10, frequency=1.2, persistence=0.5, lacunarity=2.1,
                       amplitude=0.25)


def _job(spec: dict):
    """(callable, description) of one configuration's timed call."""
    from asteroid.body import Body, Stretch
    from asteroid.craters import add_craters, sample_craters
    from asteroid.faulting import FIG8_FAULTING
    from asteroid.sphere import SphereMesh
    from terrain.craters.population import Population

    m = spec["magnitude"]
    kind = spec["kind"]
    if kind == "mesh":
        def call():
            mesh = SphereMesh(m)
            d = mesh.directions()
            f = mesh.faces()
            return dict(vertices=len(d), faces=len(f))
        return call
    if kind == "perlin":
        def call():
            mesh = SphereMesh(m)
            r = _perlin().radii(mesh, PERLIN_RADIUS, seed=SEED)
            return dict(vertices=len(r), radius_min_m=float(r.min()),
                        radius_max_m=float(r.max()))
        return call
    if kind == "faulting":
        def call():
            mesh = SphereMesh(m)
            r = FIG8_FAULTING.radii(mesh, 100.0, seed=SEED, stretch=Stretch(2.0, 1.0, 1.0))
            return dict(vertices=len(r), radius_min_m=float(r.min()),
                        radius_max_m=float(r.max()))
        return call
    if kind == "craters":
        mesh = SphereMesh(m)
        base = Body(mesh, CRATER_RADIUS, _perlin().radii(mesh, CRATER_RADIUS, seed=SEED))
        area = base.area()
        dmin = 4.0 * mesh.mean_spacing * CRATER_RADIUS
        count = spec["craters"]
        k = -2.0
        # density (per km^2, D >= dmin) giving `count` craters in [dmin, dmax) on this area
        density = count / (area / 1e6) / (1.0 - (CRATER_DMAX / dmin) ** k)
        population = Population(dmin=dmin, dmax=CRATER_DMAX, density=density, sfd_exponent=k)
        craters = sample_craters(population, base, seed=SEED)

        def call():
            result = add_craters(base, craters, seed=SEED)
            return dict(vertices=mesh.n_vertices, craters=len(craters),
                        applied=int(result.catalog.applied.sum()), dmin_m=dmin,
                        dmax_m=CRATER_DMAX)
        return call
    raise ValueError(f"unknown benchmark kind {kind!r}")


#: The kernels each configuration's call runs, warmed up before it is timed.
WARM_UP = {"mesh": ("mesh",), "perlin": ("mesh", "perlin"), "faulting": ("mesh", "faulting"),
           "craters": ("mesh", "perlin", "craters")}


def _warm_up(kind: str) -> float:
    """Compile (or load from numba's cache) the kernels of ``kind``'s call, at small M."""
    t0 = time.perf_counter()
    for part in WARM_UP[kind]:
        if part == "craters":
            _job(dict(kind="craters", magnitude=64, craters=20))()
        else:
            _job(dict(kind=part, magnitude=6))()
    return time.perf_counter() - t0


def child(spec: dict) -> dict:
    warmup_s = _warm_up(spec["kind"])
    rss_after_warmup = peak_rss_bytes()
    t0 = time.perf_counter()
    call = _job(spec)
    setup_s = time.perf_counter() - t0
    times, info = [], None
    for i in range(spec["repeat"]):
        t0 = time.perf_counter()
        info = call()
        times.append(time.perf_counter() - t0)
        log(f"  {spec['name']} run {i + 1}/{spec['repeat']}: {times[-1]:.3f} s")
    peak = peak_rss_bytes()
    return dict(warmup_s=warmup_s, setup_s=setup_s, wall=summary(times), result=info,
                peak_rss_bytes=peak, peak_rss_after_warmup_bytes=rss_after_warmup,
                peak_rss_mib=round(peak / 1024**2, 1))


# ----------------------------------------------------------------------------------------
# parent side


def benchmark(quick: bool, repeat: int, timeout: float) -> dict:
    big = 200 if quick else 1000
    faulting_m = 100 if quick else 400
    n_craters = 1000 if quick else CRATER_COUNT
    common = dict(repeat=1)
    specs = {
        "mesh_baseline": dict(common, name="mesh_baseline", kind="mesh", magnitude=big),
        "perlin": dict(common, name="perlin", kind="perlin", magnitude=big),
        "faulting": dict(common, name="faulting", kind="faulting", magnitude=faulting_m),
        "craters": dict(common, name="craters", kind="craters", magnitude=big,
                        craters=n_craters),
    }
    runs = run_rounds(__file__, specs, repeat, timeout, log)
    configs = {name: pool(children) for name, children in runs.items()}

    def flag(ok: bool) -> bool | None:
        return None if quick else bool(ok)

    med = {k: v["wall"]["median_s"] for k, v in configs.items()}
    peak = {k: v["peak_rss_bytes"] for k, v in configs.items()}
    craters = configs["craters"]["result"]
    targets = dict(
        applies=not quick,
        perlin_s_max=TARGET_PERLIN_S, faulting_s_max=TARGET_FAULTING_S,
        craters_s_max=TARGET_CRATERS_S, peak_bytes_max=TARGET_PEAK_BYTES,
        perlin_ok=flag(med["perlin"] <= TARGET_PERLIN_S),
        faulting_ok=flag(med["faulting"] <= TARGET_FAULTING_S),
        craters_ok=flag(med["craters"] <= TARGET_CRATERS_S),
        peak_memory_ok=flag(max(peak.values()) <= TARGET_PEAK_BYTES),
    )
    targets["all_ok"] = None if quick else all(
        targets[k] for k in ("perlin_ok", "faulting_ok", "craters_ok", "peak_memory_ok"))
    return dict(
        benchmark="craterscape asteroid models",
        mode="quick" if quick else "full",
        machine=machine_facts(),
        parameters=dict(magnitude=big, vertices=6 * big * big + 2, faulting_magnitude=faulting_m,
                        perlin="10 octaves, frequency 1.2, persistence 0.5, lacunarity 2.1, "
                               "amplitude 0.25 R", perlin_radius_m=PERLIN_RADIUS,
                        faulting="fig9-faulting preset, R = 100 m, stretch 2,1,1",
                        craters=n_craters, crater_radius_m=CRATER_RADIUS,
                        crater_dmax_m=CRATER_DMAX, crater_model="CraterModel() (roughness on)",
                        crater_base="the Perlin base above", seed=SEED, repeat=repeat,
                        timer="time.perf_counter",
                        memory="peak RSS (VmHWM) of a child process per configuration and round, "
                               "largest over rounds"),
        configs=configs,
        derived=dict(
            perlin_over_mesh_baseline=med["perlin"] / med["mesh_baseline"],
            perlin_ns_per_vertex_octave=med["perlin"] / (6 * big * big + 2) / 10 * 1e9,
            faulting_ns_per_vertex_fault=med["faulting"] / (6 * faulting_m**2 + 2) / 21000 * 1e9,
            craters_ms_per_crater=med["craters"] / max(1, craters["craters"]) * 1e3,
            peak_rss_mib={k: round(v / 1024**2, 1) for k, v in peak.items()},
        ),
        targets=targets,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--quick", action="store_true",
                        help="M = 200 / 100 and 1,000 craters (smoke test, seconds)")
    parser.add_argument("--repeat", type=int, default=None,
                        help="rounds: timed calls per configuration (default 3, 1 with --quick)")
    parser.add_argument("--timeout", type=float, default=1800.0,
                        help="seconds allowed per child process (default 1800)")
    parser.add_argument("--child", metavar="SPEC", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        json.dump(child(json.loads(args.child)), sys.stdout)
        sys.stdout.write("\n")
        return 0
    if args.repeat is None:
        args.repeat = 1 if args.quick else 3  # --quick: a smoke test
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    t0 = time.perf_counter()
    try:
        doc = benchmark(args.quick, args.repeat, args.timeout)
    except (RuntimeError, subprocess.TimeoutExpired, json.JSONDecodeError) as exc:
        log(f"benchmark failed: {exc}")
        json.dump(dict(error=str(exc), machine=machine_facts()), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return 1
    doc["total_benchmark_s"] = time.perf_counter() - t0
    log(f"all done in {doc['total_benchmark_s']:.1f} s")
    json.dump(doc, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
