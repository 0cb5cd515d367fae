"""SET_LIGHT over the render server: the sun on a date, and refusals of bad ones."""

import json
import struct

import numpy as np
import pytest

from render import ephemeris as eph
from tests.render.scenes import cratered_stack, descent_scenario
from tests.render.server_helpers import served

# docs/protocol.md, restated by hand
T_SET_LIGHT, T_ERROR, E_MALFORMED, E_INVALID = 0x0014, 0xFFFF, 5, 6
UTC = "2027-01-15T12:00:00"


class _Conn:
    def __init__(self, state):
        self.state = state


@pytest.fixture()
def server_state(tmp_path):
    """A server on a scenario whose scene is never loaded (the refusals come first)."""
    from render import server as mod
    from render.scenario import load_scenario

    path = tmp_path / "s.toml"
    path.write_text(descent_scenario(tmp_path / "stack", "light"))
    srv = mod.RenderServer(load_scenario(path), port=0)
    sc = srv.scenario
    return srv, _Conn(mod._State(sc, sc.lighting, {}))


@pytest.mark.parametrize("body, code, words", [
    ({"utc": "2027-02-30T00:00:00", "longitude": 0.0, "latitude": -89.0}, E_INVALID, "utc"),
    ({"utc": "tomorrow"}, E_INVALID, "utc"),
    ({"utc": UTC, "latitude": -89.0}, E_INVALID, "longitude and latitude"),
    ({"utcc": UTC}, E_INVALID, "did you mean 'utc'"),
    ({"utc": UTC, "kernels": ["/etc/passwd"]}, E_INVALID, "scenario file only"),
    ([1, 2], E_MALFORMED, "JSON object"),
])
def test_a_bad_sun_gets_an_error_reply(server_state, body, code, words):
    from render.protocol import MsgType

    srv, conn = server_state
    rtype, reply = srv._reply(conn, MsgType.SET_LIGHT, json.dumps(body).encode())
    assert rtype == T_ERROR
    got, _ = struct.unpack_from("<HH", reply)
    reason = reply[4:].decode()
    assert got == code and words in reason and "\n" not in reason


@pytest.mark.slow
def test_a_dated_sun_over_the_wire_is_the_ephemeris_sun(tmp_path, gl):
    """SET_LIGHT utc and a site, then a frame at pose time t: the truth's sun is the ephemeris
    Sun at utc + t, and INFO reports the minor version and the date."""
    from render.client import Client

    stack = cratered_stack(tmp_path / "stack")
    path = tmp_path / "serve.toml"
    path.write_text(descent_scenario(stack, "light"))
    with served(path, "--read-timeout", 3) as (_, port), Client("127.0.0.1", port) as c:
        sx, sy = c.info()["site"]
        c.set_pose((sx, sy, 1200.0), (0.0, 1.0, 0.0, 0.0), time=600.0)
        reply = c.set_light(utc=UTC, longitude=20.0, latitude=-80.0)
        sky = eph.lunar_sky(eph.et_from_utc(UTC) + 600.0, eph.Site(20.0, -80.0))
        assert np.allclose(reply["sun"], sky.sun, atol=1e-12)
        truth = c.get_truth()
        assert np.allclose(truth["sun"]["direction"], sky.sun, atol=1e-12)
        info = c.info()
        assert info["protocol_minor"] >= 1 and info["utc"] == UTC
        c.set_sensor(noise=False)  # the sensor changes, the dated sun stays
        assert np.allclose(c.get_truth()["sun"]["direction"], sky.sun, atol=1e-12)
        c.set_light(azimuth=100.0, elevation=15.0)  # back to a hand-set sun
        assert "utc" not in c.info()
