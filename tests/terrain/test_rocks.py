"""Rock fields: statistics against the model drawn from, resting, seamless windows."""

import functools
import json
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile, Window
from terrain.craters.catalog import CraterTable
from terrain.surface.rocks import RockModel, add_rocks, rock_heights


def _area_fraction_ratio(model, rocks, area, factors):
    out = []
    for f in factors:
        d = f * model.dmin
        sel = rocks.diameter >= d
        measured = float(np.sum(np.pi * rocks.diameter[sel] ** 2 / 4)) / area
        # the model truncated at dmax (F_k(dmax) is 1e-6 k by default)
        expected = float(model.fractional_area(d) - model.fractional_area(model.dmax))
        out.append(measured / expected)
    return np.array(out)


@pytest.mark.parametrize("k", [0.02, 0.2])
def test_golombek_cumulative_fractional_area_matches_model(k):
    # F_k(D) = k exp(-q D), q = 1.79 + 0.152 / k, for D in 2..10 dmin on a large flat area
    model = RockModel.from_mapping({"model": "golombek-rapp-mars", "k": k, "dmin": 0.03 if k < 0.1
                                    else 0.1})
    side = 300.0 if k < 0.1 else 150.0  # about 1000 rocks >= 10 dmin
    rocks = model.generate(5, (0.0, 0.0, side, side), margin=False)
    ratios = _area_fraction_ratio(model, rocks, side * side, np.linspace(2, 10, 9))
    assert np.all(np.abs(ratios - 1) < 0.15), ratios
    assert model.q == pytest.approx(1.79 + 0.152 / k)


def test_power_law_cumulative_number_matches_model():
    model = RockModel.from_spec("power:a=3e-4,b=-2.482,dmin=0.01")
    side = 60.0
    rocks = model.generate(11, (0.0, 0.0, side, side), margin=False)
    for f in np.linspace(2, 10, 9):
        d = f * model.dmin
        measured = np.count_nonzero(rocks.diameter >= d) / side**2
        expected = 3e-4 * d**-2.482 - 3e-4 * model.dmax**-2.482
        assert abs(measured / expected - 1) < 0.15, (d, measured, expected)


def test_shapes_follow_fragment_axis_ratios_and_are_partly_buried():
    model = RockModel.from_spec("golombek-rapp-mars:k=0.1,dmin=0.1")
    rocks = model.generate(3, (0.0, 0.0, 40.0, 40.0))
    a, b, c = rocks.axes.T
    assert np.all((a >= b) & (b >= c) & (c > 0))
    # equal-area diameter: pi a b / 4 = pi D^2 / 4
    np.testing.assert_allclose(np.sqrt(a * b), rocks.diameter, rtol=1e-12)
    assert np.median(b / a) == pytest.approx(0.71, abs=0.03)   # Fujiwara et al. 1978
    assert np.median(c / a) == pytest.approx(0.5, abs=0.03)
    assert 0 <= rocks.burial_fraction.min() and rocks.burial_fraction.max() <= 0.5
    # yaw uniform on [0, pi): a random orientation
    assert abs(np.mean(rocks.yaw) - math.pi / 2) < 0.05


def _tilted(n=257, res=0.05, slope_deg=10.0):
    y, x = np.mgrid[0:n, 0:n] * res
    return DEMTile.from_array((x * math.tan(math.radians(slope_deg)) + 0.01 * y)
                              .astype(np.float32), resolution=res)


def test_every_rock_rests_on_the_terrain_and_only_rocks_change_heights():
    tile = _tilted()
    model = RockModel.from_spec("golombek-rapp-mars:k=0.1,dmin=0.1")
    rocky, cat = add_rocks(tile, model, seed=4)
    assert len(cat.id) > 50
    z = rocky.heights.astype(np.float64)
    ground = tile.heights.astype(np.float64)
    assert np.all(z >= ground)                      # rocks add, never dig
    r, c = tile.rowcol(cat.x_m, cat.y_m)
    i, j = np.rint(r).astype(int), np.rint(c).astype(int)
    n = tile.shape[0] - 1
    ok = (r >= 0) & (r <= n) & (c >= 0) & (c <= n)  # centre between pixel centres
    # rocks alone: no other rock's outline reaches their centre
    from scipy.spatial import cKDTree

    every = model.generate(4, tile.bounds, min_diameter=2 * tile.resolution)
    dist, idx = cKDTree(np.column_stack([every.x, every.y])).query(
        np.column_stack([cat.x_m, cat.y_m]), k=2)
    ok &= dist[:, 1] > 0.75 * every.axes[idx[:, 1], 0] + 2 * tile.resolution
    i, j = i[ok], j[ok]
    # the base level is the terrain under the centre: no gap below, none sunk out of sight
    terrain_at_centre = (cat.x_m[ok] - 0.5 * tile.resolution) * math.tan(
        math.radians(10)) + 0.01 * (
        (tile.bounds[3] - cat.y_m[ok]) - 0.5 * tile.resolution)
    assert np.allclose(cat.z_base_m[ok], terrain_at_centre, atol=1e-4)
    above = z[i, j] - ground[i, j]
    assert np.all(above > 0)
    # the rock's top near its centre is its exposed height above the base level
    assert np.all(above <= cat.height_m[ok] * 1.25 + 0.02)
    assert np.median(above / cat.height_m[ok]) > 0.8
    # away from every rock the terrain is untouched, bitwise
    from scipy import ndimage

    rocks = RockModel.from_spec("golombek-rapp-mars:k=0.1,dmin=0.1").generate(4, tile.bounds)
    near = np.zeros(tile.shape, bool)
    rr, cc = tile.rowcol(rocks.x, rocks.y)
    inside = (rr > -30) & (rr < tile.shape[0] + 30) & (cc > -30) & (cc < tile.shape[1] + 30)
    for r0, c0, d in zip(rr[inside], cc[inside], rocks.diameter[inside], strict=True):
        reach = int(d / tile.resolution) + 2
        near[max(int(r0) - reach, 0):max(int(r0) + reach + 1, 0),
             max(int(c0) - reach, 0):max(int(c0) + reach + 1, 0)] = True
    far = ~ndimage.binary_dilation(near)
    assert far.sum() > 1000
    np.testing.assert_array_equal(rocky.heights[far], tile.heights[far])


def test_window_equals_the_same_window_of_the_full_run_bitwise():
    tile = _tilted(n=201)
    model = RockModel.from_spec("golombek-rapp-mars:k=0.15,dmin=0.1")
    craters = CraterTable.from_craters([])
    full, cat_full = add_rocks(tile, model, seed=9, craters=craters)
    for win in (Window(37, 50, 61, 44), Window(0, 0, 13, 200), Window(150, 120, 51, 81)):
        part, cat = add_rocks(tile, model, seed=9, craters=craters, window=win)
        np.testing.assert_array_equal(part.heights, full.heights[win.slices])
        # the window's catalogue is the full catalogue's rocks centred in the window
        left, bottom, right, top = part.bounds
        sel = ((cat_full.x_m >= left) & (cat_full.x_m < right)
               & (cat_full.y_m > bottom) & (cat_full.y_m <= top))
        assert sorted(cat.id.tolist()) == sorted(cat_full.id[sel].tolist())


@pytest.mark.parametrize("spec, fragment", [
    ("golombek-rapp-mars:k=1.5,dmin=0.1", "must lie in (0, 1)"),
    ("golombek-rapp-mars:k=0,dmin=0.1", "must lie in (0, 1)"),
    ("power:a=3e-4,b=0.5,dmin=0.1", "b must be negative"),
    ("power:a=-1,b=-2,dmin=0.1", "a must be positive"),
    ("golombek:k=0.1,dmin=0.1", "did you mean 'golombek-rapp-mars'"),
    ("golombek-rapp-mars:kk=0.1,dmin=0.1", "unknown rock key 'kk' (did you mean 'k'?)"),
    ("golombek-rapp-mars:k=0.1", "dmin"),
    ("golombek-rapp-mars:k=x,dmin=0.1", "k must be a number"),
])
def test_parameters_outside_their_domain_are_refused_by_name(spec, fragment):
    with pytest.raises(InvalidParameterError) as info:
        RockModel.from_spec(spec)
    assert fragment in str(info.value)


def test_heights_leave_out_rocks_the_tile_cannot_resolve():
    tile = _tilted(n=65, res=0.2)
    model = RockModel.from_spec("golombek-rapp-mars:k=0.2,dmin=0.05")
    rocks = model.generate(1, tile.bounds)
    z, z0, drawn = rock_heights(tile, rocks)
    assert np.all(rocks.diameter[drawn] >= 0.4) and np.all(np.isnan(z0[~drawn]))
    assert drawn.sum() < len(rocks)


def test_layer_stack_puts_each_rock_in_every_layer_that_resolves_it(tmp_path):
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import read_stack, write_stack

    base = synthesize_tile(65, resolution=4.0, relief=3.0, seed=2).tile
    site = (130.0, 130.0)
    model = RockModel.from_spec("golombek-rapp-mars:k=0.15,dmin=0.25")
    plain = build_stack(base, site, levels=4, layer_size=65, seed=3)
    rocky = build_stack(base, site, levels=4, layer_size=65, seed=3, rocks=model)
    cat = rocky.rocks
    assert len(cat.id) > 10 and len(set(cat.layer.tolist())) >= 2
    for k in range(1, len(rocky.tiles)):  # the layers still agree exactly
        col, row, size, _ = rocky.windows[k]
        assert np.array_equal(rocky.tiles[k - 1].heights[row:row + size, col:col + size],
                              rocky.tiles[k].heights[::2, ::2])
    checked = 0
    for k, (t0, t1) in enumerate(zip(plain.tiles, rocky.tiles, strict=True)):
        assert np.all(t1.heights >= t0.heights)  # rocks only add
        res = t1.resolution
        mine = (cat.layer <= k) & (cat.diameter_m >= 2 * res)
        left, bottom, right, top = t1.bounds
        mine &= (cat.x_m > left + res) & (cat.x_m < right - res) \
            & (cat.y_m > bottom + res) & (cat.y_m < top - res)
        r, c = t1.rowcol(cat.x_m[mine], cat.y_m[mine])
        i, j = np.rint(r).astype(int), np.rint(c).astype(int)
        raised = t1.heights[i, j] > t0.heights[i, j]
        assert raised.all(), (k, raised.mean())   # the rock is in that layer
        checked += raised.size
    assert checked >= len(cat.id)
    # a rock appears first in the coarsest layer that resolves it
    res = np.array([t.resolution for t in rocky.tiles])
    assert np.all(cat.diameter_m >= 2 * res[cat.layer])
    out = write_stack(rocky, tmp_path / "s")
    again = read_stack(out)
    assert again.rocks.id.tolist() == cat.id.tolist()
    assert json.loads((out / "manifest.json").read_text())["rock_catalog"] == "rocks.csv"


@functools.lru_cache(maxsize=1)
def _property_tile():
    from terrain.fractal.synthetic import synthesize_tile

    return synthesize_tile(129, resolution=0.05, relief=0.5, seed=6).tile


@given(col=st.integers(0, 120), row=st.integers(0, 120), w=st.integers(1, 60),
       h=st.integers(1, 60), seed=st.integers(0, 2**63 - 1))
def test_any_window_equals_the_full_run_bitwise(col, row, w, h, seed):
    tile = _property_tile()
    w, h = min(w, 129 - col), min(h, 129 - row)
    model = RockModel.from_spec("golombek-rapp-mars:k=0.2,dmin=0.1")
    full, _ = add_rocks(tile, model, seed=seed)
    part, _ = add_rocks(tile, model, seed=seed, window=Window(col, row, w, h))
    np.testing.assert_array_equal(part.heights, full.heights[row:row + h, col:col + w])


def _rocky_stack(folder):
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(65, resolution=4.0, relief=3.0, seed=2).tile
    model = RockModel.from_spec("golombek-rapp-mars:k=0.15,dmin=0.25")
    return write_stack(build_stack(base, (130.0, 130.0), levels=4, layer_size=65, seed=3,
                                   rocks=model), folder)


def _resting_misfit(stack, sel):
    """Per rock: top at its centre pixel minus (base + height), and how far its base lies
    outside the heights of the ground around it (0 when the ground brackets it).

    Each rock is looked at in the finest layer that holds its centre well inside; the ring is
    the terrain just outside its outline (a rock resting on the ground has its base between its
    lowest and highest point: neither floating above it all nor buried below it all).
    """
    cat = stack.rocks
    top_misfit, base_misfit = [], []
    for i in np.flatnonzero(sel):
        for tile in stack.tiles[::-1]:
            left, bottom, right, top = tile.bounds
            r_out = 0.75 * cat.axis_a_m[i] * 2 + 2 * tile.resolution
            if (cat.diameter_m[i] >= 2 * tile.resolution and left + r_out < cat.x_m[i] < right
                    - r_out and bottom + r_out < cat.y_m[i] < top - r_out):
                break
        else:
            continue
        h = tile.heights.astype(np.float64)
        r, c = tile.rowcol(cat.x_m[i], cat.y_m[i])
        top_misfit.append(h[int(round(float(r))), int(round(float(c)))]
                          - (cat.z_base_m[i] + cat.height_m[i]))
        rows, cols = np.mgrid[0:tile.shape[0], 0:tile.shape[1]]
        px, py = tile.xy(rows, cols)
        d = np.hypot(px - cat.x_m[i], py - cat.y_m[i])
        ring = (d > r_out - tile.resolution) & (d <= r_out)
        lo, hi = h[ring].min(), h[ring].max()
        base_misfit.append(max(cat.z_base_m[i] - hi, lo - cat.z_base_m[i], 0.0))
    return np.array(top_misfit), np.array(base_misfit)


def test_every_rock_rests_on_the_terrain_after_a_crater_replacement(tmp_path):
    from terrain.stack.edit import replace_crater
    from terrain.stack.store import read_stack

    folder = _rocky_stack(tmp_path / "s")
    before = read_stack(folder)
    x, y, diameter = 131.0, 129.0, 24.0
    replace_crater(folder, x, y, diameter)
    after = read_stack(folder)
    cat = after.rocks
    assert cat.id.tolist() == before.rocks.id.tolist()  # the same keyed rocks
    near = np.hypot(cat.x_m - x, cat.y_m - y) < 0.6 * diameter
    assert near.sum() >= 10
    top, base = _resting_misfit(after, near)
    assert len(top) >= 6
    # each rock's top stands its height above its base, and its base is the ground around it
    assert np.all(np.abs(top) < 0.15 * cat.height_m.max() + 0.05), top
    assert np.all(base < 0.02), base
    # the rocks were in the changed ground: their bases moved with it
    moved = np.abs(cat.z_base_m - before.rocks.z_base_m)
    assert np.median(moved[np.hypot(cat.x_m - x, cat.y_m - y) < 0.4 * diameter]) > 0.5
    for k in range(1, len(after.tiles)):  # the layers still agree exactly
        col, row, size, _ = after.windows[k]
        assert np.array_equal(after.tiles[k - 1].heights[row:row + size, col:col + size],
                              after.tiles[k].heights[::2, ::2])
    # deterministic: the same edit of the same stack gives the same bytes
    again = _rocky_stack(tmp_path / "t")
    replace_crater(again, x, y, diameter)
    twin = read_stack(again)
    for a, b in zip(after.tiles, twin.tiles, strict=True):
        np.testing.assert_array_equal(a.heights, b.heights)
    np.testing.assert_array_equal(twin.rocks.z_base_m, cat.z_base_m)
    # far from a small crater, rocks and their record are untouched
    small = _rocky_stack(tmp_path / "u")
    replace_crater(small, 140.0, 140.0, 6.0)
    edited = read_stack(small).rocks
    far = np.hypot(edited.x_m - 140.0, edited.y_m - 140.0) > 3 * 6.0
    assert far.sum() >= 5
    np.testing.assert_array_equal(edited.z_base_m[far], before.rocks.z_base_m[far])
    assert not np.array_equal(edited.z_base_m, before.rocks.z_base_m)
