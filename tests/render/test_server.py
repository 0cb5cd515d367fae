"""The render server as flight software meets it: a subprocess on a free port, driven by the
Python client and by a raw-socket client written from docs/protocol.md alone."""

import contextlib
import json
import math
import signal
import socket
import struct
import threading
import time

import numpy as np
import pytest

from tests.cli_helpers import one_line_error, run
from tests.render.scenes import cratered_stack, descent_scenario
from tests.render.server_helpers import CRATERSCAPE, rss_bytes, served

# ---------------------------------------------------------------- the spec, restated by hand
# (docs/protocol.md; deliberately not imported from render.protocol)
HDR = struct.Struct("<4sHHII")
T_HELLO, T_INFO, T_PING = 0x0001, 0x0002, 0x0003
T_SET_POSE, T_SET_SUN, T_SET_SENSOR = 0x0010, 0x0011, 0x0012
T_GET_IMAGE, T_GET_RANGE, T_GET_NORMALS, T_GET_TRUTH = 0x0020, 0x0021, 0x0022, 0x0023
T_HEIGHT_AT, T_PIXEL_RAY, T_RAY = 0x0030, 0x0031, 0x0032
T_ERROR = 0xFFFF
E_BAD_MAGIC, E_BAD_VERSION, E_TOO_LARGE, E_UNKNOWN_TYPE, E_MALFORMED = 1, 2, 3, 4, 5
E_INVALID, E_INSIDE, E_NO_POSE, E_UNAUTHORIZED, E_UNSUPPORTED = 6, 7, 8, 9, 10
E_TIMEOUT = 13


class Raw:
    """A client in 30 lines, from the protocol page."""

    def __init__(self, port, timeout=60.0):
        self.s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
        self.id = 0

    def send(self, mtype, body=b"", magic=b"CSRV", version=1, length=None):
        self.id += 1
        n = len(body) if length is None else length
        self.s.sendall(HDR.pack(magic, version, mtype, self.id, n) + body)

    def recv_exact(self, n):
        out = b""
        while len(out) < n:
            chunk = self.s.recv(n - len(out))
            if not chunk:
                raise ConnectionError("closed")
            out += chunk
        return out

    def reply(self):
        magic, version, mtype, rid, n = HDR.unpack(self.recv_exact(16))
        assert magic == b"CSRV" and version == 1
        return mtype, rid, self.recv_exact(n)

    def call(self, mtype, body=b""):
        self.send(mtype, body)
        rtype, rid, rbody = self.reply()
        assert rid == self.id
        return rtype, rbody

    def closed(self) -> bool:
        try:
            return self.s.recv(1) == b""
        except ConnectionResetError:
            return True

    def close(self):
        self.s.close()


def error_of(rtype, body):
    assert rtype == T_ERROR, hex(rtype)
    code, _ = struct.unpack_from("<HH", body)
    reason = body[4:].decode("utf-8")
    assert "\n" not in reason and reason
    return code


def reply_error(c):
    rtype, _, body = c.reply()
    return error_of(rtype, body)


def pose_body(position, attitude, t=0.0, frame=0):
    return struct.pack("<3d4ddII", *position, *attitude, t, frame, 0)


# ---------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def stack_dir(tmp_path_factory, gl):
    return cratered_stack(tmp_path_factory.mktemp("stack") / "stack")


@pytest.fixture(scope="module")
def scenario(tmp_path_factory, stack_dir):
    path = tmp_path_factory.mktemp("scenario") / "serve.toml"
    path.write_text(descent_scenario(stack_dir, "serve-test"))
    return path


@pytest.fixture(scope="module")
def reference(scenario, tmp_path_factory):
    """`craterscape render frame --index 1`: image, range and truth."""
    import cv2

    from terrain.io import read_float_tiff

    out = tmp_path_factory.mktemp("frame") / "one.png"
    render_frame(scenario, out, 1)
    truth = json.loads(out.with_name("one_truth.json").read_text())
    return dict(image=cv2.imread(str(out), cv2.IMREAD_UNCHANGED), truth=truth,
                range=read_float_tiff(out.with_name("one_range.tif")),
                png=out.read_bytes())


@pytest.fixture(scope="module")
def server(scenario):
    with served(scenario, "--read-timeout", 3, "--idle-timeout", 60) as (proc, port):
        yield proc, port


def render_frame(scenario, out, index):
    """`craterscape render frame` as a user runs it, in its own process (a GL context made in
    this one could displace the session's, which other render tests use)."""
    import subprocess

    done = subprocess.run([*CRATERSCAPE, "render", "frame", str(scenario), "-o", str(out),
                           "--index", str(index)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr


def set_reference_pose(client, truth):
    client.set_pose(truth["camera"]["position"], truth["camera"]["attitude"],
                    time=truth["time"], frame=truth["index"])


# ---------------------------------------------------------------- equality with render frame
def test_python_client_image_equals_render_frame_byte_for_byte(server, reference):
    import cv2

    from render.client import Client

    _, port = server
    with Client("127.0.0.1", port) as c:
        set_reference_pose(c, reference["truth"])
        image = c.get_image()
        rng = c.get_range()
        truth = c.get_truth()
    assert image.dtype == np.uint16 and image.shape == (48, 64)
    assert image.tobytes() == reference["image"].tobytes()
    ok, png = cv2.imencode(".png", image)
    assert ok and png.tobytes() == reference["png"]
    assert rng.tobytes() == reference["range"].astype(np.float32).tobytes()
    expected = {k: v for k, v in reference["truth"].items()
                if k not in ("image", "range", "normals")}
    assert truth == expected


def test_raw_socket_client_from_the_spec(server, reference):
    _, port = server
    c = Raw(port)
    try:
        t = reference["truth"]
        rtype, body = c.call(T_SET_POSE, pose_body(t["camera"]["position"],
                                                   t["camera"]["attitude"], t["time"],
                                                   t["index"]))
        assert rtype == T_SET_POSE | 0x8000 and body == b""
        rtype, body = c.call(T_GET_IMAGE, b"\x00")
        assert rtype == T_GET_IMAGE | 0x8000
        w, h, bits, zero = struct.unpack_from("<IIHH", body)
        assert (w, h, bits, zero) == (64, 48, 16, 0)
        pixels = np.frombuffer(body[12:], dtype="<u2").reshape(h, w)
        assert pixels.tobytes() == reference["image"].astype("<u2").tobytes()
        # the 8-bit version of the same frame: the same I/F at 255 full scale, digitised
        # again with the sensor's own noise (shot: DN / gain e-/DN; read: 2 DN; rounding)
        rtype, body = c.call(T_GET_IMAGE, b"\x08")
        w8, h8, bits8, _ = struct.unpack_from("<IIHH", body)
        assert (w8, h8, bits8) == (64, 48, 8) and len(body) == 12 + 64 * 48
        img8 = np.frombuffer(body[12:], dtype=np.uint8).astype(float)
        img16 = reference["image"].astype(float).ravel()
        expected = img16 * 255.0 / 65535.0
        sigma = np.sqrt(expected / 10.0 + 2.0**2 + 2 / 12)
        inside = (img16 > 0.05 * 65535) & (img16 < 0.95 * 65535)  # neither clipped
        assert inside.sum() > 500
        z = (img8 - expected)[inside] / sigma[inside]
        assert abs(z.mean()) < 0.15 and 0.85 < z.std() < 1.15
        rtype, body = c.call(T_GET_NORMALS)
        w, h = struct.unpack_from("<II", body)
        normals = np.frombuffer(body[8:], dtype="<f4").reshape(h, w, 3)
        hit = np.isfinite(normals[..., 0])
        assert hit.all() and np.allclose(np.linalg.norm(normals[hit], axis=1), 1.0, atol=1e-3)
        rtype, body = c.call(T_INFO)
        info = json.loads(body)
        assert info["protocol"] == 1 and info["scene"] == "terrain"
        assert error_of(*c.call(0x0777)) == E_UNKNOWN_TYPE
        rtype, body = c.call(T_PING)
        assert rtype == T_PING | 0x8000
    finally:
        c.close()


def test_a_c_client_written_from_the_spec(server, reference, tmp_path):
    import shutil
    import subprocess

    import cv2

    from render.client import Client
    from tests.render.server_helpers import REPO

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler here (apt-get install gcc) for examples/render_client.c")
    exe = tmp_path / "render_client"
    subprocess.run([cc, "-O2", "-Wall", "-Werror", "-o", str(exe),
                    str(REPO / "examples" / "render_client.c")], check=True, timeout=120)
    t = reference["truth"]
    out = tmp_path / "c.pgm"
    args = [*t["camera"]["position"], *t["camera"]["attitude"], t["time"], t["index"]]
    done = subprocess.run([str(exe), "127.0.0.1", str(server[1]), *map(repr, args), str(out)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert cv2.imread(str(out), cv2.IMREAD_UNCHANGED).tobytes() == reference["image"].tobytes()
    lines = done.stdout.split("\n")
    with Client("127.0.0.1", server[1]) as c:
        expected = c.ray(t["camera"]["position"], (0.0, 0.0, -1.0)).range
        set_reference_pose(c, t)
        radar, lidar = c.get_radar(), c.get_lidar()
        c.set_motion((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
        events = c.get_events(0.05)
    assert float(lines[0]) == pytest.approx(expected, abs=1e-6)
    rng, vel = map(float, lines[1].split())
    assert rng == pytest.approx(radar["range"], abs=1e-5) and vel == radar["velocity"] == 0.0
    h, w = lidar["range"].shape
    assert float(lines[2]) == pytest.approx(float(lidar["range"][h // 2, w // 2]), abs=1e-5)
    count, on = map(int, lines[3].split())
    assert count == len(events["t"]) > 0 and on == int(np.sum(events["p"] > 0))


def test_radar_lidar_and_events_over_the_server_agree_with_the_range_image(server, reference):
    from render.client import Client
    from render.errors import ServerError

    t = reference["truth"]
    with Client("127.0.0.1", server[1]) as c:
        assert c.info()["protocol_minor"] >= 2
        set_reference_pose(c, t)
        image_range = c.get_range()
        h, w = image_range.shape
        # a LIDAR with the camera's own pixels and no footprint reads the ideal range image
        fov = math.degrees(2 * math.atan(0.5 * w / t["intrinsics"]["fx"]))
        lid = c.get_lidar(width=w, height=h, fov=fov, supersample=1, threshold=0.0)
        ok = np.isfinite(image_range)
        assert np.allclose(lid["range"][ok], image_range[ok], rtol=1e-5)
        # the radar's nearest range in a beam along the boresight is the nearest surface the
        # camera's own pixels see within the half-power cone (3 degrees)
        radar = c.get_radar(width=6.0, pixels=64)
        k = t["intrinsics"]
        v, u = np.mgrid[0:h, 0:w]
        off = np.hypot((u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"])
        cone = ok & (off <= math.tan(math.radians(3.0)))
        assert cone.sum() >= 4
        assert radar["range"] == pytest.approx(float(image_range[cone].min()), rel=5e-3)
        assert radar["range"] <= float(image_range[cone].min()) * (1 + 1e-5)
        assert radar["histogram"].sum() == pytest.approx(1.0 - radar["power_outside"], abs=1e-4)
        c.set_motion((5.0, 0.0, -20.0), (1.0, 0.0, 0.0))
        moving = c.get_radar(width=6.0, pixels=64)
        from render.camera import quat_to_matrix

        axis = quat_to_matrix(np.array(t["camera"]["attitude"]))[:, 2]
        assert moving["boresight_velocity"] == pytest.approx(float(axis @ [5.0, 0.0, -20.0]))
        ev = c.get_events(0.05, max_events=10)
        assert len(ev["t"]) == 10 and ev["dropped"] > 0
        assert ev["t"].min() >= 0 and ev["t"].max() <= 50_000
        assert ev["start"] == t["time"] and (ev["width"], ev["height"]) == (w, h)
        with pytest.raises(ServerError, match="unknown radar key 'widht'"):
            c.get_radar(widht=3.0)
        with pytest.raises(ServerError, match="duration"):
            c.get_events(0.0)
        with pytest.raises(ServerError, match="scan"):
            c.get_lidar(mode="scan")
        with pytest.raises(ServerError, match="too large"):
            c.get_radar(range_bins=65536, doppler_bins=65536)
        with pytest.raises(ServerError, match="sub-rays a side"):
            c.get_lidar(width=4096, supersample=4)
        with pytest.raises(ServerError, match="duration"):
            c.get_events(math.nan)
        for code, body in ((0x0026, b"[1, 2"), (0x0027, b"\xff"), (0x0028, b"\x00" * 5)):
            with pytest.raises(ServerError) as err:
                c.request(code, body)
            assert err.value.code == E_MALFORMED, err.value
        assert c.get_radar(width=6.0, pixels=64)["range"] == radar["range"]
    with Client("127.0.0.1", server[1]) as fresh:
        for call in (fresh.get_radar, fresh.get_lidar, lambda: fresh.get_events(0.01)):
            with pytest.raises(ServerError, match="SET_POSE"):
                call()


# ---------------------------------------------------------------- surface queries
def test_height_normal_and_rays_agree_with_the_dem(server, stack_dir):
    from render.client import Client
    from terrain.stack.store import read_stack

    tile = read_stack(stack_dir).tiles[-1]
    r, col = 10, 20
    x, y = (float(v) for v in tile.xy(r, col))
    with Client("127.0.0.1", server[1]) as c:
        info = c.info()
        site = info["site"]
        h, n = c.height_at(x, y)
        # curvature as rendered: the datum drops by d^2 / 2R away from the site
        d2 = (x - site[0]) ** 2 + (y - site[1]) ** 2
        expected = float(tile.heights[r, col]) - d2 / (2 * 1_737_400.0)
        assert h == pytest.approx(expected, abs=1e-3)
        gy, gx = np.gradient(tile.heights.astype(np.float64), tile.resolution)
        ref = np.array([-gx[r, col], gy[r, col], 1.0])  # rows run south: d/dy = -d/drow
        ref /= np.linalg.norm(ref)
        assert np.degrees(np.arccos(np.clip(n @ ref, -1, 1))) < 0.5
        # a laser altimeter straight down from 800 m above that point meets it
        hit = c.ray((x, y, h + 800.0), (0.0, 0.0, -1.0))
        assert hit.range == pytest.approx(800.0, abs=0.05)
        assert np.allclose(hit.point, (x, y, h), atol=0.05)
        assert hit.normal @ n > 0.99
        # pointing at the sky: nothing
        assert not c.ray((x, y, h + 800.0), (0.0, 0.0, 1.0)).hit
        # through a pixel: the point lies on that pixel's ray, near the range image's value
        c.set_pose((site[0], site[1] - 600.0, 1500.0), _look(( site[0], site[1] - 600.0,
                                                               1500.0), (site[0], site[1], 0)))
        rng = c.get_range()
        truth = c.get_truth()
        hit = c.pixel_ray(40.0, 30.0)
    from render.camera import Intrinsics, Pose

    pose = Pose(tuple(truth["camera"]["position"]), tuple(truth["camera"]["attitude"]))
    uv = pose.project(hit.point[None], Intrinsics(**truth["intrinsics"]))[0]
    assert np.allclose(uv, (40.0, 30.0), atol=1e-3)
    assert hit.range == pytest.approx(float(rng[30, 40]), rel=0.01)


def _look(position, target):
    from render.camera import look_at

    return look_at(position, target).attitude


# ---------------------------------------------------------------- bad input
def test_bad_requests_get_error_replies_and_the_connection_lives_on(server):
    from render.client import Client
    from render.errors import ServerError

    with Client("127.0.0.1", server[1]) as c:
        info = c.info()
        sx, sy = info["site"]
        cases = [
            (lambda: c.get_image(), E_NO_POSE),
            (lambda: c.pixel_ray(1.0, 1.0), E_NO_POSE),
            (lambda: c.set_pose((sx, sy, math.nan), (1, 0, 0, 0)), E_INVALID),
            (lambda: c.set_pose((sx, sy, 1000.0), (0, 0, 0, 0)), E_INVALID),
            (lambda: c.set_pose((sx, sy, 1000.0), (math.inf, 0, 0, 0)), E_INVALID),
            (lambda: c.set_pose((sx, sy, -50.0), (0, 1, 0, 0)), E_INSIDE),
            (lambda: c.set_pose((sx, sy, 1e12), (0, 1, 0, 0)), E_INVALID),
            (lambda: c.set_sun((0.0, 0.0, 0.0)), E_INVALID),
            (lambda: c.set_sensor(expsure=3.0), E_INVALID),
            (lambda: c.set_sensor(bits=17), E_INVALID),
            (lambda: c.set_sensor(width=100000), E_INVALID),
            (lambda: c.set_sensor(noise="yes"), E_INVALID),
            (lambda: c.height_at(-1e6, 0.0), E_INVALID),
            (lambda: c.ray((sx, sy, 900.0), (0.0, 0.0, 0.0)), E_INVALID),
            (lambda: c.request(T_SET_SENSOR, b"[1, 2"), E_MALFORMED),
            (lambda: c.request(T_SET_SENSOR, b"\xff\xfe"), E_MALFORMED),
            (lambda: c.request(T_SET_POSE, b"\x00" * 10), E_MALFORMED),
            (lambda: c.request(T_GET_IMAGE, b"\x11"), E_INVALID),
            (lambda: c.request(0x4242), E_UNKNOWN_TYPE),
        ]
        for call, code in cases:
            with pytest.raises(ServerError) as err:
                call()
            assert err.value.code == code, err.value
        assert "expsure" in str(_raised(lambda: c.set_sensor(expsure=3.0)))
        # and then it serves: sensor settings accumulate and are reported
        settings = c.set_sensor(width=32, height=24, noise=False)
        assert (settings["width"], settings["height"], settings["noise"]) == (32, 24, False)
        assert c.set_sensor(exposure=2.0)["width"] == 32
        c.set_pose((sx, sy, 1200.0), (0.0, 1.0, 0.0, 0.0))
        a = c.get_image()
        c.set_pose((sx, sy, 1200.0), (0.0, 1.0, 0.0, 0.0), frame=7)
        assert a.shape == (24, 32) and np.array_equal(a, c.get_image())  # noise off


def _raised(call):
    try:
        call()
    except Exception as exc:  # noqa: BLE001
        return exc
    raise AssertionError("no error")


def test_fuzz_hundreds_of_malformed_messages_then_still_correct(server, reference, rng):
    """Truncated, oversized, unknown, malformed, NaN and buried poses, vanishing clients."""
    _, port = server
    t = reference["truth"]
    good_pose = pose_body(t["camera"]["position"], t["camera"]["attitude"], t["time"], t["index"])
    x, y, _ = t["camera"]["position"]
    kinds = ["garbage", "truncated_header", "truncated_body", "oversized", "bad_magic",
             "bad_version", "unknown", "wrong_length", "bad_json", "nan_pose", "buried_pose",
             "vanish_mid_frame", "random_body"]
    outcomes = {}
    for i in range(300):
        kind = kinds[i % len(kinds)]
        c = Raw(port, timeout=10.0)
        try:
            if kind == "garbage":
                c.s.sendall(rng.bytes(int(rng.integers(1, 64))))
                with contextlib.suppress(OSError):  # it may have answered and closed already
                    c.s.shutdown(socket.SHUT_WR)
                got = _drain(c)
            elif kind == "truncated_header":
                c.s.sendall(HDR.pack(b"CSRV", 1, T_PING, 1, 0)[: int(rng.integers(1, 16))])
                c.close()
                got = "vanished"
            elif kind == "truncated_body":
                c.send(T_SET_POSE, good_pose[: int(rng.integers(0, 72))], length=72)
                c.close()
                got = "vanished"
            elif kind == "oversized":
                c.send(T_SET_SENSOR, b"", length=int(rng.integers(65537, 2**32)))
                got = reply_error(c)
                assert got == E_TOO_LARGE and c.closed()
            elif kind == "bad_magic":
                c.send(T_PING, magic=bytes(rng.integers(0, 256, 4, dtype=np.uint8)))
                got = reply_error(c)
                assert got == E_BAD_MAGIC and c.closed()
            elif kind == "bad_version":
                c.send(T_PING, version=int(rng.integers(2, 65536)))
                got = reply_error(c)
                assert got == E_BAD_VERSION and c.closed()
            elif kind == "unknown":
                got = error_of(*c.call(int(rng.integers(0x0100, 0x8000))))
                assert got == E_UNKNOWN_TYPE
            elif kind == "wrong_length":
                mtype = int(rng.choice([T_SET_POSE, T_SET_SUN, T_GET_IMAGE, T_HEIGHT_AT, T_RAY,
                                        T_INFO]))
                got = error_of(*c.call(mtype, rng.bytes(int(rng.integers(1, 7)) * 10 + 3)))
                assert got == E_MALFORMED
            elif kind == "bad_json":
                body = rng.choice([b"{", b"[]", b"null", b'{"bits": "x"}', b'{"width": -3}',
                                   b'{"psf_sigma": -1}', b'{"gain": 1e999}', b"\xc3\x28"])
                got = error_of(*c.call(T_SET_SENSOR, bytes(body)))
                assert got in (E_MALFORMED, E_INVALID)
            elif kind == "nan_pose":
                v = [x, y, 1000.0, 0.0, 1.0, 0.0, 0.0]
                v[int(rng.integers(0, 7))] = float(rng.choice([np.nan, np.inf, -np.inf]))
                got = error_of(*c.call(T_SET_POSE, pose_body(v[:3], v[3:])))
                assert got == E_INVALID
            elif kind == "buried_pose":
                got = error_of(*c.call(T_SET_POSE, pose_body((x, y, -rng.uniform(1, 5000)),
                                                             (0.0, 1.0, 0.0, 0.0))))
                assert got == E_INSIDE
            elif kind == "vanish_mid_frame":
                c.call(T_SET_POSE, good_pose)
                c.send(T_GET_IMAGE, b"\x00")
                if rng.random() < 0.5:
                    c.recv_exact(int(rng.integers(1, 100)))
                c.close()
                got = "vanished"
            else:
                mtype = int(rng.choice([T_SET_POSE, T_SET_SUN, T_RAY, T_HEIGHT_AT, T_PIXEL_RAY]))
                size = {T_SET_POSE: 72, T_SET_SUN: 24, T_RAY: 48}.get(mtype, 16)
                rtype, _ = c.call(mtype, rng.bytes(size))
                got = "reply" if rtype == mtype | 0x8000 else error_of(rtype, _)
            outcomes.setdefault(kind, set()).add(got)
        finally:
            c.close()
    assert set(outcomes) == set(kinds)
    # the server is alive and still right
    test_raw_socket_client_from_the_spec(server, reference)
    assert server[0].poll() is None


def _drain(c):
    """What a server says to garbage: an error reply (first code) or just a close."""
    data = b""
    while True:
        chunk = c.s.recv(4096)
        if not chunk:
            break
        data += chunk
    if not data:
        return "closed"
    rtype = HDR.unpack_from(data)[2]
    return error_of(rtype, data[16:])


@pytest.mark.slow
def test_a_stalled_client_does_not_stall_the_others_and_times_out(server, reference):
    from render.client import Client

    _, port = server
    slow = Raw(port)
    slow.s.sendall(HDR.pack(b"CSRV", 1, T_PING, 1, 0)[:7])  # half a header, then silence
    t0 = time.monotonic()
    with Client("127.0.0.1", port) as c:
        set_reference_pose(c, reference["truth"])
        assert c.get_image().tobytes() == reference["image"].tobytes()
    assert time.monotonic() - t0 < 2.5  # served before the stalled one even timed out
    rtype, _, body = slow.reply()       # the read timeout (3 s here) then closes it
    assert error_of(rtype, body) == E_TIMEOUT and slow.closed()
    slow.close()
    # trickling a byte at a time does not stretch the read timeout
    trickle = Raw(port)
    message = HDR.pack(b"CSRV", 1, T_SET_SENSOR, 1, 2000) + b"{" * 2000
    t0 = time.monotonic()
    with contextlib.suppress(OSError):
        for byte in message:
            trickle.s.sendall(bytes([byte]))
            time.sleep(0.05)
    assert time.monotonic() - t0 < 6.0
    trickle.close()


def test_four_clients_fifty_requests_each_memory_flat(server, reference):
    from render.client import Client

    proc, port = server
    x0, y0, _ = reference["truth"]["camera"]["position"]
    done = {k: [] for k in range(4)}
    errors = []
    rss = {}

    def fly(k):
        try:
            with Client("127.0.0.1", port) as c:
                for i in range(50):
                    z = 900.0 + 20.0 * ((i * 7 + k * 13) % 11)
                    c.set_pose((x0 + 10.0 * k, y0 - 5.0 * i, z), (0.0, 1.0, 0.0, 0.0),
                               time=0.1 * i, frame=i)
                    image = c.get_image() if i % 2 else c.get_range()
                    assert image.shape == (48, 64)
                    done[k].append(time.monotonic())
                    if k == 0 and i == 9:
                        rss["early"] = rss_bytes(proc.pid)
        except Exception as exc:  # noqa: BLE001 - collected and reported below
            errors.append(repr(exc))

    threads = [threading.Thread(target=fly, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=300)
    assert not errors, errors
    assert all(len(v) == 50 for v in done.values())
    rss["late"] = rss_bytes(proc.pid)
    # memory flat: 160 more frames after the first 40 grow the server by under 16 MiB
    assert rss["late"] - rss["early"] < 16 * 2**20, rss
    # fair turns: every client had 10 answers before any client had all 50
    first_finished = min(v[-1] for v in done.values())
    assert all(v[9] < first_finished for v in done.values())


# ---------------------------------------------------------------- tokens and shutdown
def test_binding_beyond_loopback_needs_a_token(scenario):
    one_line_error(run("render", "serve", scenario, "--host", "0.0.0.0", "--port", 0),
                   "token")


def test_a_port_in_use_is_a_one_line_error(server, scenario):
    one_line_error(run("render", "serve", scenario, "--port", server[1]), "cannot listen")


@pytest.mark.slow
def test_a_token_server_refuses_clients_without_it(scenario):
    from render.client import Client
    from render.errors import ServerError

    with served(scenario, "--token", "s3cret") as (_, port):
        c = Raw(port)
        assert error_of(*c.call(T_INFO)) == E_UNAUTHORIZED and c.closed()
        c.close()
        with pytest.raises(ServerError) as err:
            Client("127.0.0.1", port, token="wrong")
        assert err.value.code == E_UNAUTHORIZED
        with Client("127.0.0.1", port, token="s3cret") as c:
            assert c.info()["scene"] == "terrain"


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_finishes_the_request_in_hand_and_exits_cleanly(scenario, sig):
    from render.client import Client

    with served(scenario) as (proc, port):
        with Client("127.0.0.1", port) as c:
            c.set_sensor(width=1536, height=1536)
            sx, sy = c.info()["site"]
            c.set_pose((sx, sy, 1500.0), (0.0, 1.0, 0.0, 0.0))
            got = {}
            th = threading.Thread(target=lambda: got.setdefault("image", c.get_image()))
            th.start()
            time.sleep(0.3)               # the frame is being rendered
            proc.send_signal(sig)
            th.join(timeout=60)
            assert got["image"].shape == (1536, 1536)
        assert proc.wait(timeout=30) == 0
        assert "stopped" in proc.stderr.read()


# ---------------------------------------------------------------- asteroid scenes
@pytest.fixture(scope="module")
def asteroid_scenario(tmp_path_factory, gl):
    from click.testing import CliRunner

    from terrain.cli.commands import main

    folder = tmp_path_factory.mktemp("asteroid")
    body = folder / "rock.npz"
    r = CliRunner().invoke(main, ["asteroid", "build", "-o", str(body), "--magnitude", "24",
                                  "--radius", "300", "--base", "perlin", "--seed", "4"])
    assert r.exit_code == 0, r.output
    path = folder / "approach.toml"
    path.write_text(f"""
name = "rock"
seed = 2
[scene]
type = "asteroid"
body = "{body}"
spin_axis = [0.0, 0.3, 1.0]
spin_period = 600.0
spin_phase = 20.0
[sun]
direction = [0.6, -0.7, 0.35]
[camera]
width = 48
height = 48
fov = 30.0
[sensor]
exposure = 2.0
read_noise = 1.0
[render]
shadow_size = 256
[trajectory]
type = "approach"
frames = 3
duration = 200.0
start_distance = 3000.0
end_distance = 1500.0
direction = [1.0, -0.5, 0.2]
""")
    return path


@pytest.mark.slow
def test_asteroid_time_turns_the_body_as_render_frame_does(asteroid_scenario, tmp_path):
    import cv2

    from render.client import Client
    from render.errors import ServerError

    out = tmp_path / "rock.png"
    render_frame(asteroid_scenario, out, 2)
    truth = json.loads((tmp_path / "rock_truth.json").read_text())
    with served(asteroid_scenario) as (_, port), Client("127.0.0.1", port) as c:
        set_reference_pose(c, truth)
        assert c.get_image().tobytes() == cv2.imread(str(out), cv2.IMREAD_UNCHANGED).tobytes()
        assert c.get_truth()["body_rotation"] == truth["body_rotation"]
        p = np.asarray(truth["camera"]["position"])
        when = truth["time"]  # the body turns: surface tests hold at this time
        hit = c.ray(p, -p)
        assert 250.0 < np.linalg.norm(hit.point) < 350.0 and hit.normal @ p > 0
        with pytest.raises(ServerError) as err:
            c.set_pose(p / np.linalg.norm(p) * 100.0, truth["camera"]["attitude"], when)
        assert err.value.code == E_INSIDE
        with pytest.raises(ServerError) as err:
            c.set_pose(0.99 * hit.point, truth["camera"]["attitude"], when)
        assert err.value.code == E_INSIDE
        c.set_pose(1.02 * hit.point, truth["camera"]["attitude"], when)  # just outside: fine
        with pytest.raises(ServerError) as err:
            c.height_at(0.0, 0.0)
        assert err.value.code == E_UNSUPPORTED


def test_last_frames_beyond_the_cache_budget_are_dropped_oldest_first(monkeypatch, scenario):
    from render import server as mod
    from render.renderer import Frame
    from render.scenario import load_scenario

    srv = mod.RenderServer(load_scenario(scenario), port=0)
    sc = srv.scenario

    def state():
        st = mod._State(sc, sc.lighting, {})
        z = np.zeros((100, 100), np.float32)
        st.frame = (z.astype(np.uint8), Frame(z, z, np.zeros((100, 100, 3), np.float32)), None)
        return st

    one = mod._frame_bytes(state().frame)
    monkeypatch.setattr(mod, "FRAME_CACHE_BYTES", 2 * one)
    a, b, c = state(), state(), state()
    for st in (a, b, c):
        srv._remember(st)
    assert a.frame is None and b.frame is not None and c.frame is not None
    srv._remember(b)  # b used again: c is now the oldest
    d = state()
    srv._remember(d)
    assert c.frame is None and b.frame is not None and d.frame is not None


@pytest.mark.slow
def test_motion_blur_as_render_frame_with_the_velocities_the_client_sends(stack_dir, tmp_path):
    """A data-sheet camera blurring over its exposure: the client sends the velocities the
    trajectory gave `render frame` (its truth lists them) and gets the same bytes."""
    from render.client import Client

    path = tmp_path / "blur.toml"
    path.write_text(f"""
name = "blur"
seed = 8
[scene]
type = "terrain"
stack = "{stack_dir}"
[sun]
azimuth = 100.0
elevation = 20.0
[camera]
width = 48
height = 40
fov = 40.0
[sensor]
bits = 12
exposure_time = 0.08
aperture = 0.00002
qe = 0.5
bandwidth = 100.0
read_noise = 5.0
gain = 30.0
[motion]
blur = true
[render]
shadow_size = 512
[trajectory]
type = "descent"
frames = 3
duration = 2.0
start_altitude = 900.0
end_altitude = 200.0
ground_track = [400.0, 0.0]
""")
    out = tmp_path / "blur.png"
    render_frame(path, out, 1)
    import cv2

    truth = json.loads((tmp_path / "blur_truth.json").read_text())
    m = truth["motion"]
    assert np.linalg.norm(m["velocity"]) > 100.0  # fast enough to smear
    with served(path) as (_, port), Client("127.0.0.1", port) as c:
        set_reference_pose(c, truth)
        still = c.get_image()
        c.set_motion(m["velocity"], m["angular_velocity"], m["body_angular_velocity"])
        blurred = c.get_image()
        assert blurred.tobytes() == cv2.imread(str(out), cv2.IMREAD_UNCHANGED).tobytes()
        assert c.get_truth()["motion"]["velocity"] == m["velocity"]
    assert not np.array_equal(still, blurred)
    assert 0 < np.median(blurred) < 4095  # neither dark nor saturated: blur is visible
