"""Light scattered into shadows: the horizon method against view factors, and in frames."""

import math

import numpy as np
import pytest

from render.scattering import disk_fraction_above, horizon_light
from terrain.core.errors import InvalidParameterError

SPACING = 1.0           # m
HEIGHT = 30.0           # m: both rims of the trench
WIDTH = 10.0            # m: its flat floor, x in [0, WIDTH]
SLOPE = 60.0            # degrees: the far (east) wall rises at this slope
ELEVATION = 40.0        # degrees: the sun, from the west (azimuth 270)
ALBEDO = 0.12


def trench(ny=64):
    """A straight trench along y: a vertical west wall, a flat floor, a 60 degree east wall."""
    x = np.arange(-40.0, 80.0, SPACING)
    run = HEIGHT / math.tan(math.radians(SLOPE))
    z = np.where(x < 0, HEIGHT, np.clip((x - WIDTH) * math.tan(math.radians(SLOPE)), 0.0,
                                         HEIGHT))
    z[x > WIDTH + run] = HEIGHT
    return x, np.broadcast_to(z, (ny, x.size)).copy()


def sun_vector(azimuth_deg, elevation_deg):
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el))


def test_shadowed_floor_receives_the_lit_walls_view_factor():
    x, z = trench()
    out = horizon_light(z, SPACING, sun_vector(270.0, ELEVATION), albedo=ALBEDO, reach=600.0)
    # the floor is in the west wall's shadow (its shadow is H cot(e) = 36 m long)
    floor = (x > 1.0) & (x < WIDTH - 1.0)
    assert np.all(out["sun"][:, floor] == 0.0)
    # the east wall is lit above the west rim's shadow line z = H - x tan(e)
    te, ts = math.tan(math.radians(ELEVATION)), math.tan(math.radians(SLOPE))
    x1 = (HEIGHT + WIDTH * ts) / (ts + te)
    z1 = (x1 - WIDTH) * ts
    x2 = WIDTH + HEIGHT / ts
    mu0 = math.sin(math.radians(SLOPE + ELEVATION))  # the sun on the wall's normal
    row = z.shape[0] // 2
    for xp in (3.0, 5.0, 7.0):
        # a floor element and an infinitely long lit strip: F = (cos b1 - cos b2) / 2, b1 and
        # b2 the strip's edges' elevation angles (Howell's catalogue of configuration
        # factors, C-3; Modest, Radiative Heat Transfer, ch. 4)
        b1 = math.atan2(z1, x1 - xp)
        b2 = math.atan2(HEIGHT, x2 - xp)
        view_factor = 0.5 * (math.cos(b1) - math.cos(b2))
        expected = ALBEDO * mu0 * view_factor   # E / F: the wall's radiosity times F
        j = int(np.argmin(np.abs(x - xp)))
        assert out["scattered"][row, j] == pytest.approx(expected, rel=0.10), xp


def test_flat_ground_sees_no_other_ground():
    flat = horizon_light(np.zeros((32, 32)), 1.0, (0.3, 0.2, 0.9), albedo=0.5)
    assert np.all(flat["scattered"] == 0.0) and np.all(flat["sun"] == 1.0)


def test_disk_fraction_and_bad_input():
    assert float(disk_fraction_above(0.2, np.array(0.3), 0.05)) == 0.0
    assert float(disk_fraction_above(0.2, np.array(0.1), 0.05)) == 1.0
    assert float(disk_fraction_above(0.2, np.array(0.2), 0.0)) == 0.0
    with pytest.raises(InvalidParameterError, match="heights"):
        horizon_light(np.zeros(5), 1.0, (0, 0, 1), albedo=0.1)
    with pytest.raises(InvalidParameterError, match="spacing"):
        horizon_light(np.zeros((4, 4)), 0.0, (0, 0, 1), albedo=0.1)


def test_earthshine_adds_the_earths_light_where_it_is_up(renderer):
    """Flat Lambertian ground: I/F = A (mu0 + earthshine mu_e), and the Earth switches off."""
    from render.camera import Intrinsics, look_at
    from render.renderer import Lighting, RenderOptions, View
    from render.terrain_scene import TerrainScene
    from terrain.core.tile import DEMTile
    from terrain.craters.catalog import CraterCatalog
    from terrain.stack.model import Layer, LayerStack

    tile = DEMTile.from_array(np.zeros((65, 65)), resolution=1.0)
    stack = LayerStack((Layer(tile, None, (0, 0)),), CraterCatalog.empty(layered=True),
                       {"site": [32.5, 32.5]})
    scene = TerrainScene(stack, curvature=False)
    earth = sun_vector(200.0, 30.0)
    light = Lighting.from_angles(90.0, 60.0, albedo=0.2, brdf="lambert", earth=earth,
                                 earthshine=0.01)
    view = View(look_at((32.5, 20.0, 40.0), (32.5, 32.5, 0.0)), Intrinsics.from_fov(32, 32, 30.0))
    on = renderer.render(scene, view, light, RenderOptions()).radiance
    off = renderer.render(scene, view, light, RenderOptions(earthshine=False)).radiance
    ok = on > 0
    assert ok.mean() > 0.9
    mu0, mu_e = math.sin(math.radians(60.0)), math.sin(math.radians(30.0))
    assert np.allclose(on[ok], 0.2 * (mu0 + 0.01 * mu_e), rtol=1e-4)
    assert np.allclose(off[ok], 0.2 * mu0, rtol=1e-4)


def test_a_distant_fine_layer_is_lit_by_its_parents_grid_of_scattered_light(renderer):
    """Seen from where an image pixel spans the parent's grid cell, a layer needs no grid.

    From 4 km the finest layer of the load test's stack (2.5 m pixels, a 5.4 m grid cell)
    is drawn with its parent's grid (a 14 m cell, the image pixel ~20 m there): the frame
    changes in a few pixels, by at most 1 % of the brightest (measured 0.25 %). From
    1.5 km every layer keeps its own grid: the frame is the same bytes.
    """
    import sys
    from pathlib import Path

    from render.camera import Intrinsics, look_at
    from render.renderer import Lighting, RenderOptions, View
    from render.terrain_scene import TerrainScene

    sys.path.append(str(Path(__file__).resolve().parent))
    from test_terrain_load import _stack

    k = Intrinsics.from_fov(128, 128, 40.0)
    light = Lighting.from_angles(120.0, 8.0, albedo=0.12)
    for altitude, grids in ((1500.0, {0, 1, 2}), (4000.0, {0, 1})):
        view = View(look_at((750.0, 700.0, altitude), (750.0, 750.0, 0.0)), k)
        frames = []
        for own in (False, True):
            scene = TerrainScene(_stack())
            if own:
                scene._scatter_source = lambda level, footprint: level
            frames.append(renderer.render(scene, view, light,
                                          RenderOptions(shadow_size=1024)).radiance)
            if not own:
                assert {key for m in scene._scatter_cache.values() for key in m} == grids
        shared, alone = frames
        if altitude < 2000.0:
            assert shared.tobytes() == alone.tobytes()
        else:
            assert 0 < (shared != alone).mean() < 0.02
            assert np.abs(shared - alone).max() <= 0.01 * alone.max()
