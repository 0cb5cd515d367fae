"""Camera conventions: projection, unprojection, quaternions, look-at, trajectories."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from render.camera import Intrinsics, look_at, quat_from_matrix, quat_to_matrix, slerp
from render.trajectory import approach, descent, keyframes
from terrain.core.errors import InvalidParameterError


def test_intrinsics_from_field_of_view():
    k = Intrinsics.from_fov(640, 480, 90.0)
    assert k.fx == pytest.approx(320.0)
    assert k.fov_x == pytest.approx(90.0)
    assert (k.cx, k.cy) == (319.5, 239.5)
    with pytest.raises(InvalidParameterError):
        Intrinsics(0, 10, 1, 1, 0, 0)


@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1))
def test_quaternion_matrix_roundtrip(q):
    m = quat_to_matrix(q)
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(m) == pytest.approx(1.0)
    assert np.allclose(quat_to_matrix(quat_from_matrix(m)), m, atol=1e-12)


def test_project_and_unproject_are_inverse():
    k = Intrinsics(800, 600, 700.0, 710.0, 401.3, 297.8)
    pose = look_at((10.0, -50.0, 30.0), (0.0, 0.0, 0.0))
    rng = np.random.default_rng(1)
    pts = rng.normal(scale=5.0, size=(100, 3))
    uv = pose.project(pts, k)
    ranges = np.linalg.norm(pts - np.array(pose.position), axis=1)
    assert np.allclose(pose.unproject(uv, ranges, k), pts, atol=1e-9)


def test_look_at_conventions():
    pose = look_at((0.0, -10.0, 0.0), (0.0, 0.0, 0.0))  # looking north, z up
    r = pose.rotation
    assert np.allclose(r[:, 2], [0, 1, 0])   # optical axis north
    assert np.allclose(r[:, 0], [1, 0, 0])   # image right = east
    assert np.allclose(r[:, 1], [0, 0, -1])  # image down = world down
    k = Intrinsics.from_fov(101, 101, 60.0)
    assert np.allclose(pose.project([[0.0, 0.0, 0.0]], k), [[50.0, 50.0]])
    assert pose.project([[0.0, 0.0, 1.0]], k)[0, 1] < 50.0  # up in the world is up the image


def test_slerp_endpoints_and_midpoint():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = quat_from_matrix(quat_to_matrix([np.cos(0.5), 0, 0, np.sin(0.5)]))
    assert np.allclose(slerp(q0, q1, 0.0), q0)
    assert np.allclose(slerp(q0, q1, 1.0), q1)
    mid = quat_to_matrix(slerp(q0, q1, 0.5))
    angle = np.degrees(np.arctan2(mid[1, 0], mid[0, 0]))
    assert angle == pytest.approx(np.degrees(0.5))


def test_descent_profile_is_geometric_and_looks_at_the_site():
    samples = descent(5, (100.0, 200.0, -50.0), start_altitude=1000.0, end_altitude=10.0,
                      duration=8.0, ground_track=(500.0, 0.0))
    alts = [s.pose.position[2] + 50.0 for s in samples]
    assert alts[0] == pytest.approx(1000.0) and alts[-1] == pytest.approx(10.0)
    ratios = np.array(alts[1:]) / np.array(alts[:-1])
    assert np.allclose(ratios, ratios[0])
    k = Intrinsics.from_fov(64, 64, 40.0)
    for s in samples:
        assert np.allclose(s.pose.project([[100.0, 200.0, -50.0]], k), [[31.5, 31.5]])
    assert [s.time for s in samples] == [0.0, 2.0, 4.0, 6.0, 8.0]


def test_keyframes_pass_through_keys_and_approach_spins():
    keys = [dict(time=0.0, position=[0, 0, 10], look_at=[0, 0, 0]),
            dict(time=1.0, position=[5, 0, 10], look_at=[1, 0, 0]),
            dict(time=2.0, position=[5, 5, 12], look_at=[1, 1, 0])]
    s = keyframes(5, keys)
    assert np.allclose(s[0].pose.position, [0, 0, 10])
    assert np.allclose(s[2].pose.position, [5, 0, 10])
    assert np.allclose(s[4].pose.position, [5, 5, 12])
    a = approach(3, start_distance=1000.0, end_distance=10.0, duration=10.0,
                 spin_period=20.0)
    assert np.linalg.norm(a[-1].pose.position) == pytest.approx(10.0)
    angle = 2 * np.degrees(np.arccos(a[1].body_rotation[0]))
    assert angle == pytest.approx(90.0)  # 5 s of a 20 s spin
