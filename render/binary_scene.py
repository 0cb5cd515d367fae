"""A binary asteroid as one scene: two bodies on their mutual orbit, drawn in one pass.

The primary and the secondary are each a body scene of their own (an
:class:`render.asteroid_scene.AsteroidScene` for a native ``.npz``, a
:class:`render.mesh_scene.MeshScene` for a shape file), modelled about their own centres.
Every frame, the binary places them where the mutual orbit puts them at the view's time
(:class:`render.orbit.MutualOrbit`, barycentre at the world origin) and turns them as their
spins say (:class:`render.orbit.Spin`; a secondary without one is tidally locked): each body
plans its own batches (culling, levels of detail, boulders) for the camera seen from its
centre, and the binary offsets them to the body's centre. One camera pass draws both into
one depth buffer, so each hides the other where it is in front.

Shadows: one map per body, fitted to that body (so each keeps the resolution a single body's
map has) and drawn with both bodies as casters, so the secondary's shadow falls on the primary
(an eclipse of the primary's surface) and the primary's on the secondary (the secondary in
eclipse) through the ordinary shadow-map lookup (:func:`render.scene.render_shadow_map`). The
other body is left out of a map whose window its bounding sphere misses, or which it lies
wholly behind as seen from the sun: it can cast nothing there.

Truth: :meth:`BinaryScene.body_poses` gives each body's centre and rotation at a time, and
:meth:`BinaryScene.body_ids` which body each pixel of a frame shows (0 sky, 1 primary, 2
secondary), from the frame's range: the surface point a pixel sees is assigned to the body
whose surface it lies on (for a star-shaped native body, the distance to its surface along
the point's direction; for a mesh body, the distance to its nearest surface vertex; for any
other mesh, the distance to its bounding sphere).

The world frame is inertial; the binary ignores a trajectory's body rotation
(:meth:`set_body_rotation`): time alone moves and turns its bodies. Imposters are not used: a
distant binary is drawn as geometry at its coarsest levels of detail. A native body is shaded
with its cube map of its finest normals as a single body is (``render/shaders/scene.frag``
looks it up by the body-frame direction from the batch's model offset, the body's centre).

Scattered light: with ``RenderOptions.scattering`` on, each body has its own (the body
scene's, :mod:`render.body_scattering`) plus the light the other body's sunlit surface sends
it (:func:`render.body_scattering.mutual_irradiance` between the two patch meshes, placed as
the frame's time puts them; recomputed every frame, without looking for what lies between).
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from render.camera import Pose, quat_to_matrix
from render.orbit import MutualOrbit, Spin
from render.scene import (
    BODY_SHADOW_BIAS,
    BODY_SHADOW_MARGIN,
    DrawBatch,
    FrameState,
    Gpu,
    Imposter,
    ShadowMap,
    far_plane,
    light_basis,
    render_shadow_map,
)
from terrain.core.errors import InvalidParameterError

if TYPE_CHECKING:
    from render.renderer import Frame, Lighting, RenderOptions, View

__all__ = ["BODY_NAMES", "SKY", "BinaryScene", "load_body"]

log = logging.getLogger(__name__)

#: Body ids of the body-id image: 0 is the sky, then the bodies in this order.
BODY_NAMES = ("primary", "secondary")
SKY = 0
#: Samples of one orbit the binary's reach is measured at (the largest distance a body's
#: centre comes from the barycentre is at apoapsis; the samples bound it for any elements).
REACH_SAMPLES = 256


class BodyScene(Protocol):
    """What the binary needs of each body (a body scene centred at its own origin)."""

    reach: float
    rotation: np.ndarray
    extra_scatter: np.ndarray | None

    def body_light(self) -> Any:
        """Give the body's scattered light (render.body_scattering.BodyLight) or None."""
        ...

    def set_body_rotation(self, quaternion: Any) -> None:
        """Set R_WB for the next frame."""
        ...

    def frame_state(self, view: View, lighting: Lighting, options: RenderOptions, gpu: Gpu,
                    imposter: Imposter | None) -> FrameState:
        """Plan the body's batches for a view relative to its centre."""
        ...

    def shadow_casters(self, gpu: Gpu, extent: float, size: int) -> list[DrawBatch]:
        """Depth batches casting the body's shadow into a map of ``extent`` metres."""
        ...


def load_body(body: Any, *, boulders: bool = True) -> Any:
    """Load one body of a binary: a native ``.npz``, a shape file, or a ready body scene.

    Parameters
    ----------
    body : str, pathlib.Path, asteroid.body.Body, NativeModel or a body scene
        A native body as ``craterscape asteroid build`` writes it (``.npz``: a
        latitude/longitude body, or a mesh body drawn as a
        :class:`~render.mesh_scene.MeshBodyScene` with its boulders), a closed mesh
        (``.ply``, ``.obj``, ``.stl``, ``.glb``; metres, centred on the body), a loaded body,
        or an :class:`~render.asteroid_scene.AsteroidScene` / :class:`~render.mesh_scene.MeshScene`.
    boulders : bool
        Draw a native body's boulders.

    Returns
    -------
    AsteroidScene or MeshScene
        Centred at its own origin.
    """
    from render.asteroid_scene import AsteroidScene
    from render.mesh_scene import MeshBodyScene, MeshScene, is_mesh_body

    if isinstance(body, (AsteroidScene, MeshScene)):
        scene = body
    elif isinstance(body, (str, Path)) and Path(body).suffix.lower() != ".npz":
        from asteroid.meshio.read import read_mesh

        vertices, faces = read_mesh(Path(body))
        scene = MeshScene(vertices, faces)
    elif isinstance(body, (str, Path)) and is_mesh_body(body):  # a mesh body's .npz
        scene = MeshBodyScene(Path(body), boulders=boulders)
    else:
        scene = AsteroidScene(body, boulders=boulders, imposter_pixels=0.0)
    if np.any(np.asarray(getattr(scene, "origin", np.zeros(3))) != 0):
        raise InvalidParameterError("a binary's body must be modelled about its own centre "
                                    "(a mesh scene with centre (0, 0, 0))")
    return scene


class BinaryScene:
    """A primary and a secondary on their mutual orbit (see the module docstring).

    Parameters
    ----------
    primary, secondary : path, body or body scene
        The two bodies (:func:`load_body`).
    orbit : render.orbit.MutualOrbit, optional
        Their mutual orbit (default: Didymos-Dimorphos).
    primary_spin : render.orbit.Spin, optional
        The primary's spin (default: :class:`render.orbit.Spin`'s, Didymos's 2.26 h about +z).
    secondary_spin : render.orbit.Spin, optional
        The secondary's spin; None (default): tidally locked.
    boulders : bool
        Draw native bodies' boulders.

    Attributes
    ----------
    reach : float, metres
        How far any part of either body comes from the barycentre.
    """

    kind = "binary"

    def __init__(self, primary: Any, secondary: Any, *, orbit: MutualOrbit | None = None,
                 primary_spin: Spin | None = None, secondary_spin: Spin | None = None,
                 boulders: bool = True) -> None:
        self.bodies = (load_body(primary, boulders=boulders),
                       load_body(secondary, boulders=boulders))
        self.orbit = orbit if orbit is not None else MutualOrbit()
        self.spins = (primary_spin if primary_spin is not None else Spin(), secondary_spin)
        self.origin = np.zeros(3)
        r1, r2 = (float(b.reach) for b in self.bodies)
        if not self.orbit.periapsis_distance > r1 + r2:
            raise InvalidParameterError(
                f"the binary's bodies would touch: their centres come within "
                f"{self.orbit.periapsis_distance:.6g} m of each other, and they reach "
                f"{r1:.6g} m and {r2:.6g} m; widen the orbit (semi_major_axis, eccentricity)")
        t = np.linspace(0.0, self.orbit.period, REACH_SAMPLES, endpoint=False)
        rel = np.linalg.norm(self.orbit.relative(t), axis=1).max()
        q = self.orbit.mass_ratio
        self.reach = float(max(q / (1 + q) * rel + r1, rel / (1 + q) + r2))
        self._shadows: list[ShadowMap | None] = [None, None]

    # ------------------------------------------------------------------ geometry
    def body_poses(self, t: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Centre and rotation of each body at time ``t``.

        Parameters
        ----------
        t : float, seconds
            From the scenario's start.

        Returns
        -------
        list of (centre, quaternion)
            Per body (:data:`BODY_NAMES` order): centre (3,) float64 m, world frame, and
            R_WB (4,) [w, x, y, z].
        """
        centres = self.orbit.positions(t)
        quats = [self.spins[0].rotation(t),
                 self.spins[1].rotation(t) if self.spins[1] is not None
                 else self.orbit.locked_rotation(t)]
        return [(np.asarray(c, dtype=np.float64), np.asarray(q, dtype=np.float64))
                for c, q in zip(centres, quats, strict=True)]

    def bodies_truth(self, t: float) -> list[dict]:
        """Give the bodies' truth at time ``t``: id, name, centre and attitude of each.

        Returns
        -------
        list of dict
            ``{"id", "name", "position": [x, y, z] (m, world), "attitude": [w, x, y, z]
            (R_WB), "reach": m}``.
        """
        return [{"id": i + 1, "name": BODY_NAMES[i], "position": c.tolist(),
                 "attitude": q.tolist(), "reach": float(self.bodies[i].reach)}
                for i, (c, q) in enumerate(self.body_poses(t))]

    def describe(self) -> dict:
        """Return the orbit and the spins as plain data (a run's manifest records them).

        Returns
        -------
        dict
            ``orbit`` (:meth:`render.orbit.MutualOrbit.as_dict`), ``primary_spin`` and
            ``secondary_spin`` (:meth:`render.orbit.Spin.as_dict`, or ``"tidally locked"``).
        """
        second = self.spins[1]
        return {"orbit": self.orbit.as_dict(), "primary_spin": self.spins[0].as_dict(),
                "secondary_spin": "tidally locked" if second is None else second.as_dict()}

    def set_body_rotation(self, quaternion: Any) -> None:
        """Ignored: each body turns by its own spin at the view's time (module docstring).

        Parameters
        ----------
        quaternion : (4,) float
            A trajectory's body rotation (unused).
        """

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World-frame bounding box: the cube of the binary's reach about the barycentre.

        Returns
        -------
        lo, hi : (3,) float64, metres
        """
        return -np.full(3, self.reach), np.full(3, self.reach)

    def contains(self, point: Any, t: float) -> bool:
        """Whether a world point lies inside either body at time ``t``.

        A native body is star-shaped about its centre: inside means nearer its centre than
        its surface in that direction; a mesh body (:class:`render.mesh_scene.MeshBodyScene`)
        by its winding number, exact whatever its shape; any other mesh by its bounding
        sphere.

        Parameters
        ----------
        point : (3,) float, metres, world frame
        t : float, seconds

        Returns
        -------
        bool
        """
        from render.mesh_scene import MeshBodyScene

        p = np.asarray(point, dtype=np.float64).reshape(1, 3)
        for body, (c, q) in zip(self.bodies, self.body_poses(t), strict=True):
            if isinstance(body, MeshBodyScene):
                if body.contains(p[0] - c, q):
                    return True
            elif self._surface_gap(body, p, c, q)[0] < 0:
                return True
        return False

    @staticmethod
    def _surface_gap(body, points: np.ndarray, centre: np.ndarray, quat: np.ndarray
                     ) -> np.ndarray:
        """Distance of world points from a body's surface along their direction (m; < 0 in).

        A mesh body (:class:`render.mesh_scene.MeshBodyScene`) gives its distance to the
        nearest surface vertex instead (unsigned: the body-id image needs only which surface
        is nearer).
        """
        from render.mesh_scene import MeshBodyScene

        rel = points - centre
        if isinstance(body, MeshBodyScene):
            return body.surface_distance(rel @ quat_to_matrix(quat))
        dist = np.linalg.norm(rel, axis=1)
        surface = getattr(getattr(body, "body", None), "surface_radius", None)
        if surface is None:
            return dist - float(body.reach)
        local = rel @ quat_to_matrix(quat)  # R_WB^T p: body frame
        safe = np.where(dist[:, None] > 0, local / np.maximum(dist, 1e-300)[:, None],
                        np.array([0.0, 0.0, 1.0]))
        return dist - np.asarray(surface(safe), dtype=np.float64)

    def body_ids(self, view: View, frame: Frame) -> np.ndarray:
        """Which body each pixel of a frame shows: 0 sky, 1 primary, 2 secondary.

        The point each pixel's range puts on a surface belongs to the body whose surface
        lies nearest to it (module docstring); bodies that never touch are told apart
        exactly.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera and time.
        frame : render.renderer.Frame
            Its range image.

        Returns
        -------
        (h, w) uint8
        """
        k = view.intrinsics
        rng = np.asarray(frame.range, dtype=np.float64)
        ids = np.zeros(rng.shape, dtype=np.uint8)
        hit = np.isfinite(rng)
        if not hit.any():
            return ids
        rays = k.rays().reshape(k.height, k.width, 3)[hit] @ view.pose.rotation.T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        pts = np.asarray(view.pose.position, dtype=np.float64) + rays * rng[hit][:, None]
        poses = self.body_poses(view.time)
        # bounding spheres first: a point inside only one body's sphere is that body's
        near = np.stack([np.linalg.norm(pts - c, axis=1) - float(b.reach)
                         for b, (c, _) in zip(self.bodies, poses, strict=True)], axis=1)
        label = np.argmin(near, axis=1)
        both = np.flatnonzero((near <= 0).all(axis=1))
        if both.size:  # inside both spheres: the nearer surface decides
            gaps = np.stack([np.abs(self._surface_gap(b, pts[both], c, q))
                             for b, (c, q) in zip(self.bodies, poses, strict=True)], axis=1)
            label[both] = np.argmin(gaps, axis=1)
        ids[hit] = (label + 1).astype(np.uint8)
        return ids

    # ------------------------------------------------------------------ per frame
    def imposter(self, view: View, options: RenderOptions) -> Imposter | None:
        """Never: the binary is drawn as geometry (module docstring).

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        options : render.renderer.RenderOptions
            The frame's quality settings.

        Returns
        -------
        None
        """
        return None

    def frame_state(self, view: View, lighting: Lighting, options: RenderOptions, gpu: Gpu,
                    imposter: Imposter | None) -> FrameState:
        """Plan one frame: both bodies placed and turned at the view's time, with their maps.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera and time.
        lighting : render.renderer.Lighting
            The sun (the shadow maps follow it).
        options : render.renderer.RenderOptions
            Level of detail target, shadows, geomorphing.
        gpu : render.scene.Gpu
            Uploads, vertex arrays and the shadow maps.
        imposter : render.scene.Imposter or None
            Always None (:meth:`imposter`).

        Returns
        -------
        render.scene.FrameState
            The primary's batches, then the secondary's; ``drawn`` holds each body's facts
            under its name and the bodies' truth under ``"bodies"``.
        """
        from dataclasses import replace

        from render.renderer import View as _View

        poses = self.body_poses(view.time)
        for body, (_, q) in zip(self.bodies, poses, strict=True):
            body.set_body_rotation(q)
        self._mutual_light(poses, lighting if options.scattering else None)
        cam = np.asarray(view.pose.position, dtype=np.float64)
        own = replace(options, shadows=False)  # the binary draws the maps, with both casters
        batches: list[DrawBatch] = []
        owner: list[int] = []  # which body each batch belongs to
        drawn: dict = {"triangles": 0, "bodies": self.bodies_truth(view.time)}
        far = 0.0
        for i, (body, (c, _)) in enumerate(zip(self.bodies, poses, strict=True)):
            local = _View(Pose(tuple((cam - c).tolist()), view.pose.attitude),
                          view.intrinsics, view.time)
            state = body.frame_state(local, lighting, own, gpu, None)
            for batch in state.batches:
                # a normal cube is looked up by the direction from the body's centre (the
                # batch's model offset), so each body keeps its finest normals
                batch.model_offset = np.asarray(batch.model_offset, dtype=np.float64) + c
            batches.extend(state.batches)
            owner.extend([i] * len(state.batches))
            drawn[BODY_NAMES[i]] = state.drawn
            drawn["triangles"] += int(state.drawn.get("triangles", 0))
            far = max(far, float(np.linalg.norm(cam - c)) + float(body.reach))
        if options.shadows and lighting is not None:
            maps = self._shadow_maps(gpu, lighting, options, poses)
            for batch, i in zip(batches, owner, strict=True):
                batch.shadow = maps[i]
        return FrameState(batches, far_plane(far), drawn)

    def _mutual_light(self, poses, lighting) -> None:
        """Set each body's light from the other (None without ``lighting``)."""
        from render.body_scattering import mutual_irradiance

        lights: list[Any] = [body.body_light() if lighting is not None else None
                             for body in self.bodies]
        rots = [quat_to_matrix(q) for _, q in poses]
        for recv, src in ((0, 1), (1, 0)):
            if lights[recv] is None or lights[src] is None:
                self.bodies[recv].extra_scatter = None
                continue
            offset = rots[recv].T @ (np.asarray(poses[src][0]) - np.asarray(poses[recv][0]))
            self.bodies[recv].extra_scatter = mutual_irradiance(
                lights[recv], lights[src], rots[recv].T @ rots[src], offset,
                rots[src].T @ np.asarray(lighting.sun, dtype=np.float64), lighting.albedo)

    def _shadow_maps(self, gpu, lighting, options, poses) -> list[ShadowMap]:
        size = options.shadow_size
        basis = light_basis(lighting.sun)  # rows: light-space x, y and the light's direction
        spheres = [(basis @ c, float(b.reach))
                   for b, (c, _) in zip(self.bodies, poses, strict=True)]

        def casters(receiver, extent, window):
            # a body casts into the receiver's map where its sphere meets the map's window
            # and it is not wholly behind the receiver from the sun
            x0, y0, x1, y1 = window
            zr = spheres[receiver][0][2] + spheres[receiver][1]
            out = []
            for j, (body, (c, _)) in enumerate(zip(self.bodies, poses, strict=True)):
                (x, y, z), r = spheres[j]
                if j != receiver and (x + r < x0 or x - r > x1 or y + r < y0 or y - r > y1
                                      or z - r > zr):
                    continue
                for batch in body.shadow_casters(gpu, extent, size):
                    batch.model_offset = np.asarray(batch.model_offset, dtype=np.float64) + c
                    out.append(batch)
            return out

        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                            for sz in (-1, 1)], dtype=np.float64)
        cubes = [c + corners * float(b.reach)
                 for b, (c, _) in zip(self.bodies, poses, strict=True)]
        both = np.concatenate(cubes)
        maps = []
        for i, body in enumerate(self.bodies):
            r = float(body.reach)
            shadow = render_shadow_map(
                gpu, self._shadows[i], size, lighting.sun, cubes[i], both,
                margin=BODY_SHADOW_MARGIN * r, bias=BODY_SHADOW_BIAS,
                draw=functools.partial(_casters_of, casters, i))
            self._shadows[i] = shadow
            maps.append(shadow)
        return maps


def _casters_of(casters, receiver: int, extent: float, window) -> list[DrawBatch]:
    """Give what casts into receiver's map: ``casters(receiver, extent, window)``."""
    return casters(receiver, extent, window)
