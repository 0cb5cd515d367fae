"""Sunlight a body scatters once into its own shadows: view factors between its facets.

A body's shadowed ground (a crater's floor, the inside of a bend of an elongated asteroid) is
lit by the body's own sunlit surface around it. This module computes that light per vertex of
a coarse "patch" mesh of the body, the classic radiosity formulation reduced to single
scattering (Cohen & Wallace 1993, *Radiosity and Realistic Image Synthesis*, ch. 4):

- **Geometry, once.** Receivers are the patch mesh's vertices (position p_i, normal n_i);
  sources are its faces (centroid c_j, normal m_j, area A_j). The view factor from a receiver
  to a source is ``F_ij = a / (pi r^2 + a)``, ``a = cos t_i cos t_j A_j``, with
  ``r = |c_j - p_i|`` and the cosines of the ray between them with each normal: the view
  factor of a coaxial disk, ``A / (pi r^2 + A)`` (Wallace, Elmquist & Haines 1989, SIGGRAPH,
  "A ray tracing algorithm for progressive radiosity"), with the disk's area as seen along
  the ray from both ends, which is the differential form ``cos t_i cos t_j A / (pi r^2)``
  where ``r^2 >> A`` and stays below 1 for neighbours,
  kept where both cosines are positive and a ray from the receiver to the source's centroid
  meets no other face (a bounding-volume hierarchy over the faces). It depends on the shape
  alone, so it is computed once per body: a sparse matrix of the pairs that see each other
  (on a convex body, none do).
- **Light, per sun direction.** A source's radiosity over the solar irradiance is
  ``B_j = A a_j mu0_j v_j`` (A the scene's normal albedo, a_j the face's albedo factor, mu0_j
  its cosine to the sun, v_j the fraction of :data:`SUN_SAMPLES` rays from points of the
  face to the sun that meet no face): the sources are Lambertian. The scattered irradiance
  over the solar irradiance is ``E_i = sum_j F_ij B_j`` (a matrix-vector product), which
  the fragment shader adds as a Lambertian response of the surface's albedo, as it does the
  terrain's (:mod:`render.scattering`). Light scattered twice or more (another factor of A) is left
  out, and the sun is a point for the sources (a penumbra's share of a source is small).
- **Sun directions on a fixed lattice.** The body-frame sun is snapped to a lattice of
  directions :data:`SUN_STEP_DEG` apart (:func:`snap_direction`) and the result cached per
  lattice point, so a spinning body is recomputed each time its sun crosses to the next
  lattice point, and a frame's light depends on its own sun alone, never on the frames
  before it (a server's image equals the command line's).

A scene carries the patch values to each level of detail's vertices (an asteroid by
direction through the patch mesh's triangles, a mesh by the nearest patch vertex) and binds
them as a vertex attribute (``in_scatter`` in ``render/shaders/scene.vert``). Check:
``tests/render/test_body_scattering.py``, a hemispherical bowl whose every point receives
``A sin(e) / 4`` of the solar irradiance under a sun at elevation e (all the light entering
its opening lands once on it, and inside a sphere every element sees every other with the
view factor ``dA / (4 pi R^2)``).
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from typing import Any

import numba
import numpy as np
import scipy.sparse

from terrain.core.errors import InvalidParameterError

__all__ = ["MAX_PATCH_FACES", "PATCH_FACES", "SUN_STEP_DEG", "BodyLight", "cluster_mesh",
           "mutual_irradiance", "snap_direction", "write_vertex_scatter"]

log = logging.getLogger(__name__)

#: The lattice of body-frame sun directions the scattered light is computed for (degrees
#: between neighbours): scattered light changes little over a degree.
SUN_STEP_DEG = 1.0
#: Patch meshes above this many faces are refused (the view factors grow with the square).
MAX_PATCH_FACES = 40_000
#: A mesh scene's patch mesh holds at most this many faces (a finer one is clustered).
PATCH_FACES = 12_000
#: Faces per leaf of the bounding-volume hierarchy.
LEAF_FACES = 4
#: Rays start this fraction of the median edge off their surface (no self-hits).
RAY_OFFSET = 1e-3
#: Irradiance results kept per body (lattice points).
CACHE = 4
#: Sun rays per source face (its centroid and halfway from it to each corner): a face the
#: edge of a shadow crosses is partly lit.
SUN_SAMPLES = 4


def snap_direction(direction: Any, step_deg: float = SUN_STEP_DEG) -> tuple[float, float, float]:
    """Snap a direction to the nearest point of a fixed lattice of directions.

    Latitude in steps of ``step_deg``, longitude in as many equal steps around each latitude
    circle as fit ``step_deg`` apart there: neighbours are about ``step_deg`` apart everywhere.

    Parameters
    ----------
    direction : (3,) float
        Any non-zero vector.
    step_deg : float
        The lattice's spacing, degrees.

    Returns
    -------
    tuple of 3 float
        The lattice point (unit vector).

    Examples
    --------
    >>> snap_direction((0.0, 0.0, 2.0))
    (0.0, 0.0, 1.0)
    """
    v = np.asarray(direction, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(v))
    if not (norm > 0 and math.isfinite(norm)):
        raise InvalidParameterError(f"a sun direction must be a non-zero 3-vector; got {v}")
    v = v / norm
    step = math.radians(step_deg)
    lat = round(math.asin(max(-1.0, min(1.0, v[2]))) / step) * step
    lat = max(-math.pi / 2, min(math.pi / 2, lat))
    n_lon = max(1, round(2.0 * math.pi * math.cos(lat) / step))
    lon_step = 2.0 * math.pi / n_lon
    lon = (round(math.atan2(v[1], v[0]) / lon_step) % n_lon) * lon_step
    out = (math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat))
    return tuple(0.0 if abs(c) < 1e-15 else float(c) for c in out)  # type: ignore[return-value]


# ---------------------------------------------------------------- bounding-volume hierarchy
def _build_bvh(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray):
    """Median-split hierarchy over triangles; flat arrays (node bounds, children, leaves)."""
    lo_t = np.minimum(np.minimum(v0, v1), v2)
    hi_t = np.maximum(np.maximum(v0, v1), v2)
    cen = (lo_t + hi_t) * 0.5
    order = np.arange(len(v0))
    lo: list = []
    hi: list = []
    left: list = []
    right: list = []
    first: list = []
    count: list = []
    stack = [(0, len(v0), -1, 0)]  # (start, end, parent, side)
    while stack:
        s, e, parent, side = stack.pop()
        node = len(lo)
        idx = order[s:e]
        lo.append(lo_t[idx].min(axis=0))
        hi.append(hi_t[idx].max(axis=0))
        left.append(-1)
        right.append(-1)
        first.append(s)
        count.append(0)
        if parent >= 0:
            (left if side == 0 else right)[parent] = node
        if e - s <= LEAF_FACES:
            count[node] = e - s
            continue
        c = cen[idx]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        half = (e - s) // 2
        part = np.argpartition(c[:, axis], half)
        order[s:e] = idx[part]
        stack.append((s + half, e, node, 1))
        stack.append((s, s + half, node, 0))
    return (np.array(lo), np.array(hi), np.array(left, np.int64), np.array(right, np.int64),
            np.array(first, np.int64), np.array(count, np.int64), order.astype(np.int64))


@numba.njit(cache=True)
def _hits(o0, o1, o2, d0, d1, d2, tmax, lo, hi, left, right, first, count, order, v0, e1, e2):
    """Whether the ray o + t d meets a triangle for 0 < t < tmax (Moller & Trumbore 1997)."""
    stack = np.empty(128, np.int64)
    stack[0] = 0
    sp = 1
    o = (o0, o1, o2)
    d = (d0, d1, d2)
    while sp > 0:
        sp -= 1
        node = stack[sp]
        tn = 0.0
        tf = tmax
        miss = False
        for a in range(3):
            if abs(d[a]) < 1e-300:
                if o[a] < lo[node, a] or o[a] > hi[node, a]:
                    miss = True
                    break
                continue
            inv = 1.0 / d[a]
            t0 = (lo[node, a] - o[a]) * inv
            t1 = (hi[node, a] - o[a]) * inv
            if t0 > t1:
                t0, t1 = t1, t0
            tn = max(tn, t0)
            tf = min(tf, t1)
            if tn > tf:
                miss = True
                break
        if miss:
            continue
        if count[node] > 0:
            for k in range(first[node], first[node] + count[node]):
                f = order[k]
                px = d1 * e2[f, 2] - d2 * e2[f, 1]
                py = d2 * e2[f, 0] - d0 * e2[f, 2]
                pz = d0 * e2[f, 1] - d1 * e2[f, 0]
                det = e1[f, 0] * px + e1[f, 1] * py + e1[f, 2] * pz
                if abs(det) < 1e-300:
                    continue
                inv = 1.0 / det
                tx = o0 - v0[f, 0]
                ty = o1 - v0[f, 1]
                tz = o2 - v0[f, 2]
                u = (tx * px + ty * py + tz * pz) * inv
                if u < 0.0 or u > 1.0:
                    continue
                qx = ty * e1[f, 2] - tz * e1[f, 1]
                qy = tz * e1[f, 0] - tx * e1[f, 2]
                qz = tx * e1[f, 1] - ty * e1[f, 0]
                w = (d0 * qx + d1 * qy + d2 * qz) * inv
                if w < 0.0 or u + w > 1.0:
                    continue
                t = (e2[f, 0] * qx + e2[f, 1] * qy + e2[f, 2] * qz) * inv
                if t > 0.0 and t < tmax:
                    return True
        else:
            stack[sp] = left[node]
            stack[sp + 1] = right[node]
            sp += 2
    return False


@numba.njit(cache=True)
def _view_factors(p, n, c, m, area, eps, lo, hi, left, right, first, count, order, v0, e1, e2):
    """COO triplets (receiver, source, F) of the pairs that see each other."""
    cap = 1024
    rows = np.empty(cap, np.int64)
    cols = np.empty(cap, np.int64)
    vals = np.empty(cap, np.float64)
    k = 0
    for i in range(p.shape[0]):
        ox = p[i, 0] + eps * n[i, 0]
        oy = p[i, 1] + eps * n[i, 1]
        oz = p[i, 2] + eps * n[i, 2]
        for j in range(c.shape[0]):
            dx = c[j, 0] + eps * m[j, 0] - ox
            dy = c[j, 1] + eps * m[j, 1] - oy
            dz = c[j, 2] + eps * m[j, 2] - oz
            r2 = dx * dx + dy * dy + dz * dz
            if r2 <= 0.0:
                continue
            r = math.sqrt(r2)
            ci = (n[i, 0] * dx + n[i, 1] * dy + n[i, 2] * dz) / r
            cj = -(m[j, 0] * dx + m[j, 1] * dy + m[j, 2] * dz) / r
            if ci <= 0.0 or cj <= 0.0:
                continue
            f = ci * cj * area[j] / (math.pi * r2 + ci * cj * area[j])
            if _hits(ox, oy, oz, dx / r, dy / r, dz / r, r * (1.0 - 1e-6), lo, hi, left,
                     right, first, count, order, v0, e1, e2):
                continue
            if k == cap:
                cap *= 2
                rows2 = np.empty(cap, np.int64)
                cols2 = np.empty(cap, np.int64)
                vals2 = np.empty(cap, np.float64)
                rows2[:k] = rows[:k]
                cols2[:k] = cols[:k]
                vals2[:k] = vals[:k]
                rows, cols, vals = rows2, cols2, vals2
            rows[k] = i
            cols[k] = j
            vals[k] = f
            k += 1
    return rows[:k], cols[:k], vals[:k]


@numba.njit(cache=True)
def _sunlit(c, corners, m, s, eps, lo, hi, left, right, first, count, order, v0, e1, e2):
    """Each face's cosine to the sun times the fraction of its sun rays that are free.

    Rays leave the centroid and the midpoints between it and each corner.
    """
    out = np.zeros(c.shape[0])
    for j in range(c.shape[0]):
        mu0 = m[j, 0] * s[0] + m[j, 1] * s[1] + m[j, 2] * s[2]
        if mu0 <= 0.0:
            continue
        free = 0
        for k in range(SUN_SAMPLES):
            w = 0.0 if k == 0 else 0.5
            q = corners[j, max(k - 1, 0)]
            x = c[j, 0] + w * (q[0] - c[j, 0]) + eps * m[j, 0]
            y = c[j, 1] + w * (q[1] - c[j, 1]) + eps * m[j, 1]
            z = c[j, 2] + w * (q[2] - c[j, 2]) + eps * m[j, 2]
            if not _hits(x, y, z, s[0], s[1], s[2], 1e300, lo, hi, left, right, first, count,
                         order, v0, e1, e2):
                free += 1
        out[j] = mu0 * free / SUN_SAMPLES
    return out


@numba.njit(cache=True)
def _mutual(p, n, c, m, area, b):
    """Irradiance at receivers (p, n) from Lambertian faces (c, m, area) of radiosity b."""
    out = np.zeros(p.shape[0])
    for j in range(c.shape[0]):
        if b[j] <= 0.0:
            continue
        for i in range(p.shape[0]):
            dx = c[j, 0] - p[i, 0]
            dy = c[j, 1] - p[i, 1]
            dz = c[j, 2] - p[i, 2]
            r2 = dx * dx + dy * dy + dz * dz
            if r2 <= 0.0:
                continue
            r = math.sqrt(r2)
            ci = (n[i, 0] * dx + n[i, 1] * dy + n[i, 2] * dz) / r
            cj = -(m[j, 0] * dx + m[j, 1] * dy + m[j, 2] * dz) / r
            if ci <= 0.0 or cj <= 0.0:
                continue
            a = ci * cj * area[j]
            out[i] += b[j] * a / (math.pi * r2 + a)
    return out


class BodyLight:
    """A body's single scattering: view factors once, irradiance per sun (module docstring).

    Parameters
    ----------
    vertices : (n, 3) float, metres
        The patch mesh's vertices, body frame.
    faces : (m, 3) int
        Its triangles, wound so that ``(v1 - v0) x (v2 - v0)`` points to the lit side.
    normals : (n, 3) float, optional
        The receivers' normals (default: area-weighted from the faces).
    albedo : (n,) float, optional
        Albedo factor per vertex; a source face takes the mean of its three.

    Attributes
    ----------
    pairs : int
        Receiver-source pairs that see each other.
    edge : float, metres
        The patch mesh's median edge.
    """

    def __init__(self, vertices: Any, faces: Any, *, normals: Any = None,
                 albedo: Any = None) -> None:
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise InvalidParameterError(f"patch vertices must be (n, 3) finite; got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
            raise InvalidParameterError(
                f"patch faces must be (m, 3) indices into the vertices; got {f.shape}")
        if len(f) > MAX_PATCH_FACES:
            raise InvalidParameterError(
                f"a scattering patch mesh holds at most {MAX_PATCH_FACES} faces; got {len(f)}")
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        cross = np.cross(b - a, c - a)
        dbl = np.linalg.norm(cross, axis=1)
        keep = dbl > 0
        self.area = 0.5 * dbl[keep]
        self.normals_f = cross[keep] / dbl[keep, None]
        self.centroids = ((a + b + c) / 3.0)[keep]
        self._corners = np.ascontiguousarray(np.stack([a, b, c], axis=1)[keep])
        if normals is None:
            from render.mesh_scene import vertex_normals
            normals = vertex_normals(v, f)
        self.normals_v = np.asarray(normals, dtype=np.float64).reshape(v.shape)
        self.vertices = v
        fa = np.ones(len(f)) if albedo is None else \
            np.asarray(albedo, dtype=np.float64).reshape(len(v))[f].mean(axis=1)
        self.face_albedo = fa[keep]
        e1, e2 = b - a, c - a
        self._bvh = _build_bvh(a, b, c)
        self._tri = (np.ascontiguousarray(a), np.ascontiguousarray(e1),
                     np.ascontiguousarray(e2))
        edge = float(np.median(np.linalg.norm(e1, axis=1)))
        self.edge = edge
        self.eps = RAY_OFFSET * edge
        view_factors: Any = _view_factors  # a numba dispatcher
        rows, cols, vals = view_factors(self.vertices, self.normals_v, self.centroids,
                                         self.normals_f, self.area, self.eps, *self._bvh,
                                         *self._tri)
        self.matrix = scipy.sparse.csr_matrix((vals, (rows, cols)),
                                              shape=(len(v), len(self.area)))
        self.pairs = int(len(vals))
        # only faces some receiver sees need their sunlight: on a mostly convex body, few
        self._seen = np.flatnonzero(np.diff(self.matrix.tocsc().indptr) > 0)
        self._matrix_seen = self.matrix[:, self._seen].tocsr()
        self._cache: OrderedDict = OrderedDict()

    def radiosity(self, sun: Any, albedo: float) -> np.ndarray:
        """Give every face's radiosity over the solar irradiance, ``A a_j mu0_j v_j``.

        The sun is snapped to the lattice of :func:`snap_direction` and the result cached.

        Parameters
        ----------
        sun : (3,) float
            Direction towards the sun, body frame.
        albedo : float
            The scene's normal albedo A.

        Returns
        -------
        (m,) float64
            One value per face of positive area.
        """
        s = np.asarray(snap_direction(sun, SUN_STEP_DEG), dtype=np.float64)
        key = ("radiosity", tuple(s.tolist()), float(albedo))
        if key not in self._cache:
            sunlit: Any = _sunlit
            mu0 = sunlit(self.centroids, self._corners, self.normals_f, s, self.eps,
                         *self._bvh, *self._tri)
            b = float(albedo) * self.face_albedo * mu0
            b.flags.writeable = False
            self._cache[key] = b
            while len(self._cache) > CACHE:
                self._cache.popitem(last=False)
        self._cache.move_to_end(key)
        return self._cache[key]

    def irradiance(self, sun: Any, albedo: float, *, snap: bool = True) -> np.ndarray:
        """Give the scattered irradiance over the solar irradiance at every patch vertex.

        Parameters
        ----------
        sun : (3,) float
            Direction towards the sun, body frame.
        albedo : float
            The scene's normal albedo A (the sources' Lambertian reflectance).
        snap : bool
            Snap the sun to the lattice of :func:`snap_direction` (and cache per point).

        Returns
        -------
        (n,) float32
            E / F per patch vertex.
        """
        s = np.asarray(snap_direction(sun, SUN_STEP_DEG) if snap else sun, dtype=np.float64)
        s = s / np.linalg.norm(s)
        key = (tuple(s.tolist()), float(albedo))
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        sunlit: Any = _sunlit
        j = self._seen
        mu0 = sunlit(self.centroids[j], self._corners[j], self.normals_f[j], s, self.eps,
                     *self._bvh, *self._tri)
        e = (self._matrix_seen @ (float(albedo) * self.face_albedo[j] * mu0)).astype(np.float32)
        e.flags.writeable = False
        self._cache[key] = e
        while len(self._cache) > CACHE:
            self._cache.popitem(last=False)
        return e


def mutual_irradiance(receiver: BodyLight, source: BodyLight, rotation: Any, offset: Any,
                      sun: Any, albedo: float) -> np.ndarray:
    """Give the irradiance one body's sunlit surface sends onto another's patch vertices.

    The source's faces are Lambertian of radiosity ``A a_j mu0_j v_j`` (their own sunlight
    with the source's own shadows, :meth:`BodyLight.radiosity`), seen from each receiver vertex
    with the view factor of :class:`BodyLight` where each faces the other; nothing between
    them is looked for (the bodies are apart, and a receiver's own horizon is its tangent
    plane), nor the source's eclipse by the receiver.

    Parameters
    ----------
    receiver, source : BodyLight
        The two bodies' patch meshes, each in its own body frame.
    rotation : (3, 3) float
        Source body frame to receiver body frame.
    offset : (3,) float, metres
        The source's centre in the receiver's body frame.
    sun : (3,) float
        Direction towards the sun, the source's body frame.
    albedo : float
        The scene's normal albedo A.

    Returns
    -------
    (n,) float32
        E / F per receiver patch vertex.
    """
    rot = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
    b = source.radiosity(sun, albedo)
    c = source.centroids @ rot.T + np.asarray(offset, dtype=np.float64).reshape(3)
    m = source.normals_f @ rot.T
    mutual: Any = _mutual
    return mutual(receiver.vertices, receiver.normals_v, c, m, source.area, b).astype(
        np.float32)


def write_vertex_scatter(lod: Any, light: BodyLight, rotation: Any, lighting: Any,
                         extra: Any, spread: Any) -> None:
    """Write a level of detail's per-vertex scattered light, when the sun or ``extra`` changed.

    Parameters
    ----------
    lod : object
        The level's GPU record: ``sbo`` (its scatter buffer) and ``scatter_key`` (what the
        buffer was written from, or None).
    light : BodyLight
        The body's scattering.
    rotation : (3, 3) float
        Body frame to world.
    lighting : render.renderer.Lighting
        The frame's sun and albedo.
    extra : (n_patch,) float or None
        Light from elsewhere (a binary's companion), added at the patch vertices.
    spread : callable
        Patch-vertex values -> the level's vertex values.
    """
    sun = np.asarray(rotation).T @ np.asarray(lighting.sun, dtype=np.float64)
    e = light.irradiance(sun, lighting.albedo)
    if lod.scatter_key is None or lod.scatter_key[0] is not e or lod.scatter_key[1] is not extra:
        total = e if extra is None else e + extra
        lod.sbo.write(np.asarray(spread(total), dtype=np.float32).tobytes())
        lod.scatter_key = (e, extra)


def cluster_mesh(vertices: Any, faces: Any, max_faces: int = PATCH_FACES
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Simplify a mesh to at most ``max_faces`` faces by vertex clustering.

    The vertices in each cell of a cubic grid merge into their mean, and the faces whose
    corners fall in fewer than three cells (or repeat another) go (Rossignac & Borrel 1993,
    "Multi-resolution 3D approximations for rendering complex scenes"); the cell grows by a
    quarter until the faces fit. The result need not be a closed surface, which the view
    factors do not ask.

    Parameters
    ----------
    vertices : (n, 3) float, metres
        The mesh's vertices.
    faces : (m, 3) int
        Its triangles (their winding is kept).
    max_faces : int
        The most faces wanted.

    Returns
    -------
    vertices : (n', 3) float64
    faces : (m', 3) int64
        The simplified mesh (the input itself where it already fits).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) <= max_faces:
        return v, f
    lo = v.min(axis=0)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                axis=1).sum()
    cell = math.sqrt(2.0 * area / max_faces)  # about two faces a cell
    while True:
        key = np.floor((v - lo) / cell).astype(np.int64)
        _, label = np.unique(key, axis=0, return_inverse=True)
        label = label.reshape(-1)
        g = label[f]
        keep = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
        g = g[keep]
        _, first = np.unique(np.sort(g, axis=1), axis=0, return_index=True)
        g = g[np.sort(first)]
        if len(g) <= max_faces:
            break
        cell *= 1.25
    count = np.bincount(label)
    merged = np.zeros((len(count), 3))
    for k in range(3):
        merged[:, k] = np.bincount(label, weights=v[:, k]) / count
    used = np.unique(g)
    index = np.full(len(count), -1, np.int64)
    index[used] = np.arange(len(used))
    return merged[used], index[g]
