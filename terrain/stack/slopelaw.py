r"""A layer stack whose roughness follows a terrain preset's slope law at every level.

A preset's law (:meth:`terrain.core.presets.TerrainPreset.median_slope_deg`, LOLA's
bidirectional slopes, Rosenburg et al. 2011) gives the median slope at every baseline L; for
Gaussian height differences the RMS gradient over L is ``T(L) = tan(theta(L)) / 0.6745``.

A 2x expansion level puts every new pixel ``d`` (half the parent's spacing) from its parents.
Its one-pixel height differences then have two parts: the parent's own slope, carried by the
interpolation (a parent of local RMS gradient ``T_p`` gives ``T_p d``), and the level's random
displacements, whose standard deviation ``s`` adds ``FILL_GAIN s^2`` to their variance. So the
level displaces each new pixel by

    s(x)^2 = d^2 max(0, t^2 - T_p(x)^2) / FILL_GAIN

(:func:`fill_amplitude`, a multiplier of the displacements of the law's own fBm continued
below the base, :func:`law_parameters`): ground smoother than ``t`` is brought up to it, ground
as steep or steeper (crater walls, rough ground) gets nothing. The target ``t`` is one number
per level (:func:`fill_target`): the one for which the layer's median one-pixel slope is the
law's, over the parent's distribution of ``T_p``. Filling every part up to the law's own
``T(d)`` would put the median above the law wherever part of the layer is steeper; and since
the law's slopes include the craters' (every layer adds its own), a level adds what the
parent lacks, not a further octave on top. Where the parent follows the law, the level adds
about one octave of the law; under a base flatter than the law, the first levels bring the
layers up to it. ``T_p`` is measured robustly, as the mean absolute one-pixel difference over
a box of :data:`SLOPE_BOX` parent pixels (times sqrt(pi / 2), its ratio to the RMS for
Gaussian differences), so one crater wall in a box does not stop the fill; ``t`` comes from
``T_p`` on every :data:`SAMPLE_STRIDE`-th parent row and column (:func:`gradient_sample`).

The box is clipped at the parent layer's edges only, and every value sums its own box in a
fixed order, so a window grown by :func:`map_halo` parent pixels gives bitwise the values of
the whole layer, and the sorted sample gives the same target however it was gathered
(chunked builds, :mod:`terrain.stack.chunkedlayers`).

Examples
--------
>>> from terrain.core.presets import preset
>>> law = preset("south-polar")
>>> flat = np.zeros((9, 9), np.float32)
>>> t = fill_target(gradient_sample(flat, 2.0), 2.0, law)
>>> round(t, 3) == round(law.rms_gradient(1.0), 3)      # nothing to share the law with
True
>>> amp = fill_amplitude(flat, 2.0, t, sigma=0.01)
>>> bool(np.allclose(amp, amp[0, 0])) and bool(amp[0, 0] > 1.0)
True
>>> steep = np.add.outer(np.zeros(9), np.arange(9.0)).astype(np.float32)  # 27 deg on 2 m
>>> fill_target(gradient_sample(steep, 2.0), 2.0, law)
0.0
"""

from __future__ import annotations

import math

import numba
import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.core.presets import MEDIAN_ABS_GAUSSIAN

__all__ = ["FILL_GAIN", "SAMPLE_STRIDE", "SLOPE_BOX", "fill_amplitude", "fill_target",
           "fill_from_gradient", "gradient_sample", "law_parameters", "law_record",
           "local_gradient", "map_halo", "strided"]

#: Variance of a layer's one-pixel height differences (median-equivalent: the squared median
#: absolute difference over 0.6745) per unit variance of a 2x expansion's displacements, on a
#: flat parent: 1.30 for Hurst exponents 0.7-0.95 at levels 1 and 2 (half the differences
#: join a parent pixel and a new one, half two new ones whose correlated displacements
#: partly cancel); ``tests/terrain/test_slopelaw.py`` measures it.
FILL_GAIN = 1.30
#: Side (parent pixels) of the box over which a parent's local slope is measured.
SLOPE_BOX = 9
#: Parent pixels between two samples of :func:`gradient_sample` (rows and columns).
SAMPLE_STRIDE = 4
#: Mean |x| over the RMS of a zero-mean Gaussian x.
_MEAN_ABS_GAUSSIAN = math.sqrt(2.0 / math.pi)


def map_halo(box: int = SLOPE_BOX) -> int:
    """Parent pixels a window needs around the map values it computes."""
    return box // 2


@numba.njit(cache=True)
def _local_mean_abs(z, r0, r1, c0, c1, half, out):
    """Mean |one-pixel difference| over the pairs inside each box (clipped at ``z``'s edges).

    Separable: per row, the sums over each output column's box of the row's horizontal
    differences and of its vertical differences to the next row; then per output, the sums of
    those over its box's rows. Every output adds its own terms in a fixed order, so any part
    computed alone gives the same values bitwise.
    """
    ny, nx = z.shape
    a_lo = max(0, r0 - half)
    a_hi = min(ny - 1, r1 - 1 + half)
    width = c1 - c0
    na = a_hi - a_lo + 1
    hs = np.zeros((na, width))
    hn = np.zeros((na, width))
    vs = np.zeros((na, width))
    vn = np.zeros((na, width))
    for a in range(a_lo, a_hi + 1):
        for j in range(width):
            b0 = max(0, c0 + j - half)
            b1 = min(nx - 1, c0 + j + half)
            t = 0.0
            n = 0.0
            u = 0.0
            m = 0.0
            for b in range(b0, b1 + 1):
                if b < b1:
                    w = z[a, b + 1] - z[a, b]
                    if not math.isnan(w):
                        t += abs(w)
                        n += 1.0
                if a < ny - 1:
                    w = z[a + 1, b] - z[a, b]
                    if not math.isnan(w):
                        u += abs(w)
                        m += 1.0
            hs[a - a_lo, j] = t
            hn[a - a_lo, j] = n
            vs[a - a_lo, j] = u
            vn[a - a_lo, j] = m
    for i in range(r0, r1):
        a0 = max(0, i - half)
        a1 = min(ny - 1, i + half)
        for j in range(width):
            t = 0.0
            n = 0.0
            for a in range(a0, a1 + 1):
                t += hs[a - a_lo, j]
                n += hn[a - a_lo, j]
                if a < a1:
                    t += vs[a - a_lo, j]
                    n += vn[a - a_lo, j]
            out[i - r0, j] = t / n if n > 0.0 else 0.0


def local_gradient(heights: np.ndarray, resolution: float, box: int = SLOPE_BOX,
                   rows=None, cols=None) -> np.ndarray:
    """RMS-equivalent gradient of each pixel's box: mean |one-pixel difference| / (0.798 r).

    Parameters
    ----------
    heights : (ny, nx) float, metres
        A layer (NaN unknown), or a window of it grown by :func:`map_halo` pixels wherever
        the layer extends.
    resolution : float
        Metres per pixel.
    box : int
        Box side in pixels.
    rows, cols : (first, last), inclusive, optional
        The pixels of ``heights`` to compute (default: all).

    Returns
    -------
    (rows, cols) float64
        Gradient (m/m); 0 where a box holds no difference.
    """
    ny, nx = heights.shape
    r0, r1 = rows if rows is not None else (0, ny - 1)
    c0, c1 = cols if cols is not None else (0, nx - 1)
    out = np.zeros((r1 - r0 + 1, c1 - c0 + 1))
    z = np.ascontiguousarray(heights, dtype=np.float64)
    _local_mean_abs(z, r0, r1 + 1, c0, c1 + 1, box // 2, out)
    return out / (_MEAN_ABS_GAUSSIAN * resolution)


def fill_amplitude(parent: np.ndarray, resolution: float, target: float, sigma: float,
                   box: int = SLOPE_BOX, rows=None, cols=None) -> np.ndarray:
    """Displacement multiplier of the next level that brings it to ``target`` (module docstring).

    Parameters
    ----------
    parent : (ny, nx) float, metres
        The parent layer (or a window of it grown by :func:`map_halo`).
    resolution : float
        The parent's metres per pixel; the new level's pixels lie half that from their parents.
    target : float
        The RMS gradient (m/m) the new level's one-pixel differences are brought up to
        (:func:`fill_target`).
    sigma : float
        The level's own displacement standard deviation (m, the cubic predictor's), which the
        multiplier scales.
    box : int
    rows, cols : (first, last), optional
        The parent pixels to compute (default: all).

    Returns
    -------
    (rows, cols) float32
        Multiplier of ``sigma``; 0 where the parent is at least as steep as the target.
    """
    return fill_from_gradient(local_gradient(parent, resolution, box, rows, cols), resolution,
                              target, sigma)


def fill_from_gradient(tp: np.ndarray, resolution: float, target: float,
                       sigma: float) -> np.ndarray:
    """:func:`fill_amplitude` from the parent's local gradients ``tp`` (:func:`local_gradient`)."""
    if not sigma > 0:
        raise InvalidParameterError(f"a level's displacement must be positive; got {sigma}")
    d = 0.5 * float(resolution)
    need = d * np.sqrt(np.maximum(0.0, target * target - tp * tp) / FILL_GAIN)
    return (need / float(sigma)).astype(np.float32)


def gradient_sample(parent: np.ndarray, resolution: float, origin=(0, 0), rows=None,
                    cols=None, box: int = SLOPE_BOX) -> np.ndarray:
    """Return the parent's local gradients on every :data:`SAMPLE_STRIDE`-th row and column.

    ``origin`` is the global (row, col) of the computed part's first pixel, so a layer read
    in windows (each grown by :func:`map_halo`) gives the same values as the whole layer.
    """
    return strided(local_gradient(parent, resolution, box, rows, cols), origin)


def strided(tp: np.ndarray, origin=(0, 0)) -> np.ndarray:
    """Every :data:`SAMPLE_STRIDE`-th value of a gradient map whose first is at ``origin``."""
    i0 = (-origin[0]) % SAMPLE_STRIDE
    j0 = (-origin[1]) % SAMPLE_STRIDE
    return tp[i0::SAMPLE_STRIDE, j0::SAMPLE_STRIDE].ravel()


def fill_target(sample: np.ndarray, resolution: float, law) -> float:
    """Return the RMS gradient a level fills up to, so that its median slope is the law's.

    Filling every part of a layer up to the law's slope would put the layer's median above
    the law wherever part of it is steeper (crater walls, rough ground). Each sampled parent
    gradient ``T_p`` leaves the new level's one-pixel differences Gaussian with RMS
    ``d max(T_p, t)``; ``t`` is chosen so that half of these differences, over the sample,
    are below the law's median ``d tan(theta(d))`` (0 where the parent alone reaches it).

    Parameters
    ----------
    sample : (n,) float
        Parent gradients (:func:`gradient_sample`), m/m.
    resolution : float
        The parent's metres per pixel.
    law : terrain.core.presets.TerrainPreset

    Returns
    -------
    float
        Target RMS gradient, m/m.
    """
    from scipy.special import erf

    tp = np.sort(np.asarray(sample, dtype=np.float64).ravel())
    median = math.tan(math.radians(law.median_slope_deg(0.5 * float(resolution))))
    if tp.size == 0:
        return median / MEDIAN_ABS_GAUSSIAN

    # below(t): the share of differences under the median, over samples of RMS max(T_p, t):
    # samples under t each contribute erf(m / (sqrt 2 t)); those above, their own (summed
    # from the top once, in a fixed order)
    with np.errstate(divide="ignore"):
        own = np.where(tp > 0, erf(median / (math.sqrt(2.0) * np.where(tp > 0, tp, 1.0))),
                       1.0)
    above = np.concatenate([np.cumsum(own[::-1])[::-1], [0.0]])

    def below(t):
        k = int(np.searchsorted(tp, t, side="left"))
        under = k * (float(erf(median / (math.sqrt(2.0) * t))) if t > 0 else 1.0)
        return (under + float(above[k])) / tp.size

    if below(0.0) <= 0.5:
        return 0.0
    lo, hi = 0.0, 4.0 * median / MEDIAN_ABS_GAUSSIAN
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if below(mid) > 0.5:
            lo = mid
        else:
            hi = mid
    return hi


def law_parameters(law, base_resolution: float, base_size: int, regolith=None):
    """Expansion parameters that continue the law's own fBm below a base.

    The law's median slope ``theta(L)`` is that of an fBm with variogram ``V L^(2H)`` whose
    Gaussian differences have ``sqrt(V) = tan(theta(17 m)) / 0.6745 * (17 m)^(1 - H)``; in
    base pixels ``V_px = V D_r^(2H)``. :meth:`ExpansionParameters.unit_variance` is linear in
    the squared height scale, so the height scale follows.

    Parameters
    ----------
    law : terrain.core.presets.TerrainPreset
    base_resolution : float
        Metres per pixel of the base.
    base_size : int
        The base's size in pixels (its larger side less one).
    regolith : terrain.fractal.regolith.RegolithLaw, optional
        The regolith floor below a metre.

    Returns
    -------
    terrain.fractal.roughness.ExpansionParameters
        Uniform (no local map), ``estimated`` False.
    """
    from terrain.core.presets import LAW_BASELINE_M
    from terrain.fractal.roughness import ExpansionParameters

    h = float(law.hurst)
    if not 0.0 < h <= 1.0:
        raise InvalidParameterError(f"slope law Hurst exponent must lie in (0, 1]; got {h}")
    h = min(h, 0.999)
    v_m = (law.rms_gradient(LAW_BASELINE_M) * LAW_BASELINE_M ** (1.0 - h)) ** 2
    v_px = v_m * float(base_resolution) ** (2.0 * h)
    unit = ExpansionParameters(3.0 - h, 1.0, base_resolution, base_size, local_box=0)
    scale = math.sqrt(v_px / unit.unit_variance())
    return ExpansionParameters(3.0 - h, scale, base_resolution, base_size, local_box=0,
                               regolith=regolith)


def law_record(law) -> dict:
    """Return the slope law as plain data for metadata and a chunked build's plan."""
    return dict(preset=law.name, slope_17m_deg=law.slope_17m_deg, hurst=law.hurst,
                self_affine_max_m=law.self_affine_max_m, fill_gain=FILL_GAIN, box=SLOPE_BOX)
