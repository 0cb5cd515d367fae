"""The wire codecs alone (no server): whatever bytes arrive, reading a message ends in a
message, a protocol error with its code, a closed connection or a timeout, never anything else,
and never a read of a body longer than the limit."""

import socket
import struct
import threading

import pytest
from hypothesis import given
from hypothesis import strategies as st

from render.errors import ProtocolError
from render.protocol import (
    HEADER,
    MAX_REQUEST_BODY,
    ErrorCode,
    MsgType,
    error_body,
    pack_header,
    parse_error,
    read_message,
)


def _read(data: bytes, close: bool = True):
    a, b = socket.socketpair()
    try:
        def feed():
            try:
                a.sendall(data)
            except OSError:  # the reader gave up first: fine
                pass
            if close:
                a.shutdown(socket.SHUT_WR)

        t = threading.Thread(target=feed)
        t.start()
        try:
            return read_message(b, MAX_REQUEST_BODY, first_timeout=2.0, timeout=0.5)
        finally:
            b.close()
            t.join()
    finally:
        a.close()


@given(st.binary(max_size=200))
def test_arbitrary_bytes_end_in_a_known_outcome(data):
    try:
        version, mtype, rid, body = _read(data)
    except ProtocolError as exc:
        assert exc.code in (ErrorCode.BAD_MAGIC, ErrorCode.BAD_VERSION, ErrorCode.TOO_LARGE)
    except (ConnectionError, TimeoutError):
        pass
    else:
        assert data[:4] == b"CSRV" and version == 1
        assert len(body) == struct.unpack_from("<I", data, 12)[0] == len(data) - 16


@given(st.integers(0, 0xFFFF), st.integers(0, 2**32 - 1), st.binary(max_size=300))
def test_well_formed_messages_round_trip(mtype, rid, body):
    _, got_type, got_id, got_body = _read(pack_header(mtype, rid, len(body)) + body)
    assert (got_type, got_id, got_body) == (mtype, rid, body)


@given(st.integers(MAX_REQUEST_BODY + 1, 2**32 - 1))
def test_an_oversized_length_is_refused_before_any_body_is_read(length):
    # no body follows and the connection stays open: a reader that waited for it would time out
    with pytest.raises(ProtocolError) as err:
        _read(HEADER.pack(b"CSRV", 1, MsgType.PING, 1, length), close=False)
    assert err.value.code == ErrorCode.TOO_LARGE


@given(st.sampled_from(list(ErrorCode)), st.text(max_size=800))
def test_error_bodies_carry_one_line_of_at_most_512_bytes(code, reason):
    body = error_body(code, reason)
    got_code, text = parse_error(body)
    assert got_code == code and "\n" not in text and len(text.encode("utf-8")) <= 512
    assert text


@pytest.mark.parametrize("bits", [8.7, 12.0, -1, 17, True, "8"])
def test_the_client_refuses_a_bit_depth_the_server_would_not_render_as_asked(bits):
    # GET_IMAGE carries one byte: 8.7 must not go out as 8, nor 300 as a struct error
    from render.client import Client
    from terrain.core.errors import InvalidParameterError

    with socket.create_server(("127.0.0.1", 0)) as server:
        with Client("127.0.0.1", server.getsockname()[1], timeout=1.0) as c:
            with pytest.raises(InvalidParameterError, match=r"^bits must be an integer"):
                c.get_image(bits)


def _answering(bodies):
    """A one-connection server on 127.0.0.1 that answers the n-th request with ``bodies[n]``
    (a reply of the request's own type and id); returns (port, thread)."""
    listener = socket.create_server(("127.0.0.1", 0))

    def serve():
        conn, _ = listener.accept()
        with conn, listener:
            for body in bodies:
                try:
                    _, mtype, rid, _ = read_message(conn, MAX_REQUEST_BODY, first_timeout=5.0,
                                                    timeout=5.0)
                except (ConnectionError, TimeoutError):
                    return
                conn.sendall(pack_header(mtype | 0x8000, rid, len(body)) + body)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    return listener.getsockname()[1], t


GARBLED = [b"", b"\x01", b"{", b"\xff\xfe", b"[1, 2]", b"\x00" * 7, b'"text"', b"{" * 5000]


@pytest.mark.parametrize("call", [
    lambda c: c.info(), lambda c: c.get_truth(), lambda c: c.set_sensor(gain=1.0),
    lambda c: c.get_image(), lambda c: c.get_range(), lambda c: c.get_normals(),
    lambda c: c.height_at(0.0, 0.0), lambda c: c.pixel_ray(1.0, 1.0),
    lambda c: c.ray((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)),
])
def test_the_client_turns_short_or_garbled_replies_into_protocol_errors(call):
    from render.client import Client

    port, t = _answering(GARBLED)
    with Client("127.0.0.1", port, timeout=5.0) as c:
        for _ in GARBLED:
            with pytest.raises(ProtocolError) as err:
                call(c)
            assert err.value.code == ErrorCode.MALFORMED
    t.join(timeout=10)


def test_the_client_refuses_an_image_whose_header_lies_about_its_size():
    from render.client import Client

    lies = [struct.pack("<IIHH", 2**32 - 1, 2**32 - 1, 8, 0) + b"\x00" * 4,
            struct.pack("<IIHH", 2, 2, 0, 0) + b"\x00" * 4,
            struct.pack("<IIHH", 2, 2, 40, 0) + b"\x00" * 8]
    port, t = _answering(lies)
    with Client("127.0.0.1", port, timeout=5.0) as c:
        for _ in lies:
            with pytest.raises(ProtocolError):
                c.get_image()
    t.join(timeout=10)
