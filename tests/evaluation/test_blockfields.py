"""Fresh craters' block fields: the published calibration, and the rocks split by place.

The references come from outside the code under test: Linne's 12,000 boulders >= 4.4 m
(Pajola et al. 2019), Bart and Melosh's largest boulder 0.29 Dc^0.66 m, and rocks drawn
here with numpy from the VIPER law and from a block field of known size around one crater.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from affine import Affine

from evaluation import lunar_stats as ls
from evaluation.blockfields import (
    BlockSite,
    FreshCraters,
    expected_blocks,
    footprint_area,
    in_footprints,
)
from evaluation.validate import block_field_check, rock_sfd_check

WIDE = (-1e5, -1e5, 1e5, 1e5)


def test_a_linne_sized_crater_in_rock_holds_linnes_blocks():
    """Dc 2.2 km, excavating rock only (a thin regolith), fresh: 12,000 blocks >= 4.4 m."""
    site = BlockSite(regolith_m=1e-6)
    linne = FreshCraters.from_columns([0.0], [0.0], [2200.0], [0.0], site)
    assert expected_blocks(linne, site, WIDE, 4.4) == pytest.approx(12000.0, rel=1e-3)
    # cumulative index -4.03: ten times fewer blocks per 1.77x in size
    ratio = expected_blocks(linne, site, WIDE, 4.4 * 10 ** (1 / 4.03)) / 12000.0
    assert ratio == pytest.approx(0.1, rel=0.01)


@pytest.mark.parametrize("dc", [200.0, 500.0, 1000.0])
def test_the_largest_block_follows_bart_and_melosh(dc):
    """The size of which one block is expected, for a crater in rock: 0.29 Dc^0.66 m within
    5 % (Bart and Melosh 2010, 18 craters)."""
    site = BlockSite(regolith_m=1e-6)
    c = FreshCraters.from_columns([0.0], [0.0], [dc], [0.0], site)
    assert c.largest[0] == pytest.approx(0.29 * dc ** 0.66, rel=0.05)


def test_old_and_shallow_craters_have_no_field():
    """A 60 m crater stays in a 10 m regolith (0.1 Dc < 10 m); a 1 Gyr crater's blocks are
    gone (2^-(1/0.06) < 1e-3); a 100 Myr crater keeps 2^(-0.1/0.06) = 31 % of them."""
    site = BlockSite(regolith_m=10.0)
    c = FreshCraters.from_columns([0, 0, 0, 0], [0, 0, 0, 0], [60.0, 400.0, 400.0, 400.0],
                                  [0.0, 1.0, 0.1, 0.0], site)
    assert len(c) == 2
    young, fresh = c.survival
    assert young / fresh == pytest.approx(2 ** (-0.1 / 0.06))
    assert len(FreshCraters.from_columns([0], [0], [400.0], [0.0],
                                         BlockSite(10.0, enabled=False))) == 0


def test_the_share_of_a_field_inside_a_layer_follows_its_radial_law():
    """Uniform inside the rim, r^-3 to two radii: half the blocks inside the rim (pi R^2
    against 2 pi R^2 (1 - 1/2)), and a half-plane holds half of everything."""
    site = BlockSite(regolith_m=1e-6)
    c = FreshCraters.from_columns([0.0], [0.0], [200.0], [0.0], site)
    total = expected_blocks(c, site, WIDE, 1.0)
    rim = 100.0 / math.sqrt(2.0)  # the square inscribed in the rim holds 2/pi of its disc
    assert expected_blocks(c, site, (-rim, -rim, rim, rim), 1.0) / total == pytest.approx(
        0.5 * 2 / math.pi, rel=0.01)
    assert expected_blocks(c, site, (0.0, -1e5, 1e5, 1e5), 1.0) / total == pytest.approx(
        0.5, rel=0.01)


def test_footprints_are_discs_of_reach_radii_counted_once():
    site = BlockSite(regolith_m=1e-6, reach=2.0)
    two = FreshCraters.from_columns([0.0, 0.0], [0.0, 0.0], [100.0, 100.0], [0.0, 0.0], site)
    assert footprint_area(two, site, (-300, -300, 300, 300)) == pytest.approx(
        math.pi * 100.0**2, rel=0.01)
    assert in_footprints(two, site, [99.0, 101.0], [0.0, 0.0]).tolist() == [True, False]


# ------------------------------------------------- a layer holding background and one field


CRATER = dict(x=0.0, y=0.0, d=300.0, age=0.03)  # excavates rock below 10 m of regolith


def _cover_size(k, top, footprint_m2, cover=0.1):
    """Size d at which blocks of d..top (N(>=d) = k d^-4.03) cover ``cover`` of the footprint,
    by numerical quadrature of the area under them."""
    d = np.geomspace(0.01, top, 20000)
    n = k * d**-4.03
    # area under blocks of d and more: sum of pi x^2 / 4 over the blocks between d and top
    mid = np.sqrt(d[1:] * d[:-1])
    shells = math.pi * mid**2 / 4 * (n[:-1] - n[1:])
    covered = np.concatenate([np.cumsum(shells[::-1])[::-1], [0.0]])
    return float(np.interp(-cover * footprint_m2, -covered, d))


def _field_stack(block_scale=1.0, *, seed=3, with_catalog=True):
    """One 5 cm layer 1 km wide (complete from 0.1 m): VIPER nominal background, and a
    fresh 300 m crater at its centre whose blocks are drawn here from the published law.

    The blocks: N(>=d) = 12,000 s (d / d_ref)^-4.03 with d_ref = 4.4 m (300 / 2200)^0.66,
    s = (1 - 10 / 30)^2, thinned by 2^(-0.03 / 0.06), drawn from the size at which they cover
    10 % of the footprint to the size of which one is expected, placed uniformly inside the
    rim and as r^-3 out to two radii.
    """
    rng = np.random.default_rng(seed)
    a, b = ls.VIPER_ROCK_MODELS["nominal"]
    half = 500.0
    n = rng.poisson(a * (0.1**b - 5.0**b) * (2 * half) ** 2)
    d_bg = (0.1**b - rng.random(n) * (0.1**b - 5.0**b)) ** (1.0 / b)
    x_bg, y_bg = rng.uniform(-half, half, (2, n))
    s = (1.0 - 10.0 / (0.1 * CRATER["d"])) ** 2
    k = 12000.0 * s * (4.4 * (CRATER["d"] / 2200.0) ** 0.66) ** 4.03
    top = k ** (1.0 / 4.03)
    lo = _cover_size(k, top, math.pi * CRATER["d"] ** 2)
    n_blocks = rng.poisson(block_scale * 2 ** (-CRATER["age"] / 0.06) * (k * lo**-4.03 - 1.0))
    d_bl = (lo**-4.03 - rng.random(n_blocks) * (lo**-4.03 - top**-4.03)) ** (1.0 / -4.03)
    u = rng.random(n_blocks)
    radius = CRATER["d"] / 2
    r = np.where(u < 0.5, radius * np.sqrt(u / 0.5), radius / (1.0 - (u - 0.5)))
    th = rng.uniform(0.0, 2 * math.pi, n_blocks)
    x_bl, y_bl = r * np.cos(th), r * np.sin(th)
    inside = (np.abs(x_bl) <= half) & (np.abs(y_bl) <= half)
    rocks = SimpleNamespace(x_m=np.concatenate([x_bg, x_bl[inside]]),
                            y_m=np.concatenate([y_bg, y_bl[inside]]),
                            diameter_m=np.concatenate([d_bg, d_bl[inside]]),
                            layer=np.zeros(n + int(inside.sum()), int))
    tile = SimpleNamespace(shape=(20000, 20000), resolution=0.05,
                           transform=Affine(0.05, 0.0, -half, 0.0, -0.05, half))
    catalog = SimpleNamespace(x_m=np.array([CRATER["x"]]), y_m=np.array([CRATER["y"]]),
                              diameter_m=np.array([CRATER["d"]]),
                              age_gyr=np.array([CRATER["age"]])) if with_catalog else None
    return SimpleNamespace(tiles=[tile], rocks=rocks, catalog=catalog,
                           info={"rocks": {"regolith_m": 10.0, "reach": 2.0}})


def test_background_and_block_field_are_each_judged_against_what_they_were_drawn_from():
    """Outside the crater's footprint the rocks are the VIPER law; inside they are the law
    plus the blocks the catalogue and the calibration expect; both checks pass. Judged as
    one population against the background law, the same rocks fail (the field is no
    excess)."""
    stack = _field_stack()
    bg, figures = rock_sfd_check(stack, "south-polar")
    assert bg.status == "pass", bg
    assert "outside fresh craters' block fields" in bg.name
    fields = block_field_check(stack, "south-polar", figures)
    assert fields.status == "pass", fields
    row = next(r for r in figures["rows"] if r["diameter_m"] >= 1.0)
    assert row["field_area_m2"] == pytest.approx(math.pi * 300.0**2, rel=0.01)
    assert row["expected_blocks"] > 10 * row["field_background_count"]  # blocks dominate
    merged, _ = rock_sfd_check(_field_stack(with_catalog=False), "south-polar")
    assert merged.status == "fail" and "times the model" in merged.meaning


def test_three_times_the_blocks_fail_the_field_check_but_not_the_background():
    stack = _field_stack(block_scale=3.0)
    bg, figures = rock_sfd_check(stack, "south-polar")
    assert bg.status == "pass", bg
    fields = block_field_check(stack, "south-polar", figures)
    assert fields.status == "fail" and "background plus blocks" in fields.meaning
    assert fields.value > 1.0  # about twice the expected count at every size


def test_the_generators_block_field_matches_the_published_expectation():
    """Blocks the rock model draws around a fresh 400 m crater in a 10 m regolith, counted at
    1 and 2 m: within Poisson scatter (3 sigma) of the calibration's expectation."""
    from terrain.craters.catalog import CraterTable
    from terrain.surface.rocks import RockModel

    model = RockModel.from_spec("viper-nominal:dmin=0.5,regolith_m=10")
    craters = CraterTable(x=np.array([0.0]), y=np.array([0.0]), diameter=np.array([400.0]),
                          age=np.array([0.01]), uid=np.array([1], np.uint64),
                          size_class=np.array([0]))
    extent = (-300.0, -300.0, 300.0, 300.0)
    with_fields = model.generate(5, extent, min_diameter=1.0, craters=craters, margin=False)
    background = model.generate(5, extent, min_diameter=1.0, margin=False)
    site = BlockSite(regolith_m=10.0)
    fresh = FreshCraters.from_columns([0.0], [0.0], [400.0], [0.01], site)
    for d in (1.0, 2.0):
        blocks = int(np.sum(with_fields.diameter >= d)) - int(np.sum(background.diameter >= d))
        want = expected_blocks(fresh, site, extent, d)
        assert abs(blocks - want) < 3 * math.sqrt(want), (d, blocks, want)
