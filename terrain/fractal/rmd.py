r"""Random midpoint displacement synthesis of fractal terrain, with the Hurst exponent it names.

Martin et al. (2014, section IV.A) generate fBm-like terrain by random midpoint displacement
(RMD): a tile of (2^n + 1)^2 pixels, W = 2^n, is refined from its four corners by halving the
spacing again and again, every new point taking a prediction from the points already there
plus a Gaussian whose scale shrinks by ``S_f = 2^(-h/2)`` per half-step (eq. 14, h = 3 - F the
Hurst exponent). With the paper's predictor, the mean of the two or four nearest parents
(diamond-square), the surface's radially averaged power spectrum is flatter than the
``f^-(2h + 2)`` of fBm: fitted as :func:`evaluation.spectrum.fit_hurst` does, 513 x 513 tiles
gave h = 0.20, 0.38, 0.57, 0.76 for nominal 0.3, 0.5, 0.7, 0.9. The cause is the predictor.
Averaging is linear interpolation, whose kernel (a tent) has a spectrum falling only as
``f^-4``: every level leaks power into all finer scales in proportion ``(s f)^(2h - 2)`` of
its own, which for h near 1 is nearly as much as the finer levels add themselves. An infinite
cascade would still scale correctly, but a tile starts at W: at low frequencies the leakage of
the missing coarser levels is absent, so the spectrum is short of power at large scales and
its fitted slope (h) too low.

The predictor and the variances used here
-----------------------------------------
We refine each level separably with the four-point interpolating subdivision of Deslauriers
and Dubuc (1989): first every row of the coarse grid gets the midpoints between its columns,
then every column of the result gets the midpoints between its rows, each predicted from the
four nearest points on its line,

    z(p) = (-z(p - 3d) + 9 z(p - d) + 9 z(p + d) - z(p + 3d)) / 16 + sigma e,

with d half the coarse spacing and e ~ N(0, 1). Its kernel reproduces cubics, so its spectrum
falls as ``f^-8`` and a level's leakage into finer scales, ``(s f)^(2h - 6)`` of its own, is
negligible: the spectrum follows ``f^-(2h + 2)`` from the first levels on. Where the line has
no point at ``p - 3d`` (or ``p + 3d``: the tile's border, or a gap) the quadratic through the
three points there predicts, ``(3 z(p - d) + 6 z(p + d) - z(p + 3d)) / 8``, and where it has only
the two parents, their mean.

sigma is the exact conditional error of each predictor on fBm. For a surface with variogram
``E[(z(a) - z(b))^2] = V |a - b|^(2h)``, the error of a linear predictor
``e = z(p) - sum w_i z(p_i)`` (weights summing to 1) has variance

    Var e = -1/2 sum_i sum_j a_i a_j V |p_i - p_j|^(2h),   a = (1, -w_1, ..., -w_k),

(the variogram form of a variance of an increment, e.g. Chiles and Delfiner 2012, eq. 4.6),
so ``sigma^2 = V d^(2h) E(h)`` with E the sum at unit d for the predictor's points
(:func:`prediction_variance`; at h = 0.8, E = 0.232 for the four-point predictor, 0.262
for the quadratic and 0.242 for the two-point mean). The relief R stays the paper's scale
parameter: the four corners are independent, N(0, c^2) with ``c = S / S_f =
R sqrt(1 - 2^(2h - 2))`` as in the paper (eq. 15), which fixes ``V = 2 c^2 / W^(2h)``.

Correlated displacements
------------------------
On fBm the errors of neighbouring predictions are not independent: two errors share
variogram terms, so their covariance follows from the same sum,

    Cov(e, e') = -1/2 sum_i sum_j a_i a'_j V |p_i - p'_j|^(2h),

(:func:`error_correlations`). For the four-point predictor the correlation of the next new
point on the line (2d along) is +0.064 at h = 0.3, 0 at 0.5 and -0.137 at 0.9; of the next
line of the row pass (2d across) +0.018 ... +0.084; of the next line of the column pass
(d across, every column is refined there) +0.105 ... +0.321. Independent displacements
put the error's power evenly over the new octave where fBm concentrates it (at h near 1)
at the octave's low end, and between neighbouring columns, where fBm's errors move
together, they add a white high-frequency floor: a re-expanded h = 0.9 fBm measured
h = 0.85. Each displacement here is therefore a separable three-tap moving average of
keyed Gaussians, ``sum_(i, j in -1..1) b_i c_j g(q + i step_along + j step_across)`` with
``b_0 = c_0 = 1``, ``b_(+-1) = beta_along``, ``c_(+-1) = beta_across`` normalised to unit
variance (:func:`noise_rows`, :func:`correlated_value`; one Gaussian per position, summed
row by row), whose lag-one correlations ``2 beta / (1 + 2 beta^2)`` equal the fBm's
(:func:`noise_taps`); lag-two and diagonal terms are second order (below 0.05). On
513 x 513 tiles the fitted Hurst exponent is within 0.03 of nominal for h = 0.3 ... 0.9
(``tests/terrain/test_rmd.py``).

Expansion (:mod:`terrain.fractal.expand`) refines real data, not a cascade of its own, and uses at
its first level the best linear predictor on the line instead of the four-point one
(:func:`kriging_line_weights`, :meth:`terrain.fractal.roughness.ExpansionParameters.sigmas` says
why).

Every Gaussian is keyed by ``(seed, "rmd", pass, global column, global row)`` (pass -1 for the
corners, 2j and 2j + 1 for the row and column passes of level j; a displacement's moving
average reads the Gaussians keyed at its neighbours' positions, a function of position
alone), and a window is computed
from exactly the points its pixels depend on (three half-spacings either side per level, the
index-range recursion of Gaskell 2005, section 2), so a window computed alone equals the same
window of the full tile, bitwise.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from terrain.core import memory
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, key_prefix, normal_at, normal_scalar, stream_id
from terrain.core.tile import Window

__all__ = ["DD_WEIGHTS", "NO_ROW", "PREDICTORS", "check_fractal_dimension", "check_tile_size",
           "correlated_value", "error_correlations", "initial_scale", "kriging_line_weights",
           "kriging_weights", "line_sigmas", "noise_rows", "noise_taps", "predict",
           "prediction_variance", "scale_factor", "synthesize"]

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


#: Predictor kinds of :func:`prediction_variance` (indices into a sigma triple).
CUBIC, QUADRATIC, LINEAR = 0, 1, 2
#: Points (in half-spacings d from the new point) and weights of each predictor.
PREDICTORS = {
    CUBIC: ((-3.0, -1.0, 1.0, 3.0), (-1 / 16, 9 / 16, 9 / 16, -1 / 16)),
    QUADRATIC: ((-1.0, 1.0, 3.0), (3 / 8, 6 / 8, -1 / 8)),
    LINEAR: ((-1.0, 1.0), (0.5, 0.5)),
}


def prediction_variance(hurst: float, points, weights) -> float:
    """E(h): variance of ``z(0) - sum w_i z(p_i)`` on fBm with unit variogram ``|r|^(2h)``.

    ``points`` are positions (scalars on a line, or (x, y) pairs), ``weights`` sum to 1.

    >>> round(prediction_variance(0.5, (-1.0, 1.0), (0.5, 0.5)), 6)   # Brownian bridge
    0.5
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 1:
        pts = pts[:, None]
    pts = np.vstack([np.zeros((1, pts.shape[1])), pts])
    a = np.r_[1.0, -np.asarray(weights, dtype=float)]
    dist = np.sqrt(((pts[:, None, :] - pts[None, :, :]) ** 2).sum(-1))
    return float(-0.5 * a @ (dist ** (2.0 * hurst)) @ a)


#: (outer, u, v, t) line weights of :func:`predict` for the Deslauriers-Dubuc predictors of
#: :data:`PREDICTORS`: four points ``outer (z(-3d) + z(3d)) + (1/2 - outer) (z(-d) + z(d))``,
#: three points (no point at -3d) ``u z(-d) + v z(d) + t z(3d)``.
DD_WEIGHTS = np.array([-1 / 16, 3 / 8, 6 / 8, -1 / 8])


def kriging_weights(hurst: float, points) -> np.ndarray:
    """Weights of the best linear predictor of ``z(0)`` from ``z(points)`` on a line of fBm.

    Minimises :func:`prediction_variance` for the variogram ``|r|^(2h)`` subject to
    ``sum w = 1`` and ``sum w p = 0`` (intrinsic kriging with a linear drift, so a plane is
    predicted exactly): the Lagrange system ``sum_j w_j g(p_i - p_j) + mu + nu p_i = g(p_i)``
    with the semivariogram ``g(r) = |r|^(2h) / 2`` (Chiles and Delfiner 2012, section 3.4).

    >>> [round(float(w), 6) + 0.0 for w in kriging_weights(0.5, (-3.0, -1.0, 1.0, 3.0))]
    [0.0, 0.5, 0.5, 0.0]
    """
    p = np.asarray(points, dtype=float)
    n = p.size
    a = np.zeros((n + 2, n + 2))
    a[:n, :n] = 0.5 * np.abs(p[:, None] - p[None, :]) ** (2.0 * hurst)
    a[:n, n] = a[n, :n] = 1.0
    a[:n, n + 1] = a[n + 1, :n] = p
    b = np.r_[0.5 * np.abs(p) ** (2.0 * hurst), 1.0, 0.0]
    return np.linalg.solve(a, b)[:n]


def kriging_line_weights(hurst: float) -> np.ndarray:
    """(outer, u, v, t) weights (as :data:`DD_WEIGHTS`) of the kriging predictors at h.

    >>> [round(float(w), 4) for w in kriging_line_weights(0.3)]
    [0.0678, 0.5286, 0.4428, 0.0286]
    """
    four = kriging_weights(hurst, PREDICTORS[CUBIC][0])
    three = kriging_weights(hurst, PREDICTORS[QUADRATIC][0])
    return np.array([0.5 * (four[0] + four[3]), three[0], three[1], three[2]])


def line_sigmas(hurst: float, unit_variance: float, weights=DD_WEIGHTS) -> np.ndarray:
    """(four-, three-, two-point) displacement std at unit half-spacing: sqrt(V E(h)).

    ``weights`` are the (outer, u, v, t) line weights of :func:`predict`.
    """
    o, u, v, t = (float(x) for x in weights)
    w = {CUBIC: (o, 0.5 - o, 0.5 - o, o), QUADRATIC: (u, v, t), LINEAR: (0.5, 0.5)}
    return np.array([math.sqrt(max(0.0, unit_variance * prediction_variance(
        hurst, PREDICTORS[k][0], w[k]))) for k in (CUBIC, QUADRATIC, LINEAR)])


def _error_terms(offset, across, axis_points=PREDICTORS[CUBIC]):
    """Return points and coefficients of the four-point error at q = (offset, across).

    The error is ``z(q) - sum w_i z(q + p_i)``, the predictor running along x.
    """
    pts, w = axis_points
    pos = [(offset, across)] + [(offset + p, across) for p in pts]
    return np.array(pos, dtype=float), np.r_[1.0, -np.asarray(w, dtype=float)]


def error_correlations(hurst: float) -> tuple[float, float, float]:
    """Correlations of neighbouring four-point prediction errors on fBm (module docstring).

    Returns (along, across the coarse rows, across the fine columns): the error at q with
    the error at the next new point on its line (2 half-spacings along), on the next coarse
    line of the row pass (2 half-spacings across) and on the next line of the column pass
    (1 half-spacing across).

    >>> [round(r, 4) for r in error_correlations(0.9)]
    [-0.1374, 0.0837, 0.3205]
    """
    def cov(a, b):
        (pa, wa), (pb, wb) = a, b
        dist = np.sqrt(((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1))
        return float(-0.5 * wa @ dist ** (2.0 * hurst) @ wb)

    e0 = _error_terms(0.0, 0.0)
    var = cov(e0, e0)
    return tuple(cov(e0, _error_terms(dx, dy)) / var for dx, dy in ((2.0, 0.0), (0.0, 2.0),
                                                                      (0.0, 1.0)))


def noise_taps(hurst: float) -> np.ndarray:
    """(along, row-pass across, column-pass across) taps beta of the correlated displacements.

    A three-tap moving average ``g(0) + beta (g(-1) + g(1))`` of independent Gaussians has
    lag-one correlation ``rho = 2 beta / (1 + 2 beta^2)``; beta is the root of smaller
    magnitude, ``(1 - sqrt(1 - 2 rho^2)) / (2 rho)``, for each of :func:`error_correlations`.
    """
    out = []
    for rho in error_correlations(hurst):
        rho = min(max(rho, -0.7), 0.7)
        out.append(0.0 if abs(rho) < 1e-12 else (1.0 - math.sqrt(1.0 - 2.0 * rho * rho))
                   / (2.0 * rho))
    return np.array(out)


#: Row index no pass reaches: :func:`noise_rows` holds nothing yet.
NO_ROW = -(2**62)


@numba.njit(cache=True)
def _noise_row(key, r, c_first, step, b_row, g, out):
    """Sum along the row the Gaussians keyed at row r into ``out``.

    ``g(c) + b_row (g(c - step) + g(c + step))`` at columns ``c_first + m step``
    (m = 0 .. out.size - 1); ``g`` is scratch.
    """
    n = out.size
    for m in range(n + 2):
        g[m] = normal_at(key, c_first + (m - 1) * step, r)
    for m in range(n):
        out[m] = g[m + 1] + b_row * (g[m] + g[m + 2])


@numba.njit(cache=True)
def noise_rows(key, r, dr, c_first, step, b_row, g, rows, held):
    """Make ``rows`` hold the along-row sums of rows ``r - dr, r, r + dr`` (:func:`_noise_row`).

    ``held`` is the r ``rows`` was last filled for (:data:`NO_ROW` at first): moving on by
    ``dr`` computes one new row. Returns r. With :func:`correlated_value` this draws the
    separable three-tap moving average of the module docstring with one Gaussian per position.
    """
    if held == r - dr:
        rows[0, :] = rows[1, :]
        rows[1, :] = rows[2, :]
        _noise_row(key, r + dr, c_first, step, b_row, g, rows[2])
    elif held != r:
        for k in range(3):
            _noise_row(key, r + (k - 1) * dr, c_first, step, b_row, g, rows[k])
    return r


@numba.njit(cache=True)
def correlated_value(rows, m, b_col, norm):
    """Return the unit-variance correlated Gaussian at column index m of :func:`noise_rows`.

    ``(rows[1, m] + b_col (rows[0, m] + rows[2, m])) norm``, a function of global position
    only (so windows stay exact).
    """
    return (rows[1, m] + b_col * (rows[0, m] + rows[2, m])) * norm



@numba.njit(cache=True)
def predict(m3, m1, p1, p3, w):
    """(prediction, kind) of the point between m1 and p1 from up to four line neighbours.

    m3 and p3 (three half-spacings out) may be NaN where the line has no point there; the
    predictor falls back to three points, then to the mean of the two parents. ``w`` holds
    the (outer, u, v, t) line weights (:data:`DD_WEIGHTS`, :func:`kriging_line_weights`).
    """
    if math.isnan(m3):
        if math.isnan(p3):
            return 0.5 * (m1 + p1), LINEAR
        return w[1] * m1 + w[2] * p1 + w[3] * p3, QUADRATIC
    if math.isnan(p3):
        return w[1] * p1 + w[2] * m1 + w[3] * m3, QUADRATIC
    return w[0] * (m3 + p3) + (0.5 - w[0]) * (m1 + p1), CUBIC


@numba.njit(cache=True)
def _at(prev, pr0, pc0, sr, sc, r, c, w_r, w_c):
    """Prev at global (r, c) on its grid, NaN outside the tile [0, w_r] x [0, w_c]."""
    if r < 0 or c < 0 or r > w_r or c > w_c:
        return math.nan
    return prev[(r - pr0) // sr, (c - pc0) // sc]


@numba.njit(cache=True)
def _pass(prev, pr0, pc0, sr, sc, out, or0, oc0, tr, tc, axis, w_r, w_c, sig, taps, key, gr0,
          gc0):
    """One separable refinement pass (see the module docstring), in global pixel indices.

    ``prev`` (origin pr0, pc0; spacings sr, sc) holds the coarse points; ``out`` (origin or0,
    oc0; spacings tr, tc) is filled: points on ``prev``'s grid are copied, the others
    (midpoints along ``axis``: 1 = between columns, 0 = between rows) are predicted and
    displaced by ``sig[kind]`` times the correlated Gaussian (``taps``: along, row-pass
    across, column-pass across) keyed at their global position.
    """
    ny, nx = out.shape
    if axis == 1:  # new points at every other column of every row
        j0 = 1 if oc0 % sc == 0 else 0
        n_new = len(range(j0, nx, 2))
        c_first, step, dr = gc0 + oc0 + j0 * tc, 2 * tc, sr
        b_row, b_col = taps[0], taps[1]
    else:  # new rows, every column
        j0 = 0
        n_new = nx
        c_first, step, dr = gc0 + oc0, tc, 2 * tr
        b_row, b_col = taps[2], taps[0]
    norm = 1.0 / math.sqrt((1.0 + 2.0 * b_row * b_row) * (1.0 + 2.0 * b_col * b_col))
    g = np.empty(n_new + 2)
    rows = np.empty((3, n_new))
    held = NO_ROW
    for i in range(ny):
        r = or0 + i * tr
        if axis == 1 or r % sr != 0:
            held = noise_rows(key, gr0 + r, dr, c_first, step, b_row, g, rows, held)
        for j in range(nx):
            c = oc0 + j * tc
            if axis == 1:
                if c % sc == 0:
                    out[i, j] = prev[(r - pr0) // sr, (c - pc0) // sc]
                    continue
                d = tc
                m = (j - j0) // 2
                m3 = _at(prev, pr0, pc0, sr, sc, r, c - 3 * d, w_r, w_c)
                m1 = prev[(r - pr0) // sr, (c - d - pc0) // sc]
                p1 = prev[(r - pr0) // sr, (c + d - pc0) // sc]
                p3 = _at(prev, pr0, pc0, sr, sc, r, c + 3 * d, w_r, w_c)
            else:
                if r % sr == 0:
                    out[i, j] = prev[(r - pr0) // sr, (c - pc0) // sc]
                    continue
                d = tr
                m = j
                m3 = _at(prev, pr0, pc0, sr, sc, r - 3 * d, c, w_r, w_c)
                m1 = prev[(r - d - pr0) // sr, (c - pc0) // sc]
                p1 = prev[(r + d - pr0) // sr, (c - pc0) // sc]
                p3 = _at(prev, pr0, pc0, sr, sc, r + 3 * d, c, w_r, w_c)
            z, kind = predict(m3, m1, p1, p3, DD_WEIGHTS)
            out[i, j] = z + sig[kind] * correlated_value(rows, m, b_col, norm)


def _needed_ranges(lo: int, hi: int, w: int) -> list[tuple[int, int]]:
    """Return the index range (inclusive) needed at every spacing 1, 2, 4, ..., w.

    Three half-spacings of the finer level either side, on the coarser grid, clipped to the
    tile.
    """
    ranges = [(lo, hi)]
    h = 1
    while h < w:
        s = 2 * h
        lo = max(0, ((lo - 3 * h) // s) * s)
        hi = min(w, -((-(hi + 3 * h)) // s) * s)
        ranges.append((lo, hi))
        h = s
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
        Metres: the paper's ``H * D_r * W`` (eq. 15); the corner heights have standard
        deviation ``relief * sqrt(1 - 2^(2h - 2))``, which sets the variogram of the whole tile
        (see the module docstring).
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
    memory.require(window.width * window.height * 8 * 3.5, f"synthesising a {size}x{size} tile")
    gr0, gc0 = (int(v) for v in origin)

    rows = _needed_ranges(window.row, window.row + window.height - 1, w)
    cols = _needed_ranges(window.col, window.col + window.width - 1, w)
    hurst = 3.0 - f
    # V of the module docstring: independent N(0, R^2) corners W apart
    corner = initial_scale(f, relief) / scale_factor(f)  # S / S_f of eq. 15
    unit = line_sigmas(hurst, 2.0 * corner**2 / float(w) ** (2.0 * hurst))
    taps = noise_taps(hurst)

    # Corners: spacing w, N(0, (S / S_f)^2), keyed at pass -1.
    (r0, r1), (c0, c1) = rows[n], cols[n]
    grid = np.empty(((r1 - r0) // w + 1, (c1 - c0) // w + 1))
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            r, c = r0 + i * w, c0 + j * w
            grid[i, j] = corner * normal_scalar(seed, STREAM_RMD, -1, gc0 + c, gr0 + r, 0)
    origin_r, origin_c = r0, c0
    s = w
    level = 0
    while s > 1:
        h = s // 2
        k = level_index(h)
        (sr0, sr1), (hc0, hc1) = rows[k + 1], cols[k]
        (hr0, hr1) = rows[k]
        sig = unit * float(h) ** hurst
        # pass 1: midpoints between columns, on the coarse rows
        part = np.empty(((sr1 - sr0) // s + 1, (hc1 - hc0) // h + 1))
        _pass(grid, origin_r, origin_c, s, s, part, sr0, hc0, s, h, 1, w, w, sig, taps,
              np.uint64(key_prefix(seed, STREAM_RMD, 2 * level, 0)), gr0, gc0)
        # pass 2: midpoints between rows, on every column
        out = np.empty(((hr1 - hr0) // h + 1, part.shape[1]))
        _pass(part, sr0, hc0, s, h, out, hr0, hc0, h, h, 0, w, w, sig, taps,
              np.uint64(key_prefix(seed, STREAM_RMD, 2 * level + 1, 0)), gr0, gc0)
        grid, origin_r, origin_c = out, hr0, hc0
        s = h
        level += 1
    return grid


def level_index(spacing: int) -> int:
    """log2 of a power-of-two spacing."""
    return int(spacing).bit_length() - 1
