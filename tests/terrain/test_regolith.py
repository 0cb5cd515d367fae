"""Regolith below a metre: the slope rises toward the measured centimetre values.

Published values the fine layers are held to (``docs/roughness.md``): RMS slopes of ~10-20 deg
at centimetre baselines (Helfenstein and Shepard 1999, Icarus 141, 107; Bandfield et al. 2015
and Hayne et al. 2021 from Diviner), a Hurst exponent of 0.5-0.7 (Helfenstein and Shepard
1999) or 0.6-0.85 (Guo et al. 2021, GRL 48, Chang'e-4 at 5 mm/pixel), and slopes that grow
as the baseline shrinks.
"""

import math

import numpy as np
import pytest

from terrain.core.errors import InvalidParameterError
from terrain.fractal.regolith import RegolithLaw
from terrain.fractal.roughness import RoughnessChoice
from terrain.fractal.synthetic import synthesize_tile
from terrain.stack.build import build_stack

#: Published RMS slope range at centimetre baselines (deg).
CM_RMS_SLOPE_DEG = (10.0, 20.0)
#: Published Hurst exponents of the regolith below a metre (the union of the two studies).
REGOLITH_HURST_RANGE = (0.5, 0.85)


def _detrended(z):
    z = z.astype(np.float64)
    rr, cc = np.mgrid[0:z.shape[0], 0:z.shape[1]]
    a = np.c_[np.ones(z.size), rr.ravel(), cc.ravel()]
    return z - (a @ np.linalg.lstsq(a, z.ravel(), rcond=None)[0]).reshape(z.shape)


def _rms_difference(z, lag):
    dx = (z[:, lag:] - z[:, :-lag]).ravel()
    dy = (z[lag:] - z[:-lag]).ravel()
    return math.sqrt(np.mean(np.r_[dx, dy] ** 2))


def _rms_slope_deg(stack, baseline):
    """RMS slope (plane removed) at ``baseline`` m, in the coarsest layer giving >= 2 pixels."""
    for tile in stack.tiles:
        lag = baseline / tile.resolution
        if (abs(lag - round(lag)) < 1e-9 and round(lag) >= 2) or tile is stack.tiles[-1]:
            lag = max(1, round(lag))
            z = _detrended(tile.heights)
            return math.degrees(math.atan(_rms_difference(z, lag) / (lag * tile.resolution)))
    raise AssertionError("unreachable")


@pytest.fixture(scope="module")
def fine_stack():
    """A 1 m synthetic base (H 0.95, like LOLA's) expanded six times to 1.6 cm pixels."""
    base = synthesize_tile(257, resolution=1.0, fractal_dimension=2.05, relief=60.0,
                           seed=3).tile
    return build_stack(base, (128.0, 128.0), levels=6, layer_size=257, seed=1,
                       params=RoughnessChoice(regolith=RegolithLaw()))


def test_cm_scale_rms_slope_lies_in_the_published_range(fine_stack):
    finest = fine_stack.tiles[-1].resolution
    assert finest == pytest.approx(0.015625)
    slope = _rms_slope_deg(fine_stack, finest)
    print(f"\nRMS slope at {100 * finest:.2g} cm: {slope:.1f} deg")
    assert CM_RMS_SLOPE_DEG[0] <= slope <= CM_RMS_SLOPE_DEG[1]


def test_slope_rises_below_a_metre(fine_stack):
    baselines = (1.0, 0.25, 0.125, 0.03125, 0.015625)
    slopes = [_rms_slope_deg(fine_stack, b) for b in baselines]
    print("\nRMS slope (deg) at " + ", ".join(f"{b:g} m: {s:.2f}"
                                             for b, s in zip(baselines, slopes, strict=True)))
    assert slopes[0] < slopes[2] < slopes[3] < slopes[4]
    assert slopes[3] > slopes[0] + 3.0  # a few degrees steeper at 3 cm than at 1 m


def test_fine_layers_have_the_regoliths_hurst_exponent(fine_stack):
    """Structure function of the finest layer between 3 cm and 25 cm lags."""
    tile = fine_stack.tiles[-1]
    z = _detrended(tile.heights)
    lags = np.array([2, 4, 8, 16])
    v = [_rms_difference(z, int(lag)) for lag in lags]
    hurst = float(np.polyfit(np.log(lags), np.log(v), 1)[0])
    print(f"\nfinest layer Hurst exponent over 3-25 cm: {hurst:.2f}")
    assert REGOLITH_HURST_RANGE[0] <= hurst <= REGOLITH_HURST_RANGE[1]


def test_the_law_is_a_floor_only_below_its_onset():
    """Levels coarser than a metre continue the base's own law unchanged."""
    from terrain.core.tile import DEMTile

    rng = np.random.default_rng(2)
    tile = DEMTile.from_array(rng.normal(size=(65, 65)).cumsum(0).cumsum(1), resolution=8.0)
    plain = RoughnessChoice().for_tile(tile)
    floored = RoughnessChoice(regolith=RegolithLaw()).for_tile(tile)
    for level in (1, 2, 3):  # 4, 2, 1 m pixels: above or at the onset's own pixels
        if 8.0 / 2**level > 1.0:
            assert np.array_equal(plain.sigmas(level), floored.sigmas(level))
    assert np.all(floored.sigmas(10) >= plain.sigmas(10))


@pytest.mark.parametrize("bad", [dict(slope_deg=0.0), dict(hurst=1.0), dict(baseline_m=-1.0)])
def test_bad_laws_are_refused(bad):
    with pytest.raises(InvalidParameterError):
        RegolithLaw(**bad)
