"""Chunked runs on Dask: synthesis, craters and expansion, bitwise equal to a single run.

Every random number in craterscape is keyed by its global position (:mod:`terrain.core.rng`), and
synthesis, cratering and expansion each compute any window exactly from a halo around it.
So a DEM far larger than memory is computed chunk by chunk, each chunk a pure function of
(its global window, the seed, the inputs), and written into its own region of a Zarr store
(:class:`terrain.core.zarrstore.ZarrDEM`): the chunks agree, bitwise, with the same pixels of a
run that computes the whole DEM in one piece.

The chunks are the blocks of a :mod:`dask.array` built by ``map_blocks`` (its ``block_info``
gives each task its chunk's position), so they run on whatever Dask runs on: this process,
a :class:`~dask.distributed.LocalCluster` of worker processes (``--workers N``), or any
Dask cluster (``--scheduler tcp://HOST:PORT``, as printed by ``dask scheduler`` or a
``dask-jobqueue`` cluster). Each task

1. returns at once if its chunk's completion marker exists (a resumed run),
2. reads the part of the input its window depends on (by window, from a GeoTIFF or any GDAL
   raster, or from a Zarr DEM), computes the window with the library's public window
   functions (:func:`terrain.fractal.synthetic.synthesize_tile`, :func:`terrain.craters.cratering.
   crater_heights`, :func:`terrain.fractal.expand.expand_level`,
   :func:`terrain.fractal.gapfill.fill_gaps`),
3. writes the chunk, then its marker.

Memory is bounded by one chunk and its halo per worker, never by the DEM (plus the decoded
input chunks a worker keeps, :data:`terrain.core.zarrstore.DECODED_CACHE_BYTES`). A worker
that dies mid-run is replaced by Dask and its task run again; a run that stops part way is
resumed by running the same command again: finished chunks are not computed again.

Examples
--------
>>> import tempfile, pathlib
>>> out = pathlib.Path(tempfile.mkdtemp()) / "tile.zarr"
>>> report = run(SynthSource(65, seed=3), out, chunk=32)
>>> report.computed, report.total
(9, 9)
>>> from terrain.fractal.synthetic import synthesize_tile
>>> h, _ = ZarrDEM(out).read()
>>> bool(np.array_equal(h, synthesize_tile(65, seed=3).tile.heights))
True
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import numpy as np
from affine import Affine

from terrain.core import metakeys as mk
from terrain.core.errors import (
    GapTooLargeError,
    InvalidDEMError,
    InvalidParameterError,
    OutputPathError,
)
from terrain.core.outputs import remove_path
from terrain.core.progress import Progress
from terrain.core.tile import Window, default_transform
from terrain.core.zarrstore import ZarrDEM, is_zarr
from terrain.craters.catalog import CraterCatalog

if TYPE_CHECKING:
    from terrain.craters.cratering import CraterModel
    from terrain.craters.population import Population
    from terrain.fractal.roughness import ExpansionParameters

__all__ = ["DEFAULT_CHUNK", "CraterSource", "ExpandSource", "FillSource", "GapTooLargeError",
           "OnReaderGrid", "RunReport", "SynthSource", "dask_client", "estimate_parameters",
           "open_reader", "run", "scratch_path", "scratch_store"]

log = logging.getLogger(__name__)

#: Default chunk side in pixels (16 MiB of float32 per chunk): a task's fixed costs (the
#: scheduler's round trip, reading its window and halo, the Zarr write and its marker) are
#: then a small share of its compute (docs/scaling.md). 2^11 + 1, not 2^11: craterscape's
#: DEMs are 2^n + 1 pixels a side, which 2^11 leaves with a last chunk one pixel wide (a
#: 8193^2 expansion: 25 chunks, 9 of them slivers paying a whole chunk's fixed costs for
#: almost no pixels), and 2^11 + 1 tiles with 2^(n - 11) chunks (the last 2050 - 2^(n - 11)
#: pixels wide: 2046 at 8193, 2034 at 32769).
DEFAULT_CHUNK = 2049
#: Smallest chunk side accepted (smaller chunks cost more in scheduling than they compute).
MIN_CHUNK = 16


class DEMReader(Protocol):
    """What a chunked run needs of its input (:class:`~terrain.io.RasterReader`, :class:`ZarrDEM`).

    ``read(window)`` returns (heights (h, w) float32 in metres, valid (h, w) bool) of a window
    (the whole DEM when None); the other members describe the whole input.
    """

    @property
    def path(self) -> str | os.PathLike: ...
    @property
    def shape(self) -> tuple[int, ...]: ...
    @property
    def transform(self) -> Affine: ...
    @property
    def crs(self) -> str | None: ...
    @property
    def nodata(self) -> float: ...
    @property
    def metadata(self) -> dict[str, str]: ...
    @property
    def resolution(self) -> float: ...

    def read(self, window: Window | None = None) -> tuple[np.ndarray, np.ndarray]: ...


def open_reader(path, band: int = 1) -> DEMReader:
    """Return a windowed reader of a DEM: a Zarr DEM or any raster GDAL reads.

    Returns a :class:`DEMReader`: ``shape``, ``transform``, ``crs``, ``nodata``, ``metadata``,
    ``resolution`` and ``read(window) -> (heights, valid)``.
    """
    from terrain.io import RasterReader

    path = Path(path)
    if path.is_dir() and is_zarr(path):
        store = ZarrDEM(path)
        store.check_complete()
        return store
    reader = RasterReader(path, band=band)
    if reader.wide:
        # Chunks are float32: a wider type's known heights could be rounded, and a known
        # height is never changed (in memory, read_dem_exact keeps them).
        raise InvalidDEMError(
            f"DEM '{path}' stores {reader.stored} heights, which a chunked run (float32 "
            "chunks) could round; convert it first (gdal_translate -ot Float32) or run it in "
            "memory")
    return reader


_T = TypeVar("_T")


def filled_field(value: _T | None) -> _T:
    """Return a field that ``__post_init__`` filled in (None only before construction ends)."""
    if value is None:  # pragma: no cover - every source's __post_init__ fills its defaults
        raise AssertionError("a source's default was not filled in by __post_init__")
    return value


def input_stamp(reader) -> dict:
    """Return what identifies an input, so a resumed run refuses an input that has changed."""
    path = Path(reader.path)
    st = path.stat()
    return dict(path=str(path.resolve()), size=st.st_size, mtime_ns=st.st_mtime_ns,
                band=getattr(reader, "band", 1))


def _read_base(reader):
    """``base(r0, r1, c0, c1)`` of :func:`~.cratering.crater_heights` from a reader."""

    def base(r0, r1, c0, c1):
        h, _ = reader.read(Window(c0, r0, c1 - c0, r1 - r0))
        return h.astype(np.float64)

    return base


# --------------------------------------------------------------------------------------
# sources: what a chunk computes


class OnReaderGrid:
    """Mixin of a chunked source whose output lies on its input's grid.

    ``shape``, ``transform``, ``crs`` and ``nodata`` are those of the input reader
    (``self.reader``, a :class:`DEMReader`).
    """

    reader: DEMReader

    @property
    def shape(self) -> tuple[int, ...]:
        """The output's (rows, cols), those of the input."""
        return self.reader.shape

    @property
    def transform(self) -> Affine:
        """The output's affine transform, that of the input."""
        return self.reader.transform

    @property
    def crs(self) -> str | None:
        """The output's CRS, that of the input."""
        return self.reader.crs

    @property
    def nodata(self) -> float:
        """The output's nodata value, that of the input."""
        return self.reader.nodata


@dataclass(frozen=True)
class SynthSource:
    """An RMD tile, optionally cratered (:func:`terrain.fractal.synthetic.synthesize_tile`).

    Parameters are those of :func:`~terrain.fractal.synthetic.synthesize_tile`; the chunks of a run
    equal the same pixels of ``synthesize_tile(size, ...).tile.heights``, bitwise.
    """

    size: int
    resolution: float = 1.0
    fractal_dimension: float = 2.2
    relief: float = 30.0
    seed: int = 0
    craters: Population | None = None
    model: CraterModel | None = None
    crs: str | None = None  # WKT (terrain.io.synthetic_crs); heights do not depend on it
    repose: Any = None  # terrain.surface.repose.Repose, or None

    def __post_init__(self):
        from terrain.core.rng import check_seed
        from terrain.fractal.rmd import check_fractal_dimension, check_tile_size

        check_tile_size(self.size)
        check_fractal_dimension(self.fractal_dimension)
        check_seed(self.seed)
        if not float(self.resolution) > 0:
            raise InvalidParameterError(f"resolution must be positive; got {self.resolution}")
        if self.craters is not None and self.model is None:
            from terrain.craters.cratering import CraterModel

            object.__setattr__(self, "model", CraterModel())

    @property
    def shape(self):
        """The output's (rows, cols)."""
        return (self.size, self.size)

    @property
    def transform(self) -> Affine:
        """The output's affine transform (metres)."""
        return default_transform(float(self.resolution), self.size)

    nodata = float("nan")

    @property
    def has_catalog(self) -> bool:
        """Whether the run writes a crater catalogue."""
        return self.craters is not None

    @property
    def metadata(self) -> dict:
        """The output's metadata tags (seed and parameters)."""
        from terrain.craters.cratering import describe_craters

        params = dict(size=self.size, resolution=float(self.resolution),
                      fractal_dimension=float(self.fractal_dimension), relief=float(self.relief))
        meta = {mk.SEED: str(self.seed),
                mk.RMD: json.dumps(params, sort_keys=True)}
        if self.craters is not None:
            meta[mk.CRATERS] = json.dumps(describe_craters(self.craters),
                                                     sort_keys=True)
            meta[mk.CRATER_MODEL] = json.dumps(filled_field(self.model).as_dict(),
                                                         sort_keys=True)
        if self.repose is not None:
            meta[mk.REPOSE] = json.dumps(self.repose.as_dict(), sort_keys=True)
        return meta

    def plan(self) -> dict:
        """Return what decides the output's bytes, to match a resumed run."""
        return dict(kind="synth", metadata=self.metadata)

    def compute(self, window: Window):
        """Compute the heights of one window, equal to the same window of a whole run.

        Returns the heights and, with craters, the catalogue rows of the craters touching the
        window as column arrays (:meth:`CraterCatalog.as_dict`, kept with the chunk).
        """
        from terrain.fractal.synthetic import synthesize_tile

        result = synthesize_tile(self.size, resolution=self.resolution,
                                 fractal_dimension=self.fractal_dimension, relief=self.relief,
                                 seed=self.seed, craters=self.craters, model=self.model,
                                 window=window, repose=self.repose)
        rows = result.catalog.as_dict() if self.has_catalog else None
        return np.asarray(result.tile.heights), rows


@dataclass(frozen=True)
class CraterSource(OnReaderGrid):
    """A crater population added to an input DEM (:func:`terrain.craters.cratering.add_craters`).

    Each chunk reads the input over its window grown by the crater halo (about 1.5 times the
    largest crater's footprint per size class), so memory per chunk grows with ``dmax``.
    ``keep_step`` > 1 keeps the heights on that lattice of global pixels (the input's own
    pixels in an expanded layer whose pixel (0, 0) is global ``origin``), adding only what
    it does not sample (:func:`terrain.craters.unresolved.keep_lattice`).
    """

    reader: DEMReader
    craters: Population
    seed: int = 0
    model: CraterModel | None = None
    keep_step: int = 1
    origin: tuple[int, int] = (0, 0)

    def __post_init__(self):
        from terrain.core.rng import check_seed

        check_seed(self.seed)
        if self.model is None:
            from terrain.craters.cratering import CraterModel

            object.__setattr__(self, "model", CraterModel())

    has_catalog = True

    @property
    def metadata(self) -> dict:
        """The output's metadata tags (the input's, with the craters' seed and parameters)."""
        from terrain.craters.cratering import describe_craters

        meta = dict(self.reader.metadata)
        meta[mk.SEED] = str(self.seed)
        meta[mk.CRATER_MODEL] = json.dumps(filled_field(self.model).as_dict(),
                                                         sort_keys=True)
        meta[mk.CRATERS] = json.dumps(describe_craters(self.craters), sort_keys=True)
        return meta

    def plan(self) -> dict:
        """Return what decides the output's bytes, to match a resumed run."""
        plan: dict[str, Any] = dict(kind="craters", input=input_stamp(self.reader),
                                    metadata=self.metadata)
        if self.keep_step > 1:
            plan.update(keep_step=int(self.keep_step), origin=list(self.origin))
        return plan

    def compute(self, window: Window):
        """Compute the cratered heights of one window, equal to the same window of a whole run.

        Returns the heights and the catalogue rows of the craters touching the window as
        column arrays (:meth:`CraterCatalog.as_dict`, kept with the chunk).
        """
        from terrain.craters.cratering import crater_heights
        from terrain.craters.unresolved import keep_lattice, lattice_halo

        step = int(self.keep_step)
        grown = window
        if step > 1:
            ny, nx = self.shape
            halo = lattice_halo(step)
            r0, c0 = max(0, window.row - halo), max(0, window.col - halo)
            r1 = min(ny, window.row + window.height + halo)
            c1 = min(nx, window.col + window.width + halo)
            grown = Window(c0, r0, c1 - c0, r1 - r0)
        z, catalog = crater_heights(_read_base(self.reader), self.shape, self.transform,
                                    self.craters, seed=self.seed, model=self.model,
                                    window=grown)
        if step > 1:
            before, _ = self.reader.read(grown)
            (o_r, o_c), (ny, nx) = self.origin, self.shape
            # from the float32 heights a whole-layer run stores between the two steps
            z = keep_lattice(before, z.astype(np.float32), step=step,
                             origin=(o_r + grown.row, o_c + grown.col),
                             layer_rows=(o_r, o_r + ny - 1), layer_cols=(o_c, o_c + nx - 1))
            dr, dc = window.row - grown.row, window.col - grown.col
            z = z[dr:dr + window.height, dc:dc + window.width]
        _, valid = self.reader.read(window)
        out = z.astype(np.float32)
        out[~(valid & np.isfinite(out))] = np.nan
        return out, catalog.as_dict()


class _StridedHeights:
    """The input's heights as :func:`terrain.fractal.roughness.square_residual` reads them.

    ``square_residual`` slices the DEM with a stride (every k-th row and column of a large
    DEM); this object answers those slices from the file, reading it once in strips and
    keeping only the rows and columns the default spacings need, so estimating the roughness
    of a DEM larger than memory gives the same parameters as the DEM in memory.
    """

    ndim = 2
    dtype = np.dtype(np.float32)

    def __init__(self, reader):
        from terrain.fractal.roughness import DEFAULT_SPACINGS, RESIDUAL_POSITIONS

        self.reader = reader
        self.shape = tuple(reader.shape)
        self.size = self.shape[0] * self.shape[1]
        k = max(1, int(math.ceil(math.sqrt(self.size / RESIDUAL_POSITIONS))))
        offsets = {(s + d) % k for s in DEFAULT_SPACINGS for d in (-s, 0, s)}
        self._rows = np.array([r for r in range(self.shape[0]) if r % k in offsets], np.int64)
        self._cols = np.array([c for c in range(self.shape[1]) if c % k in offsets], np.int64)
        self._data = None

    def astype(self, dtype):
        return self

    def _gather(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Heights at rows x cols (sorted indices), read in strips of rows."""
        ny, nx = self.shape
        out = np.empty((rows.size, cols.size), dtype=np.float32)
        strip = max(1, min(ny, (64 * 2**20) // max(1, nx * 20)))
        done = 0
        while done < rows.size:
            s0 = int(rows[done])
            s1 = min(ny, s0 + strip)
            take = rows[done:][rows[done:] < s1]
            h, _ = self.reader.read(Window(0, s0, nx, s1 - s0))
            out[done:done + take.size] = h[take - s0][:, cols]
            done += take.size
        return out

    def __getitem__(self, key):
        rs, cs = key
        rows = np.arange(*rs.indices(self.shape[0]), dtype=np.int64)
        cols = np.arange(*cs.indices(self.shape[1]), dtype=np.int64)
        if self._data is None:
            self._data = self._gather(self._rows, self._cols)
        ri = np.searchsorted(self._rows, rows)
        ci = np.searchsorted(self._cols, cols)
        if (np.all(ri < self._rows.size) and np.array_equal(self._rows[ri], rows)
                and np.all(ci < self._cols.size) and np.array_equal(self._cols[ci], cols)):
            return self._data[np.ix_(ri, ci)].astype(np.float64)
        return self._gather(rows, cols).astype(np.float64)  # a slice the cache lacks


@dataclass(frozen=True)
class _LazyTile:
    """What :meth:`terrain.fractal.roughness.ExpansionParameters.for_tile` reads of a tile."""

    heights: _StridedHeights
    resolution: float

    @property
    def shape(self):
        return self.heights.shape


def estimate_parameters(reader, fractal_dimension=None, height_scale=None, local_box=None,
                        regolith=None):
    """Expansion parameters of a DEM read by window, equal to those of the DEM in memory.

    Calls :meth:`terrain.fractal.roughness.ExpansionParameters.for_tile` on the input; only the
    strided rows and columns the roughness fit reads are held in memory. ``regolith``: a
    :class:`~terrain.fractal.regolith.RegolithLaw` or its ``as_dict()`` (plans are JSON).
    """
    from terrain.fractal.regolith import RegolithLaw
    from terrain.fractal.roughness import LOCAL_BOX, ExpansionParameters

    if isinstance(regolith, dict):
        regolith = RegolithLaw(**regolith)
    lazy = _LazyTile(_StridedHeights(reader), float(reader.resolution))
    return ExpansionParameters.for_tile(lazy, fractal_dimension, height_scale,
                                        local_box=LOCAL_BOX if local_box is None else local_box,
                                        regolith=regolith)


@dataclass(frozen=True)
class ExpandSource:
    """``times`` 2x fractal expansions of an input DEM (:func:`terrain.fractal.expand.expand`).

    Each chunk reads its parent region (half its size plus a pixel per level, and the local
    roughness box) and runs :func:`terrain.fractal.expand.expand_level` once per level with global
    positions, so it equals the same pixels of ``expand(read_dem(input), times)``.
    """

    reader: DEMReader
    times: int
    seed: int = 0
    params: ExpansionParameters | None = None

    def __post_init__(self):
        from terrain.core.rng import check_seed

        if isinstance(self.times, bool) or not isinstance(self.times, int) or self.times < 1:
            raise InvalidParameterError(f"times must be a positive integer; got {self.times!r}")
        check_seed(self.seed)
        if min(self.reader.shape) < 2:
            raise InvalidParameterError(
                f"a DEM must be at least 2 x 2 to expand; got {self.reader.shape}")
        if self.params is None:
            object.__setattr__(self, "params", estimate_parameters(self.reader))

    @property
    def shape(self):
        """The expanded output's (rows, cols)."""
        from terrain.fractal.expand import expanded_shape

        return expanded_shape(self.reader.shape, self.times)

    @property
    def transform(self):
        """The expanded output's affine transform (finer spacing, same origin)."""
        from terrain.fractal.expand import expanded_transform

        return expanded_transform(self.reader.transform, self.times)

    @property
    def crs(self):
        """The output's CRS, that of the input."""
        return self.reader.crs

    @property
    def nodata(self):
        """The input's nodata value."""
        return self.reader.nodata

    has_catalog = False

    @property
    def metadata(self) -> dict:
        """The output's metadata tags (the input's, with the expansion's seed and parameters)."""
        meta = dict(self.reader.metadata)
        meta[mk.SEED] = str(self.seed)
        meta[mk.EXPANSION] = json.dumps(dict(filled_field(self.params).as_dict(),
                                                        times=self.times), sort_keys=True)
        return meta

    def plan(self) -> dict:
        """Return what decides the output's bytes, to match a resumed run."""
        return dict(kind="expand", input=input_stamp(self.reader), metadata=self.metadata)

    def compute(self, window: Window):
        """Compute the expanded heights of one window, equal to the same window of a whole run."""
        from terrain.fractal.expand import expand_level, expanded_shape, parent_region
        from terrain.fractal.roughness import local_amplitude

        full = [tuple(self.reader.shape)]
        for _ in range(self.times):
            full.append(expanded_shape(full[-1], 1))
        rows = [(window.row, window.row + window.height - 1)]
        cols = [(window.col, window.col + window.width - 1)]
        for k in range(self.times, 0, -1):
            rows.insert(0, parent_region(*rows[0], full[k - 1][0]))
            cols.insert(0, parent_region(*cols[0], full[k - 1][1]))
        (r0, r1), (c0, c1) = rows[0], cols[0]
        p = filled_field(self.params)
        amp = None
        if p.uses_local_map:
            # The local map needs the box and one residual neighbour around the region; the
            # map is a fixed local function of the heights, clipped at the DEM's edges only.
            halo = p.local_box // 2 + 1
            ny, nx = full[0]
            g0, g1 = max(0, r0 - halo), min(ny - 1, r1 + halo)
            h0, h1 = max(0, c0 - halo), min(nx - 1, c1 + halo)
            sub, _ = self.reader.read(Window(h0, g0, h1 - h0 + 1, g1 - g0 + 1))
            grid = sub[r0 - g0:r1 - g0 + 1, c0 - h0:c1 - h0 + 1]
            amp = local_amplitude(sub, p.base_sigma, p.local_box,
                                  (r0 - g0, r1 - g0), (c0 - h0, c1 - h0))
        else:
            grid, _ = self.reader.read(Window(c0, r0, c1 - c0 + 1, r1 - r0 + 1))
        origin = (r0, c0)
        for level in range(1, self.times + 1):
            grid = expand_level(grid, origin, rows[level], cols[level], level=level,
                                sigmas=p.sigmas(level), weights=p.weights(level),
                                taps=p.taps(level), seed=self.seed, amplitude=amp,
                                amplitude_origin=(r0, c0))
            origin = (rows[level][0], cols[level][0])
        return grid, None


@dataclass(frozen=True)
class FillSource(OnReaderGrid):
    """Gap filling chunk by chunk (:func:`terrain.fractal.gapfill.fill_gaps`), with a halo.

    A chunk fills its window grown by ``halo`` pixels; that equals the same pixels of
    filling the whole DEM when every gap touching the chunk lies inside the halo together
    with the gaps whose roughness rings meet its ring and a ring of known pixels around them
    (:meth:`gaps_touching`). :func:`run` checks the whole input first (:meth:`check`) and
    raises :class:`~terrain.core.errors.GapTooLargeError` naming the gap that needs the largest
    halo and that halo. The Gaussians are keyed by global position (``fill_gaps(origin=)``).
    Where a gap's ring has fewer than 4 measurable pixels, ``fill_gaps`` falls back to the
    DEM-wide roughness, which a chunk measures on its own window: give ``roughness`` for
    such tiny inputs.
    """

    reader: DEMReader
    halo: int = 256
    seed: int = 0
    roughness: float | None = None

    def __post_init__(self):
        from terrain.core.rng import check_seed

        check_seed(self.seed)
        if isinstance(self.halo, bool) or not isinstance(self.halo, int) or self.halo < 0:
            raise InvalidParameterError(f"halo must be a non-negative integer; got {self.halo!r}")
        if self.roughness is not None and not (self.roughness >= 0
                                               and math.isfinite(self.roughness)):
            raise InvalidParameterError(
                f"roughness must be a non-negative number; got {self.roughness}")

    has_catalog = False

    @property
    def margin(self) -> int:
        """Return the pixels a cluster of gaps needs around it.

        Each gap is grown by its roughness ring; a ring more, so a gap whose ring meets the
        cluster's is in sight, and the Horn stencil.
        """
        from terrain.fractal.gapfill import RING

        return RING + 2

    @property
    def metadata(self) -> dict:
        """The output's metadata tags (the input's, with the fill's seed and parameters)."""
        meta = dict(self.reader.metadata)
        meta[mk.SEED] = str(self.seed)
        meta[mk.FILL] = json.dumps(dict(chunked=True, halo=self.halo,
                                                   roughness=self.roughness), sort_keys=True)
        return meta

    def plan(self) -> dict:
        """Return what decides the output's bytes, to match a resumed run."""
        return dict(kind="fill", input=input_stamp(self.reader), metadata=self.metadata)

    def _grown(self, window: Window) -> Window:
        ny, nx = self.shape
        r0, c0 = max(0, window.row - self.halo), max(0, window.col - self.halo)
        r1 = min(ny, window.row + window.height + self.halo)
        c1 = min(nx, window.col + window.width + self.halo)
        return Window(c0, r0, c1 - c0, r1 - r0)

    def gaps_touching(self, window: Window):
        """Return the gap touching ``window`` that needs the largest halo, if above ``halo``.

        ``(span, needed halo, (col, row), truncated)``, else None. ``truncated``: the gap runs
        past the grown window, so its span and need are lower bounds.
        """
        from scipy import ndimage

        big = self._grown(window)
        _, valid = self.reader.read(big)
        labels, n = ndimage.label(~valid, structure=np.ones((3, 3), bool))
        if n == 0:
            return None
        inner = labels[window.row - big.row:window.row - big.row + window.height,
                       window.col - big.col:window.col - big.col + window.width]
        # Gaps whose roughness rings may share pixels are one cluster: the fill of one
        # depends on the other's label order, so a cluster must be whole in the window.
        from terrain.fractal.gapfill import RING

        clusters, _ = ndimage.label(ndimage.binary_dilation(
            labels > 0, structure=np.ones((3, 3), bool), iterations=RING + 1),
            structure=np.ones((3, 3), bool))
        ny, nx = self.shape
        # beyond a cluster (gaps dilated by their rings) the window must show RING + 1 more
        # pixels, so that no gap whose ring meets the cluster's stays out of sight
        m = self.margin
        worst = None
        touching = np.unique(clusters[window.row - big.row:window.row - big.row + window.height,
                                      window.col - big.col:window.col - big.col + window.width]
                             [inner > 0])
        objects = ndimage.find_objects(clusters)
        for lab in touching:
            sl = objects[lab - 1]
            g0, g1 = sl[0].start + big.row, sl[0].stop + big.row
            h0, h1 = sl[1].start + big.col, sl[1].stop + big.col
            need = max(window.row - max(0, g0 - m), window.col - max(0, h0 - m),
                       min(ny, g1 + m) - (window.row + window.height),
                       min(nx, h1 + m) - (window.col + window.width), 0)
            if need <= self.halo:
                continue
            truncated = ((g0 == big.row > 0) or (h0 == big.col > 0)
                         or (g1 == big.row + big.height < ny)
                         or (h1 == big.col + big.width < nx))
            span = max(g1 - g0, h1 - h0) - 2 * (RING + 1)
            candidate = (span, need, (h0 + RING + 1, g0 + RING + 1), truncated)
            if worst is None or candidate[:2] > worst[:2]:
                worst = candidate
        return worst

    def check(self, chunk: int) -> None:
        """Raise :class:`GapTooLargeError` if any gap does not fit the halo.

        The error names the gap that needs the largest halo; the input is read once, chunk by
        chunk.
        """
        ny, nx = self.shape
        worst = None
        for r0 in range(0, ny, chunk):
            for c0 in range(0, nx, chunk):
                w = Window(c0, r0, min(chunk, nx - c0), min(chunk, ny - r0))
                found = self.gaps_touching(w)
                if found is not None and (worst is None or found[:2] > worst[:2]):
                    worst = found
        if worst is not None:
            raise GapTooLargeError(_gap_message(worst, self.halo))

    def compute(self, window: Window):
        """Compute the filled heights of one window from the window grown by the halo."""
        from terrain.core.tile import DEMTile
        from terrain.fractal.gapfill import fill_gaps

        worst = self.gaps_touching(window)
        if worst is not None:
            raise GapTooLargeError(_gap_message(worst, self.halo))
        big = self._grown(window)
        h, valid = self.reader.read(big)
        if valid.all():
            out = h
        else:
            tile = DEMTile(h, valid, self.transform @ Affine.translation(big.col, big.row))
            if not valid.any():
                out = h
            else:
                out = fill_gaps(tile, seed=self.seed, roughness=self.roughness,
                                origin=(big.row, big.col)).tile.heights
        return (np.asarray(out)[window.row - big.row:window.row - big.row + window.height,
                                window.col - big.col:window.col - big.col + window.width],
                None)


def _gap_message(worst, halo: int) -> str:
    span, need, (col, row), truncated = worst
    more = "at least " if truncated else ""
    return (f"the largest gap (at column {col}, row {row}) spans {more}{span} pixels and "
            f"needs a halo of {more}{need} pixels, more than the halo of {halo}; give "
            f"--halo {need if not truncated else max(need, 2 * halo)} or more, or fill "
            "without --chunk")


# --------------------------------------------------------------------------------------
# running


@dataclass
class RunReport:
    """What a chunked run did.

    Attributes
    ----------
    path : Path
        The Zarr store.
    total, computed, skipped : int
        Chunks in the DEM, computed by this run, and already written by an earlier one.
    pixels : int
        Pixels computed by this run.
    seconds : float
        Wall time of the chunk phase.
    catalog : CraterCatalog or None
        The crater catalogue of the whole DEM (sources with craters).
    computed_chunks : list of (row, col)
    busy_seconds : float
        Time the tasks spent computing and writing their chunks, summed over workers.
    """

    path: Path
    total: int
    computed: int
    skipped: int
    pixels: int
    seconds: float
    catalog: CraterCatalog | None = None
    computed_chunks: list = field(default_factory=list)
    busy_seconds: float = 0.0

    @property
    def seconds_per_chunk(self) -> float:
        """Worker time per computed chunk (compute and write, without scheduling)."""
        return self.busy_seconds / self.computed if self.computed else float("nan")

    @property
    def pixels_per_second(self) -> float:
        """Throughput of the run (NaN when it took no measurable time)."""
        return self.pixels / self.seconds if self.seconds > 0 else float("nan")


def _chunk_task(source, store, block_info=None):
    """One block of the run's Dask array: compute and write chunk (i, j) unless done.

    Returns ``[[pixels, seconds]]`` computed (zeros for a chunk already written).
    """
    i, j = block_info[None]["chunk-location"]
    if store.is_done(i, j):
        return np.zeros((1, 2))
    t0 = time.perf_counter()
    window = store.chunk_window(i, j)
    heights, catalog = source.compute(window)
    store.write_chunk(i, j, heights, catalog)
    return np.array([[window.width * window.height, time.perf_counter() - t0]])


def _open_store(source, path: Path, chunk: int, metadata=None) -> ZarrDEM:
    plan = dict(source.plan(), shape=list(source.shape), chunk=chunk)
    plan = json.loads(json.dumps(plan, sort_keys=True))
    if path.exists():
        if not path.is_dir() or not is_zarr(path):
            raise OutputPathError(f"output '{path}' exists and is not a Zarr store; choose "
                                  "another name")
        store = ZarrDEM(path)
        if store.plan != plan:
            raise OutputPathError(
                f"output '{path}' holds another run (other parameters, input or chunk size); "
                "give the same command to resume it, or choose another output")
        log.info("resuming %s", path)  # run checks and counts the chunks already written
        return store
    return ZarrDEM.create(path, source.shape, chunk, transform=source.transform,
                          crs=source.crs, nodata=source.nodata,
                          metadata=dict(source.metadata, **(metadata or {})), plan=plan)


def _rate(pixels: int, t0: float) -> str:
    """Throughput since ``t0`` (a :func:`time.perf_counter` reading), as progress text."""
    seconds = time.perf_counter() - t0
    return f"{pixels / seconds / 1e6:.3g} Mpixel/s" if seconds > 0 else ""


def run(source, output, *, chunk: int = DEFAULT_CHUNK, client=None,
        progress: Progress | None = None,
        metadata=None) -> RunReport:
    """Compute ``source`` chunk by chunk into the Zarr store ``output``, or resume it.

    Parameters
    ----------
    source : SynthSource, CraterSource, ExpandSource or FillSource
    output : str or Path
        Zarr store (a folder). If it exists and holds the same run, finished chunks are
        kept and only the others are computed; if it holds another run, it is refused.
    chunk : int
        Chunk side in pixels (one larger than the DEM is taken as the DEM's larger side).
    client : dask.distributed.Client, optional
        Cluster to run on; without one, chunks run one after another in this process.
    progress : callable, optional
        ``progress(done, total, rate)`` after every chunk (:class:`terrain.core.progress.Progress`;
        the rate in Mpixel/s as text).
    metadata : dict, optional
        Provenance tags added to the source's (command, version).

    Returns
    -------
    RunReport
    """
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < MIN_CHUNK:
        raise InvalidParameterError(f"chunk must be an integer >= {MIN_CHUNK} pixels; "
                                    f"got {chunk!r}")
    # A chunk larger than the DEM holds the DEM: Zarr would allocate the whole chunk anyway.
    chunk = min(int(chunk), max(MIN_CHUNK, *source.shape))
    path = Path(output)
    if hasattr(source, "check"):
        source.check(chunk)
    created = not path.exists()
    store = _open_store(source, path, chunk, metadata)
    try:
        return _run_store(source, store, client, progress)
    except BaseException:
        if created and not store.done_chunks():  # nothing to resume: leave nothing behind
            remove_path(path)
        raise


def _run_store(source, store: ZarrDEM, client, progress) -> RunReport:
    """Compute the chunks of ``store`` not yet written (:func:`run`, once the store is open)."""
    import dask.array  # noqa: F401  (imported before the clock starts: a second, once)

    path = store.path
    ny, nx = store.grid
    done_before = store.done_chunks()
    todo = [(i, j) for i in range(ny) for j in range(nx) if (i, j) not in done_before]
    t0 = time.perf_counter()
    shown = 0  # pixels of the chunks finished so far, for progress
    done = len(done_before)
    total = ny * nx
    if progress is not None:
        progress(done, total, "")
    values: list = []
    with contextlib.closing(_compute_chunks(source, store, client, todo, values)) as finished:
        for i, j in finished:
            w = store.chunk_window(i, j)
            shown += w.width * w.height
            done += 1
            if progress is not None:
                progress(done, total, _rate(shown, t0))
    pixels = sum(int(v[0, 0]) for v in values)
    busy = sum(float(v[0, 1]) for v in values)
    seconds = time.perf_counter() - t0
    catalog = merge_chunk_catalogs(store) if source.has_catalog else None
    store.mark_complete()
    log.info("%s: %d chunks computed, %d reused, %.3g Mpixel/s", path, len(todo),
             len(done_before), pixels / max(seconds, 1e-9) / 1e6)
    return RunReport(path, total, len(todo), len(done_before), pixels, seconds, catalog, todo,
                     busy)


def _compute_chunks(source, store: ZarrDEM, client, chunks: list, values: list):
    """Yield each chunk's (row, col) as it finishes (:func:`_chunk_task`).

    Once all have finished, ``values`` holds their ``[[pixels, seconds]]``. On a cluster
    they are fetched together then: fetching each as it finished cost the client and the
    scheduler a round trip to a worker per chunk (a third of this process's CPU during a
    run), CPU that a local cluster's workers share with them.
    """
    import dask
    import dask.array as da

    ny, nx = store.grid
    blocks = da.map_blocks(_chunk_task, source, store, dtype=np.float64,
                           chunks=((1,) * ny, (2,) * nx), meta=np.empty((0, 0)),
                           name=f"craterscape-chunk-{uuid.uuid4().hex}")
    delayed = blocks.to_delayed()
    if client is None:
        for i, j in chunks:
            values.append(dask.compute(delayed[i, j], scheduler="synchronous")[0])
            yield i, j
        return
    from dask.distributed import as_completed

    futures = client.compute([delayed[i, j] for i, j in chunks])
    where = {future.key: chunk for future, chunk in zip(futures, chunks, strict=True)}
    try:
        for future in as_completed(futures):
            if future.status != "finished":
                future.result()  # raises the chunk's error
            yield where[future.key]
        values.extend(client.gather(futures))
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending)
            # A cancelled chunk already running goes on writing: wait for it, so that it
            # is finished (and resumable) before the run ends, never writing into an
            # output the run has removed meanwhile (Zarr would make its folders again).
            _wait_until_stopped(client, {f.key for f in pending})


#: How long a failed or interrupted run waits for its chunks still running on the workers.
STOP_WAIT_SECONDS = 600.0


def _running(keys: set, dask_worker=None) -> int:
    """How many of the tasks ``keys`` this worker is executing now."""
    return sum(1 for ts in dask_worker.state.executing if ts.key in keys)


def _wait_until_stopped(client, keys: set) -> None:
    """Wait until no worker runs any of the tasks ``keys`` (at most :data:`STOP_WAIT_SECONDS`)."""
    deadline = time.monotonic() + STOP_WAIT_SECONDS
    while time.monotonic() < deadline:
        try:
            if not sum(client.run(_running, keys).values()):
                return
        except (OSError, RuntimeError, TimeoutError):  # a cluster that is gone runs nothing
            return
        time.sleep(0.05)


def scratch_path(source, output) -> Path:
    """Return the scratch Zarr store of an out-of-core run of ``source`` into ``output``.

    A hidden folder beside the output, named for the output and for what decides the
    output's bytes (:meth:`plan` of the source and its shape), so the same request finds the
    store again after a kill and another request never touches it.

    Parameters
    ----------
    source : SynthSource, CraterSource, ExpandSource or FillSource
    output : str or Path
        The file the run's result is written to (a GeoTIFF).

    Returns
    -------
    Path
        ``.NAME.KEY.zarr`` in the output's folder (KEY: 16 hexadecimal digits).
    """
    output = Path(output)
    parent = output.parent if str(output.parent) else Path(".")
    request = json.dumps(dict(output=os.path.abspath(output), plan=source.plan(),
                              shape=list(source.shape)), sort_keys=True, default=str)
    key = hashlib.sha256(request.encode("utf-8")).hexdigest()[:16]
    return parent / f".{output.name}.{key}.zarr"


@contextlib.contextmanager
def scratch_store(source, output, chunk: int | None = None):
    """Yield ``(path, chunk)`` of the scratch store of an out-of-core run; remove it on success.

    The store (:func:`scratch_path`) that a killed run of the same request left is resumed:
    ``chunk`` None takes that store's chunk side (None when there is no such store: the
    caller picks one). A store of the same request that cannot be resumed (another chunk
    side asked for, or damaged) is replaced. The store is removed once the block completes,
    that is once the output is committed; if the block fails, it stays for the next run.

    Parameters
    ----------
    source : SynthSource, CraterSource, ExpandSource or FillSource
    output : str or Path
        The output file.
    chunk : int, optional
        Chunk side asked for.
    """
    path = scratch_path(source, output)
    if path.exists():
        try:
            store = ZarrDEM(path)
            found = store.chunk
        except (InvalidDEMError, OSError, KeyError, ValueError) as exc:
            log.warning("replacing the damaged scratch store %s (%s)", path, exc)
            remove_path(path)
        else:
            if chunk is None or min(int(chunk), max(MIN_CHUNK, *source.shape)) == found:
                chunk = found
                log.warning("resuming the interrupted run in %s", path)
            else:
                log.warning("replacing the scratch store %s (chunk %d, now %d)", path, found,
                            chunk)
                remove_path(path)
    yield path, chunk
    remove_path(path)


def merge_chunk_catalogs(store: ZarrDEM) -> CraterCatalog:
    """Return the whole DEM's crater catalogue from the chunks' rows, in composition order.

    Parameters
    ----------
    store : ZarrDEM
        A store whose chunk markers hold catalogue rows (chunks without rows add none).

    Returns
    -------
    CraterCatalog
        Each crater once (a crater touching several chunks is in each one's rows), ``row``
        and ``col`` in the whole DEM's pixel grid.
    """
    parts = [store.chunk_catalog(i, j) for i in range(store.grid[0])
             for j in range(store.grid[1])]
    cat = CraterCatalog.concatenate(CraterCatalog.from_columns(p) for p in parts if p)
    if not len(cat):
        return cat
    _, first = np.unique(cat.id, return_index=True)
    cat = cat.take(first)
    cat = cat.take(np.lexsort((cat.id, -cat.age_gyr, -cat.size_class)))
    t = store.transform
    return cat.with_columns(row=(t.f - cat.y_m) / t.a - 0.5, col=(cat.x_m - t.c) / t.a - 0.5)


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None,
                processes: bool = True, memory_limit="auto"):
    """Yield a Dask client, or None (this process) when neither argument is given.

    The client runs on the cluster at ``scheduler`` or on a local pool of ``workers``.

    Parameters
    ----------
    workers : int, optional
        Local workers, each single-threaded. The compiled kernels release the GIL, but
        the Python around them (Zarr, the task's own steps) does not, and a thread shares
        its process's memory: processes are the default. The local cluster, its workers
        and its dashboard listen on loopback (127.0.0.1) only.
    scheduler : str, optional
        Address of a running scheduler, e.g. ``tcp://10.0.0.5:8786``.
    processes : bool
        Local workers are processes (default) or threads of this process.
    """
    if workers is not None and scheduler is not None:
        raise InvalidParameterError("give --workers or --scheduler, not both")
    if workers is None and scheduler is None:
        yield None
        return
    from dask.distributed import Client

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise InvalidParameterError(
                f"cannot reach the Dask scheduler at {scheduler}: {exc}") from exc
        with client:
            _prepare_workers(client)
            yield client
        return
    if workers is None or isinstance(workers, bool) or int(workers) < 1:  # None: scheduler
        raise InvalidParameterError(f"--workers must be a positive integer; got {workers!r}")
    env = {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    quiet = logging.getLogger("distributed")
    level = quiet.level
    if not log.isEnabledFor(logging.INFO):
        quiet.setLevel(logging.ERROR)  # the scheduler's chatter, unless -v
    with contextlib.ExitStack() as undo:
        undo.callback(quiet.setLevel, level)
        client = undo.enter_context(_local_client(workers, processes, memory_limit, env))
        _prepare_workers(client, keep_freed=processes)
        yield client


#: Modules a chunk task imports on a fresh worker: dask.array (its ``map_blocks`` wraps the
#: task function, so unpickling the first task imports it, SciPy's FFT included), this
#: module (the task function and the sources), the window functions the sources call, and
#: Zarr with its Blosc codec.
WORKER_MODULES = ("dask.array", "terrain.execution.chunked", "terrain.fractal.expand",
                  "terrain.fractal.gapfill", "terrain.fractal.synthetic",
                  "terrain.craters.cratering", "zarr", "numcodecs.blosc")


def prepare_worker(keep_freed: bool = False) -> list[str]:
    """Import :data:`WORKER_MODULES` in this process; return their names.

    Run on every worker when a client is made (:func:`dask_client`) and on every worker
    that joins later, so that the imports (a second or more, dask.array's and Zarr's most
    of it) are paid once per worker, when it starts, and not by the first chunk of every
    run on it.

    Parameters
    ----------
    keep_freed : bool
        Also have the worker's allocator keep freed memory
        (:func:`terrain.core.memory.keep_freed_memory`): a chunk task makes and drops
        arrays of tens of megabytes, and with glibc's defaults (which Dask's nanny makes
        stricter still, ``MALLOC_TRIM_THRESHOLD_``) each comes from fresh pages the kernel
        faults in and zeroes: a third of the workers' CPU time of an expansion was system
        time. Given to the local cluster's workers, which live for one command; not to
        the workers of a cluster the user runs, whose processes are theirs.
    """
    import importlib

    if keep_freed:
        from terrain.core.memory import keep_freed_memory

        keep_freed_memory()
    return [importlib.import_module(name).__name__ for name in WORKER_MODULES]


def _prepare_workers(client, keep_freed: bool = False) -> None:
    """Run :func:`prepare_worker` on the client's workers, and on those that join later.

    A plugin (:class:`terrain.execution.workers.PrepareWorker`): a worker that a nanny
    restarts after a crash, or one that joins a running cluster, is prepared too.
    """
    from terrain.execution.workers import PrepareWorker

    client.register_plugin(PrepareWorker(keep_freed))


@contextlib.contextmanager
def _inherited(env: dict):
    """Put ``env`` in this process's environment for the block, then back as it was."""
    before = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def _local_client(workers, processes, memory_limit, env):
    from dask.distributed import Client, LocalCluster

    # Worker processes get single-threaded numerics. The nanny sets its ``env`` in a worker
    # only once the worker's interpreter has started, and a spawned worker first imports the
    # program's main module again: a program that imports craterscape (numba) at its top had
    # workers whose numba read NUMBA_NUM_THREADS before it was set, and ran every core's
    # threads in each of them. So the variables are also in this process's environment
    # while the workers start (they inherit it), and put back as they were once they have:
    # numba here re-reads NUMBA_NUM_THREADS when it compiles and refuses a value that
    # differs from the one its thread pool started with. (A worker the nanny restarts later
    # gets them through ``env`` alone.)
    # The scheduler, the workers and the dashboard listen on loopback only: none of them asks
    # for credentials, so nothing else on the network may reach them.
    extra = {"env": env, "host": "127.0.0.1"} if processes else {}  # threads: in-process
    with contextlib.ExitStack() as stack:
        with _inherited(env if processes else {}):
            cluster = stack.enter_context(LocalCluster(
                n_workers=int(workers), threads_per_worker=1, processes=processes,
                dashboard_address="127.0.0.1:0", memory_limit=memory_limit,
                silence_logs=logging.ERROR, **extra))
        yield stack.enter_context(Client(cluster))
