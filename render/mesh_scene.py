"""Any closed triangle mesh as a scene: shape models, asteroid bodies, boulders.

The mesh lives in its body-fixed frame (metres, origin at the body's centre); the world frame
is inertial, and the body's rotation quaternion R_WB (set per frame, e.g. from a spin) maps
body to world: ``p_W = R_WB p_B + centre``. Faces are sorted along a Morton curve of their
centroids and cut into chunks of :data:`CHUNK` triangles, each with a bounding sphere, so a
frame draws only the chunks inside the view frustum.

Levels of detail: a scene may hold several meshes of the same body at decreasing resolution
(:meth:`MeshScene.add_lod`), each with its typical edge length; a frame draws the coarsest one
whose edges stay below ``RenderOptions.lod_pixels`` on screen at the body's nearest point.

Shadows: one orthographic map fitted to the body's bounding sphere, re-rendered every frame
(the body turns under the sun).

Scattered light: with ``RenderOptions.scattering`` on, the sunlight the body scatters once
into itself is computed on a patch mesh, its coarsest level of detail (clustered down to
:data:`render.body_scattering.PATCH_FACES` faces where it holds more,
:func:`render.body_scattering.cluster_mesh`), for the body-frame sun
(:mod:`render.body_scattering`) and carried to every level's vertices from the nearest patch
vertex facing the same way, as a vertex attribute.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from render.camera import quat_to_matrix
from render.scene import (
    MIN_LOD_DISTANCE_M,
    DrawBatch,
    FrameState,
    Gpu,
    Imposter,
    ShadowMap,
    body_shadow_map,
    far_plane,
)
from terrain.core.errors import InvalidParameterError

if TYPE_CHECKING:
    from render.renderer import Lighting, RenderOptions, View

__all__ = ["CHUNK", "MeshBodyScene", "MeshScene", "is_mesh_body", "vertex_normals"]

log = logging.getLogger(__name__)

#: Triangles per culling chunk.
CHUNK = 4096
#: Shadow casters of a map drawn on its own (:meth:`MeshScene.shadow_casters`) use the
#: coarsest level whose edges stay below this many of the map's texels.
SHADOW_CELL_TEXELS = 2.0


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Give the area-weighted vertex normals of a triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) float, metres
        Vertex positions.
    faces : (m, 3) int
        Vertex indices of each triangle, outward-wound.

    Returns
    -------
    (n, 3) float64
        Unit normals (zero for a vertex no face uses).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    norm[norm == 0] = 1.0
    return n / norm


def _morton_order(points: np.ndarray) -> np.ndarray:
    lo, hi = points.min(axis=0), points.max(axis=0)
    q = ((points - lo) / np.maximum(hi - lo, 1e-12) * 1023).astype(np.int64)
    code = np.zeros(len(points), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(code, kind="stable")


@dataclass(eq=False)
class _Lod:
    vbo: object
    ibo: object
    centres: np.ndarray   # (chunks, 3) body frame
    radii: np.ndarray     # (chunks,)
    firsts: np.ndarray
    counts: np.ndarray
    edge: float           # typical edge length (m)
    triangles: int
    vaos: dict
    abo: object = None    # per-vertex albedo factors (float32), or None
    sbo: Any = None       # per-vertex scattered irradiance (float32), rewritten per sun
    scatter_at: np.ndarray | None = None  # the patch vertex each vertex takes its light from
    scatter_key: Any = None               # the patch irradiances it holds (own, extra)
    source: int = 0                       # index of its mesh in the scene's meshes


class MeshScene:
    """A triangle mesh (body frame, metres) ready to render (see the module docstring).

    Parameters
    ----------
    vertices : (n, 3) float, metres
        Vertex positions, body frame.
    faces : (m, 3) int
        Vertex indices of each triangle, outward-wound (counter-clockwise seen from outside).
    centre : (3,) float, metres
        World position of the body's origin (default: the world origin).
    albedo : (n,) float, optional
        Albedo factor per vertex (multiplies the albedo, or Hapke's w; interpolated across
        faces).
    """

    kind = "mesh"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, *,
                 centre: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
                 albedo: np.ndarray | None = None) -> None:
        self.origin = np.asarray(centre, dtype=np.float64).reshape(3)
        self.rotation = np.eye(3)
        self._meshes: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._gpu: dict = {}
        self._shadow: ShadowMap | None = None
        self._light: Any = None  # render.body_scattering.BodyLight (False: too large)
        #: Scattered light from elsewhere (E / F per patch vertex of :meth:`body_light`, e.g.
        #: a binary's other body), added to the body's own; None: none.
        self.extra_scatter: np.ndarray | None = None
        self.add_lod(vertices, faces, albedo=albedo)

    def add_lod(self, vertices: np.ndarray, faces: np.ndarray, *,
                albedo: np.ndarray | None = None) -> None:
        """Add a (coarser) level of detail of the same body.

        Parameters
        ----------
        vertices : (n, 3) float, metres
            Vertex positions, body frame.
        faces : (m, 3) int
            Vertex indices of each triangle, outward-wound.
        albedo : (n,) float, optional
            Albedo factor per vertex.
        """
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise InvalidParameterError(f"mesh vertices must be (n, 3) finite; got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.min() < 0 or f.max() >= len(v):
            raise InvalidParameterError(
                f"mesh faces must be (m, 3) indices into the vertices; got {f.shape}")
        if albedo is not None:
            albedo = np.asarray(albedo, dtype=np.float32).reshape(-1)
            if albedo.shape != (len(v),) or not np.all(np.isfinite(albedo)) or albedo.min() < 0:
                raise InvalidParameterError(
                    f"mesh albedo must be one finite value >= 0 per vertex ({len(v)}); got "
                    f"{albedo.shape}")
        self._meshes.append((v, f, albedo))
        self._meshes.sort(key=lambda vf: len(vf[1]), reverse=True)
        self._gpu.clear()
        self._light = None

    @property
    def reach(self) -> float:
        """Farthest distance (m) of the finest mesh's vertices from the body's centre."""
        return float(np.linalg.norm(self._meshes[0][0], axis=1).max())

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
        return np.atleast_2d(points) @ self.rotation.T + self.origin

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World-frame bounding box: the cube of the body's reach about its centre.

        Returns
        -------
        lo, hi : (3,) float64, metres
            Its smallest and largest corner.
        """
        r = self.reach
        return self.origin - r, self.origin + r

    # ------------------------------------------------------------------ GPU
    def _upload(self, gpu):
        ctx = gpu.context  # the key uploads are cached under
        if ctx in self._gpu:
            return self._gpu[ctx]
        lods = []
        for source, (v, f, albedo) in enumerate(self._meshes):
            n = vertex_normals(v, f)
            order = _morton_order(v[f].mean(axis=1))
            f = f[order]
            chunks = max(1, math.ceil(len(f) / CHUNK))
            centres = np.empty((chunks, 3))
            radii = np.empty(chunks)
            for c in range(chunks):
                pts = v[np.unique(f[c * CHUNK:(c + 1) * CHUNK])]
                centres[c] = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
                radii[c] = np.linalg.norm(pts - centres[c], axis=1).max()
            firsts = np.arange(chunks) * CHUNK * 3
            counts = np.minimum(CHUNK, len(f) - np.arange(chunks) * CHUNK) * 3
            edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)))
            vbo = gpu.buffer(np.hstack([v, n]).astype(np.float32).tobytes())
            ibo = gpu.buffer(f.astype(np.uint32).tobytes())
            abo = None if albedo is None else gpu.buffer(albedo.tobytes())
            sbo = gpu.buffer(np.zeros(len(v), np.float32).tobytes())
            lods.append(_Lod(vbo, ibo, centres, radii, firsts, counts, edge, len(f), {}, abo,
                             sbo, source=source))
        self._gpu[ctx] = lods
        return lods

    def _vaos(self, gpu, lod: _Lod):
        key = gpu.token
        if key not in lod.vaos:
            lod.vaos[key] = gpu.vertex_arrays(lod.vbo, lod.ibo, lod.abo, scatter=lod.sbo)
        return lod.vaos[key]

    # ------------------------------------------------------------------ per frame
    def imposter(self, view: View, options: RenderOptions) -> Imposter | None:
        """Never: a mesh is always drawn as geometry.

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

    def frame_state(self, view: View, lighting: Lighting, options: RenderOptions,
                    gpu: Gpu, imposter: Imposter | None) -> FrameState:
        """Plan one frame: the visible chunks of the chosen level, with the body's map.

        Parameters
        ----------
        view : render.renderer.View
            The frame's camera.
        lighting : render.renderer.Lighting
            The sun (the shadow map follows it).
        options : render.renderer.RenderOptions
            Level of detail target, shadows.
        gpu : render.scene.Gpu
            Uploads, vertex arrays and the shadow map.
        imposter : render.scene.Imposter or None
            Always None (:meth:`imposter`).

        Returns
        -------
        render.scene.FrameState
            One batch and what it draws.
        """
        lods = self._upload(gpu)
        k = view.intrinsics
        cam = np.asarray(view.pose.position) - self.origin      # world, relative to centre
        dist = max(np.linalg.norm(cam) - self.reach, MIN_LOD_DISTANCE_M)
        focal = max(k.fx, k.fy)
        chosen = lods[0]
        for lod in lods:  # finest first: take the coarsest that is still fine enough
            if lod.edge * focal / dist <= options.lod_pixels:
                chosen = lod
        centres_w = chosen.centres @ self.rotation.T
        rot = view.pose.rotation
        c = (centres_w - cam) @ rot
        r = chosen.radii
        vis = c[:, 2] > -r
        planes = np.array([[k.fx, 0.0, k.cx + 0.5], [-k.fx, 0.0, k.width - 0.5 - k.cx],
                           [0.0, k.fy, k.cy + 0.5], [0.0, -k.fy, k.height - 0.5 - k.cy]])
        planes /= np.linalg.norm(planes, axis=1, keepdims=True)
        for plane in planes:  # a chunk is culled when its sphere is wholly outside a plane
            vis &= c @ plane > -r
        # back-facing chunks cannot be culled safely on a non-convex body: keep them
        chunks = np.flatnonzero(vis)
        vao, dvao = self._vaos(gpu, chosen)
        ranges = [(int(chosen.firsts[i]), int(chosen.counts[i])) for i in chunks]
        tris = int(chosen.counts[chunks].sum()) // 3
        shadow = self._shadow_map(gpu, lighting, options, chosen) \
            if options.shadows and lighting is not None else None
        scatter = bool(options.scattering and lighting is not None
                       and self._scatter_into(chosen, lighting))
        batch = DrawBatch(vao, dvao, ranges, world_from_model=self.rotation,
                          model_offset=np.zeros(3), shadow=shadow, triangles=tris,
                          vertex_albedo=chosen.abo is not None, vertex_scatter=scatter)
        far = far_plane(float(np.linalg.norm(cam) + self.reach))
        drawn = {"triangles": tris, "chunks": int(chunks.size), "lod_edge_m": chosen.edge,
                 "lod_triangles": chosen.triangles}
        return FrameState([batch], far, drawn)

    def body_light(self) -> Any:
        """Give the body's scattered light (a :class:`render.body_scattering.BodyLight`).

        Built on first use, on the coarsest level of detail (clustered to at most
        :data:`render.body_scattering.PATCH_FACES` faces).

        Returns
        -------
        render.body_scattering.BodyLight
            View factors of the patch mesh, body frame.
        """
        from render.body_scattering import PATCH_FACES, BodyLight, cluster_mesh

        if self._light is None:
            pv, pf, palbedo = self._meshes[-1]
            if len(pf) > PATCH_FACES:
                cv, cf = cluster_mesh(pv, pf, PATCH_FACES)
                log.info("mesh scene: scattered light on %d faces clustered from %d",
                         len(cf), len(pf))
                self._light = BodyLight(cv, cf)  # albedo factors: 1 (they stay the receivers')
            else:
                self._light = BodyLight(pv, pf, albedo=palbedo)
        return self._light

    def _scatter_into(self, lod: _Lod, lighting: Lighting) -> bool:
        """Write the body's scattered light for the frame's sun into a level's buffer."""
        from scipy.spatial import cKDTree

        light = self.body_light()
        pv = light.vertices
        if lod.scatter_at is None:
            v, f, _ = self._meshes[lod.source]
            if len(v) == len(pv) and np.array_equal(v, pv):
                lod.scatter_at = np.arange(len(v))
            else:  # nearest patch vertex facing the same way (not across a thin wall)
                scale = light.edge
                tree = cKDTree(np.hstack([pv, scale * light.normals_v]))
                lod.scatter_at = tree.query(np.hstack([v, scale * vertex_normals(v, f)]))[1]
        from render.body_scattering import write_vertex_scatter

        write_vertex_scatter(lod, light, self.rotation, lighting, self.extra_scatter,
                             lambda total: total[lod.scatter_at])
        return True

    def shadow_casters(self, gpu: Gpu, extent: float, size: int) -> list[DrawBatch]:
        """Give the depth batch that casts the body's shadows into a map of ``extent``.

        The coarsest level whose edges stay below two of the map's texels (the finest where
        none does), model frame about the body's centre, turned by the current rotation.

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
            One depth-only batch (``vao`` None).
        """
        lods = self._upload(gpu)
        chosen = lods[0]
        for lod in lods:
            if lod.edge <= SHADOW_CELL_TEXELS * extent / size:
                chosen = lod
        _, dvao = self._vaos(gpu, chosen)
        return [DrawBatch(None, dvao, [(0, chosen.triangles * 3)],
                          world_from_model=self.rotation, model_offset=np.zeros(3))]

    def _shadow_map(self, gpu, lighting, options, lod) -> ShadowMap:
        _, dvao = self._vaos(gpu, lod)
        batch = DrawBatch(None, dvao, [(0, lod.triangles * 3)], world_from_model=self.rotation,
                          model_offset=np.zeros(3))
        self._shadow = body_shadow_map(gpu, self._shadow, options.shadow_size,
                                       lighting.sun, self.reach, lambda extent: [batch])
        return self._shadow


def is_mesh_body(path: Any) -> bool:
    """Whether ``path`` names a body a scene draws as a mesh: a mesh body ``.npz`` or a mesh file.

    ``craterscape asteroid build`` writes a latitude/longitude body (``.npz`` of format
    ``craterscape-asteroid/1``, drawn by :class:`render.asteroid_scene.AsteroidScene`) or a
    body kept as its own mesh (``craterscape-mesh-asteroid/1``, beside its ``.ply``/``.obj``
    /... file); this tells them apart by the file's format tag.

    Parameters
    ----------
    path : str or pathlib.Path

    Returns
    -------
    bool
    """
    from pathlib import Path

    from asteroid.surface import MESH_FORMAT, native_format

    p = Path(path)
    if p.suffix.lower() == ".npz":
        return native_format(p) == MESH_FORMAT
    return True


class MeshBodyScene(MeshScene):
    """A body kept as its own closed mesh, drawn as a scenario's asteroid.

    What ``craterscape asteroid build --base shape:FILE`` (a shape that is not star-shaped)
    or ``--base packing:...`` writes: the ``.npz`` mesh body (its vertices, faces and
    catalogues; the boulders are rebuilt from their catalogue at their finest level,
    :func:`asteroid.surface.mesh_boulder_geometry`) or the mesh file beside it (body and
    boulders as written). It turns with the scenario's spin as a latitude/longitude body
    does (``kind`` ``"asteroid"``), and :meth:`contains` tells whether a point is inside the
    body exactly (generalised winding number), whatever its shape.

    Parameters
    ----------
    source : str or pathlib.Path
        The mesh body's ``.npz``, or a closed mesh file (``.ply``, ``.obj``, ``.stl``,
        ``.glb``; metres, about the body's centre).
    boulders : bool
        Draw the boulders (a ``.npz``'s catalogue; a mesh file's are part of its mesh).
    albedo : path or (n,) float, optional
        One albedo factor per body vertex (``.npy``); the boulders take 1.
    """

    kind = "asteroid"

    def __init__(self, source: Any, *, boulders: bool = True, albedo: Any = None) -> None:
        from pathlib import Path

        from asteroid.surface import boulder_settings, load_mesh_native, mesh_boulder_geometry

        path = Path(source)
        self.source = path
        self.catalogs: dict = {}
        if path.suffix.lower() == ".npz":
            body, tables = load_mesh_native(path)
            self.catalogs = tables
            body_v, body_f = body.vertices, body.faces
            parts = [(body_v, body_f)]
            recorded = boulder_settings(body.metadata)
            if boulders and recorded is not None and "boulders" in tables:
                parts.append(mesh_boulder_geometry(tables["boulders"], *recorded))
        else:
            from asteroid.meshio.read import read_mesh

            body_v, body_f = read_mesh(path)
            parts = [(np.asarray(body_v, dtype=np.float64), np.asarray(body_f, dtype=np.int64))]
        #: The closed surface (without boulders) the inside test uses, body frame.
        self.surface = (np.asarray(parts[0][0], dtype=np.float64),
                        np.asarray(parts[0][1], dtype=np.int64))
        vertices = np.concatenate([v for v, _ in parts])
        offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
        faces = np.concatenate([f + o for (_, f), o in zip(parts, offsets, strict=True)])
        factors = None
        if albedo is not None:
            a = np.load(albedo, allow_pickle=False) if isinstance(albedo, (str, Path)) \
                else np.asarray(albedo)
            a = np.asarray(a, dtype=np.float32).reshape(-1)
            if a.shape != (len(self.surface[0]),):
                raise InvalidParameterError(
                    f"the albedo map of mesh body '{path}' must hold one factor per body "
                    f"vertex ({len(self.surface[0])}); got {a.shape}")
            factors = np.concatenate([a, np.ones(len(vertices) - len(a), np.float32)])
        super().__init__(vertices, faces, albedo=factors)

    def contains(self, point: Any, quaternion: Any = (1.0, 0.0, 0.0, 0.0)) -> bool:
        """Whether a world point lies inside the body (boulders aside) turned by ``quaternion``.

        Parameters
        ----------
        point : (3,) float, metres, world frame
        quaternion : (4,) float
            R_WB [w, x, y, z] of the body at that time.

        Returns
        -------
        bool
        """
        from asteroid.shape import winding_number

        p = (np.asarray(point, dtype=np.float64).reshape(3) - self.origin) \
            @ quat_to_matrix(quaternion)
        v, f = self.surface
        r = np.linalg.norm(v, axis=1).max()
        if np.linalg.norm(p) > r:
            return False
        return winding_number(v, f, p) > 0.5

    def surface_distance(self, points: Any) -> np.ndarray:
        """Distance (m) of body-frame points from the nearest surface vertex (boulders aside).

        Parameters
        ----------
        points : (n, 3) float, metres, body frame

        Returns
        -------
        (n,) float64
        """
        from scipy.spatial import cKDTree

        if getattr(self, "_tree", None) is None:
            self._tree = cKDTree(self.surface[0])
        d, _ = self._tree.query(np.atleast_2d(np.asarray(points, dtype=np.float64)))
        return np.asarray(d, dtype=np.float64)
