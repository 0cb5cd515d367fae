"""Nested multi-resolution layers around a landing site (Martin et al. 2014, IV.A, IV.D, V.B).

A *layer stack* turns a coarse base DEM into a model that is sharp where a lander looks: layer
0 is the base (gaps filled with fractal terrain), and every further layer is a window of the
layer above, centred on the site, expanded 2x (:mod:`terrain.fractal.expand`). With 1025 x 1025
layers
a 1 km base reaches about 0.5 m after 11 levels, as the paper's South Pole model did.

Craters: "a list of crater definitions for the entire area [is] sorted into separate lists
for each DEM layer where craters are included in the highest resolution DEM layer that can
include the complete crater and craters smaller than the DEM pixel resolution are rejected.
Craters are added to each DEM layer before the expansion of the next highest resolution
layer." The population is one seamless, position-keyed list (:mod:`terrain.craters.population`);
each
layer enumerates the part of it that belongs to it: footprint inside the layer, diameter at
least :data:`MIN_CRATER_PIXELS` of its pixels, and not belonging to a finer layer.

Agreement between layers: a finer layer's even pixels are copies of the coarser layer's
pixels, and after the stack is built every coarser pixel inside a finer layer is set to its
co-located fine pixel (so craters added to a fine layer appear, sampled, in the coarse ones):
a coarse pixel equals the co-located fine pixel, exactly.

On disk: ``layer_NN.tif`` per layer (float32 GeoTIFF; a layer too large for memory, built
chunk by chunk by :mod:`terrain.stack.chunkedlayers`, is a Zarr DEM ``layer_NN.zarr``),
``manifest.json`` (each layer's file,
level, resolution, extent, transform, parent and window in the parent; the site, seed and
parameters) and ``craters.csv`` (the catalogue with a ``layer`` column).

The manifest is the stack's one commit point: it names every layer file and the catalogue
file, and nothing else in the folder counts.

- A new stack is written with a marker ``.craterscape.incomplete`` first and the manifest
  last; a build that fails removes what it wrote, and a rerun into a folder that a killed
  build left (marker, no manifest) clears it and starts again (:func:`prepare_folder`).
- Edits (:func:`replace_crater`) hold the edit lock ``.craterscape.lock``, write new
  versions of the layers they change and of the catalogue under new names
  (``layer_NN.STAMP.tif``, ``craters.STAMP.csv``), then replace the manifest atomically.
  A crash before that leaves the old stack whole; after it, the new one.
- Readers (:func:`read_stack`) hold a shared lock on ``.craterscape.readers`` while they
  read; an edit deletes the files the old manifest named only once it holds that lock
  exclusively, so a reader never loses a file half way. Files no manifest names (left by a
  killed edit) are swept by the next edit.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import math
import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from affine import Affine

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidDEMError, InvalidParameterError, MissingInputError
from terrain.core.outputs import remove_path
from terrain.core.progress import Progress
from terrain.core.rng import check_seed
from terrain.core.tile import DEMTile
from terrain.craters.catalog import Crater, CraterCatalog, CraterTable, RockCatalog
from terrain.craters.cratering import CraterModel, add_craters
from terrain.craters.population import Population
from terrain.fractal.expand import expand_level, expanded_transform
from terrain.fractal.gapfill import fill_gaps
from terrain.fractal.roughness import ExpansionParameters, RoughnessChoice, local_amplitude

__all__ = ["MANIFEST", "MAX_LEVELS", "MIN_CRATER_PIXELS", "Layer", "LayerStack", "build_stack",
           "levels_for_resolution", "prepare_folder", "read_stack", "replace_crater",
           "stack_lock", "write_stack"]

log = logging.getLogger(__name__)

#: Name of the manifest in a layer-stack folder.
MANIFEST = "manifest.json"
#: Catalogue file in a layer-stack folder.
CATALOG = "craters.csv"
#: Smallest crater a layer takes, in its pixels ("craters smaller than a few pixels ... are
#: rejected").
MIN_CRATER_PIXELS = 4.0
#: Most 2x expansions of a layer stack (1 km to below a millimetre).
MAX_LEVELS = 30
#: Rock catalogue in a layer-stack folder (when the stack has rocks).
ROCK_CATALOG = "rocks.csv"
#: Lock file guarding edits of a layer-stack folder.
LOCK = ".craterscape.lock"
#: Lock file readers hold shared while they read; edits hold it exclusively to delete.
READERS_LOCK = ".craterscape.readers"
#: Marker of a stack being built (removed when its manifest is in place).
INCOMPLETE = ".craterscape.incomplete"
#: Seconds an edit waits for readers before leaving old files to the next edit's sweep.
READERS_TIMEOUT = 30.0
#: Names of files a stack's writers create (swept when no manifest names them).
_STACK_FILE_PATTERNS = ("layer_*.tif", "layer_*.zarr", "craters*.csv", "rocks*.csv")
#: Work folder of a chunked build (:mod:`terrain.stack.chunkedlayers`), kept for its resumption.
WORK = ".craterscape.work"
_LOCKS = (LOCK, READERS_LOCK, INCOMPLETE)
#: Seconds an edit waits for another edit of the same stack before giving up.
LOCK_TIMEOUT = 600.0
FORMAT = "craterscape-layer-stack"


def _int_tuple(value, n: int, what: str) -> tuple[int, ...]:
    """``value`` as a tuple of ``n`` ints, or an error naming the field."""
    try:
        items = tuple(value)
        if len(items) != n or not all(float(v) == int(v) for v in items):
            raise ValueError
        return tuple(int(v) for v in items)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"layer {what} must be {n} integers; got {value!r}") from None


@dataclass(frozen=True, eq=False)
class Layer:
    """One layer of a stack: its heights and where it lies in the layer above.

    Parameters
    ----------
    tile : DEMTile
        The layer's heights, ``(ny, nx) float32, metres`` (a stack built chunk by chunk
        writes its manifest from stand-ins with the tile's shape, transform and CRS).
    window : (col, row, width, height) of int, or None
        The window of the layer above (pixels) this layer expands; None for the base.
    origin : (row, col) of int
        Global index of this layer's pixel (0, 0) at its level (the expansion's key).
    file : str, optional
        Name of the layer's file in its stack folder, once written or read.
    """

    tile: DEMTile
    window: tuple[int, int, int, int] | None
    origin: tuple[int, int]
    file: str | None = None

    def __post_init__(self):
        if self.window is not None:
            object.__setattr__(self, "window", _int_tuple(self.window, 4, "window"))
        object.__setattr__(self, "origin", _int_tuple(self.origin, 2, "origin"))


@dataclass(frozen=True, eq=False)
class LayerStack:
    """Layers (coarse to fine), the crater catalogue and provenance, as one frozen record.

    Parameters
    ----------
    layers : sequence of Layer
        Layer 0 (the base, no window) first, each further layer a 2x expansion of a window
        of the one before.
    catalog : CraterCatalog
        The crater catalogue (each crater once, with the ``layer`` it was added to).
    info : mapping
        Provenance recorded in the manifest (seed, site, parameters, edits).
    rocks : dict of column arrays, optional
        The rock catalogue, when rocks were added.
    catalog_file : str
        Name of the catalogue file in the stack folder.
    """

    layers: tuple[Layer, ...]
    catalog: CraterCatalog
    info: dict = field(default_factory=dict)
    rocks: RockCatalog | None = None
    catalog_file: str = CATALOG

    def __post_init__(self):
        layers = tuple(self.layers)
        if not layers or not all(isinstance(layer, Layer) for layer in layers):
            raise InvalidParameterError("a layer stack needs one or more Layer records")
        if layers[0].window is not None:
            raise InvalidParameterError("the base layer (0) has no window in a parent")
        for k, layer in enumerate(layers[1:], 1):
            if layer.window is None:
                raise InvalidParameterError(f"layer {k} needs its window in layer {k - 1}")
        object.__setattr__(self, "layers", layers)
        if not isinstance(self.catalog, CraterCatalog) or self.catalog.layer is None:
            raise InvalidParameterError(
                "a layer stack's catalog must be a CraterCatalog with a layer column; got "
                f"{type(self.catalog).__name__}")
        object.__setattr__(self, "info", dict(self.info))

    @property
    def tiles(self) -> tuple[DEMTile, ...]:
        """Every layer's tile, coarse to fine."""
        return tuple(layer.tile for layer in self.layers)

    @property
    def windows(self) -> tuple[tuple[int, int, int, int] | None, ...]:
        """Every layer's window in the layer above; None for the base."""
        return tuple(layer.window for layer in self.layers)

    @property
    def origins(self) -> tuple[tuple[int, int], ...]:
        """Every layer's global (row, col) origin at its level."""
        return tuple(layer.origin for layer in self.layers)

    @property
    def levels(self) -> int:
        """Number of 2x expansions (layers less one)."""
        return len(self.layers) - 1

    def with_info(self, **items) -> LayerStack:
        """Return a copy with ``items`` added to the provenance.

        Parameters
        ----------
        **items
            JSON-able values recorded in the manifest.

        Returns
        -------
        LayerStack
        """
        return replace(self, info={**self.info, **items})

    def layer_of(self, x: float, y: float, reach: float) -> int:
        """Finest layer whose extent holds a disc of radius ``reach`` m at (x, y), or -1.

        Parameters
        ----------
        x, y : float
            Centre, map coordinates (m).
        reach : float
            Radius (m).

        Returns
        -------
        int
        """
        for k in range(len(self.layers) - 1, -1, -1):
            left, bottom, right, top = self.layers[k].tile.bounds
            if (x - reach >= left and x + reach <= right and y - reach >= bottom
                    and y + reach <= top):
                return k
        return -1


def _layers(tiles, windows, origins, files=None) -> tuple[Layer, ...]:
    """Layer records of parallel lists (as the builders and editors keep them)."""
    files = files or [None] * len(tiles)
    return tuple(Layer(t, w, o, f) for t, w, o, f in zip(tiles, windows, origins, files,
                                                          strict=True))


# ---------------------------------------------------------------------------- building


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


def _layer_craters(population, seed, plan, k, factor, min_pixels):
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


def build_stack(base: DEMTile, site: tuple[float, float], *, levels: int, layer_size: int = 1025,
                seed: int = 0, population: Population | None = None,
                model: CraterModel | None = None,
                params: ExpansionParameters | RoughnessChoice | None = None,
                min_crater_pixels: float = MIN_CRATER_PIXELS,
                progress: Progress | None = None,
                rocks=None) -> LayerStack:
    """Build a nested layer stack around ``site`` (map coordinates of ``base``).

    Parameters
    ----------
    base : DEMTile
        Level 0. Gaps are filled with fractal terrain first (known heights unchanged).
    site : (x, y)
        The landing site, in the base's map coordinates; it must lie inside the base.
    levels : int
        Number of 2x expansions (layers = levels + 1).
    layer_size : int
        Pixels per side of every expanded layer (odd; a window of (n + 1) / 2 pixels of the
        layer above is expanded to n).
    seed : int
    population : Population, optional
        Craters for the whole area, sorted into the layers.
    model : CraterModel, optional
    params : ExpansionParameters or RoughnessChoice, optional
        Expansion roughness, given; or measured from the (filled) base under the user's
        choices (a :class:`~terrain.fractal.roughness.RoughnessChoice`); measured by default.
    min_crater_pixels : float
        Smallest crater a layer takes, in its pixels.
    progress : callable, optional
        ``progress(step, total, label)`` (:class:`terrain.core.progress.Progress`).
    rocks : terrain.surface.rocks.RockModel, optional
        Rocks on every layer that resolves them (:func:`_add_layer_rocks`).

    Returns
    -------
    LayerStack
    """
    seed = check_seed(seed)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise InvalidParameterError(f"levels must be a non-negative integer; got {levels!r}")
    if levels > MAX_LEVELS:
        raise InvalidParameterError(f"levels must be at most {MAX_LEVELS}; got {levels}")
    if not min_crater_pixels > 0:
        raise InvalidParameterError(
            f"min crater pixels must be positive; got {min_crater_pixels}")
    model = model or CraterModel()
    x, y = site_in_bounds(site, base.bounds)
    windows, origins, shapes, transforms = layer_plan(base, (x, y), levels, layer_size)
    plan = [(layer_bounds(sh, tr), tr.a) for sh, tr in zip(shapes, transforms, strict=True)]
    pixels = sum(h * w for h, w in shapes)
    memory.require(pixels * (4 + 1) * 2 + base.heights.size * 8 * 3,
                   f"a {levels}-level stack of {layer_size}x{layer_size} layers")
    total = 2 * levels + 2
    step = 0

    def tick(label):
        nonlocal step
        step += 1
        if progress is not None:
            progress(step, total, label)

    info: dict[str, Any] = {"base_filled_pixels": 0}
    if not base.valid.all():
        filled = fill_gaps(base, seed=seed)
        info["base_filled_pixels"] = int(filled.filled.sum())
        info["base_fill_roughness"] = filled.roughness
        base = filled.tile
    tick("fill")
    if not isinstance(params, ExpansionParameters):
        params = (params or RoughnessChoice()).for_tile(base)
    amp = (local_amplitude(base.heights, params.base_sigma, params.local_box)
           if params.uses_local_map else None)

    tiles = [base]
    catalogs = []
    factor = model.footprint_factor
    for k in range(levels + 1):
        if k > 0:
            window = windows[k]
            assert window is not None  # every layer above the base has one
            col, row, size, _ = window
            parent = tiles[k - 1]
            pr, pc = origins[k - 1]
            r0, c0 = origins[k]
            heights = expand_level(parent.heights, (pr, pc), (r0, r0 + 2 * size - 2),
                                   (c0, c0 + 2 * size - 2), level=k,
                                   sigmas=params.sigmas(k), weights=params.weights(k),
                                   taps=params.taps(), seed=seed, amplitude=amp,
                                   amplitude_origin=(0, 0), amplitude_level=0)
            heights.flags.writeable = False
            tiles.append(DEMTile(heights, np.isfinite(heights),
                                 expanded_transform(parent.transform, 1, row, col), base.crs,
                                 base.nodata))
            tick(f"expand {k}")
        if population is not None:
            # The next layer's extent is known from the plan, so craters can be sorted now.
            table = _layer_craters(population, seed, plan, k, factor, min_crater_pixels)
            if len(table):
                result = add_craters(tiles[k], table, seed=seed, model=model)
                tiles[k] = result.tile
                catalogs.append(result.catalog.with_layer(k))
            log.info("layer %d: %d craters", k, len(table))
        tick(f"craters {k}")

    rock_catalog = None
    if rocks is not None:
        rock_catalog = _add_layer_rocks(tiles, rocks, seed, population)
        info.update(rocks=rocks.as_dict(), rock_catalog=ROCK_CATALOG,
                    rock_counts=np.bincount(rock_catalog.layer,
                                            minlength=len(tiles)).tolist())

    # Coarse pixels inside a finer layer take the co-located fine pixel, finest first.
    for k in range(levels, 0, -1):
        window = windows[k]
        assert window is not None  # every layer above the base has one
        col, row, size, _ = window
        coarse = tiles[k - 1].heights.copy()
        coarse[row:row + size, col:col + size] = tiles[k].heights[::2, ::2]
        tiles[k - 1] = tiles[k - 1].replace(heights=coarse, valid=np.isfinite(coarse))

    catalog = merge_catalogs(catalogs)
    info.update(seed=seed, site=[x, y], levels=levels, layer_size=layer_size,
                expansion=params.as_dict(), min_crater_pixels=min_crater_pixels,
                population=population.as_dict() if population else None,
                crater_model=model.as_dict())
    return LayerStack(_layers(tiles, windows, origins), catalog, info, rock_catalog)


def _add_layer_rocks(tiles: list, rocks, seed: int, population) -> RockCatalog:
    """Stand the rocks each layer resolves on it (``tiles`` is changed in place).

    Every layer gets the rocks of at least :data:`terrain.surface.rocks.MIN_ROCK_PIXELS` of its
    pixels touching it, drawn on its own rock-free terrain after all expansions (so no rock
    is smeared into a finer layer by the expansion); the agreement step that follows copies
    each finer layer's pixels into the coarser ones. Crater-raised densities use the stack's
    crater population (fresh craters near the rock layers, keyed like the craters).
    Returns the catalogue: one row per rock, ``layer`` the coarsest layer that holds its
    centre and resolves it, ``z_base_m`` from the finest such layer.
    """
    from terrain.surface.rocks import MIN_ROCK_PIXELS, RockTable, rock_catalog, rock_heights

    levels, craters = _rock_levels(tiles, rocks, seed, population)
    rows: dict = {}
    for k in levels:
        tile = tiles[k]
        table = rocks.generate(seed, tile.bounds, min_diameter=MIN_ROCK_PIXELS * tile.resolution,
                               craters=craters)
        heights, z0, drawn = rock_heights(tile, table)
        tiles[k] = tile.replace(heights=heights, valid=tile.valid)
        left, bottom, right, top = tile.bounds
        inside = drawn & (table.x >= left) & (table.x <= right) & (table.y >= bottom) \
            & (table.y <= top)
        for i in np.flatnonzero(inside):
            uid = int(table.uid[i])
            first = rows[uid][2] if uid in rows else k
            rows[uid] = (table.rows[i], z0[i], first)
        log.info("layer %d: %d rocks", k, int(inside.sum()))
    if not rows:
        return rock_catalog(RockTable(np.empty((0, 15)), np.empty(0)), np.empty(0),
                            np.empty(0, np.int64))
    uids = sorted(rows)
    table = RockTable(np.array([rows[u][0] for u in uids]), np.array(uids, dtype=np.uint64))
    z0 = np.array([rows[int(u)][1] for u in table.uid])
    first = np.array([rows[int(u)][2] for u in table.uid], dtype=np.int64)
    return rock_catalog(table, z0, first)


def _rock_levels(tiles: list, rocks, seed: int, population) -> tuple[list[int], Any]:
    """Return the layers that hold rocks and the craters that raise their density."""
    from terrain.surface.rocks import MIN_ROCK_PIXELS

    levels = [k for k, t in enumerate(tiles) if MIN_ROCK_PIXELS * t.resolution < rocks.dmax]
    craters = None
    if levels and rocks.craters and population is not None:
        dmin = max(5.0 * rocks.regolith_m, population.dmin)
        if dmin < population.dmax:
            craters = population.generate(seed, tiles[levels[0]].bounds,
                                          margin=lambda d: rocks.reach * d / 2,
                                          min_diameter=dmin)
    return levels, craters


def merge_catalogs(catalogs: Iterable[CraterCatalog]) -> CraterCatalog:
    """Return a stack's crater catalogue from the per-layer ones, in composition order.

    Parameters
    ----------
    catalogs : iterable of CraterCatalog
        The layers' catalogues, each with its ``layer`` column, coarse to fine.

    Returns
    -------
    CraterCatalog
        Their rows in order (with a ``layer`` column even when there are none).
    """
    return CraterCatalog.concatenate(catalogs, optional=("layer",))


# ---------------------------------------------------------------------------- files


def _manifest(stack: LayerStack, files: list[str]) -> dict:
    layers = []
    for k, tile in enumerate(stack.tiles):
        window = stack.windows[k]
        layers.append(dict(
            level=k, file=files[k], resolution=tile.resolution, width=tile.shape[1],
            height=tile.shape[0], bounds=list(tile.bounds), transform=list(tile.transform)[:6],
            parent=None if k == 0 else k - 1,
            window_in_parent=None if window is None else list(window),
            origin=list(stack.origins[k])))
    layer = stack.catalog.layer
    counts = np.bincount(layer, minlength=len(stack.tiles)).tolist() \
        if layer is not None and len(layer) else [0] * len(stack.tiles)
    return dict(format=FORMAT, version=1, crs=stack.tiles[0].crs, layers=layers,
                catalog=CATALOG, crater_counts=counts, **stack.info)


def prepare_folder(outdir, *, inputs=(), keep=()) -> Path:
    """Check that ``outdir`` can take a new stack, before any work.

    A missing or empty folder is fine; so is a folder a killed build left (its
    ``.craterscape.incomplete`` marker and no manifest), whose files are removed here,
    except those named in ``keep`` (a chunked build keeps its work folder to resume it).
    Anything else is refused.

    Parameters
    ----------
    outdir : path
        The stack's folder.
    inputs : iterable of path
        The build's inputs: the folder may neither be one nor hold one.
    keep : iterable of str
        Names in a killed build's folder to leave in place.

    Returns
    -------
    Path
        ``outdir``.

    Raises
    ------
    InvalidParameterError, OutputPathError
        The folder holds anything else, is an input or holds one.
    """
    from terrain.core.outputs import check_output_folder

    outdir = Path(outdir)
    for item in inputs:
        if item is not None and Path(item).resolve().is_relative_to(outdir.resolve()):
            raise InvalidParameterError(
                f"output folder '{outdir}' contains the input '{item}'; choose another folder")
    check_output_folder(outdir, inputs)
    if not outdir.exists():
        return outdir
    names = {p.name for p in outdir.iterdir()}
    if INCOMPLETE in names and MANIFEST not in names:
        ours = _stack_files(outdir)
        if WORK in names and WORK not in keep:
            ours.append(outdir / WORK)
        strangers = names - {p.name for p in ours} - set(_LOCKS) - set(keep)
        strangers = {n for n in strangers if not n.endswith(".partial")}
        if strangers:
            raise InvalidParameterError(
                f"output folder '{outdir}' holds an interrupted stack build and other files "
                f"({sorted(strangers)[0]}, ...); give a new folder")
        log.warning("removing the interrupted stack build in %s", outdir)
        for p in ours:
            remove_path(p)
        from terrain.core.outputs import sweep_partials

        sweep_partials(outdir)
        names = {p.name for p in outdir.iterdir()}
    if names - set(_LOCKS) - set(keep):
        raise InvalidParameterError(
            f"output folder '{outdir}' is not empty; give a new folder (layer stacks are "
            "edited with replace-crater, never overwritten)")
    return outdir


def _stack_files(outdir: Path) -> list[Path]:
    return sorted({p for pattern in _STACK_FILE_PATTERNS for p in outdir.glob(pattern)})


def write_stack(stack: LayerStack, outdir, *, inputs=()) -> Path:
    """Write a new layer stack into ``outdir`` (created; see :func:`prepare_folder`).

    The manifest is written last; if writing fails (full disk, interrupt) the files already
    written are removed again, and a killed build is cleared by the next one.

    Parameters
    ----------
    stack : LayerStack
    outdir : path
        A missing, empty or killed build's folder.
    inputs : iterable of path
        Files the stack was made from (never written over, never inside ``outdir``).

    Returns
    -------
    Path
        ``outdir``: ``manifest.json``, ``layer_NN.tif`` and ``craters.csv`` (and
        ``rocks.csv`` with rocks).
    """
    outdir = prepare_folder(outdir, inputs=inputs)
    if outdir.exists() and not outdir.is_dir():
        raise InvalidParameterError(f"output '{outdir}' exists and is not a folder")
    created = not outdir.exists()
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        from terrain.core.outputs import cannot_write

        raise cannot_write(outdir, exc) from exc
    ok = False
    try:
        with stack_lock(outdir):
            from terrain.core.outputs import atomic_path

            if (outdir / MANIFEST).exists():  # another build finished here meanwhile
                ok = True  # it is that build's stack: leave it alone
                raise InvalidParameterError(
                    f"output folder '{outdir}' received a stack from another command "
                    "meanwhile; give a new folder")
            with atomic_path(outdir / INCOMPLETE) as tmp:
                tmp.write_text("a craterscape layer stack is being written here\n",
                               encoding="utf-8")
            (outdir / READERS_LOCK).touch()  # so that readers never create a file here
            files = [f"layer_{k:02d}.tif" for k in range(len(stack.tiles))]
            _write_files(stack, outdir, files)
            (outdir / INCOMPLETE).unlink()
        ok = True
    finally:
        if not ok:
            for p in [*_stack_files(outdir), outdir / INCOMPLETE, outdir / MANIFEST,
                      outdir / LOCK, outdir / READERS_LOCK]:
                with contextlib.suppress(OSError):
                    p.unlink()
            if created:
                with contextlib.suppress(OSError):
                    outdir.rmdir()
    return outdir


def _write_files(stack: LayerStack, outdir: Path, files: list[str], only=None,
                 catalog: str = CATALOG, rocks: bool = False) -> None:
    """Write the layers (``only`` some), the catalogues, then the manifest: the commit point.

    An edit (``only``) writes the rock catalogue when ``rocks`` (under the manifest's name).
    """
    from terrain.io import atomic_path, write_dem

    for k, tile in enumerate(stack.tiles):
        if only is not None and k not in only:
            continue
        meta = dict(tile.metadata)
        meta[mk.LAYER] = str(k)
        write_dem(tile.replace(metadata=meta), outdir / files[k])
    with atomic_path(outdir / catalog) as tmp:
        stack.catalog.to_csv(tmp)
    if stack.rocks is not None and (only is None or rocks):
        with atomic_path(outdir / stack.info.get("rock_catalog", ROCK_CATALOG)) as tmp:
            stack.rocks.to_csv(tmp)
    manifest = _manifest(stack, files)
    manifest["catalog"] = catalog
    with atomic_path(outdir / MANIFEST) as tmp:
        tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True), encoding="utf-8")


@contextlib.contextmanager
def stack_lock(outdir, timeout: float = LOCK_TIMEOUT):
    """Hold the exclusive edit lock of a layer-stack folder.

    Parameters
    ----------
    outdir : path
        The stack's folder.
    timeout : float, seconds
        How long to wait for another edit to finish.

    Yields
    ------
    None
        While the lock is held.

    Raises
    ------
    InvalidParameterError
        Another edit held the lock for ``timeout`` seconds.
    """
    path = Path(outdir) / LOCK
    fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise InvalidParameterError(
                        f"layer stack '{outdir}' is being edited by another command; try again "
                        "when it has finished") from None
                time.sleep(0.1)
        yield
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


@contextlib.contextmanager
def _readers_lock(outdir: Path, *, exclusive: bool = False, timeout: float = READERS_TIMEOUT):
    """Shared (readers) or exclusive (an edit deleting old files) lock; yields whether held.

    The folder itself is a turnstile: a reader passes it (a brief exclusive ``flock`` on the
    folder) before taking its shared lock, and an edit holds it while it waits for the
    readers already inside, so a stream of readers cannot starve an edit. A stack in a
    folder nobody may write (a read-only copy) cannot be edited either, so readers there go
    without the lock.
    """
    path = outdir / READERS_LOCK
    try:
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
    except OSError:
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            yield False
            return
    try:
        gate = os.open(outdir, os.O_RDONLY)
    except OSError:
        gate = None
    try:
        held = False
        if gate is not None:
            fcntl.flock(gate, fcntl.LOCK_EX)
        try:
            if exclusive:
                deadline = time.monotonic() + timeout
                while True:
                    try:
                        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        held = True
                        break
                    except BlockingIOError:
                        if time.monotonic() > deadline:
                            break
                        time.sleep(0.005)
            else:
                fcntl.flock(fd, fcntl.LOCK_SH)
                held = True
        finally:
            if gate is not None and not exclusive:
                fcntl.flock(gate, fcntl.LOCK_UN)
        yield held
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
        if gate is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(gate, fcntl.LOCK_UN)
            os.close(gate)


def read_stack(outdir) -> LayerStack:
    """Read a layer stack written by :func:`write_stack`: the files its manifest names.

    Holds the readers' lock while reading, so an edit running at the same time never
    deletes a file this read still needs (see the module docstring).

    Parameters
    ----------
    outdir : path
        The stack's folder.

    Returns
    -------
    LayerStack
        Its layers (each with its file name), crater catalogue, provenance and rocks.

    Raises
    ------
    InvalidDEMError
        The folder has no stack, its manifest is corrupt or names files outside the folder,
        or a layer's size disagrees with the manifest.
    """
    outdir = Path(outdir)
    if not (outdir / MANIFEST).exists():
        if (outdir / INCOMPLETE).exists():
            raise InvalidDEMError(f"'{outdir}' holds an interrupted stack build (no "
                                  f"{MANIFEST}); build it again into the same folder")
        raise MissingInputError(f"'{outdir}' is not a layer stack: {MANIFEST} is missing")
    with _readers_lock(outdir):
        return _read_stack(outdir)


def _read_stack(outdir: Path) -> LayerStack:
    from terrain.io import read_dem

    mpath = outdir / MANIFEST
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
        if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
            raise ValueError("not a craterscape layer stack")
        layers = manifest["layers"]
        files = [entry["file"] for entry in layers]
        windows = [None if e["window_in_parent"] is None else tuple(e["window_in_parent"])
                   for e in layers]
        origins = [tuple(e["origin"]) for e in layers]
    except (ValueError, KeyError, TypeError, AttributeError, UnicodeDecodeError) as exc:
        raise InvalidDEMError(f"manifest '{mpath}' is corrupt: {exc}") from None
    tiles = []
    for k, name in enumerate(files):
        if Path(name).name != name:
            raise InvalidDEMError(f"manifest '{mpath}' names a file outside the stack: {name}")
        tile = read_dem(outdir / name)
        expected = layers[k]
        if tile.shape != (expected["height"], expected["width"]):
            raise InvalidDEMError(
                f"layer file '{name}' is {tile.shape[1]}x{tile.shape[0]}; the manifest says "
                f"{expected['width']}x{expected['height']}")
        tiles.append(tile)
    cat_name = manifest.get("catalog", CATALOG)
    if not isinstance(cat_name, str) or Path(cat_name).name != cat_name:
        raise InvalidDEMError(f"manifest '{mpath}' names a catalogue outside the stack: "
                              f"{cat_name!r}")
    cat_path = outdir / cat_name
    catalog = CraterCatalog.from_csv(cat_path) if cat_path.exists() else merge_catalogs([])
    info = {k: v for k, v in manifest.items()
            if k not in ("layers", "format", "version", "crs", "catalog", "crater_counts")}
    rock_name = info.get("rock_catalog", ROCK_CATALOG)
    if not isinstance(rock_name, str) or Path(rock_name).name != rock_name:
        raise InvalidDEMError(f"manifest '{mpath}' names a rock catalogue outside the stack: "
                              f"{rock_name!r}")
    rock_path = outdir / rock_name
    rocks = (RockCatalog.from_csv(rock_path) if "rock_catalog" in info and rock_path.exists()
             else None)
    return LayerStack(_layers(tiles, windows, origins, files), catalog, info, rocks,
                      catalog_file=cat_name)


# ---------------------------------------------------------------------------- editing


def replace_crater(outdir, x: float, y: float, diameter: float, *, age: float = 0.0,
                   seed: int | None = None, model: CraterModel | None = None) -> dict:
    """Replace a blurred crater in a layer stack by a sharp synthetic one, in place.

    Martin et al. (2014, IV.D): the bowl (r <= D/2) becomes unknown and is filled with
    fractal terrain, the crater is added at the finest layer that holds it completely, and
    the change propagates to every coarser layer (co-located pixels) so the layers match
    exactly. Finer layers that overlap the crater take the change too, interpolated from the
    layer above, with their co-located pixels set exactly. A stack with rocks keeps its rocks
    (the same keyed draw) resting on the new ground, catalogue included (:func:`_reseat_rocks`).

    Parameters
    ----------
    outdir : path
        The stack's folder (edited in place; concurrent edits wait for each other).
    x, y : float, map metres
        Crater centre.
    diameter : float, metres
    age : float, Gyr
    seed : int, optional
        Keys the fill and the crater's roughness (default: the stack's seed).
    model : CraterModel, optional

    Returns
    -------
    dict
        What was done: ``x``, ``y``, ``diameter``, ``age``, ``layer`` (where the crater was
        added), ``seed`` and ``changed_layers``; also recorded in the manifest's ``edits``.

    Raises
    ------
    InvalidParameterError
        The diameter is not positive, the crater fits in no layer, or it is smaller than
        the finest layer that holds it resolves (``min_crater_pixels`` of its pixels, the
        bound of the stack's own craters).
    """
    outdir = Path(outdir)
    if not (diameter > 0 and math.isfinite(diameter)):
        raise InvalidParameterError(f"crater diameter must be positive; got {diameter}")
    model = model or CraterModel()
    with stack_lock(outdir):
        _sweep(outdir)
        stack = read_stack(outdir)
        seed = check_seed(stack.info.get("seed", 0) if seed is None else seed)
        reach = diameter * model.footprint_factor
        k = stack.layer_of(x, y, reach)
        if k < 0:
            raise InvalidParameterError(
                f"a crater of diameter {diameter} m at {x:.6g},{y:.6g} does not fit in any "
                "layer of the stack")
        tile = stack.tiles[k]
        smallest = float(stack.info.get("min_crater_pixels", MIN_CRATER_PIXELS)) \
            * tile.resolution
        if diameter < smallest:  # the bound the stack's own population was drawn with
            raise InvalidParameterError(
                f"a crater of diameter {diameter:.6g} m is below what layer {k} "
                f"({tile.resolution:.6g} m pixels) resolves at {x:.6g},{y:.6g}: give a "
                f"diameter of at least {smallest:.6g} m")
        old = tile.heights.astype(np.float64)
        rows, cols = np.mgrid[0:tile.shape[0], 0:tile.shape[1]]
        px, py = tile.xy(rows, cols)
        bowl = np.hypot(px - x, py - y) <= diameter / 2
        cut = tile.replace(valid=tile.valid & ~bowl)
        filled = fill_gaps(cut, seed=seed, gaps=bowl).tile
        crater = Crater(x, y, diameter, age, _crater_uid(x, y, diameter))
        result = add_craters(filled, CraterTable.from_craters([crater]), seed=seed,
                             model=model)
        tiles = list(stack.tiles)
        tiles[k] = result.tile
        changed = {k}
        _propagate_up(tiles, stack.windows, k, changed)
        _propagate_down(tiles, stack.windows, k, old, changed)
        rocks = stack.rocks
        if rocks is not None and stack.info.get("rocks"):
            rocks = _reseat_rocks(stack, tiles, k, seed, changed)
        catalog = merge_catalogs([stack.catalog, result.catalog.with_layer(k)])
        edit = dict(replace_crater=dict(x=x, y=y, diameter=diameter, age=age, layer=k,
                                        seed=seed, changed_layers=sorted(changed)))
        edited = replace(
            stack, catalog=catalog, rocks=rocks,
            info={**stack.info, "edits": [*stack.info.get("edits", []), edit]},
            layers=tuple(replace(layer, tile=tile)
                         for layer, tile in zip(stack.layers, tiles, strict=True)))
        _commit(edited, outdir, changed, rocks_changed=rocks is not stack.rocks)
    return edit["replace_crater"]


def _reseat_rocks(stack: LayerStack, tiles: list, k: int, seed: int,
                  changed: set) -> RockCatalog:
    """Stand the rocks whose ground an edit changed on the new ground (``tiles`` in place).

    The rocks are the stack's keyed draw (the same rocks, ids and shapes as when it was
    built). In every rock layer from ``k`` (the edited layer) down, a rock whose outline
    touches a changed pixel, and every rock whose outline meets such a rock's, is taken off:
    the pixels under their outlines are filled smoothly from the ground around them
    (:func:`terrain.fractal.gapfill.fill_gaps` without roughness: the ground a rock hid is not
    known,
    and a rough fill would raise or sink it at random), and the rocks are stood on
    that ground again (:func:`terrain.surface.rocks.rock_heights`: base level the ground under the
    centre). Coarser layers then take the co-located fine pixels, finest first, as when the
    stack was built. Returns the rock catalogue with the new base levels (the finest
    re-seated layer's, as a build records them); ``changed`` gains the layers rewritten.
    """
    from terrain.surface.rocks import MIN_ROCK_PIXELS, RockModel, rock_heights

    model = RockModel.from_mapping(stack.info["rocks"])
    table = stack.info.get("population")
    population = Population(**table) if table else None
    draw_seed = check_seed(stack.info.get("seed", 0))
    levels, craters = _rock_levels(tiles, model, draw_seed, population)
    bases: dict[tuple[int, int], float] = {}
    for j in (j for j in levels if j >= k):
        tile, before = tiles[j], stack.tiles[j]
        moved = ~((tile.heights == before.heights)
                  | (np.isnan(tile.heights) & np.isnan(before.heights)))
        if not moved.any():
            continue
        res = tile.resolution
        rows, cols = np.nonzero(moved)
        xs, ys = tile.xy(np.array([rows.min(), rows.max()]), np.array([cols.min(), cols.max()]))
        assert model.dmax is not None  # set when the model is built
        grow = 2.0 * model.dmax  # rocks whose outlines chain into the changed ground
        rocks = model.generate(draw_seed, (xs.min() - grow, ys.min() - grow, xs.max() + grow,
                                           ys.max() + grow),
                               min_diameter=MIN_ROCK_PIXELS * res, craters=craters)
        rocks = rocks.take(np.flatnonzero(rocks.diameter >= MIN_ROCK_PIXELS * res))
        discs = [_disc(tile, float(cx), float(cy), float(r) + 0.5 * res)
                 for cx, cy, r in zip(rocks.x, rocks.y, rocks.outline_radius, strict=True)]
        taken = np.zeros(len(rocks), bool)
        under = moved.copy()  # grows with each rock taken off until no rock straddles it
        while True:
            new = [i for i, (sl, m) in enumerate(discs)
                   if not taken[i] and m is not None and np.any(under[sl] & m)]
            if not new:
                break
            for i in new:
                sl, m = discs[i]
                taken[i] = True
                under[sl] |= m
        if not taken.any():
            continue
        off = np.zeros(tile.shape, bool)
        for sl, m in (d for d, t in zip(discs, taken, strict=True) if t):
            off[sl] |= m
        # the ground a rock hid is not known: the smooth fill of the ground around it
        ground = fill_gaps(tile.replace(valid=tile.valid & ~off), seed=seed, roughness=0.0,
                           gaps=off).tile
        chosen = rocks.take(np.flatnonzero(taken))
        heights, z0, _ = rock_heights(ground, chosen)
        tiles[j] = tile.replace(heights=heights, valid=np.isfinite(heights))
        bases.update({(uid, j): z for uid, z in zip(chosen.uid.tolist(), z0.tolist(),
                                                    strict=True)})
        changed.add(j)
        log.info("layer %d: %d rocks stood on the new ground", j, len(chosen))
    for j in range(len(tiles) - 1, 0, -1):  # the layers agree again, finest first
        window = stack.windows[j]
        assert window is not None  # every layer above the base has one
        col, row, size, _ = window
        coarse = tiles[j - 1].heights.copy()
        coarse[row:row + size, col:col + size] = tiles[j].heights[::2, ::2]
        if not np.array_equal(coarse, tiles[j - 1].heights, equal_nan=True):
            tiles[j - 1] = tiles[j - 1].replace(heights=coarse, valid=np.isfinite(coarse))
            changed.add(j - 1)
    cat = stack.rocks
    assert cat is not None
    z = cat.z_base_m.copy()
    # the finest layer that draws each rock and holds its centre (whose base a build records)
    finest = np.full(len(z), -1, dtype=np.int64)
    for j in levels:
        left, bottom, right, top = tiles[j].bounds
        finest[(cat.diameter_m >= MIN_ROCK_PIXELS * tiles[j].resolution)
               & (cat.x_m >= left) & (cat.x_m <= right) & (cat.y_m >= bottom)
               & (cat.y_m <= top)] = j
    for n, (uid, j) in enumerate(zip(cat.id.tolist(), finest.tolist(), strict=True)):
        if (uid, j) in bases:
            z[n] = bases[uid, j]
    return replace(cat, z_base_m=z)


def _disc(tile: DEMTile, x: float, y: float, radius: float):
    """Return (slices, mask) of the pixels within ``radius`` m of (x, y); (None, None): none."""
    r, c = tile.rowcol(x, y)
    n = radius / tile.resolution
    r0, r1 = max(int(math.floor(r - n)), 0), min(int(math.ceil(r + n)), tile.shape[0] - 1)
    c0, c1 = max(int(math.floor(c - n)), 0), min(int(math.ceil(c + n)), tile.shape[1] - 1)
    if r0 > r1 or c0 > c1:
        return None, None
    rr, cc = np.mgrid[r0:r1 + 1, c0:c1 + 1]
    return (slice(r0, r1 + 1), slice(c0, c1 + 1)), np.hypot(rr - r, cc - c) <= n


def _crater_uid(x, y, d) -> int:
    from terrain.core.rng import hash64, stream_id

    return int(hash64(0, stream_id("replace-crater"), 0, int(round(x * 1000)),
                      int(round(y * 1000)), int(round(d * 1000))))


def _propagate_up(tiles: list, windows, k: int, changed: set) -> None:
    """Set every coarser layer's pixels inside layer ``k`` to the co-located fine pixels."""
    for j in range(k, 0, -1):
        col, row, size, _ = windows[j]
        coarse = tiles[j - 1].heights.copy()
        coarse[row:row + size, col:col + size] = tiles[j].heights[::2, ::2]
        tiles[j - 1] = tiles[j - 1].replace(heights=coarse, valid=np.isfinite(coarse))
        changed.add(j - 1)


def _propagate_down(tiles: list, windows, k: int, old_k: np.ndarray, changed: set) -> None:
    """Carry layer ``k``'s change into the finer layers that overlap it (interpolated)."""
    delta = tiles[k].heights.astype(np.float64) - old_k
    for j in range(k + 1, len(tiles)):
        col, row, size, _ = windows[j]
        parent_delta = delta[row:row + size, col:col + size]
        if not np.any(parent_delta):
            break
        # Linear interpolation of the parent's change onto the 2x grid.
        n = 2 * size - 1
        up = np.zeros((n, n))
        up[::2, ::2] = parent_delta
        up[1::2, ::2] = 0.5 * (parent_delta[:-1, :] + parent_delta[1:, :])
        up[::2, 1::2] = 0.5 * (parent_delta[:, :-1] + parent_delta[:, 1:])
        up[1::2, 1::2] = 0.25 * (parent_delta[:-1, :-1] + parent_delta[1:, :-1]
                                 + parent_delta[:-1, 1:] + parent_delta[1:, 1:])
        old_j = tiles[j].heights.astype(np.float64)
        new = (old_j + up).astype(np.float32)
        new[::2, ::2] = tiles[j - 1].heights[row:row + size, col:col + size]
        tiles[j] = tiles[j].replace(heights=new, valid=np.isfinite(new))
        delta = new.astype(np.float64) - old_j
        changed.add(j)


def _commit(stack: LayerStack, outdir: Path, changed: set, *,
            rocks_changed: bool = False) -> None:
    """Write the changed layers and the catalogues under new names, then swap the manifest in.

    The manifest's swap is the commit point; the old versions are deleted once no reader
    holds them.
    """
    if any(layer.file is None for layer in stack.layers):
        raise InvalidParameterError("only a stack read from its folder can be edited in place")
    files = [str(layer.file) for layer in stack.layers]
    old_files = list(files)
    old_catalog = stack.catalog_file
    stamp = f"{time.time_ns():x}"
    for k in changed:
        files[k] = f"layer_{k:02d}.{stamp}.tif"
    catalog = f"craters.{stamp}.csv"
    old = []
    if rocks_changed:
        old.append(stack.info.get("rock_catalog", ROCK_CATALOG))
        stack = replace(stack, info={**stack.info, "rock_catalog": f"rocks.{stamp}.csv"})
    _write_files(stack, outdir, files, only=changed, catalog=catalog, rocks=rocks_changed)
    old += [name for k, name in enumerate(old_files) if name != files[k]] + [old_catalog]
    with _readers_lock(outdir, exclusive=True) as held:
        if not held:
            log.warning("readers still hold %s; its old files go at the next edit", outdir)
            return
        for name in old:
            remove_path(outdir / name)


def _sweep(outdir: Path) -> None:
    """Remove files no manifest names (left by a killed edit) and dead temporaries.

    Called with the edit lock held; waits for readers, who may still read older files.
    """
    from terrain.core.outputs import sweep_partials

    sweep_partials(outdir)
    mpath = outdir / MANIFEST
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
        named = {e["file"] for e in manifest["layers"]} | {manifest.get("catalog", CATALOG),
                                                            manifest.get("rock_catalog")}
    except (OSError, ValueError, KeyError, TypeError):
        return  # read_stack reports what is wrong
    orphans = [p for p in _stack_files(outdir) if p.name not in named]
    if not orphans:
        return
    with _readers_lock(outdir, exclusive=True) as held:
        if not held:
            return
        for p in orphans:
            remove_path(p)
    log.info("removed %d file(s) of an interrupted edit from %s", len(orphans), outdir)


def stack_transform(entry: dict) -> Affine:
    """Return the Affine transform of a manifest layer entry.

    Parameters
    ----------
    entry : dict
        One of the manifest's ``layers`` (its ``transform``: the first six coefficients).

    Returns
    -------
    affine.Affine
    """
    return Affine(*entry["transform"])
