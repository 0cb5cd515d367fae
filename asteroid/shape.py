r"""Real shape models as asteroid bases: project a closed triangle mesh onto the 6M^2 + 2 mesh.

The paper's bodies start from noise or faulting; its users also start from the shape models of
visited asteroids (Gaskell's Eros and Itokawa, OSIRIS-REx's Bennu), which "could be used as base
models on which to add further high-resolution artificial terrain" (Martin et al. 2014,
section II). A shape model becomes a base by casting a ray from the body's centre through
every mesh vertex direction and keeping the *outermost* hit: the radius along that direction.

Checks (each failure is a one-line :class:`~asteroid.errors.InvalidShapeError`):

* the file is a closed, consistently wound surface: every edge is used by exactly two
  triangles, once in each direction (an open surface has no inside, so no radius);
* no triangle repeats a vertex, and the enclosed volume is not zero (an inward-wound file is
  turned outwards, with a warning);
* the centre lies inside: the generalised winding number of the surface about the centre,
  the sum of the triangles' solid angles (Van Oosterom and Strackee 1983) over 4 pi, is 1
  inside and 0 outside.

Which centre: by default the centroid of the enclosed volume (the centre of mass of a
uniform body, what pointing and gravity use), or the file's origin (``centre="origin"``, the
body-fixed frame of a PDS shape model), or any point given in the file's units.

Not star-shaped
---------------
A radius function describes only star-shaped bodies: along some directions the surface of a
real asteroid is crossed more than once (an overhang, the saddle of a bilobed body). There the
outermost hit is kept, which fills the overhang; :attr:`Projection.non_star_fraction` reports
the fraction of mesh directions with more than one distinct crossing (the innermost and
outermost hits differ; a ray through a shared edge hits both triangles at one distance), so a
user knows how much of the body the radius function approximates.

The ray casting needs no spatial index: each source triangle is seen from the centre within a
cone, bounded by the spherical cap around the mean direction of its corners, and the
latitude/longitude mesh lists the vertex directions in a cap ring by ring
(:func:`asteroid.sphere.cap_ranges`); each triangle is tested only against those rays
(Moller and Trumbore 1997), so the cost is about (mesh vertices + source triangles).

Measured (M = 256, 393,218 directions, centroid centre; ``tests/asteroid/test_shape.py``):

=========  ====================  ===================  ============  ================
body       source volume         projected volume     difference    not star-shaped
=========  ====================  ===================  ============  ================
Eros       2506.39 km^3          2506.26 km^3         -0.005 %      0.002 %
Itokawa    0.0177020 km^3        0.0177269 km^3       +0.141 %      0.236 %
Bennu      0.0615556 km^3        0.0615544 km^3       -0.002 %      0 %
=========  ====================  ===================  ============  ================

(Itokawa's neck is where its surface folds back; keeping the outermost hit fills the
overhangs, hence the small excess.)
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numba
import numpy as np

from asteroid.body import Stretch
from asteroid.errors import InvalidShapeError
from asteroid.meshio.read import read_mesh
from asteroid.sphere import SphereMesh, cap_ranges, ring_offset, ring_size, unit_vertex
from terrain.core import memory
from terrain.core.errors import InvalidParameterError

__all__ = ["UNITS", "Projection", "ShapeModel", "check_closed", "winding_number"]

log = logging.getLogger(__name__)

#: Metres per unit of a shape model file (PDS shape models are in kilometres).
UNITS = {"km": 1000.0, "m": 1.0}
#: Barycentric tolerance of the ray-triangle test: a ray through a shared edge or vertex hits
#: every triangle there (at the same distance) instead of slipping between them.
RAY_EPSILON = 1e-9
#: Two crossings closer than this fraction of the radius are one crossing (shared edges).
SAME_HIT = 1e-7
#: Winding numbers below this mean the centre is outside (1 inside, 0 outside).
INSIDE_WINDING = 0.5


def winding_number(vertices: np.ndarray, faces: np.ndarray, point) -> float:
    """Generalised winding number of a closed triangle mesh about ``point``.

    Sum of the signed solid angles of the triangles seen from the point (Van Oosterom and
    Strackee 1983: ``tan(Omega / 2) = a . (b x c) / (abc + (a.b)c + (a.c)b + (b.c)a)``)
    over 4 pi: 1 inside an outward-wound surface, 0 outside.

    >>> from asteroid.sphere import SphereMesh
    >>> m = SphereMesh(3)
    >>> v, f = m.directions(), m.faces()
    >>> inside, outside = winding_number(v, f, [0.1, 0, 0]), winding_number(v, f, [2, 0, 0])
    >>> bool(abs(inside - 1.0) < 1e-9 and abs(outside) < 1e-9)
    True
    """
    p = np.asarray(point, dtype=np.float64)
    total = 0.0
    for start in range(0, len(faces), 1 << 20):
        f = faces[start:start + (1 << 20)]
        a = vertices[f[:, 0]] - p
        b = vertices[f[:, 1]] - p
        c = vertices[f[:, 2]] - p
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc
               + np.einsum("ij,ij->i", a, c) * lb + np.einsum("ij,ij->i", b, c) * la)
        total += float(np.sum(2.0 * np.arctan2(num, den)))
    return total / (4.0 * math.pi)


def check_closed(faces: np.ndarray, n_vertices: int, source: str) -> None:
    """Every edge used exactly twice, once each way (closed, manifold, consistently wound)."""
    if np.any((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
              | (faces[:, 0] == faces[:, 2])):
        raise InvalidShapeError(f"shape model {source} has degenerate triangles (a repeated "
                                "vertex); clean the mesh first")
    a = faces.reshape(-1)
    b = np.roll(faces, -1, axis=1).reshape(-1)
    # one sort of the directed edges answers both questions (np.unique and np.isin would
    # sort them twice more: 3 s of a 786k-triangle body's 4.8 s load)
    directed = np.sort(a * np.int64(n_vertices) + b)
    same = directed[1:] == directed[:-1]
    if same.any():
        runs = int(np.count_nonzero(same[1:] & ~same[:-1])) + int(same[0])
        raise InvalidShapeError(
            f"shape model {source} is not a consistently wound manifold surface "
            f"({runs} edges run the same way in two triangles)")
    reverse = b * np.int64(n_vertices) + a
    at = np.minimum(np.searchsorted(directed, reverse), directed.size - 1)
    missing = directed[at] != reverse
    if missing.any():
        raise InvalidShapeError(
            f"shape model {source} is not a closed surface: {int(missing.sum())} edges border "
            "only one triangle (holes or a non-manifold seam)")


@dataclass(frozen=True, eq=False)
class Projection:
    """A shape model cast onto the mesh.

    Parameters
    ----------
    radii : (N,) float64, metres
        Outermost crossing along each vertex direction (the base's radius).
    inner : (N,) float64, metres
        Innermost crossing; equal to ``radii`` where the body is star-shaped, below it where
        the ray leaves and re-enters the body (the overhang's depth is ``radii - inner``).
    """

    radii: np.ndarray
    inner: np.ndarray

    @property
    def star_shaped(self) -> np.ndarray:
        """(N,) bool: the direction crosses the surface once (shared edges count once)."""
        return self.radii - self.inner <= SAME_HIT * self.radii

    @property
    def non_star_fraction(self) -> float:
        """Fraction of mesh directions that cross the surface more than once."""
        return float(np.mean(~self.star_shaped))


@numba.njit(cache=True)
def _cast(m, vertices, faces, tmax, tmin, hits):
    """For every source triangle, test the mesh rays in its cone from the centre."""
    ranges = np.empty((2 * m + 1, 3), dtype=np.int64)
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        v0x, v0y, v0z = vertices[i0, 0], vertices[i0, 1], vertices[i0, 2]
        v1x, v1y, v1z = vertices[i1, 0], vertices[i1, 1], vertices[i1, 2]
        v2x, v2y, v2z = vertices[i2, 0], vertices[i2, 1], vertices[i2, 2]
        l0 = math.sqrt(v0x * v0x + v0y * v0y + v0z * v0z)
        l1 = math.sqrt(v1x * v1x + v1y * v1y + v1z * v1z)
        l2 = math.sqrt(v2x * v2x + v2y * v2y + v2z * v2z)
        cx = v0x / l0 + v1x / l1 + v2x / l2
        cy = v0y / l0 + v1y / l1 + v2y / l2
        cz = v0z / l0 + v1z / l1 + v2z / l2
        cl = math.sqrt(cx * cx + cy * cy + cz * cz)
        if cl < 1e-12:
            angle = math.pi
            cx, cy, cz = 0.0, 0.0, 1.0
        else:
            cx /= cl
            cy /= cl
            cz /= cl
            d0 = (cx * v0x + cy * v0y + cz * v0z) / l0
            d1 = (cx * v1x + cy * v1y + cz * v1z) / l1
            d2 = (cx * v2x + cy * v2y + cz * v2z) / l2
            angle = math.acos(max(-1.0, min(1.0, min(d0, min(d1, d2))))) + 1e-9
        e1x, e1y, e1z = v1x - v0x, v1y - v0y, v1z - v0z
        e2x, e2y, e2z = v2x - v0x, v2y - v0y, v2z - v0z
        rows = cap_ranges(m, cx, cy, cz, angle, ranges)
        for r in range(rows):
            g = ranges[r, 0]
            n = ring_size(m, g)
            o = ring_offset(m, g)
            for j in range(ranges[r, 2]):
                i = o + ((ranges[r, 1] + j) % n)
                dx, dy, dz = unit_vertex(m, i)
                # Moller-Trumbore with the ray origin at the centre
                px = dy * e2z - dz * e2y
                py = dz * e2x - dx * e2z
                pz = dx * e2y - dy * e2x
                det = e1x * px + e1y * py + e1z * pz
                if abs(det) < 1e-300:
                    continue
                inv = 1.0 / det
                sx, sy, sz = -v0x, -v0y, -v0z
                u = (sx * px + sy * py + sz * pz) * inv
                if u < -RAY_EPSILON or u > 1.0 + RAY_EPSILON:
                    continue
                qx = sy * e1z - sz * e1y
                qy = sz * e1x - sx * e1z
                qz = sx * e1y - sy * e1x
                v = (dx * qx + dy * qy + dz * qz) * inv
                if v < -RAY_EPSILON or u + v > 1.0 + RAY_EPSILON:
                    continue
                t = (e2x * qx + e2y * qy + e2z * qz) * inv
                if t <= 0.0:
                    continue
                if hits[i] == 0:
                    tmax[i] = t
                    tmin[i] = t
                else:
                    tmax[i] = max(tmax[i], t)
                    tmin[i] = min(tmin[i], t)
                hits[i] += 1


@dataclass(frozen=True, eq=False)
class ShapeModel:
    """A closed triangle mesh around its centre, in metres.

    Parameters
    ----------
    vertices : (n, 3) float64, metres
        Positions relative to the centre.
    faces : (m, 3) int64
        Outward wound.
    source : str
        Where it came from (file name), for messages and provenance.
    centre : (3,) float64
        The centre in the source file's frame, metres.
    """

    vertices: np.ndarray
    faces: np.ndarray
    source: str = "arrays"
    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def read(cls, path, *, units: str = "km", centre="centroid") -> ShapeModel:
        """Read an OBJ/PLY/STL shape model, check it and centre it.

        Parameters
        ----------
        path : str or Path
        units : {"km", "m"}
            Units of the file's coordinates (PDS shape models: km).
        centre : "centroid", "origin" or (x, y, z) in the file's units
        """
        if units not in UNITS:
            raise InvalidParameterError(f"shape units must be one of {sorted(UNITS)}; got "
                                        f"{units!r}")
        vertices, faces = read_mesh(path)
        if not isinstance(centre, str):
            centre = np.asarray(centre, dtype=np.float64) * UNITS[units]
        return cls.from_arrays(vertices * UNITS[units], faces, source=f"'{path}'",
                               centre=centre)

    @classmethod
    def from_arrays(cls, vertices, faces, *, source: str = "arrays",
                    centre="centroid") -> ShapeModel:
        """Check a closed mesh (metres) and express it about its centre."""
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise InvalidShapeError(f"shape model {source} vertices must be (n >= 4, 3); got "
                                    f"{v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4:
            raise InvalidShapeError(f"shape model {source} faces must be (m >= 4, 3) int; got "
                                    f"{f.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise InvalidShapeError(f"shape model {source} has face indices outside its vertices")
        check_closed(f, len(v), source)
        volume = _signed_volume(v, f)
        scale = float(np.abs(v).max())
        if not abs(volume) > 1e-12 * scale**3:
            raise InvalidShapeError(f"shape model {source} encloses no volume")
        if volume < 0:
            log.warning("shape model %s is wound inwards; turning its triangles outwards", source)
            f = f[:, ::-1].copy()
        if isinstance(centre, str):
            if centre == "centroid":
                c = _centroid(v, f)
            elif centre == "origin":
                c = np.zeros(3)
            else:
                raise InvalidParameterError(
                    f"shape centre must be 'centroid', 'origin' or three numbers; got {centre!r}")
        else:
            c = np.asarray(centre, dtype=np.float64).reshape(-1)
            if c.shape != (3,) or not np.all(np.isfinite(c)):
                raise InvalidParameterError(f"shape centre must be three numbers; got {centre!r}")
        w = winding_number(v, f, c)
        if w < INSIDE_WINDING:
            raise InvalidShapeError(
                f"the centre ({c[0]:.6g}, {c[1]:.6g}, {c[2]:.6g}) m of shape model {source} lies "
                f"outside its surface (winding number {w:.3f}); a body needs a centre inside it")
        return cls(np.ascontiguousarray(v - c), np.ascontiguousarray(f), source, c)

    @property
    def volume(self) -> float:
        """Enclosed volume, m^3."""
        return _signed_volume(self.vertices, self.faces)

    @property
    def equivalent_radius(self) -> float:
        """Radius of the sphere of the same volume, metres."""
        return (3.0 * self.volume / (4.0 * math.pi)) ** (1.0 / 3.0)

    def scaled(self, factor: float) -> ShapeModel:
        """Return the model scaled about its centre."""
        factor = float(factor)
        if not (factor > 0 and math.isfinite(factor)):
            raise InvalidParameterError(f"scale factor must be positive; got {factor}")
        return ShapeModel(self.vertices * factor, self.faces, self.source, self.centre)

    def stretched(self, stretch: Stretch) -> ShapeModel:
        """Return the model stretched along the axes about its centre."""
        return ShapeModel(self.vertices * stretch.factors, self.faces, self.source, self.centre)

    def project(self, mesh: SphereMesh) -> Projection:
        """Cast a ray from the centre through every mesh direction; keep the outermost hit."""
        n = mesh.n_vertices
        memory.require(n * 40.0, f"projecting {self.source} onto {n:,} directions")
        tmax = np.zeros(n)
        tmin = np.zeros(n)
        hits = np.zeros(n, dtype=np.int64)
        _cast(mesh.magnitude, self.vertices, self.faces, tmax, tmin, hits)
        missed = hits == 0
        if missed.any():
            raise InvalidShapeError(
                f"{int(missed.sum())} of {n} rays from the centre of {self.source} missed its "
                "surface; is the mesh closed around the centre?")
        projection = Projection(tmax, tmin)
        log.info("projected %s onto M = %d: %.3f %% of directions not star-shaped", self.source,
                 mesh.magnitude, 100.0 * projection.non_star_fraction)
        return projection


def _signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    total = 0.0
    for start in range(0, len(f), 1 << 20):
        c = f[start:start + (1 << 20)]
        total += float(np.einsum("ij,ij->", v[c[:, 0]], np.cross(v[c[:, 1]], v[c[:, 2]])))
    return total / 6.0


def _centroid(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Centroid of the enclosed volume (signed tetrahedra from the origin)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    return ((a + b + c) / 4.0 * vol[:, None]).sum(axis=0) / vol.sum()
