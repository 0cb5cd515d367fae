"""Layer stacks on disk: the files, the manifest that commits them, and the locks.

On disk: ``layer_NN.tif`` per layer (float32 GeoTIFF; a layer too large for memory, built
chunk by chunk by :mod:`terrain.stack.chunkedlayers`, is a Zarr DEM ``layer_NN.zarr``),
``manifest.json`` (each layer's file, level, resolution, extent, transform, parent and window
in the parent; the site, seed and parameters) and ``craters.csv`` (the catalogue with a
``layer`` column).

The manifest is the stack's one commit point: it names every layer file and the catalogue
file, and nothing else in the folder counts.

- A new stack is written with a marker ``.craterscape.incomplete`` first and the manifest
  last; a build that fails removes what it wrote, and a rerun into a folder that a killed
  build left (marker, no manifest) clears it and starts again (:func:`prepare_folder`).
- Edits (:func:`terrain.stack.edit.replace_crater`) hold the edit lock ``.craterscape.lock``
  (:func:`stack_lock`), write new versions of the layers they change and of the catalogue
  under new names (``layer_NN.STAMP.tif``, ``craters.STAMP.csv``), then replace the manifest
  atomically (:func:`commit_edit`). A crash before that leaves the old stack whole; after it,
  the new one.
- Readers (:func:`read_stack`) hold a shared lock on ``.craterscape.readers`` while they
  read; an edit deletes the files the old manifest named only once it holds that lock
  exclusively, so a reader never loses a file half way. Files no manifest names (left by a
  killed edit) are swept by the next edit (:func:`sweep_edits`).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from terrain.core import metakeys as mk
from terrain.core.checks import check_keys
from terrain.core.errors import InvalidDEMError, InvalidParameterError, MissingInputError
from terrain.core.outputs import remove_path
from terrain.core.parallel import threads
from terrain.craters.catalog import CraterCatalog, RockCatalog
from terrain.stack.model import CATALOG, LayerStack, layer_records, merge_catalogs

__all__ = ["FORMAT", "INCOMPLETE", "LOCK", "LOCK_TIMEOUT", "MANIFEST", "READERS_LOCK",
           "READERS_TIMEOUT", "ROCK_CATALOG", "WORK", "commit_edit", "prepare_folder",
           "read_stack", "stack_lock", "stack_manifest", "sweep_edits", "write_stack"]

log = logging.getLogger(__name__)

#: Name of the manifest in a layer-stack folder.
MANIFEST = "manifest.json"
#: Rock catalogue in a layer-stack folder (when the stack has rocks).
ROCK_CATALOG = "rocks.csv"
#: Lock file guarding edits of a layer-stack folder.
LOCK = ".craterscape.lock"
#: Lock file readers hold shared while they read; edits hold it exclusively to delete.
READERS_LOCK = ".craterscape.readers"
#: Marker of a stack being built (removed when its manifest is in place).
INCOMPLETE = ".craterscape.incomplete"
#: Seconds an edit waits for readers before leaving old files to the next edit's sweep.
READERS_TIMEOUT = 30.0
#: Names of files a stack's writers create (swept when no manifest names them).
_STACK_FILE_PATTERNS = ("layer_*.tif", "layer_*.zarr", "craters*.csv", "rocks*.csv")
#: Work folder of a chunked build (:mod:`terrain.stack.chunkedlayers`), kept for its resumption.
WORK = ".craterscape.work"
_LOCKS = (LOCK, READERS_LOCK, INCOMPLETE)
#: Seconds an edit waits for another edit of the same stack before giving up.
LOCK_TIMEOUT = 600.0
FORMAT = "craterscape-layer-stack"
#: Keys of a manifest: its own, then the provenance its builders, edits and the enhance stage
#: record (``LayerStack.info``). A manifest is machine-written, so any other key is refused
#: both when it is written and when it is read.
MANIFEST_KEYS = frozenset({
    "format", "version", "crs", "layers", "catalog", "crater_counts",
    "base_filled_pixels", "base_fill_roughness", "rocks", "rock_catalog", "rock_counts", "seed",
    "site", "levels", "layer_size", "expansion", "min_crater_pixels", "population",
    "crater_model", "chunked", "source", "command", "craterscape_version", "edits",
    "repose", "slope_law"})
#: Keys of each layer's entry in a manifest.
LAYER_KEYS = frozenset({"level", "file", "resolution", "width", "height", "bounds", "transform",
                        "parent", "window_in_parent", "origin"})


def stack_manifest(stack: LayerStack, files: list[str]) -> dict:
    """Return the manifest of ``stack`` whose layers are in ``files`` (JSON-able).

    Parameters
    ----------
    stack : LayerStack
        The stack (layers in memory, or stand-ins with their shape, transform and CRS).
    files : list of str
        Each layer's file name in the stack folder.

    Returns
    -------
    dict
        Format, version, CRS, each layer's entry, catalogue name, crater counts and the
        stack's provenance.
    """
    layers = []
    for k, tile in enumerate(stack.tiles):
        window = stack.windows[k]
        layers.append(dict(
            level=k, file=files[k], resolution=tile.resolution, width=tile.shape[1],
            height=tile.shape[0], bounds=list(tile.bounds), transform=list(tile.transform)[:6],
            parent=None if k == 0 else k - 1,
            window_in_parent=None if window is None else list(window),
            origin=list(stack.origins[k])))
    layer = stack.catalog.layer
    counts = np.bincount(layer, minlength=len(stack.tiles)).tolist() \
        if layer is not None and len(layer) else [0] * len(stack.tiles)
    manifest = dict(format=FORMAT, version=1, crs=stack.tiles[0].crs, layers=layers,
                    catalog=CATALOG, crater_counts=counts, **stack.info)
    check_keys(manifest, MANIFEST_KEYS, "layer-stack manifest")
    return manifest


def prepare_folder(outdir, *, inputs=(), keep=()) -> Path:
    """Check that ``outdir`` can take a new stack, before any work.

    A missing or empty folder is fine; so is a folder a killed build left (its
    ``.craterscape.incomplete`` marker and no manifest), whose files are removed here,
    except those named in ``keep`` (a chunked build keeps its work folder to resume it).
    Anything else is refused.

    Parameters
    ----------
    outdir : path
        The stack's folder.
    inputs : iterable of path
        The build's inputs: the folder may neither be one nor hold one.
    keep : iterable of str
        Names in a killed build's folder to leave in place.

    Returns
    -------
    Path
        ``outdir``.

    Raises
    ------
    InvalidParameterError, OutputPathError
        The folder holds anything else, is an input or holds one.
    """
    from terrain.core.outputs import check_output_folder

    outdir = Path(outdir)
    for item in inputs:
        if item is not None and Path(item).resolve().is_relative_to(outdir.resolve()):
            raise InvalidParameterError(
                f"output folder '{outdir}' contains the input '{item}'; choose another folder")
    check_output_folder(outdir, inputs)
    if not outdir.exists():
        return outdir
    names = {p.name for p in outdir.iterdir()}
    if INCOMPLETE in names and MANIFEST not in names:
        ours = _stack_files(outdir)
        if WORK in names and WORK not in keep:
            ours.append(outdir / WORK)
        strangers = names - {p.name for p in ours} - set(_LOCKS) - set(keep)
        strangers = {n for n in strangers if not n.endswith(".partial")}
        if strangers:
            raise InvalidParameterError(
                f"output folder '{outdir}' holds an interrupted stack build and other files "
                f"({sorted(strangers)[0]}, ...); give a new folder")
        log.warning("removing the interrupted stack build in %s", outdir)
        for p in ours:
            remove_path(p)
        from terrain.core.outputs import sweep_partials

        sweep_partials(outdir)
        names = {p.name for p in outdir.iterdir()}
    if names - set(_LOCKS) - set(keep):
        raise InvalidParameterError(
            f"output folder '{outdir}' is not empty; give a new folder (layer stacks are "
            "edited with replace-crater, never overwritten)")
    return outdir


def _stack_files(outdir: Path) -> list[Path]:
    return sorted({p for pattern in _STACK_FILE_PATTERNS for p in outdir.glob(pattern)})


def write_stack(stack: LayerStack, outdir, *, inputs=(), known=None) -> Path:
    """Write a new layer stack into ``outdir`` (created; see :func:`prepare_folder`).

    The manifest is written last; if writing fails (full disk, interrupt) the files already
    written are removed again, and a killed build is cleared by the next one.

    Parameters
    ----------
    stack : LayerStack
    outdir : path
        A missing, empty or killed build's folder.
    inputs : iterable of path
        Files the stack was made from (never written over, never inside ``outdir``).
    known : (ny, nx) float64, metres, optional
        The base's exact heights when float32 cannot hold them
        (:func:`terrain.io.read_dem_exact`): every layer holding them unchanged is written in
        float64 with them put back bitwise.

    Returns
    -------
    Path
        ``outdir``: ``manifest.json``, ``layer_NN.tif`` and ``craters.csv`` (and
        ``rocks.csv`` with rocks).
    """
    check_keys(stack.info, MANIFEST_KEYS, "layer-stack manifest")  # before anything is made
    outdir = prepare_folder(outdir, inputs=inputs)
    if outdir.exists() and not outdir.is_dir():
        raise InvalidParameterError(f"output '{outdir}' exists and is not a folder")
    created = not outdir.exists()
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        from terrain.core.outputs import cannot_write

        raise cannot_write(outdir, exc) from exc
    ok = False
    try:
        with stack_lock(outdir):
            from terrain.core.outputs import atomic_path

            if (outdir / MANIFEST).exists():  # another build finished here meanwhile
                ok = True  # it is that build's stack: leave it alone
                raise InvalidParameterError(
                    f"output folder '{outdir}' received a stack from another command "
                    "meanwhile; give a new folder")
            with atomic_path(outdir / INCOMPLETE) as tmp:
                tmp.write_text("a craterscape layer stack is being written here\n",
                               encoding="utf-8")
            (outdir / READERS_LOCK).touch()  # so that readers never create a file here
            files = [f"layer_{k:02d}.tif" for k in range(len(stack.tiles))]
            _write_files(stack, outdir, files, known=known)
            (outdir / INCOMPLETE).unlink()
        ok = True
    finally:
        if not ok:
            for p in [*_stack_files(outdir), outdir / INCOMPLETE, outdir / MANIFEST,
                      outdir / LOCK, outdir / READERS_LOCK]:
                with contextlib.suppress(OSError):
                    p.unlink()
            if created:
                with contextlib.suppress(OSError):
                    outdir.rmdir()
    return outdir


def _write_files(stack: LayerStack, outdir: Path, files: list[str], only=None,
                 catalog: str = CATALOG, rocks: bool = False, known=None) -> None:
    """Write the layers (``only`` some), the catalogues, then the manifest: the commit point.

    An edit (``only``) writes the rock catalogue when ``rocks`` (under the manifest's name).
    ``known``: the base's exact heights (see :func:`write_stack`).
    """
    from terrain.core.outputs import atomic_path
    from terrain.fractal.expand import expanded_known
    from terrain.io import write_dem

    for k, tile in enumerate(stack.tiles):
        if only is not None and k not in only:
            continue
        meta = dict(tile.metadata)
        meta[mk.LAYER] = str(k)
        exact = None
        if known is not None:
            exact = expanded_known(known, tile.shape, k, stack.origins[k], tile.heights)
        write_dem(tile.replace(metadata=meta), outdir / files[k], known=exact)
    with atomic_path(outdir / catalog) as tmp:
        stack.catalog.to_csv(tmp)
    if stack.rocks is not None and (only is None or rocks):
        with atomic_path(outdir / stack.info.get("rock_catalog", ROCK_CATALOG)) as tmp:
            stack.rocks.to_csv(tmp)
    manifest = stack_manifest(stack, files)
    manifest["catalog"] = catalog
    with atomic_path(outdir / MANIFEST) as tmp:
        tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True), encoding="utf-8")


@contextlib.contextmanager
def stack_lock(outdir, timeout: float = LOCK_TIMEOUT):
    """Hold the exclusive edit lock of a layer-stack folder.

    Parameters
    ----------
    outdir : path
        The stack's folder.
    timeout : float, seconds
        How long to wait for another edit to finish.

    Yields
    ------
    None
        While the lock is held.

    Raises
    ------
    InvalidParameterError
        Another edit held the lock for ``timeout`` seconds.
    """
    path = Path(outdir) / LOCK
    fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
    try:
        deadline = time.monotonic() + timeout
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise InvalidParameterError(
                        f"layer stack '{outdir}' is being edited by another command; try again "
                        "when it has finished") from None
                time.sleep(0.1)
        yield
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


@contextlib.contextmanager
def _readers_lock(outdir: Path, *, exclusive: bool = False, timeout: float = READERS_TIMEOUT):
    """Shared (readers) or exclusive (an edit deleting old files) lock; yields whether held.

    The folder itself is a turnstile: a reader passes it (a brief exclusive ``flock`` on the
    folder) before taking its shared lock, and an edit holds it while it waits for the
    readers already inside, so a stream of readers cannot starve an edit. A stack in a
    folder nobody may write (a read-only copy) cannot be edited either, so readers there go
    without the lock.
    """
    path = outdir / READERS_LOCK
    try:
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
    except OSError:
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            yield False
            return
    try:
        gate = os.open(outdir, os.O_RDONLY)
    except OSError:
        gate = None
    try:
        held = False
        if gate is not None:
            fcntl.flock(gate, fcntl.LOCK_EX)
        try:
            if exclusive:
                deadline = time.monotonic() + timeout
                while True:
                    try:
                        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        held = True
                        break
                    except BlockingIOError:
                        if time.monotonic() > deadline:
                            break
                        time.sleep(0.005)
            else:
                fcntl.flock(fd, fcntl.LOCK_SH)
                held = True
        finally:
            if gate is not None and not exclusive:
                fcntl.flock(gate, fcntl.LOCK_UN)
        yield held
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
        if gate is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(gate, fcntl.LOCK_UN)
            os.close(gate)


def read_stack(outdir) -> LayerStack:
    """Read a layer stack written by :func:`write_stack`: the files its manifest names.

    Holds the readers' lock while reading, so an edit running at the same time never
    deletes a file this read still needs (see the module docstring).

    Parameters
    ----------
    outdir : path
        The stack's folder.

    Returns
    -------
    LayerStack
        Its layers (each with its file name), crater catalogue, provenance and rocks.

    Raises
    ------
    InvalidDEMError
        The folder has no stack, its manifest is corrupt or names files outside the folder,
        or a layer's size disagrees with the manifest.
    """
    outdir = Path(outdir)
    if not (outdir / MANIFEST).exists():
        if (outdir / INCOMPLETE).exists():
            raise InvalidDEMError(f"'{outdir}' holds an interrupted stack build (no "
                                  f"{MANIFEST}); build it again into the same folder")
        raise MissingInputError(f"'{outdir}' is not a layer stack: {MANIFEST} is missing")
    with _readers_lock(outdir):
        return _read_stack(outdir)


def _read_stack(outdir: Path) -> LayerStack:
    from terrain.io import read_dem

    mpath = outdir / MANIFEST
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
        if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
            raise ValueError("not a craterscape layer stack")
        check_keys(manifest, MANIFEST_KEYS, "layer-stack manifest")
        layers = manifest["layers"]
        for entry in layers:
            check_keys(entry, LAYER_KEYS, "layer-stack manifest layer")
        files = [entry["file"] for entry in layers]
        windows = [None if e["window_in_parent"] is None else tuple(e["window_in_parent"])
                   for e in layers]
        origins = [tuple(e["origin"]) for e in layers]
    except (ValueError, KeyError, TypeError, AttributeError, UnicodeDecodeError) as exc:
        raise InvalidDEMError(f"manifest '{mpath}' is corrupt: {exc}") from None
    for name in files:
        if Path(name).name != name:
            raise InvalidDEMError(f"manifest '{mpath}' names a file outside the stack: {name}")
    cat_name = manifest.get("catalog", CATALOG)
    cat_bad = not isinstance(cat_name, str) or Path(cat_name).name != cat_name
    info = {k: v for k, v in manifest.items()
            if k not in ("layers", "format", "version", "crs", "catalog", "crater_counts")}
    rock_name = info.get("rock_catalog", ROCK_CATALOG)
    rock_bad = not isinstance(rock_name, str) or Path(rock_name).name != rock_name
    # the catalogues parsed and the layers decoded side by side (GDAL releases the
    # interpreter while it decodes); the failures are raised in the order the checks below
    # make them, the first layer's in the manifest's order first
    with ThreadPoolExecutor(max_workers=max(1, min(threads(), len(files)))) as pool:
        cat_path = None if cat_bad else outdir / cat_name
        cat_future = (pool.submit(CraterCatalog.from_csv, cat_path)
                      if cat_path is not None and cat_path.exists() else None)
        rock_path = None if rock_bad else outdir / rock_name
        rock_future = (pool.submit(RockCatalog.from_csv, rock_path)
                       if rock_path is not None and "rock_catalog" in info
                       and rock_path.exists() else None)
        futures = [pool.submit(read_dem, outdir / name) for name in files]
    tiles = []
    for k, (name, future) in enumerate(zip(files, futures, strict=True)):
        tile = future.result()
        expected = layers[k]
        if tile.shape != (expected["height"], expected["width"]):
            raise InvalidDEMError(
                f"layer file '{name}' is {tile.shape[1]}x{tile.shape[0]}; the manifest says "
                f"{expected['width']}x{expected['height']}")
        tiles.append(tile)
    if cat_bad:
        raise InvalidDEMError(f"manifest '{mpath}' names a catalogue outside the stack: "
                              f"{cat_name!r}")
    catalog = cat_future.result() if cat_future is not None else merge_catalogs([])
    if rock_bad:
        raise InvalidDEMError(f"manifest '{mpath}' names a rock catalogue outside the stack: "
                              f"{rock_name!r}")
    rocks = rock_future.result() if rock_future is not None else None
    return LayerStack(layer_records(tiles, windows, origins, files), catalog, info, rocks,
                      catalog_file=cat_name)


def commit_edit(stack: LayerStack, outdir: Path, changed: set, *,
            rocks_changed: bool = False) -> None:
    """Write the changed layers and the catalogues under new names, then swap the manifest in.

    The manifest's swap is the commit point; the old versions are deleted once no reader
    holds them.
    """
    if any(layer.file is None for layer in stack.layers):
        raise InvalidParameterError("only a stack read from its folder can be edited in place")
    files = [str(layer.file) for layer in stack.layers]
    old_files = list(files)
    old_catalog = stack.catalog_file
    stamp = f"{time.time_ns():x}"
    for k in changed:
        files[k] = f"layer_{k:02d}.{stamp}.tif"
    catalog = f"craters.{stamp}.csv"
    old = []
    if rocks_changed:
        old.append(stack.info.get("rock_catalog", ROCK_CATALOG))
        stack = replace(stack, info={**stack.info, "rock_catalog": f"rocks.{stamp}.csv"})
    _write_files(stack, outdir, files, only=changed, catalog=catalog, rocks=rocks_changed)
    old += [name for k, name in enumerate(old_files) if name != files[k]] + [old_catalog]
    with _readers_lock(outdir, exclusive=True) as held:
        if not held:
            log.warning("readers still hold %s; its old files go at the next edit", outdir)
            return
        for name in old:
            remove_path(outdir / name)


def sweep_edits(outdir: Path) -> None:
    """Remove files no manifest names (left by a killed edit) and dead temporaries.

    Called with the edit lock held; waits for readers, who may still read older files.
    """
    from terrain.core.outputs import sweep_partials

    sweep_partials(outdir)
    mpath = outdir / MANIFEST
    try:
        manifest = json.loads(mpath.read_text(encoding="utf-8"))
        named = {e["file"] for e in manifest["layers"]} | {manifest.get("catalog", CATALOG),
                                                            manifest.get("rock_catalog")}
    except (OSError, ValueError, KeyError, TypeError):
        return  # read_stack reports what is wrong
    orphans = [p for p in _stack_files(outdir) if p.name not in named]
    if not orphans:
        return
    with _readers_lock(outdir, exclusive=True) as held:
        if not held:
            return
        for p in orphans:
            remove_path(p)
    log.info("removed %d file(s) of an interrupted edit from %s", len(orphans), outdir)
