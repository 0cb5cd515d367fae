"""The spacecraft lamp against the analytic radiance of a Lambertian plane it lights.

A nadir camera h above a plane carries a lamp of intensity I at its centre: a pixel whose
ray leaves the axis at angle t sees the plane at r = h / cos t, lit at incidence t, so its
I/F on the sun's scale is A cos^3 t I / (h^2 F) inside the cone and nothing outside it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.lamp import Lamp, lamp_if
from render.renderer import Lighting
from terrain.core.errors import InvalidParameterError


def _plane(h, k):
    v, u = np.mgrid[0:k.height, 0:k.width].astype(float)
    x, y = (u - k.cx) / k.fx, (v - k.cy) / k.fy
    cos_t = 1.0 / np.sqrt(1.0 + x * x + y * y)
    rng = h / cos_t
    normals = np.zeros((k.height, k.width, 3))
    normals[..., 2] = 1.0
    return rng, normals, cos_t


def test_a_lamp_lights_a_plane_as_the_inverse_square_law_and_lambert_say():
    k = Intrinsics.from_fov(65, 65, 90.0)
    h, intensity, albedo, solar = 20.0, 400.0, 0.12, 1.58
    pose = look_at((0.0, 0.0, h), (0.0, 0.0, 0.0))
    rng, normals, cos_t = _plane(h, k)
    lighting = Lighting((0.0, 0.0, 1.0), albedo=albedo, brdf="lambert", irradiance=solar)
    lamp = Lamp(intensity, cone=35.0, falloff=0.0)
    got = lamp_if(lamp, rng, normals, pose, k, lighting)
    expect = albedo * cos_t**3 * intensity / (h * h * solar)
    inside = np.degrees(np.arccos(cos_t)) < 34.5
    outside = np.degrees(np.arccos(cos_t)) > 35.5
    assert np.allclose(got[inside], expect[inside], rtol=1e-5)
    assert not got[outside].any()


def test_sky_and_a_lamp_pointing_away_give_nothing_and_bad_tables_are_refused():
    k = Intrinsics.from_fov(16, 16, 60.0)
    pose = look_at((0.0, 0.0, 10.0), (0.0, 0.0, 0.0))
    rng, normals, _ = _plane(10.0, k)
    rng[:4] = np.nan
    lighting = Lighting((0.0, 0.0, 1.0))
    got = lamp_if(Lamp(50.0), rng, normals, pose, k, lighting)
    assert not got[:4].any() and got[8, 8] > 0
    away = lamp_if(Lamp(50.0, direction=(0.0, 0.0, -1.0)), rng, normals, pose, k, lighting)
    assert not away.any()
    with pytest.raises(InvalidParameterError, match="needs intensity"):
        Lamp.from_mapping({"cone": 20.0})
    with pytest.raises(InvalidParameterError, match="did you mean 'falloff'"):
        Lamp.from_mapping({"intensity": 1.0, "fallof": 2.0})
    with pytest.raises(InvalidParameterError, match="cone"):
        Lamp(1.0, cone=120.0)
    assert math.isclose(Lamp(1.0).beam(np.array([1.0]))[0], 1.0)


@pytest.mark.slow
def test_in_permanent_shadow_only_the_lamp_shows_the_ground(tmp_path, gl):
    """With the sun below the horizon the frame is black; the scenario's [lamp] lights it."""
    from render.rundir import RunReader
    from render.scenario import load_scenario
    from render.sequence import run_sequence
    from tests.render.scenes import cratered_stack, descent_scenario

    stack = cratered_stack(tmp_path / "stack")
    dark = descent_scenario(stack, "dark", frames=1).replace("elevation = 15.0",
                                                            "elevation = -5.0")
    (tmp_path / "dark.toml").write_text(dark)
    (tmp_path / "lamp.toml").write_text(dark + "\n[lamp]\nintensity = 5.0e5\ncone = 40.0\n")
    means = {}
    for name in ("dark", "lamp"):
        run_sequence(load_scenario(tmp_path / f"{name}.toml"), tmp_path / name)
        means[name] = float(RunReader(tmp_path / name).image(0).astype(float).mean())
    assert means["lamp"] > 10 * max(means["dark"], 1.0)
