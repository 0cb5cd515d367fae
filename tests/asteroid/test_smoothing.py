"""The separable box filter on the mesh."""

import numpy as np
import pytest

from asteroid.smoothing import smooth
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError


def test_constant_field_is_unchanged_and_zero_width_is_identity(rng):
    mesh = SphereMesh(20)
    assert np.allclose(smooth(mesh, np.full(mesh.n_vertices, 3.5), width=0.3, passes=3), 3.5)
    noise = rng.normal(size=mesh.n_vertices)
    assert np.array_equal(smooth(mesh, noise, width=0.0, passes=2), noise)


def test_smoothing_removes_high_frequencies(rng):
    mesh = SphereMesh(40)
    noise = rng.normal(size=mesh.n_vertices)
    out = smooth(mesh, noise, width=0.2, passes=3)
    assert out.std() < 0.2 * noise.std()
    # a low-frequency field survives
    z = mesh.directions()[:, 2]
    assert np.abs(smooth(mesh, z, width=0.1, passes=3) - z).max() < 0.02


def test_footprint_is_about_the_width_everywhere():
    mesh = SphereMesh(40)
    d = mesh.directions()
    width = 0.3
    for i in (0, int(mesh.index_of(10, 3)), int(mesh.index_of(40, 100))):
        spike = np.zeros(mesh.n_vertices)
        spike[i] = 1.0
        out = smooth(mesh, spike, width=width, passes=1)
        reach = np.arccos(np.clip(d[out > 1e-12] @ d[i], -1, 1)).max()
        assert width / 2 <= reach <= width * 0.75 + 2 * np.pi / (2 * 40)


def test_rings_alone_equal_the_whole(rng):
    mesh = SphereMesh(30)
    field = rng.normal(size=mesh.n_vertices)
    whole = smooth(mesh, field, width=0.25, passes=3)
    rings = np.zeros(61, bool)
    rings[[0, 7, 31, 60]] = True
    part = smooth(mesh, field, width=0.25, passes=3, rings=rings)
    idx = np.flatnonzero(rings[mesh.ring_of(np.arange(mesh.n_vertices))[0]])
    assert np.array_equal(whole[idx], part[idx])


def test_bad_smoothing_parameters():
    mesh = SphereMesh(2)
    with pytest.raises(InvalidParameterError, match="width"):
        smooth(mesh, np.zeros(mesh.n_vertices), width=-1.0)
    with pytest.raises(InvalidParameterError, match="passes"):
        smooth(mesh, np.zeros(mesh.n_vertices), width=1.0, passes=-1)
