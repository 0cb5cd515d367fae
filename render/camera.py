"""Camera model, poses and the frame conventions every craterscape image follows.

Frames
------
World frame W
    Terrain scenes: the DEM's map frame, x east and y north in map metres, z up in metres
    (the DEM's vertical datum; with planetary curvature on, z is still height above the
    datum, see :mod:`render.terrain_scene`). Asteroid scenes: an inertial frame in metres
    whose origin is the body's centre; body-fixed coordinates map to it through the body's
    rotation, ``p_W = R_body(t) p_B``.
Camera frame C (OpenCV)
    Origin at the camera centre, x to the right of the image, y down the image, z along the
    optical axis into the scene.
Pose
    ``position``: the camera centre in W (m). ``attitude``: the unit quaternion
    ``[w, x, y, z]`` (scalar first, Hamilton) of the rotation R_WC that takes camera-frame
    vectors to world-frame vectors, ``v_W = R_WC v_C``.
Pixels
    Row 0 is the top of the image; pixel (u, v) = (column, row) has its centre at integer
    coordinates, so a point at camera coordinates (X, Y, Z) projects to
    ``u = fx X / Z + cx``, ``v = fy Y / Z + cy`` (the OpenCV pinhole model, no distortion).
Range
    LIDAR range is the Euclidean distance from the camera centre to the surface along the
    pixel's ray, in metres (not the depth Z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from terrain.core.errors import InvalidParameterError

__all__ = ["Intrinsics", "Pose", "look_at", "quat_from_matrix", "quat_to_matrix", "slerp"]


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels (OpenCV convention, see the module docstring).

    Examples
    --------
    >>> k = Intrinsics.from_fov(640, 480, 60.0)
    >>> round(k.fx, 3), k.cx, k.cy
    (554.256, 319.5, 239.5)
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self):
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise InvalidParameterError(f"camera {name} must be a positive integer; got {v}")
            object.__setattr__(self, name, int(v))
        for name in ("fx", "fy", "cx", "cy"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise InvalidParameterError(f"camera {name} must be finite; got {v}")
            object.__setattr__(self, name, v)
        if self.fx <= 0 or self.fy <= 0:
            raise InvalidParameterError(
                f"camera focal lengths must be positive; got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float) -> Intrinsics:
        """Square pixels, horizontal field of view ``fov_deg``, principal point at the centre."""
        if not 0.0 < fov_deg < 179.0:
            raise InvalidParameterError(f"field of view must lie in (0, 179) degrees; got "
                                        f"{fov_deg}")
        f = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) float64 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_x(self) -> float:
        """Horizontal field of view (degrees), from pixel edge to pixel edge."""
        left = (self.cx + 0.5) / self.fx
        right = (self.width - 0.5 - self.cx) / self.fx
        return math.degrees(math.atan(left) + math.atan(right))

    @property
    def fov_y(self) -> float:
        """The vertical field of view in degrees (through the pixel edges)."""
        top = (self.cy + 0.5) / self.fy
        bottom = (self.height - 0.5 - self.cy) / self.fy
        return math.degrees(math.atan(top) + math.atan(bottom))

    def rays(self) -> np.ndarray:
        """(height, width, 3) float64 unit ray directions in the camera frame."""
        v, u = np.mgrid[0:self.height, 0:self.width].astype(np.float64)
        d = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy,
                      np.ones_like(u)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def as_dict(self) -> dict:
        """Return the intrinsics as plain data (pixels) for truth files."""
        return dict(width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx,
                    cy=self.cy)


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``[w, x, y, z]``."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if n == 0 or not math.isfinite(n):
        raise InvalidParameterError(f"attitude quaternion must be non-zero and finite; got {q}")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def quat_from_matrix(m) -> np.ndarray:
    """Return the unit quaternion ``[w, x, y, z]`` (w >= 0) of a rotation matrix (Shepperd)."""
    m = np.asarray(m, dtype=np.float64)
    t = np.trace(m)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    quat = np.array(q)
    quat /= np.linalg.norm(quat)
    return -quat if quat[0] < 0 else quat


def slerp(q0, q1, t: float) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions (shortest arc)."""
    q0 = np.asarray(q0, dtype=np.float64) / np.linalg.norm(q0)
    q1 = np.asarray(q1, dtype=np.float64) / np.linalg.norm(q1)
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(d)
    q = (math.sin((1 - t) * theta) * q0 + math.sin(t * theta) * q1) / math.sin(theta)
    return q / np.linalg.norm(q)


@dataclass(frozen=True)
class Pose:
    """Camera position (W, metres) and attitude quaternion R_WC (see the module docstring)."""

    position: tuple
    attitude: tuple

    def __post_init__(self):
        p = np.asarray(self.position, dtype=np.float64).reshape(-1)
        q = np.asarray(self.attitude, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise InvalidParameterError(f"camera position must be 3 finite numbers; got {p}")
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) == 0:
            raise InvalidParameterError(
                f"camera attitude must be a non-zero quaternion [w, x, y, z]; got {q}")
        q = q / np.linalg.norm(q)
        if q[0] < 0:
            q = -q
        object.__setattr__(self, "position", tuple(p.tolist()))
        object.__setattr__(self, "attitude", tuple(q.tolist()))

    @property
    def rotation(self) -> np.ndarray:
        """R_WC: camera-frame vectors to world-frame vectors."""
        return quat_to_matrix(self.attitude)

    @property
    def view_matrix(self) -> np.ndarray:
        """(4, 4) world-to-camera transform (OpenCV camera frame)."""
        r = self.rotation.T
        m = np.eye(4)
        m[:3, :3] = r
        m[:3, 3] = -r @ np.asarray(self.position)
        return m

    def to_camera(self, points) -> np.ndarray:
        """World points (n, 3) to camera-frame coordinates (n, 3)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        return (p - np.asarray(self.position)) @ self.rotation

    def project(self, points, intrinsics: Intrinsics) -> np.ndarray:
        """Pixel coordinates (n, 2) of world points; NaN behind the camera."""
        c = self.to_camera(points)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = intrinsics.fx * c[:, 0] / c[:, 2] + intrinsics.cx
            v = intrinsics.fy * c[:, 1] / c[:, 2] + intrinsics.cy
        behind = c[:, 2] <= 0
        u[behind] = np.nan
        v[behind] = np.nan
        return np.stack([u, v], axis=1)

    def unproject(self, uv, ranges, intrinsics: Intrinsics) -> np.ndarray:
        """World points (n, 3) of pixels ``uv`` (n, 2) at LIDAR ``ranges`` (n,) metres."""
        uv = np.atleast_2d(np.asarray(uv, dtype=np.float64))
        d = np.stack([(uv[:, 0] - intrinsics.cx) / intrinsics.fx,
                      (uv[:, 1] - intrinsics.cy) / intrinsics.fy, np.ones(len(uv))], axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.asarray(self.position) + (d * np.asarray(ranges)[:, None]) @ self.rotation.T

    def as_dict(self) -> dict:
        """Return the pose as plain data (metres; attitude quaternion) for truth files."""
        return dict(position=list(self.position), attitude=list(self.attitude))


def look_at(position, target, up=(0.0, 0.0, 1.0)) -> Pose:
    """Pose at ``position`` looking at ``target``; ``up`` is world-up (image up, roughly).

    When the view is parallel to ``up`` (e.g. a nadir camera), north (+y) serves as up, so
    image up points north.

    >>> p = look_at((0, 0, 100), (0, 0, 0))
    >>> np.round(p.rotation, 6).tolist()
    [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]
    """
    p = np.asarray(position, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - p
    if np.linalg.norm(z) == 0:
        raise InvalidParameterError("look-at target coincides with the camera position")
    z /= np.linalg.norm(z)
    u = np.asarray(up, dtype=np.float64)
    x = np.cross(z, u)
    if np.linalg.norm(x) < 1e-9 * max(1.0, float(np.linalg.norm(u))):
        x = np.cross(z, (0.0, 1.0, 0.0))
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(z, (1.0, 0.0, 0.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z], axis=1)
    return Pose(tuple(p), tuple(quat_from_matrix(r)))
