"""The server's radar, LIDAR and event-camera requests (GET_RADAR, GET_LIDAR, GET_EVENTS).

Each measures from the connection's pose and time (SET_POSE) with the velocities it set
(SET_MOTION; none: still); the layouts are in ``docs/protocol.md``. The radar and LIDAR take
their settings from the request's JSON object, over the scenario's ``[radar]`` (first beam)
and ``[lidar]`` tables; the event camera is the scenario's ``[events]`` table (its defaults
without one).
"""

from __future__ import annotations

import json
import math
from dataclasses import fields
from typing import TYPE_CHECKING, Any

import numpy as np

from render.errors import ProtocolError
from render.events import EventCamera, simulate
from render.instruments import renderer_look
from render.lidar import Lidar, flash, supersampled
from render.motion import Motion
from render.protocol import (
    ARRAY_HEAD,
    EVENTS_HEAD,
    EVENTS_REQUEST,
    MAX_REPLY_BODY,
    RADAR_HEAD,
    ErrorCode,
    MsgType,
)
from render.radar import RadarBeam, measure
from render.renderer import View

if TYPE_CHECKING:
    from render.server import RenderServer

__all__ = ["BYTES_PER_EVENT", "MAX_EVENT_SECONDS", "SENSOR_REQUESTS", "answer"]

#: Requests this module answers.
SENSOR_REQUESTS = frozenset({MsgType.GET_RADAR, MsgType.GET_LIDAR, MsgType.GET_EVENTS})
#: Longest stretch of time one GET_EVENTS integrates, seconds.
MAX_EVENT_SECONDS = 10.0
#: Reply bytes per event: x u16, y u16, t i64, p i8.
BYTES_PER_EVENT = 13
#: Largest GET_EVENTS reply, bytes (about five million events).
MAX_EVENTS_REPLY = 64 << 20
#: Largest side of a frame a radar or LIDAR request may render (as SET_SENSOR's).
MAX_SENSOR_SIDE = 8192


def _settings(body: bytes, what: str, base: dict) -> dict:
    from render.server import MAX_JSON_DEPTH, json_depth

    if not body:
        return dict(base)
    try:
        data = json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(ErrorCode.MALFORMED, f"{what} body is not UTF-8 JSON: {exc}") \
            from None
    except RecursionError:
        data = None
    if data is None or json_depth(data) > MAX_JSON_DEPTH:
        raise ProtocolError(ErrorCode.MALFORMED, f"{what} body is nested too deeply or null")
    if not isinstance(data, dict):
        raise ProtocolError(ErrorCode.MALFORMED, f"{what} body must be a JSON object")
    return dict(base, **data)


def _base(record: Any) -> dict:
    if record is None:
        return {}
    return {f.name: getattr(record, f.name) for f in fields(record)}


def answer(server: RenderServer, st: Any, kind: MsgType, body: bytes) -> bytes:
    """Answer one sensor request for the connection state ``st``."""
    if st.pose is None:
        raise ProtocolError(ErrorCode.NO_POSE, "set a pose (SET_POSE) first")
    motion = st.motion or Motion()
    scene = server.scene
    scene.set_body_rotation(server.body_rotation(st.time))
    spin = tuple(motion.body_angular_velocity) if scene.kind == "asteroid" else (0.0, 0.0, 0.0)
    if kind == MsgType.GET_RADAR:
        sc = st.scenario
        beam = RadarBeam.from_mapping(_settings(body, "GET_RADAR",
                                                _base(sc.radar[0] if sc.radar else None)))
        if beam.range_bins * beam.doppler_bins * 4 + RADAR_HEAD.size > MAX_REPLY_BODY:
            raise ProtocolError(ErrorCode.INVALID_VALUE, "range_bins x doppler_bins too large "
                                "for one reply")
        look = renderer_look(server._gpu, scene, st.lighting, sc.options, st.time)
        ret = measure(beam, look, st.pose, motion.velocity, body_angular_velocity=spin)
        head = RADAR_HEAD.pack(beam.range_bins, beam.doppler_bins, ret.range, ret.velocity,
                               ret.boresight_velocity, ret.power_outside,
                               float(ret.range_edges[0]), beam.range_resolution,
                               -beam.max_velocity, beam.max_velocity)
        return head + ret.histogram.astype("<f4").tobytes()
    if kind == MsgType.GET_LIDAR:
        lidar = Lidar.from_mapping(_settings(body, "GET_LIDAR", _base(st.scenario.lidar)))
        if lidar.mode != "flash":
            raise ProtocolError(ErrorCode.UNSUPPORTED, "GET_LIDAR measures a flash; scans run "
                                "in scenarios (render sequence)")
        k, _ = supersampled(lidar)
        if max(k.width, k.height) > MAX_SENSOR_SIDE:
            raise ProtocolError(ErrorCode.INVALID_VALUE, f"width x supersample must stay within"
                                f" {MAX_SENSOR_SIDE} sub-rays a side")
        look = renderer_look(server._gpu, scene, st.lighting, st.scenario.options, st.time,
                             albedo=True)
        img = flash(lidar, look, st.pose, seed=st.scenario.seed, frame=st.index)
        out = [ARRAY_HEAD.pack(lidar.width, lidar.height)]
        out += [getattr(img, n).astype("<f4").tobytes()
                for n in ("range", "first", "last", "strongest", "power")]
        out.append(img.returns.astype("u1").tobytes())
        return b"".join(out)
    duration, most = EVENTS_REQUEST.unpack(body)
    if not (math.isfinite(duration) and 0.0 < duration <= MAX_EVENT_SECONDS):
        raise ProtocolError(ErrorCode.INVALID_VALUE, f"events duration must lie in (0, "
                            f"{MAX_EVENT_SECONDS:g}] s; got {duration}")
    fit = (min(MAX_REPLY_BODY, MAX_EVENTS_REPLY) - EVENTS_HEAD.size) // BYTES_PER_EVENT
    most = min(most or fit, fit)
    camera = st.scenario.events or EventCamera()
    k = st.scenario.intrinsics
    t0, pose = st.time, st.pose
    rot0 = server.body_rotation(t0)

    def render_at(t: float) -> np.ndarray:
        dt = t - t0
        scene.set_body_rotation(motion.body_rotation_at(rot0, dt))
        view = View(motion.pose_at(pose, dt), k, t)
        return server._gpu.render(scene, view, st.lighting, st.scenario.options).radiance

    events, _ = simulate(render_at, t0, t0 + duration, camera, seed=st.scenario.seed)
    n = len(events.t)
    keep = min(n, most)
    t_us = np.round((events.t[:keep] - t0) * 1e6).astype("<i8")
    return b"".join([EVENTS_HEAD.pack(keep, k.width, k.height, n - keep, t0),
                     events.x[:keep].astype("<u2").tobytes(),
                     events.y[:keep].astype("<u2").tobytes(), t_us.tobytes(),
                     events.p[:keep].astype("i1").tobytes()])
