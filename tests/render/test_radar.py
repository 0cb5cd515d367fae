"""The radar altimeter and velocimeter against ray-traced analytic scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from render.camera import look_at
from render.radar import RadarBeam, beam_frame, measure
from terrain.core.errors import InvalidParameterError
from tests.render.analytic import plane_look

DOWN = look_at((0.0, 0.0, 1000.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("tilt", [0.0, 1.0, 10.0, 35.0])
def test_range_is_the_nearest_point_of_a_tilted_plane_inside_the_half_power_beam(tilt):
    # A plane whose normal leans `tilt` degrees from the beam: its nearest point in a cone of
    # half-angle a about the beam lies at d / cos(max(tilt - a, 0)) (d: distance to the plane).
    beam = RadarBeam(width=6.0, pixels=128)
    t = math.radians(tilt)
    m = (math.sin(t), 0.0, math.cos(t))
    ret = measure(beam, plane_look((0.0, 0.0, 0.0), m), DOWN, (0.0, 0.0, 0.0))
    d = 1000.0 * math.cos(t)
    lean = max(t - math.radians(3.0), 0.0)
    expected = d / math.cos(lean)
    # the beam is sampled one frame pixel apart: the nearest sample inside the cone may sit up
    # to one pixel inside its edge, where the range falls by R tan(lean) per radian
    pixel = math.radians(beam.width * beam.field) / beam.pixels
    assert expected * (1 - 1e-6) <= ret.range <= expected * (1 + math.tan(lean) * pixel) + 1e-3


def test_a_boulder_inside_the_beam_sets_the_range_and_one_outside_does_not():
    beam = RadarBeam(width=6.0, pixels=96)
    inside = ((20.0, -10.0, 0.0), 12.0)      # 1.3 degrees off the boresight
    outside = ((120.0, 0.0, 0.0), 30.0)      # 6.8 degrees off: beyond half power
    ret = measure(beam, plane_look(spheres=[inside, outside]), DOWN, (0.0, 0.0, 0.0))
    # numpy check: the ray to the sphere's nearest point; the sphere's nearest distance
    c = np.array(inside[0])
    assert ret.range == pytest.approx(np.linalg.norm(c - [0, 0, 1000.0]) - inside[1], abs=0.05)
    ret_out = measure(beam, plane_look(spheres=[outside]), DOWN, (0.0, 0.0, 0.0))
    assert ret_out.range == pytest.approx(1000.0, abs=0.01)  # the ray nearest the nadir


@pytest.mark.parametrize("pattern", ["gaussian", "sinc2", "uniform"])
@pytest.mark.parametrize("direction", [(0, 0, 1), (0.3, 0, 1), (0, -0.5, 1), (-0.4, 0.4, 1)])
def test_doppler_of_a_flat_plane_matches_v_dot_n_for_each_beam_direction(direction, pattern):
    beam = RadarBeam(direction=direction, width=2.0, pattern=pattern, pixels=64,
                     max_velocity=60.0, doppler_bins=240, range_bins=512)
    v = np.array([35.0, -12.0, -8.0])
    ret = measure(beam, plane_look(), DOWN, v)
    n = DOWN.rotation @ unit(direction)             # the beam in the world frame
    expected = float(v @ n)
    assert ret.boresight_velocity == pytest.approx(expected, abs=1e-9)
    assert ret.velocity == pytest.approx(expected, abs=0.05)
    profile = ret.histogram.sum(axis=0)
    peak = int(np.argmax(profile))
    assert ret.velocity_edges[peak] - 0.5 <= expected <= ret.velocity_edges[peak + 1] + 0.5
    assert ret.histogram.sum() == pytest.approx(1.0, abs=1e-9)


def test_a_turning_surface_adds_its_own_velocity():
    beam = RadarBeam(width=1.0, pixels=32)
    spin = (0.0, 0.0, 0.01)   # rad/s about the z axis through the origin: at (0, 0, 0) nothing
    pose = look_at((500.0, 0.0, 1000.0), (500.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    ret = measure(beam, plane_look(), pose, (0.0, 0.0, 0.0), body_angular_velocity=spin)
    # ground under the beam moves at omega x p = (0, 5, 0) m/s, perpendicular to the beam
    assert abs(ret.velocity) < 0.05
    pose2 = look_at((0.0, -500.0, 500.0), (500.0, 0.0, 0.0), up=(0.0, 0.0, 1.0))
    ret2 = measure(beam, plane_look(), pose2, (0.0, 0.0, 0.0), body_angular_velocity=spin)
    u = unit([500.0, 500.0, -500.0])
    assert ret2.velocity == pytest.approx(-np.array([0.0, 5.0, 0.0]) @ u, abs=0.05)


def test_beam_frame_looks_along_the_direction_and_keys_are_checked():
    bp = beam_frame(DOWN, (0.0, 0.6, 0.8))
    assert bp.rotation[:, 2] == pytest.approx(DOWN.rotation @ np.array([0.0, 0.6, 0.8]))
    with pytest.raises(InvalidParameterError, match="unknown radar key 'patern'.*pattern"):
        RadarBeam.from_mapping({"patern": "gaussian"})
    with pytest.raises(InvalidParameterError, match="pattern"):
        RadarBeam(pattern="cosine")
    with pytest.raises(InvalidParameterError, match="direction"):
        RadarBeam(direction=(0.0, 0.0, 0.0))
