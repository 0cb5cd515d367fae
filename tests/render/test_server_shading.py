"""SET_SHADING over the render server: per-connection shading switches, refusals of bad ones."""

import json
import socket
import struct

import numpy as np
import pytest

from tests.render.scenes import cratered_stack, descent_scenario
from tests.render.server_helpers import served

# docs/protocol.md, restated by hand
HDR = struct.Struct("<4sHHII")
T_INFO, T_PING, T_SET_POSE, T_SET_SHADING = 0x0002, 0x0003, 0x0010, 0x002A
T_ERROR, REPLY = 0xFFFF, 0x8000
E_MALFORMED, E_INVALID = 5, 6


class _Conn:
    def __init__(self, state):
        self.state = state


@pytest.fixture()
def server_state(tmp_path):
    """A server on a scenario whose scene is never loaded (the refusals come first)."""
    from render import server as mod
    from render.scenario import load_scenario

    path = tmp_path / "s.toml"
    path.write_text(descent_scenario(tmp_path / "stack", "shading"))
    srv = mod.RenderServer(load_scenario(path), port=0)
    sc = srv.scenario
    return srv, _Conn(mod._State(sc, sc.lighting, {}))


@pytest.mark.parametrize("body, code, words", [
    (b'{"shadow": false}', E_INVALID, "did you mean 'shadows'"),
    (b'{"scattering": "no"}', E_INVALID, "true or false"),
    (b'{"earthshine": 0}', E_INVALID, "true or false"),
    (b'[1, 2]', E_MALFORMED, "JSON object"),
    (b'{"shadows": tru', E_MALFORMED, "not UTF-8 JSON"),
    (b'\xff\xfe', E_MALFORMED, "not UTF-8 JSON"),
    (b'[' * 5000 + b']' * 5000, E_MALFORMED, "nested"),
])
def test_bad_switches_get_an_error_reply_and_change_nothing(server_state, body, code, words):
    from render.protocol import MsgType

    srv, conn = server_state
    before = conn.state.scenario.options
    rtype, reply = srv._reply(conn, MsgType.SET_SHADING, body)
    assert rtype == T_ERROR
    got, _ = struct.unpack_from("<HH", reply)
    reason = reply[4:].decode()
    assert got == code and words in reason and "\n" not in reason
    assert conn.state.scenario.options == before


def test_switches_are_set_one_by_one_and_reported(server_state):
    from render.protocol import MsgType

    srv, conn = server_state
    rtype, reply = srv._reply(conn, MsgType.SET_SHADING, b"{}")
    assert rtype == T_SET_SHADING | REPLY
    assert json.loads(reply) == {"shadows": True, "soft_shadows": True, "scattering": True,
                                 "earthshine": True}  # the scenario's [render]
    srv._reply(conn, MsgType.SET_SHADING, b'{"soft_shadows": false}')
    rtype, reply = srv._reply(conn, MsgType.SET_SHADING, b'{"scattering": false}')
    assert json.loads(reply) == {"shadows": True, "soft_shadows": False, "scattering": False,
                                 "earthshine": True}
    opts = conn.state.scenario.options
    assert not opts.soft_shadows and not opts.scattering and opts.shadows
    # a sensor change keeps the connection's switches
    srv._reply(conn, MsgType.SET_SENSOR, b'{"width": 32, "height": 24}')
    assert not conn.state.scenario.options.scattering


class _Raw:
    """A raw-socket client from the protocol page."""

    def __init__(self, port):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=120.0)
        self.id = 0

    def call(self, mtype, body=b""):
        self.id += 1
        self.s.sendall(HDR.pack(b"CSRV", 1, mtype, self.id, len(body)) + body)
        head = b""
        while len(head) < 16:
            head += self.s.recv(16 - len(head))
        _, _, rtype, rid, n = HDR.unpack(head)
        out = b""
        while len(out) < n:
            out += self.s.recv(n - len(out))
        assert rid == self.id
        return rtype, out

    def close(self):
        self.s.close()


def test_two_connections_keep_their_own_shading(tmp_path, gl):
    """Over TCP: one client turns the scattered light off, the other keeps it; a bad body is
    answered with an error and the server serves on; the image follows the connection's
    switches, and switching back gives the same bytes."""
    from render.client import Client

    stack = cratered_stack(tmp_path / "stack")
    path = tmp_path / "serve.toml"
    path.write_text(descent_scenario(stack, "shading"))
    with served(path, "--read-timeout", 3) as (_, port), \
            Client("127.0.0.1", port) as a, Client("127.0.0.1", port) as b:
        info = a.info()
        assert info["protocol_minor"] >= 5
        assert info["shading"] == {"shadows": True, "soft_shadows": True, "scattering": True,
                                   "earthshine": True}
        sx, sy = info["site"]
        pose = ((sx, sy, 1500.0), (0.0, 1.0, 0.0, 0.0))
        for c in (a, b):
            c.set_pose(*pose)
        scattered = a.get_image()
        assert a.set_shading(scattering=False, soft_shadows=False)["scattering"] is False
        assert b.info()["shading"]["scattering"] is True, "b does not see a's switch"
        direct = a.get_image()
        assert np.array_equal(b.get_image(), scattered)
        # without the light the terrain scatters, the ground is darker (the sun alone; the
        # scattered light is a few DN here, the noise keyed alike in both frames)
        darker = scattered.astype(np.int64) - direct.astype(np.int64)
        assert np.mean(darker > 0) > 0.9 and darker.mean() > 5
        raw = _Raw(port)
        try:
            rtype, body = raw.call(T_SET_SHADING, b"not json")
            assert rtype == T_ERROR and struct.unpack_from("<H", body)[0] == E_MALFORMED
            rtype, body = raw.call(T_SET_SHADING, b'{"shadows": false, "penumbra": true}')
            assert rtype == T_ERROR and struct.unpack_from("<H", body)[0] == E_INVALID
            assert raw.call(T_PING)[0] == T_PING | REPLY, "the connection and server live on"
            rtype, body = raw.call(T_INFO)
            assert json.loads(body)["shading"]["shadows"] is True, "the refused body set nothing"
        finally:
            raw.close()
        assert a.set_shading(scattering=True, soft_shadows=True)["scattering"] is True
        assert np.array_equal(a.get_image(), scattered)
