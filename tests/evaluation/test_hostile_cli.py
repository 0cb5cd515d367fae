"""Hostile input to the evaluation commands: validate first, write after; never into an input; one
exit code for "cannot write here". Refusals are exit code 2 with one line on stderr, every
input byte-identical and no output left."""

import pytest

from evaluation.spectrum import fractional_brownian_surface
from terrain.core.tile import DEMTile
from terrain.io import write_dem
from tests.cli_helpers import file_size_limit, refused, run, snapshot, unwritable_folder


@pytest.fixture
def dem(tmp_path):
    path = tmp_path / "dem.tif"
    write_dem(fractional_brownian_surface(64, 0.8, resolution=2.0, rms=4.0, seed=1), path)
    return path


@pytest.fixture
def stack(tmp_path):
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(33, resolution=8.0, relief=30.0, seed=3).tile
    return write_stack(build_stack(base, (128.0, 128.0), levels=1, layer_size=17, seed=4),
                       tmp_path / "stack")


def test_checks_fail_before_anything_is_written(tmp_path):
    tiny = tmp_path / "tiny.tif"
    write_dem(DEMTile.from_array([[1.0]], resolution=1.0), tiny)
    before = snapshot(tiny)
    out = tmp_path / "out"
    r = run("evaluation", "slopes", tiny, "-o", out)
    refused(r, before, out, folder=tmp_path)


def test_nothing_is_written_into_an_input_stack(tmp_path, stack):
    before = snapshot(stack)
    for inp in (stack, stack / "manifest.json"):
        for out in (stack, stack / "slopes"):
            refused(run("evaluation", "slopes", inp, "-o", out), before,
                    fragments=["input folder"], folder=tmp_path)
    assert snapshot(stack) == before


def test_tracking_requests_beyond_the_frames_are_refused(tmp_path, planar_run):
    before = snapshot(planar_run)
    out = tmp_path / "t"
    refused(run("evaluation", "track", planar_run, "-o", out, "--win-size", 100000), before,
            out, fragments=["must fit"], folder=tmp_path)
    refused(run("evaluation", "track", planar_run, "-o", planar_run / "t"), before, out,
            fragments=["input folder"], folder=tmp_path)


@pytest.mark.parametrize("key, value", [
    ("tracking", "max_outlier_fraction = 2.0"), ("tracking", "min_survival = 1.5"),
    ("asteroid", "max_area_fraction_steep = 3"), ("asteroid", "steep_slope_deg = 120.0"),
])
def test_fraction_thresholds_above_one_are_refused(tmp_path, dem, key, value):
    t = tmp_path / "t.toml"
    t.write_text(f"[{key}]\n{value}\n")
    before = snapshot(dem, t)
    out = tmp_path / "r.html"
    refused(run("evaluation", "report", "--dem", dem, "--thresholds", t, "-o", out), before,
            out, tmp_path / "r.json", fragments=[f"[{key}] {value.split(' =')[0]} must be <="],
            folder=tmp_path)


def test_cannot_write_here_is_exit_2(tmp_path, dem):
    before = snapshot(dem)
    ro = unwritable_folder(tmp_path)
    refused(run("evaluation", "slopes", dem, "-o", ro / "out"), before,
            fragments=["cannot write"])
    refused(run("evaluation", "report", "--dem", dem, "-o", ro / "r.html"), before,
            fragments=["cannot write"])
    with file_size_limit(4_000):  # a full disk: the first files fit, the figures do not
        r = run("evaluation", "slopes", dem, "-o", tmp_path / "out")
    refused(r, before, tmp_path / "out", fragments=["cannot write"], folder=tmp_path)
    refused(run("evaluation", "report", "--dem", dem, "-o", tmp_path / "r.txt"), before,
            tmp_path / "r.txt", tmp_path / "r.json", fragments=[".html"], folder=tmp_path)


def test_a_rerun_into_the_same_folder_leaves_no_stale_comparison(tmp_path, dem):
    ref = tmp_path / "ref.tif"
    write_dem(fractional_brownian_surface(64, 0.8, resolution=2.0, rms=4.0, seed=9), ref)
    out = tmp_path / "out"
    assert run("evaluation", "slopes", dem, "--reference", ref, "-o", out).exit_code == 0
    assert (out / "comparison.json").exists()
    r = run("evaluation", "slopes", dem, "-o", out)
    assert r.exit_code == 0, r.output
    assert not (out / "comparison.json").exists()  # it compared with a reference no more


def _demo(*args, cwd):
    import subprocess
    import sys
    from pathlib import Path

    demo = Path(__file__).resolve().parents[2] / "examples" / "demo.py"
    return subprocess.run([sys.executable, str(demo), *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def _one_line(result, *fragments):
    assert result.returncode == 2, result.stdout + result.stderr
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert lines[0].startswith("demo: error:"), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_demo_refuses_bad_campaigns_and_outputs_in_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('title = "x"\ntitel = "y"\n', encoding="utf-8")
    _one_line(_demo("--campaign", bad, "--out", tmp_path / "o1", cwd=tmp_path),
              "'titel'", "did you mean 'title'")
    broken = tmp_path / "broken.toml"
    broken.write_text("title = \n", encoding="utf-8")
    _one_line(_demo("--campaign", broken, "--out", tmp_path / "o2", cwd=tmp_path))
    _one_line(_demo("--campaign", tmp_path / "none.toml", "--out", tmp_path / "o3",
                    cwd=tmp_path), "none.toml")
    (tmp_path / "a-file").write_text("mine")
    _one_line(_demo("--quick", "--out", tmp_path / "a-file", cwd=tmp_path), "not a folder")
    home = tmp_path / "home"
    home.mkdir()
    (home / "notes.txt").write_text("mine")
    before = snapshot(home)
    _one_line(_demo("--quick", "--fresh", "--out", home, cwd=tmp_path), "holds no campaign")
    assert snapshot(home) == before
    assert not any((tmp_path / name).exists() for name in ("o1", "o2", "o3"))
    # -v shows where it failed
    verbose = _demo("-v", "--quick", "--out", tmp_path / "a-file", cwd=tmp_path)
    assert verbose.returncode == 2 and "Traceback" in verbose.stderr
