"""Two-phase Poisson faulting: the faults, their sum, smoothing, seamless subsets."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from asteroid.body import Stretch
from asteroid.faulting import FIG8_FAULTING, TRUNCATION, Faulting, fault_table
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError

MESH = SphereMesh(20)


def test_fault_table_statistics():
    normals, heights = fault_table(seed=4, phase=1, count=20000, max_size=5.0)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    # great circles uniformly oriented: normal components average to 0, z^2 to 1/3
    assert np.abs(normals.mean(axis=0)).max() < 0.02
    assert np.mean(normals[:, 2] ** 2) == pytest.approx(1 / 3, abs=0.01)
    # "faults up to 5 m": Gaussian, sigma = S / 3, truncated at S
    assert np.abs(heights).max() <= 5.0
    assert heights.std() == pytest.approx(5.0 / TRUNCATION * 0.9866, rel=0.03)
    assert abs(heights.mean()) < 0.05
    # keyed: a later batch of the same phase equals the tail of a longer table
    n2, h2 = fault_table(seed=4, phase=1, count=100, max_size=5.0, start=19900)
    assert np.array_equal(h2, heights[19900:]) and np.array_equal(n2, normals[19900:])


def test_sum_of_faults_matches_a_direct_evaluation():
    f = Faulting(faults=300, max_fault=2.0, passes=0, filter_width=0.0, fine_faults=200,
                 fine_max_fault=0.1)
    r = f.radii(MESH, 50.0, seed=11)
    u = MESH.directions()
    expected = np.full(MESH.n_vertices, 50.0)
    for phase, count, size in ((1, 300, 2.0), (2, 200, 0.1)):
        normals, heights = fault_table(11, phase, count, size)
        expected += ((u @ normals.T) > 0) @ heights     # one side of each great circle rises
    assert np.allclose(r, expected, rtol=0, atol=1e-9)


@settings(max_examples=10)
@given(st.lists(st.integers(0, MESH.n_vertices - 1), min_size=1, max_size=30),
       st.sampled_from([None, Stretch(2.0, 1.0, 1.0), Stretch(0.7, 1.3, 1.0)]))
def test_subset_equals_the_whole(indices, stretch):
    f = Faulting(faults=120, max_fault=3.0, passes=2, filter_width=15.0, fine_faults=60,
                 fine_max_fault=0.2)
    whole = f.radii(MESH, 100.0, seed=5, stretch=stretch)
    part = f.radii(MESH, 100.0, seed=5, stretch=stretch, vertices=np.array(indices))
    assert np.array_equal(whole[indices], part)


def test_smoothing_leaves_an_undulating_surface():
    rough = Faulting(faults=500, max_fault=3.0, passes=0, fine_faults=0)
    smooth = Faulting(faults=500, max_fault=3.0, passes=3, filter_width=40.0, fine_faults=0)
    mesh = SphereMesh(40)
    a = rough.radii(mesh, 100.0, seed=2)
    b = smooth.radii(mesh, 100.0, seed=2)
    faces = mesh.faces()

    def step(r):
        return np.abs(r[faces[:, 0]] - r[faces[:, 1]]).mean()

    assert step(b) < 0.3 * step(a)                     # high frequencies removed
    assert np.std(b) > 0.5 * np.std(a)                 # the large lumps stay


def test_stretch_elongates_the_body():
    f = Faulting(faults=50, max_fault=1.0, passes=1, filter_width=10.0, fine_faults=0)
    r = f.radii(MESH, 100.0, seed=3, stretch=Stretch(2.0, 1.0, 1.0))
    d = MESH.directions()
    along_x = r[np.abs(d[:, 0]) > 0.99].mean()
    along_z = r[np.abs(d[:, 2]) > 0.99].mean()
    assert along_x / along_z == pytest.approx(2.0, rel=0.15)


@pytest.mark.parametrize("seed", [0, 3, 4, 8])
def test_the_papers_faulting_relief_is_dominated_by_the_coarse_phase(seed):
    """Fig. 8's two phases as the paper describes them: the coarse faults shape the body
    (radii spread by more than a factor 1.5 on a 2:1:1 body) and the fine phase only
    roughens it (it moves no vertex by more than a few per cent of the coarse relief); the
    body stays star-shaped (every radius positive)."""
    mesh = SphereMesh(12)
    stretch = Stretch(2, 1, 1)
    both = FIG8_FAULTING.radii(mesh, 100.0, seed=seed, stretch=stretch)
    coarse = replace(FIG8_FAULTING, fine_faults=0).radii(mesh, 100.0, seed=seed,
                                                         stretch=stretch)
    assert np.all(both > 0) and both.max() / both.min() > 1.5
    assert np.abs(both - coarse).max() < 0.05 * (coarse.max() - coarse.min())


def test_bad_faulting_input():
    with pytest.raises(InvalidParameterError, match=r"faulting faults must lie in \[0, inf\]"):
        Faulting(faults=-1)
    with pytest.raises(InvalidParameterError, match="faulting max_fault must be finite"):
        Faulting(max_fault=float("nan"))
    with pytest.raises(InvalidParameterError, match="radius reach zero"):
        Faulting(faults=200, max_fault=300.0, passes=0, fine_faults=0).radii(
            SphereMesh(6), 10.0, seed=1)
