"""The 6M^2 + 2 latitude/longitude mesh: counts, index arithmetic, topology, spacing."""

import numpy as np
import pytest
import trimesh
from hypothesis import given
from hypothesis import strategies as st

from asteroid.sphere import SphereMesh, spacing_statistics
from terrain.core.errors import InvalidParameterError

MAGNITUDES = [1, 2, 3, 5, 8, 17, 40]


@pytest.mark.parametrize("m", MAGNITUDES)
def test_vertex_ring_and_face_counts(m):
    mesh = SphereMesh(m)
    assert mesh.n_vertices == 6 * m * m + 2 == len(mesh.directions())
    assert mesh.n_faces == 12 * m * m == len(mesh.faces())
    sizes = mesh.ring_sizes
    assert len(sizes) == 2 * m + 1 and sizes[0] == sizes[-1] == 1
    # ring L of each hemisphere has 6L vertices, the equator (ring M) is shared
    assert sizes[1:m + 1].tolist() == [6 * L for L in range(1, m + 1)]
    assert sizes[m:2 * m][::-1].tolist() == [6 * L for L in range(1, m + 1)]
    assert sizes.sum() == mesh.n_vertices


@pytest.mark.parametrize("m", MAGNITUDES)
def test_watertight_manifold_and_outward(m):
    mesh = SphereMesh(m)
    v, f = mesh.directions(), mesh.faces()
    tm = trimesh.Trimesh(v, f, process=False)
    assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    # every edge in exactly two triangles, once each way
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(edges, axis=0)) == len(edges)
    # Euler characteristic of a sphere
    n_edges = len(np.unique(np.sort(edges, axis=1), axis=0))
    assert mesh.n_vertices - n_edges + mesh.n_faces == 2
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area = np.linalg.norm(normals, axis=1)
    assert area.min() > 0.1 * area.mean()                       # no degenerate triangles
    assert np.all(np.einsum("ij,ij->i", normals, v[f].mean(axis=1)) > 0)   # outward


def test_rings_are_latitude_circles_with_even_longitudes():
    mesh = SphereMesh(6)
    lat, lon = mesh.latitude_longitude()
    rings, pos = mesh.ring_of(np.arange(mesh.n_vertices))
    assert np.allclose(lat, np.pi / 2 - np.pi * rings / 12)
    assert np.allclose(lon, 2 * np.pi * pos / mesh.ring_sizes[rings])
    d = mesh.directions()
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.allclose(d[:, 2], np.sin(lat))


@given(st.integers(1, 3000), st.data())
def test_index_arithmetic_round_trips(m, data):
    mesh = SphereMesh(m)
    i = data.draw(st.integers(0, mesh.n_vertices - 1))
    ring, pos = mesh.ring_of(i)
    assert 0 <= pos < mesh.ring_sizes[ring]
    assert int(mesh.index_of(ring, pos)) == i
    assert int(mesh.index_of(ring, pos + 5 * mesh.ring_sizes[ring])) == i


@pytest.mark.parametrize("m", [1, 2, 4, 9])
def test_neighbour_queries_match_the_triangulation(m):
    mesh = SphereMesh(m)
    f = mesh.faces()
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]),
                              axis=1), axis=0)
    adjacency = [set() for _ in range(mesh.n_vertices)]
    for a, b in edges:
        adjacency[a].add(b)
        adjacency[b].add(a)
    valence = []
    for i in range(mesh.n_vertices):
        got = mesh.neighbours(i)
        assert set(got.tolist()) == adjacency[i]
        valence.append(len(got))
    # six everywhere except the 6 equatorial corners of the bipyramid (valence 4)
    assert sorted(set(valence)) == [4, 6]
    assert valence.count(4) == 6


def test_along_and_across_rings():
    mesh = SphereMesh(5)
    i = int(mesh.index_of(3, 17))
    assert int(mesh.along(i, 1)) == int(mesh.index_of(3, 0))       # wraps east
    assert int(mesh.along(i, -18)) == i
    # across to the nearest longitude of the next ring, and over the pole
    j = int(mesh.across(i, 1))
    lat_i, lon_i = mesh.latitude_longitude(i)
    lat_j, lon_j = mesh.latitude_longitude(j)
    assert mesh.ring_of(j)[0] == 4
    assert abs(lon_j - lon_i) <= np.pi / mesh.ring_sizes[4] + 1e-12
    top = int(mesh.index_of(1, 0))
    over = int(mesh.across(top, -2))            # north pole, then ring 1 on the far side
    assert mesh.ring_of(over)[0] == 1
    assert np.isclose(mesh.latitude_longitude(over)[1], np.pi)


@pytest.mark.parametrize("m", [3, 16, 50])
def test_cap_query_lists_every_vertex_within_the_angle(m, rng):
    mesh = SphereMesh(m)
    d = mesh.directions()
    for _ in range(20):
        c = rng.normal(size=3)
        c /= np.linalg.norm(c)
        angle = rng.uniform(0.01, 2.5)
        got = mesh.cap(c, angle)
        assert len(np.unique(got)) == len(got)
        inside = np.flatnonzero(d @ c >= np.cos(angle))
        assert set(inside) <= set(got.tolist())
        extra = np.setdiff1d(got, inside)
        assert np.all(np.arccos(np.clip(d[extra] @ c, -1, 1)) <= angle + 1e-8)
    assert len(mesh.cap([0, 0, 1], np.pi)) == mesh.n_vertices


@pytest.mark.parametrize("m", [1, 4, 30])
def test_locate_and_surface_radius(m, rng):
    mesh = SphereMesh(m)
    u = rng.normal(size=(3000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    u = np.concatenate([u, mesh.directions()[:50], [[0, 0, 1], [0, 0, -1]]])
    tri, corners, w = mesh.locate(u)
    assert np.array_equal(mesh.faces()[tri], corners)
    assert w.min() > -1e-12                      # inside the triangle's cone
    d = mesh.directions()
    assert np.allclose(np.einsum("nk,nkj->nj", w, d[corners]), u)
    # on a sphere of radius 2 the flat-triangle surface lies between chord depth and 2
    r = mesh.surface_radius(np.full(mesh.n_vertices, 2.0), u)
    edge = spacing_statistics(mesh)["max"]
    assert r.max() <= 2.0 + 1e-12 and r.min() >= 2.0 * (1 - edge**2 / 2)
    # vertices are on the surface
    assert np.allclose(mesh.surface_radius(np.full(mesh.n_vertices, 2.0), d[:50]), 2.0)


def test_spacing_statistics_are_bounded_and_stated():
    # the docstring of asteroid.sphere states these figures
    ratios = {m: spacing_statistics(SphereMesh(m))["ratio"] for m in (1, 2, 16, 64)}
    assert ratios[1] == pytest.approx(1.414, abs=1e-3)
    assert ratios[2] == pytest.approx(1.701, abs=1e-3)
    assert ratios[16] == pytest.approx(2.027, abs=1e-3)
    assert ratios[64] == pytest.approx(2.111, abs=1e-3)
    assert max(ratios.values()) < 2.25
    s = spacing_statistics(SphereMesh(64))
    assert s["mean"] == pytest.approx(SphereMesh(64).mean_spacing, rel=0.05)


def test_directions_of_a_subset_equal_the_whole():
    mesh = SphereMesh(33)
    idx = np.array([0, 1, 100, 3000, mesh.n_vertices - 1])
    assert np.array_equal(mesh.directions(idx), mesh.directions()[idx])


@pytest.mark.parametrize("bad", [0, -3, 2.5, "7", True, None])
def test_bad_magnitude_is_refused(bad):
    with pytest.raises(InvalidParameterError, match="magnitude M must be an integer >= 1"):
        SphereMesh(bad)


@given(st.one_of(st.integers(-10**12, 10**12), st.floats(allow_nan=True), st.text(max_size=3),
                 st.none(), st.booleans()))
def test_any_magnitude_is_accepted_or_refused_cleanly(value):
    try:
        mesh = SphereMesh(value)
    except InvalidParameterError as exc:
        assert "magnitude M" in str(exc)
    else:
        assert mesh.magnitude >= 1 and mesh.n_vertices == 6 * mesh.magnitude**2 + 2


def test_bad_indices_are_refused():
    mesh = SphereMesh(2)
    with pytest.raises(InvalidParameterError, match="vertex indices must lie"):
        mesh.ring_of([26])
    with pytest.raises(InvalidParameterError, match="directions must be"):
        mesh.locate([[0.0, 0.0, 0.0]])
    with pytest.raises(InvalidParameterError, match="radii must be"):
        mesh.surface_radius(np.ones(5), [[1.0, 0, 0]])
