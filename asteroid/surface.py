r"""Any closed surface as a body: craters and boulders on a triangle mesh kept as it is.

The 6M^2 + 2 mesh holds a radius per direction, so it cannot hold a body whose surface a ray
from the centre crosses more than once (a comet's two lobes and neck, a contact binary, an
overhang). Here the body is the watertight triangle mesh itself (a shape model read from a
file, or a synthetic base from :mod:`asteroid.packing`), and the features go onto the true
surface, as Li et al. (2022) do on their implicit surfaces:

1. **Sites, uniform by area, keyed by position.** Each triangle of the base mesh draws a
   Poisson number of features with mean ``density x area x (1 - (dmax/dmin)^k)`` (the
   population of :class:`terrain.craters.population.Population`), and each feature's
   barycentric position, diameter, age and identity, from hashes keyed by
   ``(seed, stream, quantised triangle centroid, feature index)``
   (:data:`POSITION_QUANTUM`). A triangle's features are a function of where it is alone, so
   a patch of the mesh computed alone gives exactly the features the whole body gives there,
   and the same seed gives the same bytes.
2. **Local refinement.** A crater needs a few vertices across it. Triangles within a crater's
   reach whose longest edge exceeds ``D / EDGES_PER_DIAMETER`` are split, only there
   (red-green refinement: a triangle with two or three split edges splits into four, one with
   a single split edge into two, so the mesh stays conforming and watertight); this repeats
   until every crater has its resolution, so the fine levels stay local.
3. **Crater kernels along the local normal.** For a crater at site p the local frame is the
   mean vertex normal n of the base surface within the bowl and two tangents; every vertex
   within reach (Euclidean distance ``D x footprint``) that faces the same way
   (``n_v . n > 0``, so the far side of a thin neck is left alone) has a height
   ``h = (v - p) . n`` and a distance ``s`` from the axis. A plane fitted to the heights in
   the bowl is the crater's reference, the project's crater profile
   (:func:`terrain.craters.crater.crater_interior`,
   :func:`terrain.craters.crater.exterior_height`, with erosion and the slope guard of
   :mod:`asteroid.craters`) gives the new height, and the vertex moves along n by the
   difference. Inside the bowl the relief about the plane fades with the obliteration weight
   (:func:`terrain.craters.cratering.obliteration`), as on the latitude/longitude mesh.
   Craters go in age order, oldest first.
4. **Boulders resting on the surface.** Boulders are drawn per triangle of the cratered
   surface the same way, shaped as :mod:`asteroid.boulders` shapes them, their short axis
   along the triangle's normal, and lifted so that their lowest point touches the surface,
   then sunk by a burial fraction of their height.

The rim is irregular as on the latitude/longitude mesh: the same fractal rim-radius table
(:func:`terrain.craters.overlay.rim_table`, keyed by the seed and the crater's identity, which
is keyed by its position) sets the rim radius along each azimuth of the local tangent frame.
Simplifications against :mod:`asteroid.craters`: no roughness overlay (it needs the
latitude/longitude crater grid); the rim rides on the fitted plane.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numba
import numpy as np

from asteroid.body import npy_member
from asteroid.boulders import BoulderSettings, local_shapes, rotation_x, rotation_y, rotation_z
from asteroid.craters import CraterSettings
from asteroid.errors import InvalidShapeError
from asteroid.shape import check_closed
from terrain.core import memory
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, hash64, poisson, stream_id, uniform_scalar
from terrain.craters.crater import crater_interior, exterior_height, shape_arrays
from terrain.craters.cratering import obliteration
from terrain.craters.overlay import RIM_SAMPLES, periodic_sample, rim_table
from terrain.craters.population import Population

__all__ = ["BOULDER_SITE_STREAM", "CRATER_SITE_STREAM", "MESH_FORMAT", "POSITION_QUANTUM",
           "MeshBody", "MeshBoulders", "MeshCraters", "Sites", "add_mesh_craters",
           "boulder_rotations", "boulder_settings", "load_mesh_native", "mesh_boulder_geometry",
           "native_format", "place_mesh_boulders", "refine", "sample_sites", "save_mesh_native",
           "split"]

log = logging.getLogger(__name__)

#: Triangle centroids are rounded to this many metres to key their features: far below any
#: triangle, far above floating-point noise in a file's coordinates.
POSITION_QUANTUM = 1.0e-3
#: Random streams of the features on a mesh body.
CRATER_SITE_STREAM = stream_id("asteroid-mesh-crater")
BOULDER_SITE_STREAM = stream_id("asteroid-mesh-boulder")
#: Longest triangle edge a crater of diameter D needs within its reach: D / this (the
#: latitude/longitude path's smallest crater spans 4 vertex spacings).
EDGES_PER_DIAMETER = 4.0
#: Refinement rounds at most (each halves the edges near a crater).
MAX_REFINE = 10
#: Reach of a crater's change, in diameters (ejecta to x = 1, r = D).
REACH = 1.0
#: Uniform draws per site: barycentric u, v, diameter, age, then extras.
_SITE_FIELDS = 4


# ----------------------------------------------------------------------------------------
# the body


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume of an outward-wound closed mesh (divergence theorem), m^3."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) triangle areas, m^2."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) unit outward normals."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) unit vertex normals, area-weighted mean of the adjacent triangles' normals."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    out = np.zeros_like(vertices)
    for i in range(3):
        np.add.at(out, faces[:, i], n)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)


@dataclass(frozen=True, eq=False)
class MeshBody:
    """A closed, outward-wound triangle mesh about its centre, in metres.

    Parameters
    ----------
    vertices : (n, 3) float64, metres
    faces : (m, 3) int64
    metadata : dict
        Provenance (seed, recipe, source).
    """

    vertices: np.ndarray
    faces: np.ndarray
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        v = np.ascontiguousarray(self.vertices, dtype=np.float64)
        f = np.ascontiguousarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise InvalidShapeError(f"mesh body vertices must be (n, 3); got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3:
            raise InvalidShapeError(f"mesh body faces must be (m, 3) int; got {f.shape}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @property
    def n_vertices(self) -> int:
        """Number of vertices."""
        return len(self.vertices)

    def volume(self) -> float:
        """Enclosed volume, m^3."""
        return signed_volume(self.vertices, self.faces)

    def area(self) -> float:
        """Surface area, m^2."""
        return float(face_areas(self.vertices, self.faces).sum())

    @property
    def equivalent_radius(self) -> float:
        """Radius of the sphere of the same volume, metres."""
        return (3.0 * self.volume() / (4.0 * math.pi)) ** (1.0 / 3.0)

    def mean_edge(self) -> float:
        """Mean triangle edge length, metres."""
        v, f = self.vertices, self.faces
        return float(np.mean(np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2)))

    def check_closed(self) -> None:
        """Raise :class:`InvalidShapeError` unless every edge has two triangles, one each way."""
        check_closed(self.faces, self.n_vertices, "mesh body")

    def replace(self, vertices=None, faces=None, **metadata) -> MeshBody:
        """Return a copy with new geometry and/or metadata merged in."""
        return MeshBody(self.vertices if vertices is None else vertices,
                        self.faces if faces is None else faces,
                        {**self.metadata, **metadata})


# ----------------------------------------------------------------------------------------
# sites keyed by position


@dataclass(frozen=True, eq=False)
class Sites:
    """Features drawn on a mesh: triangle, position, diameter, age, identity, extra draws.

    Parameters
    ----------
    face : (n,) int64
    points : (n, 3) float64, metres
    diameters : (n,) float64, metres
    ages : (n,) float64, Gyr
    uid : (n,) uint64
    extra : (n, k) float64 in (0, 1)
    """

    face: np.ndarray
    points: np.ndarray
    diameters: np.ndarray
    ages: np.ndarray
    uid: np.ndarray
    extra: np.ndarray

    def __len__(self) -> int:
        return len(self.face)


@numba.njit(cache=True)
def _count_sites(seed, stream, q, lam):
    counts = np.empty(q.shape[0], np.int64)
    for f in range(q.shape[0]):
        key = np.int64(hash64(seed, stream, 0, q[f, 0], q[f, 1], q[f, 2]) >> np.uint64(1))
        counts[f] = poisson(uniform_scalar(seed, stream, 1, key, 0, 0), lam[f])
    return counts


@numba.njit(cache=True)
def _draw_sites(seed, stream, q, counts, n_extra, out, uid):
    k = 0
    for f in range(q.shape[0]):
        key = np.int64(hash64(seed, stream, 0, q[f, 0], q[f, 1], q[f, 2]) >> np.uint64(1))
        for j in range(counts[f]):
            for i in range(_SITE_FIELDS + n_extra):
                out[k, i] = uniform_scalar(seed, stream, 2, key, j, i)
            uid[k] = hash64(seed, stream, 3, key, j, 0)
            k += 1


def sample_sites(vertices: np.ndarray, faces: np.ndarray, population: Population, *,
                 seed: int, stream: int, n_extra: int = 0,
                 max_features: int = 20_000_000) -> Sites:
    """Draw a population's features uniformly by area, keyed by each triangle's position.

    Parameters
    ----------
    vertices : (n, 3) float64, metres
    faces : (m, 3) int64
    population : Population
        Diameter range, density per km^2 of D >= dmin, exponent k, maximum age.
    seed : int
    stream : int
        Random stream (:func:`terrain.core.rng.stream_id`).
    n_extra : int
        Further uniform draws per feature (shapes, orientations).

    Examples
    --------
    >>> from asteroid.sphere import SphereMesh
    >>> m = SphereMesh(16)
    >>> v, f = m.directions() * 1000.0, m.faces()
    >>> p = Population(dmin=20.0, dmax=200.0, density=50.0)
    >>> a = sample_sites(v, f, p, seed=3, stream=1)
    >>> b = sample_sites(v, f[::2], p, seed=3, stream=1)   # a patch alone
    >>> bool(np.isin(b.uid, a.uid).all()), len(a) > len(b) > 0
    (True, True)
    """
    seed = check_seed(seed)
    areas = face_areas(vertices, faces)
    centroids = vertices[faces].mean(axis=1)
    q = np.floor(centroids / POSITION_QUANTUM).astype(np.int64)
    k = population.sfd_exponent
    frac = 1.0 - (population.dmax / population.dmin) ** k
    lam = areas * 1e-6 * population.density * frac
    counts = _count_sites(seed, int(stream), q, lam)
    total = int(counts.sum())
    if total > max_features:
        raise InvalidParameterError(
            f"the population asks for {total:,} features on this mesh (at most "
            f"{max_features:,}); raise dmin or lower the density")
    memory.require(total * (8.0 * (_SITE_FIELDS + n_extra + 8)), f"drawing {total:,} sites")
    draws = np.empty((total, _SITE_FIELDS + n_extra))
    uid = np.empty(total, np.uint64)
    _draw_sites(seed, int(stream), q, counts, n_extra, draws, uid)
    face = np.repeat(np.arange(len(faces), dtype=np.int64), counts)
    u, v = draws[:, 0], draws[:, 1]
    flip = u + v > 1.0
    u = np.where(flip, 1.0 - u, u)
    v = np.where(flip, 1.0 - v, v)
    a, b, c = (vertices[faces[face, i]] for i in range(3))
    points = a + u[:, None] * (b - a) + v[:, None] * (c - a)
    # truncated power law: N(>D) ~ D^k on [dmin, dmax)
    lo, hi = population.dmin**k, population.dmax**k
    diameters = (lo - draws[:, 2] * (lo - hi)) ** (1.0 / k)
    ages = population.max_age * draws[:, 3]
    return Sites(face, points, diameters, ages, uid, draws[:, _SITE_FIELDS:])


# ----------------------------------------------------------------------------------------
# local refinement


def _edges(faces: np.ndarray, n_vertices: int):
    """Return the unique undirected edges and each face's three edge ids (i joins i, i+1)."""
    a = faces
    b = np.roll(faces, -1, axis=1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    key = lo * np.int64(n_vertices) + hi
    uniq, inverse = np.unique(key.reshape(-1), return_inverse=True)
    return uniq, inverse.reshape(-1, 3)


def split(vertices: np.ndarray, faces: np.ndarray, marked: np.ndarray) \
        -> tuple[np.ndarray, np.ndarray]:
    """Split the marked triangles in four, and their neighbours so the mesh stays conforming.

    A triangle with two or three split edges is split in four (red), one with a single split
    edge in two (green). New vertices are the edges' midpoints, in the order of the sorted
    edge keys, so the result is a function of the input alone.
    """
    n = len(vertices)
    uniq, fe = _edges(faces, n)
    split_edge = np.zeros(len(uniq), bool)
    red = np.asarray(marked, bool).copy()
    while True:
        split_edge[fe[red].reshape(-1)] = True
        nsplit = split_edge[fe].sum(axis=1)
        more = (nsplit >= 2) & ~red
        if not more.any():
            break
        red |= more
    ids = np.flatnonzero(split_edge)
    mid_index = np.full(len(uniq), -1, np.int64)
    mid_index[ids] = n + np.arange(len(ids))
    ea, eb = uniq[ids] // n, uniq[ids] % n
    new_v = np.concatenate([vertices, 0.5 * (vertices[ea] + vertices[eb])])
    nsplit = split_edge[fe].sum(axis=1)
    keep = faces[nsplit == 0]
    r = faces[red]
    m = mid_index[fe[red]]
    a, b, c = r[:, 0], r[:, 1], r[:, 2]
    mab, mbc, mca = m[:, 0], m[:, 1], m[:, 2]
    red_children = np.concatenate([np.column_stack(t) for t in (
        (a, mab, mca), (mab, b, mbc), (mca, mbc, c), (mab, mbc, mca))])
    green = np.flatnonzero((nsplit == 1) & ~red)
    g = faces[green]
    j = np.argmax(split_edge[fe[green]], axis=1)
    rows = np.arange(len(green))
    a = g[rows, j]
    b = g[rows, (j + 1) % 3]
    c = g[rows, (j + 2) % 3]
    mm = mid_index[fe[green][rows, j]]
    green_children = np.concatenate([np.column_stack((a, mm, c)), np.column_stack((mm, b, c))])
    return new_v, np.concatenate([keep, red_children, green_children]).astype(np.int64)


def refine(vertices: np.ndarray, faces: np.ndarray, centres: np.ndarray,
           diameters: np.ndarray, *, edges_per_diameter: float = EDGES_PER_DIAMETER,
           reach: float = REACH, max_rounds: int = MAX_REFINE) \
        -> tuple[np.ndarray, np.ndarray, int]:
    """Refine the mesh near each crater until its edges are below ``D / edges_per_diameter``.

    Returns the vertices, the faces and the number of rounds used. Far from every crater the
    mesh is untouched.
    """
    from scipy.spatial import cKDTree

    rounds = 0
    if len(centres) == 0:
        return vertices, faces, 0
    order = np.argsort(diameters)
    centres = centres[order]
    diameters = diameters[order]
    for rounds in range(1, max_rounds + 1):
        v = vertices
        tri = v[faces]
        longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
        centroid = tri.mean(axis=1)
        # only craters that can see a triangle too coarse for them need a query
        need = diameters / edges_per_diameter < longest.max()
        if not need.any():
            return vertices, faces, rounds - 1
        tree = cKDTree(centroid)
        top = float(longest.max())
        marked = np.zeros(len(faces), bool)
        for c, d in zip(centres[need], diameters[need], strict=True):
            near = tree.query_ball_point(c, reach * d + top)
            if near:
                near = np.asarray(near)
                # a triangle is within reach when its centroid is within reach plus its size
                close = np.sum((centroid[near] - c) ** 2, axis=1) \
                    <= (reach * d + longest[near]) ** 2
                marked[near[close & (longest[near] > d / edges_per_diameter)]] = True
        if not marked.any():
            return vertices, faces, rounds - 1
        vertices, faces = split(vertices, faces, marked)
    log.warning("local refinement stopped after %d rounds", max_rounds)
    return vertices, faces, rounds


# ----------------------------------------------------------------------------------------
# craters along the local normal


@numba.njit(cache=True)
def _crater_on_mesh(verts, base_normals, idx, p, n, e1, e2, d, curvature, floor, hr, ejecta,
                    beta, ca, cb, c2, c3, cplx, want_slope, irregular, table):
    """Fit the plane, then move each vertex of ``idx`` along n; returns (applied, slope).

    With ``irregular`` the rim radius at azimuth theta (from e1 towards e2) is
    ``D / 2 + table(theta) D`` (:func:`terrain.craters.overlay.rim_table`), as on the
    latitude/longitude mesh.
    """
    m = idx.size
    hx = np.empty(m)
    hy = np.empty(m)
    hh = np.empty(m)
    ok = np.zeros(m, np.bool_)
    radius = 0.5 * d
    # normal equations of h = p0 + px x + py y over the bowl
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    t0 = t1 = t2 = 0.0
    nb = 0
    for k in range(m):
        i = idx[k]
        if (base_normals[i, 0] * n[0] + base_normals[i, 1] * n[1]
                + base_normals[i, 2] * n[2]) <= 0.0:
            continue
        rx = verts[i, 0] - p[0]
        ry = verts[i, 1] - p[1]
        rz = verts[i, 2] - p[2]
        h = rx * n[0] + ry * n[1] + rz * n[2]
        x = rx * e1[0] + ry * e1[1] + rz * e1[2]
        y = rx * e2[0] + ry * e2[1] + rz * e2[2]
        hx[k], hy[k], hh[k] = x, y, h
        ok[k] = True
        if x * x + y * y <= radius * radius:
            s00 += 1.0
            s01 += x
            s02 += y
            s11 += x * x
            s12 += x * y
            s22 += y * y
            t0 += h
            t1 += x * h
            t2 += y * h
            nb += 1
    if nb < 3:
        return False, math.nan
    a = np.array([[s00, s01, s02], [s01, s11, s12], [s02, s12, s22]])
    b = np.array([t0, t1, t2])
    if abs(np.linalg.det(a)) < 1e-12 * max(1.0, s11 * s22):
        p0, px, py = t0 / s00, 0.0, 0.0
    else:
        sol = np.linalg.solve(a, b)
        p0, px, py = sol[0], sol[1], sol[2]
    slope = math.atan(math.hypot(px, py))
    if want_slope:
        return False, slope
    for k in range(m):
        if not ok[k]:
            continue
        i = idx[k]
        x, y, h = hx[k], hy[k], hh[k]
        s = math.sqrt(x * x + y * y)
        rt = radius + periodic_sample(table, math.atan2(y, x)) * d if irregular else radius
        xr = s / rt - 1.0
        if xr > 1.0:
            continue
        if xr <= 0.0:
            plane = p0 + px * x + py * y
            hin = crater_interior(xr, curvature, floor, hr, cplx)
            new = plane + hin + (h - plane) * (1.0 - obliteration(xr))
        else:
            new = h + exterior_height(xr, hr, ejecta, beta, ca, cb, c2, c3)
        dh = new - h
        verts[i, 0] += dh * n[0]
        verts[i, 1] += dh * n[1]
        verts[i, 2] += dh * n[2]
    return True, slope


def _tangents(n):
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(helper, n)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


@dataclass(frozen=True, eq=False)
class MeshCraters:
    """Craters added to a mesh body: the body and the catalogue columns."""

    body: MeshBody
    catalog: dict
    refine_rounds: int = 0


#: Columns of a mesh body's crater catalogue.
MESH_CRATER_COLUMNS = ("id", "x", "y", "z", "nx", "ny", "nz", "diameter_m", "age_gyr",
                       "depth_fraction", "rim_fraction", "depth_m", "rim_height_m",
                       "slope_deg", "slope_factor", "applied")


def add_mesh_craters(body: MeshBody, sites: Sites, *, seed: int,
                     settings: CraterSettings | None = None, refine_mesh: bool = True,
                     progress=None) -> MeshCraters:
    """Add craters at ``sites`` to a mesh body, oldest first, along the local normal.

    Parameters
    ----------
    body : MeshBody
    sites : Sites
        From :func:`sample_sites` on this body's mesh.
    seed : int
        Recorded in the metadata.
    settings : CraterSettings, optional
        The crater model (erosion, morphology) and the slope guard.
    refine_mesh : bool
        Split triangles near craters that need more resolution (:func:`refine`).
    progress : callable, optional
        ``progress(done, total)``.
    """
    from scipy.spatial import cKDTree

    seed = check_seed(seed)
    settings = settings or CraterSettings()
    model = settings.model
    n = len(sites)
    order = np.lexsort((sites.uid, -sites.ages))
    verts, faces = body.vertices, body.faces
    rounds = 0
    if refine_mesh and n:
        verts, faces, rounds = refine(verts, faces, sites.points, sites.diameters)
    memory.require(len(verts) * 3 * 8.0 * 4 + n * 200.0,
                   f"adding {n:,} craters to {len(verts):,} vertices")
    base_normals = vertex_normals(verts, faces)
    verts = np.array(verts, dtype=np.float64, copy=True)
    tree = cKDTree(verts)
    depth_f0, rim_f0 = model.erosion.factors(sites.ages[order], sites.diameters[order])
    depth_f0 = np.atleast_1d(np.asarray(depth_f0, dtype=np.float64))
    rim_f0 = np.atleast_1d(np.asarray(rim_f0, dtype=np.float64))
    cols = {name: np.zeros(n) for name in MESH_CRATER_COLUMNS}
    cols["id"] = sites.uid[order].copy()
    cols["applied"] = np.zeros(n, np.int64)
    irregular = model.rim.effective_amplitude > 0.0
    table = np.zeros(RIM_SAMPLES)
    step = max(1, n // 200)
    for k, j in enumerate(order):
        if progress is not None and k % step == 0:
            progress(k, n)
        p = sites.points[j]
        d = float(sites.diameters[j])
        idx = np.asarray(tree.query_ball_point(p, REACH * d * model.footprint_factor),
                         dtype=np.int64)
        bowl = idx[np.sum((verts[idx] - p) ** 2, axis=1) <= (0.5 * d) ** 2]
        nrm = base_normals[bowl].sum(axis=0) if len(bowl) else np.zeros(3)
        length = float(np.linalg.norm(nrm))
        if length < 1e-12:
            f = faces[sites.face[j]]
            nrm = np.cross(verts[f[1]] - verts[f[0]], verts[f[2]] - verts[f[0]])
            length = float(np.linalg.norm(nrm))
        nrm = nrm / length
        e1, e2 = _tangents(nrm)
        cols["x"][k], cols["y"][k], cols["z"][k] = p
        cols["nx"][k], cols["ny"][k], cols["nz"][k] = nrm
        cols["diameter_m"][k], cols["age_gyr"][k] = d, sites.ages[j]
        _, slope = _crater_on_mesh(verts, base_normals, idx, p, nrm, e1, e2, d, 0.0, 0.0, 0.0,
                                   0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.full(7, -2.0), True,
                                   False, table)
        sf = settings.slope.factor(slope) if math.isfinite(slope) else 0.0
        if model.slope.enabled and math.isfinite(slope):
            d0, r0 = model.factors(sites.ages[j], d, slope)
            depth_f0[k], rim_f0[k] = float(d0), float(r0)
        depth_f = float(depth_f0[k]) * sf
        rim_f = float(rim_f0[k]) * sf
        s = shape_arrays(np.array([d]), np.array([depth_f]), np.array([rim_f]),
                         model.morphology)
        cols["depth_fraction"][k], cols["rim_fraction"][k] = depth_f, rim_f
        cols["depth_m"][k], cols["rim_height_m"][k] = s["depth"][0], s["rim_height"][0]
        cols["slope_deg"][k], cols["slope_factor"][k] = math.degrees(slope), sf
        if not sf > 0.0:
            continue
        hr = float(s["rim_height"][0])
        curvature = float(s["fresh_rim_height"][0]) - hr + float(s["depth"][0])
        floor = hr - float(s["depth"][0])
        if irregular:  # the crater's own rim, keyed by its identity (so by its position)
            rim_table(seed, sites.uid[j], model.rim.effective_amplitude, model.rim.hurst, table)
        applied, _ = _crater_on_mesh(
            verts, base_normals, idx, p, nrm, e1, e2, d, curvature, floor, hr,
            float(s["ejecta"][0]), float(s["beta"][0]), float(s["a"][0]), float(s["b"][0]),
            float(s["c2"][0]), float(s["c3"][0]), s["complex"][0], False, irregular, table)
        cols["applied"][k] = int(applied)
    if progress is not None:
        progress(n, n)
    applied = int(cols["applied"].sum())
    log.info("applied %d of %d craters on the mesh (%d refinement rounds)", applied, n, rounds)
    meta = dict(craters=dict(count=n, applied=applied, seed=seed, settings=settings.as_dict(),
                             refine_rounds=rounds))
    return MeshCraters(body.replace(verts, faces, **meta), cols, rounds)


# ----------------------------------------------------------------------------------------
# boulders resting on the surface

#: Extra uniform draws per boulder: flattening, elongation, burial, yaw, pitch, roll.
_BOULDER_EXTRA = 6


@dataclass(frozen=True, eq=False)
class MeshBoulders:
    """Boulders on a mesh body: the catalogue columns and their meshes (finest level)."""

    catalog: dict
    vertices: np.ndarray
    faces: np.ndarray

    def __len__(self) -> int:
        return len(self.catalog["id"])


def place_mesh_boulders(body: MeshBody, population: Population, *, seed: int,
                        settings: BoulderSettings | None = None) -> MeshBoulders:
    """Draw boulders uniformly by area on the (cratered) surface and rest each on it.

    Each boulder's own z axis (its short axis) lies along its triangle's outward normal, its
    lowest point touches the triangle's plane, then it sinks by its burial fraction of its
    height (:class:`asteroid.boulders.BoulderSettings`).
    """
    seed = check_seed(seed)
    settings = settings or BoulderSettings()
    v, f = body.vertices, body.faces
    sites = sample_sites(v, f, population, seed=seed, stream=BOULDER_SITE_STREAM,
                         n_extra=_BOULDER_EXTRA, max_features=2_000_000)
    n = len(sites)
    u = sites.extra
    f_lo, f_hi = settings.flattening
    e_lo, e_hi = settings.elongation
    flattening = f_lo + (f_hi - f_lo) * u[:, 0]
    elongation = e_lo + (e_hi - e_lo) * u[:, 1]
    burial = settings.max_burial * u[:, 2]
    tilt = math.radians(settings.max_tilt_deg)
    # the angles as the catalogue records them, so the catalogue alone rebuilds the meshes
    yaw = np.degrees(2.0 * np.pi * u[:, 3])
    pitch = np.degrees(tilt * (2.0 * u[:, 4] - 1.0))
    roll = np.degrees(tilt * (2.0 * u[:, 5] - 1.0))
    normals = face_normals(v, f)[sites.face]
    rot = boulder_rotations(normals, yaw, pitch, roll)
    from asteroid.boulders import subdivision

    faces_all, _ = subdivision(settings.levels)
    fb = faces_all[-1]
    nv = 10 * 4 ** (settings.levels - 1) + 2
    out_v = np.empty((n, nv, 3))
    height = np.empty(n)
    depth = np.empty(n)
    centres = np.empty((n, 3))
    for start in range(0, n, 4096):
        sl = slice(start, min(n, start + 4096))
        local = local_shapes(seed, settings, sites.uid[sl], sites.diameters[sl],
                              elongation[sl], flattening[sl])
        world = np.einsum("nij,nvj->nvi", rot[sl], local)
        along = np.einsum("nvi,ni->nv", world, normals[sl])
        lowest = along.min(axis=1)
        height[sl] = along.max(axis=1) - lowest
        depth[sl] = burial[sl] * height[sl]
        centres[sl] = sites.points[sl] + normals[sl] * (-lowest - depth[sl])[:, None]
        out_v[sl] = world + centres[sl, None, :]
    faces_out = (fb[None, :, :] + (np.arange(n) * nv)[:, None, None]).reshape(-1, 3)
    cat = dict(id=sites.uid, face=sites.face,
               x_m=centres[:, 0], y_m=centres[:, 1], z_m=centres[:, 2],
               nx=normals[:, 0], ny=normals[:, 1], nz=normals[:, 2],
               diameter_m=sites.diameters, height_m=height, flattening=flattening,
               elongation=elongation, burial_fraction=burial, burial_depth_m=depth,
               yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll)
    log.info("placed %d boulders on the mesh", n)
    return MeshBoulders(cat, out_v.reshape(-1, 3), faces_out.astype(np.int64))


def boulder_rotations(normals: np.ndarray, yaw_deg: np.ndarray, pitch_deg: np.ndarray,
                      roll_deg: np.ndarray) -> np.ndarray:
    """Rotate boulders from their own frames to the body frame, short axis along the normal.

    Parameters
    ----------
    normals : (n, 3) float64
        Unit outward normal of each boulder's triangle (its own z axis).
    yaw_deg, pitch_deg, roll_deg : (n,) float64, degrees
        About the normal, then the tilts (the catalogue's columns).

    Returns
    -------
    (n, 3, 3) float64
        Own frame to body frame.
    """
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    helper = np.where(np.abs(normals[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t1 = np.cross(helper, normals)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    frame = np.stack([t1, t2, normals], axis=2)        # columns: local x, y, z
    return frame @ rotation_z(np.radians(yaw_deg)) @ rotation_y(np.radians(pitch_deg)) \
        @ rotation_x(np.radians(roll_deg))


def boulder_settings(metadata: dict) -> tuple[BoulderSettings, int] | None:
    """Return the boulder settings and seed a mesh body's metadata records (None: none).

    Parameters
    ----------
    metadata : dict
        :attr:`MeshBody.metadata` of a built body.
    """
    info = metadata.get("boulders")
    if not isinstance(info, dict) or "settings" not in info:
        return None
    s = dict(info["settings"])
    s["flattening"] = tuple(s["flattening"])
    s["elongation"] = tuple(s["elongation"])
    return BoulderSettings(**s), int(info["seed"])


def mesh_boulder_geometry(catalog: dict, settings: BoulderSettings, seed: int,
                          level: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rebuild the boulders of a mesh body's catalogue at one level of detail.

    The finest level gives exactly the meshes :func:`place_mesh_boulders` made (same bytes).

    Parameters
    ----------
    catalog : dict
        The boulder columns (:class:`MeshBoulders` ``catalog``, or a native file's table).
    settings : asteroid.boulders.BoulderSettings
        As the build recorded them (:func:`boulder_settings`).
    seed : int
        The build's seed.
    level : int, optional
        Level of detail, 0 (coarsest icosahedron) .. ``settings.levels - 1`` (default).

    Returns
    -------
    vertices : (n V_l, 3) float64, metres
    faces : (n F_l, 3) int64
    """
    from asteroid.boulders import subdivision

    levels = settings.levels
    level = levels - 1 if level is None else int(level)
    if not 0 <= level < levels:
        raise InvalidParameterError(f"boulder level must lie in [0, {levels}); got {level}")
    n = len(catalog["id"])
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    faces_all, _ = subdivision(levels)
    nv = 10 * 4**level + 2
    normals = np.column_stack([catalog["nx"], catalog["ny"], catalog["nz"]])
    rot = boulder_rotations(normals, catalog["yaw_deg"], catalog["pitch_deg"],
                            catalog["roll_deg"])
    centres = np.column_stack([catalog["x_m"], catalog["y_m"], catalog["z_m"]])
    uid = np.asarray(catalog["id"], dtype=np.uint64)
    diameter = np.asarray(catalog["diameter_m"], dtype=np.float64)
    elongation = np.asarray(catalog["elongation"], dtype=np.float64)
    flattening = np.asarray(catalog["flattening"], dtype=np.float64)
    out = np.empty((n, nv, 3))
    for start in range(0, n, 4096):
        sl = slice(start, min(n, start + 4096))
        local = local_shapes(seed, settings, uid[sl], diameter[sl], elongation[sl],
                             flattening[sl])[:, :nv]
        out[sl] = np.einsum("nij,nvj->nvi", rot[sl], local) + centres[sl, None, :]
    faces = (faces_all[level][None, :, :] + (np.arange(n) * nv)[:, None, None]).reshape(-1, 3)
    return out.reshape(-1, 3), faces.astype(np.int64)


# ----------------------------------------------------------------------------------------
# files

#: Format tag of a mesh body's native file.
MESH_FORMAT = "craterscape-mesh-asteroid/1"


def save_mesh_native(path, body: MeshBody, tables=None, *, inputs=()):
    """Write a mesh body (vertices, faces, metadata, catalogues) as ``.npz``, atomically.

    Same content, same bytes (fixed member order and zip dates, as
    :func:`asteroid.body.save_native`).
    """
    import json
    import zipfile
    from pathlib import Path

    from terrain.core.outputs import atomic_path

    path = Path(path)
    with atomic_path(path, inputs) as tmp, zipfile.ZipFile(tmp, "w", allowZip64=True) as zf:
        npy_member(zf, "format", np.array(MESH_FORMAT))
        npy_member(zf, "vertices", body.vertices)
        npy_member(zf, "faces", body.faces)
        npy_member(zf, "metadata", np.array(json.dumps(dict(body.metadata), sort_keys=True,
                                                    default=float)))
        for table, columns in (tables or {}).items():
            for column, values in columns.items():
                npy_member(zf, f"{table}/{column}", np.asarray(values))
    return path


def load_mesh_native(path) -> tuple[MeshBody, dict]:
    """Read a mesh body written by :func:`save_mesh_native`: the body and its catalogues.

    A missing file, one that is not an ``.npz``, or one of another format raises one clear
    error naming the file (:class:`terrain.core.errors.MissingInputError`,
    :class:`asteroid.errors.InvalidShapeError`).
    """
    import json
    import zipfile
    from pathlib import Path

    from terrain.core.errors import MissingInputError

    path = Path(path)
    if not path.is_file():
        raise MissingInputError(f"mesh body '{path}' does not exist")
    try:
        with np.load(path, allow_pickle=False) as z:
            fmt = str(z["format"]) if "format" in z.files else None
            if fmt != MESH_FORMAT:
                raise InvalidShapeError(f"'{path}' is not a mesh body ({MESH_FORMAT}); "
                                        f"its format is {fmt!r}")
            body = MeshBody(z["vertices"], z["faces"], json.loads(str(z["metadata"])))
            tables: dict = {}
            for name in z.files:
                if "/" in name:
                    table, column = name.split("/", 1)
                    tables.setdefault(table, {})[column] = z[name]
    except (zipfile.BadZipFile, ValueError, OSError, KeyError) as exc:
        if isinstance(exc, InvalidShapeError):
            raise
        raise InvalidShapeError(f"cannot read mesh body '{path}': {exc}") from exc
    return body, tables


def native_format(path) -> str | None:
    """Return the format tag of a craterscape ``.npz`` (None for another file or none).

    Tells a latitude/longitude body (:data:`asteroid.body.FORMAT`) from a mesh body
    (:data:`MESH_FORMAT`) without loading either.

    Parameters
    ----------
    path : str or Path
    """
    import zipfile
    from pathlib import Path

    path = Path(path)
    if path.suffix.lower() != ".npz" or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return str(z["format"]) if "format" in z.files else None
    except (zipfile.BadZipFile, ValueError, OSError, KeyError):
        return None


def save_columns(path, columns: dict, *, inputs=()):
    """Write catalogue columns as CSV atomically (identities as integers, the rest %.10g)."""
    from pathlib import Path

    from terrain.core.outputs import atomic_path

    names = list(columns)
    with atomic_path(path, inputs) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(",".join(names) + "\n")
        n = len(columns[names[0]]) if names else 0
        cols = [np.asarray(columns[k]) for k in names]
        for i in range(n):
            fh.write(",".join(str(int(c[i])) if c.dtype.kind in "iu" else f"{c[i]:.10g}"
                              for c in cols) + "\n")
    return Path(path)
