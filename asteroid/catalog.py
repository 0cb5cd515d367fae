"""Ground-truth catalogues of an asteroid's craters and boulders, as CSV.

One row per feature, columns in the order of :data:`asteroid.craters.CRATER_COLUMNS` or
:data:`asteroid.boulders.BOULDER_COLUMNS`. Units are in the column names (``_deg`` degrees,
``_m`` metres, ``_gyr`` Gyr); ``x, y, z`` without a unit are unit vectors from the body's
centre; ``r00 .. r22`` are the rows of a boulder's rotation matrix (its frame to the body
frame). ``id`` is the feature's 64-bit identity in hexadecimal (it keys the feature's own
randomness, so the same id means the same feature in every run). Latitudes are
planetocentric with z as the pole; longitudes run east from +x in [0, 360).

The same columns are stored in the native ``.npz`` (``craters/<column>``,
``boulders/<column>``), so a catalogue can always be rewritten from the model.

>>> import io
>>> buf = io.StringIO()
>>> write_table(buf, {"id": np.array([255], np.uint64), "diameter_m": np.array([12.5])},
...             ("id", "diameter_m"))
>>> buf.getvalue().splitlines()
['id,diameter_m', '00000000000000ff,12.5']
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import atomic_path
from terrain.craters.catalog import csv_sink

__all__ = ["save_table", "write_table"]


def write_table(path_or_file, columns: Mapping, order: Sequence[str]) -> None:
    """Write columns (equal-length arrays) as CSV in ``order``."""
    missing = [name for name in order if name not in columns]
    if missing:
        raise InvalidParameterError(f"catalogue is missing columns {missing}")
    n = len(columns[order[0]]) if order else 0
    for name in order:
        if len(columns[name]) != n:
            raise InvalidParameterError(
                f"catalogue column {name} has {len(columns[name])} rows; expected {n}")
    with csv_sink(path_or_file) as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(order)
        cols = [np.asarray(columns[name]) for name in order]
        for i in range(n):
            row = []
            for name, col in zip(order, cols, strict=True):
                v = col[i]
                if name == "id":
                    row.append(f"{int(v):016x}")
                elif col.dtype.kind in "iub":
                    row.append(str(int(v)))
                else:
                    x = float(v)
                    row.append(repr(x) if math.isfinite(x) else "")
            writer.writerow(row)


def save_table(path, columns: Mapping, order: Sequence[str], *,
               inputs: Iterable = ()) -> Path:
    """Write a catalogue CSV atomically (never over an input)."""
    with atomic_path(path, inputs) as tmp:
        write_table(tmp, columns, order)
    return Path(path)
