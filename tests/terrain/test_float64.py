"""A float64 DEM keeps its float64 heights bitwise through expand, enhance and fill.

Every output is read back twice: by rasterio, and by GDAL's own command-line tools
(``gdal_translate`` to a raw ENVI file, read with NumPy), so the check does not rest on the
reader the project writes with.
"""

import json
import shutil
import subprocess

import numpy as np
import pytest
import rasterio
from affine import Affine

from tests.cli_helpers import run

SHAPE = (49, 41)


@pytest.fixture
def dem64(tmp_path):
    """A float64 GeoTIFF whose heights float32 cannot hold (a kilometre plus sub-mm detail)."""
    rng = np.random.default_rng(4)
    z = 1737.123456789012 + rng.normal(size=SHAPE).cumsum(0).cumsum(1) * 0.21
    assert np.any(z.astype(np.float32).astype(np.float64) != z)  # float32 would move them
    path = tmp_path / "dem64.tif"
    with rasterio.open(path, "w", driver="GTiff", dtype="float64", count=1, width=SHAPE[1],
                       height=SHAPE[0], transform=Affine(8.0, 0.0, 1000.0, 0.0, -8.0, 5000.0)) as d:
        d.write(z, 1)
    return path, z


def _rasterio(path):
    with rasterio.open(path) as d:
        return d.dtypes[0], d.read(1)


def _gdal(path, tmp_path):
    """Heights as GDAL's command-line tools read them (raw float64 through ENVI)."""
    exe = shutil.which("gdal_translate")
    if exe is None or shutil.which("gdalinfo") is None:
        pytest.skip("gdal_translate/gdalinfo are not installed (Debian: apt-get install "
                    "gdal-bin)")
    info = json.loads(subprocess.run(["gdalinfo", "-json", str(path)], check=True,
                                     capture_output=True, text=True).stdout)
    band = info["bands"][0]
    raw = tmp_path / (path.stem + "_gdal.bin")
    subprocess.run([exe, "-q", "-of", "ENVI", str(path), str(raw)], check=True)
    ny, nx = info["size"][1], info["size"][0]
    return band["type"], np.fromfile(raw, dtype="<f8").reshape(ny, nx)


def _known_of(a, step, origin=(0, 0)):
    r0, c0 = origin
    i0, j0 = (-r0) % step, (-c0) % step
    return a[i0::step, j0::step], ((r0 + i0) // step, (c0 + j0) // step)


def test_expand_keeps_float64_heights_bitwise(dem64, tmp_path):
    path, z = dem64
    out = tmp_path / "x2.tif"
    result = run("terrain", "expand", path, "-o", out, "--times", "2", "--seed", "3")
    assert result.exit_code == 0, result.output
    for dtype, a in (_rasterio(out), _gdal(out, tmp_path)):
        assert dtype.lower() == "float64"
        assert np.array_equal(a[::4, ::4], z)  # every known height, bitwise


def test_expand_window_keeps_float64_heights_bitwise(dem64, tmp_path):
    path, z = dem64
    out = tmp_path / "win.tif"
    result = run("terrain", "expand", path, "-o", out, "--times", "1", "--window", "5,7,10,9")
    assert result.exit_code == 0, result.output
    dtype, a = _rasterio(out)
    assert dtype == "float64"
    assert np.array_equal(a[::2, ::2], z[7:16, 5:15])


def test_fill_keeps_float64_heights_bitwise(dem64, tmp_path):
    path, z = dem64
    out = tmp_path / "filled.tif"
    assert run("terrain", "fill", path, "-o", out).exit_code == 0
    for dtype, a in (_rasterio(out), _gdal(out, tmp_path)):
        assert dtype.lower() == "float64"
        assert np.array_equal(a, z)


def test_enhance_keeps_float64_heights_bitwise_in_every_layer(dem64, tmp_path):
    """The default enhance adds small craters, yet every known height stays, bitwise."""
    path, z = dem64
    out = tmp_path / "stack"
    result = run("terrain", "enhance", path, "-o", out, "--levels", "3", "--layer-size", "33",
                 "--seed", "2")
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    for k, layer in enumerate(manifest["layers"]):
        for dtype, a in (_rasterio(out / layer["file"]), _gdal(out / layer["file"], tmp_path)):
            assert dtype.lower() == "float64"
            known, (b_r, b_c) = _known_of(a, 2**k, layer["origin"])
            assert np.array_equal(known, z[b_r:b_r + known.shape[0], b_c:b_c + known.shape[1]])
