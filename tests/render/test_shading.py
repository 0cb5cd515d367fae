"""Shading: each reflectance against its formula, shadows, golden images, determinism."""

import os
from pathlib import Path

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.reflectance import reflectance
from render.renderer import Lighting, RenderOptions, View
from render.terrain_scene import TerrainScene
from terrain.core.tile import DEMTile
from terrain.craters.catalog import Crater, CraterCatalog, CraterTable
from terrain.craters.cratering import CraterModel, add_craters
from terrain.stack.model import Layer, LayerStack

GOLDEN = Path(__file__).with_name("golden")
UPDATE = os.environ.get("CRATERSCAPE_UPDATE_GOLDEN") == "1"


def _stack(tile):
    left, bottom, right, top = tile.bounds
    cat = CraterCatalog.empty(layered=True)
    return LayerStack((Layer(tile, None, (0, 0)),), cat,
                      {"site": [(left + right) / 2, (bottom + top) / 2]})


@pytest.fixture(scope="module")
def crater_scene():
    flat = DEMTile.from_array(np.zeros((65, 65)), resolution=1.0)
    crater = CraterTable.from_craters([Crater(32.5, 32.5, 30.0, 0.0, 1)])
    tile = add_craters(flat, crater, seed=1, model=CraterModel().smooth()).tile
    return TerrainScene(_stack(tile), curvature=False)


@pytest.mark.parametrize("brdf", ["lambert", "lommel-seeliger", "lunar-lambert"])
def test_each_reflectance_matches_its_formula(renderer, brdf):
    n = 65
    rows, cols = np.mgrid[0:n, 0:n]
    z = 0.3 * (cols + 0.5)  # a plane facing west
    scene = TerrainScene(_stack(DEMTile.from_array(z, resolution=1.0)), curvature=False)
    light = Lighting.from_angles(250.0, 35.0, albedo=0.3, brdf=brdf)
    k = Intrinsics.from_fov(64, 64, 30.0)
    pose = look_at((10.0, 10.0, 90.0), (32.0, 32.0, 9.0))
    frame = renderer.render(scene, View(pose, k), light,
                            RenderOptions(shadows=False, scattering=False))  # the sun alone
    normal = np.array([-0.3, 0.0, 1.0]) / np.linalg.norm([-0.3, 0.0, 1.0])
    ok = np.isfinite(frame.range)
    pts = pose.unproject(np.stack(np.meshgrid(np.arange(64), np.arange(64)), -1)
                         .reshape(-1, 2)[ok.ravel()], frame.range[ok], k)
    e = np.asarray(pose.position) - pts
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    sun = np.asarray(light.sun)
    phase = np.degrees(np.arccos(np.clip(e @ sun, -1, 1)))
    expected = reflectance(brdf, normal @ sun, e @ normal, phase, 0.3)
    assert np.allclose(frame.radiance[ok], expected, rtol=2e-4, atol=1e-6)


def test_shadows_darken_the_far_wall_and_only_it(renderer, crater_scene):
    k = Intrinsics.from_fov(96, 96, 40.0)
    pose = look_at((32.5, 32.5, 110.0), (32.5, 32.5, 0.0))
    low_sun = Lighting.from_angles(90.0, 12.0, albedo=0.2, brdf="lambert")
    lit = renderer.render(crater_scene, View(pose, k), low_sun, RenderOptions(shadows=False))
    shaded = renderer.render(crater_scene, View(pose, k), low_sun, RenderOptions(shadows=True))
    darker = shaded.radiance < lit.radiance - 1e-4
    assert darker.sum() > 50, "the sunward wall's shadow falls into the bowl"
    assert np.all(shaded.radiance <= lit.radiance + 1e-6)
    # flat ground outside the crater has no shadow (no acne at 12 degrees of sun)
    rows, cols = np.mgrid[0:96, 0:96]
    pts = pose.unproject(np.stack([cols.ravel(), rows.ravel()], 1), lit.range.ravel(), k)
    far = (np.hypot(pts[:, 0] - 32.5, pts[:, 1] - 32.5) > 31.0).reshape(96, 96)
    assert far.sum() > 500
    assert np.allclose(shaded.radiance[far], lit.radiance[far], atol=1e-6)


CASES = {
    "lambert": (Lighting.from_angles(120.0, 30.0, albedo=0.25, brdf="lambert"), False),
    "lommel_seeliger": (Lighting.from_angles(120.0, 30.0, albedo=0.25,
                                             brdf="lommel-seeliger"), False),
    "lunar_lambert": (Lighting.from_angles(120.0, 30.0, albedo=0.25, brdf="lunar-lambert"),
                      False),
    "lunar_lambert_shadows": (Lighting.from_angles(120.0, 10.0, albedo=0.25,
                                                   brdf="lunar-lambert"), True),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_golden_images_are_bit_exact(renderer, crater_scene, name):
    if "llvmpipe" not in (renderer.ctx.info.get("GL_RENDERER") or ""):
        pytest.skip("golden images are recorded on Mesa llvmpipe; this is another renderer")
    light, shadows = CASES[name]
    k = Intrinsics.from_fov(32, 32, 60.0)
    pose = look_at((5.0, 2.0, 45.0), (32.5, 32.5, -5.0))
    frame = renderer.render(crater_scene, View(pose, k), light,
                            RenderOptions(shadows=shadows, shadow_size=256, lod_pixels=1.0))
    path = GOLDEN / f"{name}.npy"
    if UPDATE or not path.exists():
        if not UPDATE:
            pytest.fail(f"golden image {path} is missing; regenerate with "
                        "CRATERSCAPE_UPDATE_GOLDEN=1")
        np.save(path, frame.radiance)
    golden = np.load(path)
    assert frame.radiance.tobytes() == golden.tobytes()


def test_same_view_same_bytes(renderer, crater_scene):
    k = Intrinsics.from_fov(64, 48, 55.0)
    pose = look_at((0.0, 0.0, 40.0), (30.0, 30.0, 0.0))
    light = Lighting.from_angles(200.0, 20.0)
    a = renderer.render(crater_scene, View(pose, k), light, RenderOptions())
    b = renderer.render(crater_scene, View(pose, k), light, RenderOptions())
    for x, y in ((a.radiance, b.radiance), (a.range, b.range), (a.normals, b.normals)):
        assert x.tobytes() == y.tobytes()
