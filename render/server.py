"""The render server: flight software drives the camera pose by pose over TCP.

``craterscape render serve SCENARIO.toml`` loads the scenario's scene once (terrain layer
stack or asteroid), prepares its shadows with a first frame, and answers requests in the wire
protocol of ``docs/protocol.md`` (codecs in :mod:`render.protocol`) until SIGINT or SIGTERM.

Threads:

- The thread that calls :meth:`RenderServer.serve` (the main thread under the CLI) owns the
  OpenGL context and does every render, one request at a time.
- An acceptor thread accepts connections. A new connection is pending until it is admitted:
  by a HELLO with the token on a token server, by its first whole request on a server without
  one. It must be admitted within the handshake window (:data:`HANDSHAKE_TIMEOUT`, at most
  the read timeout) or it is closed, and pending connections have a pool of their own
  (:data:`PENDING_PER_CLIENT` per client slot, the oldest dropped for a new one), so they
  never take the ``max_clients`` slots of admitted clients. An admitted client that sends no
  request but PING for the idle timeout is closed: a keep-alive holds no slot forever.
- One thread per connection reads its messages with a timeout on every read, checks framing
  and authorisation, queues the request, waits for its reply and sends it (with a write
  timeout). A slow, silent or vanished client only ever blocks its own thread.

Memory: replies not yet taken by their clients count against a budget
(:data:`REPLY_MEMORY`, at most an eighth of the memory the process may use); a request whose
reply would exceed it waits in the queue (others are served meanwhile) until clients read
theirs or are closed for not reading. The clients' last frames have a budget of their own
(:data:`FRAME_CACHE_BYTES`, at most a quarter). A frame size is checked against the largest
side and the memory it needs when a client sets it.

Fairness: a connection has at most one request in the queue (its thread reads the next only
after sending the reply), so the FIFO queue serves busy clients round robin.

Every frame is made by :func:`render.sequence.render_sample`, the path of ``craterscape render
frame``, so the server's image equals that command's at the same pose, time and frame index,
byte for byte. Each connection has its own pose, time, sun and sensor settings, and keeps its
last frame, so asking for the image and then the range renders once.
"""

from __future__ import annotations

import dataclasses
import hmac
import ipaddress
import json
import logging
import math
import os
import queue
import signal
import socket
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from render.asteroid_scene import AsteroidScene
from render.binary_scene import BinaryScene
from render.camera import Intrinsics, Pose, look_at
from render.errors import ProtocolError
from render.mesh_scene import MeshBodyScene
from render.motion import Motion
from render.protocol import (
    ARRAY_HEAD,
    BITS,
    CLOSING,
    ERROR,
    HEIGHT_REPLY,
    IMAGE_HEAD,
    MAX_REQUEST_BODY,
    MAX_TOKEN,
    MINOR_VERSION,
    MOTION,
    POSE,
    PROTOCOL_MINOR,
    RAY,
    RAY_REPLY,
    REPLY,
    REQUEST_SIZES,
    SHADING_KEYS,
    SUN,
    VERSION,
    XY,
    ErrorCode,
    MsgType,
    error_body,
    json_body,
    pack_header,
    read_message,
)
from render.renderer import Lighting, Renderer, View
from render.scenario import Scenario, parse_scenario
from render.scene import Scene
from render.sequence import check_frame_memory, load_scene, render_sample
from render.server_sensors import SENSOR_REQUESTS
from render.server_sensors import answer as answer_sensor
from render.terrain_scene import TerrainScene
from render.trajectory import Sample, spin_rotation
from terrain.core.checks import boolean, number, reject_unknown
from terrain.core.errors import InvalidParameterError, MemoryRequestError, MissingInputError

__all__ = ["RenderServer", "is_loopback"]

log = logging.getLogger(__name__)

#: Camera positions farther than this from the world origin are refused (m).
MAX_POSITION = 1e10
#: Largest image side and pixel count a client may ask for.
MAX_SIDE = 8192
MAX_PIXELS = 4096 * 4096
#: Focal length (pixels) of the one-pixel camera that casts a single ray: a 10 microradian
#: pixel, so the terrain and the body are drawn at their finest level of detail along it.
RAY_FOCAL = 1e5
#: Bytes of last frames kept for all clients together (radiance, range, normals, image); the
#: least recently rendered are dropped first and rendered again if asked for (same bytes).
#: At most a quarter of the memory the server may use (``terrain.core.memory``).
FRAME_CACHE_BYTES = 1 << 30
#: Bytes of replies built but not yet taken by their clients, all clients together; at most
#: an eighth of the memory the server may use. One reply larger than this is still sent when
#: no other is waiting.
REPLY_MEMORY = 512 << 20
#: Longest time (s) a new connection has to be admitted (HELLO with the token, or its first
#: request without one); never longer than the read timeout.
HANDSHAKE_TIMEOUT = 2.0
#: Floor (s) of the wait for the rest of a first message whose window has run out while the
#: server was busy (a tenth of it for the first byte, which is then already waiting).
LATE_READ = 0.5
#: Pending (not yet admitted) connections allowed per client slot; beyond them the oldest
#: pending one is dropped for the new one.
PENDING_PER_CLIENT = 4
#: Latest and earliest scene time a pose may carry (s): a mission clock fits (seconds since
#: J2000 are below 1e9), and an exposure's sub-frame times stay exact to microseconds.
MAX_TIME = 1e10
#: Fastest camera velocity (m/s) and angular velocities (rad/s) of SET_MOTION: far beyond any
#: spacecraft and any spin, and small enough that an exposure's motion stays finite.
MAX_SPEED = 1e6
MAX_RATE = 1e3
#: Deepest nesting of a SET_SENSOR JSON body (the sensor's deepest value, psf, is 3 deep).
MAX_JSON_DEPTH = 8
#: Keys of SET_SENSOR handled by the server itself; the rest belong to the [sensor] table.
SERVER_SENSOR_KEYS = ("width", "height", "noise")
#: What ``noise = false`` sets on the sensor: no shot noise, no read noise, no fixed pattern
#: (dark current stays: its mean is signal).
NOISELESS = {"shot_noise": False, "read_noise": 0.0, "prnu": 0.0}


def is_loopback(host: str) -> bool:
    """Whether every address ``host`` resolves to is a loopback address."""
    try:
        infos = socket.getaddrinfo(host, None)
    except socket.gaierror as exc:
        raise InvalidParameterError(f"cannot resolve host '{host}': {exc}") from None
    return all(ipaddress.ip_address(str(info[4][0]).split("%")[0]).is_loopback for info in infos)


def _noiseless(sensor):
    return dataclasses.replace(sensor, **NOISELESS)


@dataclass(eq=False)
class _State:
    """One connection's settings and its last frame (touched by the render thread only)."""

    scenario: Scenario            # sensor and resolution as set by the client
    lighting: Lighting
    sensor_table: dict
    noise: bool = True
    pose: Pose | None = None
    time: float = 0.0
    index: int = 0
    motion: Motion | None = None  # velocities during the exposure, as the client set them
    frame: tuple | None = None    # (image, Frame, FrameTruth)
    sun_table: dict | None = None  # the [sun] table SET_LIGHT set (None: the scenario's)

    @property
    def sensor(self):
        return self.scenario.sensor if self.noise else _noiseless(self.scenario.sensor)


class _Connection:
    def __init__(self, server: RenderServer, sock: socket.socket, address, number: int):
        self.server = server
        self.sock = sock
        self.address = address
        self.number = number
        self.replies: queue.Queue = queue.Queue(maxsize=1)
        self.admitted = False             # holds one of the max_clients slots
        self.authorized = server.token is None
        self.opened = time.monotonic()
        self.last_work = self.opened      # last request other than PING (the idle clock)
        self.reply_bytes = 0              # this client's reply counted in the reply budget
        sc = server.scenario
        self.state = _State(sc, sc.lighting, dict(sc.raw.get("sensor", {})))
        self.thread = threading.Thread(target=self.run, name=f"client-{number}", daemon=True)
        self.busy = False     # a request of this client is queued, in hand or being answered
        self._closed = threading.Event()

    # ------------------------------------------------------------------ I/O thread
    def run(self):
        srv = self.server
        try:
            while not srv.stopping.is_set():
                try:
                    # a message already waiting is read even when this thread comes late
                    # (a busy render thread can hold it up): hence the floors
                    if self.admitted:
                        # PING keeps nothing alive: the idle clock runs from the last work
                        first = srv.idle_timeout - (time.monotonic() - self.last_work)
                        rest = srv.read_timeout
                    else:  # the whole first message within the handshake window
                        first = srv.handshake_timeout - (time.monotonic() - self.opened)
                        rest = max(first, LATE_READ)
                    first = max(first, LATE_READ / 10)
                    _, msg_type, rid, body = read_message(
                        self.sock, MAX_REQUEST_BODY, first_timeout=first, timeout=rest)
                except ProtocolError as exc:
                    self.send(ERROR, 0, error_body(exc.code, exc.reason))
                    return
                except TimeoutError:
                    if self._closed.is_set():  # dropped for a newer pending connection
                        return
                    self.send(ERROR, 0, error_body(
                        ErrorCode.TIMEOUT, "no complete message within the timeout"
                        if self.admitted else "not admitted within the handshake window "
                        f"({srv.handshake_timeout:g} s); closing"))
                    return
                if not self.admitted:
                    refusal = self.admit(msg_type, body)
                    if refusal is not None:
                        self.send(ERROR, rid, refusal)
                        return
                if msg_type != MsgType.PING:
                    self.last_work = time.monotonic()
                reply = self.answer(msg_type, rid, body)
                if reply is None:
                    return
                rtype, rbody = reply
                try:
                    sent = self.send(rtype, rid, rbody)
                finally:
                    srv.release_reply(self)
                self.busy = False
                if not sent:
                    return
                if msg_type != MsgType.PING:  # a long render is no idleness
                    self.last_work = time.monotonic()
                if rtype == ERROR and int.from_bytes(rbody[:2], "little") in CLOSING:
                    return
        except (ConnectionError, OSError) as exc:
            log.info("client %d %s: %s", self.number, self.address, exc)
        finally:
            self.close()
            srv.forget(self)

    def admit(self, msg_type: int, body: bytes) -> bytes | None:
        """Take a client slot for this connection; return the error body of a refusal."""
        srv = self.server
        if not self.authorized:
            if msg_type != MsgType.HELLO or not srv.check_token(body):
                return error_body(ErrorCode.UNAUTHORIZED,
                                  "this server needs a HELLO with its token first")
        if not srv.take_slot(self):
            return error_body(ErrorCode.BUSY, f"{srv.max_clients} clients are already "
                              "connected; try again later")
        self.authorized = True
        return None

    def answer(self, msg_type: int, rid: int, body: bytes):
        """Return the reply (type, body) to one message, or None when the server stopped."""
        srv = self.server
        try:
            kind = MsgType(msg_type)
        except ValueError:
            return ERROR, error_body(ErrorCode.UNKNOWN_TYPE,
                                     f"unknown request type 0x{msg_type:04x}")
        size = REQUEST_SIZES[kind]
        if size is not None and len(body) != size:
            return ERROR, error_body(ErrorCode.MALFORMED,
                                     f"{kind.name} body must be {size} bytes; got {len(body)}")
        if kind in (MsgType.HELLO, MsgType.PING):
            if kind == MsgType.HELLO and len(body) > MAX_TOKEN:
                return ERROR, error_body(ErrorCode.MALFORMED, "token longer than 256 bytes")
            return kind | REPLY, b""
        self.busy = True
        srv.work.put((self, kind, body))
        while True:
            try:
                return self.replies.get(timeout=0.5)
            except queue.Empty:
                if self._closed.is_set():
                    return None

    def send(self, msg_type: int, rid: int, body: bytes) -> bool:
        try:
            self.sock.settimeout(self.server.write_timeout)
            self.sock.sendall(pack_header(msg_type, rid, len(body)))
            if body:
                self.sock.sendall(body)
            return True
        except OSError as exc:  # vanished or too slow to read: drop it
            log.info("client %d: cannot send reply (%s); closing", self.number, exc)
            return False

    def close(self):
        if not self._closed.is_set():
            self._closed.set()
            try:
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self.sock.close()


class RenderServer:
    """Serves one scenario's scene (see the module docstring).

    Parameters
    ----------
    scenario : render.scenario.Scenario
    host : str
        Address to bind; anything but loopback needs ``token``.
    port : int
        TCP port; 0 picks a free one (see :attr:`address` after :meth:`bind`).
    token : str, optional
        Shared secret every client sends in HELLO first.
    idle_timeout, read_timeout, write_timeout : float, seconds
        Longest wait for a client's next request, for the rest of a message once it has begun,
        and for a client to take its reply.
    max_clients : int
        Admitted connections served at once (pending ones have a pool of their own).
    handshake_timeout : float, seconds, optional
        Longest time a new connection has to be admitted (default :data:`HANDSHAKE_TIMEOUT`,
        at most ``read_timeout``).
    reply_memory : int, bytes, optional
        Budget of replies not yet taken by their clients (default :data:`REPLY_MEMORY`, at
        most an eighth of the memory the process may use).
    """

    def __init__(self, scenario: Scenario, host: str = "127.0.0.1", port: int = 10363, *,
                 token: str | None = None, idle_timeout: float = 300.0,
                 read_timeout: float = 10.0, write_timeout: float = 30.0,
                 max_clients: int = 32, handshake_timeout: float | None = None,
                 reply_memory: int | None = None):
        if token is not None:
            token = str(token)
            if not token or len(token.encode("utf-8")) > MAX_TOKEN:
                raise InvalidParameterError("the token must be 1 to 256 bytes of UTF-8")
        elif not is_loopback(host):
            raise InvalidParameterError(
                f"binding to {host} (not loopback) needs a shared token: give --token or set "
                "CRATERSCAPE_TOKEN")
        if not 0 <= int(port) <= 65535:
            raise InvalidParameterError(f"port must lie in [0, 65535]; got {port}")
        if handshake_timeout is None:
            handshake_timeout = min(HANDSHAKE_TIMEOUT, float(read_timeout))
        for name, v in (("idle timeout", idle_timeout), ("read timeout", read_timeout),
                        ("write timeout", write_timeout),
                        ("handshake timeout", handshake_timeout)):
            if not (v > 0 and math.isfinite(v)):
                raise InvalidParameterError(f"{name} must be a positive number of seconds; "
                                            f"got {v}")
        if int(max_clients) < 1:
            raise InvalidParameterError(f"max_clients must be at least 1; got {max_clients}")
        self.scenario = scenario
        self.host, self.port = host, int(port)
        self.token = token
        self.idle_timeout, self.read_timeout = float(idle_timeout), float(read_timeout)
        self.write_timeout = float(write_timeout)
        self.handshake_timeout = float(handshake_timeout)
        self.max_clients = int(max_clients)
        from terrain.core.memory import available_bytes

        avail = available_bytes()
        self.frame_cache_bytes = min(FRAME_CACHE_BYTES, avail // 4)
        self.reply_memory = int(reply_memory) if reply_memory is not None \
            else min(REPLY_MEMORY, avail // 8)
        self._pending: list[_Connection] = []   # oldest first
        self._queued = 0                         # bytes of replies not yet sent
        self._sent = threading.Condition(threading.Lock())
        self.work: queue.Queue = queue.Queue()
        self.stopping = threading.Event()
        self._clients: set[_Connection] = set()
        self._lock = threading.Lock()
        self._count = 0
        self._listener: socket.socket | None = None
        self._cached: dict[int, _State] = {}   # insertion order = render order
        self._labeller: Any = None  # render.labels.Labeller, made at the first GET_LABELS
        self.renderer: Renderer | None = None
        # The loaded scene (render.sequence.load_scene): a terrain or an asteroid scene.
        self._scene: Scene | None = None
        self.requests = 0

    # ------------------------------------------------------------------ set-up
    def load(self) -> None:
        """Load the scene and render the scenario's first frame.

        This uploads the geometry, compiles the programs and prepares the shadow maps.
        """
        self.renderer = Renderer()
        self._scene = load_scene(self.scenario)
        samples = self.scenario.samples(self.scene)
        if samples:
            render_sample(self.renderer, self.scene, self.scenario, samples[0], 0)

    def bind(self) -> tuple[str, int]:
        """Open the listening socket; returns the (host, port) bound."""
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        try:
            self._listener = socket.create_server((self.host, self.port), family=family,
                                                  backlog=64)
        except OSError as exc:
            raise InvalidParameterError(
                f"cannot listen on {self.host}:{self.port}: {exc.strerror or exc}") from None
        self._listener.settimeout(0.25)
        return self.address

    @property
    def address(self) -> tuple[str, int]:
        """The (host, port) the server listens on (after :meth:`bind`)."""
        if self._listener is None:
            raise InvalidParameterError("the server is not listening yet; call bind() first")
        return self._listener.getsockname()[:2]

    @property
    def scene(self) -> Scene:
        """The scene :meth:`load` loaded (a terrain or an asteroid scene)."""
        if self._scene is None:
            raise InvalidParameterError("the server has not loaded its scene; call load() first")
        return self._scene

    @property
    def _gpu(self) -> Renderer:
        """The renderer :meth:`load` made (every frame request comes after it)."""
        if self.renderer is None:
            raise InvalidParameterError("the server has not loaded its scene; call load() first")
        return self.renderer

    def check_token(self, body: bytes) -> bool:
        """Return whether a HELLO body carries the server's token (always, without one)."""
        if self.token is None:
            return True
        return hmac.compare_digest(body, self.token.encode("utf-8"))

    def take_slot(self, conn: _Connection) -> bool:
        """Move a pending connection to a client slot; False when all are taken."""
        with self._lock:
            if conn in self._pending:
                self._pending.remove(conn)
            if len(self._clients) >= self.max_clients:
                return False
            self._clients.add(conn)
            conn.admitted = True
            return True

    def release_reply(self, conn: _Connection) -> None:
        """Give back the reply budget a connection's reply held (sent or not)."""
        with self._sent:
            self._queued -= conn.reply_bytes
            conn.reply_bytes = 0
            self._sent.notify_all()

    def forget(self, conn: _Connection) -> None:
        """Drop a closed connection (its pending frame is dropped by the render thread)."""
        with self._lock:
            self._clients.discard(conn)
            if conn in self._pending:
                self._pending.remove(conn)
        self.release_reply(conn)
        self.work.put((conn, None, b""))  # the render thread drops its frame

    def stop(self, *_args) -> None:
        """Ask the server to stop after the request in hand (also the signal handler)."""
        self.stopping.set()

    # ------------------------------------------------------------------ main loop
    def serve(self, *, handle_signals: bool = True) -> None:
        """Answer requests until :meth:`stop` (or SIGINT/SIGTERM); then close everything."""
        if self.renderer is None:
            self.load()
        if self._listener is None:
            self.bind()
        previous = {}
        if handle_signals and threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                previous[sig] = signal.signal(sig, self.stop)
        acceptor = threading.Thread(target=self._accept, name="acceptor", daemon=True)
        acceptor.start()
        log.info("serving %s on %s:%d", self.scenario.name, *self.address)
        try:
            while not self.stopping.is_set():
                try:
                    conn, kind, body = self.work.get(timeout=0.25)
                except queue.Empty:
                    continue
                if kind is None:  # the client is gone
                    self._cached.pop(id(conn.state), None)
                    conn.state.frame = None
                    continue
                if conn._closed.is_set():
                    continue
                need = self._reply_size(conn.state, kind)
                with self._sent:
                    if need and self._queued and self._queued + need > self.reply_memory:
                        # unread replies fill the budget: serve the others first
                        self.work.put((conn, kind, body))
                        self._sent.wait(timeout=0.05)
                        continue
                reply = self._reply(conn, kind, body)
                with self._sent:
                    conn.reply_bytes = len(reply[1])
                    self._queued += conn.reply_bytes
                conn.replies.put(reply)
                if conn._closed.is_set():  # gone while it was rendered: nobody sends it
                    self.release_reply(conn)
        finally:
            self.stopping.set()
            self._shutdown(acceptor)
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _accept(self):
        while not self.stopping.is_set():
            try:
                sock, address = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._count += 1
                conn = _Connection(self, sock, address, self._count)
                self._pending.append(conn)
                oldest = None
                if len(self._pending) > PENDING_PER_CLIENT * self.max_clients:
                    oldest = self._pending.pop(0)
            if oldest is not None:  # its thread sees the close and ends
                log.info("client %d dropped unadmitted for a newer one", oldest.number)
                oldest.close()
            log.info("client %d connected from %s", conn.number, address)
            conn.thread.start()

    def _shutdown(self, acceptor):
        if self._listener is not None:
            self._listener.close()
        acceptor.join(timeout=2.0)
        while True:
            try:
                conn, kind, _ = self.work.get_nowait()
            except queue.Empty:
                break
            if kind is not None:
                conn.replies.put((ERROR, error_body(ErrorCode.SHUTTING_DOWN,
                                                    "the server is shutting down")))
        with self._lock:
            clients = list(self._clients) + list(self._pending)
        for conn in clients:  # idle ones now; busy ones once their reply is sent
            if not conn.busy:
                conn.close()
        for conn in clients:
            conn.thread.join(timeout=self.write_timeout + 1.0 if conn.busy else 2.0)
            conn.close()
        log.info("server stopped after %d requests", self.requests)

    # ------------------------------------------------------------------ requests
    def _reply(self, conn: _Connection, kind: MsgType, body: bytes):
        self.requests += 1
        try:
            return kind | REPLY, self._handle(conn.state, kind, body)
        except ProtocolError as exc:
            return ERROR, error_body(exc.code, exc.reason)
        except RecursionError:
            return ERROR, error_body(ErrorCode.MALFORMED, f"{kind.name} body is nested too "
                                     "deeply")
        except (InvalidParameterError, MissingInputError, MemoryRequestError, ValueError,
                TypeError) as exc:
            # a bad value, a missing input the request names, or a request beyond memory
            return ERROR, error_body(ErrorCode.INVALID_VALUE, str(exc))
        except Exception as exc:  # a failed render must not take the server down
            log.exception("request %s failed", kind.name)
            return ERROR, error_body(ErrorCode.INTERNAL, f"{type(exc).__name__}: {exc}")

    @staticmethod
    def _reply_size(st: _State, kind: MsgType) -> int:
        """Bytes of the reply to ``kind`` at the client's image size (small ones: 0)."""
        k = st.scenario.intrinsics
        per_pixel = {MsgType.GET_IMAGE: 2, MsgType.GET_RANGE: 4, MsgType.GET_NORMALS: 12,
                     MsgType.GET_MASKS: 4, MsgType.GET_BODY_IDS: 1}
        return k.width * k.height * per_pixel.get(kind, 0)

    def _handle(self, st: _State, kind: MsgType, body: bytes) -> bytes:
        if kind == MsgType.INFO:
            return json_body(self._info(st))
        if kind == MsgType.SET_POSE:
            self._set_pose(st, POSE.unpack(body))
            return b""
        if kind == MsgType.SET_SUN:
            sun = SUN.unpack(body)
            _finite("sun direction", sun)
            st.lighting = dataclasses.replace(st.lighting, sun=_scaled(sun, "sun direction"))
            st.scenario = dataclasses.replace(st.scenario, ephemeris=None)  # hand-set now
            st.frame = None
            return b""
        if kind == MsgType.SET_SENSOR:
            return json_body(self._set_sensor(st, body))
        if kind == MsgType.SET_LIGHT:
            return json_body(self._set_light(st, body))
        if kind == MsgType.SET_SHADING:
            return json_body(self._set_shading(st, body))
        if kind == MsgType.SET_MOTION:
            v = MOTION.unpack(body)
            _finite("motion", v)
            for i, (name, bound, unit) in enumerate((
                    ("velocity", MAX_SPEED, "m/s"), ("angular velocity", MAX_RATE, "rad/s"),
                    ("body angular velocity", MAX_RATE, "rad/s"))):
                for x in v[3 * i:3 * i + 3]:
                    number(x, f"{name} ({unit})", low=-bound, high=bound, where="SET_MOTION")
            base = self.scenario.motion.get("motion") or Motion()
            st.motion = dataclasses.replace(base, velocity=v[0:3], angular_velocity=v[3:6],
                                            body_angular_velocity=v[6:9])
            st.frame = None
            return b""
        if kind == MsgType.GET_IMAGE:
            (bits,) = BITS.unpack(body)
            if bits > 16:
                raise ProtocolError(ErrorCode.INVALID_VALUE,
                                    f"bits must be 0 (the sensor's) or 1 to 16; got {bits}")
            image, frame, _ = self._frame(st)
            sensor = st.sensor
            if bits and bits != sensor.bits:
                sensor = dataclasses.replace(sensor, bits=bits)
                image = sensor.expose(frame.radiance, frame=st.index,
                                      intrinsics=st.scenario.intrinsics,
                                      spectral_irradiance=st.lighting.spectral_irradiance)
            h, w = image.shape
            return IMAGE_HEAD.pack(w, h, sensor.bits, 0) + image.astype(
                "<u1" if sensor.bits <= 8 else "<u2").tobytes()
        if kind in (MsgType.GET_RANGE, MsgType.GET_NORMALS):
            _, frame, _ = self._frame(st)
            a = frame.range if kind == MsgType.GET_RANGE else frame.normals
            return ARRAY_HEAD.pack(a.shape[1], a.shape[0]) + a.astype(
                "<f4", copy=False).tobytes()
        if kind in SENSOR_REQUESTS:
            return answer_sensor(self, st, kind, body)
        if kind == MsgType.GET_BODY_IDS:
            kind_of = self.scenario.scene.type
            if kind_of != "binary":
                raise ProtocolError(ErrorCode.UNSUPPORTED, "GET_BODY_IDS needs a binary scene "
                                    f"(this one is {kind_of})")
            _, frame, _ = self._frame(st)
            ids = frame.body_ids
            return ARRAY_HEAD.pack(ids.shape[1], ids.shape[0]) + ids.astype("<u1").tobytes()
        if kind == MsgType.GET_TRUTH:
            _, _, truth = self._frame(st)
            d = truth.as_dict()
            for key in ("image", "range", "normals", "body_ids"):
                d.pop(key, None)
            return json_body(d)
        if kind in (MsgType.GET_LABELS, MsgType.GET_MASKS):
            return self._labels(st, kind)
        if kind == MsgType.HEIGHT_AT:
            x, y = XY.unpack(body)
            _finite("map point", (x, y))
            return HEIGHT_REPLY.pack(*self.height_and_normal(x, y))
        if kind == MsgType.PIXEL_RAY:
            u, v = XY.unpack(body)
            _finite("pixel", (u, v))
            if st.pose is None:
                raise ProtocolError(ErrorCode.NO_POSE, "set a pose (SET_POSE) first")
            k = st.scenario.intrinsics
            d = st.pose.rotation @ np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0])
            return RAY_REPLY.pack(*self.cast(st.pose.position, d, st.time, st.lighting))
        if kind == MsgType.RAY:
            values = RAY.unpack(body)
            _finite("ray", values)
            origin, direction = values[:3], values[3:]
            if np.linalg.norm(origin) > MAX_POSITION:
                raise ProtocolError(ErrorCode.INVALID_VALUE,
                                    f"ray origin more than {MAX_POSITION:g} m from the origin")
            return RAY_REPLY.pack(*self.cast(origin, direction, st.time, st.lighting))
        raise ProtocolError(ErrorCode.UNKNOWN_TYPE, f"unknown request type {kind!r}")

    def _info(self, st: _State) -> dict:
        lo, hi = self.scene.bounds()
        out = dict(protocol=VERSION, protocol_minor=MINOR_VERSION,
                   scenario=self.scenario.name, scene=self.scene.kind,
                   bounds=[lo.tolist(), hi.tolist()], sun=list(st.lighting.sun),
                   seed=self.scenario.seed, sensor=self._sensor_info(st),
                   shading=_shading(st))
        if isinstance(self.scene, TerrainScene):
            out["site"] = list(self.scene.site)
        out["protocol_minor"] = PROTOCOL_MINOR
        if st.scenario.ephemeris is not None:
            out["utc"] = st.scenario.ephemeris.utc
        return out

    def _set_light(self, st: _State, body: bytes) -> dict:
        """SET_LIGHT: the keys of a scenario's [sun] over those in force (docs/protocol.md)."""
        from render.ephemeris import DATED_KEYS

        settings = _json_object(body, "SET_LIGHT")
        if "kernels" in settings:
            raise ProtocolError(ErrorCode.INVALID_VALUE, "SET_LIGHT kernels: SPICE kernels are "
                                "named in the scenario file only")
        table = dict(st.sun_table if st.sun_table is not None
                     else self.scenario.raw.get("sun", {}))
        if "utc" in settings:  # a date replaces a hand-set sun, and the other way round
            for key in ("azimuth", "elevation", "direction", "distance"):
                table.pop(key, None)
        if any(k in settings for k in ("azimuth", "elevation", "direction")):
            table = {k: v for k, v in table.items() if k not in DATED_KEYS}
        table.update(settings)
        parsed = parse_scenario(dict(self.scenario.raw, sun=table), self.scenario.path)
        scenario = dataclasses.replace(st.scenario, lighting=parsed.lighting,
                                       ephemeris=parsed.ephemeris)
        sky = scenario.sky_at(st.time, self.scene)  # an unplaceable site fails here
        lit = scenario.lighting_at(st.time, self.scene)
        st.scenario, st.lighting, st.sun_table, st.frame = scenario, parsed.lighting, table, None
        out = dict(sun=list(lit.sun), distance_au=lit.distance, time=st.time)
        if sky is not None:
            out.update(sky.as_dict(), utc=parsed.ephemeris.utc if parsed.ephemeris else None)
        return out

    def _set_shading(self, st: _State, body: bytes) -> dict:
        """SET_SHADING: shading switches over those in force, this connection only.

        The keys are ``[render]``'s of the same names (:data:`SHADING_KEYS`), each true or
        false; an empty object changes nothing. Returns every switch in force.
        """
        settings = _json_object(body, "SET_SHADING")
        reject_unknown(settings, SHADING_KEYS, "SET_SHADING")
        values = {k: boolean(v, k, where="SET_SHADING") for k, v in settings.items()}
        if values:
            options = dataclasses.replace(st.scenario.options, **values)
            st.scenario = dataclasses.replace(st.scenario, options=options)
            st.frame = None
        return _shading(st)

    def _sensor_info(self, st: _State) -> dict:
        d = dict(st.scenario.sensor.as_dict(), noise=st.noise)
        if d.get("psf_kernel") is not None:  # as named, not the server's own path
            d["psf_kernel"] = str(st.sensor_table.get("psf_kernel"))
        d.update(st.scenario.intrinsics.as_dict())
        return d

    def _set_pose(self, st: _State, values) -> None:
        x, y, z, qw, qx, qy, qz, t, index, flags = values
        _finite("pose", (x, y, z, qw, qx, qy, qz, t))
        if flags:
            raise ProtocolError(ErrorCode.INVALID_VALUE, f"SET_POSE flags must be 0; got {flags}")
        if math.hypot(x, y, z) > MAX_POSITION:
            raise ProtocolError(ErrorCode.INVALID_VALUE,
                                f"camera position more than {MAX_POSITION:g} m from the origin")
        number(t, "time (s)", low=-MAX_TIME, high=MAX_TIME, where="SET_POSE")
        pose = Pose((x, y, z), _scaled((qw, qx, qy, qz), "attitude quaternion"))
        self._check_outside(pose, t)
        st.pose, st.time, st.index, st.frame = pose, float(t), int(index), None

    def _check_outside(self, pose: Pose, t: float) -> None:
        p = np.asarray(pose.position)
        scene = self.scene
        if isinstance(scene, BinaryScene):
            if scene.contains(p, t):
                raise ProtocolError(ErrorCode.INSIDE_SURFACE,
                                    "camera is inside a body of the binary at that time")
            return
        if isinstance(scene, TerrainScene):
            try:
                ground = scene.height_at(p[0], p[1])
            except InvalidParameterError:
                return  # beyond the terrain's edge: nothing underneath to be inside of
            if p[2] <= ground:
                raise ProtocolError(ErrorCode.INSIDE_SURFACE,
                                    f"camera at height {p[2]:.3f} m is on or below the terrain "
                                    f"({ground:.3f} m at {p[0]:.3f}, {p[1]:.3f})")
            return
        if isinstance(scene, MeshBodyScene):  # any shape: its winding number decides
            if scene.contains(p, self.body_rotation(t)):
                raise ProtocolError(ErrorCode.INSIDE_SURFACE, "camera is inside the body")
            return
        r = float(np.linalg.norm(p))
        # nearer the centre than the body's lowest vertex: inside whatever the direction
        inner = float(scene.body.radii.min()) if isinstance(scene, AsteroidScene) else 0.0
        inside = r < inner
        if not inside and r <= scene.reach:
            rng, _, _, _, nx, ny, nz = self.cast(p, -p, t, self.scenario.lighting)
            # from outside the ray meets the near side (normal against the ray); from inside,
            # the far side's inner face (normal along it) or nothing
            inside = not math.isfinite(rng) or float(np.dot((nx, ny, nz), -p)) > 0
        if inside:
            raise ProtocolError(ErrorCode.INSIDE_SURFACE,
                                f"camera at {r:.3f} m from the centre is inside the body")

    def _set_sensor(self, st: _State, body: bytes) -> dict:
        too_deep = False
        try:
            settings = json.loads(body.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            raise ProtocolError(ErrorCode.MALFORMED,
                                f"SET_SENSOR body is not UTF-8 JSON: {exc}") from None
        except RecursionError:  # nested too deeply for the parser itself
            too_deep = True
        if too_deep or json_depth(settings) > MAX_JSON_DEPTH:
            raise ProtocolError(ErrorCode.MALFORMED, "SET_SENSOR body is nested deeper than "
                                f"{MAX_JSON_DEPTH} levels")
        if not isinstance(settings, dict):
            raise ProtocolError(ErrorCode.MALFORMED, "SET_SENSOR body must be a JSON object")
        if settings.get("psf_kernel") is not None:  # null takes the kernel away
            self._check_kernel_name(settings["psf_kernel"])
        k = st.scenario.intrinsics
        w, h = settings.pop("width", k.width), settings.pop("height", k.height)
        for name, v in (("width", w), ("height", h)):
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= MAX_SIDE:
                raise ProtocolError(ErrorCode.INVALID_VALUE,
                                    f"sensor {name} must be an integer in [1, {MAX_SIDE}]; "
                                    f"got {v!r}")
        if w * h > MAX_PIXELS:
            raise ProtocolError(ErrorCode.INVALID_VALUE,
                                f"sensor {w}x{h} exceeds {MAX_PIXELS} pixels")
        a = self.scenario.options.antialias
        if max(w, h) * a > MAX_SIDE:
            raise ProtocolError(ErrorCode.INVALID_VALUE,
                                f"sensor {w}x{h} at the scenario's {a}x{a} samples a pixel "
                                f"renders {w * a}x{h * a} samples; at most {MAX_SIDE} a side")
        noise = settings.pop("noise", st.noise)
        if not isinstance(noise, bool):
            raise ProtocolError(ErrorCode.INVALID_VALUE,
                                f"sensor noise must be true or false; got {noise!r}")
        table = dict(st.sensor_table, **settings)
        raw = dict(self.scenario.raw, sensor=table)
        parsed = parse_scenario(raw, self.scenario.path)  # the scenario's own validation
        base = self.scenario.with_overrides(None, (w, h))
        check_frame_memory(base)  # MemoryRequestError: INVALID_VALUE, before any allocation
        st.scenario = dataclasses.replace(base, sensor=parsed.sensor, motion=parsed.motion,
                                          ephemeris=st.scenario.ephemeris,  # SET_LIGHT's
                                          options=st.scenario.options)  # SET_SHADING's
        st.sensor_table, st.noise, st.frame = table, noise, None
        return self._sensor_info(st)

    def _check_kernel_name(self, name) -> None:
        """Refuse a ``psf_kernel`` that is not a regular file's bare name beside the scenario.

        One reason for every refusal of a name, so a reply never tells whether a file outside
        the scenario's folder exists; the file is opened (non-blocking) by the sensor.
        """
        folder = None if self.scenario.path is None else self.scenario.path.parent.resolve()
        ok = (folder is not None and isinstance(name, str) and name not in ("", ".", "..")
              and not any(c in name for c in "/\\\0") and Path(name).name == name)
        missing = False
        if ok:
            assert folder is not None
            try:
                p = (folder / name).resolve()
                ok = p.parent == folder
                ok = ok and stat.S_ISREG(os.stat(p).st_mode)
            except FileNotFoundError:
                missing = ok  # beside the scenario, and not there
                ok = False
            except (OSError, RuntimeError, ValueError):
                ok = False
        if missing:
            raise ProtocolError(ErrorCode.INVALID_VALUE, f"SET_SENSOR psf_kernel {name!r}: no "
                                "such file beside the scenario")
        if not ok:
            raise ProtocolError(ErrorCode.INVALID_VALUE,
                                f"SET_SENSOR psf_kernel must be the name of a regular file "
                                f"beside the scenario (no folder, no link out of it); got "
                                f"{name!r}")

    def _frame(self, st: _State):
        if st.pose is None:
            raise ProtocolError(ErrorCode.NO_POSE, "set a pose (SET_POSE) first")
        if st.frame is None:
            sc = dataclasses.replace(st.scenario, lighting=st.lighting, sensor=st.sensor)
            sample = Sample(st.time, st.pose, tuple(self.body_rotation(st.time).tolist()))
            # velocities the client set, where the sensor integrates over time (blur or a
            # rolling shutter); otherwise the scenario's [motion] (see frame_motion)
            moving = st.motion if st.scenario.motion.get("blur") else None
            st.frame = render_sample(self._gpu, self.scene, sc, sample, st.index,
                                     motion=moving)
            self._remember(st)
        return st.frame

    def _labels(self, st: _State, kind: MsgType) -> bytes:
        """GET_LABELS (rims and instances, JSON) or GET_MASKS (instances, semantic, hazard)."""
        from render.labels import UNKNOWN, Labeller, LabelSpec

        _, frame, truth = self._frame(st)
        if self._labeller is None:
            spec = dataclasses.replace(self.scenario.labels or LabelSpec(), flow=False)
            self._labeller = Labeller(self.scene, spec)
        labels = self._labeller.label(frame, truth.pose, truth.intrinsics, st.lighting)
        if kind == MsgType.GET_LABELS:
            return json_body(labels.as_dict())
        h, w = frame.range.shape
        none8 = np.zeros((h, w), np.uint8)
        parts = [labels.instance_mask if labels.instance_mask is not None
                 else np.zeros((h, w), np.uint16),
                 labels.semantic if labels.semantic is not None else none8,
                 labels.hazard if labels.hazard is not None else none8 + UNKNOWN]
        return ARRAY_HEAD.pack(w, h) + parts[0].astype("<u2").tobytes() \
            + parts[1].tobytes() + parts[2].tobytes()

    def _remember(self, st: _State) -> None:
        """Keep ``st``'s frame; drop the oldest other frames beyond FRAME_CACHE_BYTES."""
        self._cached.pop(id(st), None)
        self._cached[id(st)] = st
        total = sum(_frame_bytes(s.frame) for s in self._cached.values())
        for key in list(self._cached):
            if total <= min(FRAME_CACHE_BYTES, self.frame_cache_bytes) or key == id(st):
                break
            old = self._cached.pop(key)
            total -= _frame_bytes(old.frame)
            old.frame = None

    def body_rotation(self, t: float) -> np.ndarray:
        """R_WB at time ``t`` as the scenario's [scene] spin says (identity for terrain)."""
        s = self.scenario.scene
        if self.scene.kind != "asteroid":
            return np.array([1.0, 0.0, 0.0, 0.0])
        return spin_rotation(t, s.spin_axis, float(s.spin_period), float(s.spin_phase))

    # ------------------------------------------------------------------ surface queries
    def cast(self, origin, direction, t: float, lighting: Lighting) -> tuple:
        """Return (range, point x, y, z, normal x, y, z) where a ray first meets the surface.

        NaN when it meets nothing. Rendered as one pixel at the finest level of detail.
        """
        o = np.asarray(origin, dtype=np.float64)
        d = np.asarray(_scaled(direction, "ray direction"))
        n = float(np.linalg.norm(d))
        pose = look_at(o, o + d / n * max(1.0, float(np.linalg.norm(o))))
        axis = pose.rotation[:, 2]
        self.scene.set_body_rotation(self.body_rotation(t))  # a terrain ignores it
        view = View(pose, Intrinsics(1, 1, RAY_FOCAL, RAY_FOCAL, 0.0, 0.0), t)
        # range and normals only: no shadows, no scattered light
        options = dataclasses.replace(self.scenario.options, shadows=False, scattering=False)
        frame = self._gpu.render(self.scene, view, lighting, options)
        r = float(frame.range[0, 0])
        if not math.isfinite(r):
            return (math.nan,) * 7
        p = np.asarray(pose.position) + r * axis
        return (r, *p.tolist(), *frame.normals[0, 0].astype(np.float64).tolist())

    def height_and_normal(self, x: float, y: float) -> tuple:
        """(height, normal x, y, z) of the terrain at map (x, y) (see docs/protocol.md)."""
        scene = self.scene
        if not isinstance(scene, TerrainScene):
            raise ProtocolError(ErrorCode.UNSUPPORTED,
                                "HEIGHT_AT needs a terrain scene; use RAY on an asteroid")
        h = scene.height_at(x, y)
        step = next(t.resolution for t in reversed(scene.stack.tiles)
                    if t.bounds[0] <= x <= t.bounds[2] and t.bounds[1] <= y <= t.bounds[3])

        def slope(dx, dy):
            pts = []
            for s in (1.0, -1.0):
                try:
                    pts.append((s, scene.height_at(x + s * dx, y + s * dy)))
                except InvalidParameterError:
                    pts.append((0.0, h))  # at the edge: one-sided difference
            (s0, h0), (s1, h1) = pts
            return (h0 - h1) / ((s0 - s1) * step) if s0 != s1 else 0.0

        gx, gy = slope(step, 0.0), slope(0.0, step)
        nrm = np.array([-gx, -gy, 1.0])
        nrm /= np.linalg.norm(nrm)
        return (h, *nrm.tolist())


def _frame_bytes(frame) -> int:
    if frame is None:
        return 0
    image, fr, _ = frame
    return image.nbytes + fr.radiance.nbytes + fr.range.nbytes + fr.normals.nbytes


def json_depth(obj) -> int:
    """Return the nesting depth of parsed JSON (a scalar: 0), counted without recursion."""
    deepest, todo = 0, [(obj, 0)]
    while todo:
        item, d = todo.pop()
        if isinstance(item, (list, dict)):
            deepest = max(deepest, d + 1)
            if deepest > MAX_JSON_DEPTH:
                break
            todo.extend((v, d + 1) for v in (item.values() if isinstance(item, dict) else item))
    return deepest


def _json_object(body: bytes, what: str) -> dict:
    """Parse a request's JSON object body, nested at most MAX_JSON_DEPTH deep."""
    too_deep = False
    settings = None
    try:
        settings = json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(ErrorCode.MALFORMED,
                            f"{what} body is not UTF-8 JSON: {exc}") from None
    except RecursionError:  # nested too deeply for the parser itself
        too_deep = True
    if too_deep or json_depth(settings) > MAX_JSON_DEPTH:
        raise ProtocolError(ErrorCode.MALFORMED, f"{what} body is nested deeper than "
                            f"{MAX_JSON_DEPTH} levels")
    if not isinstance(settings, dict):
        raise ProtocolError(ErrorCode.MALFORMED, f"{what} body must be a JSON object")
    return settings


def _shading(st: _State) -> dict:
    """Give the connection's shading switches (SET_SHADING's keys)."""
    return {k: bool(getattr(st.scenario.options, k)) for k in SHADING_KEYS}


def _finite(what: str, values) -> None:
    if not all(math.isfinite(v) for v in values):
        raise ProtocolError(ErrorCode.INVALID_VALUE, f"{what} has a non-finite number: "
                            f"{[float(v) for v in values]}")


def _scaled(values, what: str) -> tuple:
    """Return a direction whose norm can neither overflow nor vanish.

    It is divided by its largest magnitude when that lies outside [1e-100, 1e100] (kept as sent
    otherwise, so a pose sent back from a truth file gives the same bytes); a zero vector is
    refused.
    """
    v = np.asarray(values, dtype=np.float64)
    m = float(np.max(np.abs(v)))
    if not m > 0:
        raise ProtocolError(ErrorCode.INVALID_VALUE, f"{what} must be non-zero; got "
                            f"{v.tolist()}")
    if not 1e-100 <= m <= 1e100:
        v = v / m
    return tuple(v.tolist())
