"""Fractal expansion: double a DEM's resolution without touching a known height.

Martin et al. (2014, section IV.A, Fig. 5): a new DEM at twice the resolution takes the
existing pixels at its even positions (copied, so every known height appears unchanged,
bitwise, in every expanded layer); the square phase sets each cell centre (odd row, odd column)
to the mean of its four corners, and the diamond phase sets each edge midpoint to the mean of
its two coarse neighbours and its two neighbouring squares, each displaced by a Gaussian scaled
to approximate fBm (eqs. 13-16, :class:`terrain.roughness.ExpansionParameters`). A diamond on
the border of the DEM has no square on the outside; as the paper says, the nearest pixels of
the low-resolution DEM stand in for it (the mean of the diamond's two coarse neighbours).

Grid: expanding an ``n x m`` DEM once gives ``(2n - 1) x (2m - 1)`` pixels, pixel (2i, 2j) on
input pixel (i, j)'s centre, at half the spacing. Unknown pixels stay unknown, and a new pixel
with an unknown parent is unknown: fill gaps first (:mod:`terrain.gapfill`).

Windows and keys: every Gaussian is keyed by ``(seed, "expand", 2L or 2L + 1, global column,
global row)`` at expansion level L, and a window is computed from its parents plus a one-pixel
halo per level, so a window expanded alone equals the same window of the full expansion,
bitwise. The roughness parameters are estimated from the whole input even when only a window
is computed, and the local roughness map (:func:`terrain.roughness.local_amplitude`) is a
fixed local function of the input, so windows match the full run there too.
"""

from __future__ import annotations

import json
import logging

import numba
import numpy as np
from affine import Affine

from terrain import memory
from terrain.errors import InvalidParameterError
from terrain.rng import check_seed, key_prefix, normal_at, stream_id
from terrain.roughness import ExpansionParameters, local_amplitude
from terrain.tile import DEMTile, Window

__all__ = ["expand", "expand_level", "expanded_shape", "expanded_transform", "parent_region"]

log = logging.getLogger(__name__)

STREAM_EXPAND = stream_id("expand")


@numba.njit(cache=True)
def _parent(parent, pr0, pc0, r, c):
    return parent[r - pr0, c - pc0]


@numba.njit(cache=True)
def _amplitude(amp, ar0, ac0, scale, r, c):
    """Local roughness amplitude at child pixel (r, c): bilinear in the base-level map.

    Interpolates along the map's rows first, then along the columns, in exactly the order of
    :func:`_amplitude_row` and :func:`_amplitude_col`, so both give the same value bitwise.
    """
    if amp.shape[0] == 0:
        return 1.0
    fr = min(max(r * scale - ar0, 0.0), amp.shape[0] - 1.0)
    i = min(int(fr), amp.shape[0] - 2) if amp.shape[0] > 1 else 0
    ti = fr - i
    i1 = min(i + 1, amp.shape[0] - 1)
    n = amp.shape[1]
    fc = min(max(c * scale - ac0, 0.0), n - 1.0)
    j = min(int(fc), n - 2) if n > 1 else 0
    tj = fc - j
    j1 = min(j + 1, n - 1)
    v0 = amp[i, j] * (1.0 - ti) + amp[i1, j] * ti
    v1 = amp[i, j1] * (1.0 - ti) + amp[i1, j1] * ti
    return v0 * (1.0 - tj) + v1 * tj


@numba.njit(cache=True)
def _amplitude_row(amp, ar0, scale, r, buf):
    """The map interpolated to child row r, still at the map's column spacing, into buf."""
    if amp.shape[0] == 0:
        return
    fr = min(max(r * scale - ar0, 0.0), amp.shape[0] - 1.0)
    i = min(int(fr), amp.shape[0] - 2) if amp.shape[0] > 1 else 0
    ti = fr - i
    i1 = min(i + 1, amp.shape[0] - 1)
    for j in range(amp.shape[1]):
        buf[j] = amp[i, j] * (1.0 - ti) + amp[i1, j] * ti


@numba.njit(cache=True)
def _amplitude_col(buf, ac0, scale, c):
    """Linear interpolation along a row buffer from :func:`_amplitude_row` (1 without map)."""
    n = buf.size
    if n == 0:
        return 1.0
    fc = min(max(c * scale - ac0, 0.0), n - 1.0)
    j = min(int(fc), n - 2) if n > 1 else 0
    tj = fc - j
    return buf[j] * (1.0 - tj) + buf[min(j + 1, n - 1)] * tj


@numba.njit(cache=True)
def _square(parent, pr0, pc0, r, c, sigma, key, amp, ar0, ac0, scale):
    """Square-phase value at child (r, c), both odd: mean of four corners + Gaussian.

    Computed in float64 and rounded to float32, the precision every layer is stored in, so a
    square recomputed at a window's edge equals the stored one bitwise.
    """
    return _square_fast(parent, pr0, pc0, r, c, sigma * _amplitude(amp, ar0, ac0, scale, r, c),
                        key)


@numba.njit(cache=True)
def _square_fast(parent, pr0, pc0, r, c, sigma, key):
    """Square-phase value with the displacement scale already multiplied in."""
    a = (r - 1) // 2
    b = (c - 1) // 2
    total = (float(_parent(parent, pr0, pc0, a, b)) + float(_parent(parent, pr0, pc0, a, b + 1))
             + float(_parent(parent, pr0, pc0, a + 1, b))
             + float(_parent(parent, pr0, pc0, a + 1, b + 1)))
    return float(np.float32(0.25 * total + sigma * normal_at(key, c, r)))


@numba.njit(cache=True)
def _expand_kernel(parent, pr0, pc0, out, cr0, cc0, sigma_sq, sigma_di, key_sq, key_di,
                   amp, ar0, ac0, scale):
    ph, pw = parent.shape
    rmin = 2 * pr0
    rmax = 2 * (pr0 + ph - 1)
    cmin = 2 * pc0
    cmax = 2 * (pc0 + pw - 1)
    ny, nx = out.shape
    # pass 1: copies (even row, even column), then the square phase (odd, odd)
    for i in range(cr0 % 2, ny, 2):
        r = cr0 + i
        for j in range(cc0 % 2, nx, 2):
            out[i, j] = _parent(parent, pr0, pc0, r // 2, (cc0 + j) // 2)
    buf = np.empty(amp.shape[1], dtype=np.float64)
    for i in range(1 - cr0 % 2, ny, 2):
        r = cr0 + i
        _amplitude_row(amp, ar0, scale, r, buf)
        for j in range(1 - cc0 % 2, nx, 2):
            out[i, j] = _square_fast(parent, pr0, pc0, r, cc0 + j,
                                     sigma_sq * _amplitude_col(buf, ac0, scale, cc0 + j), key_sq)
    # pass 2: the diamond phase (north, west, east, south: a fixed order keeps sums bitwise)
    for i in range(ny):
        r = cr0 + i
        odd_row = r % 2 == 1
        _amplitude_row(amp, ar0, scale, r, buf)
        for j in range((r + cc0 + 1) % 2, nx, 2):
            c = cc0 + j
            if odd_row:  # between two coarse pixels above and below
                north = float(_parent(parent, pr0, pc0, (r - 1) // 2, c // 2))
                south = float(_parent(parent, pr0, pc0, (r + 1) // 2, c // 2))
                fill = 0.5 * (north + south)
                if c - 1 < cmin:
                    west = fill
                elif j >= 1:
                    west = float(out[i, j - 1])
                else:
                    west = _square(parent, pr0, pc0, r, c - 1, sigma_sq, key_sq, amp, ar0,
                                   ac0, scale)
                if c + 1 > cmax:
                    east = fill
                elif j + 1 < nx:
                    east = float(out[i, j + 1])
                else:
                    east = _square(parent, pr0, pc0, r, c + 1, sigma_sq, key_sq, amp, ar0,
                                   ac0, scale)
            else:  # between two coarse pixels left and right
                west = float(_parent(parent, pr0, pc0, r // 2, (c - 1) // 2))
                east = float(_parent(parent, pr0, pc0, r // 2, (c + 1) // 2))
                fill = 0.5 * (west + east)
                if r - 1 < rmin:
                    north = fill
                elif i >= 1:
                    north = float(out[i - 1, j])
                else:
                    north = _square(parent, pr0, pc0, r - 1, c, sigma_sq, key_sq, amp, ar0,
                                    ac0, scale)
                if r + 1 > rmax:
                    south = fill
                elif i + 1 < ny:
                    south = float(out[i + 1, j])
                else:
                    south = _square(parent, pr0, pc0, r + 1, c, sigma_sq, key_sq, amp, ar0,
                                    ac0, scale)
            sigma = sigma_di * _amplitude_col(buf, ac0, scale, c)
            out[i, j] = 0.25 * (north + west + east + south) + sigma * normal_at(key_di, c, r)


def parent_region(lo: int, hi: int, parent_size: int) -> tuple[int, int]:
    """Parent index range (inclusive) that child indices lo..hi (inclusive) depend on."""
    return max(0, (lo - 1) // 2), min(parent_size - 1, -(-(hi + 1) // 2))


_NO_MAP = np.zeros((0, 0), dtype=np.float32)


def expand_level(parent: np.ndarray, parent_origin: tuple[int, int], child_rows, child_cols,
                 *, level: int, sigmas: tuple[float, float], seed: int, amplitude=None,
                 amplitude_origin=(0, 0), amplitude_level: int = 0) -> np.ndarray:
    """One 2x expansion of a region, in global pixel coordinates.

    Parameters
    ----------
    parent : (h, w) float32, metres
        Parent heights (NaN unknown) whose pixel (0, 0) is the global pixel ``parent_origin``
        (row, col) of level ``level - 1``. Arithmetic is float64; results are rounded to
        float32, the precision layers are stored in, so re-expanding a stored layer
        reproduces the next one exactly.
    child_rows, child_cols : (first, last), inclusive
        Global child pixels to compute at level ``level``; they must lie within the
        expansion of ``parent``, and any parent pixel they depend on must be in ``parent``
        (the parent's extent is treated as the DEM's border).
    level : int
        Absolute expansion level of the child (keys the randomness).
    sigmas : (square, diamond)
        Displacement standard deviations (m).
    seed : int
    amplitude : (h, w) float32, optional
        Local roughness map (:func:`terrain.roughness.local_amplitude`) on the grid of
        ``amplitude_level`` with its pixel (0, 0) at global ``amplitude_origin``; every
        displacement is multiplied by its bilinear value at the new pixel.

    Returns
    -------
    (last - first + 1 rows, ...) float32
    """
    pr0, pc0 = (int(v) for v in parent_origin)
    r0, r1 = (int(v) for v in child_rows)
    c0, c1 = (int(v) for v in child_cols)
    ph, pw = parent.shape
    if not (2 * pr0 <= r0 <= r1 <= 2 * (pr0 + ph - 1)
            and 2 * pc0 <= c0 <= c1 <= 2 * (pc0 + pw - 1)):
        raise InvalidParameterError("child region lies outside the expansion of its parent")
    out = np.empty((r1 - r0 + 1, c1 - c0 + 1), dtype=np.float32)
    amp = _NO_MAP if amplitude is None else np.ascontiguousarray(amplitude, dtype=np.float32)
    _expand_kernel(np.ascontiguousarray(parent, dtype=np.float32), pr0, pc0, out, r0, c0,
                   float(sigmas[0]), float(sigmas[1]),
                   np.uint64(key_prefix(seed, STREAM_EXPAND, 2 * level, 0)),
                   np.uint64(key_prefix(seed, STREAM_EXPAND, 2 * level + 1, 0)),
                   amp, float(amplitude_origin[0]), float(amplitude_origin[1]),
                   0.5 ** (level - amplitude_level))
    return out


def expanded_shape(shape, times: int) -> tuple[int, int]:
    """Shape of a DEM expanded ``times`` times: (2^t (n - 1) + 1, 2^t (m - 1) + 1)."""
    f = 2**times
    return f * (shape[0] - 1) + 1, f * (shape[1] - 1) + 1


def expanded_transform(transform: Affine, times: int, row: int = 0, col: int = 0) -> Affine:
    """Transform of the expansion whose pixel (0, 0) sits on input pixel (row, col)'s centre."""
    res = transform.a / 2**times
    x_centre, y_centre = transform @ (col + 0.5, row + 0.5)
    return Affine(res, 0.0, x_centre - res / 2, 0.0, -res, y_centre + res / 2)


def expand(tile: DEMTile, times: int = 1, *, seed: int = 0,
           params: ExpansionParameters | None = None, window: Window | None = None,
           progress=None) -> DEMTile:
    """Expand a DEM (or a window of it) ``times`` times by 2x fractal expansion.

    Parameters
    ----------
    tile : DEMTile
        The DEM (level 0). Its known heights appear unchanged in the result.
    times : int
        Number of 2x expansions (>= 1).
    seed : int
    params : ExpansionParameters, optional
        Roughness; estimated from the whole ``tile`` by default
        (:meth:`ExpansionParameters.for_tile`).
    window : Window, optional
        Input pixels to expand (the result covers their centres): equal, bitwise, to the
        same pixels of the full expansion.
    progress : callable, optional
        ``progress(level, times)`` after each level.

    Returns
    -------
    DEMTile
        ``2^t (h - 1) + 1`` by ``2^t (w - 1) + 1`` pixels at ``resolution / 2^t``.

    Examples
    --------
    >>> t = DEMTile.from_array(np.arange(16.0).reshape(4, 4), resolution=8.0)
    >>> e = expand(t, 2, seed=1)
    >>> e.shape, e.resolution
    ((13, 13), 2.0)
    >>> bool(np.array_equal(e.heights[::4, ::4], t.heights))
    True
    """
    if isinstance(times, bool) or not isinstance(times, (int, np.integer)) or times < 1:
        raise InvalidParameterError(f"times must be a positive integer; got {times!r}")
    seed = check_seed(seed)
    if min(tile.shape) < 2:
        raise InvalidParameterError(f"a DEM must be at least 2 x 2 to expand; got {tile.shape}")
    params = params or ExpansionParameters.for_tile(tile)
    window = window or Window(0, 0, tile.shape[1], tile.shape[0])
    window.check_inside(*tile.shape)
    if window.width < 2 or window.height < 2:
        raise InvalidParameterError("an expansion window must be at least 2 x 2 pixels")
    f = 2**times
    out_shape = ((window.height - 1) * f + 1, (window.width - 1) * f + 1)
    memory.require(out_shape[0] * out_shape[1] * (4 * 2 + 1 * 2),
                   f"expanding to {out_shape[1]} x {out_shape[0]} pixels")

    # Needed ranges per level, from the final window back to the input.
    full = [tile.shape]
    for _ in range(times):
        full.append(expanded_shape(full[-1], 1))
    rows = [(window.row * f, (window.row + window.height - 1) * f)]
    cols = [(window.col * f, (window.col + window.width - 1) * f)]
    for k in range(times, 0, -1):
        rows.insert(0, parent_region(*rows[0], full[k - 1][0]))
        cols.insert(0, parent_region(*cols[0], full[k - 1][1]))

    (r0, r1), (c0, c1) = rows[0], cols[0]
    grid = tile.heights[r0:r1 + 1, c0:c1 + 1]
    origin = (r0, c0)
    amp = None
    if params.uses_local_map:
        amp = local_amplitude(tile.heights, params.base_sigma, params.local_box, rows[0],
                              cols[0])
    for level in range(1, times + 1):
        grid = expand_level(grid, origin, rows[level], cols[level], level=level,
                            sigmas=params.sigmas(level), seed=seed, amplitude=amp,
                            amplitude_origin=(r0, c0))
        origin = (rows[level][0], cols[level][0])
        if progress is not None:
            progress(level, times)
    heights = grid
    heights.flags.writeable = False  # hand the array to the tile without a copy
    meta = dict(tile.metadata)
    meta["CRATERSCAPE_SEED"] = str(seed)
    meta["CRATERSCAPE_EXPANSION"] = json.dumps(dict(params.as_dict(), times=times),
                                               sort_keys=True)
    return DEMTile(heights, np.isfinite(heights),
                   expanded_transform(tile.transform, times, window.row, window.col),
                   tile.crs, tile.nodata, meta)
