"""Crater records and catalogues.

A :class:`Crater` is one impact as a user names it (position, diameter, age); a
:class:`CraterTable` is many of them as columns, the form the generator produces and the
cratering kernel consumes. The catalogue CSV written after cratering adds what the model made
of each crater (erosion state, depth, rim height, the fitted pre-impact level): ground truth
for crater-detection navigation.
"""

from __future__ import annotations

import contextlib
import csv
import math
from dataclasses import dataclass, field

import numpy as np

from terrain.errors import InvalidParameterError

__all__ = ["CATALOG_COLUMNS", "Crater", "CraterTable", "csv_sink", "write_catalog"]


@dataclass(frozen=True)
class Crater:
    """One crater: centre (map metres), diameter (m), age (Gyr), identity.

    >>> Crater(10.0, 20.0, 5.0).age
    0.0
    >>> Crater(0, 0, -1)
    Traceback (most recent call last):
    ...
    terrain.errors.InvalidParameterError: crater diameter must be positive and finite; got -1.0
    """

    x: float
    y: float
    diameter: float
    age: float = 0.0
    uid: int = 0

    def __post_init__(self):
        for name in ("x", "y", "diameter", "age"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise InvalidParameterError(f"crater {name} must be finite; got {value}")
            object.__setattr__(self, name, value)
        if self.diameter <= 0:
            raise InvalidParameterError(
                f"crater diameter must be positive and finite; got {self.diameter}")
        if self.age < 0:
            raise InvalidParameterError(f"crater age must be >= 0 Gyr; got {self.age}")
        object.__setattr__(self, "uid", int(self.uid) & (2**64 - 1))


def _readonly(a, dtype):
    a = np.array(a, dtype=dtype, copy=True).reshape(-1)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class CraterTable:
    """Columns of craters. ``size_class`` orders the composition (larger classes first).

    Parameters
    ----------
    x, y : (n,) float64, map metres
    diameter : (n,) float64, metres
    age : (n,) float64, Gyr
    uid : (n,) uint64, the crater's identity (keys its roughness and rim randomness)
    size_class : (n,) int64, octave bin; craters of a class are fitted to the terrain left by
        all larger classes (see :mod:`terrain.cratering`)
    """

    x: np.ndarray
    y: np.ndarray
    diameter: np.ndarray
    age: np.ndarray
    uid: np.ndarray
    size_class: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        cols = dict(x=np.float64, y=np.float64, diameter=np.float64, age=np.float64,
                    uid=np.uint64, size_class=np.int64)
        n = None
        for name, dtype in cols.items():
            a = _readonly(getattr(self, name), dtype)
            if n is None:
                n = a.size
            elif a.size != n:
                raise InvalidParameterError(
                    f"crater table column {name} has {a.size} rows; expected {n}")
            object.__setattr__(self, name, a)
        if n and not (np.all(np.isfinite(self.x)) and np.all(np.isfinite(self.y))):
            raise InvalidParameterError("crater positions must be finite")
        if n and not np.all(self.diameter > 0):
            raise InvalidParameterError("crater diameters must be positive")
        if n and not np.all(self.age >= 0):
            raise InvalidParameterError("crater ages must be >= 0 Gyr")

    def __len__(self) -> int:
        return int(self.x.size)

    @classmethod
    def empty(cls) -> CraterTable:
        """Return a table without craters."""
        z = np.zeros(0)
        return cls(z, z, z, z, z.astype(np.uint64), z.astype(np.int64))

    @classmethod
    def from_craters(cls, craters) -> CraterTable:
        """Table of explicit craters; each gets the octave class floor(log2(D / 1 m))."""
        craters = list(craters)
        if not craters:
            return cls.empty()
        d = np.array([c.diameter for c in craters])
        return cls(np.array([c.x for c in craters]), np.array([c.y for c in craters]), d,
                   np.array([c.age for c in craters]),
                   np.array([c.uid for c in craters], dtype=np.uint64),
                   np.floor(np.log2(d)).astype(np.int64))

    def take(self, index) -> CraterTable:
        """Return the craters selected by ``index`` (an index array or boolean mask)."""
        return CraterTable(self.x[index], self.y[index], self.diameter[index], self.age[index],
                           self.uid[index], self.size_class[index], dict(self.meta))

    @staticmethod
    def concatenate(tables) -> CraterTable:
        """Return one table of the craters of ``tables``, in order."""
        tables = [t for t in tables if len(t)]
        if not tables:
            return CraterTable.empty()

        def joined(name: str) -> np.ndarray:
            return np.concatenate([getattr(t, name) for t in tables])

        return CraterTable(joined("x"), joined("y"), joined("diameter"), joined("age"),
                           joined("uid"), joined("size_class"))

    def composition_order(self) -> np.ndarray:
        """Return indices in processing order: larger size classes first, then oldest first.

        Ties in age are broken by uid, so the order of any two craters never depends on
        which other craters are present (a window and the full tile agree).
        """
        return np.lexsort((self.uid, -self.age, -self.size_class))

    def __iter__(self):
        for i in range(len(self)):
            yield Crater(self.x[i], self.y[i], self.diameter[i], self.age[i], int(self.uid[i]))


#: Columns of the catalogue CSV, with units.
CATALOG_COLUMNS = (
    "id", "x_m", "y_m", "row", "col", "diameter_m", "age_gyr", "size_class",
    "depth_fraction", "rim_fraction", "depth_m", "rim_height_m", "alpha", "beta",
    "reference_elevation_m",
)


@contextlib.contextmanager
def csv_sink(path_or_file):
    """Yield a text file for a CSV writer.

    ``path_or_file`` itself if it has ``write``, else that path opened for writing (and
    closed afterwards).
    """
    if hasattr(path_or_file, "write"):
        yield path_or_file
        return
    with open(path_or_file, "w", newline="", encoding="utf-8") as f:
        yield f


def write_catalog(path_or_file, rows: dict, columns=CATALOG_COLUMNS) -> None:
    """Write catalogue columns (dict of equal-length arrays keyed by ``columns``)."""
    n = len(rows["id"]) if rows else 0
    with csv_sink(path_or_file) as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for i in range(n):
            out = []
            for name in columns:
                v = rows[name][i]
                if name == "id":
                    out.append(f"{int(v):016x}")
                elif name in ("row", "col"):
                    out.append(f"{float(v):.3f}")
                elif isinstance(v, (int, np.integer)):
                    out.append(str(int(v)))
                else:
                    out.append(repr(float(v)) if math.isfinite(float(v)) else "")
            writer.writerow(out)


def read_catalog(path) -> dict:
    """Read a catalogue CSV written by :func:`write_catalog` into column arrays."""
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        names = reader.fieldnames or []
        cols: dict[str, list[str]] = {name: [] for name in names}
        for row in reader:
            for name in names:
                cols[name].append(row[name])
    out = {}
    for name, values in cols.items():
        if name == "id":
            out[name] = np.array([int(v, 16) for v in values], dtype=np.uint64)
        elif name in ("size_class", "layer"):
            out[name] = np.array([int(v) for v in values], dtype=np.int64)
        else:
            out[name] = np.array([float(v) if v else np.nan for v in values])
    return out


def read_circles(path) -> CraterTable:
    """Craters from a CSV with columns x, y, diameter and optionally age (map metres, Gyr).

    Used for crater gaps (``craterscape terrain fill --craters-at``). Each crater's identity is
    keyed by its position and size, so the same file gives the same craters.
    """
    from pathlib import Path

    from terrain.errors import MissingInputError
    from terrain.rng import hash64, stream_id

    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"crater list '{path}' does not exist")
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(line for line in f if not line.lstrip().startswith("#"))
        fields = {name.strip().lower(): name for name in (reader.fieldnames or [])}
        if not {"x", "y", "diameter"} <= set(fields):
            raise InvalidParameterError(
                f"crater list '{path}' needs columns x, y, diameter (and optionally age); "
                f"got {reader.fieldnames}")
        craters = []
        for n, row in enumerate(reader, start=2):
            try:
                x = float(row[fields["x"]])
                y = float(row[fields["y"]])
                d = float(row[fields["diameter"]])
                age = float(row[fields["age"]]) if "age" in fields and row[fields["age"]] else 0.0
            except (TypeError, ValueError):
                raise InvalidParameterError(
                    f"crater list '{path}' line {n}: x, y, diameter must be numbers") from None
            try:
                crater = Crater(x, y, d, age)
            except InvalidParameterError as exc:
                raise InvalidParameterError(f"crater list '{path}' line {n}: {exc}") from None
            uid = int(hash64(0, stream_id("circle"), 0, int(round(x * 1000)),
                             int(round(y * 1000)), int(round(d * 1000))))
            craters.append(Crater(crater.x, crater.y, crater.diameter, crater.age, uid))
    return CraterTable.from_craters(craters)
