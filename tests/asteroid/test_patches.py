"""Triangle strips split into patches of at most K strips of at most K triangles."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from asteroid.patches import PatchTree, decode_strip
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError


def _canonical(triangles):
    """Rotate each triangle to start at its smallest index (keeps the winding), sort rows."""
    t = np.asarray(triangles)
    shift = np.argmin(t, axis=1)
    rows = np.stack([np.roll(row, -k) for row, k in zip(t, shift, strict=True)])
    return rows[np.lexsort(rows.T[::-1])]


@given(st.integers(1, 24), st.integers(2, 40))
def test_patches_cover_every_triangle_exactly_once(m, k):
    mesh = SphereMesh(m)
    tree = PatchTree.build(mesh, np.ones(mesh.n_vertices), k=k)
    leaves = tree.leaves()
    triangles = np.concatenate([tree.triangles(n) for n in leaves])
    assert np.array_equal(np.sort(triangles), np.arange(mesh.n_faces))
    assert tree.n_strips[leaves].max() <= k
    assert tree.n_triangles_max[leaves].max() <= k
    assert tree.n_triangles[leaves].min() > 0
    # each inner node holds exactly its children's triangles
    for node in range(tree.n_nodes):
        kids = tree.children[node][tree.children[node] >= 0]
        if kids.size:
            assert tree.n_triangles[node] == tree.n_triangles[kids].sum()


def test_the_paper_split_into_four():
    # a node with more than K strips whose longest strip exceeds K splits in four
    mesh = SphereMesh(40)
    tree = PatchTree.build(mesh, np.ones(mesh.n_vertices), k=16)
    root_children = tree.children[0][tree.children[0] >= 0]
    assert len(root_children) == 4
    assert tree.band_stop[root_children].tolist() == [40, 40, 80, 80]


@pytest.mark.parametrize("m,k", [(3, 2), (9, 4), (20, 8)])
def test_bounding_spheres_hold_their_vertices(m, k, rng):
    mesh = SphereMesh(m)
    radii = 100.0 + rng.uniform(-20, 20, mesh.n_vertices)
    tree = PatchTree.build(mesh, radii, k=k)
    v = mesh.directions() * radii[:, None]
    faces = mesh.faces()
    for node in range(tree.n_nodes):
        pts = v[faces[tree.triangles(node)]].reshape(-1, 3)
        centre, r = tree.spheres[node, :3], tree.spheres[node, 3]
        assert np.linalg.norm(pts - centre, axis=1).max() <= r * (1 + 1e-12)
    leaves = tree.leaves()
    # culling is useful: leaves are much smaller than the body
    assert np.median(tree.spheres[leaves, 3]) < 0.5 * tree.spheres[0, 3]


@pytest.mark.parametrize("m,k", [(1, 2), (2, 2), (5, 3), (12, 5), (21, 16)])
def test_strips_draw_the_patch_triangles_outward(m, k):
    mesh = SphereMesh(m)
    faces = mesh.faces()
    tree = PatchTree.build(mesh, np.ones(mesh.n_vertices), k=k)
    for node in range(tree.n_nodes):
        strip = tree.strip(node)
        assert np.array_equal(_canonical(decode_strip(strip)),
                              _canonical(faces[tree.triangles(node)]))


def test_bad_patch_size_is_refused():
    mesh = SphereMesh(2)
    with pytest.raises(InvalidParameterError, match="patch size K"):
        PatchTree.build(mesh, np.ones(mesh.n_vertices), k=1)
    with pytest.raises(InvalidParameterError, match="radii must be"):
        PatchTree.build(mesh, np.ones(3), k=4)
