r"""Fractal roughness of a DEM: measuring it, and the RMD displacement scales that continue it.

Martin et al. (2014, eqs. 13-16) scale the Gaussian displacements of random midpoint
displacement by S_f = 2^(-h/2) per half-step (h = 3 - F, the Hurst exponent), starting from
``S = S_f H D_r W sqrt(1 - 2^(2h - 2))`` (eq. 15; H the height-range factor, D_r the base
resolution, W = 2^(M+1) the base size in pixels). The base's last square phase (the one that
creates its pixel spacing D_r) displaces by ``S S_f^(2M)`` and its last diamond phase by
``S_e = S S_f^(2M+1)`` (eq. 16). Expansion level L (L = 1 doubles the base resolution)
continues the sequence below the base: square phase ``S S_f^(2(M+L))``, diamond phase
``S S_f^(2(M+L)+1)``; each level's displacement is 2^-h times the previous one's.

Measuring what the DEM would need
---------------------------------
RMD adds, at each square phase, the part of a height its four diagonal parents cannot predict.
:func:`estimate` measures exactly that on the DEM itself: the RMS square residual

    sigma(s) = RMS[ z(p) - (z(p + (s, s)) + z(p + (s, -s)) + z(p - (s, s)) + z(p - (s, -s))) / 4 ]

for s = 1, 2, 4, 8 pixels over every valid position, and fits ``sigma(s) = sigma_1 s^h``: the
amplitude sigma_1 at s = 1, the exponent h over s = 2, 4, 8 (:data:`HURST_SPACINGS`; 1, 2, 4
on a DEM too small for them). These
second-order increments remove the local trend, so large-scale topography does not inflate h
the way a first-order variogram does (``docs/roughness.md`` compares the two on the south-pole
DEM). With the fit, the paper's parameters follow: F = 3 - h, and H from eq. 15 such that the base's
last square phase displaces by the measured sigma(1) (:meth:`ExpansionParameters.from_fit`).

Local roughness
---------------
Real terrain is not stationary: smooth plains sit beside rough crater walls. A single global
amplitude spreads the same roughness everywhere, which turns a real DEM's heavy-tailed slope
distribution into a Gaussian-like one. :func:`local_amplitude` measures the square residual
sigma(1) in a box of :data:`LOCAL_BOX` pixels around every base pixel, relative to the global
value, and expansion multiplies every displacement by this map (bilinearly interpolated to the
new pixel), which keeps a real DEM's heavy-tailed slope distribution (``docs/roughness.md``
gives the measurement). The map is a fixed local function of the base
heights (each value sums its own box in a fixed order), so windows stay exact.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass

import numba
import numpy as np

from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.parallel import run_blocks
from terrain.core.tile import DEMTile
from terrain.fractal.regolith import RegolithLaw
from terrain.fractal.rmd import (
    DD_WEIGHTS,
    kriging_line_weights,
    line_sigmas,
    noise_taps,
    prediction_variance,
    scale_factor,
)

__all__ = ["DEFAULT_SPACINGS", "LOCAL_BOX", "ExpansionParameters", "FractalFit",
           "RoughnessChoice", "estimate",
           "local_amplitude", "square_residual"]

#: Square-phase spacings (pixels) measured: sigma(1) sets the amplitude, the slope over
#: :data:`HURST_SPACINGS` the Hurst exponent.
DEFAULT_SPACINGS = (1, 2, 4, 8)
#: Spacings (pixels) of the Hurst fit when the DEM has them all. A sampled DEM holds at its
#: own pixel scale the power aliased from above its Nyquist frequency, which inflates sigma(1)
#: and lowers a fit through it: the LRO NAC SfS DEM of the south pole decimated 8x measures
#: h = 0.68 over 1, 2, 4 pixels and 0.92 over 2, 4, 8, and its expansion continues the real
#: slopes far better with the latter (``docs/roughness.md``).
HURST_SPACINGS = (2, 4, 8)
#: Hurst exponent assumed for a perfectly flat DEM (F = 2.2, the paper's choice).
DEFAULT_HURST = 0.8
#: Range the estimated Hurst exponent is clipped to (F in [2.05, 2.95]).
HURST_RANGE = (0.05, 0.95)
#: Above this many positions a residual uses every k-th row and column (a fixed subset chosen
#: by position, so the estimate is still a function of the whole input alone).
RESIDUAL_POSITIONS = 4_000_000
#: Fewest valid positions a spacing needs to enter the fit.
MIN_POSITIONS = 4
#: Side (base pixels) of the box over which the local roughness amplitude is measured.
LOCAL_BOX = 5
#: Hurst exponents of :data:`CASCADE_EXCESS`.
CASCADE_HURST = tuple(round(0.05 * k, 2) for k in range(1, 20))
#: k(h): square residual of a stationary four-point RMD cascade over that of the fBm whose
#: prediction errors set its displacements (:mod:`terrain.fractal.rmd`), mean over spacings 2, 4, 8
#: and 16 pixels of four 513 x 513 tiles per h (seeds 1000-1003); see
#: :meth:`ExpansionParameters.sigmas` and ``docs/roughness.md``.
CASCADE_EXCESS = (1.937, 1.832, 1.739, 1.656, 1.584, 1.52, 1.463, 1.412, 1.368, 1.328, 1.293,
                  1.262, 1.234, 1.21, 1.188, 1.169, 1.152, 1.138, 1.125)
#: The square residual's neighbours (base pixels): the four diagonal ones.
SQUARE_STENCIL = ((-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0))


def square_residual(heights: np.ndarray, s: int) -> tuple[float, int]:
    """RMS of a pixel minus the mean of its four diagonal neighbours at distance s (m)."""
    ny, nx = heights.shape
    if ny <= 2 * s or nx <= 2 * s:
        return math.nan, 0
    k = max(1, int(math.ceil(math.sqrt(heights.size / RESIDUAL_POSITIONS))))
    if isinstance(heights, np.ndarray):
        r = np.empty(len(range(s, ny - s, k)) * len(range(s, nx - s, k)))
        r = r[:_known_residuals(heights, s, k, r)]
    else:  # an object that answers strided slices (a DEM read from a file in strips)

        def at(dr, dc):  # the strided positions only, in float64
            return np.asarray(heights[s + dr:ny - s + dr:k, s + dc:nx - s + dc:k],
                              dtype=np.float64)

        r = at(0, 0) - 0.25 * (at(-s, -s) + at(-s, s) + at(s, -s) + at(s, s))
        r = r[np.isfinite(r)]
    return (float(np.sqrt(np.mean(r * r))) if r.size else math.nan), int(r.size)


def _square_residuals(heights, spacings, out, first: int, last: int) -> None:
    """:func:`square_residual` at ``spacings[first:last]`` into ``out`` (one spacing a block)."""
    for i in range(first, last):
        out[i] = square_residual(heights, spacings[i])


@numba.njit(cache=True, nogil=True)
def _known_residuals(z, s, k, out):
    """Write the finite square residuals at every k-th row and column into ``out``, in order.

    In one pass what ``c - 0.25 (nw + ne + sw + se)`` on float64 copies of the strided
    views, filtered by ``isfinite``, gives, the same operations in the same order (so the
    same bits) without the temporaries. Returns how many were written.
    """
    ny, nx = z.shape
    n = 0
    for a in range(s, ny - s, k):
        for b in range(s, nx - s, k):
            around = (np.float64(z[a - s, b - s]) + np.float64(z[a - s, b + s])
                      + np.float64(z[a + s, b - s]) + np.float64(z[a + s, b + s]))
            r = np.float64(z[a, b]) - 0.25 * around
            if math.isfinite(r):
                out[n] = r
                n += 1
    return n


@numba.njit(cache=True)
def _residual2(z, a, b):
    """Squared square-residual at (a, b), NaN where a neighbour is unknown."""
    r = z[a, b] - 0.25 * (z[a - 1, b - 1] + z[a - 1, b + 1] + z[a + 1, b - 1] + z[a + 1, b + 1])
    return r * r


#: Output rows of one strip of :func:`_local_amplitude` (a block of work on one thread).
AMPLITUDE_STRIP = 64


@numba.njit(cache=True, nogil=True)
def _local_amplitude(z, r0, r1, c0, c1, half, global_sigma, out, strip_first, strip_last):
    """Box mean of squared square-residuals, as separable row then column sums.

    Every output sums its own box in a fixed order (rows of the box in order, each row's
    columns in order), clipped at the DEM's edges only, so any sub-region computed alone
    gives the same values bitwise. Works in strips of rows to stay in cache: the strips
    ``strip_first .. strip_last - 1`` (of :data:`AMPLITUDE_STRIP` rows from ``r0``).

    The sums run one box offset at a time over a whole row (the inner loops are over
    columns, so they vectorise); a residual that is unknown, or outside the DEM, adds 0.0
    and counts 0, which leaves every partial sum (never -0.0) as skipping it would.
    """
    ny, nx = z.shape
    b0 = max(1, c0 - half)
    b1 = min(nx - 2, c1 - 1 + half)
    width = c1 - c0
    box = 2 * half + 1
    strip = AMPLITUDE_STRIP
    # residuals of a row at columns c0 - half .. c1 - 1 + half, NaN off b0 .. b1
    line = np.full(width + 2 * half, math.nan)
    t = np.empty(width)
    k = np.empty(width)
    for s_index in range(strip_first, strip_last):
        s0 = r0 + s_index * strip
        s1 = min(r1, s0 + strip)
        a0 = max(1, s0 - half)
        a1 = min(ny - 2, s1 - 1 + half)
        na = max(0, a1 - a0 + 1)
        rows2 = np.zeros((na, width))
        rows_n = np.zeros((na, width))
        if b1 >= b0:
            for a in range(a0, a1 + 1):
                for b in range(b0, b1 + 1):
                    line[b - c0 + half] = _residual2(z, a, b)
                sums = rows2[a - a0]
                counts = rows_n[a - a0]
                for d in range(box):
                    for j in range(width):
                        v = line[j + d]
                        known = not math.isnan(v)
                        sums[j] += v if known else 0.0
                        counts[j] += 1.0 if known else 0.0
        for i in range(s0, s1):
            lo = max(a0, i - half)
            hi = min(a1, i + half)
            t[:] = 0.0
            k[:] = 0.0
            for a in range(lo, hi + 1):
                for j in range(width):
                    t[j] += rows2[a - a0, j]
                    k[j] += rows_n[a - a0, j]
            for j in range(width):
                if k[j] == 0.0 or global_sigma <= 0.0:
                    out[i - r0, j] = 1.0
                else:
                    out[i - r0, j] = math.sqrt(t[j] / k[j]) / global_sigma


def local_amplitude(heights: np.ndarray, global_sigma: float, box: int = LOCAL_BOX,
                    rows=None, cols=None) -> np.ndarray:
    """Local square-residual amplitude relative to ``global_sigma`` (see the module docstring).

    Parameters
    ----------
    heights : (ny, nx) float32, metres
        The whole base DEM (NaN unknown).
    global_sigma : float
        The DEM's global sigma(1), metres.
    box : int
        Box side in pixels (odd); 0 or 1 gives a uniform map of ones.
    rows, cols : (first, last), inclusive, optional
        The part of the map to compute (default: all of it).

    Returns
    -------
    (rows, cols) float32
        1 where the DEM is as rough as on average; 1 where nothing can be measured.
    """
    ny, nx = heights.shape
    r0, r1 = rows if rows is not None else (0, ny - 1)
    c0, c1 = cols if cols is not None else (0, nx - 1)
    out = np.ones((r1 - r0 + 1, c1 - c0 + 1), dtype=np.float32)
    if box > 1:
        z = np.ascontiguousarray(heights, dtype=np.float32)
        strips = (r1 + 1 - r0 + AMPLITUDE_STRIP - 1) // AMPLITUDE_STRIP
        run_blocks(_local_amplitude, strips, z, r0, r1 + 1, c0, c1 + 1, box // 2,
                   float(global_sigma), out)
    return out


@dataclass(frozen=True)
class FractalFit:
    """sigma(s) = sigma_1 s^h fitted to a DEM's square residuals (s in pixels, sigma in m)."""

    sigma_1: float
    hurst: float
    spacings: tuple
    sigmas: tuple

    @property
    def fractal_dimension(self) -> float:
        """The fractal dimension D = 3 - H of the fitted surface."""
        return 3.0 - self.hurst


def estimate(tile: DEMTile, spacings=DEFAULT_SPACINGS) -> FractalFit:
    """Fit the square-residual power law of a DEM (see the module docstring).

    A plane has no roughness to continue:

    >>> plane = DEMTile.from_array(np.add.outer(np.arange(50.0), 2 * np.arange(50.0)))
    >>> estimate(plane).sigma_1
    0.0
    """
    used, sigmas = [], []
    positions = 0
    measured: list = [None] * len(spacings)
    if isinstance(tile.heights, np.ndarray):  # one spacing a thread
        run_blocks(_square_residuals, len(spacings), tile.heights, tuple(spacings), measured)
    else:  # strided slices answered from a file, which reads it once: in turn
        _square_residuals(tile.heights, tuple(spacings), measured, 0, len(spacings))
    for s, (sigma, n) in zip(spacings, measured, strict=True):
        positions += n
        if n >= MIN_POSITIONS and math.isfinite(sigma) and sigma > 0:
            used.append(s)
            sigmas.append(sigma)
    if not sigmas and positions >= MIN_POSITIONS:  # perfectly flat: nothing to continue
        return FractalFit(0.0, DEFAULT_HURST, (), ())
    if not sigmas or used[0] != spacings[0]:
        raise InvalidDEMError(
            "cannot estimate roughness: the DEM has too few valid pixels with valid "
            "neighbours; give --fractal-dimension and --height-scale explicitly")
    fit_at = [i for i, s in enumerate(used) if s in HURST_SPACINGS]
    if len(fit_at) < len(HURST_SPACINGS):  # too small for the wide spacings: the narrow ones
        fit_at = [i for i, s in enumerate(used) if s <= 4]
    if len(fit_at) >= 2:
        slope = float(np.polyfit(np.log([used[i] for i in fit_at]),
                                 np.log([sigmas[i] for i in fit_at]), 1)[0])
    else:
        slope = DEFAULT_HURST
    hurst = float(np.clip(slope, *HURST_RANGE))
    return FractalFit(sigmas[0], hurst, tuple(used), tuple(sigmas))


@dataclass(frozen=True)
class ExpansionParameters:
    """Displacement scales of fractal expansion (Martin et al. 2014, eqs. 13-16).

    Parameters
    ----------
    fractal_dimension : float
        F in [2, 3).
    height_scale : float
        H of eq. 15 (height-range factor relative to the base DEM's size).
    base_resolution : float
        D_r, metres per pixel of the base (level 0) DEM.
    base_size : int
        W, the base DEM's size in pixels (its larger side less one).
    estimated : bool
        Whether F and H were measured from the DEM (recorded in metadata).
    local_box : int
        Box (pixels) of the local roughness map that modulates the displacements; 0 for a
        uniform amplitude.
    base_sigma : float
        The base DEM's measured global sigma(1) (m), the reference of the local map.
    regolith : RegolithLaw, optional
        A roughness floor for levels finer than its onset (:meth:`sigmas`); None continues the
        base's own law at every level.
    """

    fractal_dimension: float
    height_scale: float
    base_resolution: float
    base_size: int
    estimated: bool = False
    local_box: int = LOCAL_BOX
    base_sigma: float = 0.0
    regolith: RegolithLaw | None = None

    def __post_init__(self):
        f = float(self.fractal_dimension)
        if not 2.0 <= f < 3.0:
            raise InvalidParameterError(f"fractal dimension must lie in [2, 3); got {f}")
        if not (float(self.height_scale) >= 0 and math.isfinite(float(self.height_scale))):
            raise InvalidParameterError(
                f"height scale must be a non-negative number; got {self.height_scale}")
        if not float(self.base_resolution) > 0:
            raise InvalidParameterError(
                f"base resolution must be positive; got {self.base_resolution}")
        if int(self.base_size) < 2:
            raise InvalidParameterError(f"base size must be >= 2; got {self.base_size}")
        object.__setattr__(self, "fractal_dimension", f)
        object.__setattr__(self, "height_scale", float(self.height_scale))
        object.__setattr__(self, "base_resolution", float(self.base_resolution))
        object.__setattr__(self, "base_size", int(self.base_size))
        object.__setattr__(self, "estimated", bool(self.estimated))
        if int(self.local_box) < 0:
            raise InvalidParameterError(f"local roughness box must be >= 0; got {self.local_box}")
        object.__setattr__(self, "local_box", int(self.local_box))
        object.__setattr__(self, "base_sigma", float(self.base_sigma))
        if self.regolith is not None and not isinstance(self.regolith, RegolithLaw):
            raise InvalidParameterError(
                f"regolith must be a RegolithLaw or None; got {type(self.regolith).__name__}")

    @staticmethod
    def _base_square(f: float, height_scale: float, resolution: float, size: int) -> float:
        """S S_f^(2M): the base's last square-phase displacement (eqs. 15-16)."""
        h = 3.0 - f
        sf = scale_factor(f)
        m = math.log2(size) - 1.0
        s = sf * height_scale * resolution * size * math.sqrt(1.0 - 2.0 ** (2 * h - 2))
        return s * sf ** (2 * m)

    @classmethod
    def from_fit(cls, fit: FractalFit, base_resolution: float, base_size: int,
                 fractal_dimension: float | None = None,
                 local_box: int = LOCAL_BOX) -> ExpansionParameters:
        """Parameters whose base square phase displaces by the measured sigma(1)."""
        f = fit.fractal_dimension if fractal_dimension is None else float(fractal_dimension)
        unit = cls._base_square(f, 1.0, base_resolution, base_size)
        return cls(f, fit.sigma_1 / unit, base_resolution, base_size, estimated=True,
                   local_box=local_box, base_sigma=fit.sigma_1)

    @classmethod
    def for_tile(cls, tile: DEMTile, fractal_dimension=None, height_scale=None,
                 local_box: int = LOCAL_BOX, regolith: RegolithLaw | None = None):
        """Parameters for expanding ``tile``: measured from it unless both F and H are given.

        Given only F, H is still matched to the DEM's measured sigma(1); given only H, F is
        measured. ``local_box`` = 0 switches the local roughness map off; ``regolith`` sets
        the roughness floor of the finest levels (:meth:`sigmas`).
        """
        params = cls._for_tile(tile, fractal_dimension, height_scale, local_box)
        return params if regolith is None else dataclasses.replace(params, regolith=regolith)

    @classmethod
    def _for_tile(cls, tile: DEMTile, fractal_dimension, height_scale, local_box: int):
        from terrain.fractal.rmd import check_fractal_dimension

        if fractal_dimension is not None:
            fractal_dimension = check_fractal_dimension(fractal_dimension)
        if height_scale is not None and not (0 <= height_scale < float("inf")):
            raise InvalidParameterError(f"height scale H must be >= 0 and finite; got "
                                        f"{height_scale}")
        size = max(2, max(tile.shape) - 1)
        if fractal_dimension is not None and height_scale is not None:
            sigma = 0.0
            if local_box:
                try:
                    sigma = estimate(tile).sigma_1
                except InvalidDEMError:  # too small to map: a uniform amplitude
                    sigma = 0.0
            return cls(fractal_dimension, height_scale, tile.resolution, size,
                       local_box=local_box, base_sigma=sigma)
        fit = estimate(tile)
        params = cls.from_fit(fit, tile.resolution, size, fractal_dimension, local_box)
        if height_scale is not None:
            params = cls(params.fractal_dimension, height_scale, tile.resolution, size,
                         estimated=True, local_box=local_box, base_sigma=fit.sigma_1)
        return params

    @property
    def uses_local_map(self) -> bool:
        """Whether the roughness follows a local amplitude map."""
        return self.local_box > 1 and self.base_sigma > 0

    @property
    def hurst(self) -> float:
        """The Hurst exponent H = 3 - D."""
        return 3.0 - self.fractal_dimension

    @property
    def excess(self) -> float:
        """k(h) of :meth:`sigmas`, interpolated in :data:`CASCADE_EXCESS`."""
        return float(np.interp(self.hurst, CASCADE_HURST, CASCADE_EXCESS))

    def unit_variance(self) -> float:
        """V of the fBm continued below the base: variogram ``V r^(2h)``, r in base pixels.

        The base's last square phase (eqs. 15-16) displaces by ``sigma_1``; on fBm that is
        the RMS of a pixel minus the mean of its four diagonal neighbours, whose variance is
        ``V E_sq(h)`` (:func:`terrain.fractal.rmd.prediction_variance` of that stencil), so
        ``V = sigma_1^2 / E_sq(h)``.
        """
        base = self._base_square(self.fractal_dimension, self.height_scale,
                                 self.base_resolution, self.base_size)
        e_sq = prediction_variance(self.hurst, SQUARE_STENCIL, (0.25,) * 4)
        return base * base / e_sq

    def sigmas(self, level: int) -> np.ndarray:
        """(cubic, quadratic, linear) displacement std (m) of expansion ``level`` >= 1.

        A new pixel of level L lies d = 2^-L base pixels from its parents on its line; its
        predictor's error on the fBm of :meth:`unit_variance` has standard deviation
        ``sqrt(V E(h)) d^h`` (:mod:`terrain.fractal.rmd`, module docstring). From level 2 on, each
        level's displacements are 2^-h times the previous level's, the paper's eq. 14 scaling
        over two half-steps (level 1's predictor differs: see below).

        One correction: those errors are exact for a prediction from true fBm heights, as
        level 1's are (the base is the data), but from level 2 on the predictor reads heights
        the expansion made, which carry their own independent displacements where fBm's
        errors are correlated. A stationary cascade built this way (an RMD tile,
        :func:`terrain.fractal.rmd.synthesize`) is an fBm of the right h whose square residual is
        k(h) times that of the fBm its displacements were computed for (:data:`CASCADE_EXCESS`),
        so every displacement is divided by k(h) and the cascade continues the data's own fBm.
        Two further corrections, each derived from the fBm variogram, keep the continued
        spectrum's h at its nominal value at both ends of its range:

        * at h near 1, independent displacements would add a white high-frequency floor
          where fBm's errors move together, so the displacements are drawn with the fBm
          errors' own correlations along and across the line
          (:func:`terrain.fractal.rmd.noise_taps`, derived in :mod:`terrain.fractal.rmd`).
        * at small h, level 1 reads data that holds the power sampling aliased into it from
          above its Nyquist frequency, which the four-point predictor (it reproduces cubics)
          would keep. The conditional expectation of the fBm, which a prediction should be,
          attenuates the data near Nyquist and leaves that power to the displacements: level 1
          predicts by kriging on the fBm variogram from the same four (three, two) points on
          the line (:func:`terrain.fractal.rmd.kriging_line_weights`), displacing by its own
          error, ``sqrt(V E_krig(h)) d^h / k(h)``. Later levels read the cascade's heights,
          which carry no aliased power (each level's kernel band-limits them), and keep the
          four-point predictor, which preserves the cascade's self-similarity.

        ``docs/roughness.md`` gives the measurements behind each correction and the
        alternatives that were tried; ``tests/terrain/test_expand.py`` checks the spectra.

        A :attr:`regolith` law is a floor below its onset: a level whose new pixels lie
        closer than ``regolith.onset_m`` to their parents displaces by the larger of the
        base's continuation and the same construction on the regolith's fBm
        (:meth:`terrain.fractal.regolith.RegolithLaw.variance`), so the roughness steepens
        below a metre where the base's law would let it fade.
        """
        if level < 1:
            raise InvalidParameterError(f"expansion level must be >= 1; got {level}")
        own = (line_sigmas(self.hurst, self.unit_variance(), self.weights(level))
               * 2.0 ** (-level * self.hurst) / self.excess)
        floor = self._regolith_sigmas(level)
        return floor if floor is not None and floor[0] > own[0] else own

    def _regolith_sigmas(self, level: int) -> np.ndarray | None:
        """Return the regolith law's displacements at ``level`` (None above its onset)."""
        law = self.regolith
        if law is None or self.base_resolution / 2.0**level > law.onset_m:
            return None
        h = law.hurst
        excess = float(np.interp(h, CASCADE_HURST, CASCADE_EXCESS))
        return (line_sigmas(h, law.variance(self.base_resolution), self.weights(level))
                * 2.0 ** (-level * h) / excess)

    def regolith_governs(self, level: int) -> bool:
        """Whether the regolith floor sets the displacements of ``level`` (:meth:`sigmas`)."""
        floor = self._regolith_sigmas(level)
        if floor is None:
            return False
        own = (line_sigmas(self.hurst, self.unit_variance(), self.weights(level))
               * 2.0 ** (-level * self.hurst) / self.excess)
        return bool(floor[0] > own[0])

    def weights(self, level: int) -> np.ndarray:
        """(outer, u, v, t) line weights of expansion ``level``'s predictors.

        Level 1 reads the data: kriging on the fBm variogram
        (:func:`terrain.fractal.rmd.kriging_line_weights`); later levels read the cascade's own
        heights: the four-point Deslauriers-Dubuc predictor
        (:data:`terrain.fractal.rmd.DD_WEIGHTS`).
        See :meth:`sigmas`.
        """
        if level < 1:
            raise InvalidParameterError(f"expansion level must be >= 1; got {level}")
        return kriging_line_weights(self.hurst) if level == 1 else DD_WEIGHTS.copy()

    def taps(self, level: int | None = None) -> np.ndarray:
        """Moving-average taps of the correlated displacements (:func:`~.rmd.noise_taps`).

        Those of the regolith's Hurst exponent at a ``level`` the regolith floor governs.
        """
        if level is not None and self.regolith is not None and self.regolith_governs(level):
            return noise_taps(self.regolith.hurst)
        return noise_taps(self.hurst)

    def as_dict(self) -> dict:
        """Return the parameters as plain data for metadata."""
        return asdict(self)


@dataclass(frozen=True)
class RoughnessChoice:
    """What a user chose of a DEM's expansion roughness; the rest is measured from the DEM.

    A layer stack measures its roughness from its base after filling the base's gaps
    (:func:`terrain.stack.build.build_stack`); this record carries the user's choices there, so no
    caller fills gaps or measures roughness itself.

    Parameters
    ----------
    fractal_dimension : float, optional
        F in [2, 3); measured from the DEM when None.
    height_scale : float, optional
        H of eq. 15; measured from the DEM when None.
    uniform : bool
        One roughness everywhere instead of the DEM's local roughness map.
    regolith : RegolithLaw, optional
        The roughness floor of levels finer than its onset (:meth:`ExpansionParameters.sigmas`).
    """

    fractal_dimension: float | None = None
    height_scale: float | None = None
    uniform: bool = False
    regolith: RegolithLaw | None = None

    def for_tile(self, tile: DEMTile) -> ExpansionParameters:
        """Return the expansion parameters of ``tile`` under these choices.

        Parameters
        ----------
        tile : DEMTile
            The DEM to measure (gap-free).

        Returns
        -------
        ExpansionParameters
        """
        return ExpansionParameters.for_tile(tile, self.fractal_dimension, self.height_scale,
                                            local_box=0 if self.uniform else LOCAL_BOX,
                                            regolith=self.regolith)
