"""Fractal expansion: double a DEM's resolution without touching a known height.

Martin et al. (2014, section IV.A, Fig. 5): a new DEM at twice the resolution takes the
existing pixels at its even positions (copied, so every known height appears unchanged,
bitwise, in every expanded layer), and every new pixel takes a prediction from its coarse
neighbours plus a Gaussian scaled to continue the DEM's fractal roughness. The paper predicts
by the mean of the two or four nearest parents (diamond-square); we use the four-point
separable predictor of :mod:`terrain.fractal.rmd` for the reason given there: the mean's tent kernel
leaks the coarse DEM's power into every finer scale, so an expanded fBm surface measured a
spectral Hurst exponent of 0.65 where the truth had 0.8, and its slope distribution was
farther from the truth's. Each expansion level runs two passes: the midpoints between the
columns of every coarse row, then the midpoints between the rows of every column, each from
the four nearest points on its line (the quadratic through three, or the mean of two, where
the line ends at the DEM's border or at a gap), displaced by the fBm conditional error of that
predictor (:meth:`terrain.fractal.roughness.ExpansionParameters.sigmas`). The first level, which
reads
the data, predicts by kriging on the fBm variogram instead (the weights depend on h), and every
displacement is correlated with its neighbours as fBm's prediction errors are
(:mod:`terrain.fractal.rmd`): an 8x decimated fBm expanded back measures the nominal Hurst exponent
within 0.05 for h = 0.3 ... 0.9.

Grid: expanding an ``n x m`` DEM once gives ``(2n - 1) x (2m - 1)`` pixels, pixel (2i, 2j) on
input pixel (i, j)'s centre, at half the spacing. Unknown pixels stay unknown, and a new pixel
with an unknown parent (one of the two nearest points on its line) is unknown: fill gaps first
(:mod:`terrain.fractal.gapfill`).

Windows and keys: every Gaussian is keyed by ``(seed, "expand", 2L or 2L + 1, global column,
global row)`` at expansion level L (2L for the row pass, 2L + 1 for the column pass), and a
window is computed from its parents plus a two-pixel halo per level (what the four-point
predictor reaches; the displacements' moving averages read Gaussians keyed at neighbouring
positions, a function of position alone), so a window expanded alone equals the same window
of the full expansion, bitwise. Arithmetic is float64 and every pass is rounded to float32,
the precision layers are stored in. The roughness parameters are estimated from the whole
input even when only a window is computed, and the local roughness map
(:func:`terrain.fractal.roughness.local_amplitude`) is a fixed local function of the input, so
windows match the full run there too.
"""

from __future__ import annotations

import json
import logging
import math

import numba
import numpy as np
from affine import Affine

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidParameterError
from terrain.core.parallel import run_blocks
from terrain.core.rng import check_seed, key_prefix, stream_id
from terrain.core.tile import DEMTile, Window
from terrain.fractal.rmd import NO_ROW, correlated_value, noise_rows, predict
from terrain.fractal.roughness import ExpansionParameters, local_amplitude

__all__ = ["expand", "expand_level", "expanded_known", "expanded_shape", "expanded_transform",
           "parent_region"]

log = logging.getLogger(__name__)

STREAM_EXPAND = stream_id("expand")


@numba.njit(cache=True)
def _amplitude_row(amp, ar0, scale, r, buf):
    """Interpolate the local roughness map bilinearly to child row r.

    At the map's column spacing, into buf (then :func:`_amplitude_cols` along the row);
    nothing without a map.
    """
    if amp.shape[0] == 0:
        return
    fr = min(max(r * scale - ar0, 0.0), amp.shape[0] - 1.0)
    i = min(int(fr), amp.shape[0] - 2) if amp.shape[0] > 1 else 0
    ti = fr - i
    i1 = min(i + 1, amp.shape[0] - 1)
    for j in range(amp.shape[1]):
        buf[j] = amp[i, j] * (1.0 - ti) + amp[i1, j] * ti


@numba.njit(cache=True)
def _amplitude_cols(n, ac0, scale, c_first, c_step, lo, hi, w_lo, w_hi):
    """Columns and weights of the linear interpolation along a row buffer of ``n`` values.

    For the child columns ``c_first + m c_step`` (m = 0 .. lo.size - 1), the same for every
    row of a pass: the value at m is ``buf[lo[m]] w_lo[m] + buf[hi[m]] w_hi[m]`` with the
    row buffer of :func:`_amplitude_row` (nothing to fill without a map).
    """
    if n == 0:
        return
    for m in range(lo.size):
        c = c_first + m * c_step
        fc = min(max(c * scale - ac0, 0.0), n - 1.0)
        j = min(int(fc), n - 2) if n > 1 else 0
        tj = fc - j
        lo[m] = j
        hi[m] = min(j + 1, n - 1)
        w_lo[m] = 1.0 - tj
        w_hi[m] = tj


#: Output rows of one parallel block of a pass: a block draws its first noise rows afresh
#: (three rows, then one per row), so blocks of 64 rows repeat about 3 % of the draws.
BLOCK_ROWS = 64


def _expand_pass(grid, g_r0, g_c0, sr, sc, out, o_r0, o_c0, tr, axis, sig, wts, taps, key, amp,
                 ar0, ac0, scale, rmin, rmax, cmin, cmax):
    """Run :func:`_expand_rows` over blocks of output rows, on every core.

    Every pixel is a function of its global position and the inputs alone (the noise is
    keyed by position, and a block computes its own noise rows), so the result is the same,
    bit for bit, on any number of threads (:mod:`terrain.core.parallel`).
    """
    if sc != (2 if axis == 1 else 1):  # the kernel counts parent columns, one per step
        raise ValueError(f"a pass along axis {axis} reads grid columns "
                         f"{2 if axis == 1 else 1} apart; got {sc}")
    blocks = (out.shape[0] + BLOCK_ROWS - 1) // BLOCK_ROWS
    run_blocks(_expand_blocks, blocks, grid, g_r0, g_c0, sr, sc, out, o_r0, o_c0, tr, axis,
               sig, wts, taps, key, amp, ar0, ac0, scale, rmin, rmax, cmin, cmax)


@numba.njit(cache=True, nogil=True)
def _expand_blocks(grid, g_r0, g_c0, sr, sc, out, o_r0, o_c0, tr, axis, sig, wts, taps, key,
                   amp, ar0, ac0, scale, rmin, rmax, cmin, cmax, b_first, b_last):
    """Run :func:`_expand_rows` on the blocks ``b_first .. b_last - 1`` of output rows."""
    ny = out.shape[0]
    for b in range(b_first, b_last):
        _expand_rows(grid, g_r0, g_c0, sr, sc, out, o_r0, o_c0, tr, axis, sig, wts, taps, key,
                     amp, ar0, ac0, scale, rmin, rmax, cmin, cmax, b * BLOCK_ROWS,
                     min(ny, (b + 1) * BLOCK_ROWS))


@numba.njit(cache=True, nogil=True)
def _expand_rows(grid, g_r0, g_c0, sr, sc, out, o_r0, o_c0, tr, axis, sig, wts, taps, key, amp,
                 ar0, ac0, scale, rmin, rmax, cmin, cmax, i_first, i_last):
    """One refinement pass of an expansion level over output rows ``i_first:i_last``.

    ``grid`` (origin g_r0, g_c0; spacings sr, sc) holds the points the pass reads; ``out``
    (origin o_r0, o_c0; row spacing ``tr``, column spacing 1) is filled: points already on
    ``grid`` are copied, the midpoints along ``axis`` (1: between columns, 0: between rows)
    are predicted (:func:`terrain.fractal.rmd.predict` with the line weights ``wts``) and displaced
    by
    ``sig[kind]`` times the local amplitude and the correlated Gaussian
    (:func:`terrain.fractal.rmd.noise_rows` with the moving-average ``taps``) keyed at
    (column, row); results are rounded to float32.
    """
    nx = out.shape[1]
    buf = np.empty(amp.shape[1], dtype=np.float64)
    nan = math.nan
    if axis == 1:  # new points at the odd columns of every (even) row
        j_new = 1 - o_c0 % 2
        n_new = len(range(j_new, nx, 2))
        step, b_row, b_col = 2, taps[0], taps[1]
    else:  # new (odd) rows, every column
        j_new = 0
        n_new = nx
        step, b_row, b_col = 1, taps[2], taps[0]
    norm = 1.0 / math.sqrt((1.0 + 2.0 * b_row * b_row) * (1.0 + 2.0 * b_col * b_col))
    has_map = amp.shape[1] > 0  # without a map every displacement's amplitude is 1
    a_lo = np.empty(n_new, dtype=np.int64)
    a_hi = np.empty(n_new, dtype=np.int64)
    w_lo = np.empty(n_new)
    w_hi = np.empty(n_new)
    _amplitude_cols(amp.shape[1], ac0, scale, o_c0 + j_new, step, a_lo, a_hi, w_lo, w_hi)
    g = np.empty(n_new + 2)
    noise = np.empty((3, n_new))
    held = NO_ROW
    for i in range(i_first, i_last):
        r = o_r0 + i * tr
        _amplitude_row(amp, ar0, scale, r, buf)
        if axis == 1:  # along the row: copies at even columns, predictions at odd ones
            held = noise_rows(key, r, 2, o_c0 + j_new, step, b_row, g, noise, held)
            row = grid[(r - g_r0) // sr]
            # grid columns sc = 2 apart and j stepping by 2: the parent index grows by one
            # a step (counted, not divided: an integer division per pixel cost a third of
            # the pass)
            q = (o_c0 + o_c0 % 2 - g_c0) // sc
            for j in range(o_c0 % 2, nx, 2):
                out[i, j] = row[q]
                q += 1
            k = (o_c0 + j_new - 1 - g_c0) // sc
            m = 0
            for j in range(j_new, nx, 2):
                c = o_c0 + j
                m3 = float(row[k - 1]) if c - 3 >= cmin else nan
                p3 = float(row[k + 2]) if c + 3 <= cmax else nan
                z, kind = predict(m3, float(row[k]), float(row[k + 1]), p3, wts)
                a = buf[a_lo[m]] * w_lo[m] + buf[a_hi[m]] * w_hi[m] if has_map else 1.0
                sigma = sig[kind] * a
                e = correlated_value(noise, m, b_col, norm)
                out[i, j] = np.float32(z + sigma * e)
                k += 1
                m += 1
        else:  # along the column: a copied row, or a predicted one from the rows around it
            q0 = o_c0 - g_c0  # grid columns sc = 1 apart: column j is grid column q0 + j
            if r % 2 == 0:
                row = grid[(r - g_r0) // sr]
                for j in range(nx):
                    out[i, j] = row[q0 + j]
                continue
            held = noise_rows(key, r, 2, o_c0, step, b_row, g, noise, held)
            k = (r - 1 - g_r0) // sr
            have_m3 = r - 3 >= rmin
            have_p3 = r + 3 <= rmax
            for j in range(nx):
                c = o_c0 + j
                q = q0 + j
                m3 = float(grid[k - 1, q]) if have_m3 else nan
                p3 = float(grid[k + 2, q]) if have_p3 else nan
                z, kind = predict(m3, float(grid[k, q]), float(grid[k + 1, q]), p3, wts)
                a = buf[a_lo[j]] * w_lo[j] + buf[a_hi[j]] * w_hi[j] if has_map else 1.0
                sigma = sig[kind] * a
                out[i, j] = np.float32(z + sigma * correlated_value(noise, j, b_col, norm))


def parent_region(lo: int, hi: int, parent_size: int) -> tuple[int, int]:
    """Parent index range (inclusive) that child indices lo..hi (inclusive) depend on."""
    return max(0, (lo - 3) // 2), min(parent_size - 1, -(-(hi + 3) // 2))


_NO_MAP = np.zeros((0, 0), dtype=np.float32)


def expand_level(parent: np.ndarray, parent_origin: tuple[int, int], child_rows, child_cols,
                 *, level: int, sigmas: tuple[float, float, float] | np.ndarray, weights,
                 taps, seed: int, amplitude=None, amplitude_origin=(0, 0),
                 amplitude_level: int = 0) -> np.ndarray:
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
    sigmas : (cubic, quadratic, linear)
        Displacement standard deviations (m) of the three predictors
        (:meth:`terrain.fractal.roughness.ExpansionParameters.sigmas`).
    weights : (4,) float
        Line weights of the predictors
        (:meth:`terrain.fractal.roughness.ExpansionParameters.weights`
        of the same level).
    taps : (3,) float
        Moving-average taps of the correlated displacements
        (:meth:`terrain.fractal.roughness.ExpansionParameters.taps`).
    seed : int
    amplitude : (h, w) float32, optional
        Local roughness map (:func:`terrain.fractal.roughness.local_amplitude`) on the grid of
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
    rmin, rmax, cmin, cmax = 2 * pr0, 2 * (pr0 + ph - 1), 2 * pc0, 2 * (pc0 + pw - 1)
    if not (rmin <= r0 <= r1 <= rmax and cmin <= c0 <= c1 <= cmax):
        raise InvalidParameterError("child region lies outside the expansion of its parent")
    sig = np.asarray(sigmas, dtype=np.float64)
    if sig.shape != (3,):
        raise InvalidParameterError(
            f"sigmas must be (cubic, quadratic, linear) standard deviations; got {sigmas!r}")
    wts = np.asarray(weights, dtype=np.float64)
    tap = np.asarray(taps, dtype=np.float64)
    if wts.shape != (4,) or tap.shape != (3,):
        raise InvalidParameterError(
            f"weights must be 4 line weights and taps 3 noise taps; got {weights!r}, {taps!r}")
    amp = _NO_MAP if amplitude is None else np.ascontiguousarray(amplitude, dtype=np.float32)
    scale = 0.5 ** (level - amplitude_level)
    parent = np.ascontiguousarray(parent, dtype=np.float32)
    # pass 1 on the coarse (even) rows the column pass reads: three rows either side
    ra0 = max(rmin, r0 - 3)
    ra0 -= ra0 % 2
    ra1 = min(rmax, r1 + 3)
    ra1 += ra1 % 2
    rows = np.empty(((ra1 - ra0) // 2 + 1, c1 - c0 + 1), dtype=np.float32)
    _expand_pass(parent, rmin, cmin, 2, 2, rows, ra0, c0, 2, 1, sig, wts, tap,
                 np.uint64(key_prefix(seed, STREAM_EXPAND, 2 * level, 0)), amp,
                 float(amplitude_origin[0]), float(amplitude_origin[1]), scale,
                 rmin, rmax, cmin, cmax)
    out = np.empty((r1 - r0 + 1, c1 - c0 + 1), dtype=np.float32)
    _expand_pass(rows, ra0, c0, 2, 1, out, r0, c0, 1, 0, sig, wts, tap,
                 np.uint64(key_prefix(seed, STREAM_EXPAND, 2 * level + 1, 0)), amp,
                 float(amplitude_origin[0]), float(amplitude_origin[1]), scale,
                 rmin, rmax, cmin, cmax)
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


def expanded_known(exact: np.ndarray, shape: tuple[int, int], times: int,
                   origin: tuple[int, int] = (0, 0), current: np.ndarray | None = None
                   ) -> np.ndarray:
    """Place a DEM's exact (float64) heights on the grid of its expansion.

    Expansion keeps every input pixel at the global child pixel ``2^t`` times its index;
    this puts the input's exact heights there, so a writer can store them bitwise
    (:func:`terrain.io.write_dem`'s ``known``) where the float32 grid holds them rounded.

    Parameters
    ----------
    exact : (ny, nx) float64, metres
        The input's heights as stored (NaN unknown), e.g. from
        :func:`terrain.io.read_dem_exact`.
    shape : (rows, cols)
        Shape of the expanded grid.
    times : int
        Expansions between the input and that grid (0: the input's own grid).
    origin : (row, col)
        Global index, at the grid's level, of its pixel (0, 0).
    current : (rows, cols) float32, optional
        The grid's heights: a known pixel whose height is no longer the input's height
        rounded to float32 (a crater was added there on purpose) is left out.

    Returns
    -------
    (rows, cols) float64
        The exact heights on the input's pixels, NaN everywhere else.

    Examples
    --------
    >>> k = expanded_known(np.array([[0.1, 0.2], [0.3, 0.4]]), (3, 3), 1)
    >>> k[::2, ::2].tolist() == [[0.1, 0.2], [0.3, 0.4]], bool(np.isnan(k[1]).all())
    (True, True)
    """
    f = 2**times
    r0, c0 = (int(v) for v in origin)
    rows, cols = (int(v) for v in shape)
    out = np.full((rows, cols), np.nan)
    i0, j0 = (-r0) % f, (-c0) % f  # first local pixel on the input's lattice
    b_r, b_c = (r0 + i0) // f, (c0 + j0) // f
    n_r = min(len(range(i0, rows, f)), exact.shape[0] - b_r)
    n_c = min(len(range(j0, cols, f)), exact.shape[1] - b_c)
    if n_r <= 0 or n_c <= 0:
        return out
    part = np.asarray(exact[b_r:b_r + n_r, b_c:b_c + n_c], dtype=np.float64)
    view = (slice(i0, i0 + f * n_r, f), slice(j0, j0 + f * n_c, f))
    if current is not None:
        same = np.asarray(current[view], dtype=np.float32) == part.astype(np.float32)
        part = np.where(same, part, np.nan)
    out[view] = part
    return out


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
                            sigmas=params.sigmas(level), weights=params.weights(level),
                            taps=params.taps(level), seed=seed, amplitude=amp,
                            amplitude_origin=(r0, c0))
        origin = (rows[level][0], cols[level][0])
        if progress is not None:
            progress(level, times)
    meta = dict(tile.metadata)
    meta[mk.SEED] = str(seed)
    meta[mk.EXPANSION] = json.dumps(dict(params.as_dict(), times=times),
                                               sort_keys=True)
    # the passes write float32 heights, NaN only where a parent is unknown: nothing to check
    return DEMTile.from_trusted(grid, expanded_transform(tile.transform, times, window.row,
                                                         window.col),
                                tile.crs, tile.nodata, meta)
