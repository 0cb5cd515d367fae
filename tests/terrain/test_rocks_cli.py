"""`craterscape terrain rocks` and `terrain enhance --rocks`, as a user runs them."""

import csv
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from terrain.io import read_dem
from tests.cli_helpers import one_line_error, run


@pytest.fixture
def dem(tmp_path):
    path = tmp_path / "in.tif"
    r = run("terrain", "synth", "-o", path, "--size", 129, "--resolution", 0.05, "--relief",
            0.3, "--seed", 1)
    assert r.exit_code == 0, r.output
    return path


def test_rocks_writes_heights_and_catalogue_and_a_window_matches(dem, tmp_path):
    out, cat = tmp_path / "r.tif", tmp_path / "rocks.csv"
    r = run("terrain", "rocks", dem, "-o", out, "--model", "golombek-rapp-mars", "--k", 0.1,
            "--seed", 4, "--catalog", cat)
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(cat.open()))
    assert len(rows) > 20
    assert set(rows[0]) == {"id", "x_m", "y_m", "z_base_m", "diameter_m", "height_m",
                            "burial_m", "axis_a_m", "axis_b_m", "axis_c_m",
                            "orientation_deg", "layer"}
    assert min(float(row["diameter_m"]) for row in rows) >= 0.1  # two pixels by default
    full, ground = read_dem(out), read_dem(dem)
    assert np.all(full.heights >= ground.heights) and np.any(full.heights > ground.heights)
    assert json.loads(full.metadata["CRATERSCAPE_PARAMETERS"])["rocks"]["k"] == 0.1
    win = tmp_path / "w.tif"
    r = run("terrain", "rocks", dem, "-o", win, "--model", "golombek-rapp-mars", "--k", 0.1,
            "--seed", 4, "--window",
            "30,40,50,60")
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(read_dem(win).heights, full.heights[40:100, 30:80])


@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**31), b=st.sampled_from([-2.482, -2.0, -3.0]))
def test_power_law_rocks_follow_their_cumulative_law(tmp_path_factory, seed, b):
    """A power-law field N(>=D) = a D^b per m^2, as a field geologist would count it from the
    catalogue: the number of rocks of at least D over the tile's area is a D^b at the smallest
    size (within 5 Poisson standard deviations), the count falls by 2^b per doubling of D, and
    rocks only ever add height to the ground."""
    tmp = tmp_path_factory.mktemp("rocks")
    dem = tmp / "in.tif"
    assert run("terrain", "synth", "-o", dem, "--size", 129, "--resolution", 0.05, "--relief",
               0.3, "--seed", 1).exit_code == 0
    out, cat, a, dmin = tmp / "p.tif", tmp / "p.csv", 0.05, 0.1
    r = run("terrain", "rocks", dem, "-o", out, "--model", "power", "--a", a, "--b", b,
            "--dmin", dmin, "--seed", seed, "--catalog", cat)
    assert r.exit_code == 0, r.output
    ground, rocky = read_dem(dem), read_dem(out)
    diameters = np.array([float(row["diameter_m"]) for row in csv.DictReader(cat.open())])
    area = ground.shape[0] * ground.shape[1] * 0.05**2
    expected = a * dmin**b * area
    assert abs(len(diameters) - expected) < 5 * np.sqrt(expected), (len(diameters), expected)
    n1, n2 = (diameters >= dmin).sum(), (diameters >= 2 * dmin).sum()
    assert n2 / n1 == pytest.approx(2.0**b, abs=5 * np.sqrt(2.0**b / n1))
    assert np.all(rocky.heights >= ground.heights) and np.any(rocky.heights > ground.heights)


@pytest.mark.parametrize("args, fragment", [
    (["--model", "golombek-rapp-mars", "--k", 1.2], "must lie in (0, 1)"),
    (["--k", 0.1], "'k' is fixed by the viper-nominal rock model"),
    (["--model", "golombek", "--k", 0.1], "did you mean 'golombek-rapp-mars'"),
    (["--terrain", "mare"], "'mare' is not one of"),
    (["--model", "power", "--a", 3e-4, "--b", 0.1], "b must be negative"),
    (["--model", "power", "--a", 3e-4], "needs a and b"),
    (["--model", "power", "--a", 500, "--b", -2.482], "rock field of about"),
])
def test_bad_rock_parameters_are_one_line_errors_before_writing(dem, tmp_path, args, fragment):
    out = tmp_path / "bad.tif"
    r = run("terrain", "rocks", dem, "-o", out, *args,
            env={"CRATERSCAPE_MEMORY_LIMIT": "200M"})
    one_line_error(r, fragment)
    assert not out.exists()


def test_enhance_puts_rocks_into_the_stack(tmp_path):
    base = tmp_path / "b.tif"
    assert run("terrain", "synth", "-o", base, "--size", 65, "--resolution", 4.0, "--relief",
               3, "--seed", 2).exit_code == 0
    out = tmp_path / "stack"
    r = run("terrain", "enhance", base, "-o", out, "--site", "130,130", "--levels", 4,
            "--layer-size", 65, "--rocks", "golombek-rapp-mars:k=0.15")
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader((out / "rocks.csv").open()))
    assert len(rows) > 5 and "rocks" in r.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["rocks"]["k"] == 0.15 and manifest["rocks"]["dmin"] == pytest.approx(0.5)
    bad = tmp_path / "bad"
    one_line_error(run("terrain", "enhance", base, "-o", bad, "--site", "130,130", "--levels",
                       4, "--layer-size", 65, "--rocks", "golombek-rapp-mars:q=3"),
                   "unknown rock key 'q'")
    assert not bad.exists()


@pytest.mark.parametrize("args, model", [
    ([], "viper-nominal"),
    (["--terrain", "maria"], "viper-low"),
    (["--terrain", "maria", "--model", "viper-high"], "viper-high"),
])
def test_the_rock_model_is_the_lunar_default_the_presets_or_the_one_given(dem, tmp_path, args,
                                                                         model):
    out = tmp_path / "r.tif"
    r = run("terrain", "rocks", dem, "-o", out, "--seed", 4, *args)
    assert r.exit_code == 0, r.output
    assert json.loads(read_dem(out).metadata["CRATERSCAPE_PARAMETERS"])["rocks"]["model"] == model
