"""Random midpoint displacement (diamond-square) synthesis of fractal terrain.

Martin et al. (2014, section IV.A) generate fBm-like terrain with the diamond-square RMD
algorithm (Miller 1986; Peitgen and Saupe 1988). A tile has (2^n + 1)^2 pixels, W = 2^n.
Each square phase sets the centre of every cell to the mean of its four corners plus a
Gaussian; each diamond phase sets every edge midpoint to the mean of its (up to) four axis
neighbours plus a Gaussian. After every half-step (square or diamond) the displacement scale
shrinks by

    S_f = 1 / 2^((3 - F) / 2)                                  (eq. 14)

for fractal dimension F (Hurst exponent 3 - F), starting from

    S = S_f * H * D_r * W * sqrt(1 - 2^(2 (3 - F) - 2))          (eq. 15)

where H is the height-range factor and D_r the resolution, so half-step j (0 = the first
square phase) displaces by S * S_f^j and the last one by S * S_f^(2M+1) (eq. 16, with
W = 2^(M+1), eq. 13). The four corners start at N(0, (S / S_f)^2).
We take the relief ``R = H * D_r * W`` in metres as the user's parameter; it is the
standard deviation of the corner heights and sets the scale of the whole tile.

Every Gaussian is keyed by ``(seed, "rmd", j, global column, global row)``, and a window is
computed from exactly the ancestors of its pixels (the index-range recursion of Gaskell
2005, section 2), so a window computed alone equals the same window of the full tile,
bitwise.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from terrain import memory
from terrain.errors import InvalidParameterError
from terrain.rng import check_seed, key_prefix, normal_at, normal_scalar, stream_id
from terrain.tile import Window

__all__ = ["check_fractal_dimension", "check_tile_size", "initial_scale", "scale_factor",
           "synthesize"]

STREAM_RMD = stream_id("rmd")


def check_fractal_dimension(fractal_dimension: float) -> float:
    """Validate F; surfaces have 2 <= F < 3."""
    f = float(fractal_dimension)
    if not (2.0 <= f < 3.0):
        raise InvalidParameterError(f"fractal dimension must lie in [2, 3); got {f}")
    return f


def check_tile_size(size: int) -> int:
    """Validate that ``size`` is 2^n + 1 with n >= 1 and return n."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 3:
        raise InvalidParameterError(f"tile size must be 2^n + 1 (e.g. 1025); got {size}")
    w = int(size) - 1
    if w & (w - 1):
        raise InvalidParameterError(f"tile size must be 2^n + 1 (e.g. 1025); got {size}")
    return w.bit_length() - 1


def scale_factor(fractal_dimension: float) -> float:
    """S_f of eq. 14: the displacement scale ratio between consecutive half-steps.

    >>> round(scale_factor(2.2), 6)
    0.757858
    """
    return 1.0 / 2.0 ** ((3.0 - fractal_dimension) / 2.0)


def initial_scale(fractal_dimension: float, relief: float) -> float:
    """S of eq. 15 with ``relief = H * D_r * W`` in metres."""
    h = 3.0 - fractal_dimension
    return scale_factor(fractal_dimension) * relief * math.sqrt(1.0 - 2.0 ** (2.0 * h - 2.0))


@numba.njit(cache=True)
def _value(prev, pr0, pc0, s, r, c):
    return prev[(r - pr0) // s, (c - pc0) // s]


@numba.njit(cache=True)
def _square(prev, pr0, pc0, s, r, c, sigma, key, gr0, gc0):
    h = s // 2
    total = (_value(prev, pr0, pc0, s, r - h, c - h) + _value(prev, pr0, pc0, s, r - h, c + h)
             + _value(prev, pr0, pc0, s, r + h, c - h) + _value(prev, pr0, pc0, s, r + h, c + h))
    return total * 0.25 + sigma * normal_at(key, gc0 + c, gr0 + r)


@numba.njit(cache=True)
def _refine(prev, pr0, pc0, s, out, nr0, nc0, w, sigma_sq, sigma_di, seed, level, gr0, gc0):
    """Fill ``out`` (spacing s/2, origin nr0, nc0) from ``prev`` (spacing s, origin pr0, pc0)."""
    h = s // 2
    key_sq = key_prefix(seed, STREAM_RMD, level, 0)
    key_di = key_prefix(seed, STREAM_RMD, level + 1, 0)
    ny, nx = out.shape
    # Pass 1: copy the coarse points, then the square phase.
    for i in range(ny):
        r = nr0 + i * h
        rodd = (r // h) % 2 == 1
        for j in range(nx):
            c = nc0 + j * h
            codd = (c // h) % 2 == 1
            if not rodd and not codd:
                out[i, j] = _value(prev, pr0, pc0, s, r, c)
            elif rodd and codd:
                out[i, j] = _square(prev, pr0, pc0, s, r, c, sigma_sq, key_sq, gr0, gc0)
    # Pass 2: the diamond phase. A diamond's neighbours are squares (both indices odd) or
    # coarse points; squares outside ``out`` are recomputed (same value, bitwise).
    nr1 = nr0 + (ny - 1) * h
    nc1 = nc0 + (nx - 1) * h
    for i in range(ny):
        r = nr0 + i * h
        rodd = (r // h) % 2 == 1
        for j in range(nx):
            c = nc0 + j * h
            codd = (c // h) % 2 == 1
            if rodd == codd:
                continue
            total = 0.0
            count = 0
            # Fixed neighbour order (north, west, east, south) keeps the sum bitwise stable.
            for dr, dc in ((-h, 0), (0, -h), (0, h), (h, 0)):
                rr = r + dr
                cc = c + dc
                if rr < 0 or rr > w or cc < 0 or cc > w:
                    continue
                if (rr // h) % 2 == 0:
                    total += _value(prev, pr0, pc0, s, rr, cc)
                elif nr0 <= rr <= nr1 and nc0 <= cc <= nc1:
                    total += out[(rr - nr0) // h, (cc - nc0) // h]
                else:
                    total += _square(prev, pr0, pc0, s, rr, cc, sigma_sq, key_sq, gr0, gc0)
                count += 1
            out[i, j] = total / count + sigma_di * normal_at(key_di, gc0 + c, gr0 + r)


def _needed_ranges(lo: int, hi: int, w: int) -> list[tuple[int, int]]:
    """Index range (inclusive) needed at every spacing s = 1, 2, 4, ..., w."""
    ranges = [(lo, hi)]
    s = 1
    while s < w:
        s *= 2
        lo = max(0, ((lo - s) // s) * s)
        hi = min(w, -((-(hi + s)) // s) * s)
        ranges.append((lo, hi))
    return ranges


def synthesize(size: int, *, fractal_dimension: float = 2.2, relief: float = 100.0,
               seed: int = 0, window: Window | None = None,
               origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Diamond-square fractal heights of a (size x size) tile, or of a window of it.

    Parameters
    ----------
    size : int
        Tile side in pixels, 2^n + 1.
    fractal_dimension : float
        F in [2, 3); the Hurst exponent is 3 - F.
    relief : float
        ``H * D_r * W`` of eq. 15, metres: the standard deviation of the corner heights.
    seed : int
        Key of every Gaussian.
    window : Window, optional
        Pixels to compute (default: the whole tile).
    origin : (row, col)
        Global pixel position of the tile's upper-left pixel (keys the randomness).

    Returns
    -------
    (height, width) float64, metres
        Heights of the window (zero-mean only in expectation).

    Examples
    --------
    >>> full = synthesize(65, seed=3)
    >>> part = synthesize(65, seed=3, window=Window(10, 20, 7, 5))
    >>> bool(np.array_equal(full[20:25, 10:17], part))
    True
    """
    n = check_tile_size(size)
    f = check_fractal_dimension(fractal_dimension)
    relief = float(relief)
    if not (relief >= 0 and math.isfinite(relief)):
        raise InvalidParameterError(f"relief must be a non-negative number of metres; got {relief}")
    seed = check_seed(seed)
    w = 2**n
    if window is None:
        window = Window(0, 0, size, size)
    window.check_inside(size, size)
    memory.require(window.width * window.height * 8 * 2.5, f"synthesising a {size}x{size} tile")
    gr0, gc0 = (int(v) for v in origin)

    rows = _needed_ranges(window.row, window.row + window.height - 1, w)
    cols = _needed_ranges(window.col, window.col + window.width - 1, w)
    sf = scale_factor(f)
    s0 = initial_scale(f, relief)

    # Corners: spacing w, N(0, (S / S_f)^2), keyed at level -1.
    (r0, r1), (c0, c1) = rows[n], cols[n]
    grid = np.empty(((r1 - r0) // w + 1, (c1 - c0) // w + 1))
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            r, c = r0 + i * w, c0 + j * w
            grid[i, j] = (s0 / sf) * normal_scalar(seed, STREAM_RMD, -1, gc0 + c, gr0 + r, 0)
    origin_r, origin_c = r0, c0
    s = w
    level = 0
    while s > 1:
        h = s // 2
        (nr0, nr1), (nc0, nc1) = rows[level_index(h)], cols[level_index(h)]
        out = np.empty(((nr1 - nr0) // h + 1, (nc1 - nc0) // h + 1))
        _refine(grid, origin_r, origin_c, s, out, nr0, nc0, w,
                s0 * sf ** (2 * level), s0 * sf ** (2 * level + 1), seed, 2 * level, gr0, gc0)
        grid, origin_r, origin_c = out, nr0, nc0
        s = h
        level += 1
    return grid


def level_index(spacing: int) -> int:
    """log2 of a power-of-two spacing."""
    return int(spacing).bit_length() - 1
