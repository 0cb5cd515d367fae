"""Crater populations: the power law, uniform positions and ages, seamless generation."""

import numpy as np
import pytest
from scipy import stats

from terrain.core.errors import InvalidParameterError
from terrain.craters.population import Population

EXTENT = (0.0, 0.0, 4000.0, 4000.0)  # 16 km^2


def truncated_power_law_cdf(k, d_lo, d_hi):
    def cdf(d):
        return (d_lo**k - np.asarray(d) ** k) / (d_lo**k - d_hi**k)
    return cdf


@pytest.mark.parametrize("k", [-2.0, -1.8, -3.0])
def test_diameters_follow_the_requested_power_law(k):
    pop = Population(dmin=5.0, dmax=300.0, density=400.0, sfd_exponent=k)
    craters = pop.generate(11, EXTENT)
    # KS test against the truncated cumulative power law N_cum = c D^k on [dmin, dmax)
    ks = stats.kstest(craters.diameter, truncated_power_law_cdf(k, pop.dmin, pop.dmax))
    assert ks.pvalue > 1e-3, ks
    assert craters.diameter.min() >= pop.dmin and craters.diameter.max() < pop.dmax
    # the count matches N_cum(dmin) - N_cum(dmax) per km^2 (eq. 12) within Poisson noise
    expected = pop.expected_count(16.0)
    assert abs(len(craters) - expected) < 5 * np.sqrt(expected)


def test_density_means_craters_at_least_dmin_per_km2():
    pop = Population(dmin=10.0, dmax=1e6, density=50.0)
    assert pop.cumulative(10.0) == pytest.approx(50.0)
    assert pop.cumulative(20.0) == pytest.approx(50.0 / 4)  # k = -2
    assert pop.expected_count(1.0) == pytest.approx(50.0 - pop.cumulative(1e6))


def test_positions_and_ages_are_uniform():
    pop = Population(dmin=5.0, dmax=40.0, density=600.0, max_age=3.2)
    c = pop.generate(5, EXTENT)
    assert stats.kstest(c.x, "uniform", args=(0, 4000)).pvalue > 1e-3
    assert stats.kstest(c.y, "uniform", args=(0, 4000)).pvalue > 1e-3
    assert stats.kstest(c.age, "uniform", args=(0, 3.2)).pvalue > 1e-3
    # no clumping on the generation cells: counts per 100 m square are Poisson
    counts, _, _ = np.histogram2d(c.x, c.y, bins=40, range=[[0, 4000], [0, 4000]])
    dispersion = counts.var() / counts.mean()
    assert 0.85 < dispersion < 1.15


def test_any_extent_enumerates_exactly_the_same_craters():
    pop = Population(dmin=4.0, dmax=200.0, density=300.0)
    full = pop.generate(3, (-1000.0, -1000.0, 3000.0, 3000.0))
    sub_extent = (250.5, -640.0, 1333.0, 77.0)
    part = pop.generate(3, sub_extent)
    inside = ((full.x >= 250.5) & (full.x <= 1333.0) & (full.y >= -640.0) & (full.y <= 77.0))
    key = np.lexsort((full.uid[inside],))
    key2 = np.lexsort((part.uid,))
    assert np.array_equal(full.uid[inside][key], part.uid[key2])
    assert np.array_equal(full.diameter[inside][key], part.diameter[key2])
    assert np.array_equal(full.x[inside][key], part.x[key2])
    assert len(np.unique(full.uid)) == len(full)


def test_same_seed_same_craters_other_seed_other_craters():
    pop = Population(dmin=4.0, dmax=100.0, density=300.0)
    a = pop.generate(1, EXTENT)
    b = pop.generate(1, EXTENT)
    c = pop.generate(2, EXTENT)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.diameter, b.diameter)
    assert len(a) != len(c) or not np.array_equal(a.x, c.x)


def test_octave_bins_cover_the_range():
    pop = Population(dmin=3.0, dmax=50.0, density=1.0)
    bins = pop.bins()
    assert bins[0, 0] == 3.0 and bins[-1, 1] == 50.0
    assert np.all(bins[1:, 0] == bins[:-1, 1])
    assert np.all(bins[:, 1] / bins[:, 0] <= 2.0 + 1e-12)


@pytest.mark.parametrize("kwargs, message", [
    (dict(dmin=10.0, dmax=5.0, density=1.0), "smaller than dmax"),
    (dict(dmin=0.0, dmax=5.0, density=1.0), "positive"),
    (dict(dmin=1.0, dmax=5.0, density=-1.0), "density"),
    (dict(dmin=1.0, dmax=5.0, density=1.0, sfd_exponent=1.0), "negative"),
    (dict(dmin=1.0, dmax=5.0, density=float("nan")), "finite"),
    (dict(dmin=1.0, dmax=5.0, density=1.0, max_age=-2.0), "max_age"),
])
def test_bad_populations_are_refused(kwargs, message):
    with pytest.raises(InvalidParameterError, match=message):
        Population(**kwargs)


def test_population_file(tmp_path):
    f = tmp_path / "pop.toml"
    f.write_text("[population]\ndmin = 2.0\ndmax = 64.0\ndensity = 10.0\nsfd_exponent = -1.8\n")
    pop = Population.from_toml(f, density=20.0)
    assert (pop.dmin, pop.dmax, pop.density, pop.sfd_exponent) == (2.0, 64.0, 20.0, -1.8)
    f.write_text("[population]\ndmin = 2.0\nbogus = 1\n")
    with pytest.raises(InvalidParameterError, match="bogus"):
        Population.from_toml(f)
    f.write_text("[population\n")
    with pytest.raises(InvalidParameterError, match="TOML"):
        Population.from_toml(f)


def test_a_request_too_large_for_memory_is_refused_before_allocating(monkeypatch):
    from terrain.core.errors import MemoryRequestError

    monkeypatch.setenv("CRATERSCAPE_MEMORY_LIMIT", "10M")
    pop = Population(dmin=1.0, dmax=100.0, density=1e6)
    with pytest.raises(MemoryRequestError, match="craters"):
        pop.generate(0, (0, 0, 1e5, 1e5))
