"""Building a layer stack in memory (Martin et al. 2014, IV.A, V.B).

:func:`build_stack` fills the base's gaps, then for every level adds the layer's craters
(:func:`terrain.stack.plan.layer_craters`) and expands the site's window 2x; rocks go on every
layer that resolves them; finally every coarser pixel inside a finer layer takes its
co-located fine pixel (:mod:`terrain.stack.model`). A stack too large for memory is built
chunk by chunk by :mod:`terrain.stack.chunkedlayers`, bitwise equal.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

from terrain.core import memory
from terrain.core.errors import InvalidParameterError
from terrain.core.progress import Progress
from terrain.core.rng import check_seed
from terrain.core.tile import DEMTile
from terrain.craters.catalog import RockCatalog
from terrain.craters.cratering import CraterModel, add_craters
from terrain.craters.population import Population
from terrain.craters.unresolved import keep_lattice
from terrain.fractal.expand import expand_level, expanded_transform
from terrain.fractal.gapfill import fill_gaps
from terrain.fractal.roughness import ExpansionParameters, RoughnessChoice, local_amplitude
from terrain.stack.model import LayerStack, layer_records, merge_catalogs
from terrain.stack.plan import (
    MAX_LEVELS,
    MIN_CRATER_PIXELS,
    layer_bounds,
    layer_craters,
    layer_plan,
    site_in_bounds,
)
from terrain.stack.slopelaw import (
    fill_from_gradient,
    fill_target,
    law_parameters,
    law_record,
    local_gradient,
    strided,
)
from terrain.stack.store import ROCK_CATALOG

__all__ = ["build_stack", "expansion_parameters", "fixed_cells", "relax_layer", "rock_levels"]

log = logging.getLogger(__name__)


def build_stack(base: DEMTile, site: tuple[float, float], *, levels: int, layer_size: int = 1025,
                seed: int = 0, population: Population | None = None,
                model: CraterModel | None = None,
                params: ExpansionParameters | RoughnessChoice | None = None,
                min_crater_pixels: float = MIN_CRATER_PIXELS,
                progress: Progress | None = None,
                rocks=None, keep_known: bool = False, repose=None,
                slope_law=None) -> LayerStack:
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
    keep_known : bool
        Craters of the expanded layers leave the base's own pixels as they are, adding only
        what those samples do not see (:func:`terrain.craters.unresolved.keep_lattice`): a
        real DEM's known heights stay, bitwise, in every layer.
    repose : terrain.surface.repose.Repose, optional
        Relax every layer's slopes above the angle of repose after its craters
        (:func:`relax_layer`): synthesized cells only, outside fresh craters.
    slope_law : terrain.core.presets.TerrainPreset, optional
        Every level's roughness follows this preset's slope law
        (:mod:`terrain.stack.slopelaw`): without explicit ``params`` (a
        :class:`~terrain.fractal.roughness.RoughnessChoice` of neither fractal dimension nor
        height scale) the expansion continues the law's fBm, and each level adds the slope
        its parent lacks under the law.

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
    known = base.valid.copy()  # the base's known heights, which no layer may change
    if not base.valid.all():
        filled = fill_gaps(base, seed=seed)
        info["base_filled_pixels"] = int(filled.filled.sum())
        info["base_fill_roughness"] = filled.roughness
        base = filled.tile
    tick("fill")
    params = expansion_parameters(base, params, slope_law)
    amp = (local_amplitude(base.heights, params.base_sigma, params.local_box)
           if params.uses_local_map and slope_law is None else None)

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
            sigmas = params.sigmas(k)
            if slope_law is not None:
                tp = local_gradient(parent.heights, parent.resolution)
                target = fill_target(strided(tp), parent.resolution, slope_law)
                fill = fill_from_gradient(tp, parent.resolution, target, float(sigmas[0]))
                where: dict[str, Any] = dict(amplitude=fill, amplitude_origin=(pr, pc),
                                             amplitude_level=k - 1)
            else:
                where = dict(amplitude=amp, amplitude_origin=(0, 0), amplitude_level=0)
            heights = expand_level(parent.heights, (pr, pc), (r0, r0 + 2 * size - 2),
                                   (c0, c0 + 2 * size - 2), level=k,
                                   sigmas=sigmas, weights=params.weights(k),
                                   taps=params.taps(k), seed=seed, **where)
            heights.flags.writeable = False
            tiles.append(DEMTile(heights, np.isfinite(heights),
                                 expanded_transform(parent.transform, 1, row, col), base.crs,
                                 base.nodata))
            tick(f"expand {k}")
        if population is not None:
            # The next layer's extent is known from the plan, so craters can be sorted now.
            table = layer_craters(population, seed, plan, k, factor, min_crater_pixels)
            if len(table):
                result = add_craters(tiles[k], table, seed=seed, model=model)
                if keep_known and k > 0:
                    ny, nx = tiles[k].shape
                    r0, c0 = origins[k]
                    kept = keep_lattice(tiles[k].heights, result.tile.heights, step=2**k,
                                        origin=(r0, c0), layer_rows=(r0, r0 + ny - 1),
                                        layer_cols=(c0, c0 + nx - 1)).astype(np.float32)
                    result = dataclasses.replace(
                        result, tile=result.tile.replace(heights=kept,
                                                         valid=result.tile.valid))
                tiles[k] = result.tile
                catalogs.append(result.catalog.with_layer(k))
            log.info("layer %d: %d craters", k, len(table))
        if repose is not None:
            tiles[k], moved = relax_layer(tiles[k], k, origins[k], known, repose, catalogs)
            log.info("layer %d: %d cells relaxed to repose", k, moved)
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
                crater_model=model.as_dict(),
                **({"repose": repose.as_dict()} if repose is not None else {}),
                **({"slope_law": law_record(slope_law)} if slope_law is not None else {}))
    return LayerStack(layer_records(tiles, windows, origins), catalog, info, rock_catalog)


def expansion_parameters(base: DEMTile, params, slope_law) -> ExpansionParameters:
    """Return a stack's expansion parameters: given, the slope law's, or measured from ``base``.

    Parameters
    ----------
    base : DEMTile
        The filled base.
    params : ExpansionParameters, RoughnessChoice or None
        Given parameters are kept; a choice of neither fractal dimension nor height scale
        under a ``slope_law`` continues the law's fBm
        (:func:`terrain.stack.slopelaw.law_parameters`, the choice's regolith floor kept);
        otherwise the choice is measured from ``base``.
    slope_law : terrain.core.presets.TerrainPreset or None

    Returns
    -------
    ExpansionParameters
    """
    if isinstance(params, ExpansionParameters):
        return params
    choice = params or RoughnessChoice()
    if slope_law is not None and choice.fractal_dimension is None \
            and choice.height_scale is None:
        return law_parameters(slope_law, base.resolution, max(2, max(base.shape) - 1),
                              regolith=choice.regolith)
    return choice.for_tile(base)


def fixed_cells(shape: tuple[int, int], level: int, origin: tuple[int, int],
                known: np.ndarray, known_origin: tuple[int, int]) -> np.ndarray:
    """Cells of a layer co-located with a known pixel of the base.

    Parameters
    ----------
    shape : (rows, cols)
        The part of the layer asked about.
    level : int
        The layer's level (0 the base).
    origin : (row, col)
        Global pixel index, at the layer's level, of the part's cell (0, 0).
    known : (m, n) bool
        Known pixels of a part of the base ...
    known_origin : (row, col)
        ... whose cell (0, 0) is this base pixel.

    Returns
    -------
    (rows, cols) bool
    """
    ny, nx = shape
    step = 2 ** level
    rows = origin[0] + np.arange(ny) - known_origin[0] * step
    cols = origin[1] + np.arange(nx) - known_origin[1] * step
    on_r = (rows >= 0) & (rows % step == 0) & (rows // step < known.shape[0])
    on_c = (cols >= 0) & (cols % step == 0) & (cols // step < known.shape[1])
    fixed = np.zeros((ny, nx), dtype=bool)
    ri, ci = np.flatnonzero(on_r), np.flatnonzero(on_c)
    if ri.size and ci.size:
        fixed[np.ix_(ri, ci)] = known[np.ix_(rows[ri] // step, cols[ci] // step)]
    return fixed


def relax_layer(tile: DEMTile, level: int, origin: tuple[int, int], known: np.ndarray,
                repose, catalogs: list) -> tuple[DEMTile, int]:
    """Relax one layer's synthesized slopes to the angle of repose.

    Parameters
    ----------
    tile : DEMTile
        The layer after its craters.
    level : int
        Its level (0 the base).
    origin : (row, col)
        Its global pixel origin at its level.
    known : (ny, nx) bool
        The base's known pixels: the layer's cells co-located with them keep their heights
        (a real DEM's heights never change), as do cells inside fresh craters of any layer.
    repose : terrain.surface.repose.Repose
    catalogs : list of CraterCatalog
        The catalogues of the layers built so far (this one included).

    Returns
    -------
    tile : DEMTile
    moved : int
        Cells changed.
    """
    from terrain.surface.repose import relax_to_repose

    ny, nx = tile.shape
    fixed = fixed_cells((ny, nx), level, origin, known, (0, 0))
    fresh = np.zeros((ny, nx), dtype=bool)
    for c in catalogs:
        if len(c.x_m):
            fresh |= repose.fresh_mask((ny, nx), tile.transform, c.x_m, c.y_m, c.diameter_m,
                                       c.age_gyr)
    z, changed = relax_to_repose(tile.heights, tile.resolution, repose.angle_deg,
                                 movable=~(fixed | fresh), iterations=repose.iterations)
    if not changed.any():
        return tile, 0
    heights = z.astype(tile.heights.dtype)
    return tile.replace(heights=heights, valid=tile.valid), int(changed.sum())


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

    levels, craters = rock_levels(tiles, rocks, seed, population)
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


def rock_levels(tiles: list, rocks, seed: int, population) -> tuple[list[int], Any]:
    """Return the layers that hold rocks and the craters that raise their density."""
    from terrain.surface.rocks import MIN_ROCK_PIXELS

    levels = [k for k, t in enumerate(tiles) if MIN_ROCK_PIXELS * t.resolution < rocks.dmax]
    craters = None
    if levels and rocks.craters and population is not None:
        dmin = max(5.0 * rocks.regolith_m, population.dmin)
        if dmin < population.dmax:
            craters = population.generate(seed, tiles[levels[0]].bounds,
                                          margin=rocks.crater_margin,
                                          min_diameter=dmin)
    return levels, craters
