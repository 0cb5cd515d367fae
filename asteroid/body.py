"""The asteroid body: a radius per vertex of the 6M^2 + 2 mesh, the mesh parameters, provenance.

A :class:`Body` is the value that flows between the asteroid operations (bases, craters,
boulders, export): immutable, validated when built, and saved as the *native* model, an
``.npz`` archive holding

``format``
    ``"craterscape-asteroid/1"``.
``magnitude``, ``radius``
    M and the reference radius R (metres): the sphere whose mesh the body deforms.
``radii``
    (6M^2 + 2,) float64, metres: the distance from the centre to each vertex along its unit
    direction (:meth:`asteroid.sphere.SphereMesh.directions`). ``radii - radius`` is the
    displacement.
``metadata``
    JSON provenance: seed, base and its parameters, crater and boulder settings, version.
``<table>/<column>``
    Optional catalogue columns (craters, boulders) stored beside the body as ground truth.

The archive is written byte-for-byte reproducibly (fixed zip timestamps, no compression, a
fixed member order) and atomically (:func:`terrain.core.outputs.atomic_path`), so the same inputs
and seed give the same file.

The :class:`Stretch` value maps a body onto its affine stretch along the axes (section IV.A:
"can be stretched along one axis to create an elongated shape"): the point ``r0 u0`` moves to
``S r0 u0``; its direction u is the mesh direction, so the radius along a mesh direction u is
``r0(u0) / |S^-1 u|`` with ``u0 = S^-1 u / |S^-1 u|``.
"""

from __future__ import annotations

import io
import json
import logging
import math
import zipfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numba
import numpy as np

from asteroid.sphere import SphereMesh, band_size, band_triangle
from terrain.core.checks import number
from terrain.core.errors import InvalidParameterError, MissingInputError
from terrain.core.outputs import atomic_path

__all__ = ["FORMAT", "Body", "NativeModel", "Stretch", "load_native", "npy_member", "save_native"]

log = logging.getLogger(__name__)

#: Identifier of the native file format (bumped on any incompatible change).
FORMAT = "craterscape-asteroid/1"
#: Fixed timestamp of every zip member (the earliest a zip file can hold), for identical bytes.
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


@dataclass(frozen=True)
class Stretch:
    """Affine stretch factors along x, y and z (all positive; 1, 1, 1 is no stretch).

    >>> s = Stretch(2.0, 1.0, 1.0)
    >>> u = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    >>> u0, factor = s.source(u)
    >>> factor.tolist()                 # radius multipliers along x and y
    [2.0, 1.0]
    """

    x: float = 1.0
    y: float = 1.0
    z: float = 1.0

    def __post_init__(self):
        for name in ("x", "y", "z"):
            object.__setattr__(self, name, number(getattr(self, name), name, low=0,
                                                  low_open=True, where="stretch"))

    @classmethod
    def parse(cls, value) -> Stretch:
        """From ``"A,B,C"``, a sequence of three numbers, a Stretch or None (no stretch)."""
        if value is None:
            return cls()
        if isinstance(value, Stretch):
            return value
        if isinstance(value, str):
            parts = [p.strip() for p in value.split(",")]
            try:
                value = [float(p) for p in parts]
            except ValueError:
                raise InvalidParameterError(
                    f"stretch must be three numbers A,B,C; got {value!r}") from None
        value = list(value)
        if len(value) != 3:
            raise InvalidParameterError(f"stretch must be three numbers A,B,C; got {value!r}")
        return cls(*value)

    @property
    def factors(self) -> np.ndarray:
        """The stretch factors (x, y, z) as a (3,) float64 array."""
        return np.array([self.x, self.y, self.z])

    @property
    def is_identity(self) -> bool:
        """Whether the stretch leaves every point where it is (all factors 1)."""
        return self.x == self.y == self.z == 1.0

    def source(self, directions) -> tuple[np.ndarray, np.ndarray]:
        """(u0, factor): where each unit direction u comes from, and ``1 / |S^-1 u|``.

        The radius of the stretched body along u is ``factor * r0(u0)``.
        """
        v = np.asarray(directions, dtype=np.float64) / self.factors
        length = np.linalg.norm(v, axis=-1)
        return v / length[..., None], 1.0 / length

    def as_list(self) -> list[float]:
        """Return the factors as a list [x, y, z] (for TOML and JSON)."""
        return [self.x, self.y, self.z]


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.flags.writeable = False
    return a


@numba.njit(cache=True)
def _face_sums(m, directions, radii):
    """(volume, area) of the triangle mesh: signed tetrahedra from the centre, and areas."""
    volume = 0.0
    area = 0.0
    for b in range(2 * m):
        for t in range(band_size(m, b)):
            i0, i1, i2 = band_triangle(m, b, t)
            ax, ay, az = directions[i0, 0] * radii[i0], directions[i0, 1] * radii[i0], \
                directions[i0, 2] * radii[i0]
            bx, by, bz = directions[i1, 0] * radii[i1], directions[i1, 1] * radii[i1], \
                directions[i1, 2] * radii[i1]
            cx, cy, cz = directions[i2, 0] * radii[i2], directions[i2, 1] * radii[i2], \
                directions[i2, 2] * radii[i2]
            volume += ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
            ux, uy, uz = bx - ax, by - ay, bz - az
            vx, vy, vz = cx - ax, cy - ay, cz - az
            wx, wy, wz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            area += math.sqrt(wx * wx + wy * wy + wz * wz)
    return volume / 6.0, area / 2.0


@dataclass(frozen=True, eq=False)
class Body:
    """An asteroid model: vertex radii on the magnitude-M mesh, and its provenance.

    Parameters
    ----------
    mesh : SphereMesh
    radius : float
        Reference radius R, metres (> 0).
    radii : (6M^2 + 2,) float64, metres
        Distance from the centre to each vertex; positive and finite.
    metadata : mapping
        JSON-serialisable provenance (seed, base, parameters).

    Examples
    --------
    >>> body = Body.sphere(SphereMesh(4), 1000.0)
    >>> body.radii.shape, float(body.displacement.max())
    ((98,), 0.0)
    >>> round(body.volume() / (4 / 3 * np.pi * 1000.0**3), 3)   # inscribed polyhedron
    0.94
    """

    mesh: SphereMesh
    radius: float
    radii: np.ndarray
    metadata: Mapping = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.mesh, SphereMesh):
            raise InvalidParameterError(
                f"body mesh must be a SphereMesh; got {type(self.mesh).__name__}")
        radius = float(self.radius)
        if not (radius > 0 and math.isfinite(radius)):
            raise InvalidParameterError(f"body radius must be positive metres; got {radius}")
        object.__setattr__(self, "radius", radius)
        radii = _readonly(self.radii)
        if radii.shape != (self.mesh.n_vertices,):
            raise InvalidParameterError(
                f"radii must be ({self.mesh.n_vertices},) float64 for magnitude "
                f"{self.mesh.magnitude}; got shape {radii.shape}")
        bad = ~(np.isfinite(radii) & (radii > 0))
        if bad.any():
            raise InvalidParameterError(
                f"radii must be positive and finite; {int(bad.sum())} of {radii.size} vertices "
                f"are not (first at vertex {int(np.argmax(bad))}: {radii[np.argmax(bad)]})")
        object.__setattr__(self, "radii", radii)
        meta = dict(self.metadata)
        try:
            json.dumps(meta)
        except (TypeError, ValueError) as exc:
            raise InvalidParameterError(f"body metadata must be JSON-serialisable: {exc}") \
                from exc
        object.__setattr__(self, "metadata", MappingProxyType(meta))

    @classmethod
    def sphere(cls, mesh: SphereMesh, radius: float, **metadata) -> Body:
        """Return a perfect sphere of ``radius`` metres."""
        return cls(mesh, radius, np.full(mesh.n_vertices, float(radius)), metadata)

    @property
    def magnitude(self) -> int:
        """The mesh magnitude M (6 M^2 + 2 vertices)."""
        return self.mesh.magnitude

    @property
    def displacement(self) -> np.ndarray:
        """(N,) float64 metres: radii minus the reference radius."""
        return self.radii - self.radius

    def replace(self, radii=None, **metadata) -> Body:
        """Return a new body with other radii and/or extra metadata keys."""
        meta = dict(self.metadata)
        meta.update(metadata)
        return Body(self.mesh, self.radius, self.radii if radii is None else radii, meta)

    def vertices(self) -> np.ndarray:
        """(N, 3) float64 vertex positions, metres."""
        return self.mesh.directions() * self.radii[:, None]

    def surface_radius(self, directions) -> np.ndarray:
        """Distance (m) from the centre to the surface along unit direction(s)."""
        return self.mesh.surface_radius(self.radii, directions)

    def _face_sums(self):
        return _face_sums(self.mesh.magnitude, self.mesh.directions(), self.radii)

    def volume(self) -> float:
        """Enclosed volume of the triangle mesh, m^3 (sum of signed tetrahedra)."""
        return self._face_sums()[0]

    def area(self) -> float:
        """Surface area of the triangle mesh, m^2."""
        return self._face_sums()[1]

    def summary(self) -> dict:
        """Figures a user checks first (JSON-friendly)."""
        volume, area = self._face_sums()
        r = self.radii
        return dict(magnitude=self.magnitude, vertices=self.mesh.n_vertices,
                    triangles=self.mesh.n_faces, reference_radius_m=self.radius,
                    radius_min_m=float(r.min()), radius_max_m=float(r.max()),
                    radius_mean_m=float(r.mean()), volume_m3=volume, area_m2=area,
                    equivalent_radius_m=(3.0 * volume / (4.0 * math.pi)) ** (1.0 / 3.0),
                    mean_spacing_m=self.mesh.mean_spacing * self.radius)


@dataclass(frozen=True, eq=False)
class NativeModel:
    """What a native ``.npz`` holds: the body and catalogue tables (name -> column arrays)."""

    body: Body
    tables: Mapping = field(default_factory=dict)


def npy_member(zf: zipfile.ZipFile, name: str, array: np.ndarray) -> None:
    """Write ``array`` into ``zf`` as ``NAME.npy``, stored, with a fixed date (same bytes)."""
    info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_EPOCH)
    info.compress_type = zipfile.ZIP_STORED
    info.external_attr = 0o644 << 16
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.require(array, requirements="C"), allow_pickle=False)
    zf.writestr(info, buf.getvalue())


def save_native(path, body: Body, tables: Mapping | None = None, *,
                inputs: Iterable = ()) -> Path:
    """Write the native ``.npz`` atomically, identical bytes for identical content.

    Parameters
    ----------
    path : str or Path
    body : Body
    tables : mapping of name -> mapping of column -> (n,) array, optional
        Catalogues stored beside the body (e.g. ``{"craters": {...}, "boulders": {...}}``).
    inputs : iterable of paths
        Files the output must not replace.
    """
    path = Path(path)
    with atomic_path(path, inputs) as tmp, zipfile.ZipFile(tmp, "w", allowZip64=True) as zf:
        npy_member(zf, "format", np.array(FORMAT))
        npy_member(zf, "magnitude", np.array(body.magnitude, dtype=np.int64))
        npy_member(zf, "radius", np.array(body.radius, dtype=np.float64))
        npy_member(zf, "radii", body.radii)
        npy_member(zf, "metadata", np.array(json.dumps(dict(body.metadata), sort_keys=True)))
        for table, columns in (tables or {}).items():
            for column, values in columns.items():
                values = np.asarray(values)
                if values.dtype == object:
                    raise InvalidParameterError(
                        f"table {table} column {column} must be numeric or text; got objects")
                npy_member(zf, f"{table}/{column}", values)
    log.info("wrote native model %s (M = %d, %d vertices)", path, body.magnitude,
             body.mesh.n_vertices)
    return path


def load_native(path) -> NativeModel:
    """Read a native ``.npz`` written by :func:`save_native`."""
    from terrain.core.outputs import settle

    path = Path(path)
    settle(path.parent if str(path.parent) else Path("."))  # finish an interrupted build
    if not path.exists():
        raise MissingInputError(f"native model '{path}' does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            names = set(data.files)
            need = {"format", "magnitude", "radius", "radii", "metadata"}
            if not need <= names:
                raise InvalidParameterError(
                    f"'{path}' is not a craterscape asteroid model (missing "
                    f"{sorted(need - names)})")
            fmt = str(data["format"].item())
            if fmt != FORMAT:
                raise InvalidParameterError(
                    f"'{path}' has format {fmt!r}; this version reads {FORMAT!r}")
            mesh = SphereMesh(int(data["magnitude"].item()))
            body = Body(mesh, float(data["radius"].item()), data["radii"],
                        json.loads(str(data["metadata"].item())))
            tables: dict = {}
            for name in sorted(names - need):
                if "/" in name:
                    table, column = name.split("/", 1)
                    tables.setdefault(table, {})[column] = data[name]
    except (zipfile.BadZipFile, ValueError, OSError, KeyError) as exc:
        if isinstance(exc, InvalidParameterError):
            raise
        raise InvalidParameterError(f"cannot read native model '{path}': {exc}") from exc
    return NativeModel(body, tables)
