"""Terrain commands given bad input as a hostile user gives it. Each refusal is exit code 2
with one line on stderr, leaves every input byte-identical and no output or partial file."""

import os
import signal
import stat
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import rasterio
from affine import Affine

from terrain.fractal.synthetic import synthesize_tile
from terrain.io import write_dem
from terrain.stack.store import INCOMPLETE, MANIFEST
from tests.cli_helpers import (
    file_size_limit,
    one_line_error,
    refused,
    run,
    snapshot,
    unwritable_folder,
)


@pytest.fixture
def dem(tmp_path):
    path = tmp_path / "dem.tif"
    write_dem(synthesize_tile(65, resolution=2.0, relief=20.0, seed=1).tile, path)
    return path


@pytest.fixture
def pop(tmp_path):
    path = tmp_path / "pop.toml"
    path.write_text("[population]\ndmin = 4.0\ndmax = 30.0\ndensity = 3000.0\n")
    return path


# -------------------------------------------------------------- 1. every input is protected


def test_no_input_of_a_command_can_be_an_output(tmp_path, dem, pop):
    profile = tmp_path / "profile.csv"
    profile.write_text("baseline_age_gyr,depth_fraction,rim_fraction\n0,1,1\n3.5,0.5,0.4\n")
    before = snapshot(dem, pop, profile)
    cases = [
        (["terrain", "craters", dem, "--population", pop, "-o", pop], "same file as input"),
        (["terrain", "craters", dem, "--population", pop, "--erosion-profile", profile,
          "-o", tmp_path / "o.tif", "--catalog", profile], "same file as input"),
        (["terrain", "synth", "--size", 33, "--population", pop, "-o", tmp_path / "o.tif",
          "--catalog", pop], "same file as input"),
        (["terrain", "synth", "--size", 33, "--erosion-profile", profile, "--density", 10,
          "-o", profile], "same file as input"),
    ]
    for args, fragment in cases:
        refused(run(*args), before, tmp_path / "o.tif", fragments=[fragment], folder=tmp_path)


# ------------------------------------------------------ 2. special files are written in place


def test_devices_and_fifos_are_written_in_place_never_replaced(tmp_path, dem):
    r = run("terrain", "hillshade", dem, "-o", os.devnull)
    assert r.exit_code == 0, r.output
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    r = run("terrain", "hillshade", dem, "-o", fifo)
    reader.join(timeout=30)
    assert r.exit_code == 0, r.output
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert got and got[0].startswith(b"\x89PNG\r\n\x1a\n")


# ------------------------------------------------------ 3. files that belong together


def test_a_dem_never_appears_without_its_catalogue(tmp_path, dem, pop):
    before = snapshot(dem, pop)
    out = tmp_path / "out.tif"
    bad = unwritable_folder(tmp_path) / "cat.csv"
    r = run("terrain", "craters", dem, "--population", pop, "-o", out, "--catalog", bad)
    refused(r, before, out, bad, fragments=["cannot write"], folder=tmp_path)
    with file_size_limit(20_000):  # the DEM fits; the catalogue of 400 craters does not
        r = run("terrain", "craters", dem, "--density", 2e5, "--dmin", 4, "--dmax", 8,
                "-o", out, "--catalog", tmp_path / "cat.csv")
    refused(r, before, out, tmp_path / "cat.csv", fragments=["cannot write"], folder=tmp_path)


# ------------------------------------------------------ 5. interrupted stack builds


def test_an_enhance_that_cannot_finish_leaves_nothing_and_a_killed_one_is_cleared(tmp_path,
                                                                                   dem):
    before = snapshot(dem)
    out = tmp_path / "stack"
    args = ["terrain", "enhance", dem, "-o", out, "--site", "64,64", "--levels", 1,
            "--layer-size", 65]
    with file_size_limit(12_000):  # the first layers fit, the finest does not
        r = run(*args)
    refused(r, before, out, fragments=["cannot write"], folder=tmp_path)
    out.mkdir()  # what a killed build leaves: the marker, a layer, a temporary
    (out / INCOMPLETE).write_text("")
    (out / "layer_00.tif").write_bytes(b"half")
    r = run(*args)
    assert r.exit_code == 0, r.output
    assert (out / MANIFEST).exists() and not (out / INCOMPLETE).exists()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    mine = snapshot(tmp_path / "other")
    refused(run(*args[:4], tmp_path / "other", *args[5:]), {**before, **mine},
            fragments=["not empty"])


# ------------------------------------------------------ 6. known heights kept bitwise


def test_float64_known_heights_are_written_back_bitwise(tmp_path):
    path = tmp_path / "f64.tif"
    heights = 1737400.0 + np.arange(33 * 33, dtype=np.float64).reshape(33, 33) * 0.0123
    gap = np.zeros((33, 33), bool)
    gap[10:20, 12:22] = True
    nodata = -32768.0
    with rasterio.open(path, "w", driver="GTiff", width=33, height=33, count=1,
                       dtype="float64", nodata=nodata,
                       transform=Affine(1, 0, 0, 0, -1, 33)) as dst:
        dst.write(np.where(gap, nodata, heights), 1)
    assert np.any(heights.astype(np.float32).astype(np.float64) != heights)  # float32 rounds
    before = snapshot(path)
    out = tmp_path / "out.tif"
    r = run("terrain", "fill", path, "-o", out)
    assert r.exit_code == 0, r.output
    assert snapshot(path) == before
    with rasterio.open(out) as src:
        assert src.dtypes[0] == "float64"
        filled = src.read(1)
    np.testing.assert_array_equal(filled[~gap], heights[~gap])  # every known height, bitwise
    assert np.all(np.isfinite(filled[gap])) and np.all(filled[gap] != nodata)
    # commands that work in float32 say how far the known heights move
    r = run("terrain", "expand", path, "-o", tmp_path / "x.tif")
    assert r.exit_code == 0 and "float32 moves them by up to" in r.output


# ------------------------------------------------------ 7. typed population files


@pytest.mark.parametrize("text, fragment", [
    ("[population]\ndmin = 4.0\ndmax = 30.0\ndensity = 30.0\n[population.roughness]\n"
     "amplitude = 2\n", "[population.roughness]"),
    ("[population]\ndmin = 4.0\ndmax = 30.0\ndensity = 30.0\n[population.erosion]\n"
     "bogus = 1\n", "[population.erosion]"),
    ("[population]\ndmin = 4.0\ndmax = 30.0\ndensity = 30.0\n[craters]\nx = 1\n", "craters"),
    ("[population]\ndmin = \"4\"\ndmax = 30.0\ndensity = 30.0\n", "must be a number"),
    ("[population]\ndmin = 4.0\ndmax = 30.0\ndensty = 30.0\n", "did you mean 'density'"),
])
def test_population_files_are_typed_and_closed(tmp_path, dem, text, fragment):
    pop = tmp_path / "bad.toml"
    pop.write_text(text)
    before = snapshot(dem, pop)
    out = tmp_path / "out.tif"
    refused(run("terrain", "craters", dem, "--population", pop, "-o", out), before, out,
            fragments=[fragment], folder=tmp_path)


# ------------------------------------------------------ 8. no tracebacks for odd numbers


def test_nan_inf_and_absurd_numbers_are_one_line_errors(tmp_path, dem):
    circles = tmp_path / "gaps.csv"
    circles.write_text("x,y,diameter\n10,10,nan\n")
    before = snapshot(dem, circles)
    out = tmp_path / "out.tif"
    cases = [
        (["add-crater", dem, "--at", "20,20", "--diameter", "nan", "-o", out], "finite"),
        (["add-crater", dem, "--at", "20,20", "--diameter", "inf", "-o", out], "finite"),
        (["add-crater", dem, "--at", "nan,nan", "--diameter", 5, "-o", out], "finite"),
        (["add-crater", dem, "--at", "20,20", "--diameter", -5, "-o", out], "positive"),
        (["fill", dem, "--craters-at", circles, "-o", out], "line 2"),
        (["enhance", dem, "-o", tmp_path / "s", "--site", "64,64",
          "--finest-resolution", 1e-300], "at most 30"),
        (["expand", dem, "--fractal-dimension", "nan", "-o", out], "finite"),
    ]
    for args, fragment in cases:
        refused(run("terrain", *args), before, out, tmp_path / "s", fragments=[fragment],
                folder=tmp_path)


# ------------------------------------------------------ 9. memory refused before allocating


def test_requests_larger_than_memory_are_refused_first(tmp_path, dem):
    before = snapshot(dem)
    out = tmp_path / "out.tif"
    refused(run("terrain", "fill", dem, "--denoise", 1e9, "-o", out), before, out,
            fragments=["denoise sigma"], folder=tmp_path)
    refused(run("terrain", "fill", dem, "--denoise", 30, "-o", out,
                env={"CRATERSCAPE_MEMORY_LIMIT": "1K"}), before, out,
            fragments=["needs about"], folder=tmp_path)


def test_memory_checks_respect_ulimit_v():
    code = ("import resource; from terrain.core import memory; "
            "resource.setrlimit(resource.RLIMIT_AS, (6 * 2**30, resource.RLIM_INFINITY)); "
            "print(memory.available_bytes())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert int(out.stdout) <= 6 * 2**30


def test_memory_checks_respect_cgroup_limits(tmp_path):
    from terrain.core.memory import _cgroup_headroom

    v2 = tmp_path / "v2"
    (v2 / "job").mkdir(parents=True)
    (v2 / "job" / "memory.max").write_text(f"{4 * 2**30}\n")
    (v2 / "job" / "memory.current").write_text(f"{2**30}\n")
    (v2 / "memory.max").write_text("max\n")
    cg = tmp_path / "cgroup2"
    cg.write_text("0::/job\n")
    assert _cgroup_headroom(v2, cg) == 3 * 2**30
    v1 = tmp_path / "v1" / "memory" / "job"
    v1.mkdir(parents=True)
    (v1 / "memory.limit_in_bytes").write_text(f"{2 * 2**30}\n")
    (v1 / "memory.usage_in_bytes").write_text(f"{2**29}\n")
    cg1 = tmp_path / "cgroup1"
    cg1.write_text("4:memory:/job\n1:cpu:/\n")
    assert _cgroup_headroom(tmp_path / "v1", cg1) == 2 * 2**30 - 2**29
    cg.write_text("0::/\n")
    assert _cgroup_headroom(tmp_path / "nothing", cg) is None


# ------------------------------------------------------ 10. nonsense is refused


def test_nonsense_parameters_are_refused(tmp_path, dem):
    before = snapshot(dem)
    out = tmp_path / "out.tif"
    png = tmp_path / "out.png"
    cases = [
        (["synth", "--size", 33, "--relief", 1e40, "-o", out], "--relief"),
        (["hillshade", dem, "--azimuth", "nan", "-o", png], "finite"),
        (["hillshade", dem, "--z-factor", 1e300, "-o", png], "--z-factor"),
    ]
    for args, fragment in cases:
        refused(run("terrain", *args), before, out, png, fragments=[fragment], folder=tmp_path)


# ------------------------------------------------------ 12. cannot write here


def test_every_cannot_write_here_is_exit_2_with_one_message(tmp_path, dem):
    before = snapshot(dem)
    ro = unwritable_folder(tmp_path)
    for args in (["synth", "--size", 33, "-o", ro / "x.tif"],
                 ["hillshade", dem, "-o", ro / "x.png"],
                 ["enhance", dem, "-o", ro / "stack", "--site", "64,64", "--levels", 1,
                  "--layer-size", 33]):
        refused(run("terrain", *args), before, fragments=["cannot write"], folder=tmp_path)
    with file_size_limit(2_000):  # a full disk, for a GeoTIFF and for a PNG
        for args in (["synth", "--size", 129, "-o", tmp_path / "x.tif"],
                     ["hillshade", dem, "-o", tmp_path / "x.png"]):
            refused(run("terrain", *args), before, tmp_path / "x.tif", tmp_path / "x.png",
                    fragments=["cannot write", "File too large"], folder=tmp_path)


# ------------------------------------------------------ 13. the format matches the name


def test_output_format_matches_the_extension(tmp_path, dem):
    before = snapshot(dem)
    for args, fragment in ((["hillshade", dem, "-o", tmp_path / "x.tif"], ".png"),
                           (["synth", "--size", 33, "-o", tmp_path / "x.png"], ".tif"),
                           (["synth", "--size", 33, "--density", 10, "-o", tmp_path / "x.tif",
                             "--catalog", tmp_path / "x.json"], ".csv")):
        refused(run("terrain", *args), before, tmp_path / "x.tif", tmp_path / "x.png",
                fragments=[fragment], folder=tmp_path)


# ------------------------------------------------------ 14. SIGTERM cleans up like Ctrl-C


@pytest.mark.slow
def test_sigterm_during_expand_leaves_no_partial_file(tmp_path, dem):
    big = tmp_path / "big.tif"
    write_dem(synthesize_tile(513, resolution=2.0, relief=20.0, seed=1).tile, big)
    before = snapshot(big)
    out = tmp_path / "out.tif"
    proc = subprocess.Popen([sys.executable, "-c", "from terrain.cli.commands import main; main()",
                             "terrain", "expand", str(big), "--times", "2", "-o", str(out)],
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if any(p.name.endswith(".partial") for p in tmp_path.iterdir()):
            break  # the output is being written: the worst moment
        time.sleep(0.002)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode in (143, 0), err  # 0 only if it had just finished
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]
    assert snapshot(big) == before
    if proc.returncode == 143:
        assert not out.exists() and "Traceback" not in err and err.strip().endswith(
            "terminated")


# ------------------------------------------------------ 15. a killed out-of-core run resumes


def test_a_killed_out_of_core_geotiff_run_resumes_and_cleans_its_scratch(tmp_path, monkeypatch):
    from terrain.execution.chunked import SynthSource

    small = {"CRATERSCAPE_MEMORY_LIMIT": "400K"}  # a 129 x 129 synthesis does not fit
    whole = tmp_path / "whole.tif"
    assert run("terrain", "synth", "--size", 129, "--seed", 4, "-o", whole).exit_code == 0
    out = tmp_path / "k.tif"
    compute = SynthSource.compute
    calls = []

    def killed_after_four(self, window):
        if len(calls) == 4:
            raise KeyboardInterrupt  # the run is killed part way
        calls.append(window)
        return compute(self, window)

    monkeypatch.setattr(SynthSource, "compute", killed_after_four)
    assert run("terrain", "synth", "--size", 129, "--seed", 4, "-o", out,
               env=small).exit_code == 130
    monkeypatch.setattr(SynthSource, "compute", compute)
    left = [p for p in tmp_path.iterdir() if p.name.startswith(".k.tif.")]
    assert len(left) == 1 and not out.exists()
    other = run("terrain", "synth", "--size", 129, "--seed", 5, "-o", tmp_path / "o.tif",
                env=small)  # another request keeps to its own scratch
    assert other.exit_code == 0 and left[0].exists()
    again = run("terrain", "synth", "--size", 129, "--seed", 4, "-o", out, env=small)
    assert again.exit_code == 0, again.output
    assert "4 already written" in again.output
    with rasterio.open(whole) as a, rasterio.open(out) as b:
        assert np.array_equal(a.read(1), b.read(1))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.tif", "o.tif", "whole.tif"]


def test_a_chunk_larger_than_the_dem_is_clamped_and_leaves_nothing_else(tmp_path):
    out = tmp_path / "c.zarr"
    result = run("terrain", "synth", "--size", 65, "--chunk", 100_000, "-o", out)
    assert result.exit_code == 0, result.output
    assert "1 of 1 chunks computed" in result.output


def test_a_crater_too_small_for_the_stack_is_refused(tmp_path, dem):
    stack = tmp_path / "stack"
    assert run("terrain", "enhance", dem, "-o", stack, "--site", "64,64", "--levels", 1,
               "--layer-size", 33).exit_code == 0
    before = snapshot(stack)
    refused(run("terrain", "replace-crater", stack, "--at", "64,64", "--diameter", 0.001),
            before, fragments=["0.001", "resolves"], folder=tmp_path)


def test_a_lander_wider_than_the_dem_is_one_line(tmp_path, dem):
    before = snapshot(dem)
    out = tmp_path / "h.tif"
    refused(run("terrain", "hazards", dem, "-o", out, "--lander-diameter", 1e6,
                "--max-slope", 10, "--max-step", 0.3), before, out, tmp_path / "h.png",
            fragments=["wider than the DEM"], folder=tmp_path)


def test_a_population_file_nested_50000_deep_is_one_line(tmp_path):
    deep = tmp_path / "deep.toml"
    deep.write_text("[population]\ndmin = " + "[" * 50_000 + "]" * 50_000 + "\n")
    before = snapshot(deep)
    out = tmp_path / "o.tif"
    refused(run("terrain", "synth", "--size", 33, "--population", deep, "-o", out), before,
            out, fragments=["deep.toml", "nests deeper"], folder=tmp_path)


def test_a_full_disk_names_the_path_it_could_not_write(tmp_path):
    assert run("terrain", "synth", "--size", 129, "--chunk", 64, "-o",
               tmp_path / "warm.zarr").exit_code == 0  # compiled kernels are cached
    with file_size_limit(2_000):
        result = run("terrain", "synth", "--size", 129, "--chunk", 64, "-o",
                     tmp_path / "full.zarr")
    one_line_error(result, "full.zarr", "File too large")
    assert "'output'" not in result.output
