"""A Python client of the render server (protocol in ``docs/protocol.md``).

One method per request; every error reply raises :class:`~render.errors.ServerError` with the
server's code and reason, and the connection stays usable unless the code closes it. A reply
that breaks the protocol (short, garbled, of the wrong size) raises
:class:`~render.errors.ProtocolError` with code ``MALFORMED``::

    from render.client import Client

    with Client("127.0.0.1", 10363) as c:
        c.set_pose((1000.0, 2000.0, 2000.0), (0.0, 1.0, 0.0, 0.0), time=0.0, frame=0)
        image = c.get_image()            # (h, w) uint8 or uint16
        rng = c.get_range()              # (h, w) float32 metres, NaN = no return
        hit = c.ray((1000.0, 2000.0, 2000.0), (0.0, 0.0, -1.0))   # a laser altimeter
"""

from __future__ import annotations

import json
import math
import socket
import struct
from dataclasses import dataclass

import numpy as np

from render.errors import ProtocolError, ServerError
from render.protocol import (
    ARRAY_HEAD,
    BITS,
    DEFAULT_PORT,
    ERROR,
    EVENTS_HEAD,
    EVENTS_REQUEST,
    HEIGHT_REPLY,
    IMAGE_HEAD,
    MAX_REPLY_BODY,
    MOTION,
    POSE,
    RADAR_HEAD,
    RAY,
    RAY_REPLY,
    REPLY,
    SUN,
    XY,
    ErrorCode,
    MsgType,
    pack_header,
    parse_error,
    read_message,
)
from terrain.core.errors import InvalidParameterError

__all__ = ["Client", "RayHit"]


@dataclass(frozen=True)
class RayHit:
    """Where a ray first meets the surface.

    ``range`` (m), ``point`` (3,) and unit ``normal`` (3,) in the world frame; all NaN when it
    meets nothing.
    """

    range: float
    point: np.ndarray
    normal: np.ndarray

    @property
    def hit(self) -> bool:
        """Whether the ray met the surface."""
        return bool(np.isfinite(self.range))


class Client:
    """A connection to ``craterscape render serve`` (a context manager).

    Parameters
    ----------
    host, port : where the server listens (default 127.0.0.1:10363)
    token : str, optional
        The server's shared token; sent in HELLO on connecting.
    timeout : float, seconds
        Longest wait for a reply (rendering included).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 token: str | None = None, *, timeout: float = 120.0):
        self.timeout = float(timeout)
        self._sock = socket.create_connection((host, int(port)), timeout=self.timeout)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._id = 0
        if token is not None:
            self.hello(token)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection."""
        self._sock.close()

    # ------------------------------------------------------------------ transport
    def request(self, msg_type: int, body: bytes = b"") -> bytes:
        """Send one request and return its reply body (raw access to the protocol)."""
        self._id = (self._id + 1) & 0xFFFFFFFF
        self._sock.settimeout(self.timeout)
        self._sock.sendall(pack_header(msg_type, self._id, len(body)) + body)
        _, rtype, rid, rbody = read_message(self._sock, MAX_REPLY_BODY,
                                            first_timeout=self.timeout, timeout=self.timeout)
        if rtype == ERROR:
            raise ServerError(*parse_error(rbody))
        if rtype != (msg_type | REPLY) or rid != self._id:
            raise ProtocolError(ErrorCode.MALFORMED,
                                f"reply type 0x{rtype:04x} id {rid} does not answer request "
                                f"0x{msg_type:04x} id {self._id}")
        return rbody

    # ------------------------------------------------------------------ requests
    def hello(self, token: str = "") -> None:
        """Authenticate with the server's token."""
        self.request(MsgType.HELLO, str(token).encode("utf-8"))

    def ping(self) -> None:
        """Check that the server answers (raises if it does not)."""
        self.request(MsgType.PING)

    def info(self) -> dict:
        """Return the scene, the site, its bounds, the sun and the sensor (docs/protocol.md)."""
        return _json(self.request(MsgType.INFO), "INFO")

    def set_pose(self, position, attitude, time: float = 0.0, frame: int = 0) -> None:
        """Place the camera.

        Parameters
        ----------
        position : (3,) float, metres
            Camera centre in the world frame.
        attitude : (4,) float
            Quaternion [w, x, y, z] of R_WC (camera to world; normalised by the server).
        time : float, seconds
            Scene time (turns an asteroid as its scenario's spin says).
        frame : int
            Frame index that keys the sensor noise (same index, same noise).
        """
        p = [float(v) for v in position]
        q = [float(v) for v in attitude]
        if len(p) != 3 or len(q) != 4:
            raise ValueError(f"position must have 3 numbers and attitude 4; got {len(p)}, "
                             f"{len(q)}")
        self.request(MsgType.SET_POSE, POSE.pack(*p, *q, float(time), int(frame), 0))

    def set_sun(self, direction) -> None:
        """Direction towards the sun (world frame)."""
        self.request(MsgType.SET_SUN, SUN.pack(*(float(v) for v in direction)))

    def set_motion(self, velocity, angular_velocity=(0.0, 0.0, 0.0),
                   body_angular_velocity=(0.0, 0.0, 0.0)) -> None:
        """Velocities held during the exposure (motion blur, rolling shutter).

        Parameters
        ----------
        velocity : (3,) float, m/s
            Camera velocity, world frame.
        angular_velocity : (3,) float, rad/s
            Camera angular velocity, world frame.
        body_angular_velocity : (3,) float, rad/s
            The asteroid's spin, world frame.
        """
        values = [float(x) for v in (velocity, angular_velocity, body_angular_velocity)
                  for x in v]
        if len(values) != 9:
            raise ValueError("velocity, angular_velocity and body_angular_velocity need 3 "
                             "numbers each")
        self.request(MsgType.SET_MOTION, MOTION.pack(*values))

    def set_sensor(self, **settings) -> dict:
        """Change sensor settings and return the settings in force.

        Any ``[sensor]`` key, ``width``, ``height`` and ``noise`` may be changed.
        """
        return _json(self.request(MsgType.SET_SENSOR, json.dumps(settings).encode("utf-8")),
                     "SET_SENSOR")

    def set_light(self, **settings) -> dict:
        """Set the sun as a scenario's ``[sun]`` keys (e.g. ``utc``, ``longitude``, ``latitude``).

        Returns the sun in force at the current pose's time: ``sun``, ``distance_au``, ``time``
        and, for a dated sun, the sky (:meth:`render.ephemeris.Sky.as_dict`) and ``utc``.
        """
        return _json(self.request(MsgType.SET_LIGHT, json.dumps(settings).encode("utf-8")),
                     "SET_LIGHT")

    def set_shading(self, **switches: bool) -> dict:
        """Switch shading effects for this connection (SET_SHADING; other clients keep theirs).

        Parameters
        ----------
        **switches : bool
            Any of ``shadows``, ``soft_shadows``, ``scattering`` and ``earthshine`` (the
            scenario's ``[render]`` keys); none: only ask what is in force.

        Returns
        -------
        dict
            Every switch in force on this connection.
        """
        return _json(self.request(MsgType.SET_SHADING, json.dumps(switches).encode("utf-8")),
                     "SET_SHADING")

    def get_image(self, bits: int = 0) -> np.ndarray:
        """Return the camera image of the current pose.

        Parameters
        ----------
        bits : int
            Bit depth 1 to 16; 0 keeps the sensor's.

        Returns
        -------
        image : (height, width) uint8 (bits <= 8) or uint16, DN
            Top row first; equals ``craterscape render frame`` at the same pose and index.

        Raises
        ------
        InvalidParameterError
            ``bits`` is not an integer from 0 to 16 (8.7 is not sent as 8), before any request.
        """
        if isinstance(bits, bool) or not isinstance(bits, (int, np.integer)) \
                or not 0 <= bits <= 16:
            raise InvalidParameterError(
                f"bits must be an integer, 0 (the sensor's) or 1 to 16; got {bits!r}")
        body = self.request(MsgType.GET_IMAGE, BITS.pack(int(bits)))
        w, h, b, _ = _unpack(IMAGE_HEAD, body, "GET_IMAGE", exact=False)
        if not 1 <= b <= 16:
            raise ProtocolError(ErrorCode.MALFORMED,
                                f"GET_IMAGE reply has bit depth {b}; expected 1 to 16")
        dtype = np.dtype("<u1") if b <= 8 else np.dtype("<u2")
        return _array(body[IMAGE_HEAD.size:], dtype, (h, w)).astype(
            np.uint8 if b <= 8 else np.uint16)

    def get_range(self) -> np.ndarray:
        """Return the LIDAR range image of the current pose.

        Returns
        -------
        range : (height, width) float32, metres
            Distance from the camera centre along each pixel's ray; NaN where nothing is hit.
        """
        body = self.request(MsgType.GET_RANGE)
        w, h = _unpack(ARRAY_HEAD, body, "GET_RANGE", exact=False)
        return _array(body[ARRAY_HEAD.size:], np.dtype("<f4"), (h, w)).astype(np.float32)

    def get_normals(self) -> np.ndarray:
        """Return the surface normals seen from the current pose.

        Returns
        -------
        normals : (height, width, 3) float32, unit vectors
            World frame; NaN where nothing is hit.
        """
        body = self.request(MsgType.GET_NORMALS)
        w, h = _unpack(ARRAY_HEAD, body, "GET_NORMALS", exact=False)
        return _array(body[ARRAY_HEAD.size:], np.dtype("<f4"), (h, w, 3)).astype(np.float32)

    def get_radar(self, **beam) -> dict:
        """Measure with a radar beam from the current pose and motion (GET_RADAR).

        Parameters
        ----------
        **beam
            ``[radar]`` keys (render.radar.RadarBeam) over the scenario's first beam.

        Returns
        -------
        dict
            ``range`` (m, NaN: nothing in the half-power beam), ``velocity`` (mean radial,
            m/s), ``boresight_velocity``, ``power_outside``, ``histogram`` ((range bins,
            Doppler bins) float32, sums to 1 - power_outside), ``range_edges`` and
            ``velocity_edges``.
        """
        body = self.request(MsgType.GET_RADAR, json.dumps(beam).encode("utf-8") if beam else b"")
        nr, nd, rng, vel, vb, out, r0, dr, v0, v1 = _unpack(RADAR_HEAD, body, "GET_RADAR",
                                                              exact=False)
        hist = _array(body[RADAR_HEAD.size:], np.dtype("<f4"), (nr, nd)).astype(np.float32)
        return dict(range=rng, velocity=vel, boresight_velocity=vb, power_outside=out,
                    histogram=hist, range_edges=r0 + dr * np.arange(nr + 1),
                    velocity_edges=np.linspace(v0, v1, nd + 1))

    def get_lidar(self, **lidar) -> dict:
        """Flash the LIDAR from the current pose (GET_LIDAR).

        Parameters
        ----------
        **lidar
            ``[lidar]`` keys (render.lidar.Lidar) over the scenario's table.

        Returns
        -------
        dict
            ``range``, ``first``, ``last``, ``strongest`` ((height, width) float32 metres,
            NaN: no return), ``power`` (W) and ``returns`` (uint8).
        """
        body = self.request(MsgType.GET_LIDAR, json.dumps(lidar).encode("utf-8")
                            if lidar else b"")
        w, h = _unpack(ARRAY_HEAD, body, "GET_LIDAR", exact=False)
        n = w * h
        data = body[ARRAY_HEAD.size:]
        if len(data) != 21 * n:
            raise ProtocolError(ErrorCode.MALFORMED, f"GET_LIDAR reply holds {len(data)} bytes;"
                                f" expected {21 * n}")
        out: dict[str, np.ndarray] = {
            name: _array(data[4 * n * i:4 * n * (i + 1)], np.dtype("<f4"), (h, w))
               .astype(np.float32)
               for i, name in enumerate(("range", "first", "last", "strongest", "power"))}
        out["returns"] = np.frombuffer(data[20 * n:], np.uint8).reshape(h, w).copy()
        return out

    def get_events(self, duration: float, max_events: int = 0) -> dict:
        """Run the event camera from the current pose over ``duration`` s (GET_EVENTS).

        Returns
        -------
        dict
            ``x``, ``y`` (uint16), ``t`` (int64 microseconds after ``start``), ``p`` (int8),
            ``width``, ``height``, ``start`` (s) and ``dropped`` (events beyond max_events).
        """
        body = self.request(MsgType.GET_EVENTS, EVENTS_REQUEST.pack(float(duration),
                                                                     int(max_events)))
        n, w, h, dropped, start = _unpack(EVENTS_HEAD, body, "GET_EVENTS", exact=False)
        data = body[EVENTS_HEAD.size:]
        if len(data) != 13 * n:
            raise ProtocolError(ErrorCode.MALFORMED, f"GET_EVENTS reply holds {len(data)} "
                                f"bytes; expected {13 * n}")
        return dict(x=np.frombuffer(data[:2 * n], "<u2").astype(np.uint16),
                    y=np.frombuffer(data[2 * n:4 * n], "<u2").astype(np.uint16),
                    t=np.frombuffer(data[4 * n:12 * n], "<i8").astype(np.int64),
                    p=np.frombuffer(data[12 * n:], "i1").astype(np.int8),
                    width=w, height=h, start=start, dropped=dropped)
    def get_body_ids(self) -> np.ndarray:
        """Return which body each pixel of the current pose shows (binary scenes).

        Returns
        -------
        body_ids : (height, width) uint8
            0 sky, 1 primary, 2 secondary.
        """
        body = self.request(MsgType.GET_BODY_IDS)
        w, h = _unpack(ARRAY_HEAD, body, "GET_BODY_IDS", exact=False)
        return _array(body[ARRAY_HEAD.size:], np.dtype("<u1"), (h, w)).astype(np.uint8)

    def get_truth(self) -> dict:
        """Return the frame's ground truth (a run's truth.json entry, without file names)."""
        return _json(self.request(MsgType.GET_TRUTH), "GET_TRUTH")

    def get_labels(self) -> dict:
        """Return the frame's crater rims and instance table (``GET_LABELS``, docs/labels.md)."""
        return _json(self.request(MsgType.GET_LABELS), "GET_LABELS")

    def get_masks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the frame's instance, semantic and hazard masks (``GET_MASKS``).

        Returns
        -------
        instances : (height, width) uint16
            Instance numbers (0: none), as :meth:`get_labels` lists them.
        semantic : (height, width) uint8
            0 sky, 1 terrain, 2 rock, 3 shadowed.
        hazard : (height, width) uint8
            0 unsafe, 1 safe, 255 unknown (or no lander in the scenario's ``[labels]``).
        """
        body = self.request(MsgType.GET_MASKS)
        w, h = _unpack(ARRAY_HEAD, body, "GET_MASKS", exact=False)
        n, o = w * h, ARRAY_HEAD.size
        inst = _array(body[o:o + 2 * n], np.dtype("<u2"), (h, w)).astype(np.uint16)
        sem = _array(body[o + 2 * n:o + 3 * n], np.dtype("u1"), (h, w))
        haz = _array(body[o + 3 * n:o + 4 * n], np.dtype("u1"), (h, w))
        return inst, sem, haz

    def height_at(self, x: float, y: float) -> tuple[float, np.ndarray]:
        """Terrain height and normal at a map point (terrain scenes).

        Parameters
        ----------
        x, y : float, metres
            Map coordinates.

        Returns
        -------
        height : float, metres
            World-frame height as rendered (curvature applied).
        normal : (3,) float64
            Unit surface normal, world frame.
        """
        h, *n = _unpack(HEIGHT_REPLY, self.request(MsgType.HEIGHT_AT, XY.pack(x, y)),
                        "HEIGHT_AT")
        return h, np.array(n)

    def pixel_ray(self, u: float, v: float) -> RayHit:
        """Return the 3-D point seen through pixel (u, v) of the current pose."""
        return _hit(self.request(MsgType.PIXEL_RAY, XY.pack(u, v)), "PIXEL_RAY")

    def ray(self, origin, direction) -> RayHit:
        """Where one ray first meets the surface (a laser altimeter).

        Parameters
        ----------
        origin : (3,) float, metres
            World frame.
        direction : (3,) float
            Any non-zero length.

        Returns
        -------
        RayHit
            Range (m), point and normal; NaN when the ray meets nothing.
        """
        values = [float(v) for v in origin] + [float(v) for v in direction]
        return _hit(self.request(MsgType.RAY, RAY.pack(*values)), "RAY")


def _unpack(layout: struct.Struct, body: bytes, what: str, *, exact: bool = True) -> tuple:
    """Return the fields of a fixed reply layout (a body of the wrong size: ProtocolError)."""
    if len(body) != layout.size if exact else len(body) < layout.size:
        raise ProtocolError(ErrorCode.MALFORMED,
                            f"{what} reply is {len(body)} bytes; expected "
                            f"{'' if exact else 'at least '}{layout.size}")
    return layout.unpack_from(body)


def _json(body: bytes, what: str) -> dict:
    """Return a JSON object reply (anything else: ProtocolError)."""
    try:
        value = json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        value = None
    if not isinstance(value, dict):
        raise ProtocolError(ErrorCode.MALFORMED, f"{what} reply is not a UTF-8 JSON object")
    return value


def _array(data: bytes, dtype, shape) -> np.ndarray:
    n = math.prod(int(v) for v in shape) * dtype.itemsize
    if len(data) != n:
        raise ProtocolError(ErrorCode.MALFORMED,
                            f"reply holds {len(data)} bytes of pixels; expected {n}")
    return np.frombuffer(data, dtype=dtype).reshape(shape)


def _hit(body: bytes, what: str) -> RayHit:
    r, *rest = _unpack(RAY_REPLY, body, what)
    return RayHit(r, np.array(rest[:3]), np.array(rest[3:]))
