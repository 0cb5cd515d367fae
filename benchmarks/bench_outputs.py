"""Benchmarks for the safe-output machinery (issue 17): one JSON document on stdout.

What safety costs, each against a baseline measured in the same run, the two timed
alternately (A B, B A, ...) so that both see the same load:

* ``write_dem``: writing a 2049^2 DEM the way every command does (temporary file, read back
  and compared, renamed into place) against rasterio writing the same GeoTIFF directly.
  Target: at most 1.6x the direct write (the read-back is what turns a full disk into an
  error instead of a truncated file).
* ``sensor_tiff``: a frame's range (1024^2) and normals (1024^2 x 3) written the way every
  rendered frame writes them (:func:`terrain.io.write_float_tiff`: uncompressed, safe)
  against rasterio writing the same two TIFFs directly with DEFLATE (an earlier setting, no
  safety); with both files' sizes. Target: at most the direct DEFLATE write.
* ``transaction``: committing four files as one set (journal, renames) against writing the
  same four files one by one with :func:`terrain.core.outputs.atomic_path`. Target: at most 1.5x
  plus 20 ms.
* ``read_stack``: reading a 3-layer stack under the readers' lock against reading the same
  files without it. Target: at most 1.2x plus 5 ms.

Usage::

    .venv/bin/python benchmarks/bench_outputs.py          # full (tens of seconds)
    .venv/bin/python benchmarks/bench_outputs.py --quick  # small sizes, seconds
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from _common import alternate, logger, machine_facts

log = logger("bench-outputs")


def bench_write_dem(folder: Path, size: int, repeat: int) -> dict:
    import numpy as np

    # rasterio itself is the baseline here (a direct GeoTIFF write, none of write_dem's
    # safety), so this benchmark imports it beside terrain/io.py on purpose
    import rasterio
    from rasterio.crs import CRS

    from terrain.fractal.synthetic import synthesize_tile
    from terrain.io import BLOCK_SIZE, write_dem

    tile = synthesize_tile(size, resolution=1.0, relief=30.0, seed=1).tile
    profile = dict(driver="GTiff", dtype="float32", count=1, width=size, height=size,
                   crs=CRS.from_wkt(tile.crs) if tile.crs else None, transform=tile.transform,
                   nodata=tile.nodata, compress="deflate", predictor=3, zlevel=6, tiled=True,
                   blockxsize=BLOCK_SIZE, blockysize=BLOCK_SIZE, BIGTIFF="IF_SAFER")

    def direct():
        with rasterio.open(folder / "direct.tif", "w", **profile) as dst:
            dst.write(np.asarray(tile.heights), 1)

    def safe():
        write_dem(tile, folder / "safe.tif")

    timed = alternate(dict(safe=safe, direct=direct), repeat)
    ours, base = timed.timings["safe"], timed.timings["direct"]
    ratio = timed.ratio("safe", "direct")
    return dict(size=size, safe=ours, baseline_direct=base, ratio=ratio,
                target_ratio=1.6, passed=ratio <= 1.6)


def bench_sensor_tiff(folder: Path, size: int, repeat: int) -> dict:
    import numpy as np

    # the direct DEFLATE write is the baseline, so rasterio is imported here on purpose
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from terrain.io import BLOCK_SIZE, write_float_tiff

    # a range image and world normals like a descent frame's: smooth, NaN off the terrain
    y, x = np.mgrid[0:size, 0:size] / size
    rng = (8000.0 + 3000.0 * y + 40.0 * np.sin(40 * x) * np.cos(30 * y)).astype(np.float32)
    rng[: size // 10] = np.nan
    gx, gy = np.gradient(rng.astype(np.float64))
    nor = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    nor = (nor / np.linalg.norm(nor, axis=-1, keepdims=True)).astype(np.float32)
    images = {"range": rng[:, :, None], "normals": nor}

    def ours():
        for name, a in images.items():
            write_float_tiff(a, folder / f"ours_{name}.tif")

    def direct():
        import warnings

        for name, a in images.items():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(folder / f"direct_{name}.tif", "w", driver="GTiff",
                                   dtype="float32", count=a.shape[2], width=size, height=size,
                                   nodata=float("nan"), compress="deflate", predictor=3,
                                   tiled=True, blockxsize=BLOCK_SIZE,
                                   blockysize=BLOCK_SIZE) as dst:
                    dst.write(np.moveaxis(a, 2, 0))

    timed = alternate(dict(ours=ours, direct_deflate=direct), repeat)
    ratio = timed.ratio("ours", "direct_deflate")
    sizes = {f"{who}_{name}_bytes": (folder / f"{who}_{name}.tif").stat().st_size
             for who in ("ours", "direct") for name in images}
    return dict(size=size, ours=timed.timings["ours"],
                baseline_direct_deflate=timed.timings["direct_deflate"], ratio=ratio,
                **sizes, passed=ratio <= 1.0)


def bench_transaction(folder: Path, nbytes: int, repeat: int) -> dict:
    import os

    from terrain.core.outputs import atomic_path, transaction

    payload = os.urandom(nbytes)
    names = ["a.ply", "a.npz", "a_craters.csv", "a_boulders.csv"]

    def write_all():
        for name in names:
            with atomic_path(folder / name) as tmp:
                tmp.write_bytes(payload)

    def as_set():
        with transaction(folders=[folder]):
            write_all()

    timed = alternate(dict(as_set=as_set, one_by_one=write_all), repeat)
    ours, base = timed.timings["as_set"], timed.timings["one_by_one"]
    limit = 1.5 * base["median_s"] + 0.020
    return dict(bytes_per_file=nbytes, files=len(names), set=ours, baseline_one_by_one=base,
                ratio=ours["median_s"] / base["median_s"], passed=ours["median_s"] <= limit)


def bench_read_stack(folder: Path, base_size: int, repeat: int) -> dict:
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import _read_stack, read_stack, write_stack

    base = synthesize_tile(base_size, resolution=10.0, relief=50.0, seed=2).tile
    centre = (base_size - 1) * 10.0 / 2
    stack = write_stack(build_stack(base, (centre, centre), levels=2, layer_size=base_size,
                                    seed=3), folder / "stack")
    timed = alternate(dict(locked=lambda: read_stack(stack),
                           unlocked=lambda: _read_stack(stack)), repeat)
    locked, unlocked = timed.timings["locked"], timed.timings["unlocked"]
    limit = 1.2 * unlocked["median_s"] + 0.005
    return dict(layer_size=base_size, locked=locked, baseline_unlocked=unlocked,
                ratio=locked["median_s"] / unlocked["median_s"],
                passed=locked["median_s"] <= limit)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes")
    args = parser.parse_args(argv)
    size, nbytes, layer, repeat = (257, 200_000, 129, 3) if args.quick \
        else (2049, 20_000_000, 513, 7)
    with tempfile.TemporaryDirectory(prefix="bench-outputs-") as tmp:
        tmp = Path(tmp)
        log(f"write_dem {size}^2")
        write = bench_write_dem(tmp, size, repeat)
        sensor_size = 129 if args.quick else 1024
        log(f"sensor TIFFs {sensor_size}^2")
        sensor = bench_sensor_tiff(tmp, sensor_size, repeat)
        log(f"transaction of 4 x {nbytes} bytes")
        txn = bench_transaction(tmp, nbytes, repeat)
        log(f"read_stack of {layer}^2 layers")
        read = bench_read_stack(tmp, layer, repeat)
    doc = dict(benchmark="outputs", quick=args.quick, machine=machine_facts(),
               results=dict(write_dem=write, sensor_tiff=sensor, transaction=txn,
                            read_stack=read),
               passed=all(r["passed"] for r in (write, sensor, txn, read)))
    json.dump(doc, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
