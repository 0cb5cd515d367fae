"""Horn slope and aspect against gdaldem and analytic surfaces; distributions; resampling."""

import math
import shutil
import subprocess

import numpy as np
import pytest
import rasterio
from hypothesis import given
from hypothesis import strategies as st

from evaluation.compare import compare_slope_maps
from evaluation.slope import (
    DEFAULT_ANGLES,
    cumulative_distribution,
    horn,
    horn_slope,
    matched_baseline,
    resample,
    slope_distribution,
    slope_tile,
    stack_distributions,
    weighted_quantiles,
)
from evaluation.spectrum import fractional_brownian_surface
from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.io import read_dem, write_dem

#: Required agreement with gdaldem on interior pixels (degrees).
GDAL_TOLERANCE_DEG = 1e-4


def gdaldem(kind, path, out, *extra):
    exe = shutil.which("gdaldem")
    if exe is None:
        pytest.skip("gdaldem is not installed (Debian: apt-get install gdal-bin)")
    subprocess.run([exe, kind, "-alg", "Horn", "-q", *extra, str(path), str(out)], check=True)
    with rasterio.open(out) as src:
        a = src.read(1).astype(np.float32)
        if src.nodata is not None:
            a[a == np.float32(src.nodata)] = np.nan
    return a


def gappy_dem(tmp_path, offset=0.0):
    """A rough 97 x 83 DEM (2.5 m pixels) with a hole and scattered nodata pixels."""
    t = fractional_brownian_surface(97, 0.75, resolution=2.5, rms=6.0, seed=11)
    h = t.heights[:, :83].astype(np.float64) + offset
    h[40:47, 30:38] = np.nan
    h[5, 70] = np.nan
    h[90, 3] = np.nan
    tile = DEMTile.from_array(h, resolution=2.5)
    path = tmp_path / "gappy.tif"
    write_dem(tile.replace(nodata=-9999.0), path)
    return read_dem(path), path


@pytest.mark.parametrize("edges,flags", [("mask", ()), ("gdal", ("-compute_edges",))])
def test_slope_and_aspect_agree_with_gdaldem_including_gaps_and_edges(tmp_path, edges, flags):
    tile, path = gappy_dem(tmp_path)
    ours_s, ours_a = horn(tile, edges=edges)
    theirs_s = gdaldem("slope", path, tmp_path / "s.tif", *flags)
    theirs_a = gdaldem("aspect", path, tmp_path / "a.tif", *flags)
    # the same pixels are missing (edges, gap neighbours) ...
    assert np.array_equal(np.isnan(ours_s), np.isnan(theirs_s))
    assert np.array_equal(np.isnan(ours_a), np.isnan(theirs_a))
    # ... and the others agree, to well within 1e-4 degrees (bitwise in practice)
    assert np.nanmax(np.abs(ours_s - theirs_s)) <= GDAL_TOLERANCE_DEG
    d = np.abs(((ours_a - theirs_a) + 180.0) % 360.0 - 180.0)
    assert np.nanmax(d) <= GDAL_TOLERANCE_DEG
    if edges == "gdal":
        assert np.isfinite(ours_s[0, 0]) and np.isfinite(ours_s[-1, -1])
    else:
        assert np.isnan(ours_s[0]).all() and np.isnan(ours_s[:, -1]).all()
        assert np.isnan(ours_s[41, 31])  # next to the hole


def test_real_dem_agrees_with_gdaldem_and_the_quickmap_slope_band(tmp_path, shared_file):
    path = shared_file("lunar", "aristarchus_IMP_quickmap_hsr_4p76m.tif")
    tile = read_dem(path)
    ours = horn_slope(tile)
    theirs = gdaldem("slope", path, tmp_path / "s.tif")
    assert np.nanmax(np.abs(ours - theirs)) <= GDAL_TOLERANCE_DEG
    # QuickMap's own slope band was computed independently, by LROC's tools
    quickmap = read_dem(path, band=2).heights
    agreement = compare_slope_maps(ours, quickmap)
    assert agreement.pixels > 0.95 * tile.heights.size
    assert agreement.median_abs_deg < 0.01
    assert agreement.p99_abs_deg < 0.1
    assert agreement.correlation > 0.9999


def test_slope_of_analytic_planes_is_exact():
    y, x = np.mgrid[0:40, 0:50].astype(np.float64)
    for gx, gy in [(0.3, 0.0), (-0.2, 0.5), (1.0, -1.0), (0.0, 0.0)]:
        res = 2.0
        # rows go south: map y = -row * res
        h = gx * x * res - gy * y * res
        s, a = horn(DEMTile.from_array(h, resolution=res), edges="gdal")
        expected = math.degrees(math.atan(math.hypot(gx, gy)))
        # edges extrapolated linearly are exact too, except GDAL's four corners, which
        # repeat the edge column and so see half the east-west gradient
        corners = np.zeros(s.shape, dtype=bool)
        corners[[0, 0, -1, -1], [0, -1, 0, -1]] = True
        assert np.allclose(s[~corners], expected, atol=1e-4)
        half = math.degrees(math.atan(math.hypot(gx / 2, gy)))
        assert np.allclose(s[corners], half, atol=1e-4)
        a[corners] = np.nan
        if gx or gy:
            azimuth = math.degrees(math.atan2(-gx, -gy)) % 360.0
            d = ((a[~corners] - azimuth) + 180) % 360 - 180
            assert np.allclose(d, 0.0, atol=1e-3)
        else:
            assert np.isnan(a).all()  # flat: no aspect


def test_slope_of_a_paraboloid_matches_its_gradient():
    """z = (x^2 + y^2) / (2 R): Horn's stencil is exact for quadratics (central differences)."""
    res, radius = 1.0, 80.0
    c = np.arange(-60, 61) * res
    x, y = np.meshgrid(c, -c)
    tile = DEMTile.from_array((x**2 + y**2) / (2 * radius), resolution=res)
    s = horn_slope(tile)
    expected = np.degrees(np.arctan(np.hypot(x, y) / radius))
    inner = np.isfinite(s)
    assert inner.sum() == (len(c) - 2) ** 2
    assert np.max(np.abs(s[inner] - expected[inner])) < 1e-3


def test_slope_tile_keeps_georeferencing_and_says_what_it_holds():
    t = fractional_brownian_surface(33, 0.8, resolution=3.0, seed=1)
    st_ = slope_tile(t)
    assert st_.transform == t.transform and st_.shape == t.shape
    assert st_.metadata["CRATERSCAPE_QUANTITY"] == "Horn slope (degrees)"
    assert not st_.valid[0].any() and st_.valid[1:-1, 1:-1].all()


def test_bad_edges_mode_is_refused():
    with pytest.raises(InvalidParameterError, match="edges must be one of"):
        horn(DEMTile.from_array(np.zeros((4, 4))), edges="replicate")


# ------------------------------------------------------------------------ distributions


@given(st.lists(st.floats(0.0, 89.0), min_size=1, max_size=60))
def test_cumulative_distribution_is_a_survival_function(values):
    pct = cumulative_distribution(values)
    assert np.all(np.diff(pct) <= 1e-12)
    assert pct[0] == pytest.approx(100.0 * np.mean(np.asarray(values) > 0.0))
    assert pct[-1] == 0.0
    # percentage above a threshold counts exactly the values above it
    for k in (10, 60, 120):
        assert pct[k] == pytest.approx(100.0 * np.mean(np.asarray(values) > DEFAULT_ANGLES[k]))


def test_weights_count_like_repeated_values():
    v = np.array([1.0, 5.0, 12.0])
    w = np.array([1.0, 3.0, 2.0])
    repeated = np.repeat(v, w.astype(int))
    assert np.allclose(cumulative_distribution(v, weights=w), cumulative_distribution(repeated))
    q = weighted_quantiles(v, weights=w, quantiles=(0.5,))
    assert q["p50"] == 5.0 and q["mean"] == pytest.approx(repeated.mean())


def test_unweighted_quantiles_are_the_order_statistics_numpy_interpolates():
    # against NumPy's quantile asked one fraction at a time, bit for bit: sizes where the
    # fractions fall between and on samples, ties, and a single value
    rng = np.random.default_rng(11)
    for n in (1, 2, 7, 100, 1001, 40_000):
        for v in (rng.gamma(2.0, 3.0, n), np.round(rng.normal(10.0, 4.0, n), 1)):
            got = weighted_quantiles(v)
            for q in (0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99):
                assert got[f"p{round(q * 100):d}"] == float(np.quantile(v, q))
    assert weighted_quantiles(np.arange(11.0), quantiles=(0.05, 0.5)) == {
        "p5": 0.5, "p50": 5.0, "mean": 5.0, "max": 10.0}


def test_slope_distribution_of_a_dem():
    t = fractional_brownian_surface(65, 0.8, resolution=1.0, rms=4.0, seed=2)
    d = slope_distribution(t, label="fbm")
    s = horn_slope(t)
    assert d.pixels == 63 * 63
    assert d.quantiles["p50"] == pytest.approx(float(np.nanmedian(s)))
    assert d.percent_steeper[0] == pytest.approx(100.0)


def test_stack_distributions_one_per_layer(tmp_path):
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(33, resolution=8.0, relief=30.0, seed=3).tile
    stack = build_stack(base, (128.0, 128.0), levels=2, layer_size=17, seed=4)
    folder = write_stack(stack, tmp_path / "stack")
    dists = stack_distributions(folder)
    assert [d.label for d in dists] == ["stack_layer_00", "stack_layer_01", "stack_layer_02"]
    assert [d.resolution_m for d in dists] == [8.0, 4.0, 2.0]
    assert stack_distributions(folder / "manifest.json")[1].pixels == dists[1].pixels


# --------------------------------------------------------------------------- resampling


def test_resample_averages_areas_exactly():
    h = np.add.outer(np.arange(12.0), 10 * np.arange(9.0))  # a plane
    t = DEMTile.from_array(h, resolution=1.0)
    r = resample(t, 3.0)
    assert r.shape == (4, 3) and r.resolution == 3.0
    assert np.allclose(r.heights, h.reshape(4, 3, 3, 3).mean(axis=(1, 3)))
    # a non-integer factor weights each fine pixel by the area it shares: the first coarse
    # column takes fine columns 0 and 1 whole and half of column 2
    r2 = resample(t, 2.5)
    assert r2.shape == (4, 3)
    assert r2.heights[0, 0] == pytest.approx((0 + 1 + 0.5 * 2) / 2.5 * 11, rel=1e-6)
    # where the coarse grid covers the fine one exactly, the mean is preserved
    t10 = DEMTile.from_array(h[:10, :5], resolution=1.0)
    assert resample(t10, 2.5).heights.mean() == pytest.approx(h[:10, :5].mean(), rel=1e-6)
    assert r2.transform.c == t.transform.c and r2.transform.f == t.transform.f


def test_resample_leaves_gaps_unfilled_and_refuses_refining():
    h = np.ones((8, 8))
    h[2, 3] = np.nan
    r = resample(DEMTile.from_array(h), 2.0)
    assert not r.valid[1, 1] and r.valid.sum() == 15
    with pytest.raises(InvalidParameterError, match="coarser grid"):
        resample(DEMTile.from_array(h), 0.5)


def test_matched_baseline_brings_both_to_the_coarser_spacing():
    fine = fractional_brownian_surface(128, 0.7, resolution=1.0, seed=4)
    coarse = fractional_brownian_surface(40, 0.7, resolution=3.0, seed=5)
    a, b = matched_baseline(fine, coarse)
    assert a.resolution == b.resolution == 3.0
    assert b is coarse and a.shape == (42, 42)


@given(st.integers(3, 12), st.integers(3, 12), st.integers(0, 2**32 - 1),
       st.floats(0.0, 0.4))
def test_masked_slopes_are_missing_exactly_where_a_window_touches_a_gap(ny, nx, seed, gaps):
    rng = np.random.default_rng(seed)
    h = rng.normal(0.0, 5.0, (ny, nx))
    h[rng.random((ny, nx)) < gaps] = np.nan
    tile = DEMTile.from_array(h, resolution=0.5)
    s, a = horn(tile)
    bad = np.ones((ny + 2, nx + 2), dtype=bool)
    bad[1:-1, 1:-1] = ~tile.valid
    touched = np.zeros((ny, nx), dtype=bool)
    for dr in range(3):
        for dc in range(3):
            touched |= bad[dr:dr + ny, dc:dc + nx]
    assert np.array_equal(np.isnan(s), touched)
    assert np.all((s[~touched] >= 0) & (s[~touched] <= 90))
    assert np.all(np.isnan(a[touched]))
    # compute_edges: only the invalid pixels themselves are missing
    s2, _ = horn(tile, edges="gdal")
    assert np.array_equal(np.isnan(s2), ~tile.valid)
