"""One runner for every terrain stage: ``run(spec, inputs, output, execution)``.

:func:`run` alone decides how a stage's work is done: in memory; chunk by chunk on Dask
(:mod:`terrain.execution.chunked`) when the execution asks for it (a Zarr output, workers, a
scheduler or a chunk size); or out of core, chunk by chunk through a scratch Zarr store, when
the request does not fit in memory. A Python caller and the ``craterscape`` command line get
the same bytes, because the command line is nothing but options -> spec -> :func:`run`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import shutil
from collections.abc import Callable, Iterable, Sequence
from contextlib import AbstractContextManager as ContextManager
from os import PathLike
from pathlib import Path
from typing import Any

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import protected
from terrain.core.progress import Progress
from terrain.stages.fields import FLAG, OUTPUT_PATH, Spec, integer, option, text

__all__ = ["Execution", "ProgressFactory", "Written", "run"]

log = logging.getLogger(__name__)

#: ``factory(label, unit)`` -> a context giving a progress callback or None (the command line
#: passes :func:`terrain.cli.tools.progress_bar`).
ProgressFactory = Callable[[str, str], ContextManager[Progress | None]]
#: Bytes per pixel of a whole-DEM in-memory operation's working copies.
WORKING_BYTES_PER_PIXEL = 40.0


@dataclasses.dataclass(frozen=True, kw_only=True)
class Execution(Spec):
    """How a stage runs (never what it computes: the bytes are the same every way).

    The default runs in this process, in memory, or out of core when the request does not
    fit in memory; a count of workers, a scheduler, a chunk size or a COG asks for a chunked
    run on Dask into a Zarr store.

    >>> Execution.from_mapping({"workers": 2}).chunked
    True
    """

    STAGE = "execution"
    workers: int | None = option(None, "Run chunk by chunk on a local Dask pool of N workers.",
                                 integer(low=1))
    threads: bool = option(False, "Local workers are threads of this process instead of "
                           "processes.", FLAG)
    scheduler: str | None = option(None, "Run chunk by chunk on the Dask cluster at this "
                                   "address (tcp://HOST:PORT).", text())
    chunk: int | None = option(None, "Chunk side in pixels (default 2049); implies a chunked "
                               "run.", integer(low=16))
    cog: Path | None = option(None, "After a chunked run, also convert the Zarr output into "
                              "this Cloud Optimized GeoTIFF.", OUTPUT_PATH)

    @property
    def chunked(self) -> bool:
        """Whether a chunked run is asked for (a workers count, scheduler, chunk or COG)."""
        return any(v is not None for v in (self.workers, self.scheduler, self.chunk, self.cog))


@dataclasses.dataclass(frozen=True)
class Written:
    """What a stage wrote: its files and folders, and a line for people."""

    paths: tuple[Path, ...]
    message: str


def run(spec: Spec, inputs: str | PathLike | Sequence[str | PathLike] | None,
        output: str | PathLike, execution: Execution | None = None, *,
        catalog: str | PathLike | None = None,
        progress: ProgressFactory | None = None) -> Written:
    """Run one terrain stage: in memory, chunked on Dask or out of core, as the request needs.

    Parameters
    ----------
    spec : Spec
        The stage and its parameters (:mod:`terrain.stages.specs`).
    inputs : path, sequence of paths or None
        The stage's input DEM, Zarr store or layer-stack folder (None for ``synth``).
    output : path
        What it writes: a GeoTIFF, a Zarr store (``NAME.zarr``: a chunked run, resumed if it
        exists), a PNG (``hillshade``) or a stack folder (``enhance``). Written atomically,
        never over an input.
    execution : Execution, optional
        How to run it; by default in this process, out of core if it does not fit in memory.
    catalog : path, optional
        Write the crater or rock catalogue (CSV) here (synth, craters, add-crater, rocks).
    progress : callable, optional
        ``progress(label, unit)`` -> context giving a progress callback (none by default).

    Returns
    -------
    Written
        The paths written and a one-line summary.

    Raises
    ------
    terrain.core.errors.CraterscapeError
        Bad input, named; nothing is left half-written.
    """
    from terrain.stages import dems, enhance, specs, surface

    stages: dict[type, Callable[..., Written]] = {
        specs.SynthSpec: dems.synth, specs.CratersSpec: dems.craters,
        specs.AddCraterSpec: dems.add_crater, specs.ExpandSpec: dems.expand,
        specs.FillSpec: dems.fill, specs.HillshadeSpec: dems.hillshade,
        specs.EnhanceSpec: enhance.enhance, specs.RocksSpec: surface.rocks,
        specs.HazardsSpec: surface.hazards}
    work = stages.get(type(spec))
    if work is None:
        raise InvalidParameterError(f"run takes a terrain stage spec; got {type(spec).__name__}")
    if inputs is None:
        inputs = []
    elif isinstance(inputs, (str, PathLike)):
        inputs = [inputs]
    paths = [Path(p) for p in inputs]
    if len(paths) != (0 if isinstance(spec, specs.SynthSpec) else 1):
        wanted = "no" if isinstance(spec, specs.SynthSpec) else "one"
        raise InvalidParameterError(f"terrain {spec.STAGE} takes {wanted} input; got {paths}")
    if catalog is not None and not isinstance(spec, (specs.SynthSpec, specs.CratersSpec,
                                                     specs.AddCraterSpec, specs.RocksSpec)):
        raise InvalidParameterError(f"terrain {spec.STAGE} writes no separate catalogue")
    with protected([*paths, *spec.reads()]):
        return work(spec, paths[0] if paths else None, Path(output), execution or Execution(),
                    catalog=None if catalog is None else Path(catalog),
                    progress=progress or _silent)


def _silent(label: str, unit: str) -> ContextManager[Progress | None]:
    return contextlib.nullcontext(None)


# ------------------------------------------------------------------ the choice of execution


def chunked_requested(output: Path, execution: Execution, window=None) -> bool:
    """Whether this run goes chunk by chunk on Dask (a Zarr output or a chunked execution)."""
    from terrain.core.zarrstore import is_zarr

    if not (is_zarr(output) or execution.chunked):
        return False
    if not is_zarr(output):
        raise InvalidParameterError(
            f"a chunked run (--workers, --scheduler, --chunk, --cog) writes a Zarr store: give "
            f"-o NAME.zarr, not '{output}' (and --cog FILE.tif for a GeoTIFF)")
    if window is not None:
        raise InvalidParameterError("--window computes one window in memory; drop it for a "
                                    "chunked run (or compute the window without --chunk)")
    return True


def fits_in_memory(nbytes: float) -> bool:
    """Whether ``nbytes`` fit in the memory available now (:mod:`terrain.core.memory`)."""
    return nbytes <= memory.available_bytes()


def input_fits(path: Path, band: int) -> bool:
    """Whether an input DEM and a whole-DEM operation's working copies fit in memory."""
    from terrain.core.zarrstore import ZarrDEM, is_zarr
    from terrain.io import RasterReader

    if path.is_dir() and is_zarr(path):
        ny, nx = ZarrDEM(path).shape
    else:
        ny, nx = RasterReader(path, band).shape
    return fits_in_memory(ny * nx * WORKING_BYTES_PER_PIXEL)


def run_chunked(source: Any, output: Path, execution: Execution, label: str, *,
                progress: ProgressFactory, catalog: Path | None = None,
                inputs: Iterable[Path] = (), cog: Path | None = None) -> Written:
    """Run ``source`` chunk by chunk into the Zarr store ``output`` (resumed if it exists)."""
    from terrain.core.outputs import atomic_path
    from terrain.core.zarrstore import ZarrDEM
    from terrain.execution.chunked import DEFAULT_CHUNK, dask_client
    from terrain.execution.chunked import run as run_chunks
    from terrain.io import check_output_path, write_cog

    inputs = [p for p in inputs if p is not None]
    for item in inputs:
        if Path(output).resolve() == Path(item).resolve():
            raise InvalidParameterError(f"output '{output}' is the same as input '{item}'")
    for companion in (cog, catalog):
        if companion is not None:
            check_output_path(companion, [*inputs, output])
    with progress(label, "chunk") as update:
        with dask_client(execution.workers, execution.scheduler,
                         processes=not execution.threads) as client:
            report = run_chunks(source, output, chunk=execution.chunk or DEFAULT_CHUNK,
                                client=client, progress=update,
                                metadata={mk.COMMAND: f"terrain {label}",
                                          mk.VERSION: mk.version()})
    rate = report.pixels_per_second
    lines = [f"wrote {output} ({source.shape[1]}x{source.shape[0]}; {report.computed} of "
             f"{report.total} chunks computed, {report.skipped} already written"
             + (f"; {rate / 1e6:.3g} Mpixel/s" if report.computed else "") + ")"]
    written = [output]
    if catalog is not None and report.catalog is not None:
        with atomic_path(catalog, [*inputs, output]) as tmp:
            report.catalog.to_csv(tmp)
        lines.append(f"wrote {catalog} ({len(report.catalog)} craters)")
        written.append(catalog)
    if cog is not None:
        write_cog(ZarrDEM(output), cog, inputs=[*inputs, output])
        lines.append(f"wrote {cog} (Cloud Optimized GeoTIFF)")
        written.append(cog)
    return Written(tuple(written), "\n".join(lines))


def run_dask(source: Any, output: Path, execution: Execution, label: str, *,
             progress: ProgressFactory, catalog: Path | None = None,
             inputs: Iterable[Path] = ()) -> Written:
    """Run ``source`` chunked into a Zarr ``output`` when asked, else out of core."""
    if chunked_requested(output, execution):
        return run_chunked(source, output, execution, label, progress=progress,
                           catalog=catalog, inputs=inputs, cog=execution.cog)
    return run_out_of_core(source, output, execution, label, progress=progress,
                           catalog=catalog, inputs=inputs)


def run_out_of_core(source: Any, output: Path, execution: Execution, label: str, *,
                    progress: ProgressFactory, catalog: Path | None = None,
                    inputs: Iterable[Path] = ()) -> Written:
    """Run a request larger than memory chunk by chunk, instead of refusing it.

    The chunks go to a scratch Zarr store beside the output (resumed by a rerun of the same
    request, removed once the output is written); the output GeoTIFF is written from it as a
    COG.
    """
    from terrain.io import check_output_path

    inputs = [p for p in inputs if p is not None]
    check_output_path(output, inputs)
    parent = output.parent if str(output.parent) else Path(".")
    ny, nx = source.shape
    need = ny * nx * 4 * (1 + 2.7)  # the Zarr store, then the COG and its scratch copy
    free = shutil.disk_usage(parent).free
    if need > free:
        avail = memory.format_bytes(memory.available_bytes())
        raise InvalidParameterError(
            f"{label}: {nx}x{ny} pixels do not fit in memory ({avail} available) and "
            "running them out of core needs "
            f"about {memory.format_bytes(need)} of disk in '{parent}', but only "
            f"{memory.format_bytes(free)} is free")
    from terrain.execution.chunked import DEFAULT_CHUNK, scratch_store

    with scratch_store(source, output, execution.chunk) as (scratch, chunk):
        if chunk is None:  # a chunk (with its halo) per worker well inside the memory there is
            halo = getattr(source, "halo", 0)
            share = memory.available_bytes() / (execution.workers or 1) / 4
            chunk = DEFAULT_CHUNK
            while chunk > 64 and (chunk + 2 * halo) ** 2 * 64 > share:
                chunk = (chunk - 1) // 2 + 1  # 2^k + 1 stays 2^(k-1) + 1 (DEFAULT_CHUNK)
        log.warning("%s: %dx%d pixels do not fit in memory; running chunk by chunk through "
                    "%s", label, nx, ny, scratch)
        done = run_chunked(source, scratch, dataclasses.replace(execution, chunk=chunk), label,
                           progress=progress, catalog=catalog, inputs=inputs, cog=output)
    written = (output, catalog) if catalog is not None else (output,)
    return Written(written, done.message)
