"""`terrain enhance` of a real DEM adds, by default, the small craters the DEM cannot resolve.

The count is checked against the published law the preset names (the empirical equilibrium
N(>=D) = 10^-1.1 D_km^-2 per km^2 = 0.0794 D^-2 per m^2, Trask 1966, times the preset's
multiple), and every known height of the input stays, bitwise, in every layer.
"""

import json

import numpy as np
import pytest
from scipy import integrate

from terrain.core.presets import preset
from terrain.core.tile import DEMTile
from terrain.craters.cratering import CraterModel
from terrain.io import write_dem
from tests.cli_helpers import run

#: Trask (1966) equilibrium: N(>=D) = 10^-1.1 D_km^-2 per km^2, i.e. 0.0794 D^-2 per m^2 (D in m).
TRASK_C = 10 ** -1.1


@pytest.fixture
def real_like_dem(tmp_path):
    """A 2 m/pixel DEM with fractal relief, standing in for an orbital DEM."""
    rng = np.random.default_rng(11)
    z = rng.normal(size=(97, 97)).cumsum(0).cumsum(1) * 0.05
    path = tmp_path / "dem.tif"
    write_dem(DEMTile.from_array(z, resolution=2.0), path)
    return path, z.astype(np.float32)


def _expected_in_layer(c_per_m2, dmin, dmax, side_m, factor):
    """Craters of N(>=D) = c D^-2 whose whole footprint (radius factor D) fits in a square."""
    def density(d):  # -dN/dD
        return 2.0 * c_per_m2 * d**-3 * max(0.0, side_m - 2.0 * factor * d) ** 2
    return integrate.quad(density, dmin, dmax)[0]


def test_enhance_adds_the_presets_unresolved_craters_by_default(real_like_dem, tmp_path):
    path, z = real_like_dem
    out = tmp_path / "stack"
    result = run("terrain", "enhance", path, "-o", out, "--levels", "3", "--layer-size", "513",
                 "--seed", "5")
    assert result.exit_code == 0, result.output
    manifest = json.loads((out / "manifest.json").read_text())
    craters = np.genfromtxt(out / "craters.csv", delimiter=",", names=True, dtype=None,
                            encoding="utf-8")
    finest = manifest["layers"][-1]
    res = finest["resolution"]
    dmin, dmax = 4 * res, 4 * 2.0  # 4 pixels of the finest layer .. 4 of the DEM's
    assert craters["diameter_m"].min() >= dmin - 1e-9
    assert craters["diameter_m"].max() < dmax
    assert not np.any(craters["layer"] == 0)  # nothing the DEM itself resolves
    # the finest layer takes every crater of [dmin, dmax) whose footprint it holds
    in_finest = craters["layer"] == len(manifest["layers"]) - 1
    c = preset("south-polar").crater_equilibrium * TRASK_C
    expected = _expected_in_layer(c, dmin, dmax, 513 * res, CraterModel().footprint_factor)
    n = int(in_finest.sum())
    print(f"\nfinest layer: {n} craters, {expected:.1f} expected; {len(craters)} in all")
    assert expected > 100
    assert abs(n - expected) < 3 * np.sqrt(expected), (n, expected)
    # their sizes follow the -2 law: craters of 2 dmin and larger against all of them
    big = _expected_in_layer(c, 2 * dmin, dmax, 513 * res, CraterModel().footprint_factor)
    share = np.mean(craters["diameter_m"][in_finest] >= 2 * dmin)
    assert share == pytest.approx(big / expected, abs=3 * np.sqrt(big) / expected)
    # every known height stays, bitwise, in every layer (float32 input: float32 layers)
    import rasterio

    for k, layer in enumerate(manifest["layers"]):
        with rasterio.open(out / layer["file"]) as d:
            a = d.read(1)
        f = 2**k
        r0, c0 = layer["origin"]
        i0, j0 = (-r0) % f, (-c0) % f
        known = a[i0::f, j0::f]
        b_r, b_c = (r0 + i0) // f, (c0 + j0) // f
        assert np.array_equal(known, z[b_r:b_r + known.shape[0], b_c:b_c + known.shape[1]])


def test_a_stack_without_finer_layers_gets_no_craters(real_like_dem, tmp_path):
    """The base resolves every crater its own pixels can: with no level there is none to add."""
    path, _ = real_like_dem
    out = tmp_path / "flat"
    result = run("terrain", "enhance", path, "-o", out, "--levels", "0", "--layer-size", "33")
    assert result.exit_code == 0, result.output
    assert "0 craters" in result.output


def test_an_unknown_preset_is_refused_in_one_line(real_like_dem, tmp_path):
    from tests.cli_helpers import one_line_error

    path, _ = real_like_dem
    result = run("terrain", "enhance", path, "-o", tmp_path / "s", "--levels", "1",
                 "--terrain", "south polar")
    one_line_error(result, "terrain")


def test_default_craters_chunk_by_chunk_equal_the_in_memory_stack(real_like_dem, tmp_path):
    """The known-height rule is a function of position: a chunked build gives the same bytes."""
    from terrain.stack.store import read_stack

    path, _ = real_like_dem
    common = ["--levels", "3", "--layer-size", "65", "--seed", "7"]
    mem, chunked = tmp_path / "mem", tmp_path / "chunked"
    assert run("terrain", "enhance", path, "-o", mem, *common).exit_code == 0
    r = run("terrain", "enhance", path, "-o", chunked, *common, "--chunk", "16")
    assert r.exit_code == 0, r.output
    a, b = read_stack(mem), read_stack(chunked)
    assert len(a.catalog) > 0
    for ta, tb in zip(a.tiles, b.tiles, strict=True):
        assert np.array_equal(ta.heights, tb.heights)
    assert np.array_equal(a.catalog.id, b.catalog.id)
