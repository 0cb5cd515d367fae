"""The mutual orbit against an independent two-body integration, and the bodies' spins."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from render.camera import quat_to_matrix
from render.orbit import MutualOrbit, Spin
from terrain.core.errors import InvalidParameterError


@pytest.mark.parametrize("elements", [
    {},  # Didymos-like, circular
    {"eccentricity": 0.3, "inclination": 35.0, "node": 120.0, "periapsis": 70.0,
     "mean_anomaly": 200.0, "mass_ratio": 0.4},
])
def test_positions_follow_newtons_two_body_problem(elements):
    orbit = MutualOrbit(**elements)
    gm = 4 * np.pi**2 * orbit.semi_major_axis**3 / orbit.period**2  # Kepler's third law
    q = orbit.mass_ratio
    m1, m2 = gm / (1 + q), gm * q / (1 + q)  # G m of each body
    p0, s0 = orbit.positions(0.0)
    dt = 1e-3  # the initial velocities by a central difference of the positions
    v1 = (orbit.positions(dt)[0] - orbit.positions(-dt)[0]) / (2 * dt)
    v2 = (orbit.positions(dt)[1] - orbit.positions(-dt)[1]) / (2 * dt)

    def rhs(_, y):
        r = y[3:6] - y[0:3]
        a = r / np.linalg.norm(r) ** 3
        return np.concatenate([y[6:9], y[9:12], m2 * a, -m1 * a])

    times = orbit.period * np.array([0.1, 0.37, 0.5, 0.81, 1.6])
    sol = solve_ivp(rhs, (0.0, times[-1]), np.concatenate([p0, s0, v1, v2]), t_eval=times,
                    rtol=1e-11, atol=1e-6)
    for j, t in enumerate(times):
        p, s = orbit.positions(t)
        assert np.linalg.norm(p - sol.y[0:3, j]) < 1e-3
        assert np.linalg.norm(s - sol.y[3:6, j]) < 1e-3


def test_a_circular_orbit_keeps_its_separation_and_period():
    orbit = MutualOrbit(semi_major_axis=1200.0, inclination=40.0, node=10.0)
    t = np.linspace(0, orbit.period, 17)
    sep = np.linalg.norm(orbit.relative(t), axis=1)
    assert np.allclose(sep, 1200.0, rtol=1e-12)
    assert np.allclose(orbit.relative(orbit.period), orbit.relative(0.0), atol=1e-6)
    normal = np.cross(orbit.relative(0.0), orbit.relative(orbit.period / 4))
    assert np.degrees(np.arccos(normal[2] / np.linalg.norm(normal))) == pytest.approx(40.0)


def test_a_tidally_locked_secondary_faces_the_primary():
    orbit = MutualOrbit(inclination=20.0, node=50.0, periapsis=30.0, mean_anomaly=10.0)
    for t in np.linspace(0, orbit.period, 7):
        p, s = orbit.positions(t)
        x_body = quat_to_matrix(orbit.locked_rotation(t))[:, 0]
        to_primary = (p - s) / np.linalg.norm(p - s)
        assert x_body @ to_primary == pytest.approx(1.0, abs=1e-12)


def test_a_spin_turns_once_per_period_about_its_axis():
    spin = Spin((0.0, 1.0, 1.0), 3600.0, 30.0)
    r0, r1 = quat_to_matrix(spin.rotation(0.0)), quat_to_matrix(spin.rotation(3600.0))
    assert np.allclose(r0, r1, atol=1e-12)
    axis = np.array([0.0, 1.0, 1.0]) / np.sqrt(2)
    assert np.allclose(quat_to_matrix(spin.rotation(900.0)) @ axis, axis)


@pytest.mark.parametrize("table, message", [
    ({"eccentricity": 1.0}, "eccentricity"),
    ({"semi_major_axis": -5.0}, "semi_major_axis"),
    ({"mass_ratio": 2.0}, "mass_ratio"),
    ({"perod": 10.0}, "period"),
])
def test_bad_orbits_are_refused_by_name(table, message):
    with pytest.raises(InvalidParameterError, match=message):
        MutualOrbit.from_mapping(table)


@given(a=st.floats(10.0, 1e5), e=st.floats(0.0, 0.95), inc=st.floats(0.0, 180.0),
       node=st.floats(-360.0, 360.0), peri=st.floats(-360.0, 360.0),
       m0=st.floats(-720.0, 720.0), q=st.floats(1e-4, 1.0), t=st.floats(-1e7, 1e7))
def test_any_orbit_keeps_its_barycentre_and_its_separation_bounds(a, e, inc, node, peri, m0,
                                                                   q, t):
    orbit = MutualOrbit(a, e, inc, node, peri, m0, 3600.0, q)
    p, s = orbit.positions(t)
    assert np.allclose(p + q * s, 0.0, atol=1e-9 * a)  # m1 p + m2 s = 0
    d = np.linalg.norm(s - p)
    assert a * (1 - e) * (1 - 1e-9) <= d <= a * (1 + e) * (1 + 1e-9)
