"""Crater records and catalogues.

A :class:`Crater` is one impact as a user names it (position, diameter, age); a
:class:`CraterTable` is many of them as columns, the form the generator produces and the
cratering kernel consumes. A :class:`CraterCatalog` is what the model made of each crater
(erosion state, depth, rim height, the fitted pre-impact level), the ground truth for
crater-detection navigation; a :class:`RockCatalog` the same for rocks. Both are frozen
tables of typed, read-only columns (:class:`terrain.core.table.ColumnTable`), written and
read as the catalogue CSVs (``to_csv``, ``from_csv``), joined (``concatenate``) and selected
(``take``).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import IO, ClassVar

import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.core.table import ColumnTable, read_table, write_table

__all__ = ["CATALOG_COLUMNS", "CATALOG_LAYER_COLUMNS", "ROCK_COLUMNS", "Crater", "CraterCatalog",
           "CraterTable", "RockCatalog", "read_circles", "read_columns", "write_columns"]


@dataclass(frozen=True)
class Crater:
    """One crater: centre (map metres), diameter (m), age (Gyr), identity.

    >>> Crater(10.0, 20.0, 5.0).age
    0.0
    >>> Crater(0, 0, -1)
    Traceback (most recent call last):
    ...
    terrain.core.errors.InvalidParameterError: crater diameter must be positive and finite; got -1.0
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
        all larger classes (see :mod:`terrain.craters.cratering`)
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


#: Columns of the catalogue CSV, in order; the attributes of :class:`CraterCatalog`.
CATALOG_COLUMNS = (
    "id", "x_m", "y_m", "row", "col", "diameter_m", "age_gyr", "size_class",
    "depth_fraction", "rim_fraction", "depth_m", "rim_height_m", "alpha", "beta",
    "reference_elevation_m",
)

#: The columns of a layer stack's catalogue: :data:`CATALOG_COLUMNS` and the layer.
CATALOG_LAYER_COLUMNS = (*CATALOG_COLUMNS, "layer")

#: Columns of the rock catalogue CSV, in order; the attributes of :class:`RockCatalog`.
ROCK_COLUMNS = ("id", "x_m", "y_m", "z_base_m", "diameter_m", "height_m", "burial_m",
                "axis_a_m", "axis_b_m", "axis_c_m", "orientation_deg", "layer")

@dataclass(frozen=True, eq=False)
class CraterCatalog(ColumnTable):
    """The catalogue of placed craters: one row per crater, columns as the CSV names them.

    Rows are in composition order (larger size classes first, then oldest first). Every
    column is a read-only (n,) array; the table checks its columns' lengths, dtypes and
    values when built.

    Parameters
    ----------
    id : (n,) uint64
        The crater's identity (written as 16 hex digits).
    x_m, y_m : (n,) float64, map metres
        Centre.
    row, col : (n,) float64, pixels
        Centre in the pixel grid of the DEM (or window) the catalogue describes; pixel
        centres are whole numbers.
    diameter_m : (n,) float64, metres
        Rim-to-rim diameter (> 0).
    age_gyr : (n,) float64, Gyr
        Age (>= 0).
    size_class : (n,) int64
        Octave bin the crater was composed in.
    depth_fraction, rim_fraction : (n,) float64
        Depth and rim height left by erosion, as fractions of the fresh crater's.
    depth_m, rim_height_m : (n,) float64, metres
        Depth and rim height as made.
    alpha, beta : (n,) float64
        The profile's joins in normalised radius x = r / R - 1 (:mod:`terrain.craters.crater`):
        alpha (<= 0) where the bowl meets the rim cap, beta (>= 0) where the rim's outer
        flank meets the ejecta.
    reference_elevation_m : (n,) float64, metres
        The fitted pre-impact level at the centre.
    layer : (n,) int64, optional
        The layer of a layer stack the crater was added to; None outside a stack.

    Examples
    --------
    >>> cat = CraterCatalog.empty(layered=True)
    >>> len(cat), cat.columns[-1]
    (0, 'layer')
    >>> cat.layer.dtype
    dtype('int64')
    """

    COLUMNS: ClassVar[tuple[str, ...]] = CATALOG_COLUMNS
    OPTIONAL: ClassVar[tuple[str, ...]] = ("layer",)
    DTYPES: ClassVar[Mapping[str, type]] = {"id": np.uint64, "size_class": np.int64,
                                            "layer": np.int64}
    WHAT: ClassVar[str] = "crater catalogue"
    FORMATS: ClassVar[Mapping[str, str]] = {"row": "{:.3f}", "col": "{:.3f}"}

    id: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    row: np.ndarray
    col: np.ndarray
    diameter_m: np.ndarray
    age_gyr: np.ndarray
    size_class: np.ndarray
    depth_fraction: np.ndarray
    rim_fraction: np.ndarray
    depth_m: np.ndarray
    rim_height_m: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    reference_elevation_m: np.ndarray
    layer: np.ndarray | None = None

    def __post_init__(self) -> None:
        self._freeze_columns()
        if not (np.all(np.isfinite(self.x_m)) and np.all(np.isfinite(self.y_m))):
            raise InvalidParameterError("crater catalogue positions x_m, y_m must be finite")
        if not np.all(self.diameter_m > 0):
            raise InvalidParameterError("crater catalogue diameters diameter_m must be positive")
        if not np.all(self.age_gyr >= 0):
            raise InvalidParameterError("crater catalogue ages age_gyr must be >= 0 Gyr")
        if self.layer is not None and not np.all(self.layer >= 0):
            raise InvalidParameterError("crater catalogue layers must be >= 0")

    @classmethod
    def empty(cls, *, optional: Iterable[str] = (), layered: bool = False) -> CraterCatalog:
        """Return a catalogue without rows.

        Parameters
        ----------
        optional : iterable of str
            Its optional columns (``("layer",)`` or none).
        layered : bool
            Give it the ``layer`` column of a layer stack's catalogue (as ``optional``).

        Returns
        -------
        CraterCatalog
        """
        return super().empty(optional=("layer",) if layered else optional)

    def with_layer(self, layer: int) -> CraterCatalog:
        """Return the catalogue with every row's ``layer`` set to ``layer``.

        Parameters
        ----------
        layer : int
            The layer of a layer stack the craters were added to.

        Returns
        -------
        CraterCatalog
        """
        return self.with_columns(layer=np.full(len(self), layer, dtype=np.int64))


@dataclass(frozen=True, eq=False)
class RockCatalog(ColumnTable):
    """The catalogue of rocks stood on a DEM or a layer stack: one row per rock.

    Parameters
    ----------
    id : (n,) uint64
        The rock's identity (written as 16 hex digits).
    x_m, y_m : (n,) float64, map metres
        Centre.
    z_base_m : (n,) float64, metres
        Height of the ground under the rock's centre (the base it stands on).
    diameter_m : (n,) float64, metres
        The rock's diameter as the size-frequency model draws it (> 0).
    height_m, burial_m : (n,) float64, metres
        Height above the ground and depth buried (together the vertical semi-axis).
    axis_a_m, axis_b_m, axis_c_m : (n,) float64, metres
        The ellipsoid's semi-axes (long, intermediate, vertical).
    orientation_deg : (n,) float64, degrees
        The long axis's angle from map east towards north, in [0, 180).
    layer : (n,) int64
        The coarsest layer that holds the rock's centre and resolves it (0 outside a stack).
    """

    COLUMNS: ClassVar[tuple[str, ...]] = ROCK_COLUMNS
    DTYPES: ClassVar[Mapping[str, type]] = {"id": np.uint64, "layer": np.int64}
    WHAT: ClassVar[str] = "rock catalogue"

    id: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    z_base_m: np.ndarray
    diameter_m: np.ndarray
    height_m: np.ndarray
    burial_m: np.ndarray
    axis_a_m: np.ndarray
    axis_b_m: np.ndarray
    axis_c_m: np.ndarray
    orientation_deg: np.ndarray
    layer: np.ndarray

    def __post_init__(self) -> None:
        self._freeze_columns()
        if not (np.all(np.isfinite(self.x_m)) and np.all(np.isfinite(self.y_m))):
            raise InvalidParameterError("rock catalogue positions x_m, y_m must be finite")
        if not np.all(self.diameter_m > 0):
            raise InvalidParameterError("rock catalogue diameters diameter_m must be positive")
        if not np.all(self.layer >= 0):
            raise InvalidParameterError("rock catalogue layers must be >= 0")


def write_columns(path_or_file: str | os.PathLike | IO[str],
                  rows: Mapping[str, np.ndarray], columns: Sequence[str]) -> None:
    """Write a table of equal-length columns as CSV, the way every craterscape catalogue is.

    ``id`` is written as 16 hex digits, ``row`` and ``col`` with three decimals, integers
    as integers, other numbers at full precision (``repr``) and non-finite numbers empty.

    Parameters
    ----------
    path_or_file : path or text file
        Where to write.
    rows : mapping of str to (n,) array
        The columns (at least those named by ``columns``).
    columns : sequence of str
        The header, in order.
    """
    write_table(path_or_file, rows, columns, formats=CraterCatalog.FORMATS)


def read_columns(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a CSV written by :func:`write_columns` into column arrays.

    Parameters
    ----------
    path : path
        The CSV.

    Returns
    -------
    dict of str to (n,) array
        ``id`` uint64 (from hex), ``size_class`` and ``layer`` int64, every other column
        float64 (NaN where empty).

    Raises
    ------
    ValueError
        A value is not a number.
    """
    return read_table(path, {"size_class": np.int64, "layer": np.int64})


def read_circles(path) -> CraterTable:
    """Craters from a CSV with columns x, y, diameter and optionally age (map metres, Gyr).

    Used for crater gaps (``craterscape terrain fill --craters-at``). Each crater's identity is
    keyed by its position and size, so the same file gives the same craters.
    """
    from pathlib import Path

    from terrain.core.errors import MissingInputError
    from terrain.core.rng import hash64, stream_id

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
