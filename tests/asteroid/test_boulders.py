"""Multi-resolution boulders: the RMD icosahedron, levels of detail, placement on the body."""

import math

import numpy as np
import pytest
import trimesh

from asteroid.body import Body
from asteroid.boulders import (
    BiResolutionNode,
    BoulderSettings,
    boulder_lod,
    icosahedron,
    lod_tree,
    place_boulders,
    subdivision,
)
from asteroid.catalog import BOULDER_COLUMNS
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError
from terrain.craters.population import Population


def test_icosahedron_is_regular():
    v, f = icosahedron()
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
    edges = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)
    assert np.allclose(edges, edges[0, 0])
    assert trimesh.Trimesh(v, f, process=False).is_volume


def test_levels_refine_without_moving_older_vertices():
    lod = boulder_lod(seed=3, uid=42, levels=5, diameter=2.0, flattening=0.6, elongation=1.3)
    faces, parents = subdivision(5)
    for level in range(5):
        v, f = lod.level(level)
        assert len(v) == 10 * 4**level + 2 and len(f) == 20 * 4**level
        tm = trimesh.Trimesh(v, f, process=False)
        assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    # new vertices of level l sit near the midpoints of their parent edges (RMD)
    v = lod.vertices
    n = 12
    for par in parents:
        mid = 0.5 * (v[par[:, 0]] + v[par[:, 1]])
        offset = np.linalg.norm(v[n:n + len(par)] - mid, axis=1)
        edge = np.linalg.norm(v[par[:, 0]] - v[par[:, 1]], axis=1)
        assert np.median(offset / edge) < 0.5
        n += len(par)
    # flattening and elongation shape the extent
    ext = v.max(axis=0) - v.min(axis=0)
    assert ext[2] < ext[1] < ext[0]


def test_boulders_are_keyed_by_identity():
    a = boulder_lod(seed=1, uid=5).vertices
    assert np.array_equal(a, boulder_lod(seed=1, uid=5).vertices)
    assert not np.array_equal(a, boulder_lod(seed=1, uid=6).vertices)


def test_bi_resolution_tree_is_the_papers_figure_7():
    tree = lod_tree(2, 4)
    assert tree == BiResolutionNode(2, BiResolutionNode(3, BiResolutionNode(4, 5)))
    with pytest.raises(InvalidParameterError):
        lod_tree(0, 1)


def _placed(**settings):
    body = Body.sphere(SphereMesh(32), 500.0)
    pop = Population(dmin=4.0, dmax=40.0, density=400.0, sfd_exponent=-3.0, max_age=0.0)
    return body, place_boulders(body, pop, seed=9, settings=BoulderSettings(**settings))


def test_placement_up_axis_burial_and_catalogue():
    body, boulders = _placed(max_tilt_deg=0.0, max_burial=0.5)
    assert len(boulders) > 50
    cat = boulders.catalog
    assert cat.columns == BOULDER_COLUMNS
    rot = boulders.rotations()
    assert np.allclose(np.einsum("nij,nkj->nik", rot, rot), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(rot), 1.0)
    lat, lon = np.radians(cat.lat_deg), np.radians(cat.lon_deg)
    zenith = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    assert np.allclose(rot[:, :, 2], zenith, atol=1e-12)     # "up" along the local zenith
    centres = np.column_stack([cat.x_m, cat.y_m, cat.z_m])
    assert np.allclose(centres / np.linalg.norm(centres, axis=1)[:, None], zenith)
    # the buried fraction of each boulder's height lies below the surface along the zenith
    v, _ = boulders.mesh()
    per = v.reshape(len(boulders), -1, 3)
    lowest = np.einsum("nvi,ni->nv", per, zenith).min(axis=1)
    assert np.allclose(lowest, cat.surface_radius_m - cat.burial_depth_m, atol=1e-9)
    assert np.allclose(cat.burial_depth_m, cat.burial_fraction * cat.height_m)
    assert cat.burial_fraction.max() <= 0.5
    assert np.allclose(cat.surface_radius_m, body.surface_radius(zenith))


def test_random_rotations_and_levels_of_detail():
    _, boulders = _placed(max_tilt_deg=25.0)
    cat = boulders.catalog
    assert np.abs(cat.pitch_deg).max() <= 25.0 and np.abs(cat.roll_deg).max() <= 25.0
    assert cat.yaw_deg.min() >= 0 and cat.yaw_deg.max() < 360
    for level in range(4):
        v, f = boulders.mesh(level)
        assert len(v) == len(boulders) * (10 * 4**level + 2)
        assert len(f) == len(boulders) * 20 * 4**level
    lod = boulders.lod(0)
    assert len(lod.faces) == 4
    with pytest.raises(InvalidParameterError, match="boulder level"):
        boulders.mesh(4)


def test_bad_boulder_settings():
    with pytest.raises(InvalidParameterError, match="levels"):
        BoulderSettings(levels=0)
    with pytest.raises(InvalidParameterError, match="flattening"):
        BoulderSettings(flattening=(0.9, 0.5))
    with pytest.raises(InvalidParameterError, match="max_burial"):
        BoulderSettings(max_burial=1.0)
    assert math.isclose(BoulderSettings().max_tilt_deg, 20.0)
