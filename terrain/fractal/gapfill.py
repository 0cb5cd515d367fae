"""Filling DEM gaps with terrain instead of smooth interpolation (Martin et al. 2014, IV.B-C).

Fractal gap filling (section IV.B)
----------------------------------
"The number of known neighbors for each unknown pixel is calculated and used to order the list.
Pixels with the most number of known neighbors are filled first ... This fills gaps from the
outside inwards. An individual hole pixel is filled by defining the new value as a weighted
average of the nearest neighboring pixels in all eight directions plus a random unit Gaussian
scaled by the roughness parameter and the DEM horizontal resolution. The weighting is the
inverse of the pixel distance to the known value pixel."

The paper re-sorts the whole list after every pixel; we keep eight first-in-first-out
buckets, one per count of known neighbours, with lazy updates, so each fill costs O(1) plus
the eight ray walks, which stop at the first known (or already filled) pixel and after
:data:`MAX_RAY` pixels. The order (most known neighbours first; within a count, first queued
first) and every Gaussian (keyed by ``(seed, "fill", 0, column, row)``) depend on nothing but
the input.

The roughness R (the Gaussian is ``R * resolution`` metres) is estimated per gap by default,
from the variability of the Horn slopes of the known pixels within :data:`RING` pixels of the
gap (:func:`estimate_roughness`).

Crater gap filling (section IV.C) and clean-up
----------------------------------------------
:func:`fill_crater_gaps` fills a copy of the DEM with fractal terrain, adds the user's craters
to it, and copies the crater-region pixels back into the gaps "warped" by the inverse-distance
average of (original - copy) at the nearest known pixels in the eight directions, so the
synthetic crater meets the real terrain without a step. :func:`despike` turns pixels far from
their local median into gaps, and :func:`denoise` smooths known pixels with a mask-aware
Gaussian, as the paper did to the Clementine/RADAR DEM before filling.

Nothing here changes a known height (bitwise), except :func:`despike` and :func:`denoise`,
which exist to do so and say what they changed.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass

import numba
import numpy as np
from numba.typed import List
from scipy import ndimage

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.rng import check_seed, key_prefix, normal_at, stream_id
from terrain.core.tile import DEMTile
from terrain.surface.hillshade import horn_gradient

__all__ = ["FILL_GRADIENT_GAIN", "MAX_RAY", "RING", "FillResult", "crater_region", "denoise",
           "despike", "estimate_roughness", "fill_crater_gaps", "fill_gaps"]

log = logging.getLogger(__name__)

STREAM_FILL = stream_id("fill")
#: Longest ray walk (pixels) when looking for the nearest known pixel in a direction.
MAX_RAY = 64
#: Width (pixels) of the band of known pixels around a gap that sets its roughness.
RING = 8
#: Horn-gradient RMS the fill produces per unit roughness R on flat ground (measured; see
#: estimate_roughness).
FILL_GRADIENT_GAIN = 0.85

#: Gaussian (pixels) applied to the original-minus-copy differences before warping.
WARP_SMOOTHING = 2.0

_DIRS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)],
                 dtype=np.int64)
_SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True, eq=False)
class FillResult:
    """A filled tile and the mask of the pixels that were filled."""

    tile: DEMTile
    filled: np.ndarray
    roughness: dict


@numba.njit(cache=True)
def _idw(z, known, i, j, max_ray):
    """Inverse-distance average of the nearest known pixel in each of the eight directions.

    A ray that leaves the DEM is reflected at its edge (index -1 reads 0, -2 reads 1, ...),
    so a gap on the border is filled from as many directions as one inside: otherwise the
    fill would average fewer neighbours there and come out rougher.
    """
    ny, nx = z.shape
    total = 0.0
    weights = 0.0
    for d in range(8):
        di = _DIRS[d, 0]
        dj = _DIRS[d, 1]
        step = _SQRT2 if di != 0 and dj != 0 else 1.0
        for k in range(1, max_ray + 1):
            a = i + k * di
            b = j + k * dj
            if a < 0 or a >= ny or b < 0 or b >= nx:
                a = _reflect(a, ny)
                b = _reflect(b, nx)
                if a == i and b == j:
                    break  # reflected back onto the pixel itself
            if known[a, b]:
                w = 1.0 / (k * step)
                total += w * z[a, b]
                weights += w
                break
    if weights == 0.0:
        return math.nan
    return total / weights


@numba.njit(cache=True)
def _reflect(a, n):
    """Mirror an index into [0, n) (half-sample symmetric, period 2n)."""
    if n == 1:
        return 0
    a = a % (2 * n)
    if a < 0:
        a += 2 * n
    return a if a < n else 2 * n - 1 - a


@numba.njit(cache=True)
def _count_known(known, i, j):
    ny, nx = known.shape
    n = 0
    for d in range(8):
        a = i + _DIRS[d, 0]
        b = j + _DIRS[d, 1]
        if 0 <= a < ny and 0 <= b < nx and known[a, b]:
            n += 1
    return n


@numba.njit(cache=True)
def _fill(z, known, fillable, sigma, key, max_ray, row0=0, col0=0):
    """Fill every fillable pixel reachable from a known one; returns the number filled.

    ``sigma`` is the per-pixel Gaussian scale (m). The queue is eight FIFO buckets, one per
    count of known neighbours (1..8), always served from the fullest count: O(1) per push and
    pop. A pixel whose count rises is pushed again into the higher bucket and its old entry
    is skipped when it comes up (lazy deletion). Unknown pixels that are not fillable are
    never filled; rays pass through them. ``row0, col0``: global position of pixel (0, 0),
    which keys the Gaussians.
    """
    ny, nx = z.shape
    count = np.zeros((ny, nx), dtype=np.int8)
    buckets = List()
    for _ in range(9):
        lst = List()
        lst.append(np.int64(0))
        lst.pop()
        buckets.append(lst)
    heads = np.zeros(9, dtype=np.int64)
    for i in range(ny):
        for j in range(nx):
            if fillable[i, j] and not known[i, j]:
                n = _count_known(known, i, j)
                count[i, j] = n
                if n > 0:
                    buckets[n].append(np.int64(i * nx + j))
    filled = 0
    top = 8
    while True:
        while top > 0 and heads[top] >= len(buckets[top]):
            top -= 1
        if top == 0:
            break
        idx = buckets[top][heads[top]]
        heads[top] += 1
        i = idx // nx
        j = idx % nx
        if known[i, j] or count[i, j] != top:
            continue  # already filled, or a stale entry superseded by a newer count
        value = _idw(z, known, i, j, max_ray)
        z[i, j] = value + sigma[i, j] * normal_at(key, col0 + j, row0 + i)
        known[i, j] = True
        filled += 1
        for d in range(8):
            a = i + _DIRS[d, 0]
            b = j + _DIRS[d, 1]
            if 0 <= a < ny and 0 <= b < nx and fillable[a, b] and not known[a, b]:
                count[a, b] += 1
                buckets[count[a, b]].append(np.int64(a * nx + b))
                if count[a, b] > top:
                    top = count[a, b]
    return filled


def estimate_roughness(tile: DEMTile, gaps: np.ndarray | None = None, *, ring: int = RING):
    """Per-gap roughness R (dimensionless; the fill's Gaussian is R * resolution metres).

    Parameters
    ----------
    tile : DEMTile
    gaps : (ny, nx) bool, optional
        Pixels to fill (default: the invalid pixels).
    ring : int
        Width of the band of known pixels measured around each gap.

    Returns
    -------
    labels : (ny, nx) int32
        Gap label of every gap pixel (0 elsewhere).
    roughness : (n_gaps + 1,) float64
        R per label (index 0 unused).

    Notes
    -----
    The fill adds a Gaussian of sigma = R * resolution to the inverse-distance average at
    every pixel; on flat ground the result has a Horn slope (gradient) RMS of about
    :data:`FILL_GRADIENT_GAIN` * R, almost independent of the gap's size (0.73 for an
    81-pixel disc, 0.88 for 5,000 pixels, 0.92 for 20,000). So R is set to make the filled
    gradient as variable as the terrain around the gap: the RMS deviation of the known band's
    Horn gradients from their mean (the band's plane) divided by that gain. Horn's stencil
    looks across two pixels, so it is blind to pixel-scale checkerboard noise, which real
    stereo and shape-from-shading DEMs often carry and which a pixel residual would mistake
    for roughness. Where a gap has no measurable band (a tiny DEM), the DEM-wide value is used.
    """
    gaps = ~tile.valid if gaps is None else np.asarray(gaps, dtype=bool)
    labels, n = ndimage.label(gaps, structure=np.ones((3, 3), bool))
    gx, gy = horn_gradient(tile)
    ok = np.isfinite(gx) & np.isfinite(gy) & ~gaps
    gx0 = np.where(ok, gx, 0.0)
    gy0 = np.where(ok, gy, 0.0)

    def deviation(sel_sum, sel_count):
        mx, my = sel_sum[0] / sel_count, sel_sum[1] / sel_count
        return np.sqrt(np.maximum(0.0, sel_sum[2] / sel_count - mx**2
                                  + sel_sum[3] / sel_count - my**2))

    if ok.any():
        totals = [gx0.sum(), gy0.sum(), (gx0**2).sum(), (gy0**2).sum()]
        global_dev = float(deviation(totals, ok.sum()))
    else:
        global_dev = 0.0
    rough = np.full(n + 1, global_dev)
    if n:
        near = ndimage.grey_dilation(labels, size=(2 * ring + 1, 2 * ring + 1))
        near = np.where(ok, near, 0)
        index = np.arange(n + 1)
        sums = [ndimage.sum_labels(v, near, index=index) for v in (gx0, gy0, gx0**2, gy0**2)]
        counts = ndimage.sum_labels(ok.astype(np.float64), near, index=index)
        have = counts >= 4
        dev = deviation([v[have] for v in sums], counts[have])
        rough[have] = dev
    rough = rough / FILL_GRADIENT_GAIN
    rough[0] = 0.0
    return labels.astype(np.int32), rough


def fill_gaps(tile: DEMTile, *, seed: int = 0, roughness: float | None = None,
              gaps: np.ndarray | None = None, max_ray: int = MAX_RAY,
              origin: tuple[int, int] = (0, 0)) -> FillResult:
    """Fill unknown pixels with fractal terrain, from the outside in.

    Parameters
    ----------
    tile : DEMTile
    seed : int
    roughness : float, optional
        R, the Gaussian per filled pixel in units of the resolution; estimated per gap from
        the known pixels around it by default.
    gaps : (ny, nx) bool, optional
        Which unknown pixels to fill (default: all of them).
    max_ray : int
        Longest ray walk in pixels.
    origin : (row, col)
        Global pixel position of the tile's pixel (0, 0), which keys the randomness: a part
        of a larger DEM filled with its origin equals the same pixels of the whole DEM
        filled, when every gap in it is whole (:class:`terrain.execution.chunked.FillSource`).

    Returns
    -------
    FillResult
        The tile with its gaps filled (known heights unchanged, bitwise), the mask of filled
        pixels, and the roughness used per gap.

    Examples
    --------
    >>> h = np.zeros((20, 20)); h[5:9, 5:9] = np.nan
    >>> r = fill_gaps(DEMTile.from_array(h), seed=1, roughness=0.0)
    >>> int(r.filled.sum()), bool(np.all(r.tile.heights == 0.0))
    (16, True)
    """
    seed = check_seed(seed)
    if not tile.valid.any():
        raise InvalidDEMError("cannot fill a DEM with no known pixels")
    if roughness is not None and not (roughness >= 0 and math.isfinite(roughness)):
        raise InvalidParameterError(f"roughness must be a non-negative number; got {roughness}")
    if max_ray < 1:
        raise InvalidParameterError(f"max_ray must be >= 1; got {max_ray}")
    todo = ~tile.valid if gaps is None else (np.asarray(gaps, dtype=bool) & ~tile.valid)
    ny, nx = tile.shape
    memory.require(ny * nx * (8 + 8 + 8 + 1 + 4) + todo.sum() * 8 * 16,
                   f"filling {int(todo.sum())} unknown pixels")
    if roughness is None:
        labels, per_gap = estimate_roughness(tile, todo)
        sigma = per_gap[labels] * tile.resolution
        rough_info = {"estimated": True, "per_gap": [round(float(v), 6) for v in per_gap[1:]]}
    else:
        sigma = np.full(tile.shape, float(roughness) * tile.resolution)
        rough_info = {"estimated": False, "value": float(roughness)}
    z = tile.heights.astype(np.float64)
    known = tile.valid.copy()
    key = np.uint64(key_prefix(seed, STREAM_FILL, 0, 0))
    n = _fill(z, known, np.ascontiguousarray(todo),
              np.ascontiguousarray(sigma, dtype=np.float64), key, int(max_ray),
              int(origin[0]), int(origin[1]))
    log.info("filled %d pixels", n)
    out = z.astype(np.float32)
    # Known heights are copied back untouched (float32 -> float64 -> float32 is exact anyway).
    out[tile.valid] = tile.heights[tile.valid]
    filled = known & ~tile.valid
    meta = dict(tile.metadata)
    meta[mk.SEED] = str(seed)
    meta[mk.FILL] = json.dumps(dict(rough_info, filled=int(filled.sum()),
                                               max_ray=int(max_ray)), sort_keys=True)
    result = tile.replace(heights=out, valid=known, metadata=meta)
    return FillResult(result, filled, rough_info)


@numba.njit(cache=True)
def _warp(diff, known, targets_i, targets_j, max_ray, out):
    """Inverse-distance average of ``diff`` at the nearest known pixel in 8 directions."""
    for n in range(targets_i.size):
        out[n] = _idw(diff, known, targets_i[n], targets_j[n], max_ray)


def crater_region(tile: DEMTile, craters) -> np.ndarray:
    """Pixels inside the rim (r <= D/2) of any crater of a CraterTable."""
    ny, nx = tile.shape
    region = np.zeros((ny, nx), bool)
    res = tile.resolution
    for x, y, d in zip(craters.x, craters.y, craters.diameter, strict=True):
        r, c = tile.rowcol(x, y)
        rad = 0.5 * d / res
        r0, r1 = max(0, int(math.floor(r - rad))), min(ny - 1, int(math.ceil(r + rad)))
        c0, c1 = max(0, int(math.floor(c - rad))), min(nx - 1, int(math.ceil(c + rad)))
        if r0 > r1 or c0 > c1:
            continue
        rr, cc = np.mgrid[r0:r1 + 1, c0:c1 + 1]
        region[r0:r1 + 1, c0:c1 + 1] |= (rr - r) ** 2 + (cc - c) ** 2 <= rad**2
    return region


def fill_crater_gaps(tile: DEMTile, craters, *, seed: int = 0, roughness: float | None = None,
                     model=None) -> FillResult:
    """Fill gaps that are crater interiors with craters, then every other gap with terrain.

    Martin et al. (2014, IV.C): the unknown pixels inside the given craters' rims are filled
    in a copy with fractal terrain, the craters are added to the copy, and each of those
    pixels takes the copy's height plus a *warp*, the inverse-distance average (nearest known
    pixel in each of eight directions, weights 1/distance) of (original - copy) over the known
    pixels, so the synthetic crater meets the real terrain without a step. The differences are
    smoothed first (:data:`WARP_SMOOTHING` pixels, over known pixels only), which keeps pixel
    noise at the ray ends from streaking the crater along the eight directions. The remaining gaps
    are then filled with :func:`fill_gaps`. Known heights are never changed.

    Parameters
    ----------
    tile : DEMTile
    craters : CraterTable
        Circles (map coordinates, diameter in metres, age in Gyr) known to be crater gaps.
    seed : int
    roughness : float, optional
        As :func:`fill_gaps`.
    model : CraterModel, optional
        How the craters look (default: the standard model).
    """
    from terrain.craters.cratering import add_craters

    seed = check_seed(seed)
    inside = crater_region(tile, craters) & ~tile.valid
    if not inside.any():
        return fill_gaps(tile, seed=seed, roughness=roughness)
    copy = fill_gaps(tile, seed=seed, roughness=roughness, gaps=inside).tile
    with_craters = add_craters(copy, craters, seed=seed, model=model).tile
    diff = np.where(tile.valid, tile.heights.astype(np.float64)
                    - with_craters.heights.astype(np.float64), 0.0)
    # Smooth the differences over the known pixels first (normalised convolution), so that
    # pixel noise at the ray ends does not streak the warp along the eight directions.
    weight = ndimage.gaussian_filter(tile.valid.astype(np.float64), WARP_SMOOTHING)
    with np.errstate(invalid="ignore", divide="ignore"):
        diff = np.where(tile.valid, ndimage.gaussian_filter(diff, WARP_SMOOTHING) / weight,
                        np.nan)
    ti, tj = np.nonzero(inside & with_craters.valid)
    warp = np.empty(ti.size)
    _warp(diff, tile.valid.copy(), ti.astype(np.int64), tj.astype(np.int64),
          max(tile.shape), warp)
    heights = tile.heights.copy()
    valid = tile.valid.copy()
    values = with_craters.heights[ti, tj].astype(np.float64) + np.nan_to_num(warp)
    heights[ti, tj] = values.astype(np.float32)
    valid[ti, tj] = True
    stage = tile.replace(heights=heights, valid=valid)
    rest = fill_gaps(stage, seed=seed, roughness=roughness)
    filled = rest.tile.valid & ~tile.valid
    meta = dict(rest.tile.metadata)
    meta[mk.CRATER_GAPS] = json.dumps(
        {"craters": len(craters), "pixels": int(ti.size)}, sort_keys=True)
    return FillResult(rest.tile.replace(metadata=meta), filled,
                      dict(rest.roughness, crater_pixels=int(ti.size)))


def despike(tile: DEMTile, threshold: float = 5.0, size: int = 5) -> tuple[DEMTile, np.ndarray]:
    """Turn pixels far from their local median into gaps.

    A pixel is a spike (or dip) where ``|z - median_{size x size}(z)|`` exceeds ``threshold``
    robust standard deviations (1.4826 x the median absolute residual over the DEM). Unknown
    pixels take their nearest known neighbour's height for the median only.

    Returns
    -------
    tile : DEMTile
        The tile with spikes made unknown.
    removed : (ny, nx) bool
    """
    if not (threshold > 0 and math.isfinite(threshold)):
        raise InvalidParameterError(f"despike threshold must be positive; got {threshold}")
    if size < 3 or size % 2 == 0:
        raise InvalidParameterError(f"despike window must be odd and >= 3; got {size}")
    z = tile.heights.astype(np.float64)
    if not tile.valid.all():
        idx = ndimage.distance_transform_edt(~tile.valid, return_distances=False,
                                             return_indices=True)
        z = z[tuple(idx)]
    resid = z - ndimage.median_filter(z, size=size, mode="nearest")
    known = resid[tile.valid]
    scale = 1.4826 * float(np.median(np.abs(known))) if known.size else 0.0
    if scale == 0.0:
        return tile, np.zeros(tile.shape, bool)
    removed = tile.valid & (np.abs(resid) > threshold * scale)
    log.info("despike: %d pixels removed", int(removed.sum()))
    meta = dict(tile.metadata)
    meta[mk.DESPIKE] = json.dumps(
        {"threshold": threshold, "size": size, "removed": int(removed.sum())})
    return tile.replace(valid=tile.valid & ~removed, metadata=meta), removed


def denoise(tile: DEMTile, sigma: float) -> DEMTile:
    """Gaussian smoothing (sigma in pixels) of the known pixels, ignoring gaps.

    Normalised convolution: ``G*(z m) / G*m`` with the valid mask m, so gaps neither leak
    into nor get created by the smoothing. This changes known heights, on purpose.
    """
    if not (sigma > 0 and math.isfinite(sigma)):
        raise InvalidParameterError(f"denoise sigma must be positive; got {sigma}")
    if sigma > max(tile.shape):
        raise InvalidParameterError(
            f"denoise sigma {sigma:g} px is wider than the {tile.shape[1]}x{tile.shape[0]} DEM; "
            "give at most its larger side")
    memory.require(tile.heights.size * 8 * 5 + (8 * sigma + 2) * 8,
                   f"denoising a {tile.shape[1]}x{tile.shape[0]} DEM")
    m = tile.valid.astype(np.float64)
    z = np.where(tile.valid, tile.heights.astype(np.float64), 0.0)
    num = ndimage.gaussian_filter(z, sigma, mode="nearest")
    den = ndimage.gaussian_filter(m, sigma, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = np.where(tile.valid & (den > 0), num / den, np.nan)
    meta = dict(tile.metadata)
    meta[mk.DENOISE] = json.dumps({"sigma_px": sigma})
    return tile.replace(heights=smooth.astype(np.float32), metadata=meta)
