r"""The asteroid mesh: 6M^2 + 2 near-evenly spaced vertices on rings of latitude.

Martin, Parkes, Dunstan and Rowell (2014), *Asteroid modeling for testing spacecraft approach
and landing*, section III.A: "Magnitude M defines the number of rings of latitude in each
hemisphere, including the equator but ignoring the poles giving the number of mesh vertices as
6M^2+2. There are 6L vertices in latitude ring L where L = 1 corresponds to the latitude ring
closest to the pole and latitude ring M corresponds to the equator."

Layout
------
Rings are numbered globally from the north pole, ``g = 0 .. 2M``: ring 0 is the north pole,
rings ``1 .. M`` are the northern rings L = g (ring M is the shared equator), rings
``M + 1 .. 2M - 1`` are the southern rings L = 2M - g, and ring 2M is the south pole. Ring g
has ``6 min(g, 2M - g)`` vertices (one at a pole), lies at colatitude ``theta_g = pi g / (2M)``
(rings equally spaced in latitude) and its vertex ``p`` lies at longitude
``phi = 2 pi p / n_g``. The flat vertex index runs ring by ring from the north pole::

    offset(g) = 1 + 3 g (g - 1)                         (0 < g <= M; sum of 6L for L < g)
    offset(g) = N - 1 - 3 L (L - 1) - 6 L,  L = 2M - g   (M <= g < 2M)

so that ``index = offset(g) + p`` and ``N = 6 M^2 + 2``.

The mesh is the hexagonal bipyramid (six triangular faces around each pole) with each of its
12 faces subdivided M times: every ring is split into six 60 degree sectors, and in sector s
ring L holds L vertices (plus the first vertex of the next sector). Between a ring with L
vertices per sector (``a_0 .. a_L``) and its neighbour with L + 1 (``b_0 .. b_{L+1}``) the
sector's triangles are, in canonical order,

    D_0, U_0, D_1, U_1, ..., U_{L-1}, D_L
    D_i = (a_i, b_i, b_{i+1}),   U_i = (a_i, b_{i+1}, a_{i+1})

(2L + 1 triangles; wound counter-clockwise seen from outside in the north and reversed in the
south). The band between ring g and g + 1 is one long *strip* of ``6 (2L + 1)`` triangles
(the paper's Fig. 3, see :mod:`asteroid.patches`); in all there are ``12 M^2`` triangles.

Spacing
-------
With rings equally spaced in latitude, a ring step is ``pi / (2M)`` of arc; along a ring the
spacing falls from ``pi^2 / (6M)`` near the poles to ``pi / (3M)`` at the equator. The longest
edge (a diagonal near the poles, about 2.25 / M) is at most 2.25 times the shortest (an
equatorial ring edge, about 1.047 / M): measured 1.41, 1.70, 2.03, 2.11 and 2.15 for M = 1, 2,
16, 64, 256, tending to about 2.16 (see :func:`spacing_statistics`). The mean edge length is
close to that of a hexagonal lattice with the same number of vertices,
``a = sqrt(8 pi / (sqrt(3) N))`` (:attr:`SphereMesh.mean_spacing`, 1.555 / M; the measured
mean edge is 1.606 / M), the horizontal resolution
the crater model uses (the paper's "average distance between vertex points").

Examples
--------
>>> mesh = SphereMesh(2)
>>> mesh.n_vertices, mesh.n_faces, mesh.ring_sizes.tolist()
(26, 48, [1, 6, 12, 6, 1])
>>> mesh.ring_of(np.array([0, 1, 7, 25]))
(array([0, 1, 2, 4]), array([0, 0, 0, 0]))
>>> int(mesh.index_of(2, 13))     # positions wrap around the ring
8
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numba
import numpy as np

from terrain.core import memory
from terrain.core.errors import InvalidParameterError

__all__ = [
    "MAX_MAGNITUDE",
    "SphereMesh",
    "band_offset",
    "band_size",
    "band_small_ring",
    "band_triangle",
    "cap_ranges",
    "cap_vertices",
    "check_magnitude",
    "locate_scalar",
    "ring_offset",
    "ring_unit",
    "ring_size",
    "ring_vertex",
    "spacing_statistics",
    "surface_radius_scalar",
    "unit_vertex",
]

#: Largest magnitude accepted: 6 M^2 + 2 < 2^63 keeps every index an int64, and any real
#: request is refused far below this by the memory check.
MAX_MAGNITUDE = 1_000_000_000
#: Bytes a full mesh holds per vertex: unit directions (24) and the radius (8).
BYTES_PER_VERTEX = 32
#: Bytes of the face array per vertex (2 triangles of three int64 indices).
FACE_BYTES_PER_VERTEX = 48


def check_magnitude(magnitude) -> int:
    """Validate the magnitude M (an integer >= 1) and return it.

    >>> check_magnitude(400)
    400
    >>> check_magnitude(0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: magnitude M must be an integer >= 1 ...; got 0
    """
    if isinstance(magnitude, bool) or not isinstance(magnitude, (int, np.integer)):
        if isinstance(magnitude, float) and magnitude.is_integer():
            magnitude = int(magnitude)
        else:
            raise InvalidParameterError(
                f"magnitude M must be an integer >= 1 (rings per hemisphere); got {magnitude!r}")
    magnitude = int(magnitude)
    if not 1 <= magnitude <= MAX_MAGNITUDE:
        raise InvalidParameterError(
            f"magnitude M must be an integer >= 1 (rings per hemisphere); got {magnitude}")
    return magnitude


# ----------------------------------------------------------------------------------------
# compiled index arithmetic (shared by the mesh, the patches and the crater kernel)


@numba.njit(cache=True)
def ring_size(m, g):
    """Vertices in global ring g (1 at a pole)."""
    if g == 0 or g == 2 * m:
        return 1
    return 6 * min(g, 2 * m - g)


@numba.njit(cache=True)
def ring_offset(m, g):
    """Flat index of the first vertex of global ring g (g = 2M + 1 gives N)."""
    if g <= m:
        return 0 if g == 0 else 1 + 3 * g * (g - 1)
    n = 6 * m * m + 2
    if g > 2 * m:
        return n
    el = 2 * m - g
    if el == 0:
        return n - 1
    return n - 1 - 3 * el * (el - 1) - 6 * el


@numba.njit(cache=True)
def band_small_ring(m, b):
    """(small ring, large ring, L) of band b (between rings b and b + 1); L vertices/sector."""
    if b < m:
        return b, b + 1, b
    return b + 1, b, 2 * m - 1 - b


@numba.njit(cache=True)
def band_size(m, b):
    """Triangles in band b: 6 (2L + 1)."""
    return 6 * (2 * min(b, 2 * m - 1 - b) + 1)


@numba.njit(cache=True)
def band_offset(m, b):
    """Index of the first triangle of band b in the canonical face order (b = 2M gives 12M^2)."""
    if b <= m:
        return 6 * b * b
    el = 2 * m - b
    return 12 * m * m - 6 * el * el


@numba.njit(cache=True)
def ring_vertex(m, g, p):
    """Flat index of position p (any integer; wraps) on global ring g."""
    n = ring_size(m, g)
    return ring_offset(m, g) + (p % n)


@numba.njit(cache=True)
def _ring_of_scalar(m, i):
    """Global ring of flat index i (closed form with an integer correction)."""
    n = 6 * m * m + 2
    if i == 0:
        return 0
    if i == n - 1:
        return 2 * m
    half = ring_offset(m, m + 1)
    if i < half:
        g = int((3.0 + math.sqrt(9.0 + 12.0 * (i - 1))) / 6.0)
        g = max(1, min(m, g))
        while ring_offset(m, g) > i:
            g -= 1
        while ring_offset(m, g + 1) <= i:
            g += 1
        return g
    j = n - 1 - i  # counts from the south pole
    el = int((3.0 + math.sqrt(9.0 + 12.0 * (j - 1))) / 6.0)
    g = max(m + 1, min(2 * m - 1, 2 * m - el))
    while ring_offset(m, g) > i:
        g -= 1
    while ring_offset(m, g + 1) <= i:
        g += 1
    return g


@numba.njit(cache=True)
def _ring_of(m, idx, rings, positions):
    for k in range(idx.size):
        g = _ring_of_scalar(m, idx[k])
        rings[k] = g
        positions[k] = idx[k] - ring_offset(m, g)



@numba.njit(cache=True)
def band_triangle(m, b, t):
    """Outward-wound vertices of triangle t (0 <= t < band_size) of band b."""
    gs, gl, el = band_small_ring(m, b)
    per = 2 * el + 1
    s = t // per
    k = t - s * per
    i = k // 2
    na = ring_size(m, gs)
    nb = ring_size(m, gl)
    oa = ring_offset(m, gs)
    ob = ring_offset(m, gl)
    a_i = oa + ((s * el + i) % na)
    b_next = ob + ((s * (el + 1) + i + 1) % nb)
    if k % 2 == 0:
        v1 = ob + ((s * (el + 1) + i) % nb)
        v2 = b_next
    else:
        v1 = b_next
        v2 = oa + ((s * el + i + 1) % na)
    if b < m:
        return a_i, v1, v2
    return a_i, v2, v1


@numba.njit(cache=True)
def ring_unit(m, g, p):
    """Return the unit vector of position p (0 <= p < n_g) on global ring g.

    The one formula every direction of the mesh comes from, so all of them agree bitwise.
    """
    if g == 0:
        return 0.0, 0.0, 1.0
    if g == 2 * m:
        return 0.0, 0.0, -1.0
    if 2 * g == 2 * m:
        st, ct = 1.0, 0.0
    else:
        theta = math.pi * g / (2 * m)
        st = math.sin(theta)
        ct = math.cos(theta)
    phi = 2.0 * math.pi * p / ring_size(m, g)
    return st * math.cos(phi), st * math.sin(phi), ct


@numba.njit(cache=True)
def _faces(m, out):
    t = 0
    for b in range(2 * m):
        for k in range(band_size(m, b)):
            v0, v1, v2 = band_triangle(m, b, k)
            out[t, 0] = v0
            out[t, 1] = v1
            out[t, 2] = v2
            t += 1


@numba.njit(cache=True)
def _directions(m, out):
    for g in range(2 * m + 1):
        o = ring_offset(m, g)
        for p in range(ring_size(m, g)):
            out[o + p, 0], out[o + p, 1], out[o + p, 2] = ring_unit(m, g, p)


@numba.njit(cache=True)
def _neighbours_scalar(m, i, out):
    """Mesh neighbours of vertex i, written to ``out`` (size >= 6); returns how many."""
    g = _ring_of_scalar(m, i)
    p = i - ring_offset(m, g)
    count = 0
    if g == 0 or g == 2 * m:
        ring = 1 if g == 0 else 2 * m - 1
        for q in range(6):
            out[count] = ring_vertex(m, ring, q)
            count += 1
        return count
    n = ring_size(m, g)
    el = n // 6
    out[0] = ring_vertex(m, g, p - 1)
    out[1] = ring_vertex(m, g, p + 1)
    count = 2
    s = p // el
    q = p - s * el
    for dg in (-1, 1):
        h = g + dg
        nh = ring_size(m, h)
        if nh == 1:
            out[count] = ring_offset(m, h)
            count += 1
        elif nh > n:  # larger ring: L + 1 per sector
            out[count] = ring_vertex(m, h, s * (el + 1) + q)
            out[count + 1] = ring_vertex(m, h, s * (el + 1) + q + 1)
            count += 2
            if q == 0:
                out[count] = ring_vertex(m, h, s * (el + 1) - 1)
                count += 1
        else:  # smaller ring: L - 1 per sector
            if q == 0:
                out[count] = ring_vertex(m, h, s * (el - 1))
                count += 1
            else:
                out[count] = ring_vertex(m, h, s * (el - 1) + q - 1)
                out[count + 1] = ring_vertex(m, h, s * (el - 1) + q)
                count += 2
    return count


@numba.njit(cache=True)
def _across_scalar(m, i, dg):
    """Vertex of ring g + dg nearest in longitude to vertex i (continuing over the poles)."""
    g = _ring_of_scalar(m, i)
    p = i - ring_offset(m, g)
    n = ring_size(m, g)
    phi = 2.0 * math.pi * p / n
    h = g + dg
    if h < 0:
        h = -h
        phi += math.pi
    elif h > 2 * m:
        h = 4 * m - h
        phi += math.pi
    nh = ring_size(m, h)
    q = int(math.floor(phi * nh / (2.0 * math.pi) + 0.5))
    return ring_vertex(m, h, q)


@numba.njit(cache=True)
def cap_ranges(m, cx, cy, cz, angle, ranges):
    """Rings and position ranges of every vertex within ``angle`` rad of the unit (cx, cy, cz).

    Writes ``(ring, first position, count)`` rows into ``ranges`` ((2M + 1, 3) int64) and
    returns the number of rows; positions wrap around their ring. The test is conservative by
    1e-9 rad (callers apply their exact distance test), and a cap of angle >= pi is the sphere.
    """
    theta_c = math.acos(min(1.0, max(-1.0, cz)))
    phi_c = math.atan2(cy, cx)
    if phi_c < 0.0:
        phi_c += 2.0 * math.pi
    st_c = math.sin(theta_c)
    ct_c = math.cos(theta_c)
    a = angle + 1e-9
    ca = math.cos(a)
    step = math.pi / (2 * m)
    g_lo = max(0, int(math.floor((theta_c - a) / step)))
    g_hi = min(2 * m, int(math.ceil((theta_c + a) / step)))
    rows = 0
    for g in range(g_lo, g_hi + 1):
        theta = g * step
        n = ring_size(m, g)
        if abs(theta - theta_c) > a:
            continue
        if n == 1 or a >= math.pi:
            ranges[rows, 0] = g
            ranges[rows, 1] = 0
            ranges[rows, 2] = n
            rows += 1
            continue
        st = math.sin(theta)
        denom = st_c * st
        if denom <= 1e-300:
            cos_dphi = -2.0
        else:
            cos_dphi = (ca - ct_c * math.cos(theta)) / denom
        if cos_dphi <= -1.0:
            ranges[rows, 0] = g
            ranges[rows, 1] = 0
            ranges[rows, 2] = n
            rows += 1
            continue
        dphi = math.acos(min(1.0, cos_dphi)) + 1e-9
        scale = n / (2.0 * math.pi)
        p_lo = int(math.ceil((phi_c - dphi) * scale))
        p_hi = int(math.floor((phi_c + dphi) * scale))
        count = p_hi - p_lo + 1
        if count <= 0:
            continue
        if count >= n:
            p_lo = 0
            count = n
        ranges[rows, 0] = g
        ranges[rows, 1] = p_lo % n
        ranges[rows, 2] = count
        rows += 1
    return rows


@numba.njit(cache=True)
def cap_vertices(m, cx, cy, cz, angle):
    """Flat indices of the vertices within ``angle`` rad of a unit direction (conservative)."""
    ranges = np.empty((2 * m + 1, 3), dtype=np.int64)
    rows = cap_ranges(m, cx, cy, cz, angle, ranges)
    total = 0
    for r in range(rows):
        total += ranges[r, 2]
    out = np.empty(total, dtype=np.int64)
    k = 0
    for r in range(rows):
        g = ranges[r, 0]
        n = ring_size(m, g)
        o = ring_offset(m, g)
        p0 = ranges[r, 1]
        for j in range(ranges[r, 2]):
            out[k] = o + ((p0 + j) % n)
            k += 1
    return out


@numba.njit(cache=True)
def unit_vertex(m, i):
    """Return the unit vector of flat vertex index i."""
    g = _ring_of_scalar(m, i)
    return ring_unit(m, g, i - ring_offset(m, g))


@numba.njit(cache=True)
def _cone(ax, ay, az, bx, by, bz, cx, cy, cz, ux, uy, uz):
    """Cone coordinates of u for unit vertices A, B, C (Cramer's rule)."""
    bcx, bcy, bcz = by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx
    cax, cay, caz = cy * az - cz * ay, cz * ax - cx * az, cx * ay - cy * ax
    abx, aby, abz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    det = ax * bcx + ay * bcy + az * bcz
    return ((ux * bcx + uy * bcy + uz * bcz) / det, (ux * cax + uy * cay + uz * caz) / det,
            (ux * abx + uy * aby + uz * abz) / det)



#: Order in which locate_scalar tries the bands (0: the band of u's colatitude) and the
#: triangles around u's longitude: nearest first.
_BAND_ORDER = (0, -1, 1)
_TRIANGLE_ORDER = (0, 1, -1, 2, -2, 3, -3, 4)


@numba.njit(cache=True)
def locate_scalar(m, ux, uy, uz):
    """Canonical triangle whose cone holds the unit direction u, and u's cone coordinates.

    Returns ``(triangle, i0, i1, i2, alpha, beta, gamma)``. Candidates are the triangles
    around u's longitude in the band of its colatitude and the two bands beside it (a flat
    triangle's edge along a ring is a chord, so u may lie in the next band), nearest first;
    the first whose cone holds u (all coordinates >= 0) is returned, else the one whose
    smallest coordinate is largest. The answer depends on u alone.
    """
    theta = math.acos(min(1.0, max(-1.0, uz)))
    phi = math.atan2(uy, ux)
    if phi < 0.0:
        phi += 2.0 * math.pi
    step = math.pi / (2 * m)
    b0 = min(2 * m - 1, max(0, int(theta / step)))
    best = -1
    best_score = -1e300
    r0 = r1 = r2 = 0
    ra = rb = rc = 0.0
    sector_width = math.pi / 3.0
    for db in _BAND_ORDER:
        b = b0 + db
        if b < 0 or b > 2 * m - 1:
            continue
        gs, gl, el = band_small_ring(m, b)
        per = 2 * el + 1
        total = 6 * per
        s = min(5, int(phi / sector_width))
        f = (phi - s * sector_width) / sector_width
        base = s * per + 2 * int(f * el)
        off = band_offset(m, b)
        oa = ring_offset(m, gs)
        ob = ring_offset(m, gl)
        for dk in _TRIANGLE_ORDER:
            t = (base + dk) % total
            j0, j1, j2 = band_triangle(m, b, t)
            ax, ay, az = ring_unit(m, gs, j0 - oa)
            if b < m:  # (a, b, b) / (a, b, a) in the north, (a, b, b) reversed in the south
                bx, by, bz = ring_unit(m, gl, j1 - ob)
                g2, o2 = (gl, ob) if t % per % 2 == 0 else (gs, oa)
                cx, cy, cz = ring_unit(m, g2, j2 - o2)
            else:
                g1, o1 = (gl, ob) if t % per % 2 == 0 else (gs, oa)
                bx, by, bz = ring_unit(m, g1, j1 - o1)
                cx, cy, cz = ring_unit(m, gl, j2 - ob)
            al, be, ga = _cone(ax, ay, az, bx, by, bz, cx, cy, cz, ux, uy, uz)
            score = min(al, min(be, ga))
            if score > best_score:
                best_score = score
                best = off + t
                r0, r1, r2 = j0, j1, j2
                ra, rb, rc = al, be, ga
                if score >= 0.0:
                    return best, r0, r1, r2, ra, rb, rc
    return best, r0, r1, r2, ra, rb, rc


@numba.njit(cache=True)
def _locate(m, dirs, tri, idx, weights):
    for k in range(dirs.shape[0]):
        t, i0, i1, i2, a, b, c = locate_scalar(m, dirs[k, 0], dirs[k, 1], dirs[k, 2])
        tri[k] = t
        idx[k, 0] = i0
        idx[k, 1] = i1
        idx[k, 2] = i2
        weights[k, 0] = a
        weights[k, 1] = b
        weights[k, 2] = c


@numba.njit(cache=True)
def surface_radius_scalar(m, radii, ux, uy, uz):
    """Distance from the centre along unit u to the flat-triangle surface of ``radii``.

    In the triangle whose cone holds u, ``u = alpha A + beta B + gamma C``; the ray t u meets
    the plane through r_A A, r_B B, r_C C at ``t = 1 / (alpha / r_A + beta / r_B +
    gamma / r_C)`` (write t u as barycentric weights lambda_k of the three vertices: then
    lambda_k r_k = t x_k and the weights sum to one).
    """
    t, i0, i1, i2, a, b, c = locate_scalar(m, ux, uy, uz)
    return 1.0 / (a / radii[i0] + b / radii[i1] + c / radii[i2])


@numba.njit(cache=True)
def _surface_radius(m, radii, dirs, out):
    for k in range(dirs.shape[0]):
        out[k] = surface_radius_scalar(m, radii, dirs[k, 0], dirs[k, 1], dirs[k, 2])


# ----------------------------------------------------------------------------------------
# the mesh value type


def _as_index(index, n) -> np.ndarray:
    idx = np.asarray(index)
    if idx.dtype.kind not in "iu":
        raise InvalidParameterError(f"vertex indices must be integers; got dtype {idx.dtype}")
    idx = idx.astype(np.int64, copy=False)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise InvalidParameterError(
            f"vertex indices must lie in [0, {n}); got {int(idx.min())}..{int(idx.max())}")
    return idx


def _unit_vectors(directions) -> np.ndarray:
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim == 1:
        d = d[None, :]
    if d.ndim != 2 or d.shape[1] != 3:
        raise InvalidParameterError(f"directions must be (n, 3) floats; got shape {d.shape}")
    norm = np.linalg.norm(d, axis=1)
    if not np.all(np.isfinite(norm)) or np.any(norm == 0):
        raise InvalidParameterError("directions must be finite and non-zero")
    return np.ascontiguousarray(d / norm[:, None])


@dataclass(frozen=True)
class SphereMesh:
    """The latitude/longitude mesh of magnitude M (section III.A).

    Parameters
    ----------
    magnitude : int
        M >= 1: rings per hemisphere including the equator.

    Notes
    -----
    The mesh is a pure function of M: index arithmetic is closed-form, and the arrays
    (unit directions, faces) are computed on demand, the directions cached.
    """

    magnitude: int

    def __post_init__(self):
        object.__setattr__(self, "magnitude", check_magnitude(self.magnitude))

    # --- counts ------------------------------------------------------------------------

    @property
    def n_vertices(self) -> int:
        """6 M^2 + 2."""
        return 6 * self.magnitude**2 + 2

    @property
    def n_faces(self) -> int:
        """12 M^2 triangles."""
        return 12 * self.magnitude**2

    @property
    def n_rings(self) -> int:
        """2M + 1 global rings, the poles included."""
        return 2 * self.magnitude + 1

    @property
    def n_bands(self) -> int:
        """2M bands (triangle strips) between consecutive rings."""
        return 2 * self.magnitude

    @cached_property
    def ring_sizes(self) -> np.ndarray:
        """(2M + 1,) int64: vertices per global ring."""
        m = self.magnitude
        g = np.arange(2 * m + 1)
        sizes = 6 * np.minimum(g, 2 * m - g)
        sizes[0] = sizes[-1] = 1
        return sizes.astype(np.int64)

    @cached_property
    def ring_offsets(self) -> np.ndarray:
        """(2M + 2,) int64: flat index of each ring's first vertex, then N."""
        return np.concatenate([[0], np.cumsum(self.ring_sizes)]).astype(np.int64)

    @cached_property
    def band_offsets(self) -> np.ndarray:
        """(2M + 1,) int64: index of each band's first triangle, then 12 M^2."""
        m = self.magnitude
        b = np.arange(2 * m)
        sizes = 6 * (2 * np.minimum(b, 2 * m - 1 - b) + 1)
        return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

    @property
    def ring_colatitudes(self) -> np.ndarray:
        """(2M + 1,) float64 radians: ``pi g / (2M)``."""
        return np.pi * np.arange(self.n_rings) / (2 * self.magnitude)

    @property
    def mean_spacing(self) -> float:
        """Mean vertex spacing on the unit sphere: ``sqrt(8 pi / (sqrt(3) N))`` (radians)."""
        return math.sqrt(8.0 * math.pi / (math.sqrt(3.0) * self.n_vertices))

    # --- index arithmetic ----------------------------------------------------------------

    def ring_of(self, index) -> tuple[np.ndarray, np.ndarray]:
        """(global ring, position in ring) of flat indices; both int64 arrays."""
        idx = _as_index(index, self.n_vertices)
        flat = np.ascontiguousarray(idx).reshape(-1)
        rings = np.empty(flat.size, np.int64)
        pos = np.empty(flat.size, np.int64)
        _ring_of(self.magnitude, flat, rings, pos)
        return rings.reshape(idx.shape), pos.reshape(idx.shape)

    def index_of(self, ring, position) -> np.ndarray:
        """Flat index of (global ring, position); positions wrap around their ring."""
        ring = np.asarray(ring, dtype=np.int64)
        if ring.size and (ring.min() < 0 or ring.max() > 2 * self.magnitude):
            raise InvalidParameterError(
                f"rings must lie in [0, {2 * self.magnitude}]; got {int(ring.min())}.."
                f"{int(ring.max())}")
        position = np.asarray(position, dtype=np.int64)
        return self.ring_offsets[ring] + np.mod(position, self.ring_sizes[ring])

    def latitude_longitude(self, index=None) -> tuple[np.ndarray, np.ndarray]:
        """Latitude in [-pi/2, pi/2] and longitude in [0, 2 pi), radians, per vertex."""
        if index is None:
            index = np.arange(self.n_vertices)
        rings, pos = self.ring_of(index)
        lat = np.pi / 2 - np.pi * rings / (2 * self.magnitude)
        lon = 2 * np.pi * pos / self.ring_sizes[rings]
        return lat, lon

    def along(self, index, steps=1) -> np.ndarray:
        """Vertex ``steps`` positions east along the same ring (wrapping)."""
        rings, pos = self.ring_of(index)
        return self.index_of(rings, pos + np.asarray(steps, dtype=np.int64))

    def across(self, index, rings=1) -> np.ndarray:
        """Return the vertex of the ring ``rings`` further south nearest in longitude.

        Negative ``rings`` go north; a path over a pole continues on the far side
        (longitude + pi).
        """
        idx = _as_index(index, self.n_vertices)
        dg = np.broadcast_to(np.asarray(rings, dtype=np.int64), idx.shape)
        if dg.size and np.abs(dg).max() > 2 * self.magnitude:
            raise InvalidParameterError(
                f"a ring step must lie within +-{2 * self.magnitude}; got {int(np.abs(dg).max())}")
        out = np.empty(idx.shape, np.int64)
        flat_i, flat_d, flat_o = idx.reshape(-1), dg.reshape(-1), out.reshape(-1)
        for k in range(flat_i.size):
            flat_o[k] = _across_scalar(self.magnitude, int(flat_i[k]), int(flat_d[k]))
        return out

    def neighbours(self, index: int) -> np.ndarray:
        """Return the vertices sharing an edge with vertex ``index`` (4 or 6 of them), sorted."""
        i = int(_as_index(index, self.n_vertices))
        out = np.empty(8, np.int64)
        count = _neighbours_scalar(self.magnitude, i, out)
        return np.unique(out[:count])

    def cap(self, direction, angle: float) -> np.ndarray:
        """Return flat indices of vertices within ``angle`` radians of ``direction``.

        Conservative by 1e-9 rad; ring by ring from the north.
        """
        u = _unit_vectors(direction)[0]
        return cap_vertices(self.magnitude, u[0], u[1], u[2], float(angle))

    # --- arrays ----------------------------------------------------------------------------

    def directions(self, index=None) -> np.ndarray:
        """Return unit vectors of the vertices, (n, 3) float64 (all N when index is None).

        The full array is computed once and cached; rows are read-only.
        """
        if index is None:
            return self._all_directions
        idx = _as_index(index, self.n_vertices)
        return self._directions_exact(idx)

    def _directions_exact(self, idx) -> np.ndarray:
        out = np.empty((idx.size, 3))
        _directions_subset(self.magnitude, np.ascontiguousarray(idx).reshape(-1), out)
        return out.reshape(idx.shape + (3,))

    @cached_property
    def _all_directions(self) -> np.ndarray:
        memory.require(self.n_vertices * 24.0, f"the unit directions of a magnitude "
                       f"{self.magnitude} mesh ({self.n_vertices:,} vertices)")
        out = np.empty((self.n_vertices, 3))
        _directions(self.magnitude, out)
        out.flags.writeable = False
        return out

    def faces(self) -> np.ndarray:
        """(12 M^2, 3) int64 vertex indices, outward wound, in canonical band order."""
        memory.require(self.n_faces * 24.0, f"the faces of a magnitude {self.magnitude} mesh "
                       f"({self.n_faces:,} triangles)")
        out = np.empty((self.n_faces, 3), dtype=np.int64)
        _faces(self.magnitude, out)
        return out

    def locate(self, directions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the triangle holding each direction.

        Returns (triangle (n,) int64, its vertices (n, 3) int64, cone coordinates (n, 3) float64
        with ``u = sum_k w_k A_k`` for unit vertex vectors).
        """
        u = _unit_vectors(directions)
        tri = np.empty(len(u), np.int64)
        idx = np.empty((len(u), 3), np.int64)
        w = np.empty((len(u), 3))
        _locate(self.magnitude, u, tri, idx, w)
        return tri, idx, w

    def surface_radius(self, radii, directions) -> np.ndarray:
        """Return the distance from the centre to the mesh surface along each direction.

        The surface is made of flat triangles through the vertices at ``radii``; (n,) float64
        in the units of ``radii``.
        """
        radii = np.ascontiguousarray(radii, dtype=np.float64)
        if radii.shape != (self.n_vertices,):
            raise InvalidParameterError(
                f"radii must be ({self.n_vertices},) for magnitude {self.magnitude}; "
                f"got {radii.shape}")
        u = _unit_vectors(directions)
        out = np.empty(len(u))
        _surface_radius(self.magnitude, radii, u, out)
        return out


@numba.njit(cache=True)
def _directions_subset(m, idx, out):
    for k in range(idx.size):
        out[k, 0], out[k, 1], out[k, 2] = unit_vertex(m, idx[k])


def spacing_statistics(mesh: SphereMesh) -> dict:
    """Edge lengths of the unit-sphere mesh: min, max, mean and the max/min ratio.

    >>> s = spacing_statistics(SphereMesh(16))
    >>> round(s["ratio"], 3), round(s["mean"] * 16, 3)
    (2.027, 1.606)
    """
    faces = mesh.faces()
    d = mesh.directions()
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    lengths = np.linalg.norm(d[edges[:, 0]] - d[edges[:, 1]], axis=1)
    return dict(min=float(lengths.min()), max=float(lengths.max()), mean=float(lengths.mean()),
                ratio=float(lengths.max() / lengths.min()), edges=int(len(edges)))
