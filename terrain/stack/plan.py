"""Planning a layer stack: each layer's window, extent and craters (Martin et al. 2014, IV.A).

Craters: "a list of crater definitions for the entire area [is] sorted into separate lists
for each DEM layer where craters are included in the highest resolution DEM layer that can
include the complete crater and craters smaller than the DEM pixel resolution are rejected.
Craters are added to each DEM layer before the expansion of the next highest resolution
layer." The population is one seamless, position-keyed list (:mod:`terrain.craters.population`);
each layer enumerates the part of it that belongs to it (:func:`layer_craters`): footprint
inside the layer, diameter at least :data:`MIN_CRATER_PIXELS` of its pixels, and not
belonging to a finer layer.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from affine import Affine

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterTable
from terrain.fractal.expand import expanded_transform

__all__ = ["MAX_LEVELS", "MIN_CRATER_PIXELS", "GridShape", "layer_bounds", "layer_craters",
           "layer_plan", "levels_for_resolution", "site_in_bounds"]

log = logging.getLogger(__name__)

#: Smallest crater a layer takes, in its pixels ("craters smaller than a few pixels ... are
#: rejected").
MIN_CRATER_PIXELS = 4.0
#: Most 2x expansions of a layer stack (1 km to below a millimetre).
MAX_LEVELS = 30


def _site_window(tile: DEMTile | GridShape, x: float, y: float,
                 width: int) -> tuple[int, int, int]:
    """Window (col, row, size) of ``width`` pixels in ``tile`` centred on (x, y), clamped."""
    ny, nx = tile.shape
    size = min(width, ny, nx)
    r, c = tile.rowcol(x, y)
    row = int(round(float(r))) - size // 2
    col = int(round(float(c))) - size // 2
    row = min(max(row, 0), ny - size)
    col = min(max(col, 0), nx - size)
    return col, row, size


def layer_bounds(shape: tuple[int, ...], transform: Affine) -> tuple[float, float, float, float]:
    """Return the map extent of a grid.

    Parameters
    ----------
    shape : (rows, cols)
    transform : affine.Affine
        North-up pixel-to-map transform (metres).

    Returns
    -------
    (left, bottom, right, top) : float, map metres
        The outer edges of the grid's corner pixels.
    """
    ny, nx = shape
    left, top = transform @ (0, 0)
    right, bottom = transform @ (nx, ny)
    return left, bottom, right, top


def site_in_bounds(site: tuple[float, float],
                   bounds: tuple[float, float, float, float]) -> tuple[float, float]:
    """Return the landing site as floats, refusing one outside the base DEM's extent.

    Parameters
    ----------
    site : (x, y), map metres
        The landing site.
    bounds : (left, bottom, right, top), map metres
        The base's extent (:func:`layer_bounds`).

    Returns
    -------
    (x, y) : float, map metres

    Raises
    ------
    InvalidParameterError
        The site lies outside ``bounds``.
    """
    x, y = (float(v) for v in site)
    left, bottom, right, top = bounds
    if not (left <= x <= right and bottom <= y <= top):
        raise InvalidParameterError(
            f"site {x:.6g},{y:.6g} lies outside the DEM (x {left:.6g}..{right:.6g}, "
            f"y {bottom:.6g}..{top:.6g})")
    return x, y


def layer_craters(population, seed, plan, k, factor, min_pixels):
    """Craters of the population that belong to layer k (see the module docstring).

    ``plan`` lists (bounds, resolution) of every layer, built or not.
    """
    (left, bottom, right, top), res = plan[k]
    dmin = min_pixels * res
    if population.dmax <= dmin:
        return CraterTable.empty()
    table = population.generate(seed, (left, bottom, right, top), min_diameter=dmin)
    if not len(table):
        return table
    reach = table.diameter * factor
    keep = ((table.x - reach >= left) & (table.x + reach <= right)
            & (table.y - reach >= bottom) & (table.y + reach <= top))
    if k + 1 < len(plan):
        (fl, fb, fr, ft), fres = plan[k + 1]
        in_fine = ((table.x - reach >= fl) & (table.x + reach <= fr)
                   & (table.y - reach >= fb) & (table.y + reach <= ft))
        keep &= ~(in_fine & (table.diameter >= min_pixels * fres))
    return table.take(np.flatnonzero(keep))


def layer_plan(base: DEMTile | GridShape, site: tuple[float, float], levels: int,
               layer_size: int) -> tuple[list[tuple[int, int, int, int] | None],
                                         list[tuple[int, int]], list[tuple[int, ...]],
                                         list[Affine]]:
    """Return the geometry of every layer, before any work.

    Parameters
    ----------
    base : DEMTile or GridShape
        The base layer (its shape and transform).
    site : (x, y), map metres
        Centre of the layers.
    levels : int
        Layers above the base.
    layer_size : int, pixels
        Side of the window of each layer that the next expands (odd, >= 3).

    Returns
    -------
    windows : list of (col, row, size, size) or None
        Each layer's window in the layer above (None for the base).
    origins : list of (row, col)
        Each layer's global pixel origin at its level.
    shapes : list of (rows, cols)
    transforms : list of affine.Affine
    """
    if layer_size < 3 or layer_size % 2 == 0:
        raise InvalidParameterError(
            f"layer size must be odd and >= 3 (a window of n pixels expands to 2n - 1); "
            f"got {layer_size}")
    shapes: list[tuple[int, ...]] = [tuple(base.shape)]
    transforms: list[Affine] = [base.transform]
    windows: list[tuple[int, int, int, int] | None] = [None]
    origins: list[tuple[int, int]] = [(0, 0)]
    half = (layer_size + 1) // 2
    proxy = base
    for _ in range(levels):
        col, row, size = _site_window(proxy, *site, half)
        if size < 2:
            raise InvalidParameterError("the base DEM is too small to expand around the site")
        windows.append((col, row, size, size))
        pr, pc = origins[-1]
        origins.append((2 * (pr + row), 2 * (pc + col)))
        transform = expanded_transform(transforms[-1], 1, row, col)
        transforms.append(transform)
        shapes.append((2 * size - 1, 2 * size - 1))
        proxy = GridShape(shapes[-1], transform)
    return windows, origins, shapes, transforms


class GridShape:
    """Just enough of a tile for :func:`_site_window` (shape and rowcol)."""

    def __init__(self, shape, transform):
        self.shape = shape
        self.transform = transform

    def rowcol(self, x, y):
        """Return the fractional (row, col) of map point (x, y) (pixel centres at .0)."""
        t = self.transform
        return (y - t.f) / t.e - 0.5, (x - t.c) / t.a - 0.5


def levels_for_resolution(base_resolution: float, finest_resolution: float) -> int:
    """Fewest 2x expansions that take a base to a given pixel size or finer.

    Parameters
    ----------
    base_resolution : float
        The base DEM's pixel size, metres.
    finest_resolution : float
        The pixel size wanted of the finest layer, metres (> 0).

    Returns
    -------
    int
        Levels in ``[0, MAX_LEVELS]``: ``base_resolution / 2**levels <= finest_resolution``.

    Raises
    ------
    InvalidParameterError
        If ``finest_resolution`` is not positive or needs more than :data:`MAX_LEVELS`.

    Examples
    --------
    >>> levels_for_resolution(1000.0, 0.5), levels_for_resolution(1.0, 2.0)
    (11, 0)
    """
    if not finest_resolution > 0:
        raise InvalidParameterError(
            f"finest resolution must be positive; got {finest_resolution}")
    levels = max(0, math.ceil(math.log2(base_resolution / finest_resolution) - 1e-9))
    if levels > MAX_LEVELS:
        raise InvalidParameterError(
            f"--finest-resolution {finest_resolution:g} m needs {levels} expansions of the "
            f"{base_resolution:.4g} m base; at most {MAX_LEVELS} are possible")
    return levels
