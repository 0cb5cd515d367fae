"""Hillshade against GDAL's gdaldem (an independent implementation of Horn's gradients)."""

import shutil
import subprocess

import numpy as np
import pytest
import rasterio

from terrain.fractal.synthetic import synthesize_tile
from terrain.io import write_dem
from terrain.surface.hillshade import hillshade


@pytest.mark.parametrize("azimuth, altitude", [(315.0, 45.0), (90.0, 20.0)])
def test_hillshade_agrees_with_gdaldem(tmp_path, azimuth, altitude):
    gdaldem = shutil.which("gdaldem")
    if gdaldem is None:
        pytest.skip("gdaldem (Debian gdal-bin) is not installed; `make test` installs it")
    tile = synthesize_tile(129, resolution=2.0, relief=20.0, seed=4).tile
    src = write_dem(tile, tmp_path / "dem.tif")
    out = tmp_path / "hs.tif"
    subprocess.run([gdaldem, "hillshade", "-az", str(azimuth), "-alt", str(altitude),
                    "-compute_edges", "-q", str(src), str(out)], check=True)
    with rasterio.open(out) as f:
        reference = f.read(1).astype(int)
    ours = hillshade(tile, azimuth=azimuth, altitude=altitude).astype(int)
    assert np.abs(ours[1:-1, 1:-1] - reference[1:-1, 1:-1]).max() <= 1


def test_gaps_are_black():
    from terrain.core.tile import DEMTile

    h = np.zeros((5, 5))
    h[2, 2] = np.nan
    img = hillshade(DEMTile.from_array(h))
    assert img[2, 2] == 0 and img[1, 1] == 0 and img[0, 0] > 0
