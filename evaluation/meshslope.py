r"""Slopes of asteroid models: per-vertex slopes within a 3 degree cap, slope-area histograms.

Martin et al. (2014, section VI.B) compare their synthetic asteroids with a "3 degree
resolution slope area histogram of Asteroid Eros": "Slope values were calculated for all
vertex points using a weighted slope average of all vertices within a 3 degree radius and
were collated into cumulative slope frequency values from which the slope area histogram was
calculated" (Fig. 9). :func:`mesh_slopes` does this for any closed triangle mesh, so real
shape models and synthetic bodies are measured the same way:

1. the slope of each vertex is the angle between its surface normal (the area-weighted
   mean of its triangles' normals) and the local *up* direction;
2. its reported slope is the mean of the slopes of all vertices whose direction from the
   body's centre lies within ``radius_deg`` (3 degrees) of its own, weighted by vertex area
   (a third of the area of each triangle the vertex belongs to), the paper's "weighted slope
   average of all vertices within a 3 degree radius";
3. the histogram gives the percentage of the surface *area* in each ``bin_deg`` (3 degree)
   bin, and its cumulative form the percentage of the area steeper than each bin edge.

Up: radial or gravitational
---------------------------
The paper's up is the radial direction from the centre. On an elongated body that misleads:
the ends of Eros face along its long axis while gravity there pulls along it too, so the
radial slope of the Gaskell Eros model has an area median near 44 degrees, while published
Eros slopes, measured relative to gravity, are nearly all below 35 degrees (Thomas et al.
2002, Icarus 155, 18; Zuber et al. 2000, Science 289, 2097). The *gravitational slope* takes
up as the direction opposite the local effective gravity: the attraction of the body as a
homogeneous polyhedron (:mod:`evaluation.gravity`, Werner and Scheeres 1997), evaluated from
a coarsened copy of the body (the field is smooth; :data:`DEFAULT_COARSE_FACES` triangles),
plus the centrifugal acceleration of the body's spin (Li et al. 2022, Fig. 17). Both are
reported; histograms compare gravitational slopes by default.

The density matters only through the ratio of centrifugal to gravitational acceleration:
without spin, the gravitational slope does not depend on it at all. With spin, give the
density (or the mass) and the spin period; a mesh in kilometres must be read with
``units="km"``, since the centrifugal term scales with the body's size in metres.

Which vertices share a cap: directions from the centre (the volume centroid), as on the
paper's radius-per-direction bodies. On a body that is not star-shaped (a bilobed neck, an
overhang) a cap can mix vertices of surfaces facing different ways; the slopes are still
each vertex's own, only their averaging neighbourhood is then loose.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from evaluation.gravity import (
    EROS_DENSITY,
    GRAVITATIONAL_CONSTANT,
    Polyhedron,
    centrifugal,
    coarsen,
    signed_volume,
)
from evaluation.slope import cumulative_distribution, weighted_quantiles
from terrain.core import memory
from terrain.core.errors import InvalidParameterError
from terrain.core.rows import unique_rows

__all__ = ["DEFAULT_BIN_DEG", "DEFAULT_COARSE_FACES", "DEFAULT_DENSITY", "DEFAULT_RADIUS_DEG",
           "MESH_SUFFIXES", "MeshSlopes", "SlopeAreaHistogram", "Spin", "cap_average",
           "binary_slopes", "field_sample", "load_body", "mesh_slopes", "sampled_attraction",
           "vertex_normals_and_areas"]

log = logging.getLogger(__name__)

#: Cap radius of the slope average, degrees (Martin et al. 2014, section VI.B).
DEFAULT_RADIUS_DEG = 3.0
#: Histogram bin width, degrees (the paper's "3 degree resolution slope area histogram").
DEFAULT_BIN_DEG = 3.0
#: Triangles of the coarsened body the gravity is evaluated from. Measured on the Gaskell
#: Eros model (49,152 triangles, spin 5.27 h) against gravity from the full model: 4,000
#: triangles change the per-vertex gravitational slopes by 0.32 degrees median (p99 0.99,
#: max 1.6), 2,000 by 0.54 (p99 1.5), 8,000 by 0.18 (p99 0.54); the area median moves from
#: 11.00 (full) to 11.35 degrees. 4,000 costs 5 s on Eros on 2 cores (the full model 73 s).
DEFAULT_COARSE_FACES = 4000
#: Neighbouring field points each vertex's attraction is interpolated from when the field is
#: evaluated at a sample of the vertices (:func:`sampled_attraction`).
FIELD_NEIGHBOURS = 12
#: Largest miss of a fitted plane at its own neighbours, as a fraction of the field, below
#: which an interpolated value is kept (else the field is evaluated at that vertex too).
FIELD_FIT_TOLERANCE = 1e-2
#: Levels of the field's sample: where a plane misses, the sample is made twice as dense
#: there and the plane fitted again, up to this many times in all; what still misses after
#: the last is evaluated exactly (:func:`sampled_attraction`).
FIELD_LEVELS = 2
#: Density used when neither density nor mass is given, kg m^-3 (433 Eros, the paper's body).
DEFAULT_DENSITY = EROS_DENSITY
#: Mesh files :func:`load_body` reads (the native asteroid model and what trimesh reads).
MESH_SUFFIXES = (".npz", ".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
#: Slopes reported for the histogram and its cumulative form.
SLOPE_KINDS = ("gravitational", "radial")


@dataclass(frozen=True)
class Spin:
    """A body's rotation: ``period_h`` hours (None: not spinning) about ``axis``.

    >>> round(Spin(5.27).rate, 8)
    0.00033118
    """

    period_h: float | None = None
    axis: tuple = (0.0, 0.0, 1.0)

    def __post_init__(self):
        if self.period_h is not None:
            p = float(self.period_h)
            if not (p > 0 and math.isfinite(p)):
                raise InvalidParameterError(f"spin period must be positive hours; got {p}")
            object.__setattr__(self, "period_h", p)
        a = np.asarray(self.axis, dtype=np.float64).reshape(-1)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or not np.linalg.norm(a) > 0:
            raise InvalidParameterError(f"spin axis must be three numbers, not all zero; got "
                                        f"{self.axis!r}")
        object.__setattr__(self, "axis", tuple((a / np.linalg.norm(a)).tolist()))

    @property
    def rate(self) -> float:
        """Angular rate, rad/s (0 without spin)."""
        return 0.0 if self.period_h is None else 2.0 * math.pi / (self.period_h * 3600.0)


# ------------------------------------------------------------------------------- input


def load_body(path, *, units: str = "m"):
    """Return a closed body from a mesh file or a native asteroid model, centred on its centroid.

    Parameters
    ----------
    path : str or Path
        ``.obj``, ``.ply``, ``.stl``, ``.off``, ``.glb``/``.gltf`` (through trimesh), or the
        native ``.npz`` of ``craterscape asteroid build`` (always metres; a latitude/longitude
        body or a mesh body).
    units : {"m", "km"}
        Units of a mesh file's coordinates (PDS shape models are in km).

    Returns
    -------
    asteroid.shape.ShapeModel
        Vertices in metres about the centroid, outward-wound faces; not closed, not
        consistently wound or enclosing no volume raises
        :class:`asteroid.errors.InvalidShapeError`.
    """
    from asteroid.shape import UNITS, ShapeModel

    path = Path(path)
    if units not in UNITS:
        raise InvalidParameterError(f"units must be one of {sorted(UNITS)}; got {units!r}")
    if path.suffix.lower() == ".npz":
        from asteroid.body import load_native
        from asteroid.surface import MESH_FORMAT, load_mesh_native, native_format

        if native_format(path) == MESH_FORMAT:  # a body kept as its own mesh
            mesh_body, _ = load_mesh_native(path)
            return ShapeModel.from_arrays(mesh_body.vertices, mesh_body.faces,
                                          source=f"'{path}'")
        body = load_native(path).body
        return ShapeModel.from_arrays(body.vertices(), body.mesh.faces(), source=f"'{path}'")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InvalidParameterError(
            f"'{path}' has suffix '{path.suffix}'; expected one of {', '.join(MESH_SUFFIXES)}")
    return ShapeModel.read(path, units=units)


# --------------------------------------------------------------------------- geometry


def vertex_normals_and_areas(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted unit vertex normals and vertex areas.

    Returns
    -------
    normals : (n, 3) float64
        Unit vectors (the sum of the adjacent triangles' area vectors, normalised).
    areas : (n,) float64, square metres
        A third of the area of every triangle the vertex belongs to.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # 2 * area * normal
    tri_area = 0.5 * np.linalg.norm(cross, axis=1)
    normals = np.zeros_like(v)
    areas = np.zeros(len(v))
    for k in range(3):
        for d in range(3):
            normals[:, d] += np.bincount(f[:, k], weights=cross[:, d], minlength=len(v))
        areas += np.bincount(f[:, k], weights=tri_area, minlength=len(v)) / 3.0
    norm = np.linalg.norm(normals, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = normals / norm[:, None]
    return normals, areas


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles between rows of a and b (any lengths), degrees; atan2 form, exact near 0."""
    cross = np.linalg.norm(np.cross(a, b), axis=1)
    dot = np.einsum("ij,ij->i", a, b)
    return np.degrees(np.arctan2(cross, dot))


@numba.njit(cache=True, parallel=True)
def _cap_sums(units, weights, values, order, keys_sorted, starts, ends, cells, n_side,
              chord2, out_values, out_weights):  # pragma: no cover - compiled
    n, k = values.shape
    for i in numba.prange(n):
        cx, cy, cz = cells[i, 0], cells[i, 1], cells[i, 2]
        ux, uy, uz = units[i, 0], units[i, 1], units[i, 2]
        wsum = 0.0
        acc = np.zeros(k)
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                for dz in range(-1, 2):
                    x, y, z = cx + dx, cy + dy, cz + dz
                    if x < 0 or y < 0 or z < 0 or x >= n_side or y >= n_side or z >= n_side:
                        continue
                    key = (x * n_side + y) * n_side + z
                    c = np.searchsorted(keys_sorted, key)
                    if c >= keys_sorted.size or keys_sorted[c] != key:
                        continue
                    for s in range(starts[c], ends[c]):
                        j = order[s]
                        ddx = units[j, 0] - ux
                        ddy = units[j, 1] - uy
                        ddz = units[j, 2] - uz
                        if ddx * ddx + ddy * ddy + ddz * ddz <= chord2:
                            w = weights[j]
                            wsum += w
                            for q in range(k):
                                acc[q] += w * values[j, q]
        out_weights[i] = wsum
        for q in range(k):
            out_values[i, q] = acc[q] / wsum if wsum > 0 else np.nan


def cap_average(directions, values, weights, radius_deg: float) -> np.ndarray:
    """Weighted mean of per-vertex values over every vertex's cap of ``radius_deg`` degrees.

    Parameters
    ----------
    directions : (n, 3) float64
        Vertex directions from the centre (any length, not zero).
    values : (n,) or (n, k) float64
    weights : (n,) float64
        Non-negative (vertex areas).
    radius_deg : float
        Angular radius of the cap; 0 returns the values unchanged.

    Returns
    -------
    (n,) or (n, k) float64

    Examples
    --------
    >>> d = np.array([[1.0, 0, 0], [1.0, 0.01, 0], [0, 0, 1.0]])
    >>> cap_average(d, np.array([1.0, 3.0, 5.0]), np.ones(3), 3.0).tolist()
    [2.0, 2.0, 5.0]
    """
    d = np.asarray(directions, dtype=np.float64)
    vals = np.asarray(values, dtype=np.float64)
    one = vals.ndim == 1
    vals2 = vals[:, None] if one else vals
    w = np.asarray(weights, dtype=np.float64)
    n = len(d)
    if d.shape != (n, 3) or vals2.shape[0] != n or w.shape != (n,):
        raise InvalidParameterError(
            f"directions (n, 3), values (n[, k]) and weights (n,) must agree; got {d.shape}, "
            f"{vals.shape}, {w.shape}")
    radius_deg = float(radius_deg)
    if not 0.0 <= radius_deg < 90.0:
        raise InvalidParameterError(f"cap radius must lie in [0, 90) degrees; got "
                                    f"{radius_deg}")
    if radius_deg == 0.0:
        return vals.copy()
    norm = np.linalg.norm(d, axis=1)
    if not np.all(norm > 0):
        raise InvalidParameterError("a vertex sits at the centre; it has no direction")
    units = d / norm[:, None]
    chord = 2.0 * math.sin(math.radians(radius_deg) / 2.0)
    n_side = max(1, int(math.ceil(2.0 / chord)) + 1)
    cells = np.minimum(np.floor((units + 1.0) / chord).astype(np.int64), n_side - 1)
    keys = (cells[:, 0] * n_side + cells[:, 1]) * n_side + cells[:, 2]
    order = np.argsort(keys, kind="stable")
    keys_sorted, starts = np.unique(keys[order], return_index=True)
    ends = np.append(starts[1:], n)
    expected = n * (1.0 - math.cos(math.radians(radius_deg))) / 2.0
    log.debug("cap average: %d vertices, about %.0f per %.3g degree cap", n, expected,
              radius_deg)
    out = np.empty_like(vals2)
    out_w = np.empty(n)
    _cap_sums(units, w, np.ascontiguousarray(vals2), order, keys_sorted, starts, ends, cells,
              n_side, chord * chord, out, out_w)
    return out[:, 0] if one else out


def _one_per_cell(vertices: np.ndarray, step: float, origin: np.ndarray) -> np.ndarray:
    """Sorted indices of the lowest-numbered vertex in each occupied cubic cell of ``step``."""
    cell = np.floor((vertices - origin) / step).astype(np.int64)
    _, first = unique_rows(cell, return_index=True)
    return np.sort(first)


def _field_grid(v: np.ndarray, points: int) -> tuple[np.ndarray, float]:
    """:func:`field_sample`'s indices and the cell side (metres) that gave them."""
    extent = float(np.max(v.max(axis=0) - v.min(axis=0)))
    origin = v.min(axis=0)
    # a closed surface of extent L has an area of order L^2: start from a cell of that share
    step = extent / math.sqrt(max(1, points))
    best, best_step = np.arange(len(v)), step
    for _ in range(12):
        best, best_step = _one_per_cell(v, step, origin), step
        ratio = len(best) / points
        if 0.8 <= ratio <= 1.25:
            break
        step *= math.sqrt(ratio)
    return best, best_step


def field_sample(vertices: np.ndarray, points: int) -> np.ndarray:
    """Return about ``points`` vertex indices spread evenly over a surface (one per grid cell).

    The vertices are binned on a cubic grid whose cell holds about one sample's share of the
    surface; each occupied cell keeps its lowest-numbered vertex, so the same mesh always
    gives the same sample.

    Parameters
    ----------
    vertices : (n, 3) float64, metres
    points : int
        The sample size aimed at (the result is within a factor of about two of it).

    Returns
    -------
    (k,) int64
        Sorted vertex indices.
    """
    return _field_grid(np.asarray(vertices, dtype=np.float64), points)[0]


def sampled_attraction(body: Polyhedron, vertices: np.ndarray, normals: np.ndarray,
                       points: int, *, tolerance: float = FIELD_FIT_TOLERANCE,
                       progress=None) -> tuple[np.ndarray, int]:
    """Return a polyhedron's attraction at every vertex, evaluated at a sample, interpolated.

    The field is evaluated exactly (:meth:`evaluation.gravity.Polyhedron.field`) at about
    ``points`` vertices spread evenly over the surface (:func:`field_sample`); at every
    other vertex it is the value at the vertex of a plane fitted, in the vertex's tangent
    plane, to the :data:`FIELD_NEIGHBOURS` nearest sampled vertices by weighted least squares
    (a moving least-squares fit of degree one: exact for a field that varies linearly over
    the surface). Where that plane misses one of its own neighbours by more than
    ``tolerance`` of the field, the field bends within a sample spacing (a
    coarse edge close by): there the field is evaluated at one of those vertices per cell
    of half the spacing, and the others are fitted again from the denser sample, under the
    same tolerance (:data:`FIELD_LEVELS` fits in all); a vertex whose last plane still
    misses is evaluated itself. The uncertainty this adds to a body's slopes is measured
    in ``docs/speed.md``.

    Parameters
    ----------
    body : evaluation.gravity.Polyhedron
        The (coarse) body whose field is wanted.
    vertices : (n, 3) float64, metres
        Where it is wanted.
    normals : (n, 3) float64
        Unit surface normals at the vertices (they define each tangent plane).
    points : int
        The sample size aimed at.
    tolerance : float
        Largest miss of a plane at its own neighbours, as a fraction of the field, that is
        kept (default :data:`FIELD_FIT_TOLERANCE`).
    progress : callable, optional
        Passed to the field evaluation.

    Returns
    -------
    attraction : (n, 3) float64, m s^-2
    sampled : int
        Vertices where the field was evaluated (the sample and the refits).
    """
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, dtype=np.float64)
    idx, step = _field_grid(v, points)
    out = np.empty((len(v), 3))
    _, out[idx] = body.field(v[idx], progress=progress)
    known = np.zeros(len(v), dtype=bool)
    known[idx] = True
    pending = np.flatnonzero(~known)
    for level in range(1, FIELD_LEVELS + 1):
        if not pending.size:
            break
        src = np.flatnonzero(known)
        fitted, missed = _plane_fit(v[src], out[src], cKDTree(v[src]), v[pending],
                                    normals[pending], min(FIELD_NEIGHBOURS, src.size),
                                    tolerance)
        out[pending[~missed]] = fitted[~missed]
        bad = pending[missed]
        if level == FIELD_LEVELS:  # the field bends within the finest spacing: exact there
            if bad.size:
                _, out[bad] = body.field(v[bad])
            known[bad] = True
            break
        # where the plane missed, the field is evaluated at one vertex per cell of half the
        # spacing before, and the rest are fitted again from the denser sample
        new = bad[_one_per_cell(v[bad], step / 2 ** level, v.min(axis=0))]
        _, out[new] = body.field(v[new])
        known[new] = True
        pending = np.setdiff1d(bad, new, assume_unique=True)
    return out, int(known.sum())


def _plane_fit(src_points, src_values, tree, points, normals, k, tolerance):
    """Weighted least-squares planes through each point's ``k`` nearest source values.

    Returns the planes' values at the points, (n, 3), and whether each plane misses one of
    its own neighbours by more than ``tolerance`` of its value, (n,) bool. Each point's
    plane is fitted alone (:func:`_plane_fits`, compiled), so the values do not depend on
    how many threads fit them.
    """
    dist, nb = tree.query(points, k=k, workers=-1)
    if k == 1:
        dist, nb = dist[:, None], nb[:, None]
    values = np.empty((len(points), 3))
    missed = np.empty(len(points), dtype=np.bool_)
    _plane_fits(np.ascontiguousarray(src_points, dtype=np.float64),
                np.ascontiguousarray(src_values, dtype=np.float64),
                np.ascontiguousarray(points, dtype=np.float64),
                np.nan_to_num(np.asarray(normals, dtype=np.float64)),
                np.ascontiguousarray(dist), np.ascontiguousarray(nb, dtype=np.int64),
                float(tolerance), values, missed)
    return values, missed


@numba.njit(cache=True, parallel=True)
def _plane_fits(src, src_values, points, normals, dist, nb, tolerance, out,
                missed):  # pragma: no cover - compiled
    n, k = nb.shape
    for i in numba.prange(n):
        # tangent-plane axes: the normal crossed with the coordinate axis least along it
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if abs(nx) < 0.9:
            ax, ay, az = 1.0, 0.0, 0.0
        else:
            ax, ay, az = 0.0, 1.0, 0.0
        e1x, e1y, e1z = ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax
        e1n = max(math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z), 1e-300)
        e1x, e1y, e1z = e1x / e1n, e1y / e1n, e1z / e1n
        e2x, e2y, e2z = ny * e1z - nz * e1y, nz * e1x - nx * e1z, nx * e1y - ny * e1x
        scale = max(dist[i, k - 1], 1e-300)
        # normal equations of the weighted fit: lhs (3, 3), rhs (3 coefficients, 3 components)
        lhs = np.zeros((3, 3))
        rhs = np.zeros((3, 3))
        a = np.empty((k, 3))
        for j in range(k):
            s = nb[i, j]
            dx = src[s, 0] - points[i, 0]
            dy = src[s, 1] - points[i, 1]
            dz = src[s, 2] - points[i, 2]
            a[j, 0] = 1.0
            a[j, 1] = (dx * e1x + dy * e1y + dz * e1z) / scale
            a[j, 2] = (dx * e2x + dy * e2y + dz * e2z) / scale
            r = dist[i, j] / (1.0001 * scale)
            w = (1.0 - r * r) ** 2  # Wendland-like taper: far ones count less
            for p in range(3):
                wp = w * a[j, p]
                for q in range(3):
                    lhs[p, q] += wp * a[j, q]
                    rhs[p, q] += wp * src_values[s, q]
        for p in range(3):
            lhs[p, p] += 1e-9
        coef = _solve3(lhs, rhs)
        # where the plane misses its own neighbours by more than the tolerance of the field
        # (a coarse edge or vertex close by: the field bends within a sample spacing), the
        # caller evaluates the field there
        worst = 0.0
        for j in range(k):
            s = nb[i, j]
            m = 0.0
            for q in range(3):
                e = src_values[s, q] - (a[j, 0] * coef[0, q] + a[j, 1] * coef[1, q]
                                        + a[j, 2] * coef[2, q])
                m += e * e
            worst = max(worst, math.sqrt(m))
        size = math.sqrt(coef[0, 0] ** 2 + coef[0, 1] ** 2 + coef[0, 2] ** 2)
        for q in range(3):
            out[i, q] = coef[0, q]
        missed[i] = worst > tolerance * size


@numba.njit(cache=True)
def _solve3(lhs, rhs):  # pragma: no cover - compiled
    """``lhs^-1 rhs`` for a 3x3 system, by elimination with partial pivoting (as LAPACK)."""
    m = lhs.copy()
    b = rhs.copy()
    for c in range(3):
        p = c
        for r in range(c + 1, 3):
            if abs(m[r, c]) > abs(m[p, c]):
                p = r
        if p != c:
            for q in range(3):
                m[c, q], m[p, q] = m[p, q], m[c, q]
                b[c, q], b[p, q] = b[p, q], b[c, q]
        for r in range(c + 1, 3):
            f = m[r, c] / m[c, c]
            for q in range(c, 3):
                m[r, q] -= f * m[c, q]
            for q in range(3):
                b[r, q] -= f * b[c, q]
    x = np.empty((3, 3))
    for c in range(2, -1, -1):
        for q in range(3):
            t = b[c, q]
            for r in range(c + 1, 3):
                t -= m[c, r] * x[r, q]
            x[c, q] = t / m[c, c]
    return x


# ------------------------------------------------------------------------------ result


@dataclass(frozen=True, eq=False)
class SlopeAreaHistogram:
    """Percentage of a body's surface area per slope bin (the paper's Fig. 9).

    Parameters
    ----------
    label : str
    kind : {"gravitational", "radial"}
    edges_deg : (k + 1,) float64
    area_percent : (k,) float64
        Percent of the area with slopes in ``[edges[i], edges[i + 1])``.
    percent_steeper : (k + 1,) float64
        Percent of the area steeper than each edge.
    """

    label: str
    kind: str
    edges_deg: np.ndarray
    area_percent: np.ndarray
    percent_steeper: np.ndarray

    @property
    def centres_deg(self) -> np.ndarray:
        """The bin centres in degrees, (n,) float64."""
        return 0.5 * (self.edges_deg[1:] + self.edges_deg[:-1])

    def as_dict(self) -> dict:
        """Return the histogram as plain data for the report's JSON."""
        return dict(label=self.label, kind=self.kind, edges_deg=self.edges_deg.tolist(),
                    area_percent=self.area_percent.tolist(),
                    percent_steeper=self.percent_steeper.tolist())


@dataclass(frozen=True, eq=False)
class MeshSlopes:
    """Per-vertex slopes of a body, both relative to the radial direction and to gravity.

    Parameters
    ----------
    label : str
    vertex_area : (n,) float64, m^2
    radial_deg : (n,) float64
        Cap-averaged slope relative to the radial direction.
    gravitational_deg : (n,) float64 or None
        Cap-averaged slope relative to the local effective gravity.
    gravity : (n, 3) float64, m s^-2, or None
        Effective gravity (attraction plus centrifugal) at each vertex.
    radius_deg : float
        Cap radius of the averaging.
    info : dict
        Density, mass, spin, volume, coarse-body size, timings.
    """

    label: str
    vertex_area: np.ndarray
    radial_deg: np.ndarray
    gravitational_deg: np.ndarray | None
    gravity: np.ndarray | None
    radius_deg: float
    info: dict = field(default_factory=dict)

    def slopes(self, kind: str = "gravitational") -> np.ndarray:
        """(n,) float64 degrees of the given kind."""
        if kind not in SLOPE_KINDS:
            raise InvalidParameterError(f"slope kind must be one of {SLOPE_KINDS}; got "
                                        f"{kind!r}")
        if kind == "gravitational":
            if self.gravitational_deg is None:
                raise InvalidParameterError(
                    f"{self.label}: gravitational slopes were not computed")
            return self.gravitational_deg
        return self.radial_deg

    def histogram(self, kind: str = "gravitational", *,
                  bin_deg: float = DEFAULT_BIN_DEG) -> SlopeAreaHistogram:
        """Slope-area histogram in ``bin_deg`` bins from 0 to 180 degrees.

        Slopes above 90 degrees are overhangs (the surface faces down).
        """
        bin_deg = float(bin_deg)
        if not 0.0 < bin_deg <= 90.0:
            raise InvalidParameterError(f"bin width must lie in (0, 90] degrees; got "
                                        f"{bin_deg}")
        values = self.slopes(kind)
        edges = np.arange(0.0, 180.0 + 0.5 * bin_deg, bin_deg)
        edges[-1] = max(edges[-1], 180.0)
        ok = np.isfinite(values)
        hist, _ = np.histogram(values[ok], bins=edges, weights=self.vertex_area[ok])
        total = float(self.vertex_area[ok].sum())
        return SlopeAreaHistogram(self.label, kind, edges, 100.0 * hist / total,
                                  cumulative_distribution(values, edges, self.vertex_area))

    def summary(self, kind: str) -> dict:
        """Area-weighted quantiles and the area fractions below 35 degrees."""
        values = self.slopes(kind)
        q = weighted_quantiles(values, weights=self.vertex_area)
        ok = np.isfinite(values)
        area = self.vertex_area[ok]
        q["area_fraction_below_35deg"] = float(area[values[ok] < 35.0].sum() / area.sum())
        return q

    def as_dict(self) -> dict:
        """Return the summaries (not the per-vertex arrays) as plain data for the report's JSON."""
        out = dict(label=self.label, vertices=int(self.vertex_area.size),
                   radius_deg=self.radius_deg, info=self.info,
                   radial=self.summary("radial"))
        if self.gravitational_deg is not None and self.gravity is not None:  # set together
            out["gravitational"] = self.summary("gravitational")
            g = np.linalg.norm(self.gravity, axis=1)
            out["effective_gravity_m_s2"] = dict(min=float(g.min()), max=float(g.max()),
                                                 mean=float(g.mean()))
        return out


def _density(volume: float, density, mass) -> tuple[float, str]:
    if density is not None and mass is not None:
        raise InvalidParameterError("give the density or the mass, not both")
    if mass is not None:
        mass = float(mass)
        if not (mass > 0 and math.isfinite(mass)):
            raise InvalidParameterError(f"mass must be positive kg; got {mass}")
        return mass / volume, "mass"
    if density is not None:
        density = float(density)
        if not (density > 0 and math.isfinite(density)):
            raise InvalidParameterError(f"density must be positive kg/m^3; got {density}")
        return density, "density"
    return DEFAULT_DENSITY, "default (433 Eros)"


def mesh_slopes(vertices, faces, *, label: str = "", radius_deg: float = DEFAULT_RADIUS_DEG,
                gravity: bool = True, density: float | None = None, mass: float | None = None,
                spin: Spin | None = None, coarse_faces: int = DEFAULT_COARSE_FACES,
                field_points: int | None = None, field_tolerance: float = FIELD_FIT_TOLERANCE,
                progress=None) -> MeshSlopes:
    """Radial and gravitational slopes of a closed body (see the module docstring).

    Parameters
    ----------
    vertices : (n, 3) float64, metres
        About the body's centre of mass (:func:`load_body` centres on the centroid).
    faces : (m, 3) int64
        Closed, outward wound.
    label : str
    radius_deg : float
        Cap radius of the slope average (0: each vertex's own slope).
    gravity : bool
        Compute gravitational slopes too.
    density : float, kg m^-3, optional
    mass : float, kg, optional
        Instead of the density (then density = mass / volume). Default: 2670 kg m^-3.
    spin : Spin, optional
        Rotation (default: none; then the density does not matter).
    coarse_faces : int
        Triangles of the coarsened copy the gravity is computed from.
    field_points : int, optional
        Evaluate the attraction at about this many vertices, evenly spread, and interpolate
        it to the others (:func:`sampled_attraction`); None (the default), or at least as
        many as the body has: at every vertex. The centrifugal term is exact at every vertex.
    field_tolerance : float
        With ``field_points``: the largest miss of a fitted plane, as a fraction of the field,
        that is kept (:func:`sampled_attraction`).
    progress : callable, optional
        ``progress(done, total)`` over the gravity evaluation.

    Returns
    -------
    MeshSlopes

    Examples
    --------
    On a sphere every slope is zero, radially and gravitationally (up to the facets of a
    642-vertex icosphere and of its 400-triangle coarse copy):

    >>> import trimesh
    >>> s = trimesh.creation.icosphere(subdivisions=3, radius=500.0)
    >>> r = mesh_slopes(s.vertices, s.faces, coarse_faces=400)
    >>> float(r.radial_deg.max()) < 1.0, float(r.gravitational_deg.max()) < 1.5
    (True, True)
    """
    import time

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise InvalidParameterError(
            f"vertices must be (n, 3) and faces (m, 3); got {v.shape} and {f.shape}")
    spin = spin or Spin()
    memory.require(len(v) * 200.0 + len(f) * 60.0,
                   f"slopes of a {len(v):,}-vertex body")
    t0 = time.perf_counter()
    normals, areas = vertex_normals_and_areas(v, f)
    volume = signed_volume(v, f)
    radial = _angle_deg(normals, v)
    info: dict = dict(vertices=len(v), faces=len(f), volume_m3=volume,
                      equivalent_radius_m=(3.0 * volume / (4.0 * math.pi)) ** (1.0 / 3.0),
                      area_m2=float(areas.sum()), radius_deg=radius_deg)
    grav = g_eff = None
    if gravity:
        rho, rho_from = _density(volume, density, mass)
        cv, cf = coarsen(v, f, int(coarse_faces))
        coarse_volume = signed_volume(cv, cf)
        # keep the fine body's mass on the coarse one
        body = Polyhedron.build(cv, cf, rho * volume / coarse_volume)
        t1 = time.perf_counter()
        if field_points is not None and 0 < int(field_points) < len(v):
            attraction, sampled = sampled_attraction(body, v, normals, int(field_points),
                                                     tolerance=field_tolerance,
                                                     progress=progress)
            info.update(field_points=sampled, field_neighbours=FIELD_NEIGHBOURS,
                        field_tolerance=float(field_tolerance))
        else:
            _, attraction = body.field(v, progress=progress)
        g_eff = attraction + centrifugal(v, rate=spin.rate, axis=spin.axis)
        grav = _angle_deg(normals, -g_eff)
        info.update(density_kg_m3=rho, density_from=rho_from, mass_kg=rho * volume,
                    coarse_faces=int(len(cf)), coarse_vertices=int(len(cv)),
                    coarse_volume_ratio=coarse_volume / volume,
                    spin_period_h=spin.period_h, spin_axis=list(spin.axis),
                    spin_rate_rad_s=spin.rate, gravity_s=time.perf_counter() - t1,
                    gravitational_constant=GRAVITATIONAL_CONSTANT)
        if spin.rate > 0 and info["equivalent_radius_m"] < 50.0:
            log.warning("%s is only %.3g m across in the units given; its spin barely "
                        "matters at that size: is the mesh in km (units='km')?",
                        label or "the body", 2 * info["equivalent_radius_m"])
    stacked = radial[:, None] if grav is None else np.column_stack([radial, grav])
    averaged = cap_average(v, stacked, areas, radius_deg)
    info["seconds"] = time.perf_counter() - t0
    return MeshSlopes(label, areas, averaged[:, 0],
                      None if grav is None else averaged[:, 1], g_eff, float(radius_deg),
                      info)


def binary_slopes(primary, secondary, *, orbit, primary_spin=None, secondary_spin=None,
                  t: float = 0.0, which: str = "primary", label: str = "",
                  radius_deg: float = DEFAULT_RADIUS_DEG,
                  coarse_faces: int = DEFAULT_COARSE_FACES, progress=None) -> MeshSlopes:
    """Radial and gravitational slopes of one body of a binary at time ``t``.

    A particle at rest on body A's surface feels A's attraction, the tide of the other body
    B (B's attraction there minus B's attraction at A's centre, which accelerates A as a
    whole), and the centrifugal acceleration of A's own spin (a tidally locked body turns at
    the mean motion about the orbit normal)::

        g_eff(p) = g_A(p) + g_B(p) - g_B(c_A) + omega_A^2 r_perp

    Both attractions are exact polyhedron fields (:class:`evaluation.gravity.Polyhedron`, of
    coarsened copies); the masses follow from the orbit, as the render scene's do: Kepler's
    third law gives ``G (m_A + m_B)`` from the period and the semi-major axis, the mass ratio
    splits it, and each body is homogeneous.

    Parameters
    ----------
    primary, secondary : ((n, 3) float64, (m, 3) int64)
        Each body's closed, outward-wound mesh about its centre of mass, body frame, metres.
    orbit : render.orbit.MutualOrbit
        The mutual orbit (positions, masses).
    primary_spin, secondary_spin : render.orbit.Spin, optional
        As in a binary scene: the primary's default is :class:`render.orbit.Spin`'s; a
        secondary without one is tidally locked.
    t : float, seconds
        When (the bodies' poses, as :meth:`render.binary_scene.BinaryScene.body_poses`).
    which : {"primary", "secondary"}
        The body whose surface the slopes are of.
    label, radius_deg, coarse_faces, progress
        As :func:`mesh_slopes`.

    Returns
    -------
    MeshSlopes
        Of the chosen body's vertices; ``gravity`` in its body frame.
    """
    import time

    from render.camera import quat_to_matrix
    from render.orbit import Spin as BodySpin

    if which not in ("primary", "secondary"):
        raise InvalidParameterError(f"which must be 'primary' or 'secondary'; got {which!r}")
    meshes = [tuple(np.ascontiguousarray(a, dtype=dt) for a, dt in
                    zip(m, (np.float64, np.int64), strict=True)) for m in (primary, secondary)]
    spins = [primary_spin if primary_spin is not None else BodySpin(), secondary_spin]
    t0 = time.perf_counter()
    centres = orbit.positions(float(t))
    quats = [spins[0].rotation(t), spins[1].rotation(t) if spins[1] is not None
             else orbit.locked_rotation(t)]
    rots = [quat_to_matrix(q) for q in quats]
    # spin rate and world axis of each body
    rates = []
    for spin in spins:
        if spin is None:  # tidally locked: the mean motion about the orbit normal
            rates.append((orbit.mean_motion, orbit.orbit_rotation()[:, 2]))
        else:
            rate = 0.0 if spin.period == 0 else 2.0 * math.pi / float(spin.period)
            rates.append((rate, np.asarray(spin.axis) / np.linalg.norm(spin.axis)))
    total = orbit.gm / GRAVITATIONAL_CONSTANT
    q = orbit.mass_ratio
    masses = [total / (1.0 + q), total * q / (1.0 + q)]
    a, b = (0, 1) if which == "primary" else (1, 0)
    bodies = []
    for i in (a, b):
        v, f = meshes[i]
        volume = signed_volume(v, f)
        cv, cf = coarsen(v, f, int(coarse_faces))
        bodies.append(Polyhedron.build(cv, cf, masses[i] / signed_volume(cv, cf)))
        if i == a:
            own_volume = volume
    v, f = meshes[a]
    normals, areas = vertex_normals_and_areas(v, f)
    radial = _angle_deg(normals, v)
    _, own = bodies[0].field(v, progress=progress)
    # the other body's attraction, evaluated in its own frame
    world = v @ rots[a].T + centres[a]
    at_b = (world - centres[b]) @ rots[b]
    centre_b = (centres[a] - centres[b]) @ rots[b]
    _, pull = bodies[1].field(np.vstack([at_b, centre_b[None, :]]))
    tide_world = (pull[:-1] - pull[-1]) @ rots[b].T
    tide = tide_world @ rots[a]
    rate, axis_w = rates[a]
    g_eff = own + tide + centrifugal(v, rate=rate, axis=axis_w @ rots[a])
    grav = _angle_deg(normals, -g_eff)
    info = dict(vertices=len(v), faces=len(f), volume_m3=own_volume, body=which, time_s=float(t),
                mass_kg=masses[a], other_mass_kg=masses[b],
                density_kg_m3=masses[a] / own_volume, spin_rate_rad_s=rate,
                separation_m=float(np.linalg.norm(centres[b] - centres[a])),
                tide_max_m_s2=float(np.linalg.norm(tide, axis=1).max()),
                radius_deg=radius_deg, gravitational_constant=GRAVITATIONAL_CONSTANT)
    averaged = cap_average(v, np.column_stack([radial, grav]), areas, radius_deg)
    info["seconds"] = time.perf_counter() - t0
    return MeshSlopes(label or which, areas, averaged[:, 0], averaged[:, 1], g_eff,
                      float(radius_deg), info)
