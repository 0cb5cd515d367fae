"""Radially averaged power spectra and Hurst exponents, on surfaces of known exponent."""

import numpy as np
import pytest

from evaluation.spectrum import (
    fit_hurst,
    fractional_brownian_surface,
    radial_spectrum,
)
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.tile import DEMTile

#: Acceptance figure for the Hurst exponent.
HURST_TOLERANCE = 0.05


@pytest.mark.parametrize("hurst", [0.2, 0.4, 0.6, 0.8, 1.0])
def test_hurst_exponent_recovered_within_0_05(hurst):
    errors = []
    for seed in (1, 2, 3):
        tile = fractional_brownian_surface(512, hurst, resolution=2.0, rms=10.0, seed=seed)
        fit = fit_hurst(radial_spectrum(tile))
        errors.append(fit.hurst - hurst)
        assert fit.r_squared > 0.98
    print(f"H = {hurst}: errors {np.round(errors, 4).tolist()}")
    assert max(abs(e) for e in errors) <= HURST_TOLERANCE


def test_window_matters_for_non_periodic_dems():
    """Without the Hann window the edge jump adds f^-2 leakage: steep spectra read flatter."""
    tile = fractional_brownian_surface(256, 0.9, seed=7)
    with_window = fit_hurst(radial_spectrum(tile)).hurst
    without = fit_hurst(radial_spectrum(tile, window="none")).hurst
    assert abs(with_window - 0.9) < abs(without - 0.9)
    assert without < 0.75


def test_power_is_normalised_so_it_integrates_to_the_variance():
    """Parseval: sum(P * counts) dfx dfy is the variance (a sinusoid's lies inside the bins)."""
    n, d = 128, 0.5
    x = np.arange(n) * d
    z = 3.0 * np.sin(2 * np.pi * x / 8.0)[None, :] + 1.0 * np.cos(2 * np.pi * x / 5.0)[:, None]
    s = radial_spectrum(DEMTile.from_array(z, resolution=d), detrend="mean", window="none")
    df = 1.0 / (n * d)
    assert np.sum(s.power * s.counts) * df * df == pytest.approx(np.var(z), rel=1e-6)
    # with the Hann window the power is renormalised by the window's own power
    w = radial_spectrum(DEMTile.from_array(z, resolution=d), detrend="mean")
    assert np.sum(w.power * w.counts) * df * df == pytest.approx(np.var(z), rel=0.05)


def test_plane_detrending_removes_a_tilt():
    tile = fractional_brownian_surface(128, 0.7, rms=1.0, seed=9)
    r, c = np.mgrid[0:128, 0:128]
    tilted = tile.replace(heights=tile.heights + 0.5 * c + 0.2 * r)
    a = radial_spectrum(tile)
    b = radial_spectrum(tilted)
    assert np.allclose(a.power, b.power, rtol=1e-3)
    c_ = radial_spectrum(tilted, detrend="mean")
    assert c_.power[0] > 100 * a.power[0]


def test_gaps_warn_and_small_dems_are_refused(caplog):
    h = fractional_brownian_surface(64, 0.7, seed=1).heights.astype(np.float64)
    h[:20, :20] = np.nan
    radial_spectrum(DEMTile.from_array(h), label="gappy")
    assert "invalid" in caplog.text and "gappy" in caplog.text
    with pytest.raises(InvalidDEMError, match="at least 8 x 8"):
        radial_spectrum(DEMTile.from_array(np.zeros((6, 40))))
    with pytest.raises(InvalidParameterError, match="window must be one of"):
        radial_spectrum(DEMTile.from_array(np.zeros((16, 16))), window="kaiser")
    with pytest.raises(InvalidParameterError, match="Hurst exponent must lie"):
        fractional_brownian_surface(64, 1.5)


def test_synthesis_is_reproducible_and_keyed_by_seed():
    a = fractional_brownian_surface(32, 0.6, seed=4)
    b = fractional_brownian_surface(32, 0.6, seed=4)
    c = fractional_brownian_surface(32, 0.6, seed=5)
    assert np.array_equal(a.heights, b.heights)
    assert not np.array_equal(a.heights, c.heights)
    assert a.metadata["CRATERSCAPE_SEED"] == "4"
