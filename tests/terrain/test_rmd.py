"""Diamond-square synthesis (Martin et al. 2014, eqs. 13-16): windows, scaling, validation."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import Window
from terrain.fractal.rmd import initial_scale, scale_factor, synthesize

FULL = {}


def full_tile(size, seed):
    if (size, seed) not in FULL:
        FULL[size, seed] = synthesize(size, seed=seed, relief=10.0)
    return FULL[size, seed]


@given(size=st.sampled_from([3, 5, 33, 129]), data=st.data())
def test_any_window_equals_the_same_window_of_the_full_tile(size, data):
    col = data.draw(st.integers(0, size - 1))
    row = data.draw(st.integers(0, size - 1))
    width = data.draw(st.integers(1, size - col))
    height = data.draw(st.integers(1, size - row))
    window = Window(col, row, width, height)
    part = synthesize(size, seed=4, relief=10.0, window=window)
    assert np.array_equal(part, full_tile(size, 4)[window.slices])


def test_same_seed_same_bytes_and_origin_keys_the_randomness():
    a = synthesize(65, seed=9)
    assert a.tobytes() == synthesize(65, seed=9).tobytes()
    assert not np.array_equal(a, synthesize(65, seed=10))
    assert not np.array_equal(a, synthesize(65, seed=9, origin=(64, 0)))


def test_scale_factors_follow_eqs_14_and_15():
    f = 2.3
    assert scale_factor(f) == pytest.approx(1 / 2 ** ((3 - f) / 2))
    # eq. 15 with relief = H * D_r * W
    assert initial_scale(f, 50.0) == pytest.approx(
        scale_factor(f) * 50.0 * math.sqrt(1 - 2 ** (2 * (3 - f) - 2)))


@pytest.mark.parametrize("f", [2.1, 2.3, 2.5])
def test_height_increments_scale_with_the_hurst_exponent(f):
    """fBm: E[(z(x + l) - z(x))^2] ~ l^(2H) with H = 3 - F (structure-function slope)."""
    z = synthesize(1025, fractal_dimension=f, relief=100.0, seed=21)
    lags = np.array([2, 4, 8, 16, 32, 64])
    sf = [np.mean((z[:, lag:] - z[:, :-lag]) ** 2) + np.mean((z[lag:, :] - z[:-lag, :]) ** 2)
          for lag in lags]
    slope = np.polyfit(np.log(lags), np.log(sf), 1)[0]
    assert slope / 2 == pytest.approx(3 - f, abs=0.12)


def test_relief_scales_heights_linearly():
    a = synthesize(129, seed=2, relief=1.0)
    b = synthesize(129, seed=2, relief=7.0)
    assert np.allclose(b, 7.0 * a, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("kwargs, message", [
    (dict(size=100), "2\\^n \\+ 1"),
    (dict(size=1), "2\\^n \\+ 1"),
    (dict(size=65, fractal_dimension=3.0), "fractal dimension"),
    (dict(size=65, relief=-1.0), "relief"),
    (dict(size=65, window=Window(60, 0, 10, 10)), "does not fit"),
])
def test_bad_requests_are_refused(kwargs, message):
    with pytest.raises(InvalidParameterError, match=message):
        synthesize(**kwargs)


def test_huge_tiles_are_refused_before_allocating(monkeypatch):
    from terrain.core.errors import MemoryRequestError

    monkeypatch.setenv("CRATERSCAPE_MEMORY_LIMIT", "64M")
    with pytest.raises(MemoryRequestError, match="needs about"):
        synthesize(2**16 + 1)


@pytest.mark.parametrize("hurst", [0.3, 0.5, 0.7, 0.8, 0.9])
def test_spectral_hurst_exponent_is_the_nominal_one(hurst):
    """The radially averaged power spectrum of a synthesized tile has slope -(2H + 2)."""
    from evaluation.spectrum import fit_hurst, radial_spectrum
    from terrain.core.tile import DEMTile

    fits = [fit_hurst(radial_spectrum(DEMTile.from_array(
        synthesize(513, fractal_dimension=3 - hurst, relief=100.0, seed=seed)))).hurst
        for seed in (0, 1)]
    assert np.mean(fits) == pytest.approx(hurst, abs=0.05)
