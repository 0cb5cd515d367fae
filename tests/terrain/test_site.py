"""Landing-site and lit-sun choice (terrain/surface/site.py) on DEMs whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.surface.site import landing_site, lit_sun_azimuth


def _slope_deg(tile: DEMTile) -> np.ndarray:
    """An independent slope (central differences), not the library's Horn operator."""
    gy, gx = np.gradient(tile.heights.astype(np.float64), tile.resolution)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def test_the_site_is_the_flat_patch_of_the_central_half(rng):
    z = rng.normal(0.0, 20.0, (101, 101))
    z[55:70, 30:45] = 7.0  # the only flat ground, inside the central half
    z[0:20, 0:20] = 3.0    # flatter and larger, but in the outer quarter: not a candidate
    tile = DEMTile.from_array(z, resolution=10.0)
    x, y = landing_site(tile, _slope_deg(tile), box=9)
    col, row = ~tile.transform @ (x, y)
    assert 55 <= row < 70 and 30 <= col < 45
    assert 25 <= row < 76 and 25 <= col < 76


def test_unknown_slopes_count_as_steep(rng):
    z = np.zeros((41, 41))
    tile = DEMTile.from_array(z)
    slope = np.full(z.shape, np.nan)
    slope[22:27, 12:17] = 1.0  # the only known ground
    col, row = ~tile.transform @ landing_site(tile, slope, box=3)
    assert 22 <= row < 27 and 12 <= col < 17


def test_a_slope_map_of_another_shape_is_refused():
    tile = DEMTile.from_array(np.zeros((9, 9)))
    with pytest.raises(InvalidParameterError, match="slope_deg"):
        landing_site(tile, np.zeros((8, 9)))


@pytest.mark.parametrize("facing, azimuth", [("east", 90.0), ("west", 270.0), ("north", 0.0)])
def test_the_sun_comes_from_where_the_site_faces(facing, azimuth):
    """On a plane tilted towards one side, that side's sun strikes it most steeply."""
    n = 81
    ramp = np.arange(n, dtype=np.float64) * -2.0  # descending along the axis
    z = {"east": np.tile(ramp, (n, 1)), "west": np.tile(ramp[::-1], (n, 1)),
         "north": np.tile(ramp[::-1, None], (1, n))}[facing]  # rows run north to south
    tile = DEMTile.from_array(z, resolution=10.0)
    site = tile.transform @ (n / 2, n / 2)
    assert lit_sun_azimuth(tile, site, 30.0, step_deg=90) == azimuth


def test_a_wall_up_sun_shadows_the_site():
    """A wall to the north, as high as the site is low: a northern sun never lights it."""
    n = 81
    z = np.zeros((n, n))
    z[: n // 2 - 5] = 500.0
    z[:, n // 2 + 1:] -= np.arange(n - n // 2 - 1) * 0.5  # the site faces east, a little
    tile = DEMTile.from_array(z, resolution=10.0)
    site = tile.transform @ (n / 2, n / 2)
    az = lit_sun_azimuth(tile, site, 10.0, step_deg=15)
    assert not (az >= 315.0 or az <= 45.0)


def test_sites_on_the_edge_and_bad_elevations_are_refused():
    tile = DEMTile.from_array(np.zeros((9, 9)))
    with pytest.raises(InvalidParameterError, match="interior"):
        lit_sun_azimuth(tile, tile.transform @ (0.2, 4.5), 10.0)
    with pytest.raises(InvalidParameterError, match="elevation"):
        lit_sun_azimuth(tile, tile.transform @ (4.5, 4.5), 95.0)
