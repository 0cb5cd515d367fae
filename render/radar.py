"""A radar altimeter and velocimeter: one beam's nearest range and its range x Doppler histogram.

The beam is a cone about a direction fixed in the camera (body) frame, with a gain pattern
``G(theta)`` of the off-boresight angle theta and a full width ``width`` at half power:

- ``gaussian``: ``G = exp(-4 ln 2 (theta / width)^2)``;
- ``sinc2``: ``G = sinc^2(SINC2_HALF_POWER x 2 theta / width)`` (``sinc(x) = sin(pi x)/(pi x)``),
  a uniformly illuminated aperture, half power at ``theta = width / 2``;
- ``uniform``: 1 inside ``theta <= width / 2``, 0 outside.

The beam is sampled by rays: a small square frame rendered from the platform along the
boresight (``pixels`` x ``pixels``, ``field`` beam widths across), whose range and normal
images give every sampled ray's range R, incidence i and surface point. A ray's returned
power follows the radar equation for a distributed target,
``dP ~ G^2 sigma0(i) dA / R^4`` with the illuminated area ``dA = R^2 dOmega / cos i`` and
Lambert's law for the backscatter, ``sigma0 = cos^2 i`` (Ulaby, Moore & Fung 1982, vol. II,
ch. 12), so ``dP ~ G^2 cos(i) dOmega / R^2``, ``dOmega`` being the ray's pixel solid angle.

Outputs of a measurement (:class:`RadarReturn`):

- ``range``: the nearest surface inside the half-power beam (``theta <= width / 2``), metres;
  NaN when that part of the beam meets nothing. This is the leading edge an altimeter tracks.
- ``histogram``: returned power binned by range (``range_bins`` of ``range_resolution`` m from
  the bin holding the nearest return of the whole sampled beam) and by radial velocity
  (``doppler_bins`` across ``[-max_velocity, max_velocity]`` m/s), normalised so that the
  whole sampled beam sums to 1 (what falls outside the bins is ``power_outside``). The
  radial velocity of a ray is ``v_r = (v - v_s) . u``, ``u`` the ray's unit direction,
  ``v`` the platform velocity and ``v_s`` the surface's (``omega x p`` of a turning body):
  positive while closing. With a ``wavelength`` the Doppler shift is ``2 v_r / wavelength`` Hz.
- ``velocity``: the power-weighted mean radial velocity, and ``boresight_velocity`` the
  platform's ``v . n`` along the beam direction n (what a velocimeter's beam estimates).

Examples
--------
>>> beam = RadarBeam(width=4.0)
>>> round(float(beam.gain(np.radians([0.0, 2.0]))[1]), 3)  # half power at half the width
0.5
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from render.camera import Intrinsics, Pose, quat_from_matrix
from terrain.core.checks import check_keys, integer, number, text, vector
from terrain.core.errors import InvalidParameterError

__all__ = ["PATTERNS", "RadarBeam", "RadarReturn", "beam_frame", "measure", "radar_response"]

#: Gain patterns a beam may have.
PATTERNS = ("gaussian", "sinc2", "uniform")
#: x at which ``sinc(x)^2 = 1/2`` (normalised sinc): the half-power point of a uniform aperture.
SINC2_HALF_POWER = 0.442946470689452
#: Peak bytes per sampled ray: the rendered frame and its read-backs, and about twenty
#: float64 values a ray (rays, points, velocities, weights).
RADAR_BYTES_PER_RAY = 96 + 20 * 8
#: Frames of a look: (pose, intrinsics) -> an object with ``range`` (h, w) and ``normals``
#: (h, w, 3) (render.renderer.Frame, or an analytic stand-in).
Look = Callable[[Pose, Intrinsics], Any]


@dataclass(frozen=True)
class RadarBeam:
    """The settings of a radar beam (a ``[radar]`` table).

    Parameters
    ----------
    direction : (3,) float
        Boresight in the camera (body) frame (OpenCV: z along the optical axis); normalised.
    width : float
        Full width at half power, degrees.
    pattern : str
        One of :data:`PATTERNS`.
    pixels : int
        Side of the square frame that samples the beam.
    field : float
        Width of that frame in beam widths.
    range_resolution : float
        Range bin, metres.
    range_bins : int
        Number of range bins, the first holding the nearest return.
    doppler_bins : int
        Number of radial-velocity bins across ``[-max_velocity, max_velocity]``.
    max_velocity : float
        Largest radial speed the histogram holds, m/s.
    wavelength : float
        Carrier wavelength, metres (0: Doppler reported in m/s only).
    """

    direction: tuple = (0.0, 0.0, 1.0)
    width: float = 4.0
    pattern: str = "gaussian"
    pixels: int = 64
    field: float = 2.0
    range_resolution: float = 1.0
    range_bins: int = 64
    doppler_bins: int = 128
    max_velocity: float = 100.0
    wavelength: float = 0.0

    def __post_init__(self):
        where = "radar"
        d = np.asarray(vector(self.direction, "direction", 3, where=where), dtype=np.float64)
        n = float(np.linalg.norm(d))
        if not n > 0:
            raise InvalidParameterError(f"{where} direction must be a non-zero vector")
        object.__setattr__(self, "direction", tuple((d / n).tolist()))
        object.__setattr__(self, "pattern", text(self.pattern, "pattern", choices=PATTERNS,
                                                 where=where))
        for name, low, high in (("width", 1e-3, 120.0), ("field", 1.0, 4.0),
                                ("range_resolution", 1e-6, None), ("max_velocity", 1e-6, None),
                                ("wavelength", 0.0, None)):
            object.__setattr__(self, name, float(number(getattr(self, name), name, low=low,
                                                        high=high, where=where)))
        if self.width * self.field >= 170.0:
            raise InvalidParameterError(
                f"{where} width x field must stay below 170 degrees; got "
                f"{self.width * self.field}")
        for name, hi in (("pixels", 2048), ("range_bins", 1 << 16), ("doppler_bins", 1 << 16)):
            object.__setattr__(self, name, integer(getattr(self, name), name, low=1, high=hi,
                                                   where=where))

    @classmethod
    def from_mapping(cls, mapping) -> RadarBeam:
        """Build the beam from a table; an unknown key is refused naming the nearest.

        >>> RadarBeam.from_mapping({"widht": 3.0})  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        terrain.core.errors.InvalidParameterError: unknown radar key 'widht' (did you ...
        """
        return cls(**check_keys(mapping, [f.name for f in fields(cls)], "radar"))

    def as_dict(self) -> dict:
        """Return the settings as plain data."""
        d = asdict(self)
        d["direction"] = list(self.direction)
        return d

    def gain(self, theta) -> np.ndarray:
        """One-way gain (1 on the boresight) at off-boresight angles ``theta`` (radians)."""
        x = np.asarray(theta, dtype=np.float64) / math.radians(self.width)
        if self.pattern == "gaussian":
            return np.exp(-4.0 * math.log(2.0) * x * x)
        if self.pattern == "sinc2":
            return np.sinc(2.0 * SINC2_HALF_POWER * x) ** 2
        return (x <= 0.5).astype(np.float64)

    def intrinsics(self) -> Intrinsics:
        """Return the square frame that samples the beam."""
        return Intrinsics.from_fov(self.pixels, self.pixels, self.width * self.field)


@dataclass
class RadarReturn:
    """One radar measurement (see the module docstring)."""

    range: float
    velocity: float
    boresight_velocity: float
    histogram: np.ndarray
    range_edges: np.ndarray
    velocity_edges: np.ndarray
    power_outside: float
    direction: tuple

    def as_dict(self) -> dict:
        """Return the scalars as plain data (NaN as None)."""
        def f(x):
            return None if not math.isfinite(x) else float(x)
        return dict(range=f(self.range), velocity=f(self.velocity),
                    boresight_velocity=f(self.boresight_velocity),
                    power_outside=f(self.power_outside), direction=list(self.direction))


def beam_frame(pose: Pose, direction) -> Pose:
    """Return the pose of the frame looking along ``direction`` (camera frame) from ``pose``.

    Its optical axis is the beam; its x axis is perpendicular to the camera's y axis (the
    camera's x axis where they are perpendicular).
    """
    z = np.asarray(direction, dtype=np.float64)
    z = z / np.linalg.norm(z)
    ref = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = pose.rotation @ np.column_stack([x, y, z])
    return Pose(tuple(pose.position), tuple(quat_from_matrix(r)))


def radar_response(beam: RadarBeam, pose: Pose, ranges: np.ndarray, normals: np.ndarray,
                   velocity, *, body_angular_velocity=(0.0, 0.0, 0.0),
                   centre=(0.0, 0.0, 0.0)) -> RadarReturn:
    """Turn the beam frame's range and normal images into a radar return.

    Parameters
    ----------
    beam : RadarBeam
        The beam.
    pose : render.camera.Pose
        The beam frame's pose (:func:`beam_frame`).
    ranges : (pixels, pixels) float, metres
        Range along each ray (NaN: no surface).
    normals : (pixels, pixels, 3) float
        World-frame surface normals.
    velocity : (3,) float, m/s
        The platform's world-frame velocity.
    body_angular_velocity : (3,) float, rad/s
        The surface's rotation about ``centre`` (an asteroid's spin; zero for terrain).
    centre : (3,) float, metres
        The point the surface turns about.

    Returns
    -------
    RadarReturn
    """
    k = beam.intrinsics()
    ranges = np.asarray(ranges, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if ranges.shape != (k.height, k.width) or normals.shape != (k.height, k.width, 3):
        raise InvalidParameterError(
            f"radar images must be ({k.height}, {k.width}) and ({k.height}, {k.width}, 3); got "
            f"{ranges.shape} and {normals.shape}")
    rays_c = k.rays().reshape(k.height, k.width, 3).astype(np.float64)
    rays_c /= np.linalg.norm(rays_c, axis=-1, keepdims=True)
    theta = np.arccos(np.clip(rays_c[..., 2], -1.0, 1.0))
    u = rays_c @ pose.rotation.T                      # world-frame unit rays
    g = beam.gain(theta)
    omega = rays_c[..., 2] ** 3 / (k.fx * k.fy)       # pixel solid angle, sr
    hit = np.isfinite(ranges) & (ranges > 0)
    r = np.where(hit, ranges, 1.0)
    cos_i = np.clip(-np.sum(u * normals, axis=-1), 0.0, 1.0)
    power = np.where(hit, g * g * cos_i * omega / (r * r), 0.0)
    inside = hit & (theta <= 0.5 * math.radians(beam.width))
    nearest = float(np.min(ranges[inside])) if inside.any() else math.nan
    v = np.asarray(velocity, dtype=np.float64).reshape(3)
    pts = np.asarray(pose.position) + u * r[..., None]
    v_s = np.cross(np.asarray(body_angular_velocity, dtype=np.float64),
                   pts - np.asarray(centre, dtype=np.float64))
    v_r = np.sum((v - v_s) * u, axis=-1)
    n_w = pose.rotation[:, 2]
    lit = hit & (power > 0)
    first = float(np.min(ranges[lit])) if lit.any() else 0.0
    start = math.floor(first / beam.range_resolution) * beam.range_resolution
    r_edges = start + beam.range_resolution * np.arange(beam.range_bins + 1)
    v_edges = np.linspace(-beam.max_velocity, beam.max_velocity, beam.doppler_bins + 1)
    total = float(power.sum())
    hist, _, _ = np.histogram2d(ranges[hit], v_r[hit], bins=(r_edges, v_edges),
                                weights=power[hit])
    if total > 0:
        hist /= total
        mean_v = float(np.sum(power * v_r) / total)
    else:
        mean_v = math.nan
    outside = 1.0 - float(hist.sum()) if total > 0 else 0.0
    return RadarReturn(nearest, mean_v, float(v @ n_w), hist, r_edges, v_edges,
                       max(outside, 0.0), tuple(n_w.tolist()))


def measure(beam: RadarBeam, look: Look, pose: Pose, velocity, **surface) -> RadarReturn:
    """Render the beam frame from the camera ``pose`` and measure (:func:`radar_response`).

    Parameters
    ----------
    beam : RadarBeam
        The beam (direction in the camera frame of ``pose``).
    look : callable
        ``look(pose, intrinsics)`` returns a frame with ``range`` and ``normals``.
    pose : render.camera.Pose
        The camera (body) pose.
    velocity : (3,) float, m/s
        The platform's world-frame velocity.
    **surface
        ``body_angular_velocity`` and ``centre`` of :func:`radar_response`.
    """
    from terrain.core import memory

    memory.require(beam.pixels ** 2 * RADAR_BYTES_PER_RAY
                   + beam.range_bins * beam.doppler_bins * 8,
                   f"a radar beam of {beam.pixels}x{beam.pixels} rays")
    bp = beam_frame(pose, beam.direction)
    frame = look(bp, beam.intrinsics())
    return radar_response(beam, bp, frame.range, frame.normals, velocity, **surface)
