"""Gravitational slopes of mesh bodies and of binaries, against point masses.

Outside a homogeneous sphere its attraction is a point mass's, so two spheres on their orbit
give an independent reference for the whole effective gravity: the body's own pull, the
companion's tide (its pull minus its pull at the body's centre) and the spin's centrifugal
term.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from asteroid.sphere import SphereMesh
from evaluation.gravity import GRAVITATIONAL_CONSTANT as G
from render.camera import quat_to_matrix
from render.orbit import MutualOrbit, Spin

R1, R2 = 300.0, 200.0


def _point_masses(orbit, spin, t, vertices):
    """Effective gravity on the primary's vertices (its body frame) from point masses."""
    c1, c2 = orbit.positions(t)
    rot = quat_to_matrix(spin.rotation(t))
    w = vertices @ rot.T + c1
    total = orbit.gm / G
    m1, m2 = total / (1 + orbit.mass_ratio), total * orbit.mass_ratio / (1 + orbit.mass_ratio)
    own = -G * m1 * (w - c1) / np.linalg.norm(w - c1, axis=1)[:, None] ** 3
    d = w - c2
    tide = -G * m2 * d / np.linalg.norm(d, axis=1)[:, None] ** 3 \
        + G * m2 * (c1 - c2) / np.linalg.norm(c1 - c2) ** 3
    axis = np.asarray(spin.axis) / np.linalg.norm(spin.axis)
    rel = w - c1
    spin_term = (2 * math.pi / spin.period) ** 2 * (rel - np.outer(rel @ axis, axis))
    return (own + tide + spin_term) @ rot, (own + spin_term) @ rot


def test_a_binarys_effective_gravity_is_the_point_masses():
    from evaluation.meshslope import binary_slopes

    mesh = SphereMesh(32)
    primary = (mesh.directions() * R1, mesh.faces())
    secondary = (mesh.directions() * R2, mesh.faces())
    orbit = MutualOrbit(semi_major_axis=700.0, mass_ratio=0.5, period=40000.0,
                        mean_anomaly=20.0, inclination=15.0)
    spin = Spin(axis=(0.1, 0.0, 1.0), period=9000.0, phase=30.0)
    t = 500.0
    s = binary_slopes(primary, secondary, orbit=orbit, primary_spin=spin, t=t, radius_deg=0.0)
    ref, no_tide = _point_masses(orbit, spin, t, primary[0])
    err = np.linalg.norm(s.gravity - ref, axis=1) / np.linalg.norm(ref, axis=1)
    assert err.max() < 0.01  # the facets of a 6,146-vertex sphere
    # the companion matters here: leaving its tide out is far off
    assert (np.linalg.norm(s.gravity - no_tide, axis=1) / np.linalg.norm(no_tide, axis=1)
            ).max() > 0.05
    up = primary[0] / np.linalg.norm(primary[0], axis=1, keepdims=True)
    down = -ref / np.linalg.norm(ref, axis=1, keepdims=True)
    slope = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", down, up), -1, 1)))
    assert np.abs(s.gravitational_deg - slope).max() < 1.0


def test_a_mesh_body_npz_is_read_for_slopes(tmp_path):
    """A body kept as its own mesh (.npz) reads for slopes as its mesh file would."""
    from asteroid.packing import packing_body
    from asteroid.surface import save_mesh_native
    from evaluation.meshslope import load_body

    body = packing_body("contact-binary", radius=500.0, seed=1, cells=32)
    save_mesh_native(tmp_path / "cb.npz", body)
    shape = load_body(tmp_path / "cb.npz")
    assert shape.volume == pytest.approx(body.volume(), rel=1e-9)
    assert len(shape.faces) == len(body.faces)


def test_binary_slopes_from_a_scenario_on_the_command_line(tmp_path):
    """`craterscape evaluation binary-slopes SCENARIO` reads the binary's bodies and orbit."""
    import json

    from asteroid.body import Body, save_native
    from tests.cli_helpers import one_line_error, run

    save_native(tmp_path / "p.npz", Body.sphere(SphereMesh(12), 390.0))
    save_native(tmp_path / "s.npz", Body.sphere(SphereMesh(8), 80.0))
    scenario = tmp_path / "b.toml"
    scenario.write_text('name = "b"\n[scene]\ntype = "binary"\nprimary = "p.npz"\n'
                        'secondary = "s.npz"\n[trajectory]\ntype = "keyframes"\n'
                        '[[trajectory.keyframe]]\ntime = 0.0\nposition = [1e4, 0, 0]\n'
                        'look_at = [0, 0, 0]\n')
    r = run("evaluation", "binary-slopes", scenario, "-o", tmp_path / "out", "--body",
            "secondary", "--time", 100.0, "--radius-deg", 0.0)
    assert r.exit_code == 0, r.output
    summary = json.loads((tmp_path / "out" / "secondary_slopes.json").read_text())
    assert summary["info"]["body"] == "secondary" and summary["vertices"] == 6 * 64 + 2
    # the scenario's bodies, orbit (the default, Didymos-Dimorphos) and tidal lock: the same
    # slopes as the library gives for them
    from evaluation.meshslope import binary_slopes, load_body
    from render.scenario import load_scenario

    spec = load_scenario(scenario).scene
    p, s = (load_body(tmp_path / n) for n in ("p.npz", "s.npz"))
    ref = binary_slopes((p.vertices, p.faces), (s.vertices, s.faces), orbit=spec.orbit,
                        primary_spin=spec.primary_spin, t=100.0, which="secondary",
                        radius_deg=0.0)
    rows = np.genfromtxt(tmp_path / "out" / "secondary_vertex_slopes.csv", delimiter=",",
                         names=True)
    assert np.allclose(rows["gravitational_slope_deg"], ref.gravitational_deg, atol=1e-4)
    single = tmp_path / "one.toml"
    single.write_text(scenario.read_text().replace('type = "binary"\nprimary = "p.npz"\n'
                                                   'secondary = "s.npz"',
                                                   'type = "asteroid"\nbody = "p.npz"'))
    one_line_error(run("evaluation", "binary-slopes", single, "-o", tmp_path / "x"),
                   "needs a binary scenario")
