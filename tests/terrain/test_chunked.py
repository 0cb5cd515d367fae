"""Chunked runs on Dask: every chunk equals the same pixels of a single in-memory run.

The cluster tests use a real ``LocalCluster`` of 2 worker processes; arrays are small so the
module runs in seconds once the workers are up.
"""

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
import rasterio

from terrain.core.errors import OutputPathError
from terrain.core.tile import DEMTile
from terrain.core.zarrstore import ZarrDEM
from terrain.craters.cratering import add_craters
from terrain.craters.population import Population
from terrain.execution.chunked import (
    CraterSource,
    ExpandSource,
    FillSource,
    GapTooLargeError,
    SynthSource,
    dask_client,
    open_reader,
    run,
)
from terrain.fractal.expand import expand
from terrain.fractal.gapfill import fill_gaps
from terrain.fractal.synthetic import synthesize_tile
from terrain.io import raster_layout, read_dem, write_cog, write_dem
from tests.cli_helpers import one_line_error
from tests.cli_helpers import run as cli
from tests.terrain.test_allocator import churn_faults

# Workers unpickle the test's own source subclasses by value (they cannot import this file).
cloudpickle.register_pickle_by_value(sys.modules[__name__])

POP = Population(dmin=6.0, dmax=40.0, density=1500.0)


@pytest.fixture(scope="module")
def client():
    with dask_client(2) as c:
        yield c


@pytest.fixture(scope="module")
def dem(tmp_path_factory):
    """A 97 x 129 cratered DEM at 2 m in a projected CRS, with nodata -9999."""
    path = tmp_path_factory.mktemp("chunked") / "in.tif"
    tile = synthesize_tile(129, resolution=2.0, seed=5, relief=40.0).tile
    tile = DEMTile(tile.heights[:97], tile.valid[:97], tile.transform,
                   rasterio.crs.CRS.from_epsg(32633).to_wkt(), -9999.0, {})
    write_dem(tile, path)
    return path


def stored(path):
    heights, _ = ZarrDEM(path).read()
    return heights


@pytest.mark.slow
def test_synth_on_two_workers_equals_the_single_run(client, tmp_path):
    report = run(SynthSource(129, resolution=2.0, seed=5, craters=POP), tmp_path / "s.zarr",
                 chunk=48, client=client)
    single = synthesize_tile(129, resolution=2.0, seed=5, craters=POP)
    assert report.computed == report.total == 9
    assert np.array_equal(stored(tmp_path / "s.zarr"), single.tile.heights)  # bitwise
    assert len(single.catalog.id) > 10
    for name, column in single.catalog.as_dict().items():  # the same craters, in the same order
        assert np.array_equal(getattr(report.catalog, name), column), name


def test_craters_on_two_workers_equal_the_single_run(client, dem, tmp_path):
    report = run(CraterSource(open_reader(dem), POP, seed=9), tmp_path / "c.zarr", chunk=40,
                 client=client)
    single = add_craters(read_dem(dem), POP, seed=9)
    assert np.array_equal(stored(tmp_path / "c.zarr"), single.tile.heights, equal_nan=True)
    assert np.array_equal(report.catalog.id, single.catalog.id)


def test_two_level_expansion_on_two_workers_equals_the_single_run(client, dem, tmp_path):
    run(ExpandSource(open_reader(dem), 2, seed=7), tmp_path / "e.zarr", chunk=100,
        client=client)
    single = expand(read_dem(dem), 2, seed=7)
    store = ZarrDEM(tmp_path / "e.zarr")
    assert store.shape == single.shape == (385, 513)
    assert np.array_equal(stored(tmp_path / "e.zarr"), single.heights)
    assert store.transform == single.transform and store.crs == single.crs
    assert np.array_equal(single.heights[::4, ::4], read_dem(dem).heights)  # known heights


@dataclass(frozen=True)
class KillsItsWorkerOnce(ExpandSource):
    """Expansion whose chunk (1, 1) kills the worker process computing it, the first time."""

    guard: str = ""

    def compute(self, window):
        if window.row > 0 and window.col > 0:
            try:
                os.close(os.open(self.guard, os.O_CREAT | os.O_EXCL))
            except FileExistsError:
                pass
            else:
                os.kill(os.getpid(), signal.SIGKILL)
        return super().compute(window)


def test_a_worker_killed_mid_run_is_replaced_and_the_bytes_are_unchanged(client, dem,
                                                                         tmp_path):
    guard = tmp_path / "killed-once"
    source = KillsItsWorkerOnce(open_reader(dem), 2, seed=7, guard=str(guard))
    report = run(source, tmp_path / "k.zarr", chunk=100, client=client)
    assert guard.exists()  # a worker did die
    assert report.computed == report.total
    assert np.array_equal(stored(tmp_path / "k.zarr"), expand(read_dem(dem), 2, seed=7).heights)


class Interrupted(RuntimeError):
    pass


@dataclass(frozen=True)
class StopsAfter(SynthSource):
    """Synthesis that stops the run (like a kill) when it reaches chunk row 2."""

    def compute(self, window):
        if window.row >= 64:
            raise Interrupted("stopped part way")
        return super().compute(window)


def test_an_interrupted_run_resumes_without_recomputing_finished_chunks(tmp_path):
    out = tmp_path / "r.zarr"
    with pytest.raises(Interrupted):
        run(StopsAfter(129, seed=3, craters=POP), out, chunk=32)
    store = ZarrDEM(out)
    finished = store.done_chunks()
    assert len(finished) == 10 and not store.complete  # rows 0-1 of a 5 x 5 grid
    with pytest.raises(Exception, match="incomplete"):
        open_reader(out)
    stamps = {p: p.stat().st_mtime_ns for p in (out / "height").iterdir()
              if not p.name.startswith(".")}
    report = run(SynthSource(129, seed=3, craters=POP), out, chunk=32)
    assert report.skipped == 10 and report.computed == 15
    assert not set(report.computed_chunks) & finished
    for p, t in stamps.items():  # finished chunks were not written again
        assert p.stat().st_mtime_ns == t, p
    single = synthesize_tile(129, seed=3, craters=POP)
    assert np.array_equal(stored(out), single.tile.heights)
    assert np.array_equal(report.catalog.id, single.catalog.id)


def test_resuming_with_other_parameters_is_refused(tmp_path):
    out = tmp_path / "p.zarr"
    run(SynthSource(65, seed=1), out, chunk=32)
    with pytest.raises(OutputPathError, match="another run"):
        run(SynthSource(65, seed=2), out, chunk=32)


def _gappy(tmp_path):
    tile = synthesize_tile(129, resolution=2.0, seed=11, relief=40.0).tile
    h = np.array(tile.heights)
    for r, c, a, b in ((10, 20, 4, 6), (70, 90, 7, 3), (100, 30, 5, 5), (40, 60, 3, 8)):
        h[r:r + a, c:c + b] = np.nan
    path = tmp_path / "gappy.tif"
    write_dem(DEMTile(h, np.isfinite(h), tile.transform, None, -9999.0, {}), path)
    return path


def test_chunked_gap_filling_equals_the_single_fill_and_keeps_known_heights(tmp_path):
    path = _gappy(tmp_path)
    run(FillSource(open_reader(path), halo=40, seed=4), tmp_path / "f.zarr", chunk=32)
    single = fill_gaps(read_dem(path), seed=4)
    out = stored(tmp_path / "f.zarr")
    assert np.array_equal(out, single.tile.heights)
    known = read_dem(path)
    assert np.array_equal(out[known.valid], known.heights[known.valid])
    assert np.isfinite(out).all()


def test_a_gap_larger_than_the_halo_is_named_with_the_halo_it_needs(tmp_path):
    path = _gappy(tmp_path)
    with pytest.raises(GapTooLargeError, match=r"needs a halo of .*give --halo \d+"):
        run(FillSource(open_reader(path), halo=8, seed=4), tmp_path / "g.zarr", chunk=32)
    assert not (tmp_path / "g.zarr").exists()  # refused before any work
    result = cli("terrain", "fill", path, "-o", tmp_path / "g.zarr", "--halo", "8", "--chunk", "32")
    one_line_error(result, "largest gap", "--halo")


def test_cli_chunked_expand_writes_zarr_and_a_cog_that_gdal_reads(dem, tmp_path):
    single = tmp_path / "single.tif"
    assert cli("terrain", "expand", dem, "-o", single, "--seed", "3").exit_code == 0
    result = cli("terrain", "expand", dem, "-o", tmp_path / "e.zarr", "--seed", "3",
                 "--chunk", "64", "--cog", tmp_path / "e.tif")
    assert result.exit_code == 0, result.output
    with rasterio.open(single) as a, rasterio.open(tmp_path / "e.tif") as b:
        assert b.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        assert (b.transform, b.crs, b.nodata, b.shape) == (a.transform, a.crs, a.nodata,
                                                           a.shape)
        assert np.array_equal(a.read(1), b.read(1))
        assert b.tags()["CRATERSCAPE_SEED"] == "3"


def test_cog_has_overviews_and_the_same_pixels_as_the_store(tmp_path):
    run(SynthSource(1025, resolution=0.5, seed=2), tmp_path / "big.zarr", chunk=256)
    store = ZarrDEM(tmp_path / "big.zarr")
    write_cog(store, tmp_path / "big.tif")
    with rasterio.open(tmp_path / "big.tif") as ds:
        assert ds.overviews(1) == [2, 4]
        assert ds.block_shapes[0] == (512, 512)
        assert ds.profile["compress"].lower() == "deflate"
        assert np.array_equal(ds.read(1), store.read()[0])
        assert ds.transform == store.transform
        expected = dict(width=ds.width, height=ds.height, transform=list(ds.transform)[:6],
                        overviews=[2, 4], driver="GTiff", layout="COG")
    assert raster_layout(tmp_path / "big.tif") == expected  # what bench_dask checks with
    plain = raster_layout(write_dem(DEMTile.from_array(np.zeros((4, 4))), tmp_path / "p.tif"))
    assert plain["layout"] is None and plain["overviews"] == [] and plain["width"] == 4


def test_cli_refuses_a_chunked_run_into_a_tif_and_a_store_over_its_input(dem, tmp_path):
    one_line_error(cli("terrain", "expand", dem, "-o", tmp_path / "x.tif", "--chunk", "64"),
                   "Zarr")
    store = tmp_path / "s.zarr"
    assert cli("terrain", "synth", "--size", "65", "-o", store).exit_code == 0
    one_line_error(cli("terrain", "expand", store, "-o", store, "--chunk", "32"), "input")
    one_line_error(cli("terrain", "synth", "--size", "65", "--seed", "9", "-o", store),
                   "another run")


def test_cli_resumes_a_finished_store_without_computing(tmp_path):
    store = tmp_path / "s.zarr"
    assert cli("terrain", "synth", "--size", "65", "-o", store, "--chunk", "32").exit_code == 0
    again = cli("terrain", "synth", "--size", "65", "-o", store, "--chunk", "32")
    assert again.exit_code == 0 and "0 of 9 chunks computed, 9 already written" in again.output


def test_a_zarr_store_is_an_input_like_any_raster(dem, tmp_path):
    store = tmp_path / "in.zarr"
    assert cli("terrain", "craters", dem, "-o", store, "--density", "500", "--dmax", "30",
               "--chunk", "48").exit_code == 0
    single = tmp_path / "single.tif"
    assert cli("terrain", "craters", dem, "-o", single, "--density", "500",
               "--dmax", "30").exit_code == 0
    reader = open_reader(store)
    assert reader.transform == read_dem(dem).transform
    assert np.array_equal(reader.read()[0], read_dem(single).heights, equal_nan=True)
    out = tmp_path / "e.zarr"
    assert cli("terrain", "expand", store, "-o", out, "--chunk", "64").exit_code == 0
    assert Path(out, "height").is_dir()


def test_a_request_larger_than_memory_runs_out_of_core_instead_of_being_refused(dem, tmp_path):
    single = tmp_path / "single.tif"
    assert cli("terrain", "expand", dem, "-o", single, "--times", "2").exit_code == 0
    ooc = tmp_path / "ooc.tif"
    result = cli("terrain", "expand", dem, "-o", ooc, "--times", "2",
                 env={"CRATERSCAPE_MEMORY_LIMIT": "1500K"})  # the result needs about 2 MB
    assert result.exit_code == 0, result.output
    assert "do not fit in memory" in result.output
    with rasterio.open(single) as a, rasterio.open(ooc) as b:
        assert (b.transform, b.crs, b.shape) == (a.transform, a.crs, a.shape)
        assert np.array_equal(a.read(1), b.read(1))
        assert b.tags()["CRATERSCAPE_COMMAND"] == "terrain expand"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ooc.tif", "single.tif"]


def test_progress_counts_chunks_and_pixels(tmp_path):
    seen = []
    report = run(SynthSource(65, seed=1), tmp_path / "p.zarr", chunk=32,
                 progress=lambda done, total, rate: seen.append((done, total, rate)))
    assert [s[0] for s in seen] == list(range(10)) and {s[1] for s in seen} == {9}
    assert all(rate.endswith(" Mpixel/s") for _, _, rate in seen[1:])
    assert report.pixels == 65 * 65


@pytest.mark.slow
def test_a_cluster_started_with_dask_scheduler_and_dask_worker(dem, tmp_path):
    """The address a `dask scheduler` prints is all `--scheduler` needs (loopback here)."""
    dask = Path(sys.executable).with_name("dask")
    info = tmp_path / "scheduler.json"
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", info], **quiet)]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(info.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "2",
                                       "--nthreads", "1", "--no-dashboard",
                                       "--host", "127.0.0.1"], **quiet))
        out = tmp_path / "e.zarr"
        result = cli("terrain", "expand", dem, "-o", out, "--times", "2", "--seed", "7",
                     "--scheduler", address, "--chunk", "100")
        assert result.exit_code == 0, result.output
        assert "24 of 24 chunks computed" in result.output
        assert np.array_equal(stored(out), expand(read_dem(dem), 2, seed=7).heights)
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=30)


def test_thread_workers_give_the_same_bytes(tmp_path):
    with dask_client(2, processes=False) as threads:
        run(SynthSource(129, seed=8), tmp_path / "t.zarr", chunk=48, client=threads)
    assert np.array_equal(stored(tmp_path / "t.zarr"), synthesize_tile(129, seed=8).tile.heights)


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_line(tmp_path):
    import socket

    with socket.socket() as s:  # a free loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    result = cli("terrain", "synth", "--size", "65", "-o", tmp_path / "s.zarr",
                 "--scheduler", f"tcp://127.0.0.1:{port}")
    one_line_error(result, "cannot reach the Dask scheduler", str(port))


def test_craters_larger_than_memory_run_out_of_core(dem, tmp_path):
    small = {"CRATERSCAPE_MEMORY_LIMIT": "400K"}  # the input needs about 0.5 MB in memory
    for args in (("craters", dem, "--density", "500", "--dmax", "20"),):
        single, ooc = tmp_path / f"{args[0]}-single.tif", tmp_path / f"{args[0]}-ooc.tif"
        assert cli("terrain", *args, "-o", single).exit_code == 0
        result = cli("terrain", *args, "-o", ooc, env=small)
        assert result.exit_code == 0, result.output
        assert "do not fit in memory" in result.output
        assert np.array_equal(read_dem(ooc).heights, read_dem(single).heights, equal_nan=True)


def test_a_store_made_again_at_the_same_path_is_read_afresh(tmp_path):
    import shutil

    out = tmp_path / "again.zarr"
    run(SynthSource(65, seed=1), out, chunk=32)
    shutil.rmtree(out)
    run(SynthSource(129, seed=1), out, chunk=32)
    assert np.array_equal(stored(out), synthesize_tile(129, seed=1).tile.heights)


def test_a_float64_input_is_refused_by_chunked_runs_so_no_known_height_is_rounded(tmp_path):
    from affine import Affine

    path = tmp_path / "f64.tif"
    heights = 1737400.0 + np.arange(33 * 33, dtype=np.float64).reshape(33, 33) * 0.0123
    with rasterio.open(path, "w", driver="GTiff", width=33, height=33, count=1,
                       dtype="float64", transform=Affine(1, 0, 0, 0, -1, 33)) as dst:
        dst.write(heights, 1)
    one_line_error(cli("terrain", "expand", path, "-o", tmp_path / "x.zarr"), "float64",
                   "Float32")


# ------------------------------------------------------------ a resume trusts only what is there


def _chunk_file(store_path, i, j):
    return Path(store_path, "height", f"{i}.{j}")


@pytest.mark.parametrize("damage", ["removed", "truncated", "flipped"])
def test_a_resume_recomputes_a_chunk_whose_file_no_longer_matches_its_marker(tmp_path, damage):
    out = tmp_path / "m.zarr"
    with pytest.raises(Interrupted):
        run(StopsAfter(129, seed=3), out, chunk=32)
    victim = _chunk_file(out, 1, 2)
    data = victim.read_bytes()
    if damage == "removed":
        victim.unlink()
    elif damage == "truncated":
        victim.write_bytes(data[: len(data) // 2])
    else:
        victim.write_bytes(data[:-9] + bytes([data[-9] ^ 0xFF]) + data[-8:])
    assert (out / "chunks" / "1_2.npz").exists()  # the marker stays
    report = run(SynthSource(129, seed=3), out, chunk=32)
    assert (1, 2) in report.computed_chunks and report.skipped == 9
    assert np.array_equal(stored(out), synthesize_tile(129, seed=3).tile.heights)


def test_a_resume_recomputes_a_chunk_whose_marker_is_unreadable(tmp_path):
    out = tmp_path / "u.zarr"
    with pytest.raises(Interrupted):
        run(StopsAfter(129, seed=3), out, chunk=32)
    (out / "chunks" / "0_3.npz").write_bytes(b"not a marker")
    report = run(SynthSource(129, seed=3), out, chunk=32)
    assert (0, 3) in report.computed_chunks and report.skipped == 9
    assert np.array_equal(stored(out), synthesize_tile(129, seed=3).tile.heights)


def test_a_corrupt_chunk_or_marker_of_a_finished_store_is_one_line_naming_it(tmp_path):
    from terrain.core.errors import InvalidDEMError

    out = tmp_path / "c.zarr"
    run(SynthSource(65, seed=1, craters=POP), out, chunk=32)
    victim = _chunk_file(out, 1, 0)
    victim.write_bytes(b"\x00" * 40)
    with pytest.raises(InvalidDEMError, match=r"c\.zarr.*chunk 1,0"):
        ZarrDEM(out).read()
    result = cli("terrain", "cog", out, "-o", tmp_path / "c.tif")
    one_line_error(result, "chunk 1,0")
    assert not (tmp_path / "c.tif").exists()
    (out / "chunks" / "0_1.npz").write_bytes(b"junk")
    with pytest.raises(InvalidDEMError, match="0_1.npz"):
        ZarrDEM(out).chunk_catalog(0, 1)


@dataclass(frozen=True)
class CannotAllocate(SynthSource):
    """Synthesis whose first chunk fails (as a chunk too large for memory does)."""

    def compute(self, window):
        raise MemoryError("Unable to allocate 37.3 GiB")


def test_a_chunk_larger_than_the_dem_is_clamped_and_a_failed_start_leaves_no_store(tmp_path):
    out = tmp_path / "big.zarr"
    report = run(SynthSource(65, seed=1), out, chunk=100_000)
    assert report.total == 1
    assert ZarrDEM(out).chunk == 65
    assert np.array_equal(stored(out), synthesize_tile(65, seed=1).tile.heights)
    failed = tmp_path / "failed.zarr"
    with pytest.raises(MemoryError):
        run(CannotAllocate(129, seed=3), failed, chunk=64)  # no chunk gets done
    assert not failed.exists()
    run(SynthSource(129, seed=3), failed, chunk=32)  # nothing blocks another chunk size


def test_no_listener_of_the_local_cluster_binds_a_non_loopback_address(client):
    import ipaddress

    import psutil

    me = psutil.Process()
    listening = [c.laddr for p in (me, *me.children(recursive=True))
                 for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN]
    assert listening
    exposed = [a for a in listening if not ipaddress.ip_address(a.ip).is_loopback]
    assert not exposed, exposed


def test_the_scratch_store_of_an_out_of_core_run_is_found_again_only_by_the_same_request(
        tmp_path):
    from terrain.execution.chunked import scratch_path, scratch_store

    out = tmp_path / "k.tif"
    same = scratch_path(SynthSource(129, seed=3), out)
    assert same == scratch_path(SynthSource(129, seed=3), out)
    assert same.parent == tmp_path and same.name.startswith(".k.tif.")
    assert scratch_path(SynthSource(129, seed=4), out) != same
    assert scratch_path(SynthSource(129, seed=3), tmp_path / "l.tif") != same
    with pytest.raises(Interrupted), scratch_store(StopsAfter(129, seed=3), out) as (path, _):
        run(StopsAfter(129, seed=3), path, chunk=32)
    assert path == same and len(ZarrDEM(path).done_chunks()) == 10  # kept for the rerun
    with scratch_store(SynthSource(129, seed=3), out) as (path, chunk):
        assert chunk == 32  # the interrupted run's chunk side, so it resumes
        assert run(SynthSource(129, seed=3), path, chunk=chunk).skipped == 10
    assert not path.exists()


def test_a_finished_store_missing_a_chunk_is_refused_instead_of_read_as_a_hole(tmp_path):
    from terrain.core.errors import InvalidDEMError

    out = tmp_path / "h.zarr"
    run(SynthSource(65, seed=1), out, chunk=32)
    _chunk_file(out, 1, 1).unlink()
    with pytest.raises(InvalidDEMError, match=r"h\.zarr.*chunk 1,1"):
        open_reader(out)
    one_line_error(cli("terrain", "cog", out, "-o", tmp_path / "h.tif"), "chunk 1,1")
    assert not (tmp_path / "h.tif").exists()


def test_workers_are_single_threaded_even_when_the_program_imports_craterscape_first(tmp_path):
    """A spawned worker runs the program's main module again before the nanny's environment
    is set: a program that imports craterscape (and so numba) at its top had workers with a
    thread per core each, two workers on two cores then four threads fighting for them."""
    script = tmp_path / "program.py"
    script.write_text(
        "import os\n"
        "import numba\n"
        "from terrain.execution.chunked import dask_client\n"
        "def probe():\n"
        "    import numba\n"
        "    from terrain.core.parallel import threads\n"
        "    return numba.config.NUMBA_NUM_THREADS, threads()\n"
        "if __name__ == '__main__':\n"
        "    before = os.environ.get('NUMBA_NUM_THREADS')\n"
        "    with dask_client(2) as client:\n"
        "        print(sorted(client.run(probe).values()))\n"
        "        print(os.environ.get('NUMBA_NUM_THREADS') == before)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_NUM_THREADS",
                                                              "OMP_NUM_THREADS")}
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[2])
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         env=env, timeout=300, check=True).stdout.splitlines()
    assert out[0] == "[(1, 1), (1, 1)]"
    assert out[1] == "True"  # this process's own environment is as it was



@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt only")
def test_a_local_clusters_workers_reuse_freed_memory_on_their_task_threads(client):
    """A Dask worker with glibc's defaults faults in about 1,000 pages again every round
    (41,281 measured for the 40; tests/terrain/test_allocator.py compares the default in a
    plain process); the local cluster's workers keep what they free (515 measured)."""
    workers = sorted(client.scheduler_info()["workers"])
    faults = client.gather([client.submit(churn_faults, workers=[w], pure=False)
                            for w in workers])
    assert len(faults) == 2 and max(faults) < 40 * 1000 / 20


@dataclass(frozen=True)
class FailsLast(SynthSource):
    """Synthesis whose corner chunk fails after a second (the other worker finishes the rest)."""

    def compute(self, window):
        if window.row >= 128 and window.col >= 128:
            time.sleep(1.0)
            raise Interrupted("stopped part way")
        return super().compute(window)


def test_a_chunk_that_fails_on_a_worker_stops_the_run_and_the_finished_chunks_are_kept(
        client, tmp_path):
    out = tmp_path / "f.zarr"
    # the class comes back from the worker by value (this file is pickled so): matched by name
    with pytest.raises(Exception, match="stopped part way") as raised:
        run(FailsLast(129, seed=3), out, chunk=32, client=client)
    assert type(raised.value).__name__ == "Interrupted"
    finished = ZarrDEM(out).done_chunks()
    assert finished and (4, 4) not in finished
    report = run(SynthSource(129, seed=3), out, chunk=32, client=client)
    # (a chunk still running on the other worker when the error came may have finished since)
    assert report.skipped >= len(finished) and report.computed == 25 - report.skipped
    assert (4, 4) in report.computed_chunks
    assert np.array_equal(stored(out), synthesize_tile(129, seed=3).tile.heights)


def test_a_chunk_all_nodata_is_written_and_counts_as_done(tmp_path):
    store = ZarrDEM.create(tmp_path / "n.zarr", (20, 30), 16,
                           transform=rasterio.Affine(1, 0, 0, 0, -1, 0), crs=None,
                           nodata=-9999.0, metadata={}, plan={})
    store.write_chunk(0, 1, np.full((16, 14), np.nan, np.float32))
    assert store.chunk_file(0, 1).is_file() and store.is_done(0, 1)
    assert not store.is_done(0, 0)


@dataclass(frozen=True)
class FailsFirst(SynthSource):
    """Synthesis whose first chunk to start fails at once; every other takes half a second."""

    guard: str = ""

    def compute(self, window):
        try:
            os.close(os.open(self.guard, os.O_CREAT | os.O_EXCL))
        except FileExistsError:
            time.sleep(0.5)
            return super().compute(window)
        raise Interrupted("stopped part way")


def test_a_failed_run_waits_for_its_running_chunks_and_leaves_no_stray_files(client,
                                                                            tmp_path):
    """A chunk running on the other worker when the first fails goes on to write: the run
    waits for it, so the output is a resumable store, never a folder rebuilt after the run
    removed it (Zarr makes the array's folder again when it writes a chunk)."""
    from terrain.core.zarrstore import is_zarr

    out = tmp_path / "w.zarr"
    with pytest.raises(Exception, match="stopped part way"):
        run(FailsFirst(65, seed=3, guard=str(tmp_path / "failed")), out, chunk=32,
            client=client)
    time.sleep(1.0)  # anything still running would have written by now
    assert is_zarr(out) and ZarrDEM(out).done_chunks()  # the running chunk finished, kept
    report = run(SynthSource(65, seed=3), out, chunk=32, client=client)
    assert 1 <= report.skipped < report.total
    assert np.array_equal(stored(out), synthesize_tile(65, seed=3).tile.heights)
