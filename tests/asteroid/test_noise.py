"""Perlin-noise bases: seamless subsets, statistics, band control."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from asteroid.body import Stretch
from asteroid.noise import FIG5_PRESETS, Band, PerlinNoise, perlin3
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import key_prefix

MESH = SphereMesh(24)


@given(st.lists(st.integers(0, MESH.n_vertices - 1), min_size=1, max_size=40),
       st.integers(0, 2**40))
def test_any_subset_equals_the_whole(indices, seed):
    noise = PerlinNoise(octaves=5, amplitude=0.2)
    whole = noise.radii(MESH, 800.0, seed=seed)
    part = noise.radii(MESH, 800.0, seed=seed, vertices=np.array(indices))
    assert np.array_equal(whole[indices], part)


def test_subset_equals_whole_with_stretch_and_overrides():
    noise = FIG5_PRESETS["fig5-rugged"]
    s = Stretch(1.5, 1.0, 0.8)
    whole = noise.radii(MESH, 100.0, seed=9, stretch=s)
    idx = np.arange(3, MESH.n_vertices, 11)
    assert np.array_equal(whole[idx], noise.radii(MESH, 100.0, seed=9, stretch=s, vertices=idx))


def test_same_seed_same_values_other_seed_other_values():
    noise = PerlinNoise(octaves=3)
    a = noise.radii(MESH, 1.0, seed=1)
    assert np.array_equal(a, noise.radii(MESH, 1.0, seed=1))
    assert not np.array_equal(a, noise.radii(MESH, 1.0, seed=2))


def test_gradient_noise_properties():
    prefix = key_prefix(3, 77, 0, 0)
    # zero at the lattice points
    for p in [(0, 0, 0), (3, -2, 5), (-7, 1, 1)]:
        assert perlin3(prefix, *map(float, p)) == 0.0
    rng = np.random.default_rng(2)
    pts = rng.uniform(-40, 40, (20000, 3))
    v = np.array([perlin3(prefix, *p) for p in pts])
    assert np.abs(v).max() <= 1.05                  # improved Perlin noise stays within ~1
    assert abs(v.mean()) < 0.01 and 0.2 < v.std() < 0.35
    # continuous: a tiny step changes the value a little
    w = np.array([perlin3(prefix, *(p + 1e-6)) for p in pts[:200]])
    assert np.abs(w - v[:200]).max() < 1e-4


def test_amplitude_sets_the_relief_and_bands_override():
    mesh = SphereMesh(40)
    base = PerlinNoise(octaves=1, frequency=2.0, amplitude=0.1)
    r = base.radii(mesh, 1000.0, seed=5)
    assert 0.015 < np.std(r / 1000.0 - 1.0) < 0.05
    silenced = PerlinNoise(octaves=1, frequency=2.0, amplitude=0.1,
                           bands=(Band(0, amplitude=0.0),))
    assert np.all(silenced.radii(mesh, 1000.0, seed=5) == 1000.0)
    assert base.band_frequencies().tolist() == [2.0]
    multi = PerlinNoise(octaves=4, frequency=1.0, persistence=0.5, lacunarity=2.0,
                        amplitude=0.2, bands=(Band(2, frequency=10.0),))
    assert multi.band_frequencies().tolist() == [1.0, 2.0, 10.0, 8.0]
    assert np.allclose(multi.band_amplitudes(), [0.2, 0.1, 0.05, 0.025])


def test_higher_frequency_is_rougher():
    mesh = SphereMesh(40)
    n = mesh.neighbours(5000)

    def roughness(freq):
        r = PerlinNoise(octaves=1, frequency=freq, amplitude=0.1).radii(mesh, 1.0, seed=3)
        return np.abs(r[n] - r[5000]).mean(), r

    low, _ = roughness(1.0)
    high, _ = roughness(16.0)
    assert high > 3 * low


@settings(max_examples=6)
@given(st.integers(0, 2**40))
def test_fig5_smooth_is_the_smoothest_look_and_every_look_stays_a_lumpy_ball(seed):
    """The three Fig. 5 looks as a reader sees them: ``fig5-smooth`` has the least relief
    from vertex to vertex (mean |dr| along mesh edges at least 1.3 times below both others),
    and every look is a lumpy ball, not a sphere and not a shard (radii within 0.5-1.5 R, a
    few per cent of R rms relief)."""
    mesh = SphereMesh(32)
    faces = mesh.faces()
    edge_relief = {}
    for name, noise in FIG5_PRESETS.items():
        r = noise.radii(mesh, 1000.0, seed=seed) / 1000.0
        assert 0.5 < r.min() and r.max() < 1.5, name
        assert 0.02 < r.std() < 0.2, name
        edge_relief[name] = np.abs(r[faces[:, 0]] - r[faces[:, 1]]).mean()
    smooth = edge_relief.pop("fig5-smooth")
    assert 1.3 * smooth < min(edge_relief.values()), edge_relief


def test_bad_parameters():
    with pytest.raises(InvalidParameterError, match="octaves"):
        PerlinNoise(octaves=0)
    with pytest.raises(InvalidParameterError, match="lacunarity"):
        PerlinNoise(lacunarity=1.0)
    with pytest.raises(InvalidParameterError, match="persistence"):
        PerlinNoise(persistence=1.5)
    with pytest.raises(InvalidParameterError, match="only 3 octaves"):
        PerlinNoise(octaves=3, bands=(Band(3, amplitude=0.1),))
    with pytest.raises(InvalidParameterError, match="reach zero"):
        PerlinNoise(octaves=1, amplitude=0.9, bands=(Band(0, amplitude=50.0),)).radii(
            SphereMesh(8), 1.0, seed=0)
