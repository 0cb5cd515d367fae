"""Crater roughness patches: a patch computed where it is read equals the whole patch there."""

import math

import numpy as np
import pytest

from terrain.craters.overlay import overlay_patch, overlay_patch_part

PARAMS = np.array([0.05, 0.2, 0.1, 2.2, 2.25, 2.3, 0.1])


def _patch(level, diameter, alpha, params=PARAMS, spacing=None):
    n = 2**level
    spacing = spacing or 2.0 * (1.04 * diameter + 1.0) / n
    full = np.empty((n + 1, n + 1))
    overlay_patch(7, 123, level, spacing, diameter, alpha, params, full)
    return full, spacing


@pytest.mark.parametrize("level, diameter, alpha", [
    (3, 4.0, -0.6), (4, 6.0, -0.3), (6, 30.0, -0.95), (8, 100.0, -0.5), (5, 12.0, 0.02),
])
def test_a_disc_of_the_patch_equals_the_whole_patch_there(level, diameter, alpha):
    full, spacing = _patch(level, diameter, alpha)
    n = 2**level
    radius = 1.04 * diameter / spacing + math.sqrt(2.0)
    part = np.empty_like(full)
    overlay_patch_part(7, 123, level, spacing, diameter, alpha, PARAMS, part, radius, 0, n, 0, n)
    i, j = np.mgrid[0:n + 1, 0:n + 1]
    inside = (i - n // 2) ** 2 + (j - n // 2) ** 2 <= radius**2
    assert np.array_equal(part[inside], full[inside])
    assert inside.sum() < inside.size  # the corners were left out


@pytest.mark.parametrize("rows, cols", [((0, 4), (0, 16)), ((10, 12), (3, 5)), ((16, 16), (9, 16))])
def test_a_rectangle_of_the_patch_equals_the_whole_patch_there(rows, cols):
    full, spacing = _patch(4, 7.0, -0.4)
    part = np.empty_like(full)
    overlay_patch_part(7, 123, 4, spacing, 7.0, -0.4, PARAMS, part, math.inf, *rows, *cols)
    sub = (slice(rows[0], rows[1] + 1), slice(cols[0], cols[1] + 1))
    assert np.array_equal(part[sub], full[sub])


def test_region_shortcuts_give_the_blended_scales_bitwise():
    """Sigma from the region a point lies in equals the blend of the three, on many shapes."""
    from terrain.craters.overlay import _patch_sigma, _region_bounds, _sigma_at

    rng = np.random.default_rng(3)
    for _ in range(300):
        radius = float(rng.uniform(0.5, 300.0))
        alpha = float(rng.uniform(-1.2, 0.1))
        blend = float(rng.uniform(0.01, 1.0))
        scales = rng.uniform(0.0, 2.0, 3)
        bounds = np.array(_region_bounds(radius, alpha, blend))
        n = 64
        spacing = 2.2 * 2.0 * radius / n
        for i in range(0, n + 1, 3):
            for j in range(0, n + 1, 2):
                want = _patch_sigma(i, j, n // 2, spacing, radius, alpha, blend, *scales)
                got = _sigma_at(i, j, n // 2, spacing, radius, alpha, blend, *scales, bounds)
                assert got == want
