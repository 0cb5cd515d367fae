"""Synthetic DEMs on a body carry a CRS (terrain/core/bodies.py, terrain.io.synthetic_crs), and a
global DEM reprojects onto a pole (terrain.io.reproject_polar)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import rasterio

from terrain.core.tile import DEMTile
from terrain.io import lonlat_to_xy, read_dem, reproject_polar
from tests.cli_helpers import one_line_error, run

MOON_R = 1737400.0
EQC_MOON = ('PROJCS["unknown",GEOGCS["unknown",DATUM["unknown",SPHEROID["unknown",1737400,0]],'
            'PRIMEM["Reference meridian",0],UNIT["degree",0.0174532925199433]],'
            'PROJECTION["Equirectangular"],PARAMETER["standard_parallel_1",0],'
            'PARAMETER["central_meridian",0],PARAMETER["false_easting",0],'
            'PARAMETER["false_northing",0],UNIT["metre",1],AXIS["Easting",EAST],'
            'AXIS["Northing",NORTH]]')


def test_a_moon_dem_opens_at_the_south_pole_with_the_same_heights(tmp_path):
    plain, moon = tmp_path / "plain.tif", tmp_path / "moon.tif"
    args = ["--size", 33, "--resolution", 100.0, "--seed", 3]
    assert run("terrain", "synth", "-o", plain, *args, "--local-grid").exit_code == 0
    result = run("terrain", "synth", "-o", moon, *args, "--body", "moon")
    assert result.exit_code == 0, result.output
    with rasterio.open(moon) as ds:  # GDAL places it
        assert ds.crs is not None and ds.crs.is_projected
        centre = ds.transform @ (ds.width / 2, ds.height / 2)
    tile = read_dem(moon)
    # the pole, found through PROJ from the CRS alone, is the tile's centre
    assert np.allclose(lonlat_to_xy(tile.crs, 0.0, -90.0), centre, atol=1e-6)
    # 1 km from the pole along the tile's y axis is 1 km of arc (stereographic, k = 1)
    x, y = lonlat_to_xy(tile.crs, 0.0, -90.0 + math.degrees(1000.0 / MOON_R))
    assert abs(math.hypot(x - centre[0], y - centre[1]) - 1000.0) < 0.01
    assert np.array_equal(tile.heights, read_dem(plain).heights)
    assert tile.transform == read_dem(plain).transform


def test_a_site_centred_orthographic_dem(tmp_path):
    out = tmp_path / "ortho.tif"
    result = run("terrain", "synth", "-o", out, "--size", 17, "--body", "moon",
                 "--crs", "ortho:10,-85")
    assert result.exit_code == 0, result.output
    tile = read_dem(out)
    centre = tile.transform @ (8.5, 8.5)
    assert np.allclose(lonlat_to_xy(tile.crs, 10.0, -85.0), centre, atol=1e-6)


@pytest.mark.parametrize("args, fragment", [
    (["--local-grid", "--crs", "south-polar"], "--local-grid"),
    (["--body", "moom"], "did you mean 'moon'"),
    (["--body", "moon", "--crs", "ortho:10"], "ortho:LON,LAT"),
    (["--body", "moon", "--crs", "mercator"], "unknown --crs"),
])
def test_bad_bodies_and_projections_are_one_line(tmp_path, args, fragment):
    one_line_error(run("terrain", "synth", "-o", tmp_path / "x.tif", "--size", 17, *args),
                   fragment)
    assert not (tmp_path / "x.tif").exists()


def test_every_layer_of_a_stack_on_the_moon_is_georeferenced(tmp_path):
    base, stack = tmp_path / "base.tif", tmp_path / "stack"
    assert run("terrain", "synth", "-o", base, "--size", 65, "--resolution", 50.0,
               "--relief", 200.0, "--body", "moon").exit_code == 0
    # the site by longitude/latitude: 500 m of arc from the pole along longitude 0
    lat = -90.0 + math.degrees(500.0 / MOON_R)
    result = run("terrain", "enhance", base, "-o", stack, "--site-lonlat", f"0,{lat}",
                 "--levels", 2, "--layer-size", 33)
    assert result.exit_code == 0, result.output
    layers = sorted(stack.rglob("*.tif"))
    assert len(layers) >= 3
    crs = read_dem(base).crs
    for path in layers:
        with rasterio.open(path) as ds:
            assert ds.crs is not None and ds.crs == rasterio.crs.CRS.from_wkt(crs), path


def test_a_global_dem_reprojects_onto_the_pole_with_its_latitudes():
    """Heights equal to the latitude (degrees) land where the inverse stereographic
    projection, written out here, says: lat = 2 atan(rho / 2R) - 90 degrees."""
    res = 2 * math.pi * MOON_R / 720  # half a degree
    lat = 90.0 - (np.arange(360) + 0.5) * 0.5
    z = np.repeat(lat[:, None], 720, axis=1)
    from affine import Affine

    src = DEMTile.from_array(z, transform=Affine(res, 0, -math.pi * MOON_R, 0, -res,
                                                 math.pi * MOON_R / 2), crs=EQC_MOON)
    out = reproject_polar(src, radius=MOON_R, half_width_m=400_000.0)
    assert out.crs is not None and out.shape[0] == out.shape[1]
    ny, nx = out.shape
    rows, cols = np.mgrid[0:ny:7, 0:nx:7]
    x, y = out.transform @ (cols + 0.5, rows + 0.5)
    expected = np.degrees(2 * np.arctan(np.hypot(x, y) / (2 * MOON_R))) - 90.0
    got = out.heights[rows, cols]
    ok = np.isfinite(got)
    assert ok.mean() > 0.9
    assert np.abs(got[ok] - expected[ok]).max() < 0.3  # bilinear on half-degree rows
