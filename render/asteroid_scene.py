"""An asteroid body (native ``.npz``) with its boulders as a scene.

Body: the 6M^2+2 mesh of :mod:`asteroid.sphere`, its triangles ordered by the paper's patches
(:class:`asteroid.patches.PatchTree`, at most K strips of at most K triangles, each with a
bounding sphere), so a frame draws only the patches inside the view frustum. Coarser levels of
detail (magnitude M/2, M/4, ... down to :data:`MIN_MAGNITUDE`) resample the body's surface; a
frame uses the coarsest whose vertex spacing stays below ``RenderOptions.lod_pixels`` on
screen.

Boulders: every boulder exists at each refinement level of its icosahedron
(:mod:`asteroid.boulders`); a frame draws each boulder at the coarsest level whose edges stay
below ``lod_pixels`` at its distance, skips boulders smaller than :data:`MIN_BOULDER_PIXELS`
and culls the rest against the frustum.

Imposter: when the body spans fewer than ``imposter_pixels`` pixels, the scene asks the
renderer for an imposter (:meth:`AsteroidScene.imposter`): the body is rendered once per
frame into a small texture by a camera at the same position looking at its centre, and that
texture stands for a camera-facing quad through the body's centre (the asteroid paper's
imposter), composited by the renderer (:mod:`render.imposter`: range and normals from the
imposter's nearest texel, so range stays the true range; radiance interpolated).

Seamless level of detail (the terrain's geomorphing, :mod:`render.terrain_scene`, carried
over): every body level but the coarsest carries, per vertex, the next coarser level's
surface along the vertex's direction (the flat triangle of magnitude M/2 that the ray from
the centre meets) and its interpolated normal; the vertex shader slides each vertex there as
its distance approaches the distance at which the planner switches to that level, over the
last :data:`MORPH_BAND` octave, so the switch itself changes nothing on screen (magnitude M/2's
vertices are a subset of M's, so the fully morphed mesh is the coarser one). Boulders
likewise: the vertices a refinement level adds slide to the midpoints of the edges they split
as the boulder nears the distance of the next coarser level, and at the coarsest level the
whole boulder shrinks to its centre as it nears :data:`MIN_BOULDER_PIXELS`, where it stops
being drawn. The imposter fades in: while the body spans between ``imposter_pixels`` and
:data:`IMPOSTER_FADE` times that, the frame is the geometry's with the imposter's radiance
blended in (weight 0 to 1 as the body shrinks; range and normals stay the geometry's).

Shading normals: with geomorphing on, the body is shaded with its finest level's normals
whatever level is drawn: a cube map (:data:`NORMAL_CUBE_SIZE` texels a side) holds, for each
body-frame direction from the centre, the normal interpolated on the finest triangle that
direction meets (the body is star-shaped about its centre), so the shading of the surface,
and every shading corner a tracker follows, stays on the surface while levels change; the
normal images are these normals too. Boulders keep their own.

Scattered light: with ``RenderOptions.scattering`` on, the sunlight the body scatters once
into itself (its shadows included) is computed on a patch mesh of magnitude
:data:`SCATTER_MAGNITUDE` for the body-frame sun (:mod:`render.body_scattering`: view
factors once, irradiance per sun direction on a one-degree lattice) and carried to each
level's vertices by direction (inside the patch triangle each direction meets), as a vertex
attribute the fragment stage adds as a Lambertian response. Boulders get none.

Shadows: one orthographic map fitted to the body's bounding sphere, whose projection depends
on the sun alone (never on the camera), with casters drawn at one level of detail chosen from
the map's texel size (never from the camera's distance), so nothing in the map changes as the
camera moves; the body's rotation under a fixed sun moves its shadows, as it must.

The world frame is inertial with the body's centre at the origin; the body turns by the
rotation set with :meth:`AsteroidScene.set_body_rotation`, R_WB, as the trajectory's spin
says.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from render.camera import Intrinsics, look_at, quat_to_matrix
from render.scene import (
    MIN_LOD_DISTANCE_M,
    DrawBatch,
    FrameState,
    Gpu,
    Imposter,
    Morph,
    ShadowMap,
    body_shadow_map,
    far_plane,
)
from render.terrain_buffers import half_floats
from terrain.core.errors import InvalidParameterError

if TYPE_CHECKING:
    from asteroid.body import Body, NativeModel
    from asteroid.boulders import Boulders
    from render.renderer import Lighting, RenderOptions, View

__all__ = ["IMPOSTER_FADE", "MIN_BOULDER_PIXELS", "MIN_MAGNITUDE", "MORPH_BAND", "AsteroidScene"]

log = logging.getLogger(__name__)

#: Coarsest body level of detail.
MIN_MAGNITUDE = 8
#: Boulders smaller than this on screen (pixels) are not drawn.
MIN_BOULDER_PIXELS = 0.5
#: Patch size K of the culling patches.
PATCH_K = 64
#: The imposter texture has this many texels per pixel the body spans ...
IMPOSTER_OVERSAMPLING = 3
#: ... and at least this many a side.
MIN_IMPOSTER_TEXELS = 8
#: A body is an imposter only while the camera is farther from its centre than this many
#: times its reach (closer, the body fills the view however few pixels the formula gives).
IMPOSTER_MIN_DISTANCE = 1.01
#: The imposter camera's half field of view is the body's angular radius times this, so the
#: limb stays inside its image with a texel or two to spare.
IMPOSTER_FOV_MARGIN = 1.02
#: Boulder levels of detail kept on the GPU for every boulder; finer levels are built for the
#: boulders that need them, frame by frame.
COARSE_BOULDER_LEVELS = 2
#: Octaves of distance over which a vertex morphs toward the next coarser level (as
#: :data:`render.terrain_scene.MORPH_BAND`).
MORPH_BAND = 1.0
#: The imposter fades in while the body spans from this many times ``imposter_pixels`` down
#: to ``imposter_pixels``.
IMPOSTER_FADE = 1.5
#: Texels per side of each face of the cube map of the body's finest normals.
NORMAL_CUBE_SIZE = 512
#: Shadow casters are drawn at the coarsest body level whose vertex spacing stays below this
#: many shadow-map texels.
SHADOW_CELL_TEXELS = 2.0
#: An icosahedron of radius r refined l times has edges of about this times ``r / 2^l`` (the
#: unrefined edge is ``r / sin(2 pi / 5)`` = 1.0515 r): boulder levels are chosen by it.
ICOSAHEDRON_EDGE = 1.05
#: The body's scattered light is computed on the sphere mesh of this magnitude (6 M^2 + 2
#: receivers; the finest level where that is coarser): scattered light is smooth.
SCATTER_MAGNITUDE = 24


@dataclass(eq=False)
class _BodyLod:
    magnitude: int
    spacing: float
    triangles: int
    vbo: object
    ibo: object
    centres: np.ndarray   # (patches, 3) body frame
    radii: np.ndarray
    firsts: np.ndarray
    counts: np.ndarray
    vaos: dict
    abo: object = None    # per-vertex albedo factors (float32) or None
    morph: object = None   # per-vertex targets on the next coarser level (None: coarsest)
    cube: object = None    # the finest level's normals by direction (finest level only)
    sbo: Any = None        # per-vertex scattered irradiance (float32), rewritten per sun
    scatter_at: Any = None  # (n, patch vertices) sparse interpolation from the patch mesh
    scatter_key: Any = None  # the patch irradiances the buffer holds (own, extra)


@dataclass(eq=False)
class _BoulderLevel:
    level: int
    vbo: object
    ibo: object
    faces_per: int
    vaos: dict
    morph: object = None
    abo: object = None    # boulders carry no albedo factors (as _BodyLod.abo)


class AsteroidScene:
    """An asteroid ready to render (see the module docstring).

    Parameters
    ----------
    body : str, pathlib.Path, asteroid.body.NativeModel or asteroid.body.Body
        A native ``.npz`` (with its boulders), a loaded one, or a bare body.
    boulders : bool
        Draw the boulders stored with the body.
    imposter_pixels : float
        Below this on-screen diameter (pixels) the body is drawn as an imposter.
    albedo : (n,) float or path of a ``.npy``, optional
        Albedo factor per body vertex (multiplies the albedo, or Hapke's w).

    Attributes
    ----------
    reach : float, metres
        Bounding radius about the centre, boulders included.
    """

    kind = "asteroid"

    def __init__(self, body: str | Path | NativeModel | Body, *, boulders: bool = True,
                 imposter_pixels: float = 24.0,
                 albedo: np.ndarray | str | Path | None = None) -> None:
        from asteroid.body import Body, NativeModel, load_native
        from asteroid.build import boulders_of

        native = None
        if isinstance(body, (str, Path)):
            native = load_native(Path(body))
            body = native.body
        elif isinstance(body, NativeModel):
            native = body
            body = native.body
        if not isinstance(body, Body):
            raise InvalidParameterError(
                f"an asteroid scene needs a native .npz, a NativeModel or a Body; got "
                f"{type(body).__name__}")
        if not imposter_pixels >= 0:
            raise InvalidParameterError(f"imposter_pixels must be >= 0; got {imposter_pixels}")
        self.body = body
        self.boulders = boulders_of(native) if (boulders and native is not None) else None
        self.imposter_pixels = float(imposter_pixels)
        self.origin = np.zeros(3)
        self.rotation = np.eye(3)
        self.reach = float(body.radii.max())
        if self.boulders is not None and len(self.boulders):
            c = self.boulders.catalog
            centres = np.column_stack([c.x_m, c.y_m, c.z_m])
            self.reach = max(self.reach, float(np.linalg.norm(centres, axis=1).max()
                                               + c.diameter_m.max()))
        self._gpu: dict = {}
        self._shadow: ShadowMap | None = None
        self._fine: list = []
        self._light: Any = None  # render.body_scattering.BodyLight, built on first use
        #: Scattered light from elsewhere (E / F per patch vertex of :meth:`body_light`, e.g.
        #: a binary's other body), added to the body's own; None: none.
        self.extra_scatter: np.ndarray | None = None
        self.albedo: np.ndarray | None = None
        if albedo is not None:
            if isinstance(albedo, (str, Path)):
                albedo = np.load(Path(albedo))
            a = np.asarray(albedo, dtype=np.float64).reshape(-1)
            if a.shape != (body.mesh.n_vertices,) or not np.all(np.isfinite(a)) or a.min() < 0:
                raise InvalidParameterError(
                    f"an asteroid albedo map needs one finite value >= 0 per body vertex "
                    f"({body.mesh.n_vertices}); got {a.shape}")
            self.albedo = a

    def _albedo_on(self, mesh):
        """Carry the body's albedo factors to another level's vertices (or None).

        Each is interpolated inside the fine triangle holding its direction.
        """
        if self.albedo is None:
            return None
        if mesh.magnitude == self.body.magnitude:
            return self.albedo.astype(np.float32)
        _, idx, w = self.body.mesh.locate(mesh.directions())
        return ((self.albedo[idx] * w).sum(axis=1) / w.sum(axis=1)).astype(np.float32)

    # ------------------------------------------------------------------ geometry
    def set_body_rotation(self, quaternion: Any) -> None:
        """Set the body's rotation for the next frame.

        Parameters
        ----------
        quaternion : (4,) float
            R_WB as [w, x, y, z], body to world.
        """
        self.rotation = quat_to_matrix(quaternion)

    def to_world(self, points: npt.ArrayLike) -> np.ndarray:
        """Map body-frame points to the world frame with the current rotation.

        Parameters
        ----------
        points : (n, 3) float, metres
            Body-frame points.

        Returns
        -------
        (n, 3) float64, metres
            World-frame points.
        """
        return np.atleast_2d(points) @ self.rotation.T

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World-frame bounding box: the cube of the body's reach about its centre.

        Returns
        -------
        lo, hi : (3,) float64, metres
            Its smallest and largest corner.
        """
        return -np.full(3, self.reach), np.full(3, self.reach)

    # ------------------------------------------------------------------ GPU
    def _upload(self, gpu):
        ctx = gpu.context  # the key uploads are cached under
        cached = self._gpu.get(id(ctx))
        if cached is not None and cached[0] is ctx:
            return cached[1], cached[2]
        from asteroid.patches import PatchTree
        from asteroid.sphere import SphereMesh
        from render.mesh_scene import vertex_normals

        lods = []
        surfaces = []
        m = self.body.magnitude
        magnitudes = [m]
        while magnitudes[-1] // 2 >= MIN_MAGNITUDE:
            magnitudes.append(magnitudes[-1] // 2)
        for mag in magnitudes:
            mesh = SphereMesh(mag)
            if mag == m:
                radii = np.asarray(self.body.radii, dtype=np.float64)
            else:
                radii = self.body.surface_radius(mesh.directions())
            verts = mesh.directions() * radii[:, None]
            faces = mesh.faces()
            tree = PatchTree.build(mesh, radii, k=PATCH_K)
            leaves = tree.leaves()
            order, firsts, counts = [], [], []
            pos = 0
            for leaf in leaves:
                tri = tree.triangles(int(leaf))
                order.append(tri)
                firsts.append(pos * 3)
                counts.append(tri.size * 3)
                pos += tri.size
            faces = faces[np.concatenate(order)]
            normals = vertex_normals(verts, faces)
            spacing = float(np.median(np.linalg.norm(verts[faces[:, 0]] - verts[faces[:, 1]],
                                                     axis=1)))
            vbo = gpu.buffer(np.hstack([verts, normals]).astype(np.float32).tobytes())
            ibo = gpu.buffer(faces.astype(np.uint32).tobytes())
            albedo = self._albedo_on(mesh)
            abo = None if albedo is None else gpu.buffer(albedo.tobytes())
            lods.append(_BodyLod(mag, spacing, len(faces), vbo, ibo,
                                 tree.spheres[leaves, :3].copy(), tree.spheres[leaves, 3].copy(),
                                 np.array(firsts), np.array(counts), {}, abo,
                                 sbo=gpu.buffer(np.zeros(len(verts), np.float32).tobytes())))
            surfaces.append((mesh, radii, normals))
        for fine, (mesh, _, _), (coarse, c_radii, c_normals) in zip(
                lods[:-1], surfaces[:-1], surfaces[1:], strict=True):
            targets = _coarser_surface(mesh.directions(), coarse, c_radii, c_normals)
            fine.morph = gpu.buffer(targets.astype(np.float32).tobytes())
        lods[0].cube = _normal_cube(gpu, *surfaces[0])
        levels = []
        if self.boulders is not None and len(self.boulders):
            # coarse levels for every boulder up front; finer ones only for the boulders a
            # frame brings close (see _fine_batch)
            for level in range(min(COARSE_BOULDER_LEVELS, self.boulders.settings.levels)):
                verts, faces = self.boulders.mesh(level)
                normals = vertex_normals(verts, faces)
                vbo = gpu.buffer(np.hstack([verts, normals]).astype(np.float32).tobytes())
                ibo = gpu.buffer(faces.astype(np.uint32).tobytes())
                morph = _boulder_targets(verts, normals, level, self._boulder_centres(),
                                         self._boulder_radii(), self.boulders.settings.levels)
                levels.append(_BoulderLevel(level, vbo, ibo, len(faces) // len(self.boulders),
                                            {}, gpu.buffer(morph.astype(np.float32).tobytes())))
        self._gpu[id(ctx)] = (ctx, lods, levels)
        log.info("asteroid scene: body LODs %s, %d boulders", magnitudes,
                 0 if self.boulders is None else len(self.boulders))
        return lods, levels

    @staticmethod
    def _vaos(gpu, item):
        key = gpu.token
        if key not in item.vaos:
            item.vaos[key] = gpu.vertex_arrays(item.vbo, item.ibo, item.abo, morph=item.morph,
                                               scatter=getattr(item, "sbo", None))
        return item.vaos[key]

    def _rocks(self) -> Boulders:
        """Return the boulders (only called where there are some)."""
        assert self.boulders is not None
        return self.boulders

    def _boulder_centres(self) -> np.ndarray:
        """(n, 3) float64 boulder centres (m, body frame)."""
        c = self._rocks().catalog
        return np.column_stack([c.x_m, c.y_m, c.z_m])

    def _boulder_radii(self) -> np.ndarray:
        """(n,) bounding radius (m) the level-of-detail and visibility rules use."""
        c = self._rocks().catalog
        return 0.5 * c.diameter_m * np.sqrt(np.maximum(c.elongation, 1.0))

    # ------------------------------------------------------------------ per frame
    def imposter(self, view: View, options: RenderOptions) -> Imposter | None:
        """Tell whether this view shows the body as an imposter (see the module docstring).

        Below ``imposter_pixels`` across the body is an imposter; with geomorphing on, between
        that and :data:`IMPOSTER_FADE` times it the imposter's radiance fades in.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        options : render.renderer.RenderOptions
            The frame's quality settings.

        Returns
        -------
        render.scene.Imposter or None
            The imposter's camera (the frame camera's centre, looking at the body's centre)
            with ``blend`` None (the imposter replaces the body) or the fade's weight; None
            when the body is drawn as geometry alone.
        """
        k = view.intrinsics
        cam = np.asarray(view.pose.position, dtype=np.float64)
        dist = float(np.linalg.norm(cam))
        if not dist > self.reach * IMPOSTER_MIN_DISTANCE:
            return None
        focal = max(k.fx, k.fy)
        span = 2.0 * focal * math.tan(math.asin(min(self.reach / dist, 1.0)))
        blend: float | None
        if span < self.imposter_pixels:
            blend = None  # the imposter replaces the body
        elif options.geomorph and span < IMPOSTER_FADE * self.imposter_pixels:
            # the imposter fades in (module docstring): weight 0 at IMPOSTER_FADE x, 1 at 1 x
            blend = (IMPOSTER_FADE * self.imposter_pixels - span) / (
                (IMPOSTER_FADE - 1.0) * self.imposter_pixels)
        else:
            return None
        size = int(max(MIN_IMPOSTER_TEXELS, math.ceil(span) * IMPOSTER_OVERSAMPLING))
        half = math.asin(min(self.reach / dist, 1.0)) * IMPOSTER_FOV_MARGIN
        f = 0.5 * size / math.tan(half)
        k_imp = Intrinsics(size, size, f, f, (size - 1) / 2, (size - 1) / 2)
        # cells as large on screen as the geometry it stands for would draw: the imposter's
        # texels are IMPOSTER_OVERSAMPLING times finer than the frame's pixels
        lod = options.lod_pixels * f / max(k.fx, k.fy)
        return Imposter(look_at(cam, (0.0, 0.0, 0.0)), k_imp, lod, blend)

    def frame_state(self, view: View, lighting: Lighting, options: RenderOptions, gpu: Gpu,
                    imposter: Imposter | None) -> FrameState:
        """Plan one frame: visible patches and boulders at their levels, and the shadow map.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        lighting : render.renderer.Lighting
            The sun (the shadow map follows it).
        options : render.renderer.RenderOptions
            Level of detail target, shadows, geomorphing.
        gpu : render.scene.Gpu
            Uploads, vertex arrays and the shadow map.
        imposter : render.scene.Imposter or None
            The frame's imposter (:meth:`imposter`): one that replaces the body leaves
            nothing to draw; a fading one is recorded in ``drawn["imposter_fade"]``.

        Returns
        -------
        render.scene.FrameState
            The batches (body, then boulders by level) and what they draw.
        """
        lods, levels = self._upload(gpu)
        for old in self._fine:  # the previous frame's fine boulders
            old.release()
        self._fine = []
        k = view.intrinsics
        cam = np.asarray(view.pose.position, dtype=np.float64)
        dist = float(np.linalg.norm(cam))
        focal = max(k.fx, k.fy)
        far = far_plane(dist + self.reach)
        if imposter is not None and imposter.blend is None:
            return FrameState([], far, {"imposter": True,
                                        "imposter_size": imposter.intrinsics.width})
        near = max(dist - self.reach, MIN_LOD_DISTANCE_M)
        body = lods[0]
        chosen = 0
        for i, lod in enumerate(lods):
            if lod.spacing * focal / near <= options.lod_pixels:
                body, chosen = lod, i
        rot = view.pose.rotation
        c = (body.centres @ self.rotation.T - cam) @ rot
        vis = _sphere_visible(c, body.radii, k)
        patches = np.flatnonzero(vis)
        vao, dvao = self._vaos(gpu, body)
        ranges = _merge(body.firsts[patches], body.counts[patches])
        shadow = None
        if options.shadows and lighting is not None:
            shadow = self._shadow_map(gpu, lighting, options, lods, levels)
        tris = int(body.counts[patches].sum()) // 3
        morph = None
        if options.geomorph and body.morph is not None:
            # every vertex has arrived on the next level where the planner switches to it
            switch = lods[chosen + 1].spacing * focal / options.lod_pixels
            morph = Morph(1, math.log2(switch), MORPH_BAND, level=1.0)
        scatter = options.scattering and lighting is not None
        if scatter:
            self._scatter_into(body, lighting)
        batches = [DrawBatch(vao, dvao, ranges, world_from_model=self.rotation, shadow=shadow,
                             triangles=tris, vertex_albedo=body.abo is not None,
                             morph=morph, normal_cube=(lods[0].cube if options.geomorph
                                                       else None), vertex_scatter=scatter)]
        drawn = {"body_magnitude": body.magnitude, "patches": int(patches.size),
                 "patches_total": int(len(body.radii)), "triangles": tris, "imposter": False}
        b_tris, counts = self._boulder_batches(batches, levels, view, options, gpu,
                                               shadow)
        drawn["boulders"] = counts
        drawn["triangles"] += b_tris
        if imposter is not None and imposter.blend is not None:
            drawn["imposter_fade"] = float(imposter.blend)
        return FrameState(batches, far, drawn)

    def body_light(self) -> Any:
        """Give the body's scattered light (a :class:`render.body_scattering.BodyLight`).

        Built on first use, on the sphere mesh of magnitude :data:`SCATTER_MAGNITUDE`.

        Returns
        -------
        render.body_scattering.BodyLight
            View factors of the patch mesh, body frame.
        """
        from asteroid.sphere import SphereMesh
        from render.body_scattering import BodyLight

        mag = min(SCATTER_MAGNITUDE, self.body.magnitude)
        patch = SphereMesh(mag)
        if self._light is None:
            radii = (np.asarray(self.body.radii, dtype=np.float64) if mag == self.body.magnitude
                     else self.body.surface_radius(patch.directions()))
            self._light = BodyLight(patch.directions() * radii[:, None], patch.faces(),
                                    albedo=self._albedo_on(patch))
            log.info("asteroid scene: scattered light on %d patch vertices, %d pairs in view",
                     patch.n_vertices, self._light.pairs)
        return self._light

    def _scatter_into(self, lod: _BodyLod, lighting: Lighting) -> None:
        """Write the body's scattered light for the frame's sun into a level's buffer."""
        from asteroid.sphere import SphereMesh

        light = self.body_light()
        patch = SphereMesh(min(SCATTER_MAGNITUDE, self.body.magnitude))
        if lod.scatter_at is None:  # (vertices, patch vertices) interpolation weights
            import scipy.sparse

            _, idx, w = patch.locate(SphereMesh(lod.magnitude).directions())
            rows = np.repeat(np.arange(len(idx)), 3)
            lod.scatter_at = scipy.sparse.csr_matrix(
                ((w / w.sum(axis=1, keepdims=True)).ravel(), (rows, idx.ravel())),
                shape=(len(idx), patch.n_vertices))
        from render.body_scattering import write_vertex_scatter

        write_vertex_scatter(lod, light, self.rotation, lighting, self.extra_scatter,
                             lambda total: lod.scatter_at @ total)

    def _boulder_batches(self, batches, levels, view, options, gpu, shadow):
        if not levels:
            return 0, {}
        k = view.intrinsics
        focal = max(k.fx, k.fy)
        centres = self._boulder_centres() @ self.rotation.T
        radius = self._boulder_radii()
        cam = np.asarray(view.pose.position)
        rel = (centres - cam) @ view.pose.rotation
        dist = np.maximum(np.linalg.norm(centres - cam, axis=1) - radius, MIN_LOD_DISTANCE_M)
        px = 2 * radius * focal / dist
        vis = _sphere_visible(rel, radius, k) & (px >= MIN_BOULDER_PIXELS)
        n_levels = self.boulders.settings.levels
        wanted = np.ceil(np.log2(np.maximum(ICOSAHEDRON_EDGE * radius * focal / dist
                                            / options.lod_pixels, 1.0)))
        level = np.clip(wanted, 0, n_levels - 1).astype(int)
        counts, tris = {}, 0
        for lv in levels:
            sel = np.flatnonzero(vis & (level == lv.level))
            if not sel.size:
                continue
            vao, dvao = self._vaos(gpu, lv)
            per = lv.faces_per * 3
            ranges = _merge(sel * per, np.full(sel.size, per))
            n = sel.size * lv.faces_per
            tris += n
            counts[str(lv.level)] = int(sel.size)
            batches.append(DrawBatch(vao, dvao, ranges, world_from_model=self.rotation,
                                     shadow=shadow, triangles=n,
                                     morph=_boulder_morph(lv.level, focal, options)))
        for lv in range(len(levels), n_levels):
            sel = np.flatnonzero(vis & (level == lv))
            if not sel.size:
                continue
            batch = self._fine_batch(gpu, lv, sel, shadow)
            batch.morph = _boulder_morph(lv, focal, options)
            tris += batch.triangles
            counts[str(lv)] = int(sel.size)
            batches.append(batch)
        return tris, counts

    def _fine_batch(self, gpu, level: int, indices: np.ndarray, shadow) -> DrawBatch:
        """Build a throw-away vertex array of the given boulders at a fine level of detail."""
        from asteroid.boulders import subdivision
        from render.mesh_scene import vertex_normals

        rocks = self._rocks()
        faces_all, _ = subdivision(rocks.settings.levels)
        f = faces_all[level]
        nv = 10 * 4**level + 2
        c = rocks.catalog
        rot = rocks.rotations()[indices]
        centres = np.column_stack([c.x_m, c.y_m, c.z_m])[indices]
        local = np.stack([rocks.local_shapes(slice(int(i), int(i) + 1))[0, :nv]
                          for i in indices])
        verts = (np.einsum("nij,nvj->nvi", rot, local) + centres[:, None, :]).reshape(-1, 3)
        faces = (f[None, :, :] + (np.arange(len(indices)) * nv)[:, None, None]).reshape(-1, 3)
        normals = vertex_normals(verts, faces)
        vbo = gpu.buffer(np.hstack([verts, normals]).astype(np.float32).tobytes())
        ibo = gpu.buffer(faces.astype(np.uint32).tobytes())
        targets = _boulder_targets(verts, normals, level, centres,
                                   self._boulder_radii()[indices], rocks.settings.levels)
        mbo = gpu.buffer(targets.astype(np.float32).tobytes())
        vao, dvao = gpu.vertex_arrays(vbo, ibo, morph=mbo)
        self._fine.extend([vao, dvao, vbo, ibo, mbo])
        return DrawBatch(vao, dvao, [(0, faces.size)], world_from_model=self.rotation,
                         shadow=shadow, triangles=len(faces))

    def shadow_casters(self, gpu: Gpu, extent: float, size: int) -> list[DrawBatch]:
        """Give the depth batches that cast the body's shadows into a map of ``extent``.

        The body at the coarsest level the map's texels resolve, fixed by the map and never
        by where the camera is (module docstring), and the boulders at their second level;
        model frame about the body's centre, turned by the current rotation.

        Parameters
        ----------
        gpu : render.scene.Gpu
            Uploads and vertex arrays.
        extent : float
            The map's side, metres.
        size : int
            The map's side, texels.

        Returns
        -------
        list of render.scene.DrawBatch
            Depth-only batches (``vao`` None).
        """
        lods, levels = self._upload(gpu)
        body_lod = lods[0]
        for lod in lods:
            if lod.spacing <= SHADOW_CELL_TEXELS * extent / size:
                body_lod = lod
        _, dvao = self._vaos(gpu, body_lod)
        batches = [DrawBatch(None, dvao, [(0, body_lod.triangles * 3)],
                             world_from_model=self.rotation)]
        if levels and self.boulders is not None:
            lv = levels[min(1, len(levels) - 1)]
            _, bdvao = self._vaos(gpu, lv)
            batches.append(DrawBatch(None, bdvao, [(0, lv.faces_per * 3 * len(self.boulders))],
                                     world_from_model=self.rotation))
        return batches

    def _shadow_map(self, gpu, lighting, options, lods, levels) -> ShadowMap:
        size = options.shadow_size
        self._shadow = body_shadow_map(gpu, self._shadow, size, lighting.sun, self.reach,
                                       lambda extent: self.shadow_casters(gpu, extent, size))
        return self._shadow


def _normal_cube(gpu, mesh, radii, normals):
    """Build a cube map of the finest level's normals by body-frame direction.

    Each texel holds the normal interpolated on the triangle its direction meets (module
    docstring).
    """
    n = NORMAL_CUBE_SIZE
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    tc, sc = np.meshgrid(c, c, indexing="ij")  # rows run along t, columns along s
    one = np.ones_like(sc)
    faces = [np.stack(f, axis=-1) for f in (  # GL's cube faces +X, -X, +Y, -Y, +Z, -Z
        (one, -tc, -sc), (-one, -tc, sc), (sc, one, tc), (sc, -one, -tc), (sc, -tc, one),
        (-sc, -tc, -one))]
    dirs = np.concatenate([f.reshape(-1, 3) for f in faces])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    nrm = _coarser_surface(dirs, mesh, radii, normals)[:, 4:]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return gpu.texture_cube((n, n), 3, half_floats(nrm).tobytes(), dtype="f2")


def _coarser_surface(directions, coarse, c_radii, c_normals) -> np.ndarray:
    """Give the (n, 7) morph targets of a body level's vertices.

    The coarser level's surface along each vertex's direction (the flat triangle the ray
    meets), key 1, and the interpolated normal.

    In the coarser triangle whose cone holds u, ``u = a A + b B + c C``; the ray meets the
    plane through the radii at ``t = 1 / (a / r_A + b / r_B + c / r_C)`` with barycentric
    weights ``t a / r_A`` ... (as :func:`asteroid.sphere.surface_radius_scalar`).
    """
    _, idx, w = coarse.locate(directions)
    inv = w / c_radii[idx]
    t = 1.0 / inv.sum(axis=1)
    bary = inv * t[:, None]
    out = np.empty((len(directions), 7))
    out[:, :3] = directions * t[:, None]
    out[:, 3] = 1.0
    out[:, 4:] = np.einsum("nk,nkj->nj", bary, c_normals[idx])
    return out


def _boulder_targets(verts, normals, level: int, centres, radii, levels: int) -> np.ndarray:
    """(n V_l, 7) morph targets of boulders drawn at ``level`` (module docstring).

    Level 0: every vertex slides to the boulder's centre, keyed ``log2(2 r)``; level l >= 1:
    the vertices level l adds slide to the midpoint of the edge they split, keyed
    ``log2(1.05 r) - (l - 1)`` (see :func:`_boulder_morph`); the others stay.
    """
    from asteroid.boulders import subdivision

    n = len(radii)
    nv = 10 * 4**level + 2
    v = np.asarray(verts, dtype=np.float64).reshape(n, nv, 3)
    nn = np.asarray(normals, dtype=np.float64).reshape(n, nv, 3)
    out = np.empty((n, nv, 7))
    out[..., :3] = v
    out[..., 4:] = nn
    if level == 0:
        out[..., :3] = np.asarray(centres, dtype=np.float64)[:, None, :]
        out[..., 3] = np.log2(2.0 * radii)[:, None]
    else:
        _, parents = subdivision(levels)
        par = parents[level - 1]
        old = 10 * 4 ** (level - 1) + 2
        out[:, old:, :3] = 0.5 * (v[:, par[:, 0]] + v[:, par[:, 1]])
        out[:, old:, 4:] = 0.5 * (nn[:, par[:, 0]] + nn[:, par[:, 1]])
        out[..., 3] = (np.log2(ICOSAHEDRON_EDGE * radii) - (level - 1))[:, None]
    return out.reshape(-1, 7)


def _boulder_morph(level: int, focal: float, options) -> Morph | None:
    """Give the morph of a boulder batch drawn at ``level``.

    A boulder of radius r is drawn at level l while ``1.05 r focal / (d lod_pixels)``
    exceeds ``2^(l - 1)`` (:data:`ICOSAHEDRON_EDGE`), and not at all once ``2 r focal / d``
    drops below :data:`MIN_BOULDER_PIXELS`; each vertex's key adds its boulder's part of the
    threshold distance (``log2`` metres).
    """
    if not options.geomorph:
        return None
    if level == 0:
        return Morph(2, math.log2(focal / MIN_BOULDER_PIXELS), MORPH_BAND)
    return Morph(2, math.log2(focal / options.lod_pixels), MORPH_BAND)


def _sphere_visible(c: np.ndarray, radii: np.ndarray, k) -> np.ndarray:
    """Spheres (camera-frame centres) not wholly outside the view frustum."""
    vis = c[:, 2] > -radii
    planes = np.array([[k.fx, 0.0, k.cx + 0.5], [-k.fx, 0.0, k.width - 0.5 - k.cx],
                       [0.0, k.fy, k.cy + 0.5], [0.0, -k.fy, k.height - 0.5 - k.cy]])
    planes /= np.linalg.norm(planes, axis=1, keepdims=True)
    for plane in planes:
        vis &= c @ plane > -radii
    return vis


def _merge(firsts, counts) -> list[tuple[int, int]]:
    out: list[list[int]] = []
    for o, n in zip(np.asarray(firsts), np.asarray(counts), strict=True):
        o, n = int(o), int(n)
        if out and out[-1][0] + out[-1][1] == o:
            out[-1][1] += n
        else:
            out.append([o, n])
    return [(a, b) for a, b in out]
