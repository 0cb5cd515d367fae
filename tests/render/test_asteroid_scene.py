"""Asteroid scenes: patch culling, levels of detail, boulders, imposters, spin."""

import numpy as np
import pytest
from click.testing import CliRunner

from render.asteroid_scene import AsteroidScene
from render.camera import Intrinsics, look_at
from render.renderer import Lighting, RenderOptions, View
from render.trajectory import axis_angle

LIGHT = Lighting((0.4, -0.7, 0.5), albedo=0.2, brdf="lommel-seeliger")


@pytest.fixture(scope="module")
def sphere_scene():
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh

    return AsteroidScene(Body.sphere(SphereMesh(128), 1000.0), boulders=False)


@pytest.fixture(scope="module")
def rocky(tmp_path_factory):
    from terrain.cli.commands import main

    out = tmp_path_factory.mktemp("body") / "rocky.npz"
    r = CliRunner().invoke(main, ["asteroid", "build", "-o", str(out), "--magnitude", "32",
                                  "--radius", "300", "--base", "perlin", "--seed", "4",
                                  "--boulders", "c=0.05,k=-3,dmin=4,dmax=30"])
    assert r.exit_code == 0, r.output
    return out


def test_range_of_a_spherical_body_is_exact(renderer, sphere_scene):
    k = Intrinsics.from_fov(160, 120, 45.0)
    pose = look_at((2500.0, 800.0, -1200.0), (0.0, 0.0, 0.0))
    # the finest level of detail (coarser ones are faceted by design)
    frame = renderer.render(sphere_scene, View(pose, k), LIGHT,
                            RenderOptions(shadows=False, lod_pixels=0.1))
    c = np.asarray(pose.position)
    d = k.rays() @ pose.rotation.T
    b = d @ c
    disc = b**2 - (c @ c - 1000.0**2)
    hit = disc > 0.05 * 1000.0**2
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    assert hit.sum() > 3000
    assert np.nanmax(np.abs(frame.range[hit] - t[hit]) / t[hit]) < 1e-4
    assert frame.drawn["body_magnitude"] == 128


def test_patch_culling_changes_nothing_it_should_not(renderer, sphere_scene, monkeypatch):
    k = Intrinsics.from_fov(128, 128, 20.0)
    pose = look_at((1300.0, 0.0, 300.0), (900.0, 100.0, 200.0))  # close, looking at a limb
    culled = renderer.render(sphere_scene, View(pose, k), LIGHT, RenderOptions(shadows=False))
    assert culled.drawn["patches"] < culled.drawn["patches_total"]
    import render.asteroid_scene as mod

    monkeypatch.setattr(mod, "_sphere_visible", lambda c, r, k: np.ones(len(r), bool))
    full = renderer.render(sphere_scene, View(pose, k), LIGHT, RenderOptions(shadows=False))
    assert full.drawn["patches"] == full.drawn["patches_total"]
    assert culled.radiance.tobytes() == full.radiance.tobytes()
    assert np.array_equal(culled.range, full.range, equal_nan=True)


def test_far_bodies_become_imposters_with_true_range(renderer, sphere_scene):
    k = Intrinsics.from_fov(256, 256, 10.0)
    pose = look_at((120000.0, 30000.0, 20000.0), (0.0, 0.0, 0.0))
    options = RenderOptions(shadows=False, lod_pixels=0.5)
    light = Lighting((1.0, 0.1, 0.3), albedo=0.2, brdf="lommel-seeliger")  # a full disc
    imp = renderer.render(sphere_scene, View(pose, k), light, options)
    assert imp.drawn["imposter"] is True
    sphere_scene.imposter_pixels = 0.0
    try:
        direct = renderer.render(sphere_scene, View(pose, k), light, options)
    finally:
        sphere_scene.imposter_pixels = 24.0
    assert direct.drawn["imposter"] is False
    both = np.isfinite(imp.range) & np.isfinite(direct.range)
    assert both.sum() >= 0.8 * np.isfinite(direct.range).sum() > 50
    # nearest imposter texel: exact away from the limb, where range changes fast per pixel
    rel = np.abs(imp.range[both] - direct.range[both]) / direct.range[both]
    assert np.median(rel) < 1e-3
    # radiance: interpolated from the imposter; compare on the lit disc away from limb and
    # terminator, where a few texels of resampling cannot matter
    from scipy import ndimage

    lit = ndimage.binary_erosion(both, iterations=2) & (direct.normals @ np.asarray(light.sun)
                                                        > 0.3)
    assert lit.sum() > 20
    ratio = imp.radiance[lit] / direct.radiance[lit]
    assert abs(np.median(ratio) - 1) < 0.03


def test_boulders_take_levels_of_detail_by_distance(renderer, rocky):
    scene = AsteroidScene(rocky)
    assert scene.boulders is not None and len(scene.boulders) > 20
    k = Intrinsics.from_fov(256, 256, 40.0)
    far = renderer.render(scene, View(look_at((3000.0, 0, 0), (0, 0, 0)), k), LIGHT,
                          RenderOptions(shadows=False))
    near = renderer.render(scene, View(look_at((420.0, 0, 0), (0, 0, 0)), k), LIGHT,
                           RenderOptions(shadows=False))
    finest_far = max(int(x) for x in far.drawn["boulders"])
    finest_near = max(int(x) for x in near.drawn["boulders"])
    assert finest_near > finest_far


def test_spin_turns_the_body_under_the_camera(renderer, rocky):
    scene = AsteroidScene(rocky, boulders=False)
    k = Intrinsics.from_fov(96, 96, 40.0)
    pose = look_at((1500.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    a = renderer.render(scene, View(pose, k), LIGHT, RenderOptions(shadows=False))
    scene.set_body_rotation(axis_angle((0, 0, 1), np.pi / 2))
    b = renderer.render(scene, View(pose, k), LIGHT, RenderOptions(shadows=False))
    assert not np.array_equal(a.range, b.range, equal_nan=True)
    # the vertex now facing the camera is the one that faced +y before the quarter turn
    body = scene.body
    direction = np.array([0.0, -1.0, 0.0])  # R_WB maps body -y to world +x
    r = float(body.surface_radius(direction[None, :])[0])
    centre_range = b.range[47:49, 47:49].mean()
    assert centre_range == pytest.approx(1500.0 - r, rel=0.01)
    scene.set_body_rotation((1.0, 0.0, 0.0, 0.0))


def test_an_approach_through_levels_and_the_imposter_stays_consistent(renderer, rocky):
    """Imposter fading out, body levels and boulder levels changing: no pair jumps; a
    frame whose levels are forced four steps coarser, switched, is caught."""
    from evaluation.consistency import SPIKE_BOUND, change_marks, pair_residual
    from render.rundir import FrameTruth
    from render.sensor import Sensor

    scene = AsteroidScene(rocky)
    k = Intrinsics.from_fov(128, 128, 40.0)
    sensor = Sensor(bits=16, exposure=1.5)
    poses = [look_at((d, 0.3 * d, 0.2 * d), (0.0, 0.0, 0.0))
             for d in np.geomspace(6000.0, 1500.0, 24)]

    def frame(i, lod=3.0, morph=True):
        # direct light only: light scattered into the shadows softens the switched frame's
        # contrast (its pair's spike drops from 1.51 to 1.45 medians, the bound being 1.5);
        # what is checked here is the levels of detail
        f = renderer.render(scene, View(poses[i], k), LIGHT,
                            RenderOptions(shadow_size=1024, lod_pixels=lod, geomorph=morph,
                                          scattering=False))
        return (sensor.expose(f.radiance), f.range, f.normals,
                FrameTruth(i, 0.0, poses[i], k, LIGHT.sun, drawn=f.drawn))

    def rms(frames):
        return np.array([pair_residual(a[0], b[0], a[1], b[1], a[3], b[3], normals0=a[2],
                                       normals1=b[2]).rms_dn
                         for a, b in zip(frames[:-1], frames[1:], strict=True)])

    frames = [frame(i) for i in range(len(poses))]
    drawn = [f[3].drawn for f in frames]
    layer, _ = change_marks(drawn)
    assert drawn[0]["imposter"] and not drawn[-1]["imposter"]
    assert any("imposter_fade" in d for d in drawn)
    assert len({d["body_magnitude"] for d in drawn}) >= 3 and layer.sum() >= 3
    r = rms(frames)
    assert r.max() <= SPIKE_BOUND * np.median(r)
    popped = 14
    frames[popped] = frame(popped, lod=3.0 * 16, morph=False)  # switched, coarser levels
    r = rms(frames)
    assert np.flatnonzero(r > SPIKE_BOUND * np.median(r)).tolist() == [popped - 1, popped]


def test_the_shadow_map_is_the_same_from_near_and_far(renderer, rocky):
    """Fixed sun, fixed body rotation: the map (projection and depths) ignores the camera,
    although the body is drawn at different levels of detail from the two distances."""
    scene = AsteroidScene(rocky)
    k = Intrinsics.from_fov(128, 128, 40.0)
    maps, levels = [], []
    for d in (6000.0, 700.0):
        f = renderer.render(scene, View(look_at((d, 0.3 * d, 0.2 * d), (0, 0, 0)), k), LIGHT,
                            RenderOptions(shadow_size=512))
        levels.append(f.drawn["body_magnitude"])
        m = scene._shadow
        maps.append((m.light_from_world.copy(), m.texture.read()))
    assert levels[0] != levels[1]
    assert np.array_equal(maps[0][0], maps[1][0]) and maps[0][1] == maps[1][1]

