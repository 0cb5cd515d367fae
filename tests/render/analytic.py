"""Analytic scenes traced in numpy: planes, a step and spheres, as stand-ins for the renderer."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Hit:
    """What a look returns: range (h, w), world normals (h, w, 3), optional relative albedo."""

    range: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray | None = None


def world_rays(pose, k):
    """(h, w, 3) world-frame unit rays of the frame."""
    return k.rays() @ pose.rotation.T


def plane_look(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), spheres=(), albedo=None):
    """A look at the plane through ``point`` with ``normal`` and spheres ``(centre, radius)``."""
    q = np.asarray(point, float)
    m = np.asarray(normal, float)
    m = m / np.linalg.norm(m)

    def look(pose, k):
        o = np.asarray(pose.position, float)
        u = world_rays(pose, k)
        den = u @ m
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((q - o) @ m) / den
        t = np.where((t > 0) & np.isfinite(t), t, np.nan)
        nrm = np.broadcast_to(m, u.shape).copy()
        for c, rad in spheres:
            oc = o - np.asarray(c, float)
            b = u @ oc
            disc = b * b - (oc @ oc - rad * rad)
            ts = -b - np.sqrt(np.where(disc >= 0, disc, np.nan))
            closer = (disc >= 0) & (ts > 0) & ~(ts >= t)
            t = np.where(closer, ts, t)
            p = o + u * ts[..., None]
            ns = (p - np.asarray(c, float)) / rad
            nrm = np.where(closer[..., None], ns, nrm)
        a = None if albedo is None else albedo(o + u * np.nan_to_num(t)[..., None])
        return Hit(t, nrm, a)

    return look


def step_look(low=0.0, high=5.0):
    """Ground z = ``low`` for x < 0 and a raised block z = ``high`` for x >= 0 (top only)."""

    def look(pose, k):
        o = np.asarray(pose.position, float)
        u = world_rays(pose, k)
        with np.errstate(divide="ignore", invalid="ignore"):
            th = (high - o[2]) / u[..., 2]
            tl = (low - o[2]) / u[..., 2]
        on_top = (th > 0) & (o[0] + th * u[..., 0] >= 0)
        t = np.where(on_top, th, tl)
        t = np.where(t > 0, t, np.nan)
        nrm = np.broadcast_to(np.array([0.0, 0.0, 1.0]), u.shape).copy()
        return Hit(t, nrm)

    return look
