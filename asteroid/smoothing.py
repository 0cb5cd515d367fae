r"""Smoothing a field on the latitude/longitude mesh with a filter of a given width in metres.

The two-phase faulting base (section IV.A) smooths its first phase with "smoothing passes with
[...] filters" of a width in metres ("three smoothing passes with 20 m filters"). The paper does
not say which filter; we use what its mesh makes cheap, a *separable box filter* of full width
w on the surface of the reference sphere of radius R:

1. along each ring: the mean of the ``2k + 1`` vertices centred on each vertex, where
   ``k = round(w / (2 s_g))`` for the ring's vertex spacing ``s_g = 2 pi R sin(theta_g) / n_g``
   (the whole ring's mean where the window would wrap onto itself, near the poles);
2. across rings: the mean of the ``2j + 1`` values at the same longitude on the rings
   ``g - j .. g + j``, ``j = round(w / (2 R dtheta))`` with ``dtheta = pi / (2M)``, each read
   by linear interpolation along its ring; a window that runs over a pole continues down the
   far side (longitude + pi).

So the footprint is about w x w everywhere, the poles included, and repeated passes approach
a Gaussian (three box passes are the classic approximation; Wells 1986). Every output is a
direct sum in a fixed order, so a value does not depend on which other values are computed:
:func:`smooth` can compute any set of rings alone, from the rings its window reaches
(:func:`dependency`), bitwise equal to the whole field.

Examples
--------
>>> from asteroid.sphere import SphereMesh
>>> mesh = SphereMesh(12)
>>> field = np.zeros(mesh.n_vertices); field[500] = 1.0
>>> out = smooth(mesh, field, width=0.4, passes=2)
>>> bool(abs(out.sum() - 1.0) < 0.2 and out.max() < 0.2)   # spread out, mass kept roughly
True
"""

from __future__ import annotations

import math

import numba
import numpy as np

from asteroid.sphere import SphereMesh, ring_offset, ring_size
from terrain.core.errors import InvalidParameterError

__all__ = ["across_halfwidth", "dependency", "smooth"]


def across_halfwidth(mesh: SphereMesh, width: float) -> int:
    """j: rings each side of a vertex in the across-ring window of angular width ``width``."""
    return int(round(width / (2.0 * math.pi / (2 * mesh.magnitude))))


def dependency(mesh: SphereMesh, rings: np.ndarray, width: float) -> np.ndarray:
    """Rings one pass reads to produce the rings marked in ``rings`` ((2M + 1,) bool)."""
    m = mesh.magnitude
    j = across_halfwidth(mesh, width)
    out = np.zeros(2 * m + 1, dtype=bool)
    for g in np.flatnonzero(rings):
        h = g + np.arange(-j, j + 1)
        h = np.where(h < 0, -h, h)
        h = np.where(h > 2 * m, 4 * m - h, h)
        if h.min() < 0 or h.max() > 2 * m:  # a window longer than pole to pole
            out[:] = True
            return out
        out[h] = True
    return out


@numba.njit(cache=True)
def _along_ring(m, values, g, width, out):
    """Stage 1 on ring g: the box mean of the 2k + 1 vertices centred on each vertex."""
    n = ring_size(m, g)
    o = ring_offset(m, g)
    if n == 1:
        out[o] = values[o]
        return
    spacing = 2.0 * math.pi * math.sin(math.pi * g / (2 * m)) / n
    k = int(round(width / (2.0 * spacing)))
    if 2 * k + 1 >= n:
        total = 0.0
        for p in range(n):
            total += values[o + p]
        mean = total / n
        for p in range(n):
            out[o + p] = mean
        return
    inv = 1.0 / (2 * k + 1)
    for p in range(n):
        window = 0.0
        for q in range(p - k, p + k + 1):
            window += values[o + (q % n)]
        out[o + p] = window * inv


@numba.njit(cache=True, parallel=True)
def _along(m, values, rings, width, out):
    """Stage 1 on every marked ring (rings in parallel)."""
    for g in numba.prange(2 * m + 1):
        if rings[g]:
            _along_ring(m, values, np.int64(g), width, out)


@numba.njit(cache=True)
def _ring_value(m, values, g, phi):
    """Linear interpolation along ring g at longitude phi (any real)."""
    n = ring_size(m, g)
    o = ring_offset(m, g)
    if n == 1:
        return values[o]
    t = phi * n / (2.0 * math.pi)
    f = math.floor(t)
    i0 = int(f) % n
    w = t - f
    return values[o + i0] * (1.0 - w) + values[o + (i0 + 1) % n] * w


@numba.njit(cache=True)
def _across_ring(m, values, g, j, out):
    """Stage 2 on ring g: the box mean across rings at each vertex's longitude."""
    inv = 1.0 / (2 * j + 1)
    n = ring_size(m, g)
    o = ring_offset(m, g)
    for p in range(n):
        phi = 2.0 * math.pi * p / n
        total = 0.0
        for dg in range(-j, j + 1):
            if dg == 0:
                total += values[o + p]
                continue
            h = g + dg
            ph = phi
            if h < 0:
                h = -h
                ph = phi + math.pi
            elif h > 2 * m:
                h = 4 * m - h
                ph = phi + math.pi
            total += _ring_value(m, values, h, ph)
        out[o + p] = total * inv


@numba.njit(cache=True, parallel=True)
def _across(m, values, rings, j, out):
    """Run stage 2 on every marked ring (rings in parallel).

    A window over a pole continues on the far side, longitude + pi.
    """
    for g in numba.prange(2 * m + 1):
        if rings[g]:
            _across_ring(m, values, np.int64(g), j, out)


def smooth(mesh: SphereMesh, values, *, width: float, passes: int = 1,
           rings=None) -> np.ndarray:
    """Box-filter a per-vertex field ``passes`` times (see the module docstring).

    Parameters
    ----------
    mesh : SphereMesh
    values : (N,) float64
        The field (valid at least on the rings :func:`dependency` asks for).
    width : float
        Full width of the box, radians on the unit sphere (metres / R).
    passes : int
    rings : (2M + 1,) bool, optional
        Rings whose output is wanted (default all); the others are left as they were.

    Returns
    -------
    (N,) float64
        A new array.
    """
    if not (width >= 0 and math.isfinite(width)):
        raise InvalidParameterError(f"filter width must be >= 0; got {width}")
    if isinstance(passes, bool) or not isinstance(passes, (int, np.integer)) or passes < 0:
        raise InvalidParameterError(f"smoothing passes must be an integer >= 0; got {passes!r}")
    m = mesh.magnitude
    values = np.array(values, dtype=np.float64, copy=True)
    if values.shape != (mesh.n_vertices,):
        raise InvalidParameterError(f"values must be ({mesh.n_vertices},); got {values.shape}")
    target = np.ones(2 * m + 1, bool) if rings is None else np.asarray(rings, bool)
    # rings needed after each pass, from the last pass back to the input
    needed = [target]
    for _ in range(passes):
        needed.insert(0, dependency(mesh, needed[0], width))
    j = across_halfwidth(mesh, width)
    scratch = np.zeros_like(values)
    for p in range(1, passes + 1):
        _along(m, values, needed[p - 1], width, scratch)
        _across(m, scratch, needed[p], j, values)
    return values
