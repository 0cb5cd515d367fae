"""Ground-truth catalogues of an asteroid's craters and boulders: typed tables, and CSV.

One row per feature, columns in the order of :data:`CRATER_COLUMNS` or
:data:`BOULDER_COLUMNS`. Units are in the column names (``_deg`` degrees, ``_m`` metres,
``_gyr`` Gyr); ``x, y, z`` without a unit are unit vectors from the body's centre;
``r00 .. r22`` are the rows of a boulder's rotation matrix (its frame to the body frame).
``id`` is the feature's 64-bit identity in hexadecimal (it keys the feature's own randomness,
so the same id means the same feature in every run). Latitudes are planetocentric with z as the
pole; longitudes run east from +x in [0, 360).

Both catalogues are :class:`terrain.core.table.ColumnTable` records: typed, read-only columns
checked when built, an unknown column refused by name (``from_columns``), written and read
back as CSV (``to_csv``, ``from_csv``). The same columns are stored in the native ``.npz``
(``craters/<column>``, ``boulders/<column>``), so a catalogue can always be rewritten from the
model.

>>> import io
>>> cat = BoulderCatalog.empty()
>>> buf = io.StringIO()
>>> cat.to_csv(buf)
>>> buf.getvalue().split(",")[:3]
['id', 'lat_deg', 'lon_deg']
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import atomic_path
from terrain.core.table import ColumnTable

__all__ = ["BOULDER_COLUMNS", "CRATER_COLUMNS", "BoulderCatalog", "CraterCatalog", "save_table"]

#: Columns of the crater catalogue, in CSV order; the attributes of :class:`CraterCatalog`.
CRATER_COLUMNS = (
    "id", "lat_deg", "lon_deg", "x", "y", "z", "diameter_m", "age_gyr", "size_class",
    "depth_fraction", "rim_fraction", "slope_deg", "slope_factor", "depth_m", "rim_height_m",
    "alpha", "beta", "reference_radius_m", "extent_deg", "applied",
)

#: Columns of the boulder catalogue, in CSV order; the attributes of :class:`BoulderCatalog`.
BOULDER_COLUMNS = (
    "id", "lat_deg", "lon_deg", "x_m", "y_m", "z_m", "diameter_m", "height_m", "flattening",
    "elongation", "burial_fraction", "burial_depth_m", "surface_radius_m", "yaw_deg",
    "pitch_deg", "roll_deg", "size_class",
    "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22",
)


@dataclass(frozen=True, eq=False)
class CraterCatalog(ColumnTable):
    """The craters of an asteroid, in age order (oldest first): one row per crater.

    Parameters
    ----------
    id : (n,) uint64
        The crater's identity.
    lat_deg, lon_deg : (n,) float64, degrees
        Centre, planetocentric.
    x, y, z : (n,) float64
        Unit vector from the body's centre to the crater's centre.
    diameter_m : (n,) float64, metres
        Rim-to-rim diameter (> 0).
    age_gyr : (n,) float64, Gyr
        Age (>= 0).
    size_class : (n,) int64
        Octave bin.
    depth_fraction, rim_fraction : (n,) float64
        Depth and rim height left by erosion and slope, as fractions of the fresh crater's.
    slope_deg : (n,) float64, degrees
        Local slope under the crater (NaN where it could not be fitted).
    slope_factor : (n,) float64
        The depth and rim reduction the slope applied (:class:`asteroid.craters.SlopeErosion`).
    depth_m, rim_height_m : (n,) float64, metres
        Depth and rim height as made.
    alpha, beta : (n,) float64
        The profile's joins in normalised radius (:mod:`terrain.craters.crater`).
    reference_radius_m : (n,) float64, metres
        The fitted pre-impact radius at the centre (NaN where it could not be fitted).
    extent_deg : (n,) float64, degrees
        Angular extent of the crater's footprint.
    applied : (n,) int64
        1 where the crater was dug, 0 where it was skipped (too steep).
    """

    COLUMNS: ClassVar[tuple[str, ...]] = CRATER_COLUMNS
    DTYPES: ClassVar[Mapping[str, type]] = {"id": np.uint64, "size_class": np.int64,
                                            "applied": np.int64}
    WHAT: ClassVar[str] = "asteroid crater catalogue"
    LINE_END: ClassVar[str] = "\n"

    id: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    diameter_m: np.ndarray
    age_gyr: np.ndarray
    size_class: np.ndarray
    depth_fraction: np.ndarray
    rim_fraction: np.ndarray
    slope_deg: np.ndarray
    slope_factor: np.ndarray
    depth_m: np.ndarray
    rim_height_m: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    reference_radius_m: np.ndarray
    extent_deg: np.ndarray
    applied: np.ndarray

    def __post_init__(self) -> None:
        self._freeze_columns()
        if not np.all(self.diameter_m > 0):
            raise InvalidParameterError(f"{self.WHAT} diameters diameter_m must be positive")
        if not np.all(self.age_gyr >= 0):
            raise InvalidParameterError(f"{self.WHAT} ages age_gyr must be >= 0 Gyr")
        if not np.all((self.applied == 0) | (self.applied == 1)):
            raise InvalidParameterError(f"{self.WHAT} column applied must be 0 or 1")


@dataclass(frozen=True, eq=False)
class BoulderCatalog(ColumnTable):
    """The boulders on an asteroid: one row per boulder.

    Parameters
    ----------
    id : (n,) uint64
        The boulder's identity (keys its shape).
    lat_deg, lon_deg : (n,) float64, degrees
        Where it stands, planetocentric.
    x_m, y_m, z_m : (n,) float64, metres
        Its centre in the body frame.
    diameter_m : (n,) float64, metres
        Size (> 0).
    height_m : (n,) float64, metres
        Height of its unrotated shape.
    flattening, elongation : (n,) float64
        Shape ratios.
    burial_fraction : (n,) float64
        Fraction of the height buried.
    burial_depth_m : (n,) float64, metres
        Depth buried.
    surface_radius_m : (n,) float64, metres
        The body's radius under the boulder.
    yaw_deg, pitch_deg, roll_deg : (n,) float64, degrees
        Its orientation on the local surface.
    size_class : (n,) int64
        Octave bin.
    r00, r01, r02, r10, r11, r12, r20, r21, r22 : (n,) float64
        Rows of its rotation from its own frame to the body frame.
    """

    COLUMNS: ClassVar[tuple[str, ...]] = BOULDER_COLUMNS
    DTYPES: ClassVar[Mapping[str, type]] = {"id": np.uint64, "size_class": np.int64}
    WHAT: ClassVar[str] = "boulder catalogue"
    LINE_END: ClassVar[str] = "\n"

    id: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray
    diameter_m: np.ndarray
    height_m: np.ndarray
    flattening: np.ndarray
    elongation: np.ndarray
    burial_fraction: np.ndarray
    burial_depth_m: np.ndarray
    surface_radius_m: np.ndarray
    yaw_deg: np.ndarray
    pitch_deg: np.ndarray
    roll_deg: np.ndarray
    size_class: np.ndarray
    r00: np.ndarray
    r01: np.ndarray
    r02: np.ndarray
    r10: np.ndarray
    r11: np.ndarray
    r12: np.ndarray
    r20: np.ndarray
    r21: np.ndarray
    r22: np.ndarray

    def __post_init__(self) -> None:
        self._freeze_columns()
        if not np.all(self.diameter_m > 0):
            raise InvalidParameterError(f"{self.WHAT} diameters diameter_m must be positive")
        if not (np.all(np.isfinite(self.x_m)) and np.all(np.isfinite(self.y_m))
                and np.all(np.isfinite(self.z_m))):
            raise InvalidParameterError(f"{self.WHAT} centres x_m, y_m, z_m must be finite")

    def rotations(self) -> np.ndarray:
        """(n, 3, 3) rotation of each boulder from its own frame to the body frame."""
        return np.stack([getattr(self, f"r{i}{j}") for i in range(3) for j in range(3)],
                        axis=-1).reshape(-1, 3, 3)


def save_table(path, table: ColumnTable, *, inputs: Iterable = ()) -> Path:
    """Write a catalogue CSV atomically (never over an input).

    Parameters
    ----------
    path : str or pathlib.Path
        The CSV.
    table : CraterCatalog or BoulderCatalog
        The catalogue.
    inputs : iterable of paths
        Files the output must not replace.

    Returns
    -------
    pathlib.Path
    """
    with atomic_path(path, inputs) as tmp:
        table.to_csv(tmp)
    return Path(path)
