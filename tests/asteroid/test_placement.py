"""Feature counts from the power law and uniform positions on the sphere."""

import numpy as np
import pytest
from scipy import stats

from asteroid.boulders import icosahedron
from asteroid.placement import expected_counts, sample, uniform_directions
from terrain.core.rng import uniform
from terrain.craters.population import Population


def _icosahedron_cells(directions):
    """Index of the nearest icosahedron face centre: 20 cells of equal area (symmetry)."""
    v, f = icosahedron()
    centres = v[f].mean(axis=1)
    centres /= np.linalg.norm(centres, axis=1)[:, None]
    return np.argmax(directions @ centres.T, axis=1)


def _chi_square_p(directions):
    counts = np.bincount(_icosahedron_cells(directions), minlength=20)
    return stats.chisquare(counts).pvalue


def test_positions_are_uniform_over_equal_area_cells():
    n = 200_000
    u = uniform(11, 5, 0, np.arange(n), np.arange(2)[:, None])
    ours = uniform_directions(u[0], u[1])
    assert _chi_square_p(ours) > 0.01
    # the paper's eqs. 1-2 normalise a point uniform in a cube: they crowd the cube's
    # corners, eight of the twenty cells' centres (the test sees it at once)
    cube = np.stack([u[0] - 0.5, u[1] - 0.5, uniform(11, 6, 0, np.arange(n), 0) - 0.5], axis=1)
    cube /= np.linalg.norm(cube, axis=1)[:, None]
    assert _chi_square_p(cube) < 1e-12


def test_uniform_in_latitude_bands_too():
    # equal-area latitude bands: |sin(lat)| uniform; and longitudes uniform
    pop = Population(dmin=1.0, dmax=2.0, density=1e4)
    p = sample(pop, 4 * np.pi * 1e6, seed=4, stream="test")
    assert len(p) > 90_000
    z = p.directions[:, 2]
    assert stats.kstest(z, "uniform", args=(-1, 2)).pvalue > 0.01
    assert stats.kstest(p.longitude, "uniform", args=(0, 2 * np.pi)).pvalue > 0.01
    lat_counts = np.histogram(np.sin(p.latitude), bins=10, range=(-1, 1))[0]
    assert stats.chisquare(lat_counts).pvalue > 0.01


def test_counts_and_diameters_follow_the_power_law():
    pop = Population(dmin=5.0, dmax=160.0, density=400.0, sfd_exponent=-2.0, max_age=3.5)
    area = 4 * np.pi * 3000.0**2
    p = sample(pop, area, seed=8, stream="test")
    expected = expected_counts(pop, area)
    assert expected.sum() == pytest.approx(pop.expected_count(area / 1e6))
    counts = np.bincount(p.size_class, minlength=len(expected))
    # Poisson counts: within 4 sigma of the mean in every bin
    assert np.all(np.abs(counts - expected) < 4 * np.sqrt(expected) + 1)
    # diameters: the truncated power law's CDF
    lo, hi, k = 5.0, 160.0, -2.0

    def cdf(d):
        return (lo**k - d**k) / (lo**k - hi**k)

    assert stats.kstest(p.diameters, cdf).pvalue > 0.01
    assert p.ages.min() >= 0 and p.ages.max() <= 3.5
    assert len(np.unique(p.uid)) == len(p)


def test_the_list_is_a_function_of_the_seed_and_stream():
    pop = Population(dmin=5.0, dmax=40.0, density=100.0)
    a = sample(pop, 1e8, seed=1, stream="asteroid-crater")
    b = sample(pop, 1e8, seed=1, stream="asteroid-crater")
    c = sample(pop, 1e8, seed=1, stream="asteroid-boulder")
    assert np.array_equal(a.directions, b.directions) and np.array_equal(a.uid, b.uid)
    assert not np.array_equal(a.uid[:10], c.uid[:10])
    # a wider range adds bins but leaves the existing bins' features where they were
    wider = sample(Population(dmin=5.0, dmax=80.0, density=100.0), 1e8, seed=1,
                   stream="asteroid-crater")
    first = a.size_class == 0
    assert np.array_equal(wider.directions[wider.size_class == 0], a.directions[first])


def test_a_population_too_large_is_refused():
    from terrain.core.errors import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="more than the limit"):
        sample(Population(dmin=0.01, dmax=1.0, density=1e9), 1e12, seed=1, stream="x",
               max_features=1000)
