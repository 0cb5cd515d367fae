"""Craters below a DEM's resolution, added without moving any of its known heights.

An expanded layer of a real DEM holds the DEM's own heights on a lattice (every ``step``-th
pixel, ``step`` = 2^level, :mod:`terrain.fractal.expand`). A crater smaller than the DEM
resolves is added there as its height change ``d`` less the part of ``d`` the lattice
samples: ``d - B[d]``, where ``B`` interpolates ``d``'s lattice values bilinearly to every
pixel, and to zero at the layer's ends (where the layer meets its parent). ``B[d]`` equals
``d`` on the lattice, so every known height stays, bitwise, and what is added is exactly what
the DEM's samples cannot see: a crater between lattice points is added whole, one over a
lattice point keeps its height there and is added around it. ``docs/roughness.md`` describes
the use in ``terrain enhance``.

Everything is a function of global pixel positions: a window computed from the craters of the
window grown by :func:`lattice_halo` pixels equals the same window of the whole layer,
bitwise.

Examples
--------
A crater between the lattice points of a 4-pixel lattice is added whole; on a 2-pixel
lattice its centre is a known pixel, which keeps its height:

>>> before = np.zeros((5, 5))
>>> bowl = np.array([[0, 0, 0, 0, 0], [0, 1, 2, 1, 0], [0, 2, 4, 2, 0],
...                  [0, 1, 2, 1, 0], [0, 0, 0, 0, 0]], float)
>>> rows = cols = (0, 4)
>>> z = keep_lattice(before, before - bowl, step=4, origin=(0, 0), layer_rows=rows,
...                  layer_cols=cols)
>>> bool(np.array_equal(z, -bowl))
True
>>> z = keep_lattice(before, before - bowl, step=2, origin=(0, 0), layer_rows=rows,
...                  layer_cols=cols)
>>> float(z[2, 2]), bool(np.array_equal(z[::2, ::2], before[::2, ::2]))
(0.0, True)
"""

from __future__ import annotations

import numpy as np

__all__ = ["keep_lattice", "lattice_halo"]


def lattice_halo(step: int) -> int:
    """Pixels a window must grow by so that its lattice interpolation is the whole layer's."""
    return int(step)


def _weights(first: int, n: int, step: int, lo: int, hi: int):
    """Lines below/above each of n global indices from ``first``, the weight, and which are real.

    ``lo``, ``hi``: the layer's first and last global index (inclusive). The lines are the
    lattice lines inside the layer and the layer's two ends; an end that is not a lattice
    line is a *pseudo* line, on which the sampled change is taken as zero (the layer meets
    its parent there, which has none of the added craters). So the part of ``d`` taken out
    falls linearly from a lattice line to the layer's end, rather than continuing from the
    nearest lattice point as a constant (which would raise or lower the whole margin, and a
    layer with no lattice line at all by the change at one of its ends, against its parent).

    Returns
    -------
    a0, a1 : (n,) int64
        Global index of the line at or below and at or above each index.
    t : (n,) float64
        Weight of ``a1`` (0 on a line).
    real0, real1 : (n,) bool
        Whether ``a0`` and ``a1`` are lattice lines (else the layer's ends, valued zero).
    """
    g = np.arange(first, first + n, dtype=np.int64)
    first_line = -(-lo // step) * step
    last_line = (hi // step) * step
    a0 = (g // step) * step
    a1 = np.where(g == a0, a0, a0 + step)
    real0 = (a0 >= lo) & (a0 <= hi)
    real1 = (a1 >= lo) & (a1 <= hi)
    a0 = np.where(real0, a0, lo)
    a1 = np.where(real1, a1, hi)
    if first_line > last_line:  # no lattice line in the layer
        real0[:] = False
        real1[:] = False
    span = a1 - a0
    t = np.where(span > 0, (g - a0) / np.maximum(span, 1), 0.0).astype(np.float64)
    return a0, a1, t, real0, real1


def keep_lattice(before: np.ndarray, after: np.ndarray, *, step: int, origin: tuple[int, int],
                 layer_rows: tuple[int, int], layer_cols: tuple[int, int]) -> np.ndarray:
    """Return ``before`` plus the part of ``after - before`` the lattice does not sample.

    Parameters
    ----------
    before, after : (h, w) float, metres
        A region of a layer without and with the craters; its pixel (0, 0) is the layer's
        global pixel ``origin`` (row, col). The region must reach the lattice lines around
        every pixel it is to be exact for (grow a window by :func:`lattice_halo`).
    step : int
        Lattice step in pixels (2^level); 1 keeps ``before`` everywhere.
    origin : (row, col)
        Global index of the region's pixel (0, 0).
    layer_rows, layer_cols : (first, last)
        The whole layer's global rows and columns (inclusive), where the lattice ends.

    Returns
    -------
    (h, w) float64
        Equal to ``before`` on every lattice pixel, bitwise; NaN where either input is.
    """
    before = np.asarray(before, dtype=np.float64)
    d = np.asarray(after, dtype=np.float64) - before
    h, w = d.shape
    r0, c0 = (int(v) for v in origin)
    ra0, ra1, t, rr0, rr1 = _weights(r0, h, step, *layer_rows)
    cb0, cb1, s, cr0, cr1 = _weights(c0, w, step, *layer_cols)
    # the lattice lines must lie inside the region (the layer's ends, valued zero, need not)
    ra0, ra1 = np.clip(ra0 - r0, 0, h - 1), np.clip(ra1 - r0, 0, h - 1)
    cb0, cb1 = np.clip(cb0 - c0, 0, w - 1), np.clip(cb1 - c0, 0, w - 1)
    known = np.where(np.isfinite(d), d, 0.0)  # an unknown pixel spreads no NaN
    rows = ((1.0 - t) * rr0)[:, None] * known[ra0] + (t * rr1)[:, None] * known[ra1]
    sampled = ((1.0 - s) * cr0)[None, :] * rows[:, cb0] + (s * cr1)[None, :] * rows[:, cb1]
    out = before + (d - sampled)
    on_r = (np.arange(r0, r0 + h) % step) == 0
    on_c = (np.arange(c0, c0 + w) % step) == 0
    lattice = on_r[:, None] & on_c[None, :]
    out[lattice] = before[lattice]
    return out
