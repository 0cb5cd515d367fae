"""A lamp on the spacecraft: a light bound to the camera, for operations in permanent shadow.

A ``[lamp]`` table puts a spotlight at ``position`` (metres, camera frame: x right, y down, z
along the boresight) pointing along ``direction`` (camera frame, default the boresight), of
radiant ``intensity`` I on its axis (W sr^-1 nm^-1 in the camera's band), full within the
half-angle ``cone`` and fading to nothing over a further ``falloff`` degrees (a smoothstep),
falling with the inverse square of the distance.

It is added to each frame from the frame's own range and normals: the surface point p seen by
a pixel receives, normal to the beam, ``E = I g(angle) / |p - lamp|^2``, and shows the I/F
``R(mu0, mu, phase) E / F`` on the sun's scale (R the scene's reflectance law at the lamp's
incidence ``mu0``, the camera's emission ``mu`` and their phase angle; F the solar spectral
irradiance at the body), so the sensor exposes lamp light and sunlight together. The lamp
casts no shadows: at the camera's centre (the default) a surface hides its own lamp shadow
from the camera exactly; with an offset they would show as thin rims, which are not drawn.
The scene's mean albedo is used (an albedo map modulates the sunlit term only).

Examples
--------
>>> Lamp.from_mapping({"intensity": 100.0}).cone
30.0
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from render.reflectance import reflectance
from terrain.core.checks import check_keys, number, vector
from terrain.core.errors import InvalidParameterError

__all__ = ["Lamp", "lamp_if"]


@dataclass(frozen=True)
class Lamp:
    """A spotlight bound to the camera (a ``[lamp]`` table; see the module docstring).

    Parameters
    ----------
    intensity : float
        Radiant intensity on the axis, W sr^-1 nm^-1.
    cone : float
        Half-angle of full intensity, degrees.
    falloff : float
        Degrees beyond ``cone`` over which the beam fades to zero.
    position : (3,) float
        Metres from the camera centre, camera frame.
    direction : (3,) float
        Beam axis, camera frame.
    """

    intensity: float
    cone: float = 30.0
    falloff: float = 5.0
    position: tuple = (0.0, 0.0, 0.0)
    direction: tuple = (0.0, 0.0, 1.0)

    def __post_init__(self):
        where = "scenario [lamp]"
        object.__setattr__(self, "intensity", number(self.intensity, "intensity", low=0.0,
                                                     where=where))
        object.__setattr__(self, "cone", number(self.cone, "cone", low=0.0, high=90.0,
                                                where=where))
        object.__setattr__(self, "falloff", number(self.falloff, "falloff", low=0.0,
                                                   high=90.0, where=where))
        object.__setattr__(self, "position", vector(self.position, "position", 3,
                                                    where=where))
        d = np.asarray(vector(self.direction, "direction", 3, where=where), dtype=np.float64)
        if not np.linalg.norm(d) > 0:
            raise InvalidParameterError(f"{where} direction must be a non-zero vector")
        object.__setattr__(self, "direction", tuple((d / np.linalg.norm(d)).tolist()))

    @classmethod
    def from_mapping(cls, table: Any) -> Lamp:
        """Build the lamp from a ``[lamp]`` table (``intensity`` required; unknown keys refused)."""
        data = check_keys(table, {"intensity", "cone", "falloff", "position", "direction"},
                          "scenario [lamp]")
        if "intensity" not in data:
            raise InvalidParameterError("scenario [lamp] needs intensity (W sr^-1 nm^-1)")
        return cls(**data)

    def as_dict(self) -> dict:
        """Return the lamp as plain data."""
        return asdict(self)

    def beam(self, cos_axis: np.ndarray) -> np.ndarray:
        """Relative intensity at angles whose cosines from the axis are ``cos_axis``.

        >>> Lamp(1.0, cone=10.0, falloff=10.0).beam(np.cos(np.radians([0.0, 15.0, 25.0])))
        array([1. , 0.5, 0. ])
        """
        ang = np.degrees(np.arccos(np.clip(cos_axis, -1.0, 1.0)))
        if self.falloff == 0:
            return (ang <= self.cone).astype(np.float64)
        t = np.clip((self.cone + self.falloff - ang) / self.falloff, 0.0, 1.0)
        return t * t * (3.0 - 2.0 * t)


def lamp_if(lamp: Lamp, range_m: np.ndarray, normals: np.ndarray, pose: Any,
            intrinsics: Any, lighting: Any) -> np.ndarray:
    """Return the lamp's I/F (on the sun's scale) for every pixel of a frame.

    Parameters
    ----------
    lamp : Lamp
    range_m : (h, w) float
        Distance along each pixel's ray (NaN: sky).
    normals : (h, w, 3) float
        World-frame unit normals.
    pose : render.camera.Pose
    intrinsics : render.camera.Intrinsics
    lighting : render.renderer.Lighting
        The reflectance law, albedo and the solar irradiance at the body.

    Returns
    -------
    (h, w) float32
        Zero on sky and outside the beam.
    """
    h, w = range_m.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy,
                     np.ones_like(u)], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    rot = np.asarray(pose.rotation, dtype=np.float64)  # camera to world
    p_cam = rays * np.asarray(range_m, dtype=np.float64)[..., None]  # camera frame points
    to_lamp = np.asarray(lamp.position) - p_cam
    dist = np.linalg.norm(to_lamp, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        l_cam = to_lamp / dist[..., None]
        n_cam = np.asarray(normals, dtype=np.float64) @ rot  # world to camera, row-wise
        mu0 = np.sum(n_cam * l_cam, axis=-1)
        mu = np.sum(n_cam * -rays, axis=-1)
        phase = np.degrees(np.arccos(np.clip(np.sum(l_cam * -rays, axis=-1), -1.0, 1.0)))
        axis_cos = np.sum(-l_cam * np.asarray(lamp.direction), axis=-1)
        e_normal = lamp.intensity * lamp.beam(axis_cos) / dist**2
    ok = np.isfinite(range_m) & np.isfinite(mu0) & (mu > 0)
    out = np.zeros((h, w))
    r = reflectance(lighting.brdf, np.where(ok, mu0, 0.0), np.where(ok, mu, 1.0),
                    np.where(ok, phase, 0.0), lighting.albedo, lighting.mcewen, lighting.hapke)
    out[ok] = (r * e_normal)[ok] / lighting.spectral_irradiance
    if not math.isfinite(float(out.max(initial=0.0))):
        raise InvalidParameterError("the lamp's irradiance is not finite (a surface at the "
                                    "lamp's position?)")
    return out.astype(np.float32)
