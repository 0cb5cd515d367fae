"""Reading and writing DEMs and images; the only module that imports rasterio.

Reading goes through GDAL, so anything GDAL opens works: GeoTIFF, PDS3 labels (``.LBL``),
ISIS cubes, IMG. Nodata values, NaN and GDAL's per-dataset masks all become the tile's valid
mask. GDAL scale and offset are applied, except an offset equal to the radius of the CRS's
reference sphere (PDS products such as LOLA's LDEM store ``radius = DN * scale + offset``):
heights then stay relative to that sphere, and the offset is recorded in the metadata as
``CRATERSCAPE_DATUM_RADIUS``.

Writing is atomic: the file is written under a temporary name in the destination folder and
renamed into place only when complete, so a crash or interrupt never leaves a half-written
file, and an output path that names an input is refused before any work starts.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
import threading
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.errors import NotGeoreferencedWarning, RasterioError, RasterioIOError

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.errors import (
    InvalidDEMError,
    InvalidParameterError,
    MissingInputError,
    OutputPathError,
)
from terrain.core.outputs import atomic_path, check_output_path
from terrain.core.tile import DEMTile

__all__ = ["check_output_path", "lonlat_to_xy", "read_dem", "read_dem_exact",
           "read_float_tiff", "same_crs", "write_bands", "write_dem", "write_float_tiff",
           "write_png"]
__all__ += ["orthographic_crs", "polar_crs", "reproject_polar", "synthetic_crs", "xy_to_lonlat"]
# chunked runs (terrain.execution.chunked)
__all__ += ["RasterReader", "raster_layout", "write_cog"]

log = logging.getLogger(__name__)

#: GeoTIFF block size of written tiles (pixels).
BLOCK_SIZE = 256
#: Compression of the sensor images (:func:`write_float_tiff`, every frame's range and
#: normals): none. They are written every frame and read several times by the evaluation
#: (pairs, warps, truth round trips), and their mantissas barely compress: on the demo
#: descent's 1024^2 images (medians of five, this 2-core machine) Zstandard level 1 with the
#: floating-point predictor made the normals 21 % smaller (9.95 MB against 12.58) for 6 times
#: the write (105 ms against 17) and 4 times the read (56 ms against 14), and the range half
#: the size (2.06 MB against 4.19) for 6 and 5 times (36 against 6 ms, 21 against 4). The
#: demo's evaluation stage reading uncompressed runs took about 16 CPU s less of some 125.
#: Any GDAL tool compresses a run afterwards (``gdal_translate -co COMPRESS=ZSTD
#: -co PREDICTOR=3``) and every reader here reads it the same.
SENSOR_TIFF_COMPRESSION = dict(compress="none")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


#: Output extensions of the writers (the format written must match the name).
DEM_SUFFIXES = (".tif", ".tiff")
PNG_SUFFIXES = (".png",)
#: Stored types whose values float32 may not hold exactly.
_WIDE_TYPES = ("float64", "int32", "uint32", "int64", "uint64")

#: The one warnings filter this module adds, while any of its threads opens a file that may
#: not be georeferenced (frames, truth, scratch tiles: rasterio warns at each).
_QUIET_FILTER = ("ignore", None, NotGeoreferencedWarning, None, 0)
_quiet_lock = threading.Lock()
_quiet_users = 0
_quiet_added = False  # whether the filter went in at the first entry (not already there)


@contextlib.contextmanager
def _not_georeferenced_quiet():
    """Silence rasterio's NotGeoreferencedWarning for the ``with`` block, on any thread.

    ``warnings.catch_warnings`` is not for threads: it saves the process-wide filter list on
    entry and puts that copy back on exit, so two threads that overlap leave behind (or
    throw away) each other's filters and anyone else's. Files are read on several threads
    at once (stacks, runs, chunks): here the filter goes in when the first reader enters and
    that one entry comes out when the last leaves, nothing else touched.
    """
    global _quiet_users, _quiet_added
    with _quiet_lock:
        if _quiet_users == 0:
            _quiet_added = _QUIET_FILTER not in warnings.filters
            if _quiet_added:
                warnings.filterwarnings("ignore", category=NotGeoreferencedWarning)
        _quiet_users += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet_users -= 1
            if _quiet_users == 0 and _quiet_added:
                with contextlib.suppress(ValueError):  # someone reset the filters meanwhile
                    warnings.filters.remove(_QUIET_FILTER)
                warnings._filters_mutated()


def read_dem_exact(path, *, band: int = 1) -> tuple[DEMTile, np.ndarray | None]:
    """:func:`read_dem`, and the DEM's exact heights when float32 cannot hold them.

    Returns
    -------
    tile : DEMTile
    exact : (ny, nx) float64, metres, or None
        The heights as stored (NaN where unknown), for a stored type wider than float32
        (float64 or 32/64-bit integers) whose known heights float32 rounds; None otherwise.
        Pass them to :func:`write_dem` as ``known`` to write those heights back bitwise.
    """
    return _read_dem(path, band, exact=True)


def read_dem(path, *, band: int = 1, exact: bool = False) -> DEMTile:
    """Read one band of any GDAL-readable DEM into a :class:`DEMTile`.

    Parameters
    ----------
    path : str or Path
        File to read (GeoTIFF, PDS3 ``.LBL``, ...), or a Zarr DEM written by a chunked run.
    band : int
        1-based band index.
    exact : bool
        For commands that write known heights back: say with a warning (not an info line)
        that a DEM stored in a type wider than float32 has known heights float32 rounds
        (:func:`read_dem_exact` keeps them).

    Returns
    -------
    DEMTile
        float32 heights in metres; nodata, NaN and masked pixels invalid.
    """
    return _read_dem(path, band, exact)[0]


def _read_dem(path, band: int, exact: bool) -> tuple[DEMTile, np.ndarray | None]:
    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"input DEM '{path}' does not exist")
    if path.is_dir():
        return _read_zarr_dem(path), None
    try:
        with _not_georeferenced_quiet():
            src = rasterio.open(path)
        with src:
            if not 1 <= band <= src.count:
                raise InvalidDEMError(f"DEM '{path}' has {src.count} band(s); band {band} asked")
            nrows, ncols = src.height, src.width
            itemsize = np.dtype(src.dtypes[band - 1]).itemsize
            memory.require(nrows * ncols * (itemsize + 4 + 4 + 2), f"reading DEM '{path}'")
            raw = src.read(band, masked=True)
            scale = src.scales[band - 1] if src.scales else 1.0
            offset = src.offsets[band - 1] if src.offsets else 0.0
            crs = src.crs
            transform = src.transform
            nodata = src.nodata
            tags = src.tags()
            georeferenced = not (src.transform.is_identity and src.crs is None
                                 and not src.gcps[0])
    except (RasterioIOError, RasterioError) as exc:
        raise InvalidDEMError(f"cannot read DEM '{path}': {_first_line(exc)}") from exc

    if not georeferenced:
        raise InvalidDEMError(
            f"DEM '{path}' has no georeferencing, so its pixel size is unknown; assign one "
            "first (for example gdal_translate -a_ullr ULX ULY LRX LRY)")
    if crs is not None and crs.is_geographic:
        raise InvalidDEMError(
            f"DEM '{path}' is in geographic coordinates (degrees); reproject it to a projected "
            "CRS in metres first (for example with gdalwarp -t_srs)")
    if transform.b != 0 or transform.d != 0:
        raise InvalidDEMError(f"DEM '{path}' is rotated; warp it to a north-up grid first")

    data = np.ma.getdata(raw)
    valid = ~np.ma.getmaskarray(raw) & np.isfinite(data)
    stored = str(data.dtype)
    metadata = {k: v for k, v in tags.items() if mk.is_key(k)}
    metadata[mk.SOURCE] = str(path)
    scale = 1.0 if scale is None else float(scale)
    offset = 0.0 if offset is None else float(offset)
    if offset != 0.0 and crs is not None and _is_reference_radius(crs, offset):
        metadata[mk.DATUM_RADIUS] = repr(offset)
        offset = 0.0
    if scale != 1.0 or offset != 0.0:
        data = data.astype(np.float64) * scale + offset
    elif data.dtype == np.float32 and data.flags.c_contiguous:
        data.flags.writeable = False  # float32 metres already: the tile shares the array
    else:
        data = data.astype(np.float64)
    if not valid.any():
        raise InvalidDEMError(f"DEM '{path}' band {band} has no valid pixels (all nodata)")
    exact_heights = None
    if stored in _WIDE_TYPES:
        known = data[valid]
        moved = float(np.max(np.abs(known.astype(np.float32).astype(np.float64) - known)))
        if moved > 0:
            exact_heights = np.where(valid, data, np.nan)
            metadata[mk.SOURCE_DTYPE] = stored
            (log.warning if exact else log.info)(
                "DEM '%s' stores %s heights; float32 moves them by up to %.3g m%s", path,
                stored, moved, " (outputs that keep every known height are written in "
                "float64)" if exact else "")
    # Keep the file's nodata value where it still means "unknown" in float32 metres.
    out_nodata = float("nan")
    if nodata is not None and np.isfinite(nodata) and scale == 1.0 and offset == 0.0:
        if np.isfinite(np.float32(nodata)):
            out_nodata = float(np.float32(nodata))
    return (DEMTile(data, valid, transform, crs.to_wkt() if crs else None, out_nodata, metadata),
            exact_heights)


def _read_zarr_dem(path: Path) -> DEMTile:
    """Return a whole Zarr DEM written by a chunked run (:mod:`~.zarrstore`) as a tile."""
    from terrain.core.zarrstore import ZarrDEM, is_zarr

    if not is_zarr(path):
        raise InvalidDEMError(f"input DEM '{path}' is a folder, not a file (nor a Zarr store)")
    store = ZarrDEM(path)
    store.check_complete()
    memory.require(store.shape[0] * store.shape[1] * (4 + 4 + 2), f"reading DEM '{path}'")
    heights, valid = store.read()
    if not valid.any():
        raise InvalidDEMError(f"DEM '{path}' has no valid pixels (all nodata)")
    metadata = dict(store.metadata, **{mk.SOURCE: str(path)})
    return DEMTile(heights, valid, store.transform, store.crs, store.nodata, metadata)


def _is_reference_radius(crs: CRS, offset: float) -> bool:
    try:
        ellipsoid = crs.to_dict(projjson=True)
    except Exception:  # pragma: no cover - exotic CRS definitions
        return False
    return any(abs(candidate - offset) <= 1.0
               for key in ("semi_major_axis", "radius")
               for candidate in _find_numbers(ellipsoid, key))


def _find_numbers(obj, key):
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k == key and isinstance(v, (int, float)):
                yield float(v)
            elif k == key and isinstance(v, dict) and "value" in v:
                yield float(v["value"])
            else:
                yield from _find_numbers(v, key)
    elif isinstance(obj, list):
        for item in obj:
            yield from _find_numbers(item, key)


def _verify(tmp, expected: np.ndarray, path, messages: str = "") -> None:
    """Read a just-written TIFF back and compare it with what was written.

    GDAL reports some write failures (a full disk, a file-size limit) only as messages on
    stderr and leaves a truncated file; reading back turns them into one "cannot write"
    error, naming the first message, before the file is put in place.
    """
    try:
        with _not_georeferenced_quiet():
            with rasterio.open(tmp) as src:
                back = src.read()
        whole = back.shape == expected.shape and np.array_equal(back, expected, equal_nan=True)
    except (RasterioIOError, RasterioError):
        whole = False
    if not whole:
        first = messages.strip().splitlines()[0].strip() if messages.strip() else ""
        reason = first.rstrip(".") if first else "the written file does not read back whole"
        raise OutputPathError(f"cannot write '{path}': {reason}")


def _verify_blocks(tmp, path, messages: str = "", *, bands: int,
                   tags: dict | None = None) -> None:
    """Check that a just-written tiled TIFF opens and holds every block and tag it should.

    The cheap form of :func:`_verify` for images written every frame: a write that failed
    part-way (a full disk, a file-size limit) leaves blocks that end past the end of the
    file, or none, or metadata (written last) that does not read back; every block's offset
    and byte count are read from the directory (GDAL's ``BLOCK_OFFSET_x_y`` and
    ``BLOCK_SIZE_x_y``) and the tags compared, not the pixels decompressed.
    """
    whole = False
    try:
        size = os.path.getsize(tmp)
        with _not_georeferenced_quiet():
            with rasterio.open(tmp) as src:
                bh, bw = src.block_shapes[0]
                nx, ny = -(-src.width // bw), -(-src.height // bh)
                ends = []
                for band in range(1, src.count + 1):
                    for i in range(nx):
                        for j in range(ny):
                            off = src.get_tag_item(f"BLOCK_OFFSET_{i}_{j}", "TIFF", bidx=band)
                            n = src.get_tag_item(f"BLOCK_SIZE_{i}_{j}", "TIFF", bidx=band)
                            ends.append(int(off) + int(n) if off and n and int(n) > 0 else -1)
                meta = src.tags()
        whole = (bool(ends) and min(ends) > 0 and max(ends) <= size and src.count == bands
                 and all(meta.get(k) == v for k, v in (tags or {}).items()))
    except (OSError, ValueError, RasterioIOError, RasterioError):
        whole = False
    if not whole:
        first = messages.strip().splitlines()[0].strip() if messages.strip() else ""
        reason = first.rstrip(".") if first else "the written file does not hold every block"
        raise OutputPathError(f"cannot write '{path}': {reason}")


#: Held while file descriptor 2 points at a capture (:func:`_c_stderr`). Frames are written
#: on a thread while the next renders (``render.sequence``): two captures at once would each
#: save the other's sink as "stderr", and the process would lose its real one for good.
_FD2_LOCK = threading.RLock()


@contextlib.contextmanager
def _c_stderr() -> Iterator[list]:
    """Capture what C libraries (GDAL, libtiff) print on file descriptor 2 meanwhile.

    Yields a list that receives the text; the caller decides whether it is an error (then it
    becomes the one-line reason) or is passed on to stderr unchanged. One capture at a time
    in the process (:data:`_FD2_LOCK`); what another thread prints meanwhile is captured too
    and passed on afterwards.
    """
    import sys

    out: list = []
    with _FD2_LOCK:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):  # no real stderr: nothing to capture
            yield out
            return
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), 2)
            try:
                yield out
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                sink.seek(0)
                out.append(sink.read().decode("utf-8", "replace"))


def _replay(captured: list) -> None:
    import sys

    text = "".join(captured)
    if text:
        sys.stderr.write(text)


def same_crs(a: str | None, b: str | None) -> bool:
    """Return whether two CRS definitions (WKT) describe the same CRS.

    GDAL's own equality, so equivalent CRSs written differently compare equal; None equals
    only None.
    """
    if a is None or b is None:
        return a is None and b is None
    try:
        return CRS.from_wkt(a) == CRS.from_wkt(b)
    except Exception:  # unparsable WKT: fall back to the text
        return " ".join(a.split()) == " ".join(b.split())


def write_dem(tile: DEMTile, path, *, inputs: Iterable = (),
              description: str = "height (m)", known: np.ndarray | None = None) -> Path:
    """Write a tile as a tiled, DEFLATE-compressed float32 GeoTIFF, atomically.

    The tile's CRS, transform and nodata value are preserved; its metadata (seed,
    parameters, provenance) goes into the GeoTIFF's GDAL metadata tags. ``inputs`` lists
    files the output must not replace; ``description`` labels the band (e.g. "slope (deg)").
    ``known`` ((ny, nx) float64 metres, NaN where unknown; from :func:`read_dem_exact`) puts
    exact known heights back bitwise where the tile is valid: the file is then float64.
    """
    check_output_path(path, inputs, suffixes=DEM_SUFFIXES, what="GeoTIFF")
    nrows, ncols = tile.shape
    nodata = tile.nodata
    data = tile.heights
    dtype = "float32"
    if known is not None:  # exact heights float32 cannot hold: write them back, in float64
        known = np.asarray(known, dtype=np.float64)
        if known.shape != tile.shape:
            raise ValueError(f"known heights must be {tile.shape}; got {known.shape}")
        data = np.where(np.isfinite(known) & tile.valid, known,
                        tile.heights.astype(np.float64))
        dtype = "float64"
    if np.isfinite(nodata):
        data = np.where(tile.valid, data, nodata).astype(dtype)
    profile = dict(
        driver="GTiff", dtype=dtype, count=1, width=ncols, height=nrows,
        crs=CRS.from_wkt(tile.crs) if tile.crs else None, transform=tile.transform,
        nodata=nodata, compress="deflate", predictor=3, zlevel=6, tiled=True,
        blockxsize=BLOCK_SIZE, blockysize=BLOCK_SIZE, BIGTIFF="IF_SAFER",
    )
    with atomic_path(path, inputs) as tmp:
        with _c_stderr() as captured:
            try:
                with rasterio.open(tmp, "w", **profile) as dst:
                    dst.write(data, 1)
                    dst.update_tags(**dict(tile.metadata))
                    dst.set_band_description(1, description)
            except (RasterioIOError, RasterioError) as exc:
                raise OutputPathError(f"cannot write '{path}': {_first_line(exc)}") from exc
        _verify(tmp, data[None], path, "".join(captured))
        _replay(captured)
    log.info("wrote %s (%d x %d)", path, ncols, nrows)
    return Path(path)


def write_png(image: np.ndarray, path, *, inputs: Iterable = ()) -> Path:
    """Write an 8- or 16-bit grey or BGR image as PNG, atomically."""
    import cv2  # local: OpenCV is heavy and only needed for images

    check_output_path(path, inputs, suffixes=PNG_SUFFIXES, what="PNG")
    image = np.asarray(image)
    if image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG images must be uint8 or uint16; got {image.dtype}")
    ok, buf = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - OpenCV failure
        raise OutputPathError(f"cannot encode PNG for '{path}'")
    with atomic_path(path, inputs) as tmp:
        tmp.write_bytes(buf.tobytes())
    return Path(path)


def lonlat_to_xy(crs_wkt: str | None, lon: float, lat: float) -> tuple[float, float]:
    """Map coordinates of a longitude/latitude (degrees) on the CRS's own body and datum."""
    from terrain.core.errors import InvalidParameterError

    if not crs_wkt:
        raise InvalidParameterError("the DEM has no CRS, so longitude/latitude cannot be placed "
                                    "on it; give the site in map coordinates")
    if not (-360.0 <= lon <= 360.0 and -90.0 <= lat <= 90.0):
        raise InvalidParameterError(f"longitude/latitude out of range: {lon}, {lat}")
    from rasterio.warp import transform

    crs = CRS.from_wkt(crs_wkt)
    base = crs.to_dict(projjson=True).get("base_crs")
    if base is None:
        raise InvalidParameterError("the DEM's CRS has no geographic base CRS")
    xs, ys = transform(CRS.from_user_input(json.dumps(base)), crs, [lon], [lat])
    if not (np.isfinite(xs[0]) and np.isfinite(ys[0])):
        raise InvalidParameterError(f"longitude/latitude {lon}, {lat} has no position in the "
                                    "DEM's projection")
    return float(xs[0]), float(ys[0])


def xy_to_lonlat(crs_wkt: str | None, x: float, y: float) -> tuple[float, float]:
    """Longitude/latitude (degrees, on the CRS's own body) of map coordinates ``x, y``.

    The inverse of :func:`lonlat_to_xy`.

    Parameters
    ----------
    crs_wkt : str or None
        The map's CRS (WKT).
    x, y : float
        Map coordinates (the CRS's units).

    Returns
    -------
    (float, float)
        Longitude and latitude, degrees.
    """
    from terrain.core.errors import InvalidParameterError

    if not crs_wkt:
        raise InvalidParameterError("the DEM has no CRS, so its points have no longitude and "
                                    "latitude; give them")
    from rasterio.warp import transform

    crs = CRS.from_wkt(crs_wkt)
    base = crs.to_dict(projjson=True).get("base_crs")
    if base is None:
        raise InvalidParameterError("the DEM's CRS has no geographic base CRS")
    lons, lats = transform(crs, CRS.from_user_input(json.dumps(base)), [x], [y])
    if not (np.isfinite(lons[0]) and np.isfinite(lats[0])):
        raise InvalidParameterError(f"map point {x}, {y} has no longitude/latitude in the "
                                    "DEM's projection")
    return float(lons[0]), float(lats[0])


def write_float_tiff(array: np.ndarray, path, *, tags: dict | None = None, inputs=()) -> Path:
    """Write a (h, w) or (h, w, bands) float32 image as a tiled TIFF, atomically.

    Not georeferenced (sensor images: range, normals); NaN marks invalid pixels and is the
    nodata value. Bands keep their order (band 1 = channel 0). Stored as
    :data:`SENSOR_TIFF_COMPRESSION` says (uncompressed); the file is checked to hold every
    block it lists (:func:`_verify_blocks`) before it is put in place.
    """
    check_output_path(path, inputs, suffixes=DEM_SUFFIXES, what="TIFF")
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise ValueError(f"image must be (h, w) or (h, w, bands); got {a.shape}")
    h, w, bands = a.shape
    profile = dict(driver="GTiff", dtype="float32", count=bands, width=w, height=h,
                   nodata=float("nan"), tiled=True, blockxsize=BLOCK_SIZE,
                   blockysize=BLOCK_SIZE, **SENSOR_TIFF_COMPRESSION)
    with atomic_path(path, inputs) as tmp, _not_georeferenced_quiet():
        with _c_stderr() as captured:
            try:
                with rasterio.open(tmp, "w", **profile) as dst:
                    dst.write(np.moveaxis(a, 2, 0))
                    if tags:
                        dst.update_tags(**{k: str(v) for k, v in tags.items()})
            except (RasterioIOError, RasterioError) as exc:
                raise OutputPathError(f"cannot write '{path}': {_first_line(exc)}") from exc
        _verify_blocks(tmp, path, "".join(captured), bands=bands,
                       tags={k: str(v) for k, v in (tags or {}).items()})
        _replay(captured)
    return Path(path)


def _read_float_bands(path, pixel: tuple[int, int] | None = None) -> np.ndarray:
    """(bands, h, w) of a float TIFF, or of its one pixel ``(row, col)``: (bands, 1, 1)."""
    from rasterio.windows import Window as RioWindow

    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"image '{path}' does not exist")
    try:
        with _not_georeferenced_quiet():
            with rasterio.open(path) as src:
                if pixel is None:
                    return src.read()
                row, col = pixel
                if not (0 <= row < src.height and 0 <= col < src.width):
                    raise InvalidParameterError(
                        f"pixel (row {row}, column {col}) lies outside image '{path}' "
                        f"({src.width}x{src.height})")
                return src.read(window=RioWindow(col, row, 1, 1))
    except (RasterioIOError, RasterioError) as exc:
        raise InvalidDEMError(f"cannot read image '{path}': {_first_line(exc)}") from exc


def read_float_tiff(path) -> np.ndarray:
    """Read a float TIFF written by :func:`write_float_tiff`: (h, w) or (h, w, bands)."""
    a = _read_float_bands(path)
    return a[0] if a.shape[0] == 1 else np.moveaxis(a, 0, 2)


def read_float_tiff_pixel(path, row: int, col: int) -> np.ndarray:
    """Return one pixel of a float TIFF written by :func:`write_float_tiff`: (bands,).

    Only the tile that holds it is decoded (a sixteenth of a 1024^2 range image's), and its
    values are those :func:`read_float_tiff` gives there. A pixel outside the image raises
    :class:`~terrain.core.errors.InvalidParameterError`.
    """
    return _read_float_bands(path, (row, col))[:, 0, 0]


def raster_layout(path) -> dict:
    """Return how a raster file is laid out: what a check of a Cloud Optimized GeoTIFF reads.

    Parameters
    ----------
    path : path-like
        Any raster GDAL opens.

    Returns
    -------
    dict
        ``width`` and ``height`` (pixels), ``transform`` (the six affine coefficients
        a, b, c, d, e, f), ``overviews`` (the decimation factors of band 1), ``driver`` and
        ``layout`` (GDAL's ``IMAGE_STRUCTURE`` ``LAYOUT``: ``"COG"`` for a COG, else None).
    """
    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"raster '{path}' does not exist")
    try:
        with _not_georeferenced_quiet():
            with rasterio.open(path) as ds:
                return dict(width=ds.width, height=ds.height, transform=list(ds.transform)[:6],
                            overviews=ds.overviews(1), driver=ds.driver,
                            layout=ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT"))
    except (RasterioIOError, RasterioError) as exc:
        raise InvalidDEMError(f"cannot read raster '{path}': {_first_line(exc)}") from exc


def write_bands(bands, tile: DEMTile, path, *, descriptions=(), tags: dict | None = None,
                inputs: Iterable = ()) -> Path:
    """Write (h, w) float32 bands on ``tile``'s grid (CRS, transform) as one GeoTIFF, atomically.

    NaN is the nodata value; ``descriptions`` label the bands, ``tags`` go into the GDAL
    metadata beside the tile's own.
    """
    check_output_path(path, inputs, suffixes=DEM_SUFFIXES, what="GeoTIFF")
    data = np.stack([np.asarray(b, dtype=np.float32) for b in bands])
    if data.shape[1:] != tile.shape:
        raise ValueError(f"bands must have the tile's shape {tile.shape}; got {data.shape[1:]}")
    profile = dict(
        driver="GTiff", dtype="float32", count=data.shape[0], width=tile.shape[1],
        height=tile.shape[0], crs=CRS.from_wkt(tile.crs) if tile.crs else None,
        transform=tile.transform, nodata=float("nan"), compress="deflate", predictor=3,
        tiled=True, blockxsize=BLOCK_SIZE, blockysize=BLOCK_SIZE, BIGTIFF="IF_SAFER")
    with atomic_path(path, inputs) as tmp, _not_georeferenced_quiet():
        with _c_stderr() as captured:
            try:
                with rasterio.open(tmp, "w", **profile) as dst:
                    dst.write(data)
                    dst.update_tags(**dict(tile.metadata), **{k: str(v) for k, v in
                                                              (tags or {}).items()})
                    for i, text in enumerate(descriptions, start=1):
                        dst.set_band_description(i, text)
            except (RasterioIOError, RasterioError) as exc:
                raise OutputPathError(f"cannot write '{path}': {_first_line(exc)}") from exc
        _verify(tmp, data, path, "".join(captured))
        _replay(captured)
    return Path(path)


# --------------------------------------------------------------------------------------
# windowed reading and Cloud Optimized GeoTIFFs (chunked runs, terrain.execution.chunked)


class RasterReader:
    """Read windows of one band of any GDAL raster, as :func:`read_dem` would read them.

    The file is opened again for every read, so a reader is a small picklable value that
    Dask ships to its workers. Heights are converted exactly as :func:`read_dem` converts
    them (scale and offset in float64, then float32; nodata, NaN and GDAL masks unknown),
    so a window read here equals the same window of ``read_dem(path).heights``, bitwise.

    Parameters
    ----------
    path : str or Path
    band : int
        1-based band index.
    """

    def __init__(self, path, band: int = 1):
        path = Path(path)
        if not path.exists():
            raise MissingInputError(f"input DEM '{path}' does not exist")
        if path.is_dir():
            raise InvalidDEMError(f"input DEM '{path}' is a folder, not a file")
        self.path, self.band = path, int(band)
        try:
            with _not_georeferenced_quiet():
                src = rasterio.open(path)
            with src:
                if not 1 <= band <= src.count:
                    raise InvalidDEMError(
                        f"DEM '{path}' has {src.count} band(s); band {band} asked")
                self.shape = (src.height, src.width)
                stored = src.dtypes[band - 1]
                scale = src.scales[band - 1] if src.scales else 1.0
                offset = src.offsets[band - 1] if src.offsets else 0.0
                crs, transform, nodata, tags = src.crs, src.transform, src.nodata, src.tags()
                self.block = src.block_shapes[band - 1]
                georeferenced = not (src.transform.is_identity and src.crs is None
                                     and not src.gcps[0])
        except (RasterioIOError, RasterioError) as exc:
            raise InvalidDEMError(f"cannot read DEM '{path}': {_first_line(exc)}") from exc
        if not georeferenced:
            raise InvalidDEMError(f"DEM '{path}' has no georeferencing, so its pixel size is "
                                  "unknown; assign one first (gdal_translate -a_ullr)")
        if crs is not None and crs.is_geographic:
            raise InvalidDEMError(f"DEM '{path}' is in geographic coordinates (degrees); "
                                  "reproject it to a projected CRS in metres first")
        if transform.b != 0 or transform.d != 0:
            raise InvalidDEMError(f"DEM '{path}' is rotated; warp it to a north-up grid first")
        self.stored = stored
        #: Whether float32 may not hold the stored values exactly (see read_dem_exact).
        self.wide = stored in _WIDE_TYPES
        self.metadata = {k: v for k, v in tags.items() if mk.is_key(k)}
        self.metadata[mk.SOURCE] = str(path)
        self.scale = 1.0 if scale is None else float(scale)
        self.offset = 0.0 if offset is None else float(offset)
        if self.offset != 0.0 and crs is not None and _is_reference_radius(crs, self.offset):
            self.metadata[mk.DATUM_RADIUS] = repr(self.offset)
            self.offset = 0.0
        self.nodata = float("nan")
        if (nodata is not None and np.isfinite(nodata) and self.scale == 1.0
                and self.offset == 0.0 and np.isfinite(np.float32(nodata))):
            self.nodata = float(np.float32(nodata))
        self.transform = transform
        self.crs = crs.to_wkt() if crs else None

    @property
    def resolution(self) -> float:
        """The pixel spacing in metres (square pixels)."""
        return float(self.transform.a)

    def read(self, window=None) -> tuple[np.ndarray, np.ndarray]:
        """Heights (float32 metres, NaN unknown) and valid mask of a window.

        Parameters
        ----------
        window : terrain.core.tile.Window, optional
            Default: the whole raster (which must then fit in memory).

        Returns
        -------
        heights : (height, width) float32, metres
        valid : (height, width) bool
        """
        from rasterio.windows import Window as RioWindow

        from terrain.core.tile import Window

        window = window or Window(0, 0, self.shape[1], self.shape[0])
        window.check_inside(*self.shape)
        memory.require(window.width * window.height * 20, f"reading a window of '{self.path}'")
        try:
            with _not_georeferenced_quiet():
                with rasterio.open(self.path) as src:
                    raw = src.read(self.band, masked=True, window=RioWindow(
                        window.col, window.row, window.width, window.height))
        except (RasterioIOError, RasterioError) as exc:
            raise InvalidDEMError(f"cannot read DEM '{self.path}': {_first_line(exc)}") from exc
        data = np.ma.getdata(raw).astype(np.float64)
        valid = ~np.ma.getmaskarray(raw) & np.isfinite(data)
        if self.scale != 1.0 or self.offset != 0.0:
            data = data * self.scale + self.offset
        h = data.astype(np.float32)
        valid &= np.isfinite(h)
        h[~valid] = np.nan
        return h, valid


#: Block (tile) side of written Cloud Optimized GeoTIFFs, pixels.
COG_BLOCK = 512
#: DEFLATE level of COGs: the fastest. On fractal float32 heights with the floating-point
#: predictor, GDAL's default level 6 made a 2049^2 COG 1 % smaller and took 23 % longer
#: (measured), and compression dominates converting a 1e9-pixel DEM.
COG_DEFLATE_LEVEL = 1


def write_cog(source, path, *, inputs: Iterable = (), description: str = "height (m)",
              progress=None) -> Path:
    """Convert a chunked DEM into a tiled, compressed Cloud Optimized GeoTIFF with overviews.

    The DEM is copied window by window (memory bounded by one row of chunks) into a tiled
    BigTIFF beside the output, overviews are built (average, down to one block), and GDAL's
    COG driver lays it out as a COG (DEFLATE, floating-point predictor), renamed into place
    atomically. QGIS and GDAL open the result directly.

    Parameters
    ----------
    source
        A chunked DEM: ``shape``, ``chunk``, ``transform``, ``crs``, ``nodata``, ``metadata``
        and ``read(window) -> (heights, valid)`` (:class:`terrain.core.zarrstore.ZarrDEM`).
    path : str or Path
        Output ``.tif``; never an input.
    progress : callable, optional
        ``progress(done, total)`` per row of chunks copied.
    """
    import shutil

    from rasterio.enums import Resampling
    from rasterio.shutil import copy as rio_copy
    from rasterio.windows import Window as RioWindow

    from terrain.core.tile import Window

    path = check_output_path(path, inputs)
    ny, nx = source.shape
    parent = path.parent if str(path.parent) else Path(".")
    need = ny * nx * 4 * 2.7  # scratch copy with overviews + the COG, compressed at worst 1:1
    free = shutil.disk_usage(parent).free
    if free < need:
        raise OutputPathError(f"writing the COG '{path}' needs up to {memory.format_bytes(need)}"
                              f" of disk in '{parent}' but only {memory.format_bytes(free)} "
                              "is free")
    nodata = source.nodata
    profile = dict(driver="GTiff", dtype="float32", count=1, width=nx, height=ny,
                   crs=CRS.from_wkt(source.crs) if source.crs else None,
                   transform=source.transform, nodata=nodata, tiled=True,
                   blockxsize=COG_BLOCK, blockysize=COG_BLOCK, compress="zstd", zstd_level=1,
                   predictor=3, BIGTIFF="YES")
    factors = []
    f = 2
    while max(ny, nx) / f >= COG_BLOCK / 2 and f <= 2**16:
        factors.append(f)
        f *= 2
    step = max(int(source.chunk), COG_BLOCK)
    step = -(-step // COG_BLOCK) * COG_BLOCK
    fd, scratch_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".scratch.tif",
                                        dir=parent)
    os.close(fd)
    scratch = Path(scratch_name)
    try:
        with atomic_path(path, inputs) as tmp:
            try:
                with rasterio.Env(GDAL_NUM_THREADS="ALL_CPUS"), \
                        rasterio.open(scratch, "w", **profile) as dst:
                    rows = range(0, ny, step)
                    for done, r0 in enumerate(rows, start=1):
                        h = min(step, ny - r0)
                        for c0 in range(0, nx, step):
                            w = min(step, nx - c0)
                            heights, valid = source.read(Window(c0, r0, w, h))
                            if np.isfinite(nodata):
                                heights = np.where(valid, heights, np.float32(nodata))
                            dst.write(heights.astype(np.float32), 1,
                                      window=RioWindow(c0, r0, w, h))
                        if progress is not None:
                            progress(done, len(rows))
                    dst.update_tags(**dict(source.metadata))
                    dst.set_band_description(1, description)
                    if factors:
                        dst.build_overviews(factors, Resampling.average)
                with rasterio.Env(GDAL_NUM_THREADS="ALL_CPUS"):
                    rio_copy(scratch, tmp, driver="COG", COMPRESS="DEFLATE", PREDICTOR="YES",
                             LEVEL=COG_DEFLATE_LEVEL, NUM_THREADS="ALL_CPUS",
                             BLOCKSIZE=COG_BLOCK, BIGTIFF="IF_SAFER",
                             OVERVIEWS="FORCE_USE_EXISTING", RESAMPLING="AVERAGE")
            except (RasterioIOError, RasterioError) as exc:
                raise OutputPathError(f"cannot write '{path}': {_first_line(exc)}") from exc
    finally:
        with contextlib.suppress(FileNotFoundError):
            scratch.unlink()
    log.info("wrote COG %s (%d x %d, overviews %s)", path, nx, ny, factors)
    return path


def polar_crs(radius: float, *, pole: str = "south", false_easting: float = 0.0,
              false_northing: float = 0.0) -> str:
    """WKT of a polar stereographic CRS on a sphere of ``radius`` (m).

    Parameters
    ----------
    radius : float
        Sphere radius (m), e.g. the Moon's 1737400.
    pole : {"south", "north"}
        The pole at the projection's centre.
    false_easting, false_northing : float
        Map coordinates of the pole (m).

    Returns
    -------
    str
        The CRS as WKT.

    Examples
    --------
    >>> "Polar_Stereographic" in polar_crs(1737400.0) or "Stereographic" in polar_crs(1737400.0)
    True
    """
    if pole not in ("south", "north"):
        raise ValueError(f"pole must be 'south' or 'north'; got {pole!r}")
    lat0 = -90 if pole == "south" else 90
    return CRS.from_proj4(f"+proj=stere +lat_0={lat0} +lon_0=0 +k=1 +x_0={false_easting!r} "
                          f"+y_0={false_northing!r} +R={radius:.0f} +units=m +no_defs").to_wkt()


def orthographic_crs(radius: float, lon: float, lat: float, *, false_easting: float = 0.0,
                     false_northing: float = 0.0) -> str:
    """WKT of an orthographic CRS centred on ``lon, lat`` (degrees) on a sphere (m).

    Parameters
    ----------
    radius : float
        Sphere radius (m).
    lon, lat : float
        Centre of the projection (degrees).
    false_easting, false_northing : float
        Map coordinates of the centre (m).

    Returns
    -------
    str
        The CRS as WKT.
    """
    if not (-360.0 <= lon <= 360.0 and -90.0 <= lat <= 90.0):
        raise ValueError(f"centre longitude/latitude out of range: {lon}, {lat}")
    return CRS.from_proj4(f"+proj=ortho +lat_0={lat!r} +lon_0={lon!r} +x_0={false_easting!r} "
                          f"+y_0={false_northing!r} +R={radius:.0f} +units=m +no_defs").to_wkt()


def reproject_polar(src: DEMTile, *, radius: float, half_width_m: float,
                    pole: str = "south", limit_lat: float = 60.0) -> DEMTile:
    """Return a global DEM reprojected onto a polar stereographic grid around one pole.

    A simple-cylindrical product's pixels are far from square near a pole, so slopes are
    only comparable after reprojection: bilinear, onto square pixels of the product's own
    spacing along a meridian, ``half_width_m`` either side of the pole. Only rows poleward
    of ``limit_lat`` are read (the projection cannot take the other pole, and GDAL would
    warn for every row it tried).

    Parameters
    ----------
    src : DEMTile
        A simple-cylindrical DEM in metres on a sphere of ``radius`` (y = latitude x R).
    radius : float
        Sphere radius (m).
    half_width_m : float
        Half the side of the output grid (m).
    pole : {"south", "north"}
        The pole at the centre.
    limit_lat : float
        Latitude (degrees, unsigned) beyond which the source is read.

    Returns
    -------
    DEMTile
        Heights ``(n, n) float64`` metres, NaN where the source has none, CRS
        :func:`polar_crs` with the pole at (0, 0).
    """
    import math

    from affine import Affine
    from rasterio.transform import from_origin
    from rasterio.warp import Resampling, reproject

    res = src.resolution
    sign = -1.0 if pole == "south" else 1.0
    row = int(round((~src.transform @ (0.0, sign * limit_lat * math.pi / 180.0 * radius))[1]))
    rows = slice(row, None) if pole == "south" else slice(0, row)
    heights = src.heights[rows].astype(np.float64)
    src_transform = src.transform @ Affine.translation(0, rows.start or 0)
    n = int(2 * half_width_m / res)
    crs = CRS.from_proj4(f"+proj=stere +lat_0={int(sign * 90)} +lon_0=0 +k=1 +x_0=0 +y_0=0 "
                         f"+R={radius:.0f} +units=m +no_defs")
    transform = from_origin(-n * res / 2, n * res / 2, res, res)
    dst = np.full((n, n), np.nan, dtype=np.float64)
    logging.getLogger("rasterio._err").setLevel(logging.ERROR)  # PROJ's per-row chatter
    reproject(heights, dst, src_transform=src_transform,
              src_crs=src.crs, dst_transform=transform, dst_crs=crs,
              resampling=Resampling.bilinear, src_nodata=np.nan, dst_nodata=np.nan)
    return DEMTile.from_array(dst, transform=transform, crs=crs.to_wkt(),
                              metadata=dict(src.metadata))


def synthetic_crs(body: str | None, projection: str | None, centre: tuple[float, float]
                  ) -> str | None:
    """WKT of a synthetic DEM's CRS on a body, its centre at map point ``centre``.

    Parameters
    ----------
    body : str or None
        A body of :data:`terrain.core.bodies.BODY_RADII`; None: no CRS.
    projection : str or None
        A projection of :data:`terrain.core.bodies.PROJECTIONS` (default south-polar).
    centre : (float, float)
        Map coordinates (m) of the projection's centre: the tile's centre.

    Returns
    -------
    str or None
        The CRS as WKT; None without a body.
    """
    from terrain.core.bodies import BODY_RADII, check_projection

    kind = check_projection(body, projection)
    if kind is None or body is None:  # check_projection gives None exactly without a body
        return None
    radius = BODY_RADII[body]
    if kind[0] == "stere":
        return polar_crs(radius, pole="south" if kind[1] < 0 else "north",
                         false_easting=centre[0], false_northing=centre[1])
    return orthographic_crs(radius, kind[1], kind[2], false_easting=centre[0],
                            false_northing=centre[1])
