"""Binary scenes from scenario files: parsing, a rendered run's truth, and the render server."""

import json

import numpy as np
import pytest

from render.scenario import parse_scenario
from terrain.core.errors import InvalidParameterError
from tests.render.server_helpers import served


def _scenario(primary="p.npz", secondary="s.npz", orbit=None, extra_scene="", frames=2):
    orbit = orbit or 'semi_major_axis = 1190.0\nmean_anomaly = 30.0\ninclination = 10.0'
    return f"""
name = "binary-test"
seed = 3
[scene]
type = "binary"
primary = "{primary}"
secondary = "{secondary}"
{extra_scene}
[scene.orbit]
{orbit}
[scene.primary_spin]
axis = [0.0, 0.0, 1.0]
period = 8136.0
[sun]
direction = [0.3, 0.9, 0.3]
[surface]
albedo = 0.2
reflectance = "lommel-seeliger"
[camera]
width = 64
height = 64
fov = 40.0
[sensor]
bits = 8
exposure = 3.0
gain = 0.0
read_noise = 0.0
[render]
shadow_size = 512
[trajectory]
type = "approach"
frames = {frames}
duration = 600.0
start_distance = 5000.0
end_distance = 4000.0
direction = [0.3, 1.0, 0.2]
"""


def _parse(text):
    import tomllib

    return parse_scenario(tomllib.loads(text))


@pytest.mark.parametrize("change, message", [
    ({"orbit": "semi_major_axis = 1190.0\nsemi_major_axes = 2.0"}, "semi_major_axis"),
    ({"orbit": "eccentricity = 1.5"}, "eccentricity"),
    ({"extra_scene": "spin_period = 10.0"}, "primary_spin"),
    ({"extra_scene": "body = 'x.npz'"}, "does not apply to a binary"),
    ({"extra_scene": "secondary_spinn = {period = 1.0}"}, "secondary_spin"),
])
def test_bad_binary_scenes_are_refused_in_one_line(change, message):
    with pytest.raises(InvalidParameterError, match=message):
        _parse(_scenario(**change))


def test_binary_keys_are_refused_in_a_single_body_scene():
    with pytest.raises(InvalidParameterError, match="primary belongs to a binary scene"):
        _parse('[scene]\ntype = "asteroid"\nbody = "a.npz"\nprimary = "b.npz"\n'
               '[trajectory]\ntype = "keyframes"\n[[trajectory.keyframe]]\ntime = 0.0\n'
               'position = [1e4, 0, 0]\nlook_at = [0, 0, 0]\n')


def test_the_orbit_and_spins_come_through():
    s = _parse(_scenario(orbit="semi_major_axis = 1500.0\neccentricity = 0.1\nperiod = 1e5"))
    assert s.scene.orbit.semi_major_axis == 1500.0 and s.scene.orbit.period == 1e5
    assert s.scene.primary_spin.period == 8136.0 and s.scene.secondary_spin is None
    assert s.scene.inputs() == ("p.npz", "s.npz")


@pytest.fixture(scope="module")
def binary_files(tmp_path_factory):
    from asteroid.body import Body, save_native
    from asteroid.sphere import SphereMesh

    folder = tmp_path_factory.mktemp("binary")
    save_native(folder / "p.npz", Body.sphere(SphereMesh(32), 390.0))
    save_native(folder / "s.npz", Body.sphere(SphereMesh(16), 80.0))
    path = folder / "binary.toml"
    path.write_text(_scenario())
    return path


def test_a_run_records_each_bodys_pose_and_labels_its_pixels(binary_files, tmp_path, gl):
    from render.rundir import RunReader
    from render.scenario import load_scenario
    from render.sequence import run_sequence

    scenario = load_scenario(binary_files)
    run_sequence(scenario, tmp_path / "run")
    run = RunReader(tmp_path / "run")
    orbit = scenario.scene.orbit
    for k, truth in enumerate(run.truth):
        p, s = orbit.positions(truth.time)
        bodies = {b["name"]: b for b in truth.bodies}
        assert np.allclose(bodies["primary"]["position"], p)
        assert np.allclose(bodies["secondary"]["position"], s)
        ids = run.body_ids(k)
        rng = run.range(k)
        assert ids.dtype == np.uint8 and set(np.unique(ids)) <= {0, 1, 2}
        assert np.array_equal(ids == 0, np.isnan(rng))  # the sky, and only it, is 0
        assert (ids == 1).sum() > 100
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["scene"] == "binary"
    assert manifest["binary"]["orbit"]["semi_major_axis"] == 1190.0
    assert manifest["binary"]["secondary_spin"] == "tidally locked"


def test_the_server_serves_a_binary(binary_files, tmp_path, gl):
    from render.camera import look_at
    from render.client import Client
    from render.errors import ServerError
    from render.scenario import load_scenario

    orbit = load_scenario(binary_files).scene.orbit
    t = 1234.5
    p, s = orbit.positions(t)
    pose = look_at(p + np.array([3000.0, 500.0, 800.0]), p)
    with served(binary_files) as (_, port), Client(port=port) as c:
        info = c.info()
        assert info["scene"] == "binary" and info["protocol_minor"] >= 2
        c.set_pose(pose.position, pose.attitude, time=t)
        ids = c.get_body_ids()
        rng = c.get_range()
        assert np.array_equal(ids == 0, np.isnan(rng)) and (ids == 1).sum() > 100
        truth = c.get_truth()
        assert np.allclose(truth["bodies"][1]["position"], s)
        inside = s + np.array([10.0, 0.0, 0.0])  # within the secondary at that time
        with pytest.raises(ServerError, match="inside"):
            c.set_pose(tuple(inside), pose.attitude, time=t)


def test_the_example_scenario_parses():
    from pathlib import Path

    from render.scenario import load_scenario

    s = load_scenario(Path(__file__).resolve().parents[2] / "examples" / "didymos_binary.toml")
    assert s.scene.type == "binary" and s.scene.orbit.semi_major_axis == 1190.0


def test_body_ids_over_the_wire_need_a_binary(tmp_path):
    """GET_BODY_IDS of a single-body or terrain scene is UNSUPPORTED; the connection lives."""
    import struct

    from render import server as mod
    from render.protocol import ErrorCode, MsgType
    from render.scenario import load_scenario
    from tests.render.scenes import descent_scenario

    path = tmp_path / "s.toml"
    path.write_text(descent_scenario(tmp_path / "stack", "ids"))
    srv = mod.RenderServer(load_scenario(path), port=0)
    sc = srv.scenario

    class _Conn:
        state = mod._State(sc, sc.lighting, {})

    rtype, reply = srv._reply(_Conn(), MsgType.GET_BODY_IDS, b"")
    code, _ = struct.unpack_from("<HH", reply)
    assert rtype == 0xFFFF and code == ErrorCode.UNSUPPORTED
    assert "binary" in reply[4:].decode()


def test_a_missing_body_is_one_line_and_exit_2(tmp_path):
    from click.testing import CliRunner

    from terrain.cli.commands import main

    path = tmp_path / "b.toml"
    path.write_text(_scenario(primary="nowhere.npz"))
    r = CliRunner().invoke(main, ["render", "frame", str(path), "-o", str(tmp_path / "f.png")])
    assert r.exit_code == 2
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and "nowhere.npz" in lines[0], r.output
