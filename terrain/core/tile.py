"""The DEM tile: the value that flows between terrain operations.

A :class:`DEMTile` is immutable: heights, valid mask, georeferencing and provenance. Every
operation takes tiles and returns new ones. Heights of invalid pixels are NaN inside a tile,
and the valid mask says the same thing explicitly, so no NaN can spread unnoticed: operations
read the mask, and the file writer turns NaN back into the nodata value.

Georeferencing follows GDAL: ``transform`` maps (col, row) pixel corners to map (x, y); only
north-up transforms (no rotation) are accepted, so the pixel spacing is ``(transform.a,
-transform.e)`` metres. Pixel (row, col) has its centre at
``transform @ (col + 0.5, row + 0.5)``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from affine import Affine

from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.parallel import run_blocks

__all__ = ["DEMTile", "Window", "default_transform"]


def default_transform(resolution: float, nrows: int) -> Affine:
    """North-up transform of a local map frame with the tile's lower-left corner at (0, 0)."""
    return Affine(resolution, 0.0, 0.0, 0.0, -resolution, resolution * nrows)


#: Rows per block of :func:`_finite_rows` (a 8193-pixel row is 32 KiB of heights).
FINITE_ROWS = 256


def _finite_rows(heights: np.ndarray, valid: np.ndarray, first: int, last: int) -> None:
    """Write ``isfinite(heights)`` into ``valid`` on the blocks of rows ``first .. last - 1``.

    NumPy releases the GIL in the comparison, so :func:`terrain.core.parallel.run_blocks`
    derives a large tile's mask on every core.
    """
    rows = slice(first * FINITE_ROWS, last * FINITE_ROWS)
    np.isfinite(heights[rows], out=valid[rows])


@dataclass(frozen=True)
class Window:
    """A rectangle of pixels: ``col, row`` of the upper-left pixel, ``width, height`` in pixels.

    >>> Window.parse("10,20,64,32")
    Window(col=10, row=20, width=64, height=32)
    """

    col: int
    row: int
    width: int
    height: int

    def __post_init__(self):
        for name in ("col", "row", "width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise InvalidParameterError(f"window {name} must be an integer; got {value!r}")
            object.__setattr__(self, name, int(value))
        if self.width <= 0 or self.height <= 0:
            raise InvalidParameterError(
                f"window width and height must be positive; got {self.width}x{self.height}")

    @classmethod
    def parse(cls, text: str) -> Window:
        """Parse ``"COL,ROW,WIDTH,HEIGHT"``."""
        parts = [p.strip() for p in str(text).split(",")]
        if len(parts) != 4:
            raise InvalidParameterError(f"window must be COL,ROW,WIDTH,HEIGHT; got {text!r}")
        try:
            values = [int(p) for p in parts]
        except ValueError:
            raise InvalidParameterError(
                f"window must be four integers COL,ROW,WIDTH,HEIGHT; got {text!r}") from None
        return cls(*values)

    def check_inside(self, nrows: int, ncols: int) -> None:
        """Raise unless the window lies inside a ``nrows x ncols`` raster."""
        if (self.col < 0 or self.row < 0 or self.col + self.width > ncols
                or self.row + self.height > nrows):
            raise InvalidParameterError(
                f"window {self.col},{self.row},{self.width},{self.height} does not fit inside "
                f"the {ncols}x{nrows} (width x height) raster")

    @property
    def slices(self) -> tuple[slice, slice]:
        """The (rows, cols) slices that cut this window out of an array."""
        return (slice(self.row, self.row + self.height), slice(self.col, self.col + self.width))


@dataclass(frozen=True, eq=False)
class DEMTile:
    """A georeferenced height grid with an explicit valid mask.

    Parameters
    ----------
    heights : (ny, nx) float32, metres
        Heights; NaN wherever ``valid`` is False (enforced on construction).
    valid : (ny, nx) bool
        True where the height is known.
    transform : affine.Affine
        North-up pixel-corner to map transform (GDAL convention); map units are metres.
    crs : str or None
        WKT of the coordinate reference system, None for a local frame.
    nodata : float
        Value that marks unknown pixels when the tile is written to a file.
    metadata : mapping of str to str
        Provenance: seed, parameters, source file. Written to GeoTIFF tags.

    Examples
    --------
    >>> t = DEMTile.from_array(np.zeros((3, 4)), resolution=2.0)
    >>> t.shape, t.resolution, t.valid.all()
    ((3, 4), 2.0, np.True_)
    """

    heights: np.ndarray
    valid: np.ndarray
    transform: Affine
    crs: str | None = None
    nodata: float = float("nan")
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self):
        h = np.asarray(self.heights)
        if h.ndim != 2 or min(h.shape) < 1:
            raise InvalidDEMError(f"DEM heights must be a non-empty 2-D array; got shape {h.shape}")
        if not np.issubdtype(h.dtype, np.number) or np.iscomplexobj(h):
            raise InvalidDEMError(f"DEM heights must be real numbers; got dtype {h.dtype}")
        v = np.asarray(self.valid)
        if v.shape != h.shape:
            raise InvalidDEMError(
                f"DEM valid mask must have the heights' shape {h.shape}; got {v.shape}")
        if h.dtype == np.float32 and h.flags.c_contiguous and not h.flags.writeable:
            pass  # already an immutable float32 array: share it
        else:
            h = np.array(h, dtype=np.float32, order="C", copy=True)
        finite = np.isfinite(h)  # values beyond float32's range are invalid, never inf
        v = np.logical_and(v, finite)
        stale = ~v & ~np.isnan(h)  # invalid pixels whose height is not NaN yet (inf, masked)
        if stale.any():
            if not h.flags.writeable:
                h = h.copy()
            np.copyto(h, np.float32(np.nan), where=stale)
        h.flags.writeable = False
        v.flags.writeable = False
        if not isinstance(self.transform, Affine):
            raise InvalidDEMError(f"DEM transform must be an affine.Affine; got {self.transform!r}")
        t = self.transform
        if t.b != 0 or t.d != 0:
            raise InvalidDEMError(
                f"DEM transform must be north-up (no rotation); got {tuple(t)[:6]}")
        if not (t.a > 0 and t.e < 0 and math.isfinite(t.a) and math.isfinite(t.e)):
            raise InvalidDEMError(
                "DEM transform must have positive x spacing and negative y spacing; got "
                f"a={t.a}, e={t.e}")
        if not math.isclose(t.a, -t.e, rel_tol=1e-6):
            raise InvalidDEMError(
                f"DEM pixels must be square; got {t.a} x {-t.e} (resample the DEM first)")
        meta = MappingProxyType({str(k): str(val) for k, val in dict(self.metadata).items()})
        object.__setattr__(self, "heights", h)
        object.__setattr__(self, "valid", v)
        object.__setattr__(self, "nodata", float(self.nodata))
        object.__setattr__(self, "metadata", meta)

    # --- construction -----------------------------------------------------------------
    @classmethod
    def from_trusted(cls, heights: np.ndarray, transform: Affine, crs: str | None = None,
                     nodata: float = float("nan"),
                     metadata: Mapping[str, str] | None = None) -> DEMTile:
        """Wrap heights a stage has just computed, without checking them once more.

        For a stage's own output, whose invariants hold by construction: ``heights`` is a
        C-contiguous float32 array, NaN where unknown and nowhere infinite, and
        ``transform`` is that of a valid tile, scaled. The valid mask is derived
        (``isfinite``); the heights are made read-only and shared. Building a tile of
        8193^2 pixels through the checking constructor costs as much as several passes
        over it, for nothing a stage's output could fail.

        >>> t = DEMTile.from_trusted(np.zeros((2, 2), np.float32), Affine(1, 0, 0, 0, -1, 2))
        >>> t.valid.all(), t.heights.flags.writeable
        (np.True_, False)
        """
        if heights.dtype != np.float32 or not heights.flags.c_contiguous or heights.ndim != 2:
            raise InvalidDEMError("DEMTile.from_trusted takes C-contiguous 2-D float32 heights; "
                                  f"got {heights.dtype} {heights.shape}")
        tile = object.__new__(cls)
        heights.flags.writeable = False
        valid = np.empty(heights.shape, dtype=bool)
        run_blocks(_finite_rows, -(-heights.shape[0] // FINITE_ROWS), heights, valid)
        valid.flags.writeable = False
        meta = MappingProxyType({str(k): str(v) for k, v in dict(metadata or {}).items()})
        for name, value in (("heights", heights), ("valid", valid), ("transform", transform),
                            ("crs", crs), ("nodata", float(nodata)), ("metadata", meta)):
            object.__setattr__(tile, name, value)
        return tile

    @classmethod
    def from_array(cls, heights, *, resolution: float = 1.0, valid=None, transform=None,
                   crs=None, nodata=float("nan"), metadata=None) -> DEMTile:
        """Tile from an array; NaN heights become invalid.

        Without a transform the tile gets a local frame at ``resolution`` metres per pixel.
        """
        h = np.asarray(heights)
        if h.ndim != 2:
            raise InvalidDEMError(f"DEM heights must be a 2-D array; got shape {h.shape}")
        if not np.issubdtype(h.dtype, np.number) or np.iscomplexobj(h):
            raise InvalidDEMError(f"DEM heights must be real numbers; got dtype {h.dtype}")
        if transform is None:
            resolution = float(resolution)
            if not (resolution > 0 and math.isfinite(resolution)):
                raise InvalidParameterError(f"resolution must be positive; got {resolution}")
            transform = default_transform(resolution, h.shape[0])
        if valid is None:
            valid = np.isfinite(h)
        return cls(h, valid, transform, crs, nodata, metadata or {})

    def replace(self, **changes) -> DEMTile:
        """Copy with some fields changed (heights and valid are re-validated)."""
        fields: dict[str, Any] = dict(heights=self.heights, valid=self.valid,
                                      transform=self.transform, crs=self.crs,
                                      nodata=self.nodata, metadata=self.metadata)
        fields.update(changes)
        return DEMTile(**fields)

    def with_metadata(self, **items) -> DEMTile:
        """Copy with provenance entries added; non-string values are stored as JSON."""
        meta = dict(self.metadata)
        for key, value in items.items():
            meta[key] = value if isinstance(value, str) else json.dumps(value, sort_keys=True)
        return self.replace(metadata=meta)

    # --- geometry ---------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """The (rows, cols) of the heights."""
        return self.heights.shape

    @property
    def resolution(self) -> float:
        """Pixel spacing in metres."""
        return float(self.transform.a)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(left, bottom, right, top) in map units."""
        ny, nx = self.shape
        left, top = self.transform @ (0, 0)
        right, bottom = self.transform @ (nx, ny)
        return (left, bottom, right, top)

    def xy(self, rows, cols) -> tuple[np.ndarray, np.ndarray]:
        """Map coordinates of pixel centres."""
        t = self.transform
        cols = np.asarray(cols, dtype=np.float64)
        rows = np.asarray(rows, dtype=np.float64)
        return t.c + (cols + 0.5) * t.a, t.f + (rows + 0.5) * t.e

    def rowcol(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) of map coordinates, pixel centres at integers."""
        t = self.transform
        return ((np.asarray(y, dtype=np.float64) - t.f) / t.e - 0.5,
                (np.asarray(x, dtype=np.float64) - t.c) / t.a - 0.5)

    def window(self, window: Window) -> DEMTile:
        """Return the sub-tile covered by ``window`` (georeferencing shifted accordingly)."""
        window.check_inside(*self.shape)
        rs, cs = window.slices
        transform = self.transform @ Affine.translation(window.col, window.row)
        return DEMTile(self.heights[rs, cs], self.valid[rs, cs], transform, self.crs,
                       self.nodata, self.metadata)

    @property
    def valid_fraction(self) -> float:
        """The fraction of valid pixels."""
        return float(self.valid.mean())
