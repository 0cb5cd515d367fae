"""Editing a layer stack in place: a blurred crater replaced by a sharp one.

Martin et al. (2014), IV.D.

The edit holds the stack's edit lock, changes the layers in memory so that they still agree
exactly (:mod:`terrain.stack.model`), and commits them as new files behind the manifest
(:func:`terrain.stack.store.commit_edit`), so readers and a killed edit never see a torn stack.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed
from terrain.core.tile import DEMTile
from terrain.craters.catalog import Crater, CraterTable, RockCatalog
from terrain.craters.cratering import CraterModel, add_craters
from terrain.craters.population import Population
from terrain.fractal.gapfill import fill_gaps
from terrain.stack.build import rock_levels
from terrain.stack.model import LayerStack, merge_catalogs
from terrain.stack.plan import MIN_CRATER_PIXELS
from terrain.stack.store import commit_edit, read_stack, stack_lock, sweep_edits

__all__ = ["replace_crater"]

log = logging.getLogger(__name__)


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
        sweep_edits(outdir)
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
        commit_edit(edited, outdir, changed, rocks_changed=rocks is not stack.rocks)
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
    levels, craters = rock_levels(tiles, model, draw_seed, population)
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
