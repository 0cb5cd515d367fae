"""The extended sun: a step's shadow edge has the penumbra of the solar disk."""

import math

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.renderer import Lighting, RenderOptions, View
from render.terrain_scene import TerrainScene
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterCatalog
from terrain.stack.model import Layer, LayerStack

RES = 0.25          # m per DEM pixel
STEP_X = 40.0       # m: the plateau ends here (map x)
HEIGHT = 20.0       # m: its height above the floor
ELEVATION = 20.0    # degrees: the sun, from the west (azimuth 270)


def step_scene():
    ny, nx = 160, 640
    x = (np.arange(nx) + 0.5) * RES
    z = np.where(x < STEP_X, HEIGHT, 0.0)
    tile = DEMTile.from_array(np.broadcast_to(z, (ny, nx)).copy(), resolution=RES)
    site = [nx * RES / 2, ny * RES / 2]
    stack = LayerStack((Layer(tile, None, (0, 0)),), CraterCatalog.empty(layered=True),
                       {"site": site})
    return TerrainScene(stack, curvature=False), site


def disk_fraction_visible(u):
    """Fraction of a uniform disk above a straight edge ``u`` radii above its centre."""
    u = np.clip(u, -1.0, 1.0)
    covered = (np.arccos(u) - u * np.sqrt(1.0 - u * u)) / math.pi
    return 1.0 - covered


def width_10_90(d, vis):
    """Ground distance between where the visibility crosses 0.1 and 0.9 (vis increasing)."""
    return float(np.interp(0.9, vis, d) - np.interp(0.1, vis, d))


def test_step_shadow_has_the_penumbra_of_the_solar_disk(renderer):
    scene, site = step_scene()
    # 0.2 au: a solar disk 1.33 degrees in radius: 8 m from no sun to full sun past a 20 m step
    light = Lighting.from_angles(270.0, ELEVATION, albedo=0.2, brdf="lambert", distance=0.2)
    alpha = light.sun_angular_radius
    # analytic: at distance D beyond the step the edge stands atan(H / D) high; the sun's
    # visible fraction is that of its disk above the edge
    d = np.linspace(30.0, 90.0, 6001)
    edge = np.arctan(HEIGHT / d)
    vis_true = disk_fraction_visible((math.radians(ELEVATION) - edge) / alpha)
    expected = width_10_90(d, vis_true)
    assert 5.0 < expected < 6.0  # 10-90 % of the 8 m the whole disk spans

    centre_x = STEP_X + HEIGHT / math.tan(math.radians(ELEVATION))  # the shadow's edge, map x
    k = Intrinsics.from_fov(512, 64, 40.0)
    pose = look_at((centre_x, site[1], 45.0), (centre_x, site[1], 0.0))
    frame = renderer.render(scene, View(pose, k), light,
                            RenderOptions(shadow_size=4096, scattering=False))
    row = frame.radiance[32]
    cam = np.asarray(pose.position)
    rays = np.array([[(u - k.cx) / k.fx, 0.0, 1.0] for u in range(k.width)])
    world = rays @ pose.rotation.T
    hit_x = cam[0] + world[:, 0] * (cam[2] / -world[:, 2])
    lit = light.albedo * light.sun[2]  # Lambert I/F on the flat floor in full sun
    vis = row / lit
    inside = (hit_x > STEP_X + 2.0)
    order = np.argsort(hit_x[inside])
    dd, vv = hit_x[inside][order] - STEP_X, vis[inside][order]
    assert vv[0] < 0.02 and vv[-1] > 0.98, "the frame must span umbra to full sun"
    measured = width_10_90(dd, np.maximum.accumulate(vv))
    assert measured == pytest.approx(expected, rel=0.10)
    # and the point sun's edge is sharp (a few texels)
    point = renderer.render(scene, View(pose, k), light,
                            RenderOptions(shadow_size=4096, scattering=False,
                                          soft_shadows=False))
    vp = point.radiance[32][inside][order] / lit
    assert width_10_90(dd, np.maximum.accumulate(vp)) < 0.15 * expected
