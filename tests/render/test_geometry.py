"""The renderer's geometry is exact: range, normals and projection against analytic truth."""

import numpy as np

from render.camera import Intrinsics, look_at
from render.mesh_scene import MeshScene
from render.renderer import Lighting, RenderOptions, View
from render.terrain_scene import TerrainScene
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterCatalog
from terrain.stack.model import Layer, LayerStack

LIGHT = Lighting.from_angles(135.0, 40.0, albedo=0.2, brdf="lambert")


def single_layer(heights, resolution=1.0, site=None):
    tile = DEMTile.from_array(heights, resolution=resolution)
    left, bottom, right, top = tile.bounds
    site = site or ((left + right) / 2, (bottom + top) / 2)
    cat = CraterCatalog.empty(layered=True)
    return LayerStack((Layer(tile, None, (0, 0)),), cat, {"site": list(site)})


def test_range_and_normals_of_a_tilted_plane_are_exact(renderer):
    n, res = 257, 1.0
    rows, cols = np.mgrid[0:n, 0:n]
    x = (cols + 0.5) * res
    y = (n - rows - 0.5) * res
    gx, gy, z0 = 0.2, -0.1, 100.0
    scene = TerrainScene(single_layer(z0 + gx * x + gy * y, res), curvature=False)
    k = Intrinsics.from_fov(200, 150, 50.0)
    pose = look_at((60.0, 20.0, 260.0), (128.0, 140.0, 110.0))
    frame = renderer.render(scene, View(pose, k), LIGHT, RenderOptions(shadows=False))
    # analytic ray-plane intersection
    normal = np.array([-gx, -gy, 1.0]) / np.linalg.norm([-gx, -gy, 1.0])
    c = np.asarray(pose.position)
    rays = k.rays() @ pose.rotation.T
    t = ((np.array([0.0, 0.0, z0]) - c) @ normal) / (rays @ normal)
    hit = c + rays * t[..., None]
    inside = ((hit[..., 0] > 3) & (hit[..., 0] < n - 3) & (hit[..., 1] > 3)
              & (hit[..., 1] < n - 3) & (t > 0))
    assert inside.mean() > 0.5
    rel = np.abs(frame.range[inside] - t[inside]) / t[inside]
    assert np.nanmax(rel) < 1e-4
    assert np.allclose(frame.normals[inside], normal, atol=1e-4)
    # shading follows Lambert: I/F = A mu0
    mu0 = float(normal @ np.asarray(LIGHT.sun))
    assert np.allclose(frame.radiance[inside], 0.2 * mu0, atol=1e-5)


def _inside_polygon(points, poly):
    """Signed distance (pixels) of points inside a convex polygon (negative outside)."""
    d = np.full(len(points), np.inf)
    n = len(poly)
    area = sum(poly[i, 0] * poly[(i + 1) % n, 1] - poly[(i + 1) % n, 0] * poly[i, 1]
               for i in range(n))
    sign = 1.0 if area > 0 else -1.0
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        e = b - a
        cross = (e[0] * (points[:, 1] - a[1]) - e[1] * (points[:, 0] - a[0])) * sign
        d = np.minimum(d, cross / np.linalg.norm(e))
    return d


def test_known_points_appear_at_the_pixels_the_truth_predicts(renderer):
    """A square with known corners covers exactly the pixels whose centres its projection holds.

    The rasteriser covers a pixel when its centre lies inside the projected triangle, so the
    coverage boundary is the projected edge itself: any error in the projection (a half-pixel
    convention slip, a flipped axis, a wrong principal point) moves it by that much.
    """
    corners = np.array([[-20.0, -15.0, 5.0], [25.0, -18.0, 8.0], [22.0, 30.0, 2.0],
                        [-18.0, 26.0, 0.0]])
    centre = corners.mean(axis=0)
    scene = MeshScene(corners - centre, np.array([[0, 1, 2], [0, 2, 3]]), centre=centre)
    k = Intrinsics(160, 120, 150.0, 151.0, 80.2, 59.7)
    for eye in ((5.0, -60.0, 90.0), (-40.0, 10.0, 70.0), (30.3, 45.1, 60.0)):
        pose = look_at(eye, centre)
        frame = renderer.render(scene, View(pose, k), LIGHT, RenderOptions(shadows=False))
        poly = pose.project(corners, k)
        v, u = np.mgrid[0:k.height, 0:k.width]
        pix = np.stack([u.ravel(), v.ravel()], axis=1).astype(float)
        dist = _inside_polygon(pix, poly).reshape(k.height, k.width)
        covered = np.isfinite(frame.range)
        clear = np.abs(dist) > 1e-3
        assert np.array_equal(covered[clear], dist[clear] > 0)
        assert covered.sum() > 100


def icosphere(radius, subdivisions):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices), np.asarray(s.faces)


def test_range_of_a_sphere_matches_the_analytic_range(renderer):
    radius = 1000.0
    v, f = icosphere(radius, 7)
    scene = MeshScene(v, f)
    k = Intrinsics.from_fov(128, 128, 50.0)
    pose = look_at((1800.0, -2200.0, 900.0), (0.0, 0.0, 0.0))
    frame = renderer.render(scene, View(pose, k), LIGHT, RenderOptions(shadows=False))
    c = np.asarray(pose.position)
    d = k.rays() @ pose.rotation.T
    b = d @ c
    disc = b**2 - (c @ c - radius**2)
    hit = disc > 0.05 * radius**2  # away from the limb, where facets decide coverage
    t = -b - np.sqrt(np.maximum(disc, 0))
    assert hit.sum() > 2000
    rel = np.abs(frame.range[hit] - t[hit]) / t[hit]
    assert np.nanmax(rel) < 1e-4
    assert np.all(np.isnan(frame.range[disc < -0.05 * radius**2]))


def test_no_background_shows_through_layer_seams(renderer):
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack

    base = synthesize_tile(65, resolution=64.0, relief=600.0, seed=4).tile
    site = (2080.0, 2080.0)
    stack = build_stack(base, site, levels=3, layer_size=33, seed=2,
                        population=Population(dmin=1.0, dmax=2000.0, density=3e4))
    scene = TerrainScene(stack, curvature=False)
    k = Intrinsics.from_fov(256, 256, 40.0)
    lo, hi = scene.bounds()
    for alt, lod in ((3000.0, 1.5), (3000.0, 12.0), (600.0, 6.0)):
        pose = look_at((site[0] + 1.0, site[1] + 2.0, hi[2] + alt), (site[0], site[1], 0.0))
        frame = renderer.render(scene, View(pose, k), LIGHT,
                                RenderOptions(shadows=False, lod_pixels=lod))
        assert not np.isnan(frame.range).any(), f"background pixels at alt {alt}, lod {lod}"
        assert len(frame.drawn["layers"]) >= 2
