"""Radar and LIDAR through the renderer: a rendered plane against numpy rays, and a descent."""

from __future__ import annotations

import math

import numpy as np
import pytest

from render.camera import look_at
from render.lidar import Lidar, flash
from render.radar import RadarBeam, measure
from render.renderer import Lighting, RenderOptions
from tests.render.analytic import plane_look


def plane_mesh(normal, half=5000.0, grid=8):
    """A square of side 2 half through the origin with that normal, as triangles."""
    from render.mesh_scene import MeshScene

    m = np.asarray(normal, float) / np.linalg.norm(normal)
    a = np.cross(m, [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(m, a)
    g = np.linspace(-half, half, grid + 1)
    s, t = np.meshgrid(g, g)
    verts = (s.ravel()[:, None] * a + t.ravel()[:, None] * b).astype(np.float64)
    faces = []
    n = grid + 1
    for i in range(grid):
        for j in range(grid):
            p = i * n + j
            faces += [(p, p + 1, p + n + 1), (p, p + n + 1, p + n)]
    f = np.array(faces, np.int64)
    # wind every face towards the normal
    e = np.cross(verts[f[:, 1]] - verts[f[:, 0]], verts[f[:, 2]] - verts[f[:, 0]])
    flip = e @ m < 0
    f[flip] = f[flip][:, ::-1]
    return MeshScene(verts, f)


@pytest.mark.parametrize("tilt", [0.0, 30.0])
def test_rendered_radar_and_flash_lidar_agree_with_numpy_rays_on_a_plane(renderer, tilt):
    from render.instruments import renderer_look

    t = math.radians(tilt)
    m = (math.sin(t), 0.0, math.cos(t))
    scene = plane_mesh(m)
    light = Lighting((0.3, 0.2, 1.0))
    opts = RenderOptions(shadows=False)
    pose = look_at((0.0, 0.0, 800.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    look = renderer_look(renderer, scene, light, opts, 0.0, albedo=True)
    beam = RadarBeam(direction=(0.2, 0.0, 1.0), width=4.0, pixels=48)
    v = (12.0, 3.0, -9.0)
    got, want = measure(beam, look, pose, v), measure(beam, plane_look(normal=m), pose, v)
    assert got.range == pytest.approx(want.range, rel=1e-4)
    assert got.velocity == pytest.approx(want.velocity, abs=0.01)
    lid = Lidar(width=8, height=6, fov=3.0, divergence=0.6, supersample=4, threshold=0.0)
    a, b = flash(lid, look, pose), flash(lid, plane_look(normal=m), pose)
    assert np.allclose(a.range, b.range, rtol=2e-5)
    assert np.allclose(a.power, b.power, rtol=1e-3)   # the read-back albedo is 1 everywhere


@pytest.mark.slow
def test_a_descent_with_radar_and_lidar_writes_their_files(tmp_path, gl):
    from render.scenario import load_scenario
    from render.sequence import run_sequence
    from tests.render.scenes import cratered_stack, descent_scenario

    stack = cratered_stack(tmp_path / "stack")
    text = descent_scenario(stack, "instruments", frames=2) + """
[[radar]]
direction = [0.0, 0.0, 1.0]
width = 3.0
pixels = 32
[[radar]]
direction = [0.3, 0.0, 1.0]
width = 3.0
pixels = 32
[lidar]
width = 16
height = 12
fov = 20.0
divergence = 2.0
supersample = 2
range_noise = 0.02
"""
    (tmp_path / "s.toml").write_text(text)
    manifest = run_sequence(load_scenario(tmp_path / "s.toml"), tmp_path / "run")
    run_sequence(load_scenario(tmp_path / "s.toml"), tmp_path / "again")
    for name in ("radar.npz", "lidar.npz"):   # the same scenario and seed, the same arrays
        with np.load(tmp_path / "run" / name) as f, np.load(tmp_path / "again" / name) as g:
            assert sorted(f.files) == sorted(g.files)
            assert all(np.array_equal(f[k], g[k], equal_nan=f[k].dtype.kind == "f")
                       for k in f.files)
    assert manifest["radar"]["measurements"] == 4
    assert manifest["lidar"]["measurements"] == 2 * 16 * 12
    with np.load(tmp_path / "run" / "radar.npz") as f:
        assert f["range"].shape == (2, 2) and np.all(np.isfinite(f["range"]))
        assert f["histogram_1"].shape == (2, 64, 128)
        assert f["range"][1, 0] < f["range"][0, 0]            # the descent closes in
    with np.load(tmp_path / "run" / "lidar.npz") as f:
        assert f["range"].shape == (2, 12, 16)
        assert np.nanmedian(f["range"][1]) < np.nanmedian(f["range"][0])
    # `render frame` writes the same measurements for its one frame
    from tests.cli_helpers import run

    r = run("render", "frame", tmp_path / "s.toml", "-o", tmp_path / "one.png", "--index", 1)
    assert r.exit_code == 0, r.output
    for name in ("radar", "lidar"):
        with np.load(tmp_path / f"one_{name}.npz") as f, \
                np.load(tmp_path / "run" / f"{name}.npz") as g:
            assert np.array_equal(f["range"][0], g["range"][1], equal_nan=True)


def test_a_scan_through_the_renderer_follows_a_descent_point_by_point(renderer):
    from render.instruments import renderer_look
    from render.lidar import scan
    from render.motion import Motion

    scene = plane_mesh((0.0, 0.0, 1.0))
    look = renderer_look(renderer, scene, Lighting((0.3, 0.2, 1.0)), RenderOptions(), 0.0,
                         albedo=True)
    pose = look_at((0.0, 0.0, 300.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    lid = Lidar(mode="scan", width=8, height=8, fov=6.0, point_rate=64.0, supersample=1,
                threshold=0.0, tolerance=0.05, pattern="spiral")
    sc = scan(lid, look, pose, 0.0, Motion(velocity=(0.0, 0.0, -50.0)))
    # numpy: each point's ray, from where the sensor was at its time, meets z = 0 at
    want = sc.position[:, 2] / -sc.direction[:, 2]
    assert np.max(np.abs(sc.range - want)) < 0.3        # within the slices' tolerance
    assert sc.range[-1] < sc.range[0] - 40.0            # 50 m lower after 63/64 s


def test_unknown_keys_in_the_new_tables_are_refused(tmp_path):
    import tomllib

    from render.scenario import parse_scenario
    from terrain.core.errors import InvalidParameterError
    from tests.render.scenes import descent_scenario

    base = tomllib.loads(descent_scenario(tmp_path, "keys"))
    with pytest.raises(InvalidParameterError, match="unknown radar key 'widht'"):
        parse_scenario(dict(base, radar={"widht": 2.0}))
    with pytest.raises(InvalidParameterError, match="unknown lidar key 'powr'"):
        parse_scenario(dict(base, lidar={"powr": 2.0}))
    with pytest.raises(InvalidParameterError, match="radar"):
        parse_scenario(dict(base, radar=[1, 2]))
    s = parse_scenario(dict(base, radar=[{"width": 2.0}, {"width": 3.0}], lidar={"mode": "scan"}))
    assert [b.width for b in s.radar] == [2.0, 3.0] and s.lidar.mode == "scan"
