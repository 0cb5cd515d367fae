"""LIDAR as built: flash and scanning LIDAR with footprints, multiple returns, a link budget.

The renderer's range image is an ideal LIDAR (one exact range per pixel ray). This module
turns it into what a LIDAR reports.

Flash LIDAR
    A ``width`` x ``height`` detector behind optics of ``fov`` degrees (across the width,
    square pixels), looking along ``direction`` in the camera frame. Each pixel's laser
    footprint is the disk of angular radius ``divergence / 2`` about the pixel's ray (in the
    image plane: a disk of radius ``tan(divergence / 2)``); ``divergence = 0`` makes it the
    pixel's own square. The footprint is sampled by sub-rays ``supersample`` to a pixel
    along each axis (a frame rendered at that resolution), each sub-ray returning its range
    R, incidence i (from the normal) and albedo.
Link budget
    The transmitted ``power`` (W) is shared equally by the pixels, and a pixel's share equally
    by its sub-rays. A sub-ray's received power is the LIDAR equation for an extended
    Lambertian target (e.g. Gardner 1992, IEEE TGRS 30, 1061, eq. 2)::

        P_r = P_t efficiency albedo cos(i) A_r / (pi R^2),   A_r = pi (aperture / 2)^2

    A pixel's power is the sum over its sub-rays; below ``threshold`` (W) the pixel drops out
    (NaN): dark, steep and distant surfaces fail in that order of the three factors.

Returns
-------
    The sub-rays' ranges sorted and cut where two neighbours are more than
    ``range_resolution`` apart form a pixel's returns (a histogram of ranges within the
    footprint); a return is detected when its own power reaches ``threshold``. ``first``,
    ``last`` and ``strongest`` are the power-weighted mean ranges of the nearest, farthest
    and strongest detected returns, ``returns`` their number (at most ``max_returns``
    counted), ``range`` the power-weighted mean over the whole footprint (a centroiding
    receiver) where the pixel's power reaches the threshold.
Range noise
    Gaussian, ``range_noise`` metres rms, drawn per (seed, frame, pixel, output) and added to
    every reported range.
Scanning LIDAR
    The same detector grid visited one point at a time along ``pattern`` (``raster``: row by
    row, alternate rows reversed; ``spiral``: outward from the centre) at ``point_rate``
    points a second while the platform moves. A point's time is its place in the pattern;
    the pose at that time follows the trajectory's velocities (:class:`render.motion.Motion`,
    as motion blur does). Points are measured in time slices within which the image moves
    less than ``tolerance`` grid pixels, each slice from the pose at its middle (a flash of
    the grid), so a point's range is that of its own time to within that tolerance.

Examples
--------
>>> lid = Lidar(width=8, height=8, fov=4.0, power=1.0, aperture=0.1, efficiency=1.0,
...             threshold=1e-9)
>>> r = lid.detection_range(albedo=0.1, cos_incidence=1.0)   # metres where a pixel drops
>>> round(r, 1)
62.5
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from render.camera import Intrinsics, Pose
from render.radar import beam_frame
from terrain.core.checks import check_keys, integer, number, text, vector
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import normal, stream_id

__all__ = ["MODES", "SCAN_PATTERNS", "Lidar", "LidarImage", "LidarScan", "flash",
           "footprint", "scan", "scan_order"]

MODES = ("flash", "scan")
SCAN_PATTERNS = ("raster", "spiral")
STREAM_RANGE_NOISE = stream_id("lidar-range-noise")
#: Peak bytes per sub-ray of a flash: the rendered frame and its read-backs (as a camera
#: frame), the world rays and incidence cosines (float64), and the footprint gathers (about
#: ten float64 arrays of pixels x sub-rays a footprint).
FLASH_BYTES_PER_SUB_RAY = 96 + 32 + 10 * 8
#: Frames of a look: (pose, intrinsics) -> an object with ``range`` (h, w), ``normals``
#: (h, w, 3) and optionally ``albedo`` (h, w), the surface's albedo relative to the scene's.
Look = Callable[[Pose, Intrinsics], Any]


@dataclass(frozen=True)
class Lidar:
    """The settings of a LIDAR (a ``[lidar]`` table); see the module docstring."""

    mode: str = "flash"
    width: int = 64
    height: int = 64
    fov: float = 10.0
    direction: tuple = (0.0, 0.0, 1.0)
    divergence: float = 0.0
    supersample: int = 4
    power: float = 1e5
    aperture: float = 0.05
    efficiency: float = 0.5
    albedo: float = 0.12
    threshold: float = 1e-9
    range_resolution: float = 0.1
    range_noise: float = 0.0
    max_returns: int = 3
    pattern: str = "raster"
    point_rate: float = 10000.0
    tolerance: float = 0.5

    def __post_init__(self):
        where = "lidar"
        object.__setattr__(self, "mode", text(self.mode, "mode", choices=MODES, where=where))
        object.__setattr__(self, "pattern", text(self.pattern, "pattern", choices=SCAN_PATTERNS,
                                                 where=where))
        d = np.asarray(vector(self.direction, "direction", 3, where=where), dtype=np.float64)
        if not np.linalg.norm(d) > 0:
            raise InvalidParameterError(f"{where} direction must be a non-zero vector")
        object.__setattr__(self, "direction", tuple((d / np.linalg.norm(d)).tolist()))
        for name, low, high in (("fov", 1e-3, 150.0), ("divergence", 0.0, 30.0),
                                ("power", 0.0, None), ("aperture", 1e-6, None),
                                ("efficiency", 0.0, 1.0), ("albedo", 0.0, 1.0),
                                ("threshold", 0.0, None), ("range_resolution", 1e-6, None),
                                ("range_noise", 0.0, None), ("point_rate", 1e-3, None),
                                ("tolerance", 1e-3, None)):
            object.__setattr__(self, name, float(number(getattr(self, name), name, low=low,
                                                        high=high, where=where)))
        for name, hi in (("width", 4096), ("height", 4096), ("supersample", 16),
                         ("max_returns", 16)):
            object.__setattr__(self, name, integer(getattr(self, name), name, low=1, high=hi,
                                                   where=where))

    @classmethod
    def from_mapping(cls, mapping) -> Lidar:
        """Build the LIDAR from a table; an unknown key is refused naming the nearest.

        >>> Lidar.from_mapping({"treshold": 1e-9})  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        terrain.core.errors.InvalidParameterError: unknown lidar key 'treshold' (did you ...
        """
        return cls(**check_keys(mapping, [f.name for f in fields(cls)], "lidar"))

    def as_dict(self) -> dict:
        """Return the settings as plain data."""
        d = asdict(self)
        d["direction"] = list(self.direction)
        return d

    def intrinsics(self) -> Intrinsics:
        """Return the detector grid (square pixels, ``fov`` across the width)."""
        return Intrinsics.from_fov(self.width, self.height, self.fov)

    @property
    def receiver_area(self) -> float:
        """Collecting area of the receiver, m^2."""
        return math.pi * (0.5 * self.aperture) ** 2

    def received_power(self, ranges, cos_incidence, albedo) -> np.ndarray:
        """Return a pixel's received power (W) from a surface filling its footprint."""
        r = np.asarray(ranges, dtype=np.float64)
        return (self.power / (self.width * self.height) * self.efficiency
                * np.asarray(albedo) * np.asarray(cos_incidence) * self.receiver_area
                / (math.pi * r * r))

    def detection_range(self, albedo: float | None = None, cos_incidence: float = 1.0) -> float:
        """Range (m) beyond which a pixel drops out on a surface of that albedo and incidence."""
        a = self.albedo if albedo is None else albedo
        if self.threshold <= 0:
            return math.inf
        return math.sqrt(float(self.received_power(1.0, cos_incidence, a)) / self.threshold)


def footprint(lidar: Lidar) -> tuple[np.ndarray, np.ndarray, int]:
    """Sub-ray offsets of a pixel's footprint in the supersampled frame.

    Returns
    -------
    dy, dx : (k,) int
        Offsets (rows, columns) from ``s i + pad``, ``s j + pad`` of pixel (i, j)'s sub-rays.
    pad : int
        Sub-rays added around the supersampled frame so that every footprint fits.
    """
    s = lidar.supersample
    c = 0.5 * (s - 1)
    if lidar.divergence == 0:
        m = np.arange(s)
        dy, dx = np.meshgrid(m, m, indexing="ij")
        return dy.ravel(), dx.ravel(), 0
    fx = lidar.intrinsics().fx
    rho = math.tan(math.radians(0.5 * lidar.divergence)) * fx * s
    lo, hi = math.ceil(c - rho), math.floor(c + rho)
    m = np.arange(lo, hi + 1)
    dy, dx = np.meshgrid(m, m, indexing="ij")
    keep = (dy - c) ** 2 + (dx - c) ** 2 <= rho * rho
    if not keep.any():  # a footprint narrower than a sub-ray: the nearest sub-ray
        keep = (dy - c) ** 2 + (dx - c) ** 2 <= (dy - c).min() ** 2 * 2 + 1e-9
    pad = max(0, -lo)
    return dy[keep] + pad, dx[keep] + pad, pad


def supersampled(lidar: Lidar) -> tuple[Intrinsics, int]:
    """Return the frame whose pixels are the sub-rays, and its padding (sub-rays on each side)."""
    k = lidar.intrinsics()
    s = lidar.supersample
    _, _, pad = footprint(lidar)
    w, h = k.width * s + 2 * pad, k.height * s + 2 * pad
    return Intrinsics(w, h, k.fx * s, k.fy * s, 0.5 * (w - 1), 0.5 * (h - 1)), pad


@dataclass
class LidarImage:
    """One flash: per-pixel ranges (NaN: no return), metres, and received power, W."""

    range: np.ndarray
    first: np.ndarray
    last: np.ndarray
    strongest: np.ndarray
    returns: np.ndarray
    power: np.ndarray


def flash_response(lidar: Lidar, ranges: np.ndarray, normals: np.ndarray, rays: np.ndarray,
                   albedo: np.ndarray | None = None, *, seed: int = 0,
                   frame: int = 0) -> LidarImage:
    """Turn the supersampled frame's images into a flash (see the module docstring).

    Parameters
    ----------
    lidar : Lidar
        The LIDAR.
    ranges : (H, W) float, metres
        Range of every sub-ray of :func:`supersampled`'s frame (NaN: nothing).
    normals : (H, W, 3) float
        World-frame surface normals there.
    rays : (H, W, 3) float
        World-frame unit sub-ray directions.
    albedo : (H, W) float, optional
        The surface's albedo relative to ``lidar.albedo`` (1 where not given).
    seed, frame : int
        Key the range noise.

    Returns
    -------
    LidarImage
    """
    k, _ = supersampled(lidar)
    if ranges.shape != (k.height, k.width):
        raise InvalidParameterError(f"lidar sub-ray images must be ({k.height}, {k.width}); "
                                    f"got {ranges.shape}")
    dy, dx, _ = footprint(lidar)
    s = lidar.supersample
    rows = (s * np.arange(lidar.height))[:, None, None] + dy[None, None, :]
    cols = (s * np.arange(lidar.width))[None, :, None] + dx[None, None, :]
    r = np.asarray(ranges, dtype=np.float64)[rows, cols]           # (h, w, k)
    cos_i = np.clip(-np.sum(np.asarray(rays, dtype=np.float64)
                            * np.asarray(normals, dtype=np.float64), axis=-1), 0.0, 1.0)
    a = np.ones_like(r) if albedo is None else np.asarray(albedo, dtype=np.float64)[rows, cols]
    hit = np.isfinite(r) & (r > 0)
    rr = np.where(hit, r, 1.0)
    p = np.where(hit, lidar.received_power(rr, cos_i[rows, cols], lidar.albedo * a)
                 / len(dy), 0.0)
    total = p.sum(axis=-1)
    seen = (total >= lidar.threshold) & (total > 0)
    nan = np.full(total.shape, np.nan)
    mean = np.where(seen, np.sum(p * rr, axis=-1) / np.where(seen, total, 1.0), nan)
    # returns: clusters of sorted sub-ray ranges split at gaps over the range resolution
    order = np.argsort(np.where(hit, r, np.inf), axis=-1)
    rs = np.take_along_axis(np.where(hit, r, np.inf), order, axis=-1)
    ps = np.take_along_axis(p, order, axis=-1)
    gap = np.diff(rs, axis=-1) > lidar.range_resolution
    cluster = np.concatenate([np.zeros(rs.shape[:-1] + (1,), np.int64),
                              np.cumsum(gap, axis=-1)], axis=-1)
    first, last, strongest = nan.copy(), nan.copy(), nan.copy()
    best = np.zeros(total.shape)
    count = np.zeros(total.shape, np.uint8)
    fin = np.isfinite(rs)
    for c in range(int(cluster.max(initial=0)) + 1):
        m = (cluster == c) & fin
        pc = np.sum(np.where(m, ps, 0.0), axis=-1)
        ok = (pc >= lidar.threshold) & (pc > 0)
        if not ok.any():
            continue
        rc = np.sum(np.where(m, ps * np.where(fin, rs, 0.0), 0.0), axis=-1) / np.where(ok, pc, 1)
        first = np.where(ok & np.isnan(first), rc, first)
        last = np.where(ok, rc, last)
        stronger = ok & (pc > best)
        strongest = np.where(stronger, rc, strongest)
        best = np.where(stronger, pc, best)
        count = np.where(ok & (count < lidar.max_returns), count + 1, count).astype(np.uint8)
    if lidar.range_noise > 0:
        cols_i, rows_i = np.meshgrid(np.arange(lidar.width), np.arange(lidar.height))
        noisy = []
        for j, img in enumerate((mean, first, last, strongest)):
            z = normal(seed, STREAM_RANGE_NOISE, frame, cols_i, rows_i, j)
            noisy.append(img + lidar.range_noise * z)
        mean, first, last, strongest = noisy
    return LidarImage(mean.astype(np.float32), first.astype(np.float32),
                      last.astype(np.float32), strongest.astype(np.float32), count,
                      total.astype(np.float32))


def flash(lidar: Lidar, look: Look, pose: Pose, *, seed: int = 0, frame: int = 0) -> LidarImage:
    """Render the sub-rays from the camera ``pose`` and return one flash.

    Parameters
    ----------
    lidar : Lidar
        The LIDAR (``direction`` in the camera frame of ``pose``).
    look : callable
        ``look(pose, intrinsics)`` returns a frame with ``range``, ``normals`` and optionally
        ``albedo``.
    pose : render.camera.Pose
        The camera (body) pose.
    seed, frame : int
        Key the range noise.
    """
    from terrain.core import memory

    k, _ = supersampled(lidar)
    dy, _, _ = footprint(lidar)
    memory.require(max(k.width * k.height, lidar.width * lidar.height * len(dy))
                   * FLASH_BYTES_PER_SUB_RAY,
                   f"a {lidar.width}x{lidar.height} flash of {len(dy)} sub-rays a pixel")
    lp = beam_frame(pose, lidar.direction)
    fr = look(lp, k)
    rays = k.rays() @ lp.rotation.T
    return flash_response(lidar, fr.range, fr.normals, rays, getattr(fr, "albedo", None),
                          seed=seed, frame=frame)


def scan_order(lidar: Lidar) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the grid in the order the scan visits them.

    >>> rows, cols = scan_order(Lidar(width=3, height=2, pattern="raster"))
    >>> rows.tolist(), cols.tolist()
    ([0, 0, 0, 1, 1, 1], [0, 1, 2, 2, 1, 0])
    """
    h, w = lidar.height, lidar.width
    rows, cols = np.mgrid[0:h, 0:w]
    if lidar.pattern == "raster":
        cols = np.where(rows % 2 == 1, w - 1 - cols, cols)
        return rows.ravel(), cols.ravel()
    y, x = rows - 0.5 * (h - 1), cols - 0.5 * (w - 1)
    radius = np.hypot(x, y)
    turn = (np.arctan2(y, x) % (2 * math.pi)) / (2 * math.pi)
    key = np.lexsort(((np.floor(radius) + turn).ravel(),))
    return rows.ravel()[key], cols.ravel()[key]


@dataclass
class LidarScan:
    """The points of one scan, in the order measured."""

    time: np.ndarray          # (n,) s
    row: np.ndarray           # (n,) int
    col: np.ndarray           # (n,) int
    position: np.ndarray      # (n, 3) m, world frame: the sensor at the point's time
    direction: np.ndarray     # (n, 3) world-frame unit ray at that time
    range: np.ndarray         # (n,) m, NaN: no return
    first: np.ndarray
    last: np.ndarray
    strongest: np.ndarray
    returns: np.ndarray
    power: np.ndarray
    slices: int


def scan(lidar: Lidar, look: Look, pose: Pose, t0: float, motion, *, seed: int = 0,
         frame: int = 0, nearest_range: float | None = None) -> LidarScan:
    """Scan the grid along the pattern from ``t0`` while the platform moves with ``motion``.

    Parameters
    ----------
    lidar : Lidar
        The LIDAR.
    look : callable
        As for :func:`flash`.
    pose : render.camera.Pose
        The camera pose at ``t0``.
    t0 : float
        The scan's start, seconds.
    motion : render.motion.Motion
        Velocities held during the scan.
    seed, frame : int
        Key the range noise.
    nearest_range : float, optional
        The nearest surface (m), bounding image motion; measured by a first flash otherwise.

    Returns
    -------
    LidarScan
    """
    rows, cols = scan_order(lidar)
    n = len(rows)
    times = np.arange(n) / lidar.point_rate
    k = lidar.intrinsics()
    if nearest_range is None:
        first = flash(lidar, look, pose, seed=seed, frame=frame)
        fin = np.isfinite(first.range)
        nearest_range = float(np.min(first.range[fin])) if fin.any() else 1e9
    speed = motion.image_speed(k, nearest_range)
    duration = n / lidar.point_rate
    slices = max(1, math.ceil(duration * speed / lidar.tolerance)) if speed > 0 else 1
    out = {name: np.full(n, np.nan, np.float32) for name in ("range", "first", "last",
                                                             "strongest", "power")}
    ret = np.zeros(n, np.uint8)
    pos = np.zeros((n, 3))
    dirs = np.zeros((n, 3))
    rays_c = k.rays()
    edges = np.linspace(0.0, duration, slices + 1)
    which = np.minimum(np.searchsorted(edges, times, side="right") - 1, slices - 1)
    for s in range(slices):
        sel = np.nonzero(which == s)[0]
        if not len(sel):
            continue
        mid = 0.5 * (edges[s] + edges[s + 1])
        img = flash(lidar, look, motion.pose_at(pose, mid), seed=seed, frame=frame)
        r, c = rows[sel], cols[sel]
        for name in ("range", "first", "last", "strongest", "power"):
            out[name][sel] = getattr(img, name)[r, c]
        ret[sel] = img.returns[r, c]
    # each point's pose at its own time (Motion.pose_at, vectorised: Rodrigues' formula)
    pos[:] = np.asarray(pose.position) + np.outer(times, motion.velocity)
    beam_c = beam_frame(Pose((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)), lidar.direction).rotation
    d0 = pose.rotation @ (beam_c @ rays_c[rows, cols].T)          # (3, n) at t0, world
    d0 = d0.T
    w = np.asarray(motion.angular_velocity, dtype=np.float64)
    rate = float(np.linalg.norm(w))
    if rate > 0:
        axis = w / rate
        a = (rate * times)[:, None]
        dirs[:] = (d0 * np.cos(a) + np.cross(axis, d0) * np.sin(a)
                   + axis * (d0 @ axis)[:, None] * (1 - np.cos(a)))
    else:
        dirs[:] = d0
    return LidarScan(t0 + times, rows, cols, pos, dirs, out["range"], out["first"],
                     out["last"], out["strongest"], ret, out["power"], slices)
