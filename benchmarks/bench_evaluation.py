"""Benchmarks for craterscape's evaluation stage: one JSON document on stdout.

Every configuration runs in its own child process (this script re-invoked with ``--child``),
so that the peak resident set size of each is its own; a child warms up first (numba compiles
its kernels, or loads them from its on-disk cache), then times its call and its baseline
alternately (A B, B A, A B ...), so that both see the same load, and reports median, min and
max wall time of each; peak memory is read after the first call, before any baseline ran.
Each compares against a baseline measured in the same run:

* ``slope``: Horn slope of an N x N float32 DEM (RMD terrain), ours (compute only, and read +
  compute + write a GeoTIFF) against the ``gdaldem slope -alg Horn`` binary on the same file
  (process start, read, compute, write), both writing what ``write_dem`` writes (tiled,
  DEFLATE) and gdaldem's plain default; the child also checks the two agree (max difference).
* ``spectrum``: radially averaged power spectrum and Hurst fit of an RMD tile (F = 2.3, so
  H = 0.7) against a bare ``rfft2`` of the same array (the floor any FFT-based spectrum pays).
* ``gravity``: Werner-Scheeres polyhedron attraction at N points of a body of F triangles
  against a point mass at the same points (the naive model), with the angle between the two
  fields on the surface (why the polyhedron is worth its cost).
* ``mesh_slopes``: per-vertex radial and gravitational slopes of a whole synthetic body
  (asteroid build: coarsening, gravity at every vertex, 3 degree cap averages); the baseline
  is the radial-only run (no gravity).
* ``tracking``: Harris + pyramidal LK with forward-backward checks and replenishment, then
  scoring against truth, through a rendered planar descent (the test suite's analytic
  renderer), against bare OpenCV (detect once, forward LK only, no scoring).

Usage::

    .venv/bin/python benchmarks/bench_evaluation.py            # full sizes (a few minutes)
    .venv/bin/python benchmarks/bench_evaluation.py --quick    # small sizes (seconds)

Progress goes to stderr; the exit status is 0 when every child ran.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import alternate, logger, peak_rss_bytes
from _common import machine_facts as _machine_facts
from _common import run_child as _run_child

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench")


def run_child(spec: dict, timeout: float) -> dict:
    out = _run_child(__file__, spec, timeout, log)
    out["peak_rss_mib"] = round(out["peak_rss_bytes"] / 1024**2, 1)
    log(f"{spec['name']}: done in {out.pop('_child_s'):.1f} s")
    return out


def machine_facts() -> dict:
    return _machine_facts(
        load_average=list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        gdaldem=shutil.which("gdaldem"))


# ----------------------------------------------------------------------------------------
# children


def child_slope(spec: dict) -> dict:
    import numpy as np

    from evaluation.slope import horn, slope_tile
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.io import read_dem, write_dem

    n = spec["size"]
    tmp = Path(tempfile.mkdtemp(prefix="bench-eval-"))
    try:
        dem = synthesize_tile(n, resolution=1.0, fractal_dimension=2.2, relief=60.0,
                              seed=1).tile
        path = tmp / "dem.tif"
        write_dem(dem, path)
        horn(dem)  # warm-up
        rss0 = peak_rss_bytes()

        def end_to_end():
            write_dem(slope_tile(read_dem(path)), tmp / "ours.tif")

        calls = dict(ours_compute=lambda: horn(dem), ours_read_compute_write=end_to_end)
        exe = shutil.which("gdaldem")
        if exe:
            def gdal(out, *options):
                def call():
                    subprocess.run([exe, "slope", "-alg", "Horn", "-q", *options, str(path),
                                    str(tmp / out)], check=True)
                return call

            # as write_dem writes (tiled, DEFLATE, floating-point predictor), and gdaldem's
            # default (plain, uncompressed GeoTIFF)
            calls["gdaldem"] = gdal("gdal.tif", "-co", "TILED=YES", "-co", "COMPRESS=DEFLATE",
                                    "-co", "PREDICTOR=3")
            calls["gdaldem_uncompressed"] = gdal("gdal-plain.tif")
        timed = alternate(calls, spec["repeat"])
        peak = timed.peak_after_first_bytes
        slope, _ = timed.results["ours_compute"]
        result = dict(pixels=n * n, **timed.timings, peak_rss_bytes=peak,
                      peak_rss_increment_bytes=peak - rss0)
        if exe:
            g = read_dem(tmp / "gdal.tif").heights  # gdaldem's nodata as NaN
            result.update(max_abs_difference_deg=float(np.nanmax(np.abs(g - slope))),
                          same_nodata_pixels=bool(np.array_equal(np.isnan(g),
                                                                 np.isnan(slope))))
        else:
            result["gdaldem"] = None
        return result
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def child_spectrum(spec: dict) -> dict:
    import numpy as np

    from evaluation.spectrum import fit_hurst, radial_spectrum
    from terrain.fractal.synthetic import synthesize_tile

    n = spec["size"]
    # RMD with fractal dimension 2.3: Hurst exponent 0.7 (F = 3 - H)
    dem = synthesize_tile(n, resolution=2.0, fractal_dimension=2.3, relief=50.0,
                          seed=2).tile
    fit_hurst(radial_spectrum(dem))  # warm-up
    z = dem.heights.astype(np.float64)
    rss0 = peak_rss_bytes()
    timed = alternate(dict(ours=lambda: fit_hurst(radial_spectrum(dem)),
                           bare_rfft2=lambda: np.fft.rfft2(z)), spec["repeat"])
    peak = timed.peak_after_first_bytes
    return dict(pixels=n * n, **timed.timings, hurst_nominal_rmd=0.7,
                hurst_estimated=timed.results["ours"].hurst,
                peak_rss_bytes=peak, peak_rss_increment_bytes=peak - rss0)


def _ellipsoid(subdivisions: int):
    import numpy as np
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(s.vertices) * [17000.0, 6000.0, 5500.0], np.asarray(s.faces)


def child_gravity(spec: dict) -> dict:
    import numba
    import numpy as np

    from evaluation.gravity import GRAVITATIONAL_CONSTANT, Polyhedron, coarsen

    v, f = _ellipsoid(7)
    cv, cf = coarsen(v, f, spec["faces"])
    body = Polyhedron.build(cv, cf, 2670.0)
    pts = v[np.linspace(0, len(v) - 1, spec["points"]).astype(np.int64)] * 1.0005
    body.field(pts[:8])  # warm-up (compile or load the cache)
    gm = GRAVITATIONAL_CONSTANT * body.mass

    def point_mass():
        r = np.linalg.norm(pts, axis=1)
        return -gm * pts / r[:, None] ** 3

    rss0 = peak_rss_bytes()
    timed = alternate(dict(ours=lambda: body.field(pts), point_mass=point_mass),
                      spec["repeat"])
    peak = timed.peak_after_first_bytes
    ours, base = timed.timings["ours"], timed.timings["point_mass"]
    _, g = timed.results["ours"]
    gp = timed.results["point_mass"]
    cosang = np.einsum("ij,ij->i", g, gp) / (np.linalg.norm(g, axis=1)
                                             * np.linalg.norm(gp, axis=1))
    angle = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    ns = ours["median_s"] / (len(pts) * len(body.faces)) * 1e9
    return dict(points=len(pts), faces=int(len(body.faces)), ours=ours, point_mass=base,
                ns_per_point_face=ns, numba_threads=numba.get_num_threads(),
                point_mass_direction_error_deg=dict(median=float(np.median(angle)),
                                                    max=float(angle.max())),
                peak_rss_bytes=peak, peak_rss_increment_bytes=peak - rss0)


def child_mesh_slopes(spec: dict) -> dict:
    from asteroid.build import build
    from asteroid.recipe import Recipe
    from evaluation.meshslope import Spin, mesh_slopes

    recipe = Recipe.from_dict(dict(magnitude=spec["magnitude"], radius=6000.0, seed=3,
                                   base="perlin", stretch=[2.6, 1.0, 0.95],
                                   perlin=dict(amplitude=0.12), craters=dict(c=0.5, k=-2.0)))
    body = build(recipe).body
    v, f = body.vertices(), body.mesh.faces()
    small = build(Recipe(magnitude=8, radius=500.0, seed=1, base="perlin")).body
    mesh_slopes(small.vertices(), small.mesh.faces(), coarse_faces=200)  # warm-up
    rss0 = peak_rss_bytes()
    timed = alternate(dict(ours=lambda: mesh_slopes(v, f, spin=Spin(5.27),
                                                    coarse_faces=spec["coarse_faces"]),
                           radial_only=lambda: mesh_slopes(v, f, gravity=False)),
                      spec["repeat"])
    peak = timed.peak_after_first_bytes
    r = timed.results["ours"]
    return dict(vertices=len(v), faces=len(f), coarse_faces=r.info["coarse_faces"],
                **timed.timings, gravity_s=r.info["gravity_s"],
                radial_median_deg=r.summary("radial")["p50"],
                gravitational_median_deg=r.summary("gravitational")["p50"],
                peak_rss_bytes=peak, peak_rss_increment_bytes=peak - rss0)


def _planar_module():
    spec = importlib.util.spec_from_file_location(
        "evaluation_test_fixtures", ROOT / "tests" / "evaluation" / "conftest.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def child_tracking(spec: dict) -> dict:
    import cv2
    import numpy as np

    from evaluation.tracking import score, track
    from render.rundir import RunReader

    planar = _planar_module()
    tmp = Path(tempfile.mkdtemp(prefix="bench-eval-"))
    try:
        t0 = time.perf_counter()
        run = planar.write_planar_run(tmp / "run", n_frames=spec["frames"],
                                      width=spec["width"], height=spec["height"])
        render_s = time.perf_counter() - t0
        reader = RunReader(run)
        frames = [reader.image(k) for k in range(len(reader))]
        rss0 = peak_rss_bytes()

        def ours():
            return score(track(reader), reader)

        def bare():
            p = cv2.goodFeaturesToTrack(frames[0], 300, 0.01, 8, useHarrisDetector=True)
            for a, b in zip(frames[:-1], frames[1:], strict=True):
                p, st, _ = cv2.calcOpticalFlowPyrLK(a, b, p, None, winSize=(21, 21),
                                                    maxLevel=3)
                p = p[st.reshape(-1) == 1].reshape(-1, 1, 2)
            return p

        timed = alternate(dict(ours=ours, bare_opencv=bare), spec["repeat"])
        peak = timed.peak_after_first_bytes
        scored = timed.results["ours"]
        e = scored.error_summary()
        return dict(frames=len(frames), width=spec["width"], height=spec["height"],
                    render_s=render_s, **timed.timings,
                    ours_frames_per_s=len(frames) / timed.timings["ours"]["median_s"],
                    tracks=scored.tracks.n_tracks, median_error_px=e["median_px"],
                    outlier_fraction=e["outlier_fraction"],
                    peak_rss_bytes=peak, peak_rss_increment_bytes=peak - rss0,
                    frame_bytes=int(np.asarray(frames[0]).nbytes))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


CHILDREN = dict(slope=child_slope, spectrum=child_spectrum, gravity=child_gravity,
                mesh_slopes=child_mesh_slopes, tracking=child_tracking)


# ----------------------------------------------------------------------------------------
# parent


def benchmark(quick: bool, repeat: int, timeout: float) -> dict:
    sizes = dict(
        slope=dict(size=1025 if quick else 4097),
        spectrum=dict(size=1025 if quick else 4097),
        gravity=dict(points=5000 if quick else 50000, faces=2000 if quick else 4000),
        mesh_slopes=dict(magnitude=40 if quick else 160, coarse_faces=2000 if quick else 4000),
        tracking=dict(frames=12 if quick else 40, width=320 if quick else 640,
                      height=240 if quick else 480),
    )
    results = {}
    for name, spec in sizes.items():
        results[name] = run_child(dict(spec, name=name, repeat=repeat), timeout)
    s = results["slope"]
    if s.get("gdaldem"):
        s["speedup_vs_gdaldem_end_to_end"] = (s["gdaldem"]["median_s"]
                                              / s["ours_read_compute_write"]["median_s"])
    g = results["gravity"]
    g["cost_vs_point_mass"] = g["ours"]["median_s"] / max(g["point_mass"]["median_s"], 1e-12)
    sp = results["spectrum"]
    sp["overhead_vs_bare_fft"] = sp["ours"]["median_s"] / max(sp["bare_rfft2"]["median_s"],
                                                             1e-12)
    t = results["tracking"]
    t["overhead_vs_bare_opencv"] = t["ours"]["median_s"] / max(t["bare_opencv"]["median_s"],
                                                              1e-12)
    m = results["mesh_slopes"]
    m["gravity_share"] = m["gravity_s"] / m["ours"]["median_s"]
    return dict(benchmark="craterscape evaluation", mode="quick" if quick else "full",
                machine=machine_facts(), parameters=dict(sizes=sizes, repeat=repeat,
                                                         timer="time.perf_counter",
                                                         memory="peak RSS (VmHWM) per child, "
                                                                "after its first call"),
                results=results)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (seconds)")
    parser.add_argument("--repeat", type=int, default=3, help="timed calls per configuration")
    parser.add_argument("--timeout", type=float, default=900.0,
                        help="seconds allowed per child process (default 900)")
    parser.add_argument("--child", metavar="SPEC", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        spec = json.loads(args.child)
        json.dump(CHILDREN[spec["name"]](spec), sys.stdout)
        sys.stdout.write("\n")
        return 0
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
