"""Camera trajectories: keyframes, descent profiles and asteroid approaches.

A trajectory gives, for each frame, a time (s), a camera :class:`~render.camera.Pose` in the
world frame and the body's rotation (identity for terrain). Three kinds:

Keyframes
    Times, positions and either attitudes (quaternions R_WC) or look-at targets. Positions are
    interpolated by a centripetal-free uniform Catmull-Rom spline (smooth, passing through every
    keyframe; linear between two keyframes); attitudes by slerp between keyframes, or by
    looking at the interpolated target.
Descent
    From ``start_altitude`` to ``end_altitude`` above the site, with the altitude falling
    geometrically (each frame the same fraction lower, so image scale changes evenly, as in a
    real powered descent's last kilometres), the horizontal offset from the site shrinking in
    proportion, and the camera looking at the site (or straight down).
Approach
    Towards an asteroid's centre from ``start_distance`` to ``end_distance`` along a fixed
    direction (distance falling geometrically), looking at the centre, while the body spins
    about its axis at a constant rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from render.camera import Pose, look_at, slerp
from terrain.core.errors import InvalidParameterError

__all__ = ["Sample", "approach", "axis_angle", "descent", "keyframes", "spin_rotation"]


@dataclass(frozen=True)
class Sample:
    """One frame of a trajectory."""

    time: float
    pose: Pose
    body_rotation: tuple = (1.0, 0.0, 0.0, 0.0)


def axis_angle(axis, angle_rad: float) -> np.ndarray:
    """Quaternion [w, x, y, z] of a rotation by ``angle_rad`` about ``axis``."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0 or not np.isfinite(n):
        raise InvalidParameterError(f"rotation axis must be a non-zero vector; got {axis}")
    a = a / n
    return np.array([math.cos(angle_rad / 2), *(math.sin(angle_rad / 2) * a)])


def _times(frames: int, duration: float) -> np.ndarray:
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise InvalidParameterError(f"frames must be a positive integer; got {frames!r}")
    if not duration >= 0:
        raise InvalidParameterError(f"duration must be >= 0 s; got {duration}")
    if frames == 1:
        return np.zeros(1)
    return np.linspace(0.0, float(duration), frames)


def _catmull_rom(times, points, t):
    """Uniform Catmull-Rom through ``points`` at ``times`` (end tangents mirrored)."""
    i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2))
    t0, t1 = times[i], times[i + 1]
    u = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
    p1, p2 = points[i], points[i + 1]
    p0 = points[i - 1] if i > 0 else 2 * p1 - p2
    p3 = points[i + 2] if i + 2 < len(points) else 2 * p2 - p1
    return 0.5 * ((2 * p1) + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u * u
                  + (-p0 + 3 * p1 - 3 * p2 + p3) * u ** 3)


def keyframes(frames: int, keys: list[dict], up=(0.0, 0.0, 1.0)) -> list[Sample]:
    """Return samples interpolated between keyframes (dicts: time, position, attitude | look_at)."""
    if len(keys) < 1:
        raise InvalidParameterError("a keyframe trajectory needs at least one keyframe")
    keys = sorted(keys, key=lambda k: float(k["time"]))
    times = np.array([float(k["time"]) for k in keys])
    if np.any(np.diff(times) <= 0):
        raise InvalidParameterError("keyframe times must increase strictly")
    pos = np.array([np.asarray(k["position"], dtype=np.float64) for k in keys])
    if pos.shape[1:] != (3,):
        raise InvalidParameterError("keyframe positions must be [x, y, z]")
    mode = "look_at" if all("look_at" in k for k in keys) else "attitude"
    if mode == "attitude" and not all("attitude" in k for k in keys):
        raise InvalidParameterError(
            "give every keyframe either an attitude [w, x, y, z] or a look_at [x, y, z]")
    out = []
    for t in _times(frames, times[-1] - times[0]) + times[0]:
        if len(keys) == 1:
            p = pos[0]
        else:
            p = _catmull_rom(times, pos, t)
        i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, max(len(keys) - 2, 0)))
        j = min(i + 1, len(keys) - 1)
        u = 0.0 if j == i else (t - times[i]) / (times[j] - times[i])
        if mode == "look_at":
            a = np.asarray(keys[i]["look_at"], dtype=np.float64)
            b = np.asarray(keys[j]["look_at"], dtype=np.float64)
            pose = look_at(p, a + u * (b - a), up)
        else:
            q = slerp(keys[i]["attitude"], keys[j]["attitude"], u)
            pose = Pose(tuple(p), tuple(q))
        out.append(Sample(float(t), pose))
    return out


def descent(frames: int, site, *, start_altitude: float, end_altitude: float,
            duration: float, ground_track=(0.0, 0.0), look: str = "site",
            height_at=None) -> list[Sample]:
    """Return a descent onto ``site`` (x, y, ground height z) (see the module docstring).

    ``ground_track``: horizontal offset (m) of the start from the site, shrinking in proportion
    to the altitude. ``look``: "site" (look at the site) or "nadir" (straight down, north up).
    ``height_at(x, y)``, if given, is used to keep the altitude above the ground below the
    camera at least ``end_altitude`` / 2.
    """
    if not (start_altitude > 0 and end_altitude > 0):
        raise InvalidParameterError(
            f"descent altitudes must be positive; got {start_altitude}, {end_altitude}")
    if look not in ("site", "nadir"):
        raise InvalidParameterError(f"look must be 'site' or 'nadir'; got {look!r}")
    x0, y0, z0 = (float(v) for v in site)
    gx, gy = (float(v) for v in ground_track)
    out = []
    times = _times(frames, duration)
    for i, t in enumerate(times):
        f = i / (len(times) - 1) if len(times) > 1 else 1.0
        alt = start_altitude * (end_altitude / start_altitude) ** f
        share = alt / start_altitude
        x, y = x0 + gx * share, y0 + gy * share
        z = z0 + alt
        if height_at is not None:
            z = max(z, height_at(x, y) + 0.5 * end_altitude)
        if look == "site":
            pose = look_at((x, y, z), (x0, y0, z0))
        else:
            pose = look_at((x, y, z), (x, y, z - 1.0))
        out.append(Sample(float(t), pose))
    return out


def approach(frames: int, *, start_distance: float, end_distance: float, duration: float,
             direction=(1.0, 0.0, 0.0), spin_axis=(0.0, 0.0, 1.0), spin_period: float = 0.0,
             spin_phase_deg: float = 0.0, up=(0.0, 0.0, 1.0)) -> list[Sample]:
    """Return an approach to a spinning body centred at the world origin.

    ``spin_period`` in seconds (0: no spin); the body rotation at time t is
    ``axis_angle(spin_axis, spin_phase + 2 pi t / spin_period)``.
    """
    if not (start_distance > 0 and end_distance > 0):
        raise InvalidParameterError(
            f"approach distances must be positive; got {start_distance}, {end_distance}")
    d = np.asarray(direction, dtype=np.float64)
    if np.linalg.norm(d) == 0:
        raise InvalidParameterError("approach direction must be a non-zero vector")
    d /= np.linalg.norm(d)
    out = []
    times = _times(frames, duration)
    for i, t in enumerate(times):
        f = i / (len(times) - 1) if len(times) > 1 else 1.0
        dist = start_distance * (end_distance / start_distance) ** f
        pose = look_at(d * dist, (0.0, 0.0, 0.0), up)
        q = spin_rotation(t, spin_axis, spin_period, spin_phase_deg)
        out.append(Sample(float(t), pose, tuple(q.tolist())))
    return out


def spin_rotation(t: float, spin_axis=(0.0, 0.0, 1.0), spin_period: float = 0.0,
                  spin_phase_deg: float = 0.0) -> np.ndarray:
    """Return the body rotation R_WB (quaternion [w, x, y, z]) at time ``t`` (s).

    The body spins about ``spin_axis`` with ``spin_period`` (s; 0: no spin) from
    ``spin_phase_deg`` at t = 0.

    >>> spin_rotation(25.0, spin_period=100.0).round(6).tolist()
    [0.707107, 0.0, 0.0, 0.707107]
    """
    angle = math.radians(spin_phase_deg)
    if spin_period:
        angle += 2 * math.pi * t / spin_period
    return axis_angle(spin_axis, angle)
