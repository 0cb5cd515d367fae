"""Motion during the exposure: blur length, rolling-shutter row truth, velocities, albedo maps."""

import math

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.motion import Motion, render_exposure, trajectory_velocities
from render.renderer import Lighting, RenderOptions, View
from render.scenario import parse_scenario
from render.sensor import Sensor
from render.sequence import render_sample
from render.terrain_scene import TerrainScene
from render.trajectory import keyframes
from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterCatalog
from terrain.stack.model import Layer, LayerStack

K = Intrinsics.from_fov(128, 128, 60.0)
H = 100.0
SPOTS = [(40, 64), (64, 40), (96, 80)]  # (row, col) of bright albedo pixels
LIGHT = Lighting.from_angles(0.0, 90.0, albedo=1.0, brdf="lambert")
OPTIONS = RenderOptions(shadows=False)


@pytest.fixture(scope="module")
def spotted():
    """A flat plain of albedo 0 with a few single bright pixels: point-like features."""
    n = 161
    tile = DEMTile.from_array(np.zeros((n, n)), resolution=1.0)
    albedo = np.zeros((n, n))
    for r, c in SPOTS:
        albedo[r + 16, c + 16] = 1.0
    amap = DEMTile.from_array(albedo, resolution=1.0)
    cat = CraterCatalog.empty(layered=True)
    scene = TerrainScene(LayerStack((Layer(tile, None, (0, 0)),), cat, {"site": [80.5, 80.5]}),
                         curvature=False, albedo_map=amap)
    points = [np.array([*(amap.transform @ (c + 16.5, r + 16.5)), 0.0]) for r, c in SPOTS]
    return scene, points


def centroid(img, around, half=9):
    r0, c0 = (int(round(v)) for v in around)
    win = img[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1].astype(np.float64)
    rows, cols = np.mgrid[r0 - half:r0 + half + 1, c0 - half:c0 + half + 1]
    m = win.sum()
    cu, cv = (win * cols).sum() / m, (win * rows).sum() / m
    var_u = (win * (cols - cu) ** 2).sum() / m
    return cu, cv, var_u


def nadir(x, y):
    return look_at((x, y, H), (x, y + 1e-3, 0.0))


def test_albedo_map_scales_the_surface(renderer, spotted):
    scene, points = spotted
    fr = renderer.render(scene, View(nadir(80.5, 80.5), K), LIGHT, OPTIONS)
    for p in points:
        u, v = nadir(80.5, 80.5).project(p[None], K)[0]
        assert fr.radiance[int(round(v)), int(round(u))] > 0.3
    assert np.median(fr.radiance) == 0.0


def test_blur_smears_a_point_over_the_distance_it_moves(renderer, spotted):
    scene, points = spotted
    pose = nadir(80.5, 80.5)
    still = renderer.render(scene, View(pose, K), LIGHT, OPTIONS).radiance
    for speed, t_exp in ((30.0, 0.1), (50.0, 0.2)):
        sensor = Sensor.from_mapping(dict(exposure_time=t_exp, aperture=0.01, gain=1.0))
        motion = Motion(velocity=(speed, 0.0, 0.0))
        rad, _, info = render_exposure(renderer, scene, View(pose, K), LIGHT, OPTIONS,
                                       sensor, motion)
        length = speed * t_exp * K.fx / H  # pixels the ground moves across the image
        for p in points:
            u, v = pose.project(p[None], K)[0]
            cu0, _, var0 = centroid(still, (v, u))
            mid = motion.pose_at(pose, t_exp / 2).project(p[None], K)[0]
            cu, cv, var = centroid(rad, (mid[1], mid[0]), half=int(length) + 6)
            measured = math.sqrt(12 * (var - var0))  # a box of length L adds L^2 / 12
            assert measured == pytest.approx(length, abs=0.5), (speed, t_exp, info)
            assert cu == pytest.approx(mid[0], abs=0.5)
        assert info["samples"] >= 2 * length


def test_rolling_shutter_row_truth_places_each_point(renderer, spotted):
    scene, points = spotted
    data = {"scene": {"type": "terrain", "stack": "unused"}, "seed": 5,
            "sun": {"azimuth": 0.0, "elevation": 90.0},
            "surface": {"albedo": 1.0, "reflectance": "lambert"},
            "camera": {"width": 128, "height": 128, "fov": 60.0},
            "sensor": {"exposure_time": 2e-4, "line_time": 1e-3, "aperture": 0.01,
                       "gain": 1.0, "shot_noise": False, "bits": 16},
            "render": {"shadows": False},
            "trajectory": {"type": "keyframes", "frames": 2, "keyframe": [
                {"time": 0.0, "position": [60.0, 80.5, H], "look_at": [60.0, 80.501, 0.0]},
                {"time": 1.0, "position": [120.0, 80.5, H], "look_at": [120.0, 80.501, 0.0]},
            ]}}
    scenario = parse_scenario(data)
    assert scenario.motion["blur"]  # a rolling shutter implies motion
    samples = keyframes(2, data["trajectory"]["keyframe"])
    image, frame, truth = render_sample(renderer, scene, scenario, samples[0], 0, samples)
    assert truth.motion["velocity"] == pytest.approx([60.0, 0.0, 0.0])
    shifts = []
    for p in points:
        row = 64.0
        for _ in range(10):  # the row that images p is where p projects at that row's time
            row = truth.row_pose(row).project(p[None], K)[0][1]
        u, v = truth.row_pose(row).project(p[None], K)[0]
        cu, cv, _ = centroid(frame.radiance, (v, u))
        assert cu == pytest.approx(u, abs=0.5) and cv == pytest.approx(v, abs=0.5)
        u0 = truth.pose.project(p[None], K)[0][0]
        shifts.append(u0 - u)
    # lower rows are read later, so the camera has moved further: the skew rolling shutters show
    assert shifts[2] > shifts[0] + 3.0
    again, _, _ = render_sample(renderer, scene, scenario, samples[0], 0, samples)
    assert again.tobytes() == image.tobytes()


def test_velocities_from_a_trajectory():
    keys = [{"time": 0.0, "position": [0, 0, 10], "attitude": [1, 0, 0, 0]},
            {"time": 2.0, "position": [4, 0, 10],
             "attitude": [math.cos(0.25), 0, 0, math.sin(0.25)]}]
    m = trajectory_velocities(keyframes(3, keys), 1)
    assert m.velocity == pytest.approx((2.0, 0.0, 0.0))
    assert m.angular_velocity == pytest.approx((0.0, 0.0, 0.25))  # 0.5 rad in 2 s about z


def test_bad_motion_tables():
    with pytest.raises(InvalidParameterError, match="'velocity'"):
        Motion.from_mapping({"velocty": [1, 0, 0]})
    with pytest.raises(InvalidParameterError, match="velocity"):
        Motion(velocity=(1.0, 2.0))


def test_a_band_of_rows_is_the_same_band_of_a_full_render(renderer, spotted):
    scene, _ = spotted
    view = View(look_at((60.0, 50.0, 80.0), (80.5, 80.5, 0.0)), K)
    full = renderer.render(scene, view, LIGHT, OPTIONS)
    band = renderer.render(scene, view, LIGHT, OPTIONS, rows=(37, 90))
    assert band.radiance[37:90].tobytes() == full.radiance[37:90].tobytes()
    assert band.range[37:90].tobytes() == full.range[37:90].tobytes()
    again = renderer.render(scene, view, LIGHT, OPTIONS)  # the scissor is gone
    assert again.radiance.tobytes() == full.radiance.tobytes()


def test_a_spinning_body_smears_a_spot_over_the_arc_it_turns(renderer):
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh
    from render.asteroid_scene import AsteroidScene

    body = Body.sphere(SphereMesh(64), 1000.0)
    d = body.mesh.directions()
    spot = np.where(d[:, 0] > math.cos(math.radians(1.5)), 1.0, 0.0)  # a spot facing +x
    scene = AsteroidScene(body, boulders=False, albedo=spot)
    k = Intrinsics.from_fov(128, 128, 20.0)
    pose = look_at((5000.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    light = Lighting((1.0, 0.0, 0.0), albedo=1.0, brdf="lambert")
    still = renderer.render(scene, View(pose, k), light, OPTIONS).radiance
    omega, t_exp = 0.02, 3.0  # the spot travels 60 m on the surface during the exposure
    sensor = Sensor.from_mapping(dict(exposure_time=t_exp, aperture=0.01, gain=1.0))
    rad, _, info = render_exposure(renderer, scene, View(pose, k), light, OPTIONS, sensor,
                                   Motion(body_angular_velocity=(0.0, 0.0, omega)))
    _, _, var0 = centroid(still, (63.5, 63.5), half=20)
    cu, cv, var = centroid(rad, (63.5, 63.5), half=20)
    length = 2 * 1000.0 * math.sin(omega * t_exp / 2) * k.fx / 4000.0  # chord, in pixels
    assert math.sqrt(12 * (var - var0)) == pytest.approx(length, abs=0.5), info
    assert info["samples"] >= 2 * length
