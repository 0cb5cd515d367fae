"""Position-keyed randomness: a pure function of (seed, stream, level, position, counter)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from terrain.core import rng

MASK = 2**64 - 1


def _mix(z):
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def reference_hash(seed, stream, level, ix, iy, k):
    """Independent pure-Python implementation of the documented hash."""
    h = 0x243F6A8885A308D3
    for word in (seed, stream, level, k, ix, iy):
        h = _mix(((h ^ (word & MASK)) + 0x9E3779B97F4A7C15) & MASK)
    return h


@given(seed=st.integers(0, rng.MAX_SEED), stream=st.integers(0, rng.MAX_SEED),
       level=st.integers(-5, 60), ix=st.integers(-2**40, 2**40), iy=st.integers(-2**40, 2**40),
       k=st.integers(0, 2**32))
def test_hash_matches_reference(seed, stream, level, ix, iy, k):
    assert int(rng.hash64(seed, stream, level, ix, iy, k)) == reference_hash(
        seed, stream, level, ix, iy, k)


def test_uniform_and_normal_distributions():
    ix = np.arange(200_000)
    u = rng.uniform(7, rng.stream_id("test"), 0, ix, 3)
    g = rng.normal(7, rng.stream_id("test"), 0, ix, 3)
    assert np.all((u > 0) & (u < 1))
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    assert stats.kstest(g, "norm").pvalue > 1e-3
    # neighbouring positions are uncorrelated
    assert abs(np.corrcoef(g[:-1], g[1:])[0, 1]) < 0.01


def test_inverse_normal_cdf_accuracy():
    from scipy.special import ndtri

    p = np.concatenate([np.geomspace(1e-300, 0.5, 400), 1 - np.geomspace(1e-16, 0.5, 400)])
    ours = np.array([rng._ppnd16(v) for v in p])
    assert np.allclose(ours, ndtri(p), rtol=1e-14, atol=1e-14)


def test_tabulated_gaussian_matches_the_normal_quantiles():
    from scipy.special import ndtri

    u = np.concatenate([np.linspace(1e-6, 1 - 1e-6, 100_001), np.geomspace(1e-15, 1e-2, 500)])
    ours = np.array([rng.gaussian(v) for v in u])
    assert np.max(np.abs(ours - ndtri(u))) < 2e-4
    assert np.all(np.diff(ours[:100_001]) >= 0), "monotone in u"


def test_any_subset_draws_the_same_numbers():
    s = rng.stream_id("subset")
    full = rng.normal(1, s, 2, np.arange(-50, 50)[None, :], np.arange(-20, 20)[:, None])
    part = rng.normal(1, s, 2, np.arange(10, 13)[None, :], np.arange(-3, 4)[:, None])
    assert np.array_equal(full[17:24, 60:63], part)
    assert rng.normal_scalar(1, s, 2, 10, -3, 0) == full[17, 60]


def test_broadcast_keys_of_any_shape_and_size_draw_each_keys_own_deviate():
    """An image's worth (parallel rows), a 3-d broadcast and a 1-d run equal the scalars."""
    from terrain.core.parallel import limited

    s = rng.stream_id("broadcast")
    cols, rows = np.arange(-300, 300)[None, :], np.arange(0, 150)[:, None]
    image = rng.normal(5, s, 1, cols, rows, 3)
    with limited(1):
        assert np.array_equal(rng.normal(5, s, 1, cols, rows, 3), image)
    for i, j in ((0, 0), (149, 599), (77, 301)):
        assert image[i, j] == rng.normal_scalar(5, s, 1, int(cols[0, j]), int(rows[i, 0]), 3)
    cube = rng.uniform(5, s, 1, np.arange(4)[None, None, :], np.arange(3)[None, :, None],
                       np.arange(2)[:, None, None])
    assert cube.shape == (2, 3, 4)
    assert cube[1, 2, 3] == rng.uniform_scalar(5, s, 1, 3, 2, 1)
    run = rng.uniform(5, s, 1, np.arange(70_000), 9)
    assert run.shape == (70_000,) and run[69_999] == rng.uniform_scalar(5, s, 1, 69_999, 9, 0)
    assert rng.uniform(5, s, 1, np.arange(0), 9).shape == (0,)
    assert rng.normal(5, s, 1, 4, 9).shape == ()


def test_keys_separate_streams_levels_and_seeds():
    base = rng.uniform(1, 2, 3, np.arange(1000), 0)
    for other in (rng.uniform(2, 2, 3, np.arange(1000), 0),
                  rng.uniform(1, 3, 3, np.arange(1000), 0),
                  rng.uniform(1, 2, 4, np.arange(1000), 0),
                  rng.uniform(1, 2, 3, np.arange(1000), 1),
                  rng.uniform(1, 2, 3, np.arange(1000), 0, k=1)):
        assert abs(np.corrcoef(base, other)[0, 1]) < 0.1
        assert not np.any(base == other)


@pytest.mark.parametrize("bad", [-1, 2**63, 1.5, "3", True, None])
def test_bad_seeds_are_refused(bad):
    with pytest.raises(ValueError, match="seed"):
        rng.check_seed(bad)


@settings(max_examples=200, deadline=None)
@given(st.floats(1e-6, 1 - 1e-6), st.sampled_from([0.5, 8.0, 16.0, 120.0, 499.0]))
def test_poisson_is_the_inverse_cdf_scipy_gives(u, lam):
    k = rng.poisson(u, lam)
    # the smallest count whose CDF reaches u (allowing for rounding at the step)
    assert stats.poisson.cdf(k, lam) >= u - 1e-9
    assert k == 0 or stats.poisson.cdf(k - 1, lam) <= u + 1e-9


@settings(max_examples=100, deadline=None)
@given(st.floats(0.01, 0.99), st.sampled_from([600.0, 5000.0]))
def test_poisson_of_a_large_mean_is_close_to_the_exact_quantile(u, lam):
    # the normal approximation's quantile error is about one count at these means
    assert abs(rng.poisson(u, lam) - stats.poisson.ppf(u, lam)) <= 2
