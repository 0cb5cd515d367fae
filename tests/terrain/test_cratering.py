"""Cratered terrain: determinism, window exactness, nodata policy, composition order."""

import numpy as np
import pytest

from terrain.core.tile import DEMTile, Window
from terrain.craters.catalog import Crater, CraterTable
from terrain.craters.cratering import CraterModel, add_craters
from terrain.craters.population import Population
from terrain.fractal.synthetic import synthesize_tile

POP = Population(dmin=3.0, dmax=90.0, density=4000.0, max_age=1.0)


@pytest.fixture(scope="module")
def full():
    return synthesize_tile(257, resolution=1.0, relief=6.0, seed=17, craters=POP)


def test_same_seed_same_bytes(full):
    again = synthesize_tile(257, resolution=1.0, relief=6.0, seed=17, craters=POP)
    assert again.tile.heights.tobytes() == full.tile.heights.tobytes()
    for key in full.catalog.columns:
        assert np.array_equal(getattr(again.catalog, key), getattr(full.catalog, key))
    other = synthesize_tile(257, resolution=1.0, relief=6.0, seed=18, craters=POP)
    assert not np.array_equal(other.tile.heights, full.tile.heights)


@pytest.mark.parametrize("window", [
    Window(0, 0, 257, 257), Window(100, 120, 37, 20), Window(0, 0, 1, 1),
    Window(200, 5, 57, 252), Window(128, 128, 1, 129),
])
def test_any_window_equals_the_same_window_of_the_full_tile(full, window):
    part = synthesize_tile(257, resolution=1.0, relief=6.0, seed=17, craters=POP, window=window)
    assert np.array_equal(part.tile.heights, full.tile.heights[window.slices])
    # georeferencing of the window matches
    assert part.tile.xy(0, 0) == full.tile.xy(window.row, window.col)
    # the window's catalogue holds every crater touching it, centred inside or not
    ids = set(part.catalog.id.tolist())
    assert ids <= set(full.catalog.id.tolist())
    x, y = full.catalog.x_m, full.catalog.y_m
    left, bottom, right, top = part.tile.bounds
    gx = np.clip(x, left, right) - x
    gy = np.clip(y, bottom, top) - y
    touching = np.hypot(gx, gy) <= full.catalog.diameter_m * CraterModel().footprint_factor
    assert ids == set(full.catalog.id[touching].tolist())
    outside = (x < left) | (x > right) | (y < bottom) | (y > top)
    if window == Window(100, 120, 37, 20):
        assert np.any(touching & outside), "craters centred outside the window touch it"


def test_windows_of_a_real_style_dem_are_exact():
    base = synthesize_tile(129, resolution=2.0, relief=5.0, seed=3).tile
    h = base.heights.copy()
    h[40:50, 60:90] = np.nan  # a gap
    tile = DEMTile.from_array(h, resolution=2.0)
    pop = Population(dmin=6.0, dmax=60.0, density=1500.0)
    whole = add_craters(tile, pop, seed=5)
    for w in (Window(50, 30, 40, 30), Window(0, 100, 129, 29)):
        part = add_craters(tile, pop, seed=5, window=w)
        assert np.array_equal(part.tile.heights, whole.tile.heights[w.slices], equal_nan=True)


def test_gaps_stay_gaps_and_craters_do_not_invent_data():
    h = np.zeros((101, 101))
    h[30:60, 30:60] = np.nan
    tile = DEMTile.from_array(h, resolution=1.0)
    out = add_craters(tile, CraterTable.from_craters([Crater(45.0, 55.0, 40.0, 0.0, 1)]),
                      seed=0).tile
    assert np.array_equal(out.valid, tile.valid)
    assert np.isnan(out.heights[30:60, 30:60]).all()
    assert np.isfinite(out.heights[tile.valid]).all()


def test_terrain_away_from_craters_is_unchanged_bitwise():
    base = synthesize_tile(129, resolution=1.0, relief=4.0, seed=8).tile
    crater = Crater(40.0, 40.0, 20.0, 0.5, 11)
    out = add_craters(base, CraterTable.from_craters([crater]), seed=8,
                      model=CraterModel().smooth()).tile
    rows, cols = np.mgrid[0:129, 0:129]
    x, y = base.xy(rows, cols)
    far = np.hypot(x - 40.0, y - 40.0) > 20.0
    assert np.array_equal(out.heights[far], base.heights[far])
    assert not np.array_equal(out.heights[~far], base.heights[~far])


def test_younger_crater_obliterates_an_older_one_of_its_class():
    flat = DEMTile.from_array(np.zeros((161, 161)), resolution=1.0)
    old = Crater(70.0, 80.0, 50.0, 0.05, 1)
    young = Crater(95.0, 80.0, 50.0, 0.01, 2)
    both = add_craters(flat, CraterTable.from_craters([old, young]), seed=1,
                       model=CraterModel().smooth()).tile
    only_young = add_craters(flat, CraterTable.from_craters([young]), seed=1,
                             model=CraterModel().smooth()).tile
    # on the young crater's floor and lower wall the old crater is gone
    rows, cols = np.mgrid[0:161, 0:161]
    x, y = flat.xy(rows, cols)
    r_young = np.hypot(x - 95.0, y - 80.0)
    inner = r_young < 25.0 * (1 - 0.25)
    assert np.allclose(both.heights[inner], only_young.heights[inner], atol=1e-5)
    # and the result is continuous across the young rim (no cliff where it meets old ejecta)
    step = np.abs(np.diff(both.heights.astype(np.float64), axis=1)).max()
    assert step < 0.5 * 0.2 * 50.0


def test_smaller_classes_are_added_onto_larger_ones():
    """Order: large to small; a small crater inside a large one is not erased by it."""
    flat = DEMTile.from_array(np.zeros((201, 201)), resolution=1.0)
    large_young = Crater(100.0, 100.0, 120.0, 0.0, 1)
    small_old = Crater(100.0, 100.0, 10.0, 0.5, 2)
    out = add_craters(flat, CraterTable.from_craters([large_young, small_old]), seed=1,
                      model=CraterModel().smooth())
    heights = out.tile.heights
    large = add_craters(flat, CraterTable.from_craters([large_young]), seed=1,
                        model=CraterModel().smooth()).tile.heights
    assert heights[100, 100] < large[100, 100]
    cat = out.catalog
    assert cat.diameter_m.tolist() == [120.0, 10.0]  # composition order


def test_catalogue_columns_are_consistent(full):
    cat = full.catalog
    n = len(cat.id)
    assert n > 100
    assert len(np.unique(cat.id)) == n
    assert np.all((cat.diameter_m >= POP.dmin) & (cat.diameter_m < POP.dmax))
    assert np.all((cat.age_gyr >= 0) & (cat.age_gyr <= POP.max_age))
    assert np.all(cat.rim_fraction <= cat.depth_fraction)
    assert np.allclose(cat.depth_m / cat.depth_fraction,
                       0.196 * (cat.diameter_m / 1000) ** 1.01 * 1000)


def test_windows_with_complex_craters_are_exact():
    """Lunar-scale craters (complex above 15 km, with slope-dependent degradation) at 1 km."""
    pop = Population(dmin=4000.0, dmax=60000.0, density=0.004, max_age=3.5)
    full = synthesize_tile(129, resolution=1000.0, relief=3000.0, seed=9, craters=pop)
    assert (full.catalog.diameter_m > 15000.0).any()
    for w in (Window(40, 30, 50, 40), Window(0, 90, 129, 39)):
        part = synthesize_tile(129, resolution=1000.0, relief=3000.0, seed=9, craters=pop,
                               window=w)
        assert np.array_equal(part.tile.heights, full.tile.heights[w.slices])


def test_the_same_bytes_on_one_thread_as_on_three():
    """Craters are composed in parallel bands; a pixel sees its craters in the same order."""
    from terrain.core.parallel import limited

    tile = synthesize_tile(257, resolution=1.0, relief=40.0, seed=5).tile
    pop = Population(dmin=2.0, dmax=120.0, density=4e4)
    with limited(3):
        many = add_craters(tile, pop, seed=3)
    with limited(1):
        one = add_craters(tile, pop, seed=3)
    assert len(many.catalog) > 500
    assert np.array_equal(many.tile.heights, one.tile.heights, equal_nan=True)
