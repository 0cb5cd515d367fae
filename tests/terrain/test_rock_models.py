"""Lunar rock models and crater block fields, counted as a geologist counts boulders.

The references are the published laws and measurements written out here, not the model's
own functions: the VIPER environment specification's N(>=D) = a D^b per m^2, Linne's boulder
field (Pajola et al. 2019: 12,000 boulders >= 4.4 m, cumulative index -4.03, largest 30.8 m
around a 2.2 km crater), the largest boulder of a crater, 0.29 Dc^0.66 m (Bart and Melosh
2010), the median boulder survival of 40-80 Myr (Basilevsky et al. 2013; Watkins et al.
2019) and the Neukum production function's N(>=1 km) = 8.38e-4 per km^2 per Gyr with a
cumulative slope of -3 below 1 km (Neukum et al. 2001).
"""

import math

import numpy as np
import pytest

from terrain.core.errors import InvalidParameterError
from terrain.craters.catalog import Crater, CraterTable
from terrain.fractal.synthetic import synthesize_tile
from terrain.surface.rocks import RockModel, add_rocks

#: The VIPER environment specification, N(>=D) = a D^b rocks per m^2 (D in metres).
PUBLISHED = {"viper-nominal": (3e-4, -2.482), "viper-low": (1e-4, -1.755),
             "viper-high": (2e-3, -2.661)}


def _count(rocks, d, area):
    return np.count_nonzero(rocks.diameter >= d) / area


@pytest.mark.parametrize("name, d_lo, side", [
    ("viper-nominal", 0.1, 1000.0),   # 91,000 rocks >= 0.1 m, 300 >= 1 m
    ("viper-low", 0.1, 2000.0),       # 400 rocks >= 1 m
    ("viper-high", 0.2, 1000.0),      # 316 rocks >= 2 m
])
def test_viper_laws_hold_over_a_decade_of_size(name, d_lo, side):
    """N(>=D) counted on a large plain (no craters) is the published law within 15 % from
    d_lo to 10 d_lo, the law cut at the model's 5 m upper end."""
    a, b = PUBLISHED[name]
    model = RockModel.from_spec(f"{name}:dmin={d_lo / 2}")
    rocks = model.generate(7, (0.0, 0.0, side, side), min_diameter=d_lo, margin=False)
    for d in np.geomspace(d_lo, 10 * d_lo, 6):
        expected = a * d**b - a * 5.0**b
        measured = _count(rocks, d, side * side)
        assert abs(measured / expected - 1) < 0.15, (name, d, measured, expected)
    assert rocks.diameter.max() <= 5.0


def test_viper_nominal_gives_300_metre_rocks_per_km2_and_is_the_default():
    model = RockModel.from_spec("viper-nominal:dmin=0.5")
    rocks = model.generate(3, (0.0, 0.0, 3000.0, 3000.0), margin=False)
    per_km2 = _count(rocks, 1.0, 9e6) * 1e6
    assert per_km2 == pytest.approx(300 - 3e-4 * 5.0**-2.482 * 1e6, rel=0.1)
    assert RockModel(dmin=0.5).model == "viper-nominal"


@pytest.mark.parametrize("spec, fragment", [
    ("golombek:k=0.02,dmin=0.1", "did you mean 'golombek-rapp-mars'"),
    ("viper-nominl:dmin=0.1", "did you mean 'viper-nominal'"),
    ("viper-low:a=1e-3,dmin=0.1", "'a' is fixed by the viper-low rock model"),
    ("viper-high:block_index=-1.5,dmin=0.1", "block_index must be below -2"),
])
def test_renamed_and_fixed_models_are_refused_by_name(spec, fragment):
    with pytest.raises(InvalidParameterError, match=fragment.replace("(", r"\(")):
        RockModel.from_spec(spec)


def _field(age, diameter=500.0, seed=5, model="viper-nominal:dmin=0.5"):
    """Rocks in the block field (within two radii) of one crater at the origin."""
    m = RockModel.from_spec(model)
    half = diameter * 1.5
    craters = CraterTable.from_craters([Crater(0.0, 0.0, diameter, age)])
    rocks = m.generate(seed, (-half, -half, half, half), craters=craters, margin=False)
    inside = np.hypot(rocks.x, rocks.y) <= diameter
    return rocks.take(np.flatnonzero(inside)), math.pi * diameter**2


def test_fresh_block_fields_follow_linnes_steep_size_distribution():
    """Around a fresh 500 m crater the boulders >= 2-8 m follow a cumulative index near
    Linne's -4.03 (Pajola et al. 2019), far steeper than the plains' -2.48, and its largest
    block is of the size Linne's is for its diameter (30.8 m / 2.2 km) within a factor 3."""
    rocks, area = _field(0.0)
    d = np.geomspace(2.0, 8.0, 5)
    n = np.array([_count(rocks, x, area) for x in d])
    index = np.polyfit(np.log(d), np.log(n), 1)[0]
    assert -4.6 < index < -3.5, index
    plain = RockModel.from_spec("viper-nominal:dmin=0.5").generate(
        5, (0.0, 0.0, 3000.0, 3000.0), margin=False)
    n_plain = np.array([_count(plain, x, 9e6) for x in d])
    assert index < PUBLISHED["viper-nominal"][1] - 1.0  # steeper than the plains' law
    assert n[0] > 20 * n_plain[0]              # a block field, not a sprinkle
    ratio = rocks.diameter.max() / 500.0
    assert 30.8 / 2200 / 3 < ratio < 30.8 / 2200 * 3, ratio


def test_a_linne_size_crater_has_linnes_boulders():
    """A fresh 2.2 km crater in a thin (5 m) regolith has about Linne's 12,000 boulders
    >= 4.4 m (Pajola et al. 2019) within two radii, and its largest within a factor 1.5 of
    Linne's 30.8 m."""
    rocks, _ = _field(0.0, diameter=2200.0, model="viper-nominal:dmin=4,regolith_m=5")
    plain = 3e-4 * (4.4**-2.482 - 5.0**-2.482) * math.pi * 2200.0**2
    n = np.count_nonzero(rocks.diameter >= 4.4) - plain
    assert 12000 * 0.8 < n < 12000 * 1.2, n
    assert 30.8 / 1.5 < rocks.diameter.max() < 30.8 * 1.5, rocks.diameter.max()


@pytest.mark.parametrize("diameter", [200.0, 500.0, 1000.0])
def test_largest_block_follows_bart_and_melosh(diameter):
    """The largest boulder of a fresh crater in rock is 0.29 Dc^0.66 m (Bart and Melosh
    2010), whose craters scatter about a factor 2 around it."""
    published = 0.29 * diameter**0.66
    largest = []
    for seed in range(5):
        m = RockModel.from_spec("viper-nominal:dmin=1,regolith_m=2")
        craters = CraterTable.from_craters([Crater(0.0, 0.0, diameter, 0.0)])
        half = diameter * 1.2
        rocks = m.generate(seed, (-half, -half, half, half), craters=craters,
                           min_diameter=published / 4, margin=False)
        largest.append(rocks.diameter.max())
    ratio = float(np.median(largest)) / published
    assert 0.5 < ratio < 2.0, (diameter, largest, published)


@pytest.mark.parametrize("regolith, blocky", [(5.0, 60.0), (10.0, 110.0)])
def test_only_craters_that_dig_below_the_regolith_throw_blocks(regolith, blocky):
    """Excavating to a tenth of their diameter, craters up to 10 regolith thicknesses throw
    out no blocks; just beyond, small ones; a crater of 40 thicknesses hundreds >= 1 m."""
    model = f"viper-nominal:dmin=0.1,regolith_m={regolith}"

    def blocks(diameter, d):
        rocks, area = _field(0.0, diameter=diameter, model=model)
        plain = 3e-4 * (d**-2.482 - 5.0**-2.482) * area
        return np.count_nonzero(rocks.diameter >= d) - plain, plain

    below, plain = blocks(9.5 * regolith, 0.1)
    assert below < 5 * math.sqrt(plain), below
    near, plain = blocks(blocky, 0.1)
    assert near > 5 * math.sqrt(plain), near
    big, plain = blocks(40 * regolith, 1.0)
    assert big > 100 + 5 * math.sqrt(plain), big


def _fresh_craters(side, seed, age_gyr=0.6, dmin=40.0):
    """Craters >= dmin made over the last age_gyr at the Neukum production rate (N(>=1 km) =
    8.38e-4 per km^2 per Gyr, cumulative slope -3 below 1 km), ages uniform: a plain's fresh
    craters, not chosen to be near the site or away from it."""
    rng = np.random.default_rng(seed)
    per_km2 = 8.38e-4 * age_gyr * (dmin / 1000.0) ** -3.0
    n = rng.poisson(per_km2 * (side / 1000.0) ** 2)
    d = dmin * (1.0 - rng.random(n)) ** (-1.0 / 3.0)
    xy = rng.random((n, 2)) * side
    return CraterTable.from_craters([Crater(float(x), float(y), float(dd), float(t)) for
                                     (x, y), dd, t in zip(xy, d, rng.random(n) * age_gyr,
                                                          strict=True)])


@pytest.mark.parametrize("regolith", [5.0, 10.0])
def test_a_typical_site_stays_in_the_viper_band(regolith):
    """Over a large plain whose fresh craters formed at the production rate, the rocks per m^2
    from 6 cm to 1.25 m lie between the VIPER low and high laws: the block fields add to the
    nominal plain what fresh craters add, not a different surface."""
    side = 4000.0
    craters = _fresh_craters(side, seed=11)
    model = RockModel.from_spec(f"viper-nominal:dmin=0.05,regolith_m={regolith}")
    # small rocks on sample squares spread over the plain, large ones on its middle km^2
    for d, square, n_side in ((0.06, 20.0, 12), (0.2, 60.0, 12), (0.6, 1000.0, 1),
                              (1.25, 2000.0, 1)):
        count, area = 0, 0.0
        for cx in np.linspace(0.5 * square, side - 0.5 * square, n_side):
            for cy in np.linspace(0.5 * square, side - 0.5 * square, n_side):
                if n_side == 1:
                    cx = cy = side / 2
                box = (cx - square / 2, cy - square / 2, cx + square / 2, cy + square / 2)
                rocks = model.generate(3, box, craters=craters, min_diameter=d, margin=False)
                count += int(np.count_nonzero(rocks.diameter >= d))
                area += square * square
        low = PUBLISHED["viper-low"][0] * d ** PUBLISHED["viper-low"][1]
        high = PUBLISHED["viper-high"][0] * d ** PUBLISHED["viper-high"][1]
        assert low < count / area < high, (d, count / area, low, high)


def test_block_fields_fade_with_the_median_boulder_survival():
    """Half the boulders survive 40-80 Myr; by 300 Myr almost none are left; an older field is
    the same blocks, thinned."""
    fresh, area = _field(0.0)
    plain = 3e-4 * 1.0**-2.482 * area  # plains rocks >= 1 m expected in the same area

    def blocks(age):
        rocks, _ = _field(age)
        return np.count_nonzero(rocks.diameter >= 1.0) - plain, rocks

    n0, _ = blocks(0.0)
    n40, _ = blocks(0.04)
    n80, _ = blocks(0.08)
    n300, old = blocks(0.3)
    assert n40 / n0 >= 0.5 * 0.95 and n80 / n0 <= 0.5 * 1.05, (n40 / n0, n80 / n0)
    assert n300 / n0 < 0.05
    assert set(old.uid.tolist()) <= set(fresh.uid.tolist())
    model = RockModel.from_spec("viper-nominal:dmin=0.5,craters=off")
    craters = CraterTable.from_craters([Crater(0.0, 0.0, 500.0, 0.0)])
    none = model.generate(5, (-750, -750, 750, 750), craters=craters, margin=False)
    assert np.count_nonzero(np.hypot(none.x, none.y) <= 500) < 2 * plain * 4


def test_small_craters_in_the_regolith_have_no_blocks():
    rocks, area = _field(0.0, diameter=20.0, model="viper-nominal:dmin=0.05,regolith_m=5")
    plain = 3e-4 * (0.05**-2.482 - 5.0**-2.482) * area
    assert len(rocks) < plain + 5 * math.sqrt(plain)


def _craters():
    return CraterTable.from_craters([Crater(120.0, 80.0, 160.0, 0.01),
                                     Crater(-60.0, 40.0, 60.0, 0.0),
                                     Crater(30.0, -150.0, 600.0, 0.05)])


def test_a_rock_is_the_same_rock_in_every_layer_that_resolves_it():
    """Nested extents at halving resolutions (as a stack's layers): every rock a coarse layer
    holds that also lies in a finer one is there, bitwise, and the finer one adds only rocks
    the coarse layer cannot resolve."""
    model = RockModel.from_spec("viper-high:dmin=0.02")
    craters = _craters()
    layers = [((-200.0, -200.0, 200.0, 200.0), 0.5), ((-100.0, -100.0, 100.0, 100.0), 0.25),
              ((-50.0, -50.0, 50.0, 50.0), 0.125)]
    tables = [model.generate(9, ext, min_diameter=2 * res, craters=craters, margin=False)
              for ext, res in layers]
    for (ext, res), coarse, fine in zip(layers[1:], tables, tables[1:], strict=False):
        xmin, ymin, xmax, ymax = ext
        sel = ((coarse.x >= xmin) & (coarse.x <= xmax) & (coarse.y >= ymin)
               & (coarse.y <= ymax))
        assert sel.sum() > 5
        index = {u: i for i, u in enumerate(fine.uid.tolist())}
        for u, row in zip(coarse.uid[sel].tolist(), coarse.rows[sel], strict=True):
            assert np.array_equal(fine.rows[index[u]], row)
        new = ~np.isin(fine.uid, coarse.uid)
        assert np.all(fine.diameter[new] < 2 * layers[0][1] * (res / layers[1][1]) * 2)
    assert any(np.count_nonzero(t.diameter > 5.0) for t in tables)  # blocks beyond the plains


def test_chunks_of_a_rocky_tile_equal_the_full_run():
    """A tile cut into 3 x 3 chunks, rocks and block fields generated and stood on each chunk
    alone, gives the full run's heights bitwise and its catalogue exactly."""
    from terrain.core.tile import Window

    tile = synthesize_tile(257, resolution=0.5, relief=2.0, seed=4).tile
    x0, y0 = tile.transform.c, tile.transform.f
    craters = CraterTable.from_craters([Crater(x0 + 30.0, y0 - 40.0, 50.0, 0.0),
                                        Crater(x0 + 70.0, y0 - 70.0, 80.0, 0.02)])
    model = RockModel.from_spec("viper-high:dmin=1.0")
    full, cat = add_rocks(tile, model, seed=2, craters=craters)
    assert len(cat) > 30
    ids = []
    for r0 in (0, 85, 170):
        for c0 in (0, 85, 170):
            w = Window(c0, r0, 87 if c0 == 170 else 85, 87 if r0 == 170 else 85)
            part, pcat = add_rocks(tile, model, seed=2, craters=craters, window=w)
            np.testing.assert_array_equal(
                part.heights, full.heights[w.row:w.row + w.height, w.col:w.col + w.width])
            ids += pcat.id.tolist()
    assert sorted(ids) == sorted(cat.id.tolist())


def test_every_terrain_preset_names_a_rock_model_that_exists():
    from terrain.core.presets import PRESETS

    for p in PRESETS.values():
        assert RockModel.from_spec(f"{p.rock_model}:dmin=0.1").model == p.rock_model


def test_the_command_lines_model_names_are_the_libraries():
    from terrain.stages.specs import ROCK_MODELS
    from terrain.surface.rocks import MODELS

    assert sorted(ROCK_MODELS) == sorted(MODELS)


@pytest.mark.parametrize("name", ["viper-low", "viper-nominal", "viper-high"])
def test_a_viper_model_reads_back_from_its_own_record(name):
    """A stack records its rock model as plain data (with the law's a and b filled in); the
    record must rebuild the same model (the hazard report does), and only another law is
    refused."""
    from terrain.core.errors import InvalidParameterError
    from terrain.surface.rocks import RockModel

    model = RockModel.from_spec(f"{name}:dmin=0.1")
    assert RockModel.from_mapping(model.as_dict()) == model
    with pytest.raises(InvalidParameterError, match="fixed by"):
        RockModel.from_mapping(dict(model.as_dict(), a=1.0))
