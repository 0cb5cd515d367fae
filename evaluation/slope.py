r"""Horn slope and aspect of DEMs, cumulative slope-frequency distributions, matched baselines.

Slope and aspect
----------------
Horn's (1981) 3x3 weighted differences, computed exactly as GDAL's ``gdaldem slope -alg Horn``
and ``gdaldem aspect`` compute them (``apps/gdaldem_lib.cpp``, ``GDALSlopeHornAlg`` and
``GDALAspectAlg``). With the window

    a b c
    d e f
    g h i

and pixel spacing ``r`` metres::

    dx = ((a + d + d + g) - (c + f + f + i)) / r        # = -8 dz/d(east)
    dy = ((g + h + h + i) - (a + b + b + c)) / r        # = -8 dz/d(north)
    slope  = atan(sqrt(dx^2 + dy^2) / 8)                 # degrees
    aspect = azimuth of the downslope direction (-grad z), degrees clockwise from north

GDAL adds the window terms in float32 (the template type of its float path) and only then
converts to double; this module does the same additions in the same order, so its slopes and
aspects are the ones gdaldem writes, bit for bit on every float32 DEM we compared (the
tests check 1e-4 degrees against the ``gdaldem`` binary). The float32 sums cost accuracy
on DEMs whose heights are far from zero: on the Aristarchus QuickMap DEM (heights near
-1360 m, 4.76 m pixels) a float64 evaluation of the same formula differs by up to
1.9e-3 degrees. That is far below anything a slope distribution resolves, and agreeing
with the reference tool is worth more to a user cross-checking in QGIS; this is why this
module supersedes :func:`terrain.surface.hillshade.horn_gradient` (float64, edges replicated)
for evaluation instead of reusing it.

Edges and gaps (``edges``):

``"mask"`` (default, gdaldem without ``-compute_edges``)
    The outermost rows and columns, and every pixel whose 3x3 window touches an invalid
    pixel, are NaN: nothing is extrapolated, so statistics see only measured slopes.
``"gdal"`` (gdaldem ``-compute_edges``)
    Missing rows and columns outside the DEM are extrapolated linearly (``2 z0 - z1``);
    invalid neighbours are replaced by the centre pixel; only invalid pixels are NaN. In its
    first and last rows GDAL clamps the column index instead of extrapolating, so the four
    corner windows repeat the edge column and see half the east-west gradient (on a plane
    rising 0.3 m/m eastwards the corners get 8.5 degrees instead of 16.7); this mode does
    the same, to stay identical to gdaldem.

Aspect is NaN where the surface is exactly flat (gdaldem writes its nodata value there).

Distributions
-------------
The paper's Fig. 11 plots, per layer, "the percentage of terrain greater than a given slope
angle" (Martin et al. 2014, section V.E). :func:`cumulative_distribution` computes exactly
that over the valid pixels (or over weights such as vertex areas, for meshes).

Matched baselines
-----------------
A Horn slope on a grid of spacing r measures the slope over a 2r baseline, so the slopes of
DEMs of different resolution are compared after the finer DEM has been resampled to the
coarser one's spacing (:func:`resample`, an area-weighted average that uses only valid
pixels: each coarse pixel is valid when valid fine pixels cover at least
:data:`MIN_COVERAGE` of it).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from affine import Affine
from scipy import sparse

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.tile import DEMTile

__all__ = ["DEFAULT_ANGLES", "EDGE_MODES", "QUANTILES", "SlopeDistribution",
           "cumulative_distribution", "horn", "horn_aspect", "horn_slope", "matched_baseline",
           "resample", "slope_distribution", "slope_tile", "stack_distributions",
           "weighted_quantiles"]

log = logging.getLogger(__name__)

#: Slope thresholds (degrees) at which cumulative distributions are tabulated: 0.5 degree
#: steps, fine enough for the paper's Fig. 11-13 (1-5 degree ticks).
DEFAULT_ANGLES = np.arange(0.0, 90.0 + 1e-9, 0.5)
#: Quantiles reported with every distribution (fractions).
QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99)
#: Edge handling modes of :func:`horn` (see the module docstring).
EDGE_MODES = ("mask", "gdal")
#: A resampled pixel is valid when valid source pixels cover at least this fraction of it.
MIN_COVERAGE = 0.999
#: Peak bytes per pixel of :func:`horn` (padded float32 copy, window copies in "gdal" mode,
#: window sums, float64 intermediates; measured 52 in "mask" and 77 in "gdal" mode).
HORN_BYTES_PER_PIXEL = 80
#: Peak bytes per input pixel of :func:`resample` (float64 masked copies and sparse
#: products; measured 56).
RESAMPLE_BYTES_PER_PIXEL = 64


# ------------------------------------------------------------------------- slope, aspect


def _check_tile(tile) -> DEMTile:
    if not isinstance(tile, DEMTile):
        raise InvalidParameterError(f"expected a DEMTile; got {type(tile).__name__}")
    return tile


def _windows(tile: DEMTile, edges: str) -> list[np.ndarray]:
    """Return the nine (ny, nx) float32 views a..i of every pixel's 3x3 window (row-major)."""
    if edges not in EDGE_MODES:
        raise InvalidParameterError(f"edges must be one of {EDGE_MODES}; got {edges!r}")
    z = tile.heights  # float32, NaN where invalid
    ny, nx = z.shape
    p = np.full((ny + 2, nx + 2), np.nan, dtype=np.float32)
    p[1:-1, 1:-1] = z
    if edges == "gdal" and ny >= 2 and nx >= 2:
        two = np.float32(2.0)
        # GDAL's INTERPOL(a, b) = 2 a - b in float32; NaN stays NaN (becomes the centre below)
        p[0, 1:-1] = two * z[0] - z[1]
        p[-1, 1:-1] = two * z[-1] - z[-2]
        p[1:-1, 0] = two * z[:, 0] - z[:, 1]
        p[1:-1, -1] = two * z[:, -1] - z[:, -2]
    views = [p[r:r + ny, c:c + nx] for r in range(3) for c in range(3)]
    if edges == "gdal":
        if ny >= 2 and nx >= 2:
            views = [v.copy() for v in views]
            # In its first and last rows GDAL clamps the column index (jmin = j, jmax = j),
            # so the four corner windows repeat the edge column instead of extrapolating it.
            for row in (0, ny - 1):
                for k in (0, 3, 6):
                    views[k][row, 0] = views[k + 1][row, 0]
                for k in (2, 5, 8):
                    views[k][row, nx - 1] = views[k - 1][row, nx - 1]
        centre = views[4]
        views = [np.where(np.isnan(v), centre, v) for v in views]
    return views


def _sums(views) -> tuple[np.ndarray, np.ndarray]:
    """GDAL's Horn sums, float32 in GDAL's order: x = left - right, y = bottom - top."""
    a, b, c, d, _, f, g, h, i = views
    x = (((a + d) + d) + g) - (((c + f) + f) + i)
    y = (((g + h) + h) + i) - (((a + b) + b) + c)
    return x, y


def horn(tile: DEMTile, *, edges: str = "mask") -> tuple[np.ndarray, np.ndarray]:
    """Horn slope and aspect, as gdaldem computes them (see the module docstring).

    Parameters
    ----------
    tile : DEMTile
        Heights in metres on square pixels (metres).
    edges : {"mask", "gdal"}
        Edge and gap handling (module docstring).

    Returns
    -------
    slope : (ny, nx) float32, degrees in [0, 90]
        NaN where invalid (see ``edges``).
    aspect : (ny, nx) float32, degrees in [0, 360)
        Azimuth of steepest descent, clockwise from north (grid up); NaN where invalid or
        exactly flat.

    Examples
    --------
    A plane rising 1 m per metre to the east faces west:

    >>> t = DEMTile.from_array(np.tile(np.arange(5.0), (4, 1)))
    >>> s, a = horn(t)
    >>> float(s[1, 1]), float(a[1, 1]), bool(np.isnan(s[0, 0]))
    (45.0, 270.0, True)
    """
    tile = _check_tile(tile)
    memory.require(tile.heights.size * float(HORN_BYTES_PER_PIXEL),
                   f"Horn slope of a {tile.shape[1]}x{tile.shape[0]} DEM")
    x, y = _sums(_windows(tile, edges))
    res = tile.resolution
    with np.errstate(invalid="ignore"):
        dx = x.astype(np.float64) / res
        dy = y.astype(np.float64) / -res  # GDAL divides by the (negative) north-south step
        slope = np.degrees(np.arctan(np.sqrt(dx * dx + dy * dy) / 8.0)).astype(np.float32)
        # GDALAspectAlg: atan2(dy, -dx') with dx' = right - left = -x, unit spacing
        ang = np.degrees(np.arctan2(y.astype(np.float64), x.astype(np.float64)))
        ang = ang.astype(np.float32)
        aspect = np.where(ang > np.float32(90.0), np.float32(450.0) - ang,
                          np.float32(90.0) - ang).astype(np.float32)
    aspect[aspect == np.float32(360.0)] = np.float32(0.0)
    aspect[(x == 0) & (y == 0)] = np.nan
    # Horn's sums skip the centre pixel, so an invalid centre must be masked explicitly
    # (GDAL's ComputeVal returns nodata for it before looking at the window).
    slope[~tile.valid] = np.nan
    aspect[np.isnan(slope)] = np.nan
    return slope, aspect


def horn_slope(tile: DEMTile, *, edges: str = "mask") -> np.ndarray:
    """Horn slope in degrees, ``(ny, nx) float32``, NaN where invalid (see :func:`horn`)."""
    return horn(tile, edges=edges)[0]


def horn_aspect(tile: DEMTile, *, edges: str = "mask") -> np.ndarray:
    """Horn aspect (azimuth of descent, degrees from north), ``(ny, nx) float32`` (:func:`horn`)."""
    return horn(tile, edges=edges)[1]


def slope_tile(tile: DEMTile, *, edges: str = "mask") -> DEMTile:
    """Return the slope map as a tile with the DEM's georeferencing (values in degrees, not metres).

    The quantity is recorded in the metadata (``CRATERSCAPE_QUANTITY``), since a DEMTile's
    values are heights by default.
    """
    slope = horn_slope(tile, edges=edges)
    meta = dict(tile.metadata)
    meta.update(**{mk.QUANTITY: "Horn slope (degrees)", mk.SLOPE_EDGES: edges})
    return DEMTile(slope, np.isfinite(slope), tile.transform, tile.crs, float("nan"), meta)


# ----------------------------------------------------------------------- distributions


def _as_values(values, weights):
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if weights is None:
        w = None
        keep = np.isfinite(v)
    else:
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape != v.shape:
            raise InvalidParameterError(
                f"weights must match values: expected shape {v.shape}; got {w.shape}")
        if np.any(w < 0):
            raise InvalidParameterError("weights must be non-negative")
        keep = np.isfinite(v) & np.isfinite(w) & (w > 0)
        w = w[keep]
    return v[keep], w


def cumulative_distribution(values, angles=None, weights=None) -> np.ndarray:
    """Percentage of terrain steeper than each angle (the paper's Fig. 11 ordinate).

    Parameters
    ----------
    values : array of float, degrees
        Slopes; NaN are ignored.
    angles : (k,) float, degrees, optional
        Thresholds (default :data:`DEFAULT_ANGLES`).
    weights : array of float, optional
        Non-negative weights (e.g. areas) of the values; default equal.

    Returns
    -------
    (k,) float64, percent
        ``100 * sum(w[v > angle]) / sum(w)``.

    Examples
    --------
    >>> cumulative_distribution([1.0, 2.0, 3.0, 4.0], angles=[0.0, 2.0, 4.0]).tolist()
    [100.0, 50.0, 0.0]
    """
    angles = DEFAULT_ANGLES if angles is None else np.asarray(angles, dtype=np.float64)
    v, w = _as_values(values, weights)
    if v.size == 0:
        raise InvalidParameterError("no valid slopes to build a distribution from")
    if w is None:  # equal weights: the sorted values are all it needs (a sort, not an argsort)
        v = np.sort(v)
        below = np.searchsorted(v, angles, side="right")
        return 100.0 * (v.size - below) / v.size
    order = np.argsort(v, kind="stable")
    v = v[order]
    cw = np.concatenate([[0.0], np.cumsum(w[order])])
    below = np.searchsorted(v, angles, side="right")
    return 100.0 * (cw[-1] - cw[below]) / cw[-1]


def weighted_quantiles(values, quantiles=QUANTILES, weights=None) -> dict:
    """Quantiles (and mean) of values, optionally weighted; keys ``p10``, ``p50``, ..., ``mean``.

    Weighted quantiles take the smallest value whose cumulative weight reaches the fraction.

    >>> weighted_quantiles(np.arange(101.0), quantiles=(0.5,))
    {'p50': 50.0, 'mean': 50.0, 'max': 100.0}
    """
    v, w = _as_values(values, weights)
    if v.size == 0:
        raise InvalidParameterError("no valid values to take quantiles of")
    out = {}
    if w is None:
        # one partition for every quantile: the same order statistics and interpolation as
        # one call per quantile, the same bits, at a third of the time on a 1024^2 layer
        at = np.quantile(v, np.asarray(quantiles, dtype=np.float64))
        for q, x in zip(quantiles, at, strict=True):
            out[f"p{round(q * 100):d}"] = float(x)
        out["mean"] = float(v.mean())
    else:
        order = np.argsort(v, kind="stable")
        sv, cw = v[order], np.cumsum(w[order])
        for q in quantiles:
            k = min(int(np.searchsorted(cw, q * cw[-1], side="left")), sv.size - 1)
            out[f"p{round(q * 100):d}"] = float(sv[k])
        out["mean"] = float(np.sum(v * w) / np.sum(w))
    out["max"] = float(v.max())
    return out


@dataclass(frozen=True, eq=False)
class SlopeDistribution:
    """The cumulative slope-frequency distribution of one DEM (or layer).

    Parameters
    ----------
    label : str
        Name shown in tables and plots.
    resolution_m : float
        Pixel spacing at which the slopes were computed (the Horn baseline is twice this).
    angles_deg : (k,) float64
    percent_steeper : (k,) float64, percent
        Percentage of valid pixels steeper than each angle.
    pixels : int
        Number of valid slopes.
    quantiles : dict
        ``p10 ... p99``, ``mean``, ``max`` in degrees.
    source : str
        File it came from, if any.
    """

    label: str
    resolution_m: float
    angles_deg: np.ndarray
    percent_steeper: np.ndarray
    pixels: int
    quantiles: dict = field(default_factory=dict)
    source: str = ""

    def as_dict(self) -> dict:
        """Return the distribution as plain data for the report's JSON."""
        return dict(label=self.label, resolution_m=self.resolution_m, pixels=self.pixels,
                    source=self.source, quantiles=self.quantiles,
                    angles_deg=self.angles_deg.tolist(),
                    percent_steeper=self.percent_steeper.tolist())


def slope_distribution(tile: DEMTile, *, label: str = "", edges: str = "mask", angles=None,
                       slopes: np.ndarray | None = None) -> SlopeDistribution:
    """Cumulative slope distribution of a DEM's Horn slopes (``slopes`` if already computed)."""
    tile = _check_tile(tile)
    if slopes is None:
        slopes = horn_slope(tile, edges=edges)
    elif np.shape(slopes) != tile.shape:
        raise InvalidParameterError(
            f"slopes must have the DEM's shape {tile.shape}; got {np.shape(slopes)}")
    angles = DEFAULT_ANGLES if angles is None else np.asarray(angles, dtype=np.float64)
    valid = np.isfinite(slopes)
    n = int(valid.sum())
    if n == 0:
        raise InvalidDEMError(f"DEM {label or tile.metadata.get(mk.SOURCE, '')!s} "
                              "has no pixel whose whole 3x3 window is valid; no slope to "
                              "measure")
    values = slopes[valid]
    return SlopeDistribution(label, tile.resolution, angles,
                             cumulative_distribution(values, angles),
                             n, weighted_quantiles(values),
                             tile.metadata.get(mk.SOURCE, ""))


def stack_distributions(stack_dir, *, edges: str = "mask", angles=None,
                        label: str | None = None) -> list[SlopeDistribution]:
    """One distribution per layer of a layer stack (the paper's Fig. 11).

    Parameters
    ----------
    stack_dir : str or Path
        The stack folder, or its ``manifest.json``.
    label : str, optional
        Prefix of the labels (default the folder name); each gets ``_layer_NN``.
    """
    from terrain.stack.store import read_stack

    stack_dir = Path(stack_dir)
    if stack_dir.name == "manifest.json":
        stack_dir = stack_dir.parent
    stack = read_stack(stack_dir)
    prefix = label or stack_dir.name
    return [slope_distribution(t, label=f"{prefix}_layer_{k:02d}", edges=edges, angles=angles)
            for k, t in enumerate(stack.tiles)]


# --------------------------------------------------------------------------- resampling


def _overlap_matrix(n_in: int, n_out: int, factor: float) -> sparse.csr_matrix:
    """(n_out, n_in) fractions of each input cell inside each output cell (1-D, area)."""
    rows, cols, vals = [], [], []
    for o in range(n_out):
        lo, hi = o * factor, (o + 1) * factor
        first, last = int(math.floor(lo)), min(int(math.ceil(hi)), n_in)
        for k in range(first, last):
            w = min(hi, k + 1) - max(lo, k)
            if w > 1e-12:
                rows.append(o)
                cols.append(k)
                vals.append(w)
    return sparse.csr_matrix((vals, (rows, cols)), shape=(n_out, n_in))


def resample(tile: DEMTile, resolution: float) -> DEMTile:
    """Area-weighted average of a DEM onto a coarser square grid of ``resolution`` metres.

    The new grid starts at the tile's upper-left corner and holds as many whole coarse pixels
    as fit. Each coarse height is the mean of the fine heights weighted by the area they
    share, over valid fine pixels only; coarse pixels less than :data:`MIN_COVERAGE`
    covered by valid fine pixels are invalid (no gap is smeared into terrain).

    Parameters
    ----------
    tile : DEMTile
    resolution : float
        Metres per pixel, at least the tile's own (this averages; it never refines).

    Returns
    -------
    DEMTile
        Same CRS, north-up transform at the new spacing.

    Examples
    --------
    >>> t = DEMTile.from_array(np.arange(16.0).reshape(4, 4))
    >>> resample(t, 2.0).heights.tolist()
    [[2.5, 4.5], [10.5, 12.5]]
    """
    tile = _check_tile(tile)
    resolution = float(resolution)
    if not (resolution > 0 and math.isfinite(resolution)):
        raise InvalidParameterError(f"resolution must be positive metres; got {resolution}")
    factor = resolution / tile.resolution
    if factor < 1.0 - 1e-9:
        raise InvalidParameterError(
            f"resampling averages onto a coarser grid; asked for {resolution:g} m from a "
            f"{tile.resolution:g} m DEM")
    if abs(factor - 1.0) <= 1e-9:
        return tile
    ny, nx = tile.shape
    oy, ox = int(math.floor(ny / factor + 1e-9)), int(math.floor(nx / factor + 1e-9))
    if oy < 1 or ox < 1:
        raise InvalidParameterError(
            f"a {nx}x{ny} DEM at {tile.resolution:g} m holds no {resolution:g} m pixel")
    memory.require(tile.heights.size * float(RESAMPLE_BYTES_PER_PIXEL),
                   f"resampling a {nx}x{ny} DEM to {resolution:g} m")
    wr = _overlap_matrix(ny, oy, factor)
    wc = _overlap_matrix(nx, ox, factor)
    valid = tile.valid.astype(np.float64)
    z = np.where(tile.valid, tile.heights, 0.0).astype(np.float64)
    total = np.asarray((wr @ sparse.csr_matrix(z * valid) @ wc.T).todense())
    cover = np.asarray((wr @ sparse.csr_matrix(valid) @ wc.T).todense())
    area = factor * factor
    ok = cover >= MIN_COVERAGE * area
    with np.errstate(invalid="ignore", divide="ignore"):
        heights = np.where(ok, total / np.where(cover > 0, cover, 1.0), np.nan)
    t = tile.transform
    transform = Affine(resolution, 0.0, t.c, 0.0, -resolution, t.f)
    meta = dict(tile.metadata)
    meta[mk.RESAMPLED_FROM_M] = repr(tile.resolution)
    return DEMTile(heights, ok, transform, tile.crs, tile.nodata, meta)


def matched_baseline(a: DEMTile, b: DEMTile) -> tuple[DEMTile, DEMTile]:
    r"""Return both DEMs at the coarser one's spacing (the finer one is :func:`resample`\ d).

    >>> fine = DEMTile.from_array(np.zeros((8, 8)), resolution=1.0)
    >>> coarse = DEMTile.from_array(np.zeros((4, 4)), resolution=2.0)
    >>> [t.resolution for t in matched_baseline(fine, coarse)]
    [2.0, 2.0]
    """
    a, b = _check_tile(a), _check_tile(b)
    coarse = max(a.resolution, b.resolution)
    if math.isclose(a.resolution, b.resolution, rel_tol=1e-6):
        return a, b
    return resample(a, coarse), resample(b, coarse)
