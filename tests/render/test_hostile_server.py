"""The render server against hostile clients: no file of the server's read or stalled over
the wire, no slot or memory held by clients that never authenticate or never read, every
number checked when it arrives, and every failure answered with the code docs/protocol.md
gives it. A real server on 127.0.0.1, driven by raw sockets and by the Python client."""

import contextlib
import json
import math
import os
import socket
import struct
import threading
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.render.scenes import cratered_stack, descent_scenario
from tests.render.server_helpers import rss_bytes, served
from tests.render.test_server import T_ERROR, Raw, error_of, pose_body

T_SET_POSE, T_SET_SUN, T_SET_SENSOR, T_SET_MOTION = 0x0010, 0x0011, 0x0012, 0x0013
T_GET_IMAGE, T_GET_RANGE, T_GET_NORMALS = 0x0020, 0x0021, 0x0022
T_HEIGHT_AT, T_PIXEL_RAY, T_RAY = 0x0030, 0x0031, 0x0032
E_MALFORMED, E_INVALID, E_INSIDE, E_NO_POSE = 5, 6, 7, 8
E_UNAUTHORIZED, E_BUSY, E_TIMEOUT, E_INTERNAL = 9, 11, 13, 14
#: Codes after which the connection stays open (docs/protocol.md, "Error codes").
OPEN_CODES = {4, 5, 6, 7, 8, 10, 14}
SECRET = "hunter2-secret"
NADIR = (0.0, 1.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def folder(tmp_path_factory, gl):
    """A scenario folder with a kernel beside it, a text file, a FIFO and a link leading out;
    a private file one folder up."""
    root = tmp_path_factory.mktemp("hostile")
    stack = cratered_stack(root / "stack")
    sc_dir = root / "scenario"
    sc_dir.mkdir()
    text = descent_scenario(stack, "hostile").replace("[render]\n", "[render]\nantialias = 3\n")
    (sc_dir / "serve.toml").write_text(text)
    (sc_dir / "flat.toml").write_text(descent_scenario(stack, "flat"))
    np.save(sc_dir / "kernel.npy", np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]], float))
    (sc_dir / "notes.txt").write_text(f"{SECRET} 1 2\n")
    os.mkfifo(sc_dir / "pipe.txt")
    (sc_dir / "sub").mkdir()
    (root / "private.txt").write_text(f"{SECRET}\n")
    os.symlink(root / "private.txt", sc_dir / "link.txt")
    return sc_dir


@pytest.fixture(scope="module")
def server(folder):
    with served(folder / "serve.toml", "--read-timeout", 3, "--idle-timeout", 60,
                env={"CRATERSCAPE_MEMORY_LIMIT": "3G"}) as (proc, port):
        yield proc, port


def _site(c):
    sx, sy = c.info()["site"]
    return sx, sy


def _release(fifo):
    """Open the FIFO's other end, so that a reader blocked on it (the old server) goes on."""
    with contextlib.suppress(OSError):
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))


# ---------------------------------------------------------------- files over the wire
def test_a_psf_kernel_over_the_wire_reads_no_file_outside_the_scenario_folder(server, folder):
    from render.client import Client
    from render.errors import ServerError

    outside = folder.parent / "private.txt"
    absent = folder.parent / "absent.txt"
    names = [str(outside), str(absent), "../private.txt", "sub/../../private.txt",
             "link.txt", "/etc/passwd", "sub", "", ".", "notes.txt", "pipe.txt",
             "missing.npy", "sub/../kernel.npy"]
    reasons = {}
    try:
        with Client("127.0.0.1", server[1], timeout=10.0) as c:
            for name in names:
                t0 = time.monotonic()
                with pytest.raises(ServerError) as err:
                    c.set_sensor(psf_kernel=name)
                assert time.monotonic() - t0 < 5.0, name     # never a blocking open
                assert err.value.code == E_INVALID, (name, err.value)
                assert SECRET not in err.value.reason, name  # never a file's content
                reasons[name] = err.value.reason.replace(name, "NAME")
            # a file outside cannot be told from one that does not exist
            assert reasons[str(outside)] == reasons[str(absent)]
            assert reasons["../private.txt"] == reasons["sub/../../private.txt"]
            # a kernel beside the scenario is taken, and the reply names it as the client did
            got = c.set_sensor(psf_kernel="kernel.npy")
            assert got["psf_kernel"] == "kernel.npy"
            assert str(folder) not in str(got)
            sx, sy = _site(c)
            c.set_pose((sx, sy, 1200.0), NADIR)
            assert c.get_image().shape == (48, 64)
    finally:
        _release(folder / "pipe.txt")
    with Client("127.0.0.1", server[1], timeout=10.0) as other:  # nobody was stalled
        other.ping()


def test_deep_json_and_missing_kernels_get_the_codes_of_the_protocol_page(server):
    from render.client import Client
    from render.errors import ServerError

    with Client("127.0.0.1", server[1], timeout=10.0) as c:
        for body in (b"[" * 60000, b'{"psf": ' + b"[" * 30000 + b"]" * 30000 + b"}",
                     b'{"psf": [[1.0, ' + b"[" * 40 + b"]" * 40 + b"]]}"):
            with pytest.raises(ServerError) as err:
                c.request(T_SET_SENSOR, body)
            assert err.value.code == E_MALFORMED, err.value
        with pytest.raises(ServerError) as err:
            c.set_sensor(psf_kernel="missing.npy")
        assert err.value.code == E_INVALID and "missing.npy" in err.value.reason
        c.ping()


# ---------------------------------------------------------------- numbers on receipt
@pytest.mark.parametrize("slot", range(9))
def test_motion_out_of_range_is_refused_when_it_arrives(server, slot):
    values = [0.0] * 9
    values[slot] = 1e300
    c = Raw(server[1], timeout=20.0)
    try:
        assert error_of(*c.call(T_SET_MOTION, struct.pack("<9d", *values))) == E_INVALID
    finally:
        c.close()


def test_times_and_motions_accepted_never_break_a_later_frame(server):
    from render.client import Client
    from render.errors import ServerError

    with Client("127.0.0.1", server[1], timeout=60.0) as c:
        sx, sy = _site(c)
        for t in (1e308, -1e308, 1e300):
            with pytest.raises(ServerError) as err:
                c.set_pose((sx, sy, 1200.0), NADIR, time=t)
            assert err.value.code == E_INVALID and "time" in err.value.reason
        c.set_pose((sx, sy, 1200.0), NADIR, time=1e6)   # a mission clock is fine
        c.set_motion((300.0, 0.0, -20.0), (0.0, 0.01, 0.0))
        image = c.get_image()
        assert image.shape == (48, 64) and image.max() > 0


@pytest.mark.parametrize("key", ["line_time", "exposure_time", "transfer_time"])
def test_sensor_times_beyond_any_camera_are_refused_and_the_next_frame_renders(server, key):
    """A line time of 1.8e308 s made the exposure span infinite and every later frame fail
    as INTERNAL (found by the fuzz test)."""
    from render.client import Client
    from render.errors import ServerError

    with Client("127.0.0.1", server[1], timeout=60.0) as c:
        sx, sy = _site(c)
        c.set_pose((sx, sy, 1200.0), NADIR)
        with pytest.raises(ServerError) as err:
            c.set_sensor(**{key: 1.7976931348623157e308})
        assert err.value.code == E_INVALID and key in err.value.reason
        assert c.get_image().max() > 0


def test_a_frame_too_large_to_render_is_refused_when_the_size_arrives(server):
    """The scenario renders 3 x 3 samples a pixel: 4096^2 pixels are 12288^2 samples, above
    the largest side; 2700^2 would need more memory than the server's limit (3 GiB here)."""
    from render.client import Client
    from render.errors import ServerError

    with Client("127.0.0.1", server[1], timeout=60.0) as c:
        with pytest.raises(ServerError) as err:
            c.set_sensor(width=4096, height=4096)
        assert err.value.code == E_INVALID and "12288" in err.value.reason
        with pytest.raises(ServerError) as err:
            c.set_sensor(width=2700, height=2700)
        assert err.value.code == E_INVALID and "memory" in err.value.reason
        assert c.set_sensor(width=64, height=48)["width"] == 64  # the old size still serves
        sx, sy = _site(c)
        c.set_pose((sx, sy, 1200.0), NADIR)
        assert c.get_image().shape == (48, 64)


# ---------------------------------------------------------------- fuzzing the server
EDGE = [0.0, -0.0, 1.0, -1.0, 5e-324, 1e-300, 1e10, 1e11, 1e300, 1.7976931348623157e308,
        -1e308, math.inf, -math.inf, math.nan]
HOSTILE_NAMES = ["../private.txt", "/etc/passwd", "link.txt", "pipe.txt", "notes.txt",
                 "sub", ".", "..", "", "kernel.npy", "missing.npy", "a\x00b", "\\\\host\\x",
                 "sub/../kernel.npy", "~/x", "%s%n", "k" * 300]
numbers = st.one_of(st.sampled_from(EDGE), st.floats(allow_nan=True, allow_infinity=True))
psf_names = st.one_of(st.sampled_from(HOSTILE_NAMES), st.text(max_size=40))
sensor_values = st.one_of(numbers, st.integers(-2**70, 2**70), st.booleans(), st.none(),
                          st.text(max_size=10),
                          st.lists(st.lists(numbers, max_size=3), max_size=3))


def _request(kind, draw):
    if kind == "pose":
        return T_SET_POSE, struct.pack("<3d4ddII", *[draw(numbers) for _ in range(8)],
                                       draw(st.integers(0, 2**32 - 1)), 0)
    if kind == "motion":
        return T_SET_MOTION, struct.pack("<9d", *[draw(numbers) for _ in range(9)])
    if kind == "sun":
        return T_SET_SUN, struct.pack("<3d", *[draw(numbers) for _ in range(3)])
    if kind == "ray":
        return T_RAY, struct.pack("<6d", *[draw(numbers) for _ in range(6)])
    if kind == "pixel":
        return T_PIXEL_RAY, struct.pack("<2d", draw(numbers), draw(numbers))
    if kind == "height":
        return T_HEIGHT_AT, struct.pack("<2d", draw(numbers), draw(numbers))
    if kind == "kernel":
        return T_SET_SENSOR, json.dumps({"psf_kernel": draw(psf_names)}).encode("utf-8")
    key = draw(st.sampled_from(["width", "height", "psf", "psf_sigma", "exposure", "gain",
                                "bits", "read_noise", "line_time", "noise", "prnu_seed"]))
    try:
        body = json.dumps({key: draw(sensor_values)})
    except ValueError:
        body = "{}"
    return T_SET_SENSOR, body.encode("utf-8")


KINDS = ["pose", "motion", "sun", "ray", "pixel", "height", "kernel", "sensor"]


@given(st.data())
def test_fuzz_file_names_and_numeric_edges_never_hurt_the_server(server, folder, data):
    """Bounded: each example is one connection of at most 6 requests and a frame; every
    reply is the request's own or an error with an open code (never INTERNAL), and the
    frame after whatever was accepted renders."""
    deadline = time.monotonic() + 60.0
    c = Raw(server[1], timeout=30.0)
    try:
        assert c.call(T_SET_POSE, pose_body((1625.0, 1625.0, 2500.0), NADIR))[0] \
            == T_SET_POSE | 0x8000
        for _ in range(data.draw(st.integers(1, 6))):
            mtype, body = _request(data.draw(st.sampled_from(KINDS)), data.draw)
            rtype, rbody = c.call(mtype, body)
            if rtype == T_ERROR:
                code = error_of(rtype, rbody)
                assert code in OPEN_CODES - {E_INTERNAL}, (mtype, body[:80], rbody)
                assert SECRET not in rbody.decode("utf-8", "replace")
            else:
                assert rtype == mtype | 0x8000
        rtype, rbody = c.call(T_GET_RANGE)
        if rtype == T_ERROR:  # a frame may be refused, never fail
            assert error_of(rtype, rbody) in (E_NO_POSE, E_INSIDE), rbody
        assert time.monotonic() < deadline
    finally:
        c.close()
        _release(folder / "pipe.txt")


# ---------------------------------------------------------------- slots and memory
def _flood(port, stop, count):
    """Keep ``count`` silent connections open, reconnecting each as soon as it is closed."""
    socks = []
    while not stop.is_set():
        socks = [s for s in socks if not _gone(s)]
        while len(socks) < count and not stop.is_set():
            try:
                socks.append(socket.create_connection(("127.0.0.1", port), timeout=1.0))
            except OSError:
                break
        time.sleep(0.02)
    for s in socks:
        s.close()


def _gone(s) -> bool:
    s.setblocking(False)
    try:
        data = s.recv(4096)
    except BlockingIOError:
        return False
    except OSError:
        data = b""
    if data and not data.startswith(b"CSRV"):
        return False
    s.close()
    return True


@pytest.mark.slow
def test_clients_without_the_token_cannot_lock_out_those_with_it(folder):
    from render.client import Client
    from render.errors import ServerError

    with served(folder / "flat.toml", "--token", "s3cret", "--max-clients", 2,
                "--read-timeout", 3) as (_, port):
        silent = Raw(port)
        t0 = time.monotonic()
        rtype, _, body = silent.reply()     # the handshake window is short, not a read timeout
        assert error_of(rtype, body) == E_TIMEOUT and time.monotonic() - t0 < 3.5
        silent.close()
        stop = threading.Event()
        flood = threading.Thread(target=_flood, args=(port, stop, 24))
        flood.start()
        served_ok, refused = 0, []
        try:
            time.sleep(1.0)
            for _ in range(10):
                try:
                    with Client("127.0.0.1", port, token="s3cret", timeout=10.0) as c:
                        c.info()
                    served_ok += 1
                except ServerError as exc:
                    refused.append(exc.code)
                time.sleep(0.3)
        finally:
            stop.set()
            flood.join()
        assert served_ok == 10, refused


@pytest.mark.slow
def test_pinging_or_silent_clients_cannot_hold_the_slots_of_a_tokenless_server(folder):
    from render.client import Client
    from render.errors import ServerError

    with served(folder / "flat.toml", "--max-clients", 2, "--idle-timeout", 3,
                "--read-timeout", 3) as (_, port):
        stop = threading.Event()

        def keepalive():
            with contextlib.suppress(OSError, ServerError), \
                    Client("127.0.0.1", port, timeout=10.0) as c:
                while not stop.is_set():
                    c.ping()
                    time.sleep(0.5)

        holders = [threading.Thread(target=keepalive) for _ in range(2)]
        flood = threading.Thread(target=_flood, args=(port, stop, 24))
        for th in holders:
            th.start()
        time.sleep(1.0)
        flood.start()
        t0 = time.monotonic()
        got = None
        try:
            while got is None and time.monotonic() - t0 < 10.0:
                try:
                    with Client("127.0.0.1", port, timeout=10.0) as c:
                        got = c.info()["scene"]
                except ServerError as exc:
                    assert exc.code == E_BUSY
                    time.sleep(0.3)
        finally:
            stop.set()
            for th in (*holders, flood):
                th.join()
        assert got == "terrain"
        assert time.monotonic() - t0 < 6.0  # within the idle timeout, and a little


@pytest.mark.slow
def test_replies_nobody_reads_do_not_pile_up_in_the_servers_memory(folder):
    """Six clients ask for 2896^2 normals (100 MB each) and never read. The server may use
    1 GiB here, so it keeps at most 128 MiB of unread replies and 256 MiB of last frames: it
    grows by less than 768 MiB (without budgets: about 900 MiB, and 3.4 GB at 4096^2), and a
    seventh client is served at once instead of after the six renders."""
    from render.client import Client

    side = 2896
    with served(folder / "flat.toml", "--read-timeout", 3,
                env={"CRATERSCAPE_MEMORY_LIMIT": "1G"}) as (proc, port):
        with Client("127.0.0.1", port, timeout=60.0) as c:
            sx, sy = _site(c)
        base = peak = rss_bytes(proc.pid)
        hogs = []
        try:
            for _ in range(6):
                h = Raw(port, timeout=120.0)
                hogs.append(h)
                h.s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
                sensor = json.dumps({"width": side, "height": side}).encode()
                assert h.call(T_SET_SENSOR, sensor)[0] == T_SET_SENSOR | 0x8000
                assert h.call(T_SET_POSE, pose_body((sx, sy, 1500.0), NADIR))[0] \
                    == T_SET_POSE | 0x8000
                h.send(T_GET_NORMALS)
                peak = max(peak, rss_bytes(proc.pid))
            t0 = time.monotonic()
            with Client("127.0.0.1", port, timeout=120.0) as c:
                c.set_pose((sx, sy, 1500.0), NADIR)
                assert c.get_range().shape == (48, 64)
            assert time.monotonic() - t0 < 5.0
            while time.monotonic() - t0 < 20.0:
                peak = max(peak, rss_bytes(proc.pid))
                time.sleep(0.2)
        finally:
            for h in hogs:
                h.close()
        assert peak - base < 768 * 2**20, (base, peak)
