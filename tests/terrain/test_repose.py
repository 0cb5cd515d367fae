"""Slopes relaxed to the angle of repose (terrain.surface.repose) on steep synthetic ground.

What a scientist checks of a relaxation to repose: afterwards no slope of the free ground is
steeper than the angle of repose (Horn's slope, measured by the evaluation's own operator, and
the slope between any two neighbouring free cells), the volume of material is kept, pinned
cells keep their heights bitwise, and a window grown by the documented halo is that window
of the whole tile.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from evaluation.slope import horn_slope
from terrain.core.tile import DEMTile
from terrain.fractal.rmd import synthesize
from terrain.surface.repose import relax_to_repose

#: The angle of repose of lunar regolith (Carrier et al. 1991, Lunar Sourcebook ch. 9).
REPOSE_DEG = 35.0
#: Pairs within a thousandth of their limit count as settled (the relaxation's tolerance).
TOLERANCE = 1e-3
#: Enough sweeps for these areas to settle (the relaxation stops once they have).
SWEEPS = 20000


#: Centres (row, col) of the bowls of :func:`_bowls`.
CENTRES = [(60, 60), (60, 190), (180, 100), (200, 210)]


def _bowls(n=257, seed=1):
    """Flat ground with paraboloid bowls 16 m deep and 16 m in radius (walls to 63 deg).

    Returns the heights (m, 1 m pixels) and each cell's distance (pixels) to the nearest
    bowl's centre.
    """
    y, x = np.mgrid[:n, :n].astype(float)
    z = np.random.default_rng(seed).normal(0.0, 0.05, (n, n))
    near = np.full((n, n), np.inf)
    for cy, cx in CENTRES:
        r = np.hypot(x - cx, y - cy)
        z += np.where(r < 16.0, 16.0 * ((r / 16.0) ** 2 - 1.0), 0.0)
        near = np.minimum(near, r)
    return z, near


def _steepest_pair_deg(z, free, resolution=1.0):
    """Steepest slope (deg) between two neighbouring cells of which one at least is free."""
    worst = 0.0
    for di, dj in [(0, 1), (1, 0), (1, 1), (1, -1)]:
        a = (slice(0, z.shape[0] - di), slice(max(0, -dj), z.shape[1] - max(0, dj)))
        b = (slice(di, None), slice(max(0, dj), z.shape[1] + min(0, dj)))
        ok = (free[a] | free[b]) & np.isfinite(z[a]) & np.isfinite(z[b])
        grad = np.abs(z[a] - z[b])[ok] / (resolution * math.hypot(di, dj))
        if grad.size:
            worst = max(worst, float(grad.max()))
    return math.degrees(math.atan(worst))


def _horn_deg(z, resolution=1.0):
    return horn_slope(DEMTile.from_array(z.astype(np.float32), resolution=resolution),
                      edges="mask")


def _at_repose(deg):
    return deg <= math.degrees(math.atan(math.tan(math.radians(REPOSE_DEG)) * (1 + TOLERANCE)))


def test_deep_bowls_on_a_large_area_relax_to_repose():
    z, near = _bowls()
    assert np.nanmax(_horn_deg(z)) > 60.0
    # pinned heights on the flat ground (a real DEM's pixels) and a gap of unknown cells
    movable = np.ones(z.shape, bool)
    movable[::9, ::11] = False
    movable |= near < 30.0
    z[120:126, 20:30] = np.nan
    free = movable & np.isfinite(z)
    out, changed = relax_to_repose(z, 1.0, REPOSE_DEG, movable=movable, iterations=SWEEPS)
    assert _at_repose(np.nanmax(_horn_deg(out)))
    assert _at_repose(_steepest_pair_deg(out, free))
    # the pinned cells never joined a steep pair, so the material only moved within the bowls
    assert np.nansum(out) == pytest.approx(np.nansum(z), abs=1e-9 * np.nansum(np.abs(z)))
    np.testing.assert_array_equal(out[~movable], z[~movable])
    assert np.isnan(out[120:126, 20:30]).all()
    assert not changed[~free].any()
    # the bowls were filled in part and their rims cut down: material moved downslope
    assert out[60, 60] > z[60, 60] + 1.0
    assert changed.sum() < 0.2 * z.size  # the flat ground away from the bowls never moved


def test_steep_fractal_relaxes_to_repose():
    z = synthesize(129, fractal_dimension=2.6, relief=12.0, seed=5)
    assert np.mean(_horn_deg(z)[1:-1, 1:-1] > REPOSE_DEG) > 0.3
    out, _ = relax_to_repose(z, 2.0, REPOSE_DEG, iterations=SWEEPS)
    assert _at_repose(np.nanmax(_horn_deg(out, 2.0)))
    assert _at_repose(_steepest_pair_deg(out, np.ones(z.shape, bool), 2.0))
    assert out.sum() == pytest.approx(z.sum(), abs=1e-9 * np.abs(z).sum())


@pytest.mark.parametrize("block", [1, 7, 10 ** 6])
def test_skipping_settled_blocks_changes_no_height(block):
    # one block as large as the tile sweeps every cell every time: the plain Jacobi sweeps
    z, _ = _bowls(257, seed=2)
    z = z[30:130, 30:130]
    movable = np.ones(z.shape, bool)
    movable[40:50, 40:44] = False
    kw = dict(movable=movable, iterations=400)
    expected, _ = relax_to_repose(z, 1.0, REPOSE_DEG, **kw)
    out, _ = relax_to_repose(z, 1.0, REPOSE_DEG, block=block, **kw)
    np.testing.assert_array_equal(out, expected)


@pytest.mark.parametrize("win", [(50, 45, 30, 30), (0, 170, 70, 60)])
def test_window_grown_by_the_halo_equals_the_whole_tile_on_steep_walls(win):
    # the windows cut through a bowl's wall, whose cells keep moving after the rest settles
    z, _ = _bowls(257, seed=3)
    iterations = 150
    movable = np.ones(z.shape, bool)
    movable[::13, ::5] = False
    full, _ = relax_to_repose(z, 1.0, REPOSE_DEG, movable=movable, iterations=iterations)
    c, r, w, h = win
    halo = iterations + 1
    r0, c0 = max(0, r - halo), max(0, c - halo)
    r1, c1 = min(z.shape[0], r + h + halo), min(z.shape[1], c + w + halo)
    part, _ = relax_to_repose(z[r0:r1, c0:c1], 1.0, REPOSE_DEG, movable=movable[r0:r1, c0:c1],
                              iterations=iterations)
    np.testing.assert_array_equal(part[r - r0:r - r0 + h, c - c0:c - c0 + w],
                                  full[r:r + h, c:c + w])


def test_bad_block_is_refused():
    from terrain.core.errors import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="block"):
        relax_to_repose(np.zeros((4, 4)), 1.0, REPOSE_DEG, block=0)
