"""Benchmarks for chunked runs on Dask (terrain.execution.chunked): one JSON document on stdout.

What the issue asks to show, each against a baseline measured in the same run:

* ``throughput``: one 2x fractal expansion of an N^2 DEM (the enhancement's main cost) in
  pixels per second, by the in-memory single-process path (``terrain.fractal.expand.expand``, the
  baseline), chunk by chunk in this process, and on a ``LocalCluster`` of 1 and 2 worker
  processes; peak memory of the in-memory run and of every worker; and the cluster's
  start-up time (paid once per run).
* ``overhead``: the scheduler's cost per chunk: N no-op chunk tasks through the same
  ``map_blocks`` path on the 2-worker cluster, and the Zarr write of an empty chunk.
* ``enhance``: a layer stack (the base and 2 expanded layers as large as the base, craters
  on every layer) built in memory (``terrain.stack.build.build_stack``, the baseline, written as
  GeoTIFFs) and chunk by chunk on a 2-worker ``LocalCluster``
  (``terrain.stack.chunkedlayers.build_stack_chunked``), in stack pixels per second.
* ``out_of_core`` (full run only): a 16385^2 DEM synthesised into Zarr, expanded once to
  32769^2 (1.07e9 pixels) on 2 workers and converted into a COG, with the peak memory of the
  whole process tree (sampled) and the COG's georeferencing read back through GDAL.

Every configuration runs in its own child process, one per round, the configurations of a
comparison alternating between rounds (baseline first, then the reverse order, and so on);
each reports the median over its rounds (5 for the throughput, 3 for the rest). A worker's
peak memory is read inside the worker process (its own high-water mark, not the
``ru_maxrss`` it inherits from its parent). Usage::

    .venv/bin/python benchmarks/bench_dask.py            # full benchmark (~15 minutes;
                                                         # chunks of the default side)
    .venv/bin/python benchmarks/bench_dask.py --quick    # 513^2, one round, no cluster1

Progress goes to stderr. Timings taken on a shared machine vary; compare ratios.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from _common import logger, machine_facts, peak_rss_bytes, run_rounds, summary
from _common import run_child as _run_child

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-dask")

#: Out-of-core target of the issue: 16385^2 -> 32769^2 with peak memory under 4 GB.
OOC_SIZE = 16385
OOC_TARGET_BYTES = 4 * 10**9
SEED = 14


def _input(path: Path, size: int, chunk: int, workers: int | None = None):
    """A synthetic size^2 DEM at 8 m written as Zarr (chunked, so any size fits)."""
    from terrain.execution.chunked import SynthSource, dask_client, run

    with dask_client(workers) as client:
        return run(SynthSource(size, resolution=8.0, relief=200.0, seed=SEED), path,
                   chunk=chunk, client=client)


def _warm_up() -> None:
    """Compile (or load numba's cache of) the kernels this process runs, on a tiny stack.

    A cluster's workers are new processes in every run: the throughput children run this
    on every worker (``client.run``) before the timed run and report its time apart
    (``worker_warm_up_s``), a fixed cost per worker and run, like the cluster's start.
    """
    from terrain.craters.population import Population
    from terrain.fractal.expand import expand
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack

    tile = synthesize_tile(33, resolution=8.0, relief=20.0, seed=1).tile
    expand(tile, 1, seed=1)
    build_stack(tile, (128.0, 128.0), levels=1, layer_size=17, seed=1,
                population=Population(dmin=16.0, dmax=64.0, density=2000.0))


def child_throughput(spec):
    import numpy as np

    from terrain.core.tile import DEMTile
    from terrain.execution.chunked import (
        ExpandSource,
        dask_client,
        estimate_parameters,
        open_reader,
        run,
    )
    from terrain.fractal.expand import expand

    work = Path(spec["dir"])
    src = work / "in.zarr"
    reader = open_reader(src)
    params = estimate_parameters(reader)
    mode = spec["mode"]
    _warm_up()
    times = []
    extra = {}
    for k in range(spec["repeat"]):
        out = work / f"{mode}-{k}.zarr"
        if mode == "memory":
            h, v = reader.read()
            tile = DEMTile(h, v, reader.transform, reader.crs)
            t0 = time.perf_counter()
            e = expand(tile, 1, seed=SEED, params=params)
            times.append(time.perf_counter() - t0)
            pixels = e.heights.size
            del e, tile, h, v
            continue
        workers = None if mode == "inprocess" else spec["workers"]
        t0 = time.perf_counter()
        with dask_client(workers) as client:
            started = time.perf_counter() - t0
            if client is not None:
                t1 = time.perf_counter()
                client.run(_warm_up)
                extra["worker_warm_up_s"] = time.perf_counter() - t1
            report = run(ExpandSource(reader, 1, SEED, params), out, chunk=spec["chunk"],
                         client=client)
            if client is not None:
                extra["worker_peak_rss_bytes"] = worker_peak_rss(client)
        times.append(report.seconds)
        extra.setdefault("worker_s_per_chunk_runs", []).append(report.seconds_per_chunk)
        extra["cluster_start_s"] = started
        pixels = report.pixels
        extra["chunks"] = report.total
        shutil.rmtree(out)
    med = float(np.median(times))
    if "worker_s_per_chunk_runs" in extra:
        extra["worker_s_per_chunk"] = float(np.median(extra["worker_s_per_chunk_runs"]))
    return dict(summary(times), pixels=pixels, pixels_per_s=pixels / med,
                peak_rss_bytes=peak_rss_bytes(), **extra)


def child_overhead(spec):
    import dask.array as da
    import numpy as np
    from dask.distributed import as_completed

    from terrain.core.zarrstore import ZarrDEM
    from terrain.execution.chunked import dask_client

    n = spec["tasks"]

    def noop(block_info=None):
        return np.zeros((1, 1), np.int64)

    with dask_client(2) as client:
        arr = da.map_blocks(noop, dtype=np.int64, chunks=((1,) * n, (1,)),
                            meta=np.empty((0, 0), np.int64))
        tasks = arr.to_delayed().ravel().tolist()
        t0 = time.perf_counter()
        for f in as_completed(client.compute(tasks)):
            f.result()
        per_task = (time.perf_counter() - t0) / n
    from affine import Affine

    store = ZarrDEM.create(Path(spec["dir"]) / "overhead.zarr", (spec["chunk"] * 4,) * 2,
                           spec["chunk"], transform=Affine(1, 0, 0, 0, -1, 0), crs=None,
                           nodata=float("nan"), metadata={}, plan={})
    block = np.zeros((spec["chunk"], spec["chunk"]), np.float32)
    t0 = time.perf_counter()
    for j in range(4):
        store.write_chunk(0, j, block)
    write = (time.perf_counter() - t0) / 4
    return dict(tasks=n, scheduler_s_per_chunk=per_task, zarr_write_s_per_chunk=write,
                chunk=spec["chunk"])


def child_enhance(spec):
    import numpy as np

    from terrain.craters.population import Population
    from terrain.execution.chunked import dask_client, open_reader
    from terrain.stack.build import build_stack
    from terrain.stack.chunkedlayers import build_stack_chunked
    from terrain.stack.store import write_stack

    work = Path(spec["dir"])
    reader = open_reader(work / "in.zarr")
    _warm_up()
    ny, nx = reader.shape
    site = reader.transform @ (nx / 2, ny / 2)
    pop = Population(dmin=16.0, dmax=400.0, density=200.0)
    args = dict(levels=2, layer_size=spec["layer_size"], seed=SEED, population=pop)
    times: list[float] = []
    extra: dict = {}
    for k in range(spec["repeat"]):
        out = work / f"stack-{spec['mode']}-{k}"
        if spec["mode"] == "memory":
            from terrain.io import read_dem

            t0 = time.perf_counter()
            stack = build_stack(read_dem(work / "in.zarr"), site, **args)
            write_stack(stack, out)
            times.append(time.perf_counter() - t0)
            pixels = sum(t.heights.size for t in stack.tiles)
            del stack
        else:
            with dask_client(spec["workers"]) as client:
                t0 = time.perf_counter()
                result = build_stack_chunked(reader, out, site, chunk=spec["chunk"],
                                             client=client, **args)
                times.append(time.perf_counter() - t0)
                extra["worker_peak_rss_bytes"] = worker_peak_rss(client)
            pixels = ny * nx + 2 * spec["layer_size"] ** 2
            assert result["craters"] > 0
        shutil.rmtree(out)
    med = float(np.median(times))
    return dict(summary(times), pixels=pixels, pixels_per_s=pixels / med,
                peak_rss_bytes=peak_rss_bytes(), **extra)


def worker_peak_rss(client) -> list[int]:
    """Every worker's own peak RSS in bytes, read in the worker process itself, sorted.

    ``worker_memory`` travels by value (the workers need not import this folder) and reads
    the worker's own high-water mark: ``ru_maxrss`` would give the parent's peak, which a
    freshly started worker process inherits. Each answer carries the process id it was read
    in, checked to be a worker's and not this process's.
    """
    import os

    import _common
    import cloudpickle

    cloudpickle.register_pickle_by_value(_common)
    try:
        peaks = client.run(_common.worker_memory)
    finally:
        cloudpickle.unregister_pickle_by_value(_common)
    pids = [v["pid"] for v in peaks.values()]
    if os.getpid() in pids or len(set(pids)) != len(pids):
        raise RuntimeError(f"worker memory was not read in the workers' own processes "
                           f"(parent {os.getpid()}, workers {pids})")
    return sorted(int(v["peak_rss_bytes"]) for v in peaks.values())


def _pooled(children: list[dict]) -> dict:
    """One configuration's children (one per round) as one record: times pooled, peaks maxed."""
    import numpy as np

    times = [t for c in children for t in c["runs_s"]]
    first = children[0]
    out = dict(first, **summary(times), children=len(children),
               peak_rss_bytes=max(c["peak_rss_bytes"] for c in children))
    out["pixels_per_s"] = first["pixels"] / out["median_s"]
    if "worker_peak_rss_bytes" in first:  # the k-th largest worker's, largest over rounds
        out["worker_peak_rss_bytes"] = [int(v) for v in np.max(
            [c["worker_peak_rss_bytes"] for c in children], axis=0)]
    if "worker_s_per_chunk_runs" in first:
        runs = [t for c in children for t in c["worker_s_per_chunk_runs"]]
        out["worker_s_per_chunk_runs"] = runs
        out["worker_s_per_chunk"] = float(np.median(runs))
    for key in ("cluster_start_s", "worker_warm_up_s"):
        if key in first:
            out[key] = float(np.median([c[key] for c in children]))
    return out


def _tree_rss(pid):
    import psutil

    try:
        proc = psutil.Process(pid)
        procs = [proc, *proc.children(recursive=True)]
    except psutil.NoSuchProcess:
        return 0
    total = 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.NoSuchProcess:
            pass
    return total


def _run_sampled(cmd, cwd):
    """Run a command, sampling the summed RSS of its process tree every 0.2 s."""
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    peak = [0]
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            peak[0] = max(peak[0], _tree_rss(proc.pid))
            time.sleep(0.2)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    t0 = time.perf_counter()
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    stop.set()
    thread.join()
    if proc.returncode != 0:
        raise RuntimeError(f"{cmd} failed: {err.strip().splitlines()[-1:]}")
    return wall, peak[0], err.strip().splitlines()


def out_of_core(work: Path, size: int, chunk: int) -> dict:
    from terrain.io import raster_layout

    exe = str(Path(sys.executable).with_name("craterscape"))
    src, out, cog = work / "ooc-in.zarr", work / "ooc-out.zarr", work / "ooc-out.tif"
    free = shutil.disk_usage(work).free
    need = (size * 2) ** 2 * 4 * 4
    if free < need:
        return dict(skipped=f"needs about {need / 1e9:.1f} GB of disk, {free / 1e9:.1f} free")
    log(f"out of core: synthesising {size}^2 into Zarr")
    synth_wall, synth_peak, _ = _run_sampled(
        [exe, "terrain", "synth", "--size", str(size), "--resolution", "8", "--relief", "200",
         "--seed", str(SEED), "-o", str(src), "--workers", "2", "--chunk", str(chunk)], ROOT)
    log(f"out of core: expanding to {2 * size - 1}^2 and converting to a COG")
    wall, peak, lines = _run_sampled(
        [exe, "terrain", "expand", str(src), "--times", "1", "--seed", str(SEED),
         "-o", str(out), "--workers", "2", "--chunk", str(chunk), "--cog", str(cog)], ROOT)
    geo = raster_layout(cog)
    expected = [4.0, 0.0, 4.0 - 2.0, 0.0, -4.0, 8.0 * size - 4.0 + 2.0]
    result = dict(size_in=size, size_out=2 * size - 1, chunk=chunk, workers=2,
                  synth_wall_s=synth_wall, synth_peak_tree_rss_bytes=synth_peak,
                  expand_and_cog_wall_s=wall, peak_tree_rss_bytes=peak,
                  target_peak_bytes=OOC_TARGET_BYTES, meets_target=peak < OOC_TARGET_BYTES,
                  pixels=(2 * size - 1) ** 2, cog=geo, cog_bytes=cog.stat().st_size,
                  expected_transform=expected,
                  georeferencing_ok=(geo["width"] == 2 * size - 1
                                     and all(abs(a - b) < 1e-9 for a, b in
                                             zip(geo["transform"], expected, strict=True))),
                  messages=lines[-3:])
    for p in (src, out):
        shutil.rmtree(p, ignore_errors=True)
    cog.unlink(missing_ok=True)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="513^2 in one round (smoke test)")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--skip-out-of-core", action="store_true",
                        help="full run without the 16385^2 out-of-core configuration")
    parser.add_argument("--chunk", type=int, default=None,
                        help="chunk side of the full run (default: the library's, "
                             "terrain.execution.chunked.DEFAULT_CHUNK)")
    parser.add_argument("--throughput-only", action="store_true",
                        help="the expansion's throughput alone (memory, in-process, 1 and 2 "
                             "workers), no overhead, stack or out-of-core parts")
    args = parser.parse_args(argv)
    if args.child:
        spec = json.loads(args.child)
        result = {"throughput": child_throughput, "overhead": child_overhead,
                  "enhance": child_enhance}[spec["kind"]](spec)
        print(json.dumps(result))
        return 0

    # --quick is a smoke test: one round, no 1-worker cluster (a cluster's start costs seconds)
    from terrain.execution.chunked import DEFAULT_CHUNK

    size, chunk, rounds = (513, 128, 1) if args.quick else (4097, args.chunk or DEFAULT_CHUNK, 3)
    # Runs of 1 and 2 workers each take a second or two and differ by 10-20 % from one fresh
    # cluster to the next on this machine: the throughput comparison takes 5 rounds.
    throughput_rounds = 1 if args.quick else 5
    work = Path(tempfile.mkdtemp(prefix="bench-dask-"))
    results = dict(machine=machine_facts(note="shared machine: other jobs ran concurrently"))
    try:
        log(f"input: {size}^2 synthetic DEM")
        _input(work / "in.zarr", size, chunk)
        specs = {mode: dict(kind="throughput", name=mode, mode=mode, workers=workers,
                            chunk=chunk, repeat=1, dir=str(work))
                 for mode, workers in (("memory", None), ("inprocess", None), ("cluster1", 1),
                                       ("cluster2", 2))
                 if not (args.quick and mode == "cluster1")}  # cluster2 runs the same code
        runs = {mode: _pooled(children) for mode, children in
                run_rounds(__file__, specs, throughput_rounds, 3600, log).items()}
        base = runs["memory"]["pixels_per_s"]
        results["throughput"] = dict(
            input_size=size, output_size=2 * size - 1, chunk=chunk, runs=runs,
            baseline="memory",
            speedup_vs_memory={k: v["pixels_per_s"] / base for k, v in runs.items()},
            per_chunk_compute_s=runs["inprocess"]["median_s"] / runs["inprocess"]["chunks"],
            worker_s_per_chunk={k: v.get("worker_s_per_chunk") for k, v in runs.items()},
            two_vs_one_worker=(runs["cluster2"]["pixels_per_s"] / runs["cluster1"]["pixels_per_s"]
                               if "cluster1" in runs else None))
        if args.throughput_only:
            return _print(results)
        results["overhead"] = _run_child(__file__, dict(
            kind="overhead", name="overhead", tasks=200, chunk=chunk, repeat=1, dir=str(work)),
            600, log)
        specs = {mode: dict(kind="enhance", name=f"enhance-{mode}", mode=mode, workers=workers,
                            chunk=chunk, repeat=1, layer_size=size, dir=str(work))
                 for mode, workers in (("memory", None), ("cluster2", 2))}
        stack = {mode: _pooled(children) for mode, children in
                 run_rounds(__file__, specs, rounds, 3600, log).items()}
        results["enhance"] = dict(
            base_size=size, layer_size=size, levels=2, chunk=chunk, runs=stack,
            baseline="memory",
            speedup_vs_memory=stack["cluster2"]["pixels_per_s"] / stack["memory"]["pixels_per_s"])
        if not args.quick and not args.skip_out_of_core:
            results["out_of_core"] = out_of_core(work, OOC_SIZE, 2048)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return _print(results)


def _print(results: dict) -> int:
    print(json.dumps(results, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
