"""The render server's wire protocol, version 1 (specified in ``docs/protocol.md``).

Every message is a 16-byte little-endian header (magic ``CSRV``, version, type, request id,
body length) and a body. This module holds the constants, the header codec, the fixed body
layouts of every request and reply, and a reader that never trusts a length field. The server
(:mod:`render.server`) and the client (:mod:`render.client`) both use it, so they cannot
disagree; the tests also talk to the server with raw sockets written from the page alone.

>>> h = pack_header(MsgType.PING, 7, 0)
>>> len(h), unpack_header(h)
(16, (1, 3, 7, 0))
"""

from __future__ import annotations

import json
import math
import socket
import struct
import time
from enum import IntEnum

from render.errors import ProtocolError

__all__ = ["ERROR", "HEADER", "MAGIC", "MAX_REPLY_BODY", "MAX_REQUEST_BODY", "MINOR_VERSION",
           "PROTOCOL_MINOR",
           "REPLY", "SHADING_KEYS", "VERSION", "ErrorCode", "MsgType", "error_body",
           "pack_header", "read_exact", "read_message", "unpack_header"]

MAGIC = b"CSRV"
VERSION = 1
#: Minor version (INFO's ``protocol_minor``): additions a version-1 client may use or ignore.
#: 1: SET_LIGHT (the sun on a date); 2: GET_LABELS and GET_MASKS (image-space labels);
#: 3: GET_RADAR, GET_LIDAR and GET_EVENTS (instruments); 4: GET_BODY_IDS (binary scenes);
#: 5: SET_SHADING (the connection's shading switches).
PROTOCOL_MINOR = 5
#: The same (the name the label and instrument requests' code uses).
MINOR_VERSION = PROTOCOL_MINOR
#: Header: magic, version (u16), type (u16), request id (u32), body length (u32).
HEADER = struct.Struct("<4sHHII")
#: Largest request body the server reads (bytes); checked before reading the body.
MAX_REQUEST_BODY = 65536
#: Largest reply body the Python client accepts (bytes).
MAX_REPLY_BODY = 1 << 30
#: Reply type bit: the reply to type T is T | REPLY.
REPLY = 0x8000
#: Error reply type.
ERROR = 0xFFFF
#: Longest error reason sent (bytes of UTF-8).
MAX_REASON = 512
#: Longest token (bytes of UTF-8).
MAX_TOKEN = 256
#: Default TCP port (PANGU's).
DEFAULT_PORT = 10363


class MsgType(IntEnum):
    """Request types (see docs/protocol.md)."""

    HELLO = 0x0001
    INFO = 0x0002
    PING = 0x0003
    SET_POSE = 0x0010
    SET_SUN = 0x0011
    SET_SENSOR = 0x0012
    SET_MOTION = 0x0013
    SET_LIGHT = 0x0014
    GET_IMAGE = 0x0020
    GET_RANGE = 0x0021
    GET_NORMALS = 0x0022
    GET_TRUTH = 0x0023
    GET_LABELS = 0x0024
    GET_MASKS = 0x0025
    GET_RADAR = 0x0026
    GET_LIDAR = 0x0027
    GET_EVENTS = 0x0028
    GET_BODY_IDS = 0x0029
    SET_SHADING = 0x002A
    HEIGHT_AT = 0x0030
    PIXEL_RAY = 0x0031
    RAY = 0x0032


class ErrorCode(IntEnum):
    """Codes of the error reply (see docs/protocol.md)."""

    BAD_MAGIC = 1
    BAD_VERSION = 2
    TOO_LARGE = 3
    UNKNOWN_TYPE = 4
    MALFORMED = 5
    INVALID_VALUE = 6
    INSIDE_SURFACE = 7
    NO_POSE = 8
    UNAUTHORIZED = 9
    UNSUPPORTED = 10
    BUSY = 11
    SHUTTING_DOWN = 12
    TIMEOUT = 13
    INTERNAL = 14


#: Codes after which the server closes the connection.
CLOSING = frozenset({ErrorCode.BAD_MAGIC, ErrorCode.BAD_VERSION, ErrorCode.TOO_LARGE,
                     ErrorCode.UNAUTHORIZED, ErrorCode.BUSY, ErrorCode.SHUTTING_DOWN,
                     ErrorCode.TIMEOUT})

# Fixed bodies (little-endian).
POSE = struct.Struct("<3d4ddII")      # position, attitude (w, x, y, z), time, frame, flags
SUN = struct.Struct("<3d")            # direction towards the sun
MOTION = struct.Struct("<9d")         # velocity, angular velocity, body angular velocity
BITS = struct.Struct("<B")            # 0 (the sensor's) or 1 to 16
XY = struct.Struct("<2d")             # map x, y  /  pixel u, v
RAY = struct.Struct("<6d")            # origin, direction
HEIGHT_REPLY = struct.Struct("<4d")   # height, normal
RAY_REPLY = struct.Struct("<7d")      # range, point, normal
IMAGE_HEAD = struct.Struct("<IIHH")   # width, height, bits, 0
ARRAY_HEAD = struct.Struct("<II")     # width, height
ERROR_HEAD = struct.Struct("<HH")     # code, 0
#: GET_RADAR reply head: range bins, Doppler bins, then range, mean radial velocity, boresight
#: velocity, power outside the bins, first range edge, range bin, lowest and highest velocity.
RADAR_HEAD = struct.Struct("<II8d")
#: GET_EVENTS request: duration (s), most events wanted (0: as many as fit a reply).
EVENTS_REQUEST = struct.Struct("<dI")
#: GET_EVENTS reply head: count, width, height, events dropped by max_events, start time (s).
EVENTS_HEAD = struct.Struct("<IIIId")

#: Body length of each fixed-size request (None: variable).
REQUEST_SIZES = {MsgType.HELLO: None, MsgType.INFO: 0, MsgType.PING: 0,
                 MsgType.SET_POSE: POSE.size, MsgType.SET_SUN: SUN.size,
                 MsgType.SET_SENSOR: None, MsgType.SET_MOTION: MOTION.size,
                 MsgType.SET_LIGHT: None,
                 MsgType.GET_IMAGE: BITS.size, MsgType.GET_RANGE: 0,
                 MsgType.GET_NORMALS: 0, MsgType.GET_TRUTH: 0, MsgType.GET_LABELS: 0,
                 MsgType.GET_MASKS: 0, MsgType.GET_BODY_IDS: 0, MsgType.HEIGHT_AT: XY.size,
                 MsgType.PIXEL_RAY: XY.size, MsgType.RAY: RAY.size,
                 MsgType.GET_RADAR: None, MsgType.GET_LIDAR: None,
                 MsgType.GET_EVENTS: EVENTS_REQUEST.size, MsgType.SET_SHADING: None}
#: The switches of SET_SHADING (the ``[render]`` keys of the same names).
SHADING_KEYS = ("shadows", "soft_shadows", "scattering", "earthshine")


def pack_header(msg_type: int, request_id: int, length: int) -> bytes:
    """Return the 16-byte header of a message."""
    return HEADER.pack(MAGIC, VERSION, int(msg_type), int(request_id) & 0xFFFFFFFF, int(length))


def unpack_header(data: bytes) -> tuple[int, int, int, int]:
    """(version, type, request id, length) of a header; a wrong magic is a ProtocolError."""
    magic, version, msg_type, request_id, length = HEADER.unpack(data)
    if magic != MAGIC:
        raise ProtocolError(ErrorCode.BAD_MAGIC, f"bad magic {magic!r}; expected {MAGIC!r}")
    return version, msg_type, request_id, length


def error_body(code: int, reason: str) -> bytes:
    """Body of an error reply: the code and one line of reason, cut to MAX_REASON bytes."""
    line = " ".join(str(reason).split()) or "error"
    text = line.encode("utf-8")[:MAX_REASON].decode("utf-8", "ignore").encode("utf-8")
    return ERROR_HEAD.pack(int(code), 0) + text


def parse_error(body: bytes) -> tuple[int, str]:
    """(code, reason) of an error reply body."""
    if len(body) < ERROR_HEAD.size:
        raise ProtocolError(ErrorCode.MALFORMED, "error reply shorter than 4 bytes")
    code, _ = ERROR_HEAD.unpack_from(body)
    return code, body[ERROR_HEAD.size:].decode("utf-8", "replace")


def read_exact(sock: socket.socket, n: int, deadline: float | None = None) -> bytes:
    """Exactly ``n`` bytes from ``sock``; EOF before that raises ConnectionError.

    ``deadline`` (a ``time.monotonic()`` value) bounds the whole read, so a peer trickling a
    byte at a time cannot stretch it (TimeoutError); without one, the socket's own timeout
    applies to each recv.
    """
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"message incomplete after the timeout ({got} of {n} bytes)")
            sock.settimeout(left)
        k = sock.recv_into(view[got:], n - got)
        if k == 0:
            raise ConnectionError(f"connection closed after {got} of {n} bytes")
        got += k
    return bytes(buf)


def read_message(sock: socket.socket, max_body: int, *, first_timeout: float | None = None,
                 timeout: float | None = None) -> tuple[int, int, int, bytes]:
    """Read one message: (version, type, request id, body).

    ``first_timeout`` bounds the wait for the header's first byte, ``timeout`` the rest of the
    message from then on (header and body together). The length is checked against
    ``max_body`` before the body is read. Raises :class:`~render.errors.ProtocolError` for a
    bad magic or an oversized body, ConnectionError at EOF and TimeoutError when a read times
    out.
    """
    sock.settimeout(first_timeout)
    first = sock.recv(1)
    if not first:
        raise ConnectionError("connection closed")
    deadline = None if timeout is None else time.monotonic() + timeout
    head = first + read_exact(sock, HEADER.size - 1, deadline)
    version, msg_type, request_id, length = unpack_header(head)
    if version != VERSION:
        raise ProtocolError(ErrorCode.BAD_VERSION,
                            f"protocol version {version} is not supported; this side speaks "
                            f"{VERSION}")
    if length > max_body:
        raise ProtocolError(ErrorCode.TOO_LARGE,
                            f"message body of {length} bytes exceeds the maximum {max_body}")
    body = read_exact(sock, length, deadline) if length else b""
    return version, msg_type, request_id, body


def json_body(obj) -> bytes:
    """UTF-8 JSON of ``obj`` (NaN written as null, so any JSON parser reads it)."""
    return json.dumps(_no_nan(obj), sort_keys=True).encode("utf-8")


def _no_nan(obj):
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _no_nan(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_no_nan(v) for v in obj]
    return obj
