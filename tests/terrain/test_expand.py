"""Fractal expansion (Martin et al. 2014, IV.A): known heights kept, windows exact, realism."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import ndimage, stats

from terrain.core.tile import DEMTile, Window
from terrain.fractal.expand import expand, expanded_shape
from terrain.fractal.roughness import ExpansionParameters, estimate, local_amplitude
from terrain.surface.hillshade import horn_gradient

RNG_BASE = np.random.default_rng(7).normal(size=(40, 33)).cumsum(0).cumsum(1)


def base_tile(gaps=False):
    h = RNG_BASE.copy()
    if gaps:
        h[10:14, 5:9] = np.nan
    return DEMTile.from_array(h, resolution=16.0)


def test_known_heights_appear_unchanged_in_every_level():
    tile = base_tile()
    for times in (1, 2, 3):
        out = expand(tile, times, seed=5)
        f = 2**times
        assert out.shape == expanded_shape(tile.shape, times)
        assert out.resolution == tile.resolution / f
        assert np.array_equal(out.heights[::f, ::f], tile.heights)  # bitwise
    # and every intermediate level is contained in the next
    two = expand(tile, 2, seed=5)
    three = expand(tile, 3, seed=5)
    assert np.array_equal(three.heights[::2, ::2], two.heights)


def test_pixel_centres_stay_put():
    tile = base_tile()
    out = expand(tile, 2, seed=1)
    assert out.xy(0, 0) == tile.xy(0, 0)
    assert out.xy(8, 12) == tile.xy(2, 3)


@given(data=st.data())
def test_any_window_expands_to_the_same_pixels_as_the_full_dem(data):
    tile = base_tile()
    times = data.draw(st.integers(1, 3))
    col = data.draw(st.integers(0, tile.shape[1] - 2))
    row = data.draw(st.integers(0, tile.shape[0] - 2))
    width = data.draw(st.integers(2, tile.shape[1] - col))
    height = data.draw(st.integers(2, tile.shape[0] - row))
    full = _full(times)
    part = expand(tile, times, seed=9, window=Window(col, row, width, height))
    f = 2**times
    expected = full.heights[row * f:(row + height - 1) * f + 1, col * f:(col + width - 1) * f + 1]
    assert np.array_equal(part.heights, expected)
    assert part.xy(0, 0) == full.xy(row * f, col * f)


_FULL = {}


def _full(times):
    if times not in _FULL:
        _FULL[times] = expand(base_tile(), times, seed=9)
    return _FULL[times]


def test_same_seed_same_bytes_and_parameters_recorded():
    tile = base_tile()
    a, b = expand(tile, 2, seed=3), expand(tile, 2, seed=3)
    assert a.heights.tobytes() == b.heights.tobytes()
    assert not np.array_equal(a.heights, expand(tile, 2, seed=4).heights)
    meta = a.metadata["CRATERSCAPE_EXPANSION"]
    assert '"estimated": true' in meta and '"times": 2' in meta


def test_explicit_parameters_override_and_scale_the_roughness():
    tile = base_tile()
    smooth = ExpansionParameters.for_tile(tile, 2.2, 1e-6, local_box=0)
    rough = ExpansionParameters.for_tile(tile, 2.2, 1e-2, local_box=0)
    assert smooth.sigmas(1)[0] < rough.sigmas(1)[0]
    a = expand(tile, 1, seed=1, params=smooth)
    b = expand(tile, 1, seed=1, params=rough)
    lin = expand(tile, 1, seed=1, params=ExpansionParameters.for_tile(tile, 2.2, 0.0, 0))
    assert np.abs(a.heights - lin.heights).max() < np.abs(b.heights - lin.heights).max()


@pytest.mark.parametrize("hurst", [0.4, 0.8])
def test_displacements_are_the_fbm_prediction_errors(hurst):
    """Level 1's displacements are the RMS error of its kriging predictor on a real fBm
    surface (no larger than the Deslauriers-Dubuc predictor's error there); level 2's are
    the Deslauriers-Dubuc error one octave finer."""
    from evaluation.spectrum import fractional_brownian_surface

    def rms(x):
        return np.sqrt(np.mean(x**2))

    # pixel-scale lags of a spectrally synthesised surface are not yet self-affine: compare
    # at 4 and 8 pixels
    truth = fractional_brownian_surface(1025, hurst, rms=20.0, seed=3).heights[::4, ::4]
    truth = truth.astype(float)
    base = DEMTile.from_array(truth[::2, ::2], resolution=2.0)
    p = ExpansionParameters.for_tile(base, fractal_dimension=3 - hurst, local_box=0)
    # displacements are the fBm's prediction errors over the cascade's excess k(h)
    cubic, quadratic, linear = p.sigmas(1) * p.excess
    outer = p.weights(1)[0]
    rows = truth[::2]
    m3, m1, p1, p3 = rows[:, 0:-5:2], rows[:, 2:-3:2], rows[:, 4:-1:2], rows[:, 6::2]
    new = rows[:, 3:-2:2]
    kriging = new - (outer * (m3 + p3) + (0.5 - outer) * (m1 + p1))
    dd = new - (9 * (m1 + p1) - (m3 + p3)) / 16
    assert cubic == pytest.approx(rms(kriging), rel=0.1)
    assert rms(kriging) <= 1.01 * rms(dd)
    mean_err = rows[:, 1::2] - 0.5 * (rows[:, :-1:2] + rows[:, 2::2])
    assert linear == pytest.approx(rms(mean_err), rel=0.1)
    # one level finer, the Deslauriers-Dubuc error 2^-h times smaller (eq. 14 over two
    # half-steps)
    assert p.sigmas(2)[0] * p.excess == pytest.approx(rms(dd) * 2**-hurst, rel=0.1)


@pytest.mark.parametrize("hurst", [0.3, 0.8])
def test_cascade_excess_is_what_an_rmd_tile_measures(hurst):
    """k(h): square residual of a synthesized tile over the fBm its displacements assume."""
    from terrain.fractal.rmd import prediction_variance, synthesize
    from terrain.fractal.roughness import (
        CASCADE_EXCESS,
        CASCADE_HURST,
        SQUARE_STENCIL,
        square_residual,
    )

    z = synthesize(513, fractal_dimension=3 - hurst, relief=1.0, seed=77)
    corner2 = 1.0 - 2.0 ** (2 * hurst - 2)  # corner variance at relief 1 (eq. 15)
    v = 2.0 * corner2 / 512 ** (2 * hurst)
    e = prediction_variance(hurst, SQUARE_STENCIL, (0.25,) * 4)
    k = np.mean([square_residual(z, s)[0] / (np.sqrt(v * e) * s**hurst) for s in (2, 4, 8, 16)])
    assert k == pytest.approx(np.interp(hurst, CASCADE_HURST, CASCADE_EXCESS), rel=0.06)


def test_gaps_stay_gaps():
    tile = base_tile(gaps=True)
    out = expand(tile, 1, seed=1)
    assert np.array_equal(out.valid[::2, ::2], tile.valid)
    assert not out.valid[20:28, 10:18].any()


def test_local_roughness_map_is_exact_for_any_subregion():
    z = RNG_BASE.astype(np.float32)
    full = local_amplitude(z, 1.0, 5)
    part = local_amplitude(z, 1.0, 5, rows=(3, 17), cols=(20, 32))
    assert np.array_equal(part, full[3:18, 20:33])


def test_bad_requests():
    from terrain.core.errors import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="times"):
        expand(base_tile(), 0)
    with pytest.raises(InvalidParameterError, match="at least 2"):
        expand(base_tile(), 1, window=Window(0, 0, 1, 5))
    with pytest.raises(InvalidParameterError, match="fractal dimension"):
        ExpansionParameters(3.5, 1.0, 1.0, 10)


# ----------------------------------------------------------------- realism


def _horn_slope(heights, resolution):
    gx, gy = horn_gradient(DEMTile.from_array(heights, resolution=resolution))
    return np.degrees(np.arctan(np.hypot(gx, gy)))[1:-1, 1:-1].ravel()


def _compare(truth, resolution, factor=8, seed=0):
    n0, n1 = ((np.array(truth.shape) - 1) // factor) * factor + 1
    truth = truth[:n0, :n1]
    coarse = truth[::factor, ::factor]
    base = DEMTile.from_array(coarse, resolution=resolution * factor)
    levels = int(np.log2(factor))
    enhanced = expand(base, levels, seed=seed).heights
    assert np.array_equal(enhanced[::factor, ::factor], base.heights)
    rows, cols = np.mgrid[0:n0, 0:n1] / factor
    bicubic = ndimage.map_coordinates(coarse.astype(np.float64), [rows, cols], order=3,
                                      mode="nearest")
    s_true = _horn_slope(truth, resolution)
    ks_enh = stats.ks_2samp(s_true, _horn_slope(enhanced, resolution)).statistic
    ks_bic = stats.ks_2samp(s_true, _horn_slope(bicubic, resolution)).statistic
    return ks_enh, ks_bic, truth, enhanced, bicubic


def radial_spectrum(z, resolution):
    """Radially averaged power spectrum (Hann-windowed, plane removed)."""
    n0, n1 = z.shape
    rr, cc = np.mgrid[0:n0, 0:n1]
    a = np.c_[np.ones(z.size), rr.ravel(), cc.ravel()]
    coef = np.linalg.lstsq(a, z.ravel(), rcond=None)[0]
    z = z - (a @ coef).reshape(z.shape)
    z = z * np.outer(np.hanning(n0), np.hanning(n1))
    p = np.abs(np.fft.fftshift(np.fft.fft2(z))) ** 2
    ky = np.fft.fftshift(np.fft.fftfreq(n0, resolution))
    kx = np.fft.fftshift(np.fft.fftfreq(n1, resolution))
    k = np.hypot(*np.meshgrid(ky, kx, indexing="ij"))
    edges = np.geomspace(1 / (min(n0, n1) * resolution) * 2, 0.5 / resolution, 12)
    idx = np.digitize(k, edges)
    centres = np.sqrt(edges[:-1] * edges[1:])
    return centres, np.array([p[idx == i].mean() for i in range(1, len(edges))])


def test_expansion_continues_real_lunar_roughness(shared_file):
    """LRO NAC shape-from-shading DEM (1.08 m): decimate by 8, expand back, compare slopes.

    The Horn slope's central differences cancel the DEM's period-2 row/column pattern, so
    the truth's slope distribution is the terrain's.
    """
    from terrain.io import read_dem

    tile = read_dem(shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif"))
    ks_enh, ks_bic, truth, enhanced, bicubic = _compare(
        tile.heights.astype(np.float64), tile.resolution)
    print(f"\nSFS DEM, Horn-slope KS distance to the original: expanded {ks_enh:.3f}, "
          f"bicubic {ks_bic:.3f} (ratio {ks_enh / ks_bic:.2f})")
    for name, z in (("original", truth), ("expanded", enhanced), ("bicubic", bicubic)):
        k, p = radial_spectrum(z.astype(np.float64), tile.resolution)
        print(f"  {name:9s} power at wavelengths "
              + " ".join(f"{1 / kk:6.1f}m:{pp:9.3g}" for kk, pp in zip(k[::3], p[::3],
                                                                        strict=True)))
    # the expansion continues the real slopes at least twice as well as bicubic does
    assert ks_enh <= 0.5 * ks_bic
    # at the finest wavelengths bicubic has lost power that the expansion restores
    _, p_true = radial_spectrum(truth.astype(np.float64), tile.resolution)
    _, p_exp = radial_spectrum(enhanced.astype(np.float64), tile.resolution)
    _, p_bic = radial_spectrum(bicubic, tile.resolution)
    fine = slice(-4, None)
    assert np.all(np.abs(np.log(p_exp[fine] / p_true[fine]))
                  < np.abs(np.log(p_bic[fine] / p_true[fine])))


def fbm_surface(n, hurst, seed):
    """Fractional Brownian surface by spectral synthesis, P(k) ~ k^-(2H + 2)."""
    rng = np.random.default_rng(seed)
    k = np.hypot(np.fft.fftfreq(2 * n)[:, None], np.fft.fftfreq(2 * n)[None, :])
    k[0, 0] = 1.0
    amp = k ** (-(hurst + 1))
    amp[0, 0] = 0.0
    noise = rng.normal(size=k.shape) + 1j * rng.normal(size=k.shape)
    z = np.fft.ifft2(amp * noise).real[:n, :n]  # a quarter: no periodic wrap-around
    return z / z.std()


def test_expansion_halves_bicubics_slope_distance_on_an_fbm_with_hurst_08():
    """Spectral fBm, H = 0.8, decimated 8x and expanded back: KS <= half of bicubic's."""
    z = fbm_surface(585, 0.8, seed=2) * 60.0
    ks_enh, ks_bic, *_ = _compare(z, 1.0)
    print(f"\nfBm H=0.8: Horn-slope KS expanded {ks_enh:.3f}, bicubic {ks_bic:.3f}")
    assert ks_enh <= 0.5 * ks_bic


@pytest.mark.parametrize("hurst", [0.3, 0.5, 0.7, 0.8, 0.9])
def test_expansion_continues_the_hurst_exponent_of_a_decimated_fbm(hurst):
    """Spectral H of a decimated (8x), re-expanded fBm (the default, estimated parameters) is
    within 0.05 of nominal."""
    from evaluation.spectrum import fit_hurst, fractional_brownian_surface
    from evaluation.spectrum import radial_spectrum as spectrum

    t = fractional_brownian_surface(1025, hurst, rms=50.0, seed=0)
    coarse = DEMTile.from_array(t.heights[::8, ::8], resolution=8.0)
    e = expand(coarse, 3, seed=0)
    assert fit_hurst(spectrum(e)).hurst == pytest.approx(hurst, abs=0.05)


def test_expansion_beats_bicubic_on_a_known_fbm_surface():
    z = fbm_surface(585, 0.5, seed=2) * 60.0
    ks_enh, ks_bic, *_ = _compare(z, 1.0)
    print(f"\nfBm H=0.5: Horn-slope KS expanded {ks_enh:.3f}, bicubic {ks_bic:.3f}")
    assert ks_enh <= 0.45 * ks_bic
    fit = estimate(DEMTile.from_array(z[::8, ::8], resolution=8.0))
    assert 0.45 < fit.hurst < 0.75


def test_the_same_bytes_on_one_thread_as_on_three():
    """Each pass runs in parallel blocks of rows; the noise is keyed by position alone."""
    from terrain.core.parallel import limited
    from terrain.fractal.synthetic import synthesize_tile

    tile = synthesize_tile(129, resolution=4.0, relief=50.0, seed=2).tile
    with limited(3):
        many = expand(tile, 2, seed=9)
    with limited(1):
        one = expand(tile, 2, seed=9)
    assert np.array_equal(many.heights, one.heights, equal_nan=True)
    assert np.array_equal(many.heights[::4, ::4], tile.heights)  # known heights kept
