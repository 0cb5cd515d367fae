"""Albedo maps: per vertex on bodies and meshes, per pixel on terrain (also scaling Hapke's w)."""

import math

import numpy as np
import pytest

from render.asteroid_scene import AsteroidScene
from render.camera import Intrinsics, look_at
from render.mesh_scene import MeshScene
from render.reflectance import SATO_643NM, hapke
from render.renderer import Lighting, RenderOptions, View
from render.terrain_scene import TerrainScene
from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterCatalog
from terrain.stack.model import Layer, LayerStack

LIGHT = Lighting((0.3, -0.5, 0.8), albedo=0.2, brdf="lommel-seeliger")
K = Intrinsics.from_fov(96, 96, 40.0)


def _hit_points(frame, pose):
    ok = np.isfinite(frame.range)
    uv = np.stack(np.meshgrid(np.arange(K.width), np.arange(K.height)), -1).reshape(-1, 2)
    pts = np.full((K.height * K.width, 3), np.nan)
    pts[ok.ravel()] = pose.unproject(uv[ok.ravel()], frame.range[ok], K)
    return pts.reshape(K.height, K.width, 3)


def test_per_vertex_albedo_on_an_asteroid_body(renderer):
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh

    body = Body.sphere(SphereMesh(32), 1000.0)
    north = body.mesh.directions()[:, 2] > 0
    plain = AsteroidScene(body, boulders=False)
    dark_north = AsteroidScene(body, boulders=False, albedo=np.where(north, 0.5, 1.0))
    pose = look_at((2600.0, -1500.0, 900.0), (0.0, 0.0, 0.0))
    for lod in (0.1, 8.0):  # the finest and a coarser level of detail
        opts = RenderOptions(shadows=False, lod_pixels=lod)
        a = renderer.render(plain, View(pose, K), LIGHT, opts)
        b = renderer.render(dark_north, View(pose, K), LIGHT, opts)
        pts = _hit_points(a, pose)
        lit = a.radiance > 1e-3
        far_north = lit & (pts[..., 2] > 250.0)
        far_south = lit & (pts[..., 2] < -250.0)
        assert far_north.sum() > 100 and far_south.sum() > 100
        assert np.allclose(b.radiance[far_north], 0.5 * a.radiance[far_north], rtol=1e-5)
        assert np.allclose(b.radiance[far_south], a.radiance[far_south], rtol=1e-6)


def test_per_vertex_albedo_on_a_mesh(renderer):
    v = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    scene = MeshScene(v, f, albedo=[0.0, 1.0, 1.0, 0.0])  # dark west edge, bright east
    pose = look_at((0.0, 0.0, 150.0), (0.0, 0.001, 0.0))
    fr = renderer.render(scene, View(pose, K), Lighting((0, 0, 1), albedo=1.0, brdf="lambert"),
                         RenderOptions(shadows=False))
    pts = _hit_points(fr, pose)
    ok = np.isfinite(pts[..., 0])
    # Lambert with the sun overhead: I/F = albedo, linear from 0 at x = -50 to 1 at x = 50
    assert np.allclose(fr.radiance[ok], (pts[..., 0][ok] + 50.0) / 100.0, atol=2e-3)
    with pytest.raises(InvalidParameterError, match="per vertex"):
        MeshScene(v, f, albedo=[1.0, 1.0])


def test_terrain_albedo_map_scales_hapkes_w(renderer):
    tile = DEMTile.from_array(np.zeros((65, 65)), resolution=1.0)
    cat = CraterCatalog.empty(layered=True)
    amap = DEMTile.from_array(np.full((65, 65), 1.5), resolution=1.0)
    scene = TerrainScene(LayerStack((Layer(tile, None, (0, 0)),), cat, {"site": [32.5, 32.5]}),
                         curvature=False, albedo_map=amap)
    light = Lighting.from_angles(90.0, 50.0, brdf="hapke")
    pose = look_at((20.0, 32.5, 60.0), (32.5, 32.5, 0.0))
    fr = renderer.render(scene, View(pose, K), light, RenderOptions(shadows=False))
    p = _hit_points(fr, pose)[48, 48]
    v = np.asarray(pose.position) - p
    v /= np.linalg.norm(v)
    sun = np.asarray(light.sun)
    g = math.degrees(math.acos(v @ sun))
    want = float(hapke(sun[2], v[2], g, SATO_643NM, scale=1.5))
    assert fr.radiance[48, 48] == pytest.approx(want, rel=1e-4)
    assert want > 1.3 * float(hapke(sun[2], v[2], g, SATO_643NM))
