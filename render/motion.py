"""Motion during the exposure: blur from the camera's (and body's) motion, rolling shutter.

A frame's time ``t0`` is the start of the exposure of its first row. Between ``t0`` and the end
of the last row's exposure the camera moves with constant linear velocity ``v`` (m/s, world
frame) and turns with constant angular velocity ``omega`` (rad/s, world frame), and a body
spins with ``body_omega``::

    position(t) = position(t0) + v (t - t0)
    R_WC(t) = Rot(omega (t - t0)) R_WC(t0)          (Rot: the rotation vector's rotation)

Row r of a sensor with line time ``line_time`` (s, 0: global shutter) integrates over
``[t0 + r line_time, t0 + r line_time + exposure_time]``. The renderer draws the scene at N
sub-frame times spread evenly over the whole span (mid-points of N equal intervals) and each
row averages the sub-frames weighted by how much of their interval falls inside its own window
(with a rolling shutter each sub-frame shades only the rows that use it).
N is chosen so that no image point moves more than :data:`MAX_STEP_PIXELS` between sub-frames
(estimated from the velocities, the nearest range and the focal length), capped by
``max_samples``; a still camera with a global shutter, or one whose image moves less than that
during the exposure, takes the frame time's render alone.

Truth: :meth:`Motion.pose_at` gives the pose at any time, and :func:`row_time` the mid-exposure
time of a row, where the row's image is centred; the run directory stores the motion with each
frame (:class:`render.rundir.FrameTruth`). Velocities come from the trajectory
(:func:`trajectory_velocities`: central differences between neighbouring frames) or are set
per request (``[motion]`` velocity and angular_velocity).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from render.camera import Pose, quat_from_matrix, quat_to_matrix
from terrain.core.checks import check_keys
from terrain.core.errors import InvalidParameterError

if TYPE_CHECKING:
    from render.renderer import Frame, Lighting, Renderer, RenderOptions, View
    from render.scene import Scene
    from render.sensor import Sensor

__all__ = ["MAX_STEP_PIXELS", "Motion", "render_exposure", "rotation_vector_matrix",
           "row_time", "trajectory_velocities"]

log = logging.getLogger(__name__)

#: Largest image motion (pixels) between two sub-frames of a blurred exposure.
MAX_STEP_PIXELS = 0.5


def rotation_vector_matrix(rv) -> np.ndarray:
    """(3, 3) rotation by the rotation vector ``rv`` (axis * angle, radians; Rodrigues)."""
    rv = np.asarray(rv, dtype=np.float64)
    a = float(np.linalg.norm(rv))
    if a < 1e-15:
        return np.eye(3)
    k = rv / a
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(a) * kx + (1 - math.cos(a)) * kx @ kx


def _rotation_vector(r: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (inverse of :func:`rotation_vector_matrix`)."""
    c = (np.trace(r) - 1) / 2
    a = math.acos(max(-1.0, min(1.0, c)))
    if a < 1e-12:
        return np.zeros(3)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return v / (2 * math.sin(a)) * a


def _vec3(v, name):
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidParameterError(f"motion {name} must be 3 finite numbers; got {v!r}")
    return tuple(a.tolist())


@dataclass(frozen=True)
class Motion:
    """Velocities held during one exposure (see the module docstring).

    ``velocity`` m/s and ``angular_velocity`` rad/s of the camera, ``body_angular_velocity``
    rad/s of the body (asteroid spin), all world frame; ``samples``: sub-frames per exposure
    (0: automatic); ``max_samples``: the cap of the automatic choice.
    """

    velocity: tuple = (0.0, 0.0, 0.0)
    angular_velocity: tuple = (0.0, 0.0, 0.0)
    body_angular_velocity: tuple = (0.0, 0.0, 0.0)
    samples: int = 0
    max_samples: int = 64

    def __post_init__(self):
        for name in ("velocity", "angular_velocity", "body_angular_velocity"):
            object.__setattr__(self, name, _vec3(getattr(self, name), name))
        for name, lo in (("samples", 0), ("max_samples", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo or v > 4096:
                raise InvalidParameterError(
                    f"motion {name} must be an integer in [{lo}, 4096]; got {v!r}")
            object.__setattr__(self, name, int(v))

    @classmethod
    def from_mapping(cls, mapping) -> Motion:
        """Build the motion from a table (a scenario's ``[motion]`` less ``blur``, or a request).

        Unknown keys are errors naming the nearest valid key.
        """
        return cls(**check_keys(mapping, set(cls.__dataclass_fields__), "motion"))

    @property
    def still(self) -> bool:
        """Whether nothing moves during the exposure (no velocity, no rotation)."""
        return not any(np.any(np.asarray(v)) for v in (
            self.velocity, self.angular_velocity, self.body_angular_velocity))

    def pose_at(self, pose: Pose, dt: float) -> Pose:
        """Return the camera pose ``dt`` seconds after ``pose``."""
        p = np.asarray(pose.position) + np.asarray(self.velocity) * dt
        r = rotation_vector_matrix(np.asarray(self.angular_velocity) * dt) @ pose.rotation
        return Pose(tuple(p), tuple(quat_from_matrix(r)))

    def body_rotation_at(self, quaternion, dt: float) -> tuple:
        """Return the body rotation R_WB ``dt`` seconds after ``quaternion``."""
        r = rotation_vector_matrix(np.asarray(self.body_angular_velocity) * dt) \
            @ quat_to_matrix(quaternion)
        return tuple(quat_from_matrix(r).tolist())

    def as_dict(self) -> dict:
        """Return the motion as plain data (m/s and rad/s) for truth files."""
        return dict(velocity=list(self.velocity), angular_velocity=list(self.angular_velocity),
                    body_angular_velocity=list(self.body_angular_velocity))

    def image_speed(self, intrinsics, nearest_range: float, body_radius: float = 0.0) -> float:
        """Return an upper estimate of how fast (pixels/s) an image point moves."""
        f = max(intrinsics.fx, intrinsics.fy)
        d = max(nearest_range, 1e-6)
        return f * (float(np.linalg.norm(self.angular_velocity))
                    + float(np.linalg.norm(self.velocity)) / d
                    + float(np.linalg.norm(self.body_angular_velocity)) * body_radius / d)


def row_time(row, exposure_time: float, line_time: float):
    """Mid-exposure time (s after the frame time) of a row: ``row line_time + exposure/2``."""
    return np.asarray(row, dtype=np.float64) * line_time + 0.5 * exposure_time


def trajectory_velocities(samples, index: int) -> Motion:
    """Return the velocities at frame ``index`` of a trajectory.

    Central differences between its neighbouring frames (one-sided at the ends; zero for a
    single frame).
    """
    n = len(samples)
    if n < 2:
        return Motion()
    a, b = max(index - 1, 0), min(index + 1, n - 1)
    dt = samples[b].time - samples[a].time
    if dt <= 0:
        return Motion()
    pa, pb = samples[a].pose, samples[b].pose
    v = (np.asarray(pb.position) - np.asarray(pa.position)) / dt
    w = _rotation_vector(pb.rotation @ pa.rotation.T) / dt
    bw = _rotation_vector(quat_to_matrix(samples[b].body_rotation)
                          @ quat_to_matrix(samples[a].body_rotation).T) / dt
    return Motion(tuple(v), tuple(w), tuple(bw))


def _row_weights(h, times, step, exposure_time, line_time):
    """(h, n) weights: the share of each sub-frame's interval inside each row's window."""
    start = np.arange(h)[:, None] * line_time
    width = max(exposure_time, 1e-12 * max(step, 1e-12))
    lo = np.maximum(start, times[None, :] - step / 2)
    hi = np.minimum(start + width, times[None, :] + step / 2)
    w = np.maximum(hi - lo, 0.0)
    total = w.sum(axis=1, keepdims=True)
    empty = total[:, 0] <= 0
    if np.any(empty):  # an instantaneous row between sub-frames: the nearest one
        nearest = np.abs(times[None, :] - (start[empty] + width / 2)).argmin(axis=1)
        w[empty] = 0.0
        w[np.flatnonzero(empty), nearest] = 1.0
        total = w.sum(axis=1, keepdims=True)
    return w / total


def render_exposure(renderer: Renderer, scene: Scene, view: View, lighting: Lighting,
                    options: RenderOptions, sensor: Sensor, motion: Motion,
                    body_rotation: Sequence[float] = (1.0, 0.0, 0.0, 0.0)
                    ) -> tuple[np.ndarray, Frame, dict]:
    """Render the I/F a sensor integrates while the camera moves (see the module docstring).

    Parameters
    ----------
    renderer : render.renderer.Renderer
        Renders the frame and its sub-frames.
    scene : render.scene.Scene
        What is seen; its body turns by ``motion.body_angular_velocity`` (its ``reach`` is
        the lever arm that sets how far the spin moves the image).
    view : render.renderer.View
        The camera at the frame time.
    lighting : render.renderer.Lighting
        The sun and reflectance.
    options : render.renderer.RenderOptions
        Quality settings.
    sensor : render.sensor.Sensor
        Integration time and line time (rolling shutter).
    motion : Motion
        Velocities held during the exposure, and the sub-frame count.
    body_rotation : (4,) float
        R_WB [w, x, y, z] at the frame time.

    Returns
    -------
    radiance : (h, w) float32
        The integrated I/F.
    frame : render.renderer.Frame
        The frame at the frame time (range, normals and truth belong to it).
    info : dict
        The sub-frame count (``samples``) and their times (``times``, s from the start).
    """
    from render.renderer import View

    t_exp = sensor.integration_time
    line = sensor.line_time
    k = view.intrinsics
    span = (k.height - 1) * line + t_exp
    scene.set_body_rotation(body_rotation)
    first = renderer.render(scene, view, lighting, options)
    if span <= 0 or (motion.still and line == 0):
        return first.radiance, first, {"samples": 1, "times": [0.0]}
    n = motion.samples
    if n == 0:
        finite = first.range[np.isfinite(first.range)]
        nearest = float(finite.min()) if finite.size else 1.0
        moved = motion.image_speed(k, nearest, scene.reach) * span
        n = int(min(max(math.ceil(moved / MAX_STEP_PIXELS), 1), motion.max_samples))
        if moved / n > MAX_STEP_PIXELS:
            log.warning("motion blur: the image moves about %.1f px in the exposure; %d "
                        "sub-frames (max_samples) leave %.2f px between them", moved, n,
                        moved / n)
        if line > 0:
            n = max(n, 2)
    if n == 1 and line == 0:  # the image moves < MAX_STEP_PIXELS: the frame time's render
        return first.radiance, first, {"samples": 1, "times": [0.0]}
    step = span / n
    times = (np.arange(n) + 0.5) * step
    weights = _row_weights(k.height, times, step, t_exp, line)
    out = np.zeros((k.height, k.width), dtype=np.float64)
    for j, t in enumerate(times):
        if not np.any(weights[:, j]):
            continue
        scene.set_body_rotation(motion.body_rotation_at(body_rotation, float(t)))
        used = np.flatnonzero(weights[:, j])
        rows = (int(used[0]), int(used[-1]) + 1) if line > 0 else None
        sub = renderer.render(scene, View(motion.pose_at(view.pose, float(t)), k,
                                          view.time + float(t)), lighting, options, rows=rows)
        if rows is None:
            out += weights[:, j:j + 1] * sub.radiance
        else:
            out[rows[0]:rows[1]] += weights[rows[0]:rows[1], j:j + 1] \
                * sub.radiance[rows[0]:rows[1]]
    scene.set_body_rotation(body_rotation)
    return out.astype(np.float32), first, {"samples": n, "times": times.tolist()}
