"""The `craterscape terrain` commands, as a user runs them (click's CliRunner)."""

import csv
import json

import numpy as np
import pytest
import rasterio

from terrain.core.tile import DEMTile, Window
from terrain.io import read_dem, write_dem
from tests.cli_helpers import one_line_error, run


@pytest.fixture
def dem(tmp_path):
    path = tmp_path / "in.tif"
    r = run("terrain", "synth", "-o", path, "--size", 129, "--resolution", 2.0, "--relief", 5,
            "--seed", 1)
    assert r.exit_code == 0, r.output
    return path


def test_synth_with_craters_writes_tile_catalogue_and_provenance(tmp_path):
    out, cat = tmp_path / "t.tif", tmp_path / "c.csv"
    r = run("terrain", "synth", "-o", out, "--size", 257, "--resolution", 1.0,
            "--fractal-dimension", 2.2, "--relief", 8, "--seed", 7, "--dmin", 3, "--dmax", 60,
            "--density", 3000, "--sfd-exponent", -2, "--catalog", cat)
    assert r.exit_code == 0, r.output
    tile = read_dem(out)
    assert tile.shape == (257, 257) and tile.valid.all()
    assert tile.metadata["CRATERSCAPE_SEED"] == "7"
    assert '"density": 3000.0' in tile.metadata["CRATERSCAPE_PARAMETERS"]
    rows = list(csv.DictReader(cat.open()))
    assert len(rows) > 50
    assert {"id", "x_m", "y_m", "diameter_m", "age_gyr", "depth_m", "rim_height_m",
            "depth_fraction", "rim_fraction"} <= set(rows[0])
    # same command, same bytes
    out2 = tmp_path / "t2.tif"
    run("terrain", "synth", "-o", out2, "--size", 257, "--resolution", 1.0, "--relief", 8,
        "--seed", 7, "--dmin", 3, "--dmax", 60, "--density", 3000, "--sfd-exponent", -2)
    assert out2.read_bytes() == out.read_bytes()


def test_synth_window_equals_the_window_of_the_full_run(tmp_path):
    args = ["--size", 129, "--relief", 5, "--seed", 3, "--density", 5000, "--dmin", 3,
            "--dmax", 40]
    assert run("terrain", "synth", "-o", tmp_path / "full.tif", *args).exit_code == 0
    r = run("terrain", "synth", "-o", tmp_path / "win.tif", *args, "--window", "10,20,50,30")
    assert r.exit_code == 0, r.output
    full, win = read_dem(tmp_path / "full.tif"), read_dem(tmp_path / "win.tif")
    assert np.array_equal(win.heights, full.heights[20:50, 10:60])
    assert win.transform == full.window(Window(10, 20, 50, 30)).transform


def test_craters_command_and_window(dem, tmp_path):
    args = ["--dmin", 6, "--dmax", 60, "--density", 800, "--seed", 4]
    r = run("terrain", "craters", dem, "-o", tmp_path / "c.tif", *args, "--catalog",
            tmp_path / "c.csv")
    assert r.exit_code == 0, r.output
    full = read_dem(tmp_path / "c.tif")
    assert not np.array_equal(full.heights, read_dem(dem).heights)
    r = run("terrain", "craters", dem, "-o", tmp_path / "w.tif", *args, "--window", "5,6,40,50")
    assert r.exit_code == 0, r.output
    assert np.array_equal(read_dem(tmp_path / "w.tif").heights, full.heights[6:56, 5:45])


def test_population_file_and_flags(dem, tmp_path):
    pop = tmp_path / "pop.toml"
    pop.write_text("[population]\ndmin = 6.0\ndmax = 50.0\ndensity = 100.0\nmax_age = 0.5\n")
    r = run("terrain", "craters", dem, "-o", tmp_path / "c.tif", "--population", pop,
            "--density", 900, "--catalog", tmp_path / "c.csv")
    assert r.exit_code == 0, r.output
    ages = [float(row["age_gyr"]) for row in csv.DictReader((tmp_path / "c.csv").open())]
    assert ages and max(ages) <= 0.5


def test_add_crater_fresh_and_without_roughness(dem, tmp_path):
    base = read_dem(dem)
    x, y = base.xy(64, 64)
    out = tmp_path / "one.tif"
    r = run("terrain", "add-crater", dem, "-o", out, "--at", f"{x},{y}", "--diameter", 80,
            "--no-roughness", "--catalog", tmp_path / "one.csv")
    assert r.exit_code == 0, r.output
    change = read_dem(out).heights - base.heights
    depth = 0.196 * (80 / 1000) ** 1.01 * 1000
    assert change.min() < -0.5 * depth
    row = next(csv.DictReader((tmp_path / "one.csv").open()))
    assert float(row["age_gyr"]) == 0.0 and float(row["depth_m"]) == pytest.approx(depth)
    # far from the crater nothing changed
    assert np.array_equal(change[:10, :10], np.zeros((10, 10), np.float32))


def test_hillshade_and_info(dem, tmp_path):
    r = run("terrain", "hillshade", dem, "-o", tmp_path / "h.png")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "h.png").read_bytes()[:4] == b"\x89PNG"
    r = run("terrain", "info", dem)
    assert r.exit_code == 0 and '"width": 129' in r.output


# ---------------------------------------------------------------- bad input: exit 2, one line


def test_missing_and_corrupt_inputs(tmp_path):
    one_line_error(run("terrain", "craters", tmp_path / "nope.tif", "-o", tmp_path / "o.tif",
                       "--density", 10), "does not exist")
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"not a tiff at all")
    one_line_error(run("terrain", "craters", bad, "-o", tmp_path / "o.tif", "--density", 10),
                   "cannot read DEM")
    assert not (tmp_path / "o.tif").exists()


def test_all_nodata_dem(tmp_path):
    path = tmp_path / "empty.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                       nodata=-5.0, transform=rasterio.Affine(1, 0, 0, 0, -1, 4)) as f:
        f.write(np.full((4, 4), -5.0, np.float32), 1)
    one_line_error(run("terrain", "add-crater", path, "-o", tmp_path / "o.tif", "--at", "1,1",
                       "--diameter", 2), "no valid pixels")


def test_dem_without_georeferencing(tmp_path):
    import warnings

    path = tmp_path / "plain.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1,
                           dtype="float32") as f:
            f.write(np.zeros((4, 4), np.float32), 1)
    one_line_error(run("terrain", "info", path), "no georeferencing")


def test_inconsistent_and_non_positive_parameters(dem, tmp_path):
    o = tmp_path / "o.tif"
    one_line_error(run("terrain", "craters", dem, "-o", o, "--dmin", 50, "--dmax", 10,
                       "--density", 5), "dmin", "dmax")
    one_line_error(run("terrain", "synth", "-o", o, "--size", 0), "size")
    one_line_error(run("terrain", "synth", "-o", o, "--size", 100), "2^n + 1")
    one_line_error(run("terrain", "synth", "-o", o, "--resolution", -1), "resolution")
    one_line_error(run("terrain", "add-crater", dem, "-o", o, "--at", "10,10", "--diameter",
                       -5), "diameter")
    one_line_error(run("terrain", "craters", dem, "-o", o, "--density", -3), "density")
    one_line_error(run("terrain", "craters", dem, "-o", o), "--density")
    one_line_error(run("terrain", "synth", "-o", o, "--size", 65, "--window", "60,0,10,10"),
                   "does not fit")
    one_line_error(run("terrain", "add-crater", dem, "-o", o, "--at", "1e7,0", "--diameter",
                       5), "does not touch")
    assert not o.exists()


def test_output_equal_to_input_is_refused_and_input_untouched(dem, tmp_path):
    before = dem.read_bytes()
    one_line_error(run("terrain", "craters", dem, "-o", dem, "--density", 10), "same file")
    one_line_error(run("terrain", "craters", dem, "-o", tmp_path / "x.tif", "--density", 10,
                       "--catalog", dem), "same file")
    assert dem.read_bytes() == before


def test_request_too_large_for_memory_and_for_the_disk(tmp_path):
    # Larger than memory alone runs out of core (tests/terrain/test_chunked.py); a request
    # whose out-of-core run would not fit on the disk either is refused before any work.
    r = run("terrain", "synth", "-o", tmp_path / "big.tif", "--size", 2**22 + 1,
            env={"CRATERSCAPE_MEMORY_LIMIT": "1G"})
    one_line_error(r, "memory", "disk")
    assert not (tmp_path / "big.tif").exists()


def test_verbose_shows_the_traceback(tmp_path):
    r = run("-v", "terrain", "craters", tmp_path / "nope.tif", "-o", tmp_path / "o.tif",
            "--density", 1)
    assert r.exit_code == 2
    assert "Traceback" in r.output


def test_nodata_preserved_through_craters(tmp_path):
    h = np.full((64, 64), 3.0)
    h[10:20, 10:20] = np.nan
    src = write_dem(DEMTile.from_array(h, resolution=1.0, nodata=-9999.0), tmp_path / "g.tif")
    r = run("terrain", "craters", src, "-o", tmp_path / "o.tif", "--density", 2000, "--dmin",
            3, "--dmax", 20)
    assert r.exit_code == 0, r.output
    out = read_dem(tmp_path / "o.tif")
    assert out.nodata == -9999.0
    assert np.array_equal(out.valid, read_dem(src).valid)


# ---------------------------------------------------------------- DEM enhancement commands


@pytest.fixture
def coarse(tmp_path):
    path = tmp_path / "coarse.tif"
    r = run("terrain", "synth", "-o", path, "--size", 65, "--resolution", 500.0, "--relief",
            800, "--seed", 2)
    assert r.exit_code == 0, r.output
    return path


def test_expand_command_and_window(coarse, tmp_path):
    r = run("terrain", "expand", coarse, "-o", tmp_path / "e.tif", "--times", 2, "--seed", 3)
    assert r.exit_code == 0, r.output
    base, out = read_dem(coarse), read_dem(tmp_path / "e.tif")
    assert out.shape == (257, 257) and out.resolution == 125.0
    assert np.array_equal(out.heights[::4, ::4], base.heights)
    assert "fractal_dimension" in out.metadata["CRATERSCAPE_PARAMETERS"]
    r = run("terrain", "expand", coarse, "-o", tmp_path / "w.tif", "--times", 2, "--seed", 3,
            "--window", "10,20,9,5")
    assert r.exit_code == 0, r.output
    assert np.array_equal(read_dem(tmp_path / "w.tif").heights, out.heights[80:97, 40:73])
    r = run("terrain", "expand", coarse, "-o", tmp_path / "f.tif", "--fractal-dimension", 2.3,
            "--height-scale", 0.001, "--uniform-roughness")
    assert r.exit_code == 0 and "F=2.300" in r.output


@pytest.mark.slow
def test_enhance_command_writes_a_layer_stack(coarse, tmp_path):
    out = tmp_path / "stack"
    r = run("terrain", "enhance", coarse, "-o", out, "--site", "16000,16000", "--levels", 3,
            "--layer-size", 33, "--seed", 5, "--density", 100000, "--dmin", 1, "--dmax", 5000)
    assert r.exit_code == 0, r.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["layers"]) == 4
    assert (out / "craters.csv").exists()
    assert manifest["layers"][-1]["resolution"] == pytest.approx(62.5)
    r = run("terrain", "replace-crater", out, "--at", "16000,16000", "--diameter", 400)
    assert r.exit_code == 0, r.output
    one_line_error(run("terrain", "enhance", coarse, "-o", out, "--site", "16000,16000",
                       "--levels", 2), "not empty")
    one_line_error(run("terrain", "enhance", coarse, "-o", tmp_path / "s2", "--site",
                       "-900000,5", "--levels", 2), "outside the DEM")
    one_line_error(run("terrain", "enhance", coarse, "-o", tmp_path / "s3", "--site", "5,5"),
                   "--levels")


def test_enhance_site_by_longitude_latitude(shared_file, tmp_path):
    dem = shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif")
    r = run("terrain", "enhance", dem, "-o", tmp_path / "sp", "--site-lonlat", "354.2,-85.005",
            "--levels", 2, "--layer-size", 65)
    assert r.exit_code == 0, r.output
    manifest = json.loads((tmp_path / "sp" / "manifest.json").read_text())
    left, bottom, right, top = manifest["layers"][-1]["bounds"]
    x, y = manifest["site"]
    assert left < x < right and bottom < y < top


def test_fill_command_with_crater_gaps_and_despike(tmp_path):
    h = read_dem_like_hole(tmp_path)
    circles = tmp_path / "circles.csv"
    x, y = h.xy(32, 32)
    circles.write_text(f"x,y,diameter,age\n{x},{y},30,0.1\n")
    src = write_dem(h, tmp_path / "holey.tif")
    r = run("terrain", "fill", src, "-o", tmp_path / "filled.tif", "--craters-at", circles,
            "--seed", 2)
    assert r.exit_code == 0, r.output
    out = read_dem(tmp_path / "filled.tif")
    assert out.valid.all()
    assert np.array_equal(out.heights[h.valid], h.heights[h.valid])
    r = run("terrain", "fill", src, "-o", tmp_path / "f2.tif", "--despike", 8, "--roughness",
            0.05)
    assert r.exit_code == 0, r.output
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    one_line_error(run("terrain", "fill", src, "-o", tmp_path / "f3.tif", "--craters-at", bad),
                   "x, y, diameter")


def read_dem_like_hole(tmp_path):
    from terrain.fractal.synthetic import synthesize_tile

    t = synthesize_tile(65, resolution=1.0, relief=3.0, seed=1).tile
    h = t.heights.copy()
    h[25:40, 25:40] = np.nan
    return DEMTile.from_array(h, resolution=1.0)


def test_replace_crater_on_a_missing_or_corrupt_stack(tmp_path):
    one_line_error(run("terrain", "replace-crater", tmp_path / "none", "--at", "1,1",
                       "--diameter", 10), "layer-stack folder")
    (tmp_path / "st").mkdir()
    (tmp_path / "st" / "manifest.json").write_text("[]")
    one_line_error(run("terrain", "replace-crater", tmp_path / "st", "--at", "1,1",
                       "--diameter", 10), "corrupt")


def test_add_crater_makes_complex_craters_and_takes_the_transition(tmp_path):
    """A 40 km crater through the CLI is Pike-deep; raising the transition makes it simple."""
    import csv

    from terrain.core.tile import DEMTile
    from terrain.io import read_dem, write_dem

    flat = tmp_path / "flat.tif"
    write_dem(DEMTile.from_array(np.zeros((301, 301), np.float32), resolution=400.0), flat)
    depths = {}
    for name, extra in (("complex", []), ("simple", ["--transition-diameter", "50000"])):
        out, cat = tmp_path / f"{name}.tif", tmp_path / f"{name}.csv"
        result = run("terrain", "add-crater", flat, "-o", out, "--at", "60200,60200",
                     "--diameter", 40000, "--no-roughness", "--catalog", cat, *extra)
        assert result.exit_code == 0, result.output
        with open(cat, newline="") as f:
            depths[name] = float(next(csv.DictReader(f))["depth_m"])
        assert np.isfinite(read_dem(out).heights).all()
    assert depths["complex"] == pytest.approx(1.044 * 40**0.301 * 1000, rel=1e-3)
    assert depths["simple"] == pytest.approx(0.196 * 40**1.01 * 1000, rel=1e-3)
    bad = run("terrain", "add-crater", flat, "-o", tmp_path / "x.tif", "--at", "60200,60200",
              "--diameter", 40000, "--transition-diameter", -5)
    assert bad.exit_code == 2 and "--transition-diameter" in bad.output
