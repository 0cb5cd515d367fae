"""The compiled azimuth (terrain.core.arctan) against the C library's atan2."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest

from terrain.core.arctan import atan2


@numba.njit
def _many(y, x, out):
    for i in range(y.size):
        out[i] = atan2(y[i], x[i])


def _ulps(got, want):
    return np.abs(got - want) / np.spacing(np.abs(want))


@pytest.mark.parametrize("scale", [1.0, 1e-6, 1e6])
def test_within_two_ulps_of_libm(scale):
    # fdlibm states under 1 ulp for atan; the ratio y / x and the folds about pi / 2 and
    # pi add at most half an ulp each
    rng = np.random.default_rng(7)
    y = rng.uniform(-600, 600, 200_000) * scale
    x = rng.uniform(-600, 600, 200_000) * scale
    got = np.empty_like(y)
    _many(y, x, got)
    want = np.arctan2(y, x)
    assert _ulps(got, want).max() <= 2.0
    assert np.mean(got == want) > 0.7


def test_every_ratio_range():
    # the reduction's interval ends (7/16, 11/16, 1 and their inverses), both sides
    t = np.array([0.0, 1e-300, 1e-9, 0.4375, 0.6875, 1.0, 1 / 0.6875, 1 / 0.4375, 1e9])
    t = np.concatenate([t, np.nextafter(t, 0.0), np.nextafter(t, 2.0)])
    for sy in (1.0, -1.0):
        for sx in (1.0, -1.0):
            y, x = sy * t, sx * np.ones_like(t)
            got = np.empty_like(y)
            _many(y, x, got)
            assert _ulps(got, np.arctan2(y, x)).max() <= 2.0


@pytest.mark.parametrize("y, x", [(0.0, 1.0), (-0.0, 1.0), (0.0, -1.0), (-0.0, -1.0),
                                  (1.0, 0.0), (-1.0, 0.0), (0.0, 0.0), (-0.0, 0.0),
                                  (0.0, -0.0), (-0.0, -0.0), (2.0, 2.0), (-3.0, -3.0)])
def test_axes_and_diagonals_as_libm(y, x):
    got, want = atan2(y, x), math.atan2(y, x)
    assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want)


def test_range_and_symmetry():
    rng = np.random.default_rng(3)
    y, x = rng.normal(size=(2, 10_000))
    got = np.empty_like(y)
    _many(y, x, got)
    assert np.all(np.abs(got) <= math.pi)
    mirrored = np.empty_like(y)
    _many(-y, x, mirrored)
    assert np.array_equal(mirrored, -got)  # odd in y, bitwise


def test_vectorised_row_equals_scalar():
    # the stamp's row loop may run in vector lanes: the same bytes as one at a time
    from terrain.craters.cratering import _row_azimuths

    out = np.empty(301)
    _row_azimuths(-150.0, 1.0, 0.3712, -7.25, 0, 300, out)
    one = np.array([atan2(-7.25, (-150.0 + (j + 0.5) * 1.0) - 0.3712) for j in range(301)])
    assert np.array_equal(out, one)
