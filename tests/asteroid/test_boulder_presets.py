"""Measured boulder populations: index and density of what is drawn, from the recipe."""

from __future__ import annotations

import math

import numpy as np
import pytest

from asteroid.boulder_presets import MEASURED
from asteroid.recipe import Recipe, parse_spec
from asteroid.sphere import SphereMesh
from asteroid.surface import BOULDER_SITE_STREAM, sample_sites


@pytest.mark.parametrize("name", sorted(MEASURED))
def test_sfd_index_and_density_over_a_decade(name):
    k, n_ref, d_ref = MEASURED[name]
    recipe = Recipe.from_sources(base="perlin", magnitude=8, radius=1000.0, seed=1,
                                 boulders=parse_spec(name, "boulders"))
    population = recipe.boulders.population(1.0)
    assert population.dmin == d_ref and population.dmax >= 10 * d_ref
    # a large area: a 40 km body holds ~20 km^2 ... 2e4 km^2 of surface
    radius = 40_000.0 if n_ref < 100 else 8_000.0
    mesh = SphereMesh(32)
    sites = sample_sites(mesh.directions() * radius, mesh.faces(), population, seed=5,
                         stream=BOULDER_SITE_STREAM)
    area_km2 = 4 * math.pi * (radius / 1000.0) ** 2 * 0.999
    d = sites.diameters
    # density at or above d_ref against the measured one (Poisson, 5 sigma)
    expected = n_ref * area_km2
    assert abs(len(d) - expected) < 5 * math.sqrt(expected)
    # maximum-likelihood index of the sizes within one decade, [d_ref, 10 d_ref)
    sel = d[d < 10 * d_ref]
    r = 10.0 ** k
    # truncated Pareto MLE: solve 1/|k| - ln(10) r / (1 - r) = mean ln(D / d_ref) for k
    mean_log = float(np.mean(np.log(sel / d_ref)))

    def score(kk):
        rr = 10.0 ** kk
        return -1.0 / kk - math.log(10.0) * rr / (1.0 - rr) - mean_log

    lo, hi = -6.0, -1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if score(lo) * score(mid) <= 0:
            hi = mid
        else:
            lo = mid
    assert len(sel) > 2000
    assert abs(0.5 * (lo + hi) - k) < 0.1, (name, 0.5 * (lo + hi), r)


def test_shapes_near_the_measured_axis_ratios():
    recipe = Recipe.from_sources(base="perlin", magnitude=8, radius=1000.0, seed=1,
                                 boulders=parse_spec("itokawa,dmin=2", "boulders"))
    s = recipe.boulders.settings
    e = 0.5 * sum(s.elongation)
    f = 0.5 * sum(s.flattening)
    # axes (sqrt(e), 1/sqrt(e), f): a : b : c against 2 : 1.4 : 1 (Michikami et al. 2010)
    a, b, c = math.sqrt(e), 1 / math.sqrt(e), f
    assert b / a == pytest.approx(0.7, abs=0.05) and c / a == pytest.approx(0.5, abs=0.05)
    assert recipe.boulders.dmin == 2.0
