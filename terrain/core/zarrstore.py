"""Chunked DEM stores in Zarr: georeferenced, written chunk by chunk, resumable.

A store is a Zarr (format 2) group holding one float32 array ``height`` whose chunks are the
work units of a chunked run (:mod:`terrain.execution.chunked`). Its attributes carry what a
GeoTIFF's
header would: the GDAL geotransform, the CRS as WKT, the nodata value and craterscape's
provenance tags, plus the run's plan (what is being computed, so a resumed run can refuse a
store that was started with other parameters) and whether every chunk is written.

Every chunk is written exactly once by the task that computes it, into its own region only;
the task then flushes the chunk's file to disk and writes a completion marker
(``chunks/ROW_COL.npz``, flushed and renamed into place atomically) holding the chunk's crater
catalogue rows and the size and CRC-32 of the chunk's file as written (or that there is
none: stores made before every chunk got a file have none for a chunk all nodata). A run
that stops part way leaves the markers of the chunks that were fully written, and the next
run skips exactly the chunks whose file still matches its marker: a chunk without a readable
marker, or whose file was removed, truncated or altered since, is computed and written again
from scratch, so neither a torn write nor a damaged file is ever kept.

``_ARRAY_DIMENSIONS`` is set (``["y", "x"]``), so xarray opens the store too.

Examples
--------
>>> import tempfile, pathlib
>>> from affine import Affine
>>> d = pathlib.Path(tempfile.mkdtemp()) / "dem.zarr"
>>> s = ZarrDEM.create(d, (5, 7), 4, transform=Affine(2, 0, 0, 0, -2, 10), crs=None,
...                    nodata=float("nan"), metadata={}, plan={"what": "doc"})
>>> s.write_chunk(0, 1, np.ones((4, 3), np.float32))
>>> s.done_chunks()
{(0, 1)}
>>> float(s.read(Window(4, 0, 3, 2))[0][0, 0])
1.0
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
import threading
import zipfile
import zlib
from collections import OrderedDict
from pathlib import Path

import numpy as np
from affine import Affine

from terrain.core.errors import InvalidDEMError, MissingInputError, OutputPathError
from terrain.core.outputs import cannot_write, is_write_error
from terrain.core.tile import Window

__all__ = ["ARRAY_NAME", "ZarrDEM", "is_zarr"]

log = logging.getLogger(__name__)

#: Name of the height array inside the store's group.
ARRAY_NAME = "height"
#: Folder (inside the store) of the per-chunk completion markers.
MARKERS = "chunks"
#: Attribute holding craterscape's own description of the store.
ATTR = "craterscape"
#: Marker entry holding (size in bytes, CRC-32) of the chunk's file; size -1: no file.
CHUNK_STAMP = "_chunk_file"
#: What a marker or chunk file that cannot be read raises (numpy, zipfile, zarr and blosc).
_UNREADABLE = (OSError, ValueError, EOFError, RuntimeError, KeyError, zipfile.BadZipFile,
               zlib.error)


def _fsync(path: Path) -> None:
    """Flush a file or folder to disk, so a machine that loses power still finds it."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _file_stamp(path: Path) -> tuple[int, int]:
    """(size, CRC-32) of a file; (-1, 0) when there is none."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return (-1, 0)
    return (len(data), zlib.crc32(data))


#: Bytes of decoded chunks a process keeps of the complete stores it reads (four 2049^2
#: chunks and some: a 2x2 neighbourhood of input chunks). A chunk task reads
#: its window with a halo of a few pixels, which reaches into up to three neighbouring chunks:
#: without the cache each task decoded those whole again (a 2x expansion of 4097^2 into
#: 2049^2 chunks decoded 36 input chunks for 16 tasks, a fifth of the workers' time).
DECODED_CACHE_BYTES = 96 * 2**20
_DECODED: OrderedDict[tuple, np.ndarray] = OrderedDict()
_DECODED_LOCK = threading.Lock()


def _decoded_chunk(store: ZarrDEM, i: int, j: int) -> np.ndarray:
    """Return chunk (i, j) of a complete store, decoded (float32, as stored), via the cache.

    A chunk is kept under the size and CRC-32 its marker recorded together with the
    inode, size and modification time of its file now, so a chunk written again (a store
    made anew at the same path, a damaged chunk recomputed) is decoded again, never served
    stale; a chunk whose marker cannot be read, or disagrees with its file, is not kept.
    """
    w = store.chunk_window(i, j)
    key = _chunk_key(store, i, j)
    if key is not None:
        with _DECODED_LOCK:
            block = _DECODED.get(key)
            if block is not None:
                _DECODED.move_to_end(key)
                return block
    block = np.asarray(_array(store.path, "r")[w.row:w.row + w.height, w.col:w.col + w.width],
                       dtype=np.float32)
    block.flags.writeable = False
    if key is not None and block.nbytes <= DECODED_CACHE_BYTES // 2:  # two at least, or none
        with _DECODED_LOCK:
            _DECODED[key] = block
            held = sum(b.nbytes for b in _DECODED.values())
            while held > DECODED_CACHE_BYTES:
                held -= _DECODED.popitem(last=False)[1].nbytes
    return block


def _chunk_key(store: ZarrDEM, i: int, j: int) -> tuple | None:
    """Return what identifies chunk (i, j)'s stored bytes (:func:`_decoded_chunk`), or None."""
    try:
        with np.load(store._marker(i, j)) as f:
            size, crc = (int(v) for v in f[CHUNK_STAMP])
    except _UNREADABLE:  # no marker, or one from before the stamps: not kept
        return None
    try:
        st = os.stat(store.chunk_file(i, j))
        found = (st.st_ino, st.st_size, st.st_mtime_ns)
    except FileNotFoundError:  # all nodata, in a store from before every chunk had a file
        found = (-1, -1, 0)
    if found[1] != size:
        return None
    return (str(store.path), i, j, size, crc, found)


def is_zarr(path) -> bool:
    """Whether ``path`` names a Zarr store (an existing one, or a new name ending in .zarr)."""
    path = Path(path)
    if path.is_dir():
        return (path / ".zgroup").exists() or (path / "zarr.json").exists()
    return path.suffix.lower() == ".zarr"


def _zarr():
    import zarr  # local: only chunked runs need it

    return zarr


_ARRAYS: dict = {}


def _array(path: Path, mode: str):
    """Return the store's height array, opened once per process and mode.

    Opening costs a few milliseconds of metadata reads, as much as writing a small chunk.
    The array opened for writing writes every chunk it is given: by default Zarr first
    compares each chunk with the fill value, to leave a chunk all nodata unwritten, a pass
    over a 2049^2 chunk that cost 4 ms (nodata NaN) to 11 ms (a numeric nodata) of the
    80 ms or so a worker spends on it in an expansion (and every chunk gets a marker
    anyway).
    """
    key = (str(path), mode)
    array = _ARRAYS.get(key)
    if array is None:
        array = _zarr().open_array(str(path / ARRAY_NAME), mode=mode)
        if mode != "r":
            array = array.with_config({"write_empty_chunks": True})
        if len(_ARRAYS) > 64:
            _ARRAYS.clear()
        _ARRAYS[key] = array
    return array


class ZarrDEM:
    """A georeferenced float32 DEM in a Zarr store, with per-chunk completion markers.

    Parameters
    ----------
    path : str or Path
        The store's folder.

    Attributes
    ----------
    shape : (nrows, ncols)
    chunk : int
        Chunk side in pixels (the last row and column of chunks may be smaller).
    transform : affine.Affine
        North-up pixel-corner to map transform (metres).
    crs : str or None
        WKT.
    nodata : float
        Value stored in unknown pixels (NaN or a finite number).
    metadata : dict of str to str
        Provenance tags (the GeoTIFF tags of the same DEM written in one piece).
    plan : dict
        What the store holds (command and parameters); resumed runs must match it.
    complete : bool
        Whether every chunk has been written.
    """

    def __init__(self, path):
        path = Path(path)
        if not path.exists():
            raise MissingInputError(f"Zarr store '{path}' does not exist")
        zarr = _zarr()
        try:
            group = zarr.open_group(str(path), mode="r")
            attrs = dict(group.attrs).get(ATTR)
            array = group[ARRAY_NAME]
        except Exception as exc:  # zarr raises many types for a foreign or broken store
            raise InvalidDEMError(f"'{path}' is not a craterscape Zarr DEM "
                                  f"({type(exc).__name__}: {exc})") from exc
        if not isinstance(attrs, dict):
            raise InvalidDEMError(f"'{path}' is a Zarr store without craterscape's "
                                  "georeferencing attributes")
        self.path = path
        self.shape = tuple(int(v) for v in array.shape)
        self.chunk = int(array.chunks[0])
        self.transform = Affine.from_gdal(*attrs["geotransform"])
        self.crs = attrs.get("crs")
        self.nodata = float(attrs["nodata"]) if attrs.get("nodata") is not None else float("nan")
        self.metadata = {str(k): str(v) for k, v in attrs.get("metadata", {}).items()}
        self.plan = attrs.get("plan", {})
        self.complete = bool(attrs.get("complete", False))

    # --- creation -----------------------------------------------------------------------
    @classmethod
    def create(cls, path, shape, chunk: int, *, transform: Affine, crs: str | None,
               nodata: float, metadata: dict, plan: dict) -> ZarrDEM:
        """Create an empty store (no chunk written yet)."""
        path = Path(path)
        parent = path.parent if str(path.parent) else Path(".")
        if not parent.is_dir():
            raise OutputPathError(f"output folder '{parent}' does not exist")
        if path.exists():
            raise OutputPathError(f"output '{path}' already exists")
        zarr = _zarr()
        ny, nx = (int(v) for v in shape)
        for mode in ("r", "r+"):  # a store made again at a path read before is a new store
            _ARRAYS.pop((str(path), mode), None)
        try:
            group = zarr.open_group(str(path), mode="w-", zarr_format=2)
            fill = float(nodata) if np.isfinite(nodata) else float("nan")
            array = group.create_array(ARRAY_NAME, shape=(ny, nx), chunks=(chunk, chunk),
                                       dtype="float32", fill_value=fill)
            array.attrs["_ARRAY_DIMENSIONS"] = ["y", "x"]
            group.attrs[ATTR] = dict(
                geotransform=list(transform.to_gdal()), crs=crs,
                nodata=None if not np.isfinite(nodata) else float(nodata),
                metadata={str(k): str(v) for k, v in metadata.items()}, plan=plan,
                complete=False)
            (path / MARKERS).mkdir()
        except OSError as exc:
            if is_write_error(exc):
                raise cannot_write(path, exc) from exc
            raise
        log.info("created Zarr store %s (%d x %d, chunks %d)", path, nx, ny, chunk)
        return cls(path)

    def mark_complete(self) -> None:
        """Record that every chunk is written (readers refuse an incomplete store)."""
        zarr = _zarr()
        group = zarr.open_group(str(self.path), mode="r+")
        attrs = dict(group.attrs[ATTR])
        attrs["complete"] = True
        try:
            group.attrs[ATTR] = attrs
            for flushed in (self.path / ".zattrs", self.path):
                with contextlib.suppress(FileNotFoundError):
                    _fsync(flushed)
        except OSError as exc:
            if is_write_error(exc):
                raise cannot_write(self.path, exc) from exc
            raise
        self.complete = True

    # --- geometry -----------------------------------------------------------------------
    @property
    def grid(self) -> tuple[int, int]:
        """Number of chunks along (rows, columns)."""
        return (-(-self.shape[0] // self.chunk), -(-self.shape[1] // self.chunk))

    def chunk_window(self, i: int, j: int) -> Window:
        """Pixels of chunk (i, j)."""
        r0, c0 = i * self.chunk, j * self.chunk
        return Window(c0, r0, min(self.chunk, self.shape[1] - c0),
                      min(self.chunk, self.shape[0] - r0))

    @property
    def resolution(self) -> float:
        """The pixel spacing in metres (square pixels)."""
        return float(self.transform.a)

    # --- chunks -------------------------------------------------------------------------
    def _marker(self, i: int, j: int) -> Path:
        return self.path / MARKERS / f"{i}_{j}.npz"

    def chunk_file(self, i: int, j: int) -> Path:
        """Return the file Zarr keeps chunk (i, j) in (absent until the chunk is written)."""
        return self.path / ARRAY_NAME / f"{i}{self._separator}{j}"

    @property
    def _separator(self) -> str:
        try:
            meta = json.loads((self.path / ARRAY_NAME / ".zarray").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return "."
        return str(meta.get("dimension_separator") or ".")

    def is_done(self, i: int, j: int) -> bool:
        """Whether chunk (i, j) is written: its marker is readable and its file matches it.

        A chunk whose file was removed, truncated or altered after its marker was written is
        not done (a resumed run computes it again).
        """
        marker = self._marker(i, j)
        try:
            with np.load(marker) as f:
                size, crc = (int(v) for v in f[CHUNK_STAMP])
        except FileNotFoundError:
            return False
        except _UNREADABLE as exc:
            log.warning("chunk %d,%d of %s: unreadable marker (%s); computing it again",
                        i, j, self.path, exc)
            return False
        if _file_stamp(self.chunk_file(i, j)) != (size, crc):
            log.warning("chunk %d,%d of %s does not match its marker (removed or altered "
                        "since it was written); computing it again", i, j, self.path)
            return False
        return True

    def done_chunks(self) -> set[tuple[int, int]]:
        """Chunks that are written and match their markers (:meth:`is_done`)."""
        done = set()
        ny, nx = self.grid
        for p in (self.path / MARKERS).glob("*.npz"):
            with contextlib.suppress(ValueError):
                i, j = (int(v) for v in p.stem.split("_"))
                if 0 <= i < ny and 0 <= j < nx and self.is_done(i, j):
                    done.add((i, j))
        return done

    def write_chunk(self, i: int, j: int, heights: np.ndarray, catalog: dict | None = None):
        """Write chunk (i, j) (float32, NaN unknown), then its completion marker.

        Unknown pixels are stored as the nodata value. Only the chunk's own region is
        touched, so chunks can be written in parallel from any process.
        """
        w = self.chunk_window(i, j)
        heights = np.asarray(heights, dtype=np.float32)
        if heights.shape != (w.height, w.width):
            raise InvalidDEMError(f"chunk {i},{j} must be {w.height}x{w.width}; "
                                  f"got {heights.shape}")
        if np.isfinite(self.nodata):
            heights = np.where(np.isnan(heights), np.float32(self.nodata), heights)
        marker = self._marker(i, j)
        try:
            _array(self.path, "r+")[w.row:w.row + w.height, w.col:w.col + w.width] = heights
            chunk_file = self.chunk_file(i, j)
            stamp = _file_stamp(chunk_file)
            if stamp[0] >= 0:
                _fsync(chunk_file)
            _fsync(chunk_file.parent)
            fd, tmp = tempfile.mkstemp(prefix=f".{marker.stem}.", suffix=".partial",
                                       dir=marker.parent)
            try:
                with os.fdopen(fd, "wb") as f:
                    entries = dict(catalog or {})
                    entries[CHUNK_STAMP] = np.array(stamp, np.int64)
                    np.savez(f, **entries)
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, marker)
                _fsync(marker.parent)
            finally:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(tmp)
        except OSError as exc:
            if is_write_error(exc):
                raise cannot_write(self.chunk_file(i, j), exc) from exc
            raise

    def chunk_catalog(self, i: int, j: int) -> dict:
        """Return the crater catalogue rows stored with chunk (i, j)'s marker."""
        marker = self._marker(i, j)
        try:
            with np.load(marker) as f:
                return {k: f[k] for k in f.files if k != CHUNK_STAMP}
        except _UNREADABLE as exc:
            raise InvalidDEMError(f"Zarr DEM '{self.path}': the marker of chunk {i},{j} "
                                  f"('{marker}') cannot be read ({type(exc).__name__}: {exc}); "
                                  "remove it and rerun the command that made the store") from None

    # --- reading ------------------------------------------------------------------------
    def read(self, window: Window | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Heights (float32, NaN unknown) and valid mask of a window (default: everything)."""
        window = window or Window(0, 0, self.shape[1], self.shape[0])
        window.check_inside(*self.shape)
        rs, cs = window.slices
        try:
            if self.complete:  # no chunk changes any more: decode each once per process
                h = self._assemble(window)
            else:
                h = np.asarray(_array(self.path, "r")[rs, cs], dtype=np.float32)
        except _UNREADABLE as exc:
            raise self._unreadable(window, exc) from None
        valid = np.isfinite(h)
        if np.isfinite(self.nodata):
            valid &= h != np.float32(self.nodata)
        h = np.where(valid, h, np.float32(np.nan)).astype(np.float32)
        return h, valid

    def _assemble(self, window: Window) -> np.ndarray:
        """Return the window's stored values (float32) from the decoded chunks it overlaps."""
        out = np.empty((window.height, window.width), dtype=np.float32)
        c = self.chunk
        for i in range(window.row // c, -(-(window.row + window.height) // c)):
            for j in range(window.col // c, -(-(window.col + window.width) // c)):
                block = _decoded_chunk(self, i, j)
                r0, c0 = max(window.row, i * c), max(window.col, j * c)
                r1 = min(window.row + window.height, i * c + block.shape[0])
                c1 = min(window.col + window.width, j * c + block.shape[1])
                out[r0 - window.row:r1 - window.row, c0 - window.col:c1 - window.col] = \
                    block[r0 - i * c:r1 - i * c, c0 - j * c:c1 - j * c]
        return out

    def _unreadable(self, window: Window, exc: BaseException) -> InvalidDEMError:
        """Return the error for a failed read, naming the first chunk that cannot be read."""
        array = _array(self.path, "r")
        c = self.chunk
        for i in range(window.row // c, -(-(window.row + window.height) // c)):
            for j in range(window.col // c, -(-(window.col + window.width) // c)):
                w = self.chunk_window(i, j)
                try:
                    array[w.row:w.row + w.height, w.col:w.col + w.width]
                except _UNREADABLE as err:
                    return InvalidDEMError(
                        f"Zarr DEM '{self.path}': chunk {i},{j} ('{self.chunk_file(i, j)}') "
                        f"cannot be read ({type(err).__name__}: {err}); the store is damaged")
        return InvalidDEMError(f"Zarr DEM '{self.path}' cannot be read "
                               f"({type(exc).__name__}: {exc})")

    def check_complete(self) -> None:
        """Raise unless every chunk is written and its file has the size its marker recorded.

        The sizes are compared, not the checksums (that would read the whole store): a chunk
        file removed or truncated since is named instead of being read as nodata.
        """
        if not self.complete:
            ny, nx = self.grid
            raise InvalidDEMError(
                f"Zarr DEM '{self.path}' is incomplete ({len(self.done_chunks())} of "
                f"{ny * nx} chunks written); rerun the command that made it to resume")
        ny, nx = self.grid
        for i in range(ny):
            for j in range(nx):
                marker = self._marker(i, j)
                try:
                    with np.load(marker) as f:
                        if CHUNK_STAMP not in f.files:  # a store from before the stamps
                            continue
                        size = int(f[CHUNK_STAMP][0])
                except _UNREADABLE as exc:
                    raise InvalidDEMError(
                        f"Zarr DEM '{self.path}': the marker of chunk {i},{j} ('{marker}') "
                        f"cannot be read ({type(exc).__name__}: {exc}); the store is "
                        "damaged") from None
                chunk_file = self.chunk_file(i, j)
                found = chunk_file.stat().st_size if chunk_file.exists() else -1
                if found != size:
                    state = "is missing" if found < 0 else f"holds {found} bytes, not {size}"
                    raise InvalidDEMError(
                        f"Zarr DEM '{self.path}': chunk {i},{j} ('{chunk_file}') {state}; "
                        "the store is damaged")
