"""Hazard truth on analytic cases: a tilted plane, and one known rock on it."""

import math

import numpy as np
import pytest
import rasterio
from scipy import ndimage

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.surface.hazards import footprint_offsets, hazard_map
from terrain.surface.rocks import RockTable, rock_heights
from tests.cli_helpers import one_line_error, run

RES = 0.1
L = 2.0


def plane(angle_deg, azimuth_deg, n=121):
    """A plane rising at ``angle_deg`` towards ``azimuth_deg`` (clockwise from north)."""
    rows, cols = np.mgrid[0:n, 0:n]
    x, y = cols * RES, -rows * RES
    g = math.tan(math.radians(angle_deg))
    az = math.radians(azimuth_deg)
    z = 1737.0 + g * (x * math.sin(az) + y * math.cos(az))
    return DEMTile.from_array(z, resolution=RES)


@pytest.mark.parametrize("angle, azimuth", [(0.0, 0.0), (7.3, 30.0), (11.5, 200.0),
                                            (35.0, 290.0)])
def test_a_tilted_plane_gives_its_slope_everywhere_inside_the_margins(angle, azimuth):
    h = hazard_map(plane(angle, azimuth), lander_diameter=L, max_slope=12.0, max_step=0.3)
    margin = int(L / 2 / RES)
    inner = (slice(margin, -margin), slice(margin, -margin))
    assert np.all(np.isfinite(h.slope[inner]))
    assert np.max(np.abs(h.slope[inner] - angle)) < 0.05
    assert np.max(np.abs(h.step[inner])) < 1e-3        # nothing stands above a plane
    # the footprint reaches beyond the DEM in the margins: unknown, never safe
    assert np.all(np.isnan(h.safe[:margin])) and np.all(np.isnan(h.safe[:, -margin:]))
    assert np.all(h.safe[inner] == (1.0 if angle <= 12.0 else 0.0))


def test_one_known_rock_makes_unsafe_exactly_the_footprints_that_hold_it():
    tile = plane(5.0, 120.0)
    # one round rock 0.6 m across and 1 m tall, unburied: its widest section stands c / 2 =
    # 0.5 m above its base, so every pixel it covers stands more than max step (0.3 m) high
    row = np.zeros(15)
    row[:9] = [6.0, 6.0, 0.6, 0.6, 0.6, 1.0, 0.0, 0.0, 0.0]
    rock = RockTable(row[None, :], np.array([1], np.uint64))
    z, z0, drawn = rock_heights(tile, rock)
    rocky = tile.replace(heights=z)
    covered = z > tile.heights
    assert drawn.all() and 20 < covered.sum() < 40
    assert np.min((z - tile.heights)[covered]) > 0.45   # c / 2 less the slope's share
    h = hazard_map(rocky, lander_diameter=L, max_slope=12.0, max_step=0.3)
    known = np.isfinite(h.safe)
    # footprint of pixel p holds the rock <=> a covered pixel lies within L/2 of p
    off = footprint_offsets(L, RES)
    n = int(np.abs(off).max())
    disc = np.zeros((2 * n + 1, 2 * n + 1), bool)
    disc[off[:, 0] + n, off[:, 1] + n] = True
    holds = ndimage.binary_dilation(covered, structure=disc)
    assert holds[known].sum() > 300
    np.testing.assert_array_equal(h.safe[known] == 0, holds[known])
    assert h.safe_fraction == pytest.approx(1 - holds[known].mean())


def test_bad_thresholds_are_refused():
    with pytest.raises(InvalidParameterError, match="max slope"):
        hazard_map(plane(1, 0), lander_diameter=L, max_slope=95, max_step=0.3)
    with pytest.raises(InvalidParameterError, match="less than 2 pixels"):
        hazard_map(plane(1, 0), lander_diameter=0.1, max_slope=10, max_step=0.3)


def test_cli_writes_three_bands_safe_fraction_and_png(tmp_path):
    from terrain.io import write_dem

    dem = tmp_path / "dem.tif"
    write_dem(plane(15.0, 0.0), dem)
    out = tmp_path / "hazards.tif"
    r = run("terrain", "hazards", dem, "-o", out, "--lander-diameter", 2, "--max-slope", 12,
            "--max-step", 0.3)
    assert r.exit_code == 0, r.output
    with rasterio.open(out) as src:
        assert src.count == 3
        assert src.descriptions[0] == "slope (deg)"
        assert float(src.tags()["CRATERSCAPE_SAFE_FRACTION"]) == 0.0
        slope = src.read(1)
    assert np.nanmedian(slope) == pytest.approx(15.0, abs=0.05)
    assert (tmp_path / "hazards.png").stat().st_size > 100
    one_line_error(run("terrain", "hazards", dem, "-o", tmp_path / "x.tif",
                       "--lander-diameter", 2, "--max-slope", 12, "--max-step", -1),
                   "max step must be positive")
    assert not (tmp_path / "x.tif").exists()


def test_a_lander_wider_than_the_dem_is_refused_before_anything_is_allocated(monkeypatch):
    import terrain.surface.hazards as hz

    def no_footprint(*args):
        raise AssertionError("the footprint was built before the request was checked")

    monkeypatch.setattr(hz, "footprint_offsets", no_footprint)
    with pytest.raises(InvalidParameterError, match="wider than the DEM"):
        hazard_map(plane(1, 0), lander_diameter=1e6, max_slope=10, max_step=0.3)


def test_a_footprint_too_large_for_memory_is_refused_first(monkeypatch):
    from terrain.core.errors import MemoryRequestError

    tile = plane(1, 0)
    ny, nx = tile.shape
    monkeypatch.setenv("CRATERSCAPE_MEMORY_LIMIT", str(ny * nx * 8 * 24 + 1000))
    with pytest.raises(MemoryRequestError, match="footprint"):
        hazard_map(tile, lander_diameter=0.9 * nx * tile.resolution, max_slope=10,
                   max_step=0.3)
