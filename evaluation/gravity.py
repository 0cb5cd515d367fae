r"""Gravity of a constant-density polyhedron (Werner and Scheeres 1997), and what a body feels.

The exact potential and attraction of a homogeneous closed polyhedron at any point, inside or
outside, follow from Gauss's divergence theorem applied twice (Werner and Scheeres 1997,
Celest. Mech. Dyn. Astron. 65, 313, eqs. 15-16)::

    U(p) = G sigma / 2 [ sum_e  r_e . E_e . r_e  L_e  -  sum_f  r_f . F_f . r_f  w_f ]
    g(p) = grad U = G sigma [ -sum_e  E_e . r_e  L_e  +  sum_f  F_f . r_f  w_f ]

with ``r_e``, ``r_f`` the vectors from the field point p to any point of edge e or face f,
``F_f = n_f n_f^T`` (outward unit face normal), ``E_e = n_A n_A,e^T + n_B n_B,e^T`` over the
two faces A, B meeting at edge e (``n_X,e`` the unit normal of the edge in the plane of face X,
pointing out of X), the edge factor ``L_e = ln((|r_i| + |r_j| + e) / (|r_i| + |r_j| - e))``
for an edge of length e between vertices i and j, and ``w_f`` the signed solid angle of face
f seen from p (Van Oosterom and Strackee 1983)::

    w_f = 2 atan2( r_i . (r_j x r_k),
                   |r_i||r_j||r_k| + |r_i| r_j.r_k + |r_j| r_k.r_i + |r_k| r_i.r_j )

``sum_f w_f`` is 4 pi inside the body and 0 outside, so the Laplacian ``-G sigma sum_f w_f``
is Poisson's ``-4 pi G sigma`` inside and zero outside.

The edge dyad is a sum of one term per face, so :func:`polyhedron_field` accumulates
``n_f n_f,e^T`` per face and per edge of that face instead of pairing faces across edges.
That costs two logarithms per edge instead of one, and buys robustness: it holds for any
closed, consistently oriented triangle surface, including the slightly non-manifold ones
vertex clustering makes (:func:`coarsen`), because every step of the derivation is a
divergence or Stokes theorem over one face.

A field point on an edge (``|r_i| + |r_j| = e``) makes ``L_e`` infinite while ``E_e r_e``
vanishes; the product tends to zero and is taken as zero.

Effective gravity
-----------------
A body spinning at angular rate omega about an axis through its centre of mass adds the
centrifugal acceleration ``omega^2 r_perp`` (r_perp: the point's distance vector from the
axis), as Li et al. (2022, Fig. 17, after Cheng et al. 2012) do for Eros. The centre of mass
of a homogeneous body is the centroid of its volume.

Coarsening
----------
The attraction varies smoothly over the surface; its sharp features are the surface's own,
and they matter only within a few of their sizes. :func:`coarsen` clusters the vertices on a
cubic grid (Rossignac and Borrel 1993), moves each cluster to the mean of its vertices, drops
the triangles that collapse and cancels pairs that become the same triangle wound both ways.
A closed surface stays closed (the image of a cycle under a vertex map is a cycle), which is
what the formula above needs. The density of the coarse body is scaled so it keeps the fine
body's mass.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numba
import numpy as np

from terrain.core import memory
from terrain.core.arctan import atan2
from terrain.core.errors import InvalidParameterError
from terrain.core.rows import unique_rows

__all__ = ["EROS_DENSITY", "EROS_PERIOD_H", "GRAVITATIONAL_CONSTANT", "Polyhedron",
           "centrifugal", "closed_chain", "coarsen", "polyhedron_field", "signed_volume"]

log = logging.getLogger(__name__)

#: Newtonian constant of gravitation, m^3 kg^-1 s^-2 (CODATA 2018).
GRAVITATIONAL_CONSTANT = 6.67430e-11
#: Bulk density of 433 Eros, kg m^-3: 2.67 +- 0.03 g cm^-3 (Yeomans et al. 2000, Science 289,
#: 2085).
EROS_DENSITY = 2670.0
#: Sidereal rotation period of 433 Eros, hours (Yeomans et al. 2000: 5.270 h).
EROS_PERIOD_H = 5.270
#: Field points evaluated per chunk (bounds the progress granularity).
CHUNK = 4096


def _as_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
        raise InvalidParameterError(f"vertices must be (n >= 4, 3) float; got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4 or not np.issubdtype(f.dtype, np.integer):
        raise InvalidParameterError(f"faces must be (m >= 4, 3) int; got {f.shape} {f.dtype}")
    f = np.ascontiguousarray(f, dtype=np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise InvalidParameterError("faces index vertices that do not exist")
    if not np.all(np.isfinite(v)):
        raise InvalidParameterError("vertices must be finite")
    return v, f


def signed_volume(vertices, faces) -> float:
    """Enclosed volume of a closed, outward-wound triangle surface (signed tetrahedra), m^3.

    >>> cube_v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    >>> round(signed_volume(cube_v, _CUBE_FACES), 12)
    1.0
    """
    v, f = _as_mesh(vertices, faces)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)



def closed_chain(faces) -> bool:
    """Return True when every edge is traversed as often in one direction as in the other.

    That is the condition for the divergence theorem, hence for :func:`polyhedron_field`; a
    manifold closed surface is the special case of once each way.

    >>> closed_chain(_CUBE_FACES), closed_chain(_CUBE_FACES[:-1])
    (True, False)
    """
    f = np.asarray(faces, dtype=np.int64)
    a = f.reshape(-1)
    b = np.roll(f, -1, axis=1).reshape(-1)
    n = int(f.max()) + 1
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * n + hi
    sign = np.where(a < b, 1, -1)
    uniq, inv = np.unique(key, return_inverse=True)
    balance = np.bincount(inv, weights=sign, minlength=uniq.size)
    return bool(np.all(balance == 0))


@dataclass(frozen=True, eq=False)
class Polyhedron:
    """A homogeneous closed polyhedron, with the per-face geometry the field needs.

    Parameters
    ----------
    vertices : (n, 3) float64, metres
    faces : (m, 3) int64
        Outward wound, forming a closed chain (:func:`closed_chain`).
    density : float, kg m^-3

    Examples
    --------
    >>> cube_v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    >>> p = Polyhedron.build(cube_v - 0.5, _CUBE_FACES, 1000.0)
    >>> round(p.mass, 6), round(p.volume, 12)
    (1000.0, 1.0)
    """

    vertices: np.ndarray
    faces: np.ndarray
    density: float
    normals: np.ndarray  # (m, 3) unit outward face normals
    edge_normals: np.ndarray  # (m, 3, 3) unit in-plane outward normal of edge k -> k+1
    face_edges: np.ndarray  # (m, 3) index of the undirected edge k -> k+1 in ``edges``
    edges: np.ndarray  # (e, 2) vertex indices of the undirected edges
    edge_lengths: np.ndarray  # (e,)
    volume: float

    @classmethod
    def build(cls, vertices, faces, density: float) -> Polyhedron:
        """Check a closed surface and precompute its face and edge normals."""
        v, f = _as_mesh(vertices, faces)
        density = float(density)
        if not (density > 0 and math.isfinite(density)):
            raise InvalidParameterError(f"density must be positive kg/m^3; got {density}")
        if not closed_chain(f):
            raise InvalidParameterError(
                "the polyhedron is not closed: some edges are not traversed equally often in "
                "both directions, so it has no inside for gravity")
        p = [v[f[:, k]] for k in range(3)]
        cross = np.cross(p[1] - p[0], p[2] - p[0])
        norm = np.linalg.norm(cross, axis=1)
        keep = norm > 0
        if not keep.all():  # zero-area triangles contribute nothing
            f, p, cross, norm = f[keep], [q[keep] for q in p], cross[keep], norm[keep]
        normals = cross / norm[:, None]
        edge_normals = np.empty((len(f), 3, 3))
        for k in range(3):
            en = np.cross(p[(k + 1) % 3] - p[k], normals)
            edge_normals[:, k] = en / np.linalg.norm(en, axis=1)[:, None]
        a = f.reshape(-1)
        b = np.roll(f, -1, axis=1).reshape(-1)
        pairs = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
        edges, face_edges = unique_rows(pairs, return_inverse=True)
        lengths = np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)
        volume = signed_volume(v, f)
        if not volume > 0:
            raise InvalidParameterError(
                f"the polyhedron encloses a non-positive volume ({volume:.6g} m^3); are its "
                "triangles wound inwards?")
        return cls(v, f, density, normals, edge_normals,
                   np.ascontiguousarray(face_edges.reshape(len(f), 3)),
                   np.ascontiguousarray(edges), lengths, volume)

    @property
    def mass(self) -> float:
        """Kg."""
        return self.density * self.volume

    def field(self, points, *, progress=None) -> tuple[np.ndarray, np.ndarray]:
        """Potential and attraction at points (see :func:`polyhedron_field`)."""
        return polyhedron_field(self, points, progress=progress)


#: Field points a block of :func:`_field` carries together, one per vector lane: each face's
#: corners, normals and edge normals are read once for the block, and the lanes' arithmetic
#: (the compiled ``atan2`` included) runs side by side. Each lane sums its terms in the order
#: one point alone would, so the block's size does not change a bit of the field.
LANES = 16


@numba.njit(cache=True, parallel=True)
def _field(v, f, normals, edge_normals, face_edges, edges, edge_lengths, points, gs, pot,
           acc):  # pragma: no cover - compiled
    """Werner and Scheeres (1997) eqs. 15-16, one face-edge at a time (module docstring).

    Per block of :data:`LANES` field points (the last point repeated to fill the last block):
    vertex distances once, ``L_e`` once per (undirected) edge, then the face and face-edge
    terms. The solid angle's ``atan2`` is :func:`terrain.core.arctan.atan2` (fdlibm's, plain
    arithmetic that vectorises and is the same on every machine; within 2 ulp of the C
    library's).
    """
    n_points = points.shape[0]
    n_faces = f.shape[0]
    n_vertices = v.shape[0]
    n_edges = edges.shape[0]
    n_blocks = (n_points + LANES - 1) // LANES
    for block in numba.prange(n_blocks):
        q0 = block * LANES
        px = np.empty(LANES)
        py = np.empty(LANES)
        pz = np.empty(LANES)
        for lane in range(LANES):
            q = min(q0 + lane, n_points - 1)
            px[lane], py[lane], pz[lane] = points[q, 0], points[q, 1], points[q, 2]
        rn = np.empty((n_vertices, LANES))
        for i in range(n_vertices):
            vx, vy, vz = v[i, 0], v[i, 1], v[i, 2]
            for lane in range(LANES):
                rn[i, lane] = math.sqrt((vx - px[lane]) ** 2 + (vy - py[lane]) ** 2
                                        + (vz - pz[lane]) ** 2)
        le = np.empty((n_edges, LANES))
        for e in range(n_edges):
            a, b = edges[e, 0], edges[e, 1]
            length = edge_lengths[e]
            for lane in range(LANES):
                s = rn[a, lane] + rn[b, lane]
                if s - length <= 1e-12 * s:
                    le[e, lane] = 0.0  # field point on the edge: the term's limit is zero
                else:
                    le[e, lane] = math.log((s + length) / (s - length))
        u = np.zeros(LANES)
        gx = np.zeros(LANES)
        gy = np.zeros(LANES)
        gz = np.zeros(LANES)
        for t in range(n_faces):
            i0, i1, i2 = f[t, 0], f[t, 1], f[t, 2]
            v00, v01, v02 = v[i0, 0], v[i0, 1], v[i0, 2]
            v10, v11, v12 = v[i1, 0], v[i1, 1], v[i1, 2]
            v20, v21, v22 = v[i2, 0], v[i2, 1], v[i2, 2]
            nx, ny, nz = normals[t, 0], normals[t, 1], normals[t, 2]
            m00, m01, m02 = edge_normals[t, 0, 0], edge_normals[t, 0, 1], edge_normals[t, 0, 2]
            m10, m11, m12 = edge_normals[t, 1, 0], edge_normals[t, 1, 1], edge_normals[t, 1, 2]
            m20, m21, m22 = edge_normals[t, 2, 0], edge_normals[t, 2, 1], edge_normals[t, 2, 2]
            e0, e1, e2 = face_edges[t, 0], face_edges[t, 1], face_edges[t, 2]
            for lane in range(LANES):
                # the corners relative to the field point, r_k = v_k - p; every sum is formed
                # in the order one point alone forms it
                r00, r01, r02 = v00 - px[lane], v01 - py[lane], v02 - pz[lane]
                r10, r11, r12 = v10 - px[lane], v11 - py[lane], v12 - pz[lane]
                r20, r21, r22 = v20 - px[lane], v21 - py[lane], v22 - pz[lane]
                n0, n1, n2 = rn[i0, lane], rn[i1, lane], rn[i2, lane]
                # face term F_f r_f w_f with r_f = r_0 (Van Oosterom and Strackee 1983 for w_f)
                cx = r11 * r22 - r12 * r21
                cy = r12 * r20 - r10 * r22
                cz = r10 * r21 - r11 * r20
                triple = r00 * cx + r01 * cy + r02 * cz
                d01 = r00 * r10 + r01 * r11 + r02 * r12
                d12 = r10 * r20 + r11 * r21 + r12 * r22
                d20 = r20 * r00 + r21 * r01 + r22 * r02
                omega = 2.0 * atan2(triple, n0 * n1 * n2 + n0 * d12 + n1 * d20 + n2 * d01)
                nr = nx * r00 + ny * r01 + nz * r02
                u[lane] -= nr * nr * omega
                # edge terms of this face, n_f (n_fe . r_e) L_e; n_f . r_e = nr on the face
                en0 = m00 * r00 + m01 * r01 + m02 * r02
                en1 = m10 * r10 + m11 * r11 + m12 * r12
                en2 = m20 * r20 + m21 * r21 + m22 * r22
                edge_sum = 0.0
                edge_sum += en0 * le[e0, lane]
                edge_sum += en1 * le[e1, lane]
                edge_sum += en2 * le[e2, lane]
                u[lane] += nr * edge_sum
                c = nr * omega - edge_sum
                gx[lane] += nx * c
                gy[lane] += ny * c
                gz[lane] += nz * c
        for lane in range(min(LANES, n_points - q0)):
            q = q0 + lane
            pot[q] = 0.5 * gs * u[lane]
            acc[q, 0] = gs * gx[lane]
            acc[q, 1] = gs * gy[lane]
            acc[q, 2] = gs * gz[lane]


def polyhedron_field(body: Polyhedron, points, *, progress=None) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """Gravitational potential and attraction of a homogeneous polyhedron.

    Parameters
    ----------
    body : Polyhedron
    points : (n, 3) float64, metres
        Field points, anywhere (inside, outside, on the surface).
    progress : callable, optional
        ``progress(done, total)`` after each chunk of :data:`CHUNK` points.

    Returns
    -------
    potential : (n,) float64, J/kg (m^2 s^-2)
        Positive, ``G M / r`` far away.
    attraction : (n, 3) float64, m s^-2
        The gravitational acceleration ``grad U`` (pointing into the body).

    Examples
    --------
    Far from a unit cube of 1000 kg the field is a point mass's:

    >>> cube_v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    >>> p = Polyhedron.build(cube_v - 0.5, _CUBE_FACES, 1000.0)
    >>> u, g = polyhedron_field(p, [[0.0, 0.0, 100.0]])
    >>> round(float(u[0] / (GRAVITATIONAL_CONSTANT * 1000.0 / 100.0)), 6)
    1.0
    >>> round(float(g[0, 2] / (-GRAVITATIONAL_CONSTANT * 1000.0 / 100.0**2)), 6)
    1.0
    """
    if not isinstance(body, Polyhedron):
        raise InvalidParameterError(f"expected a Polyhedron; got {type(body).__name__}")
    pts = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=np.float64)))
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InvalidParameterError(f"points must be (n, 3) metres; got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise InvalidParameterError("field points must be finite")
    n = len(pts)
    memory.require(n * 32.0, f"gravity at {n:,} points")
    pot = np.empty(n)
    acc = np.empty((n, 3))
    gs = GRAVITATIONAL_CONSTANT * body.density
    for start in range(0, n, CHUNK):
        stop = min(n, start + CHUNK)
        _field(body.vertices, body.faces, body.normals, body.edge_normals, body.face_edges,
               body.edges, body.edge_lengths, pts[start:stop], gs, pot[start:stop],
               acc[start:stop])
        if progress is not None:
            progress(stop, n)
    return pot, acc


def centrifugal(points, *, rate: float, axis=(0.0, 0.0, 1.0), centre=(0.0, 0.0, 0.0)) \
        -> np.ndarray:
    """Centrifugal acceleration ``omega^2 r_perp`` of points on a body spinning at ``rate``.

    Parameters
    ----------
    points : (n, 3) float64, metres
    rate : float, rad/s
    axis : (3,) float
        Spin axis direction (normalised here).
    centre : (3,) float, metres
        A point on the axis (the centre of mass).

    Returns
    -------
    (n, 3) float64, m s^-2

    >>> centrifugal([[2.0, 0.0, 5.0]], rate=0.5).tolist()
    [[0.5, 0.0, 0.0]]
    """
    a = np.asarray(axis, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.linalg.norm(a) > 0:
        raise InvalidParameterError(f"spin axis must be a non-zero 3-vector; got {axis!r}")
    a = a / np.linalg.norm(a)
    rate = float(rate)
    if not math.isfinite(rate):
        raise InvalidParameterError(f"spin rate must be finite; got {rate}")
    r = np.atleast_2d(np.asarray(points, dtype=np.float64)) - np.asarray(centre, float)
    perp = r - np.outer(r @ a, a)
    return rate * rate * perp


def coarsen(vertices, faces, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """Return a closed surface with about ``target_faces`` triangles, by vertex clustering.

    See the module docstring. The grid step is searched so that the result lands within
    about 25 % of the target; a surface already at or below the target is returned as is.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        A closed chain (:func:`closed_chain`).
    target_faces : int
        At least 20.

    Returns
    -------
    vertices : (k, 3) float64
    faces : (l, 3) int64
        Still a closed chain.
    """
    v, f = _as_mesh(vertices, faces)
    if isinstance(target_faces, bool) or not isinstance(target_faces, (int, np.integer)) \
            or target_faces < 20:
        raise InvalidParameterError(f"target faces must be an integer >= 20; got "
                                    f"{target_faces!r}")
    if len(f) <= target_faces:
        return v, f
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
                                axis=1).sum()
    # a closed surface has about twice as many triangles as vertices; a cluster cell of side
    # s holds about s^2 of surface
    step = math.sqrt(area / (0.5 * target_faces))
    best: tuple[np.ndarray, np.ndarray] | None = None
    for _ in range(12):
        cv, cf = _cluster(v, f, step)
        if best is None or abs(len(cf) - target_faces) < abs(len(best[1]) - target_faces):
            best = (cv, cf)
        ratio = len(cf) / target_faces
        if 0.8 <= ratio <= 1.25 and len(cf) >= 4:
            break
        step *= math.sqrt(max(ratio, 0.05))
    assert best is not None  # the loop above runs at least once
    cv, cf = best
    if len(cf) < 4:
        raise InvalidParameterError(
            f"coarsening to {target_faces} triangles collapsed the body; ask for more")
    return cv, cf


def _cluster(v: np.ndarray, f: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    cell = np.floor((v - v.min(axis=0)) / step).astype(np.int64)
    _, cluster = unique_rows(cell, return_inverse=True)
    k = int(cluster.max()) + 1
    counts = np.bincount(cluster, minlength=k).astype(np.float64)
    cv = np.stack([np.bincount(cluster, weights=v[:, d], minlength=k) for d in range(3)],
                  axis=1) / counts[:, None]
    cf = cluster[f]
    keep = (cf[:, 0] != cf[:, 1]) & (cf[:, 1] != cf[:, 2]) & (cf[:, 0] != cf[:, 2])
    cf = cf[keep]
    # cancel triangles that now appear wound both ways (they bound nothing)
    rot = np.argmin(cf, axis=1)
    canon = np.stack([cf[np.arange(len(cf)), (rot + j) % 3] for j in range(3)], axis=1)
    flipped = canon[:, 1] > canon[:, 2]
    key = np.where(flipped[:, None], canon[:, [0, 2, 1]], canon)
    _, inv = unique_rows(key, return_inverse=True)
    sign = np.where(flipped, -1, 1)
    net = np.bincount(inv, weights=sign)
    # keep |net| copies of each group's triangle, wound by the sign of the net count
    order = np.argsort(inv, kind="stable")
    first_of = order[np.searchsorted(inv[order], np.arange(net.size))]
    reps = np.abs(net).astype(np.int64)
    base = key[first_of]
    wound = np.where((net < 0)[:, None], base[:, [0, 2, 1]], base)
    out = np.repeat(wound, reps, axis=0)
    used = np.unique(out)
    remap = np.full(k, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return cv[used], remap[out]


# The twelve outward triangles of the unit cube with vertices ordered (x, y, z) in {0, 1}^3
# as ``4 x + 2 y + z``; used by the doctests.
_CUBE_FACES = np.array([
    [0, 1, 3], [0, 3, 2],  # x = 0
    [4, 6, 7], [4, 7, 5],  # x = 1
    [0, 4, 5], [0, 5, 1],  # y = 0
    [2, 3, 7], [2, 7, 6],  # y = 1
    [0, 2, 6], [0, 6, 4],  # z = 0
    [1, 5, 7], [1, 7, 3],  # z = 1
], dtype=np.int64)
