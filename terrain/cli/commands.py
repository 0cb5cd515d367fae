"""The ``craterscape`` command and its ``terrain`` group.

The root command lives in the lowest layer and discovers the stage groups through the
``craterscape.groups`` entry points, so ``terrain`` never imports a higher package (rasterio's
``rio`` registers its subcommands the same way). Errors that craterscape raises on purpose
become one line on stderr and exit code 2; ``-v`` shows the traceback.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import signal
import sys
import traceback
from importlib.metadata import entry_points
from pathlib import Path

import click

from terrain.cli.tools import (
    FINITE,
    PAIR,
    WINDOW,
    progress_bar,
    version,
    version_option,
    with_options,
)
from terrain.core import metakeys as mk
from terrain.core.errors import CraterscapeError, InvalidParameterError
from terrain.core.outputs import (
    cannot_write,
    is_write_error,
    protected,
    remove_temporaries,
    transaction,
)

__all__ = ["main", "terrain"]

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "craterscape.groups"
EXIT_BAD_INPUT = 2
#: Exit code after SIGTERM (128 + 15, as a shell reports it).
EXIT_TERMINATED = 143
#: Largest tile relief (m): ten times Olympus Mons, far inside float32 heights.
MAX_RELIEF = 2.0e5
#: Largest crater add-crater takes, in DEM diagonals (its rim still reaches the DEM).
MAX_CRATER_TO_DEM = 100.0
#: Largest hillshade vertical exaggeration.
MAX_Z_FACTOR = 1.0e6
#: Path parameters that name what a command writes; every other path parameter is an input
#: that no output may replace or enter (:func:`terrain.core.outputs.protect`).
OUTPUT_PARAMS = frozenset({"output", "catalog", "cog"})
#: Path parameters a command edits in place (protected from nothing but themselves).
IN_PLACE_PARAMS = frozenset({"stack_dir"})


class Terminated(BaseException):
    """SIGTERM arrived: unwind like Ctrl-C so partial files are removed."""


def _on_sigterm(signum, frame):
    raise Terminated()


def _harden(command):
    """Make a command's float options refuse NaN and infinity, and protect its inputs.

    Every float option of the command (and its subcommands) refuses NaN and infinity, and its
    input paths are registered with :func:`terrain.core.outputs.protect` when it runs. Applied to
    every command the root loads, so new commands get it without doing anything.
    """
    if getattr(command, "_craterscape_hardened", False):
        return command
    command._craterscape_hardened = True
    for param in command.params:
        if type(param.type) is click.types.FloatParamType:
            param.type = FINITE
    if isinstance(command, click.Group):
        for sub in command.commands.values():
            _harden(sub)
        return command
    callback = command.callback
    if callback is None:  # pragma: no cover
        return command
    path_params = [p.name for p in command.params if isinstance(p.type, click.Path)
                   and p.name not in OUTPUT_PARAMS and p.name not in IN_PLACE_PARAMS]

    def guarded(*args, **kwargs):
        inputs = []
        for name in path_params:
            value = kwargs.get(name)
            if isinstance(value, (list, tuple)):
                inputs += [v for v in value if v is not None]
            elif value is not None:
                inputs.append(value)
        with protected(inputs):
            return callback(*args, **kwargs)

    command.callback = guarded
    return command


class _Root(click.Group):
    """Loads stage groups from entry points and turns errors into one line."""

    def list_commands(self, ctx):
        names = {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)}
        return sorted(names | set(self.commands))

    def get_command(self, ctx, name):
        if name in self.commands:
            return _harden(self.commands[name])
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            if ep.name == name:
                try:
                    return _harden(ep.load())
                except Exception as exc:  # a broken stage must not take the others down
                    return _broken_group(name, exc)
        return None

    def invoke(self, ctx):
        previous = None
        with contextlib.suppress(ValueError):  # only the main thread may set handlers
            previous = signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            return super().invoke(ctx)
        except click.UsageError as exc:  # bad options: the same one line as any bad input
            _fail(ctx, click.ClickException(exc.format_message()), EXIT_BAD_INPUT)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except CraterscapeError as exc:
            _fail(ctx, exc, EXIT_BAD_INPUT)
        except KeyboardInterrupt:
            remove_temporaries()
            click.echo("craterscape: interrupted", err=True)
            ctx.exit(130)
        except Terminated:
            remove_temporaries()
            click.echo("craterscape: terminated", err=True)
            ctx.exit(EXIT_TERMINATED)
        except OSError as exc:
            if is_write_error(exc):  # one code and one message for "cannot write here"
                _fail(ctx, cannot_write(None, exc), EXIT_BAD_INPUT)
            _fail(ctx, exc, 1)
        except ArithmeticError as exc:  # an unchecked number overflowed: still bad input
            _fail(ctx, InvalidParameterError(
                f"a number is out of range ({type(exc).__name__}: {exc}); check the values "
                "given (-v shows where)"), EXIT_BAD_INPUT)
        except MemoryError as exc:
            _fail(ctx, exc, 1)
        finally:
            if previous is not None:
                with contextlib.suppress(ValueError):
                    signal.signal(signal.SIGTERM, previous)


def _broken_group(name, exc):
    reason = f"{type(exc).__name__}: {exc}"

    @click.command(name=name, help=f"(unavailable: {reason})", context_settings={
        "ignore_unknown_options": True, "allow_extra_args": True})
    def broken():
        raise CraterscapeError(f"the '{name}' commands cannot load ({reason}); reinstall "
                               "craterscape with `make setup`")

    return broken


def _fail(ctx, exc, code):
    verbose = (ctx.obj or {}).get("verbosity", 0) > 0
    if verbose:
        traceback.print_exception(exc, file=sys.stderr)
    text = exc.format_message() if isinstance(exc, click.ClickException) else str(exc)
    message = text.strip().splitlines()[0] if text.strip() else type(exc).__name__
    click.echo(f"craterscape: error: {message}", err=True)
    ctx.exit(code)


@click.group(cls=_Root, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output; tracebacks on errors.")
@click.option("-q", "--quiet", count=True, help="Less log output.")
@version_option
@click.pass_context
def main(ctx, verbose, quiet):
    """craterscape: virtual planets for testing spacecraft landers."""
    ctx.ensure_object(dict)
    ctx.obj["verbosity"] = verbose - quiet
    level = {-2: logging.ERROR, -1: logging.WARNING, 0: logging.WARNING, 1: logging.INFO}.get(
        max(-2, min(verbose - quiet, 2)), logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s", force=True)


# --------------------------------------------------------------------------------------
# shared option helpers


_output_option = click.option(
    "-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
    help="Output GeoTIFF (written atomically; never over an input).")
_store_output_option = click.option(
    "-o", "--output", required=True, type=click.Path(path_type=Path),
    help="Output GeoTIFF (written atomically; never over an input), or a Zarr store "
         "(NAME.zarr: a chunked run, resumed if it exists).")
_seed_option = click.option("--seed", type=click.IntRange(0, 2**63 - 1), default=0,
                            show_default=True, help="Keys every random draw.")
_window_option = click.option(
    "--window", type=WINDOW, default=None,
    help="Compute only this window (pixels); bitwise equal to the same window of a full run.")


def _crater_options(func):
    options = [
        click.option("--dmin", type=float, default=None,
                     help="Smallest crater diameter (m). Default: 3 pixels."),
        click.option("--dmax", type=float, default=None,
                     help="Largest crater diameter (m). Default: a quarter of the DEM's extent."),
        click.option("--density", type=float, default=None,
                     help="Craters with D >= dmin per km^2."),
        click.option("--sfd-exponent", type=float, default=None,
                     help="k of N_cum = c D^k (default -2; -1.8 for mare)."),
        click.option("--max-age", type=float, default=None,
                     help="Oldest crater age in Gyr; ages are uniform below it (default 3.5)."),
        click.option("--population", type=click.Path(dir_okay=False, path_type=Path),
                     default=None, help="TOML file with a [population] table (flags override)."),
        click.option("--catalog", type=click.Path(dir_okay=False, path_type=Path), default=None,
                     help="Write the crater catalogue (CSV) here."),
        click.option("--erosion-profile", type=click.Path(dir_okay=False, path_type=Path),
                     default=None,
                     help="CSV baseline degradation profile (baseline_age_gyr, depth_fraction, "
                          "rim_fraction)."),
        click.option("--erosion-exponent", type=float, default=None,
                     help="P of the Ross/Soderblom scaling T_b = T_x (D_b/D_x)^P (default 1.1)."),
        click.option("--no-roughness", is_flag=True,
                     help="Switch off the crater fractal overlay and the irregular rim."),
        *_morphology_options,
    ]
    return with_options(options)(func)


def _model(erosion_profile, erosion_exponent, no_roughness):
    from terrain.craters.crater import (
        DEFAULT_PEAK_RING_DIAMETER,
        DEFAULT_TRANSITION_DIAMETER,
        Morphology,
    )
    from terrain.craters.cratering import CraterModel
    from terrain.craters.erosion import ErosionModel, SlopeDegradation

    kwargs = {} if erosion_exponent is None else {"exponent": erosion_exponent}
    if erosion_profile is not None:
        erosion = ErosionModel.from_csv(erosion_profile, **kwargs)
    else:
        erosion = ErosionModel.default(**kwargs)
    # the complex-crater and slope options (_morphology_options) travel in the context
    meta = click.get_current_context().meta
    transition = meta.get("transition_diameter")
    transition = DEFAULT_TRANSITION_DIAMETER if transition is None else transition
    morphology = Morphology(transition, max(DEFAULT_PEAK_RING_DIAMETER, 2.0 * transition),
                            enabled=not meta.get("simple_craters_only", False))
    slope = SlopeDegradation(enabled=not meta.get("no_slope_degradation", False))
    model = CraterModel(erosion=erosion, morphology=morphology, slope=slope)
    return model.smooth() if no_roughness else model


def _to_meta(ctx, param, value):
    ctx.meta[param.name] = value
    return value


#: Complex craters and slope-dependent degradation (read by :func:`_model` from the context,
#: so that every crater command takes them without changing its signature).
_morphology_options = [
    click.option("--transition-diameter", type=click.FloatRange(min=0.0, min_open=True),
                 default=None, expose_value=False, callback=_to_meta,
                 help="Craters wider than this (m) are complex: flat floor, terraced walls, "
                      "central peak (default 15000, the lunar value; it scales as 1/g)."),
    click.option("--simple-craters-only", is_flag=True, expose_value=False, callback=_to_meta,
                 help="Make every crater simple, whatever its size."),
    click.option("--no-slope-degradation", is_flag=True, expose_value=False,
                 callback=_to_meta,
                 help="Age craters on steep ground at the flat-ground rate."),
]


def _population(population_file, *, dmin, dmax, density, sfd_exponent, max_age, resolution,
                extent, required, warn_small=True):
    from terrain.craters.population import Population

    if population_file is None and density is None:
        if required:
            raise InvalidParameterError("give --density (craters per km^2) or --population FILE")
        return None
    overrides = dict(dmin=dmin, dmax=dmax, density=density, sfd_exponent=sfd_exponent,
                     max_age=max_age)
    defaults = dict(dmin=3.0 * resolution, dmax=extent / 4.0)
    if population_file is not None:
        pop = Population.from_toml(population_file, defaults=defaults, **overrides)
    else:
        values = dict(defaults)
        values.update({k: v for k, v in overrides.items() if v is not None})
        pop = Population(**values)
    if warn_small and pop.dmin < 2.0 * resolution:
        log.warning("dmin %.3g m is below two pixels (%.3g m): such craters are aliased",
                    pop.dmin, 2.0 * resolution)
    return pop


def _write_outputs(result, output, catalog, inputs, command, params):
    """Write the DEM and its catalogue, committed together (:func:`~.outputs.transaction`)."""
    from terrain.io import atomic_path, write_dem

    tile = result.tile.with_metadata(**{mk.COMMAND: command,
                                     mk.PARAMETERS: params,
                                     mk.VERSION: version()})
    with transaction(folders={Path(output).parent}):
        write_dem(tile, output, inputs=inputs)
        if catalog is not None:
            with atomic_path(catalog, [*inputs, output]) as tmp:
                result.catalog.to_csv(tmp)
    if catalog is not None:
        click.echo(f"wrote {output} and {catalog} ({len(result.catalog)} craters)",
                   err=True)
    else:
        click.echo(f"wrote {output}", err=True)


def _check_outputs(output, catalog, inputs):
    from terrain.io import DEM_SUFFIXES, check_output_path

    check_output_path(output, inputs, suffixes=DEM_SUFFIXES, what="GeoTIFF")
    if catalog is not None:
        check_output_path(catalog, [*inputs, output], suffixes=(".csv",), what="CSV")
        if Path(catalog).resolve() == Path(output).resolve():
            raise InvalidParameterError("--catalog must differ from --output")


# --------------------------------------------------------------------------------------
# chunked runs on Dask (terrain.execution.chunked): --workers, --scheduler, --chunk, --cog


def _chunk_options(lead: str, run: str, pool_note: str = "") -> list:
    """Return --workers, --threads, --scheduler and --chunk, which every chunked command takes.

    ``lead`` starts the help of --workers and --scheduler ("Run", "Build the stack"), ``run``
    names what --chunk implies ("run", "build"), ``pool_note`` ends --workers' help.
    """
    return [
        click.option("--workers", type=click.IntRange(1, None), default=None,
                     help=f"{lead} chunk by chunk on a local Dask pool of N workers{pool_note}."),
        click.option("--threads", is_flag=True,
                     help="Local workers are threads of this process instead of processes."),
        click.option("--scheduler", default=None, metavar="tcp://HOST:PORT",
                     help=f"{lead} chunk by chunk on the Dask cluster at this address."),
        click.option("--chunk", type=click.IntRange(16, None), default=None,
                     help=f"Chunk side in pixels (default 1024); implies a chunked {run}."),
    ]


_dask_options = with_options([
    *_chunk_options("Run", "run", " (writes Zarr)"),
    click.option("--cog", type=click.Path(dir_okay=False, path_type=Path), default=None,
                 help="After a chunked run, also convert the Zarr output into this "
                      "Cloud Optimized GeoTIFF."),
])


def _chunked_requested(output, workers, scheduler, chunk, cog, window=None) -> bool:
    from terrain.core.zarrstore import is_zarr

    wanted = is_zarr(output) or any(v is not None for v in (workers, scheduler, chunk, cog))
    if not wanted:
        return False
    if not is_zarr(output):
        raise InvalidParameterError(
            f"a chunked run (--workers, --scheduler, --chunk, --cog) writes a Zarr store: give "
            f"-o NAME.zarr, not '{output}' (and --cog FILE.tif for a GeoTIFF)")
    if window is not None:
        raise InvalidParameterError("--window computes one window in memory; drop it for a "
                                    "chunked run (or compute the window without --chunk)")
    return True


def _run_chunked(source, output, *, workers, threads, scheduler, chunk, cog, label,
                 catalog=None, inputs=()):
    from terrain.core.zarrstore import ZarrDEM
    from terrain.execution.chunked import DEFAULT_CHUNK, dask_client, run
    from terrain.io import atomic_path, check_output_path, write_cog

    for item in inputs:
        if item is not None and Path(output).resolve() == Path(item).resolve():
            raise InvalidParameterError(f"output '{output}' is the same as input '{item}'")
    if cog is not None:
        check_output_path(cog, [*inputs, output])
    if catalog is not None:
        check_output_path(catalog, [*inputs, output])
    with progress_bar(label, "chunk") as update:
        with dask_client(workers, scheduler, processes=not threads) as client:
            report = run(source, output, chunk=chunk or DEFAULT_CHUNK, client=client,
                         progress=update, metadata={mk.COMMAND: f"terrain {label}",
                                                        mk.VERSION: version()})
    rate = report.pixels_per_second
    click.echo(f"wrote {output} ({source.shape[1]}x{source.shape[0]}; {report.computed} of "
               f"{report.total} chunks computed, {report.skipped} already written"
               + (f"; {rate / 1e6:.3g} Mpixel/s" if report.computed else "") + ")", err=True)
    if catalog is not None and report.catalog is not None:
        with atomic_path(catalog, [*inputs, output]) as tmp:
            report.catalog.to_csv(tmp)
        click.echo(f"wrote {catalog} ({len(report.catalog)} craters)", err=True)
    if cog is not None:
        write_cog(ZarrDEM(output), cog, inputs=[*inputs, output])
        click.echo(f"wrote {cog} (Cloud Optimized GeoTIFF)", err=True)
    return report


# --------------------------------------------------------------------------------------
# the terrain group


@click.group()
def terrain():
    """DEM tiles: synthetic terrain, craters, hillshades."""


@terrain.command()
@_store_output_option
@click.option("--size", type=int, default=1025, show_default=True,
              help="Tile side in pixels, 2^n + 1.")
@click.option("--resolution", type=float, default=1.0, show_default=True,
              help="Metres per pixel.")
@click.option("--fractal-dimension", type=float, default=2.2, show_default=True,
              help="RMD fractal dimension F in [2, 3) (eq. 14).")
@click.option("--relief", type=float, default=30.0, show_default=True,
              help="Tile-scale relief R = H * D_r * W of eq. 15 (m): the standard deviation "
                   "of the corner heights.")
@click.option("--body", type=str, default=None,
              help="Body the DEM lies on (moon, mars, mercury): the DEM gets a CRS on its "
                   "sphere, centred on the tile (default: a local frame without CRS).")
@click.option("--crs", "projection", type=str, default=None,
              help="Projection with --body: south-polar (default), north-polar, or "
                   "ortho:LON,LAT (a site-centred orthographic CRS).")
@_seed_option
@_window_option
@_crater_options
@_dask_options
def synth(output, size, resolution, fractal_dimension, relief, body, projection, seed, window,
          dmin, dmax, density, sfd_exponent, max_age, population, catalog, erosion_profile,
          erosion_exponent, no_roughness, workers, threads, scheduler, chunk, cog):
    """Synthesise fractal terrain (RMD diamond-square), optionally cratered."""
    from terrain.core.bodies import check_projection
    from terrain.fractal.rmd import check_fractal_dimension, check_tile_size
    from terrain.fractal.synthetic import synthesize_tile

    check_tile_size(size)
    check_fractal_dimension(fractal_dimension)
    if not resolution > 0:
        raise InvalidParameterError(f"resolution must be positive; got {resolution}")
    if not 0 <= relief <= MAX_RELIEF:
        raise InvalidParameterError(
            f"--relief must lie in [0, {MAX_RELIEF:g}] m (heights are float32 metres); got "
            f"{relief:g}")
    if window is not None:
        window.check_inside(size, size)
    crs = None
    if check_projection(body, projection) is not None:
        from terrain.io import synthetic_crs

        crs = synthetic_crs(body, projection, (size * resolution / 2, size * resolution / 2))
    if not _chunked_requested(output, workers, scheduler, chunk, cog, window):
        _check_outputs(output, catalog, [])
    pop = _population(population, dmin=dmin, dmax=dmax, density=density,
                      sfd_exponent=sfd_exponent, max_age=max_age, resolution=resolution,
                      extent=(size - 1) * resolution, required=False)
    if pop is None and catalog is not None:
        raise InvalidParameterError("--catalog needs craters: give --density or --population")
    model = _model(erosion_profile, erosion_exponent, no_roughness)
    if _chunked_requested(output, workers, scheduler, chunk, cog, window):
        from terrain.execution.chunked import SynthSource

        source = SynthSource(size, resolution, fractal_dimension, relief, seed, pop, model, crs)
        _run_chunked(source, output, workers=workers, threads=threads, scheduler=scheduler,
                     chunk=chunk, cog=cog, label="synth", catalog=catalog)
        return
    if window is None and not _fits_in_memory(size * size * 40.0):
        from terrain.execution.chunked import SynthSource

        source = SynthSource(size, resolution, fractal_dimension, relief, seed, pop, model, crs)
        _run_out_of_core(source, output, workers=workers, threads=threads, scheduler=scheduler,
                         chunk=chunk, label="synth", catalog=catalog)
        return
    with progress_bar("craters", "class") as update:
        result = synthesize_tile(size, resolution=resolution,
                                 fractal_dimension=fractal_dimension, relief=relief, seed=seed,
                                 craters=pop, model=model, window=window, progress=update,
                                 crs=crs)
    params = dict(size=size, resolution=resolution, fractal_dimension=fractal_dimension,
                  relief=relief, seed=seed, population=pop.as_dict() if pop else None,
                  **({"body": body, "crs": projection or "south-polar"} if body else {}),
                  window=None if window is None else
                  [window.col, window.row, window.width, window.height])
    _write_outputs(result, output, catalog, [], "terrain synth", params)


@terrain.command()
@click.argument("input_dem", type=click.Path(path_type=Path))
@_store_output_option
@_seed_option
@_window_option
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
@_crater_options
@_dask_options
def craters(input_dem, output, seed, window, band, dmin, dmax, density, sfd_exponent, max_age,
            population, catalog, erosion_profile, erosion_exponent, no_roughness, workers,
            threads, scheduler, chunk, cog):
    """Add a power-law crater population to a DEM."""
    from terrain.craters.cratering import add_craters
    from terrain.io import read_dem

    if _chunked_requested(output, workers, scheduler, chunk, cog, window):
        from terrain.execution.chunked import CraterSource, open_reader

        reader = open_reader(input_dem, band)
        pop = _population(population, dmin=dmin, dmax=dmax, density=density,
                          sfd_exponent=sfd_exponent, max_age=max_age,
                          resolution=reader.resolution,
                          extent=min(reader.shape) * reader.resolution, required=True)
        source = CraterSource(reader, pop, seed,
                              _model(erosion_profile, erosion_exponent, no_roughness))
        _run_chunked(source, output, workers=workers, threads=threads, scheduler=scheduler,
                     chunk=chunk, cog=cog, label="craters", catalog=catalog,
                     inputs=[input_dem])
        return
    _check_outputs(output, catalog, [input_dem])
    if window is None and not _input_fits(input_dem, band):
        from terrain.execution.chunked import CraterSource, open_reader

        reader = open_reader(input_dem, band)
        pop = _population(population, dmin=dmin, dmax=dmax, density=density,
                          sfd_exponent=sfd_exponent, max_age=max_age,
                          resolution=reader.resolution,
                          extent=min(reader.shape) * reader.resolution, required=True)
        source = CraterSource(reader, pop, seed,
                              _model(erosion_profile, erosion_exponent, no_roughness))
        _run_out_of_core(source, output, workers=workers, threads=threads, scheduler=scheduler,
                         chunk=chunk, label="craters", catalog=catalog, inputs=[input_dem])
        return
    tile = read_dem(input_dem, band=band, exact=True)
    if window is not None:
        window.check_inside(*tile.shape)
    extent = min(tile.shape) * tile.resolution
    pop = _population(population, dmin=dmin, dmax=dmax, density=density,
                      sfd_exponent=sfd_exponent, max_age=max_age, resolution=tile.resolution,
                      extent=extent, required=True)
    model = _model(erosion_profile, erosion_exponent, no_roughness)
    with progress_bar("craters", "class") as update:
        result = add_craters(tile, pop, seed=seed, model=model, window=window, progress=update)
    params = dict(input=str(input_dem), band=band, seed=seed, population=pop.as_dict(),
                  window=None if window is None else
                  [window.col, window.row, window.width, window.height])
    _write_outputs(result, output, catalog, [input_dem], "terrain craters", params)


@terrain.command("add-crater")
@click.argument("input_dem", type=click.Path(path_type=Path))
@_output_option
@click.option("--at", "at", type=PAIR, required=True,
              help="Crater centre X,Y in the DEM's map coordinates (m).")
@click.option("--diameter", type=float, required=True, help="Crater diameter (m).")
@click.option("--age", type=float, default=0.0, show_default=True,
              help="Crater age in Gyr (0: fresh).")
@_seed_option
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
@click.option("--catalog", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the crater's catalogue row (CSV) here.")
@click.option("--erosion-profile", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="CSV baseline degradation profile.")
@click.option("--erosion-exponent", type=float, default=None,
              help="P of the Ross/Soderblom scaling (default 1.1).")
@click.option("--no-roughness", is_flag=True,
              help="Switch off the fractal overlay and the irregular rim.")
@_morphology_options[0]
@_morphology_options[1]
@_morphology_options[2]
def add_crater(input_dem, output, at, diameter, age, seed, band, catalog, erosion_profile,
               erosion_exponent, no_roughness):
    """Add one crater at a map position."""
    from terrain.core.rng import hash64, stream_id
    from terrain.craters.catalog import Crater, CraterTable
    from terrain.craters.cratering import add_craters
    from terrain.io import read_dem

    if not diameter > 0:
        raise InvalidParameterError(f"--diameter must be positive metres; got {diameter}")
    if not age >= 0:
        raise InvalidParameterError(f"--age must be >= 0 Gyr; got {age}")
    _check_outputs(output, catalog, [input_dem])
    tile = read_dem(input_dem, band=band, exact=True)
    x, y = at
    left, bottom, right, top = tile.bounds
    extent = math.hypot(right - left, top - bottom)
    if diameter > MAX_CRATER_TO_DEM * extent:
        raise InvalidParameterError(
            f"--diameter {diameter:g} m is more than {MAX_CRATER_TO_DEM:g} times the DEM's "
            f"extent ({extent:.6g} m)")
    reach = diameter
    if x + reach < left or x - reach > right or y + reach < bottom or y - reach > top:
        raise InvalidParameterError(
            f"crater at {x},{y} with diameter {diameter} m does not touch the DEM, whose "
            f"extent is x {left:.6g}..{right:.6g}, y {bottom:.6g}..{top:.6g}")
    uid = int(hash64(seed, stream_id("add-crater"), 0, int(round(x * 1000)),
                     int(round(y * 1000)), int(round(diameter * 1000))))
    table = CraterTable.from_craters([Crater(x, y, diameter, age, uid)])
    model = _model(erosion_profile, erosion_exponent, no_roughness)
    result = add_craters(tile, table, seed=seed, model=model)
    params = dict(input=str(input_dem), band=band, seed=seed, x=x, y=y, diameter=diameter,
                  age=age, roughness=not no_roughness)
    _write_outputs(result, output, catalog, [input_dem], "terrain add-crater", params)


@terrain.command("hillshade")
@click.argument("input_dem", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Output PNG (8-bit grey).")
@click.option("--azimuth", type=float, default=315.0, show_default=True,
              help="Sun azimuth, degrees clockwise from north.")
@click.option("--altitude", type=float, default=45.0, show_default=True,
              help="Sun elevation above the horizon, degrees.")
@click.option("--z-factor", type=float, default=1.0, show_default=True,
              help="Vertical exaggeration.")
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
def hillshade_cmd(input_dem, output, azimuth, altitude, z_factor, band):
    """Write a shaded-relief PNG of a DEM."""
    from terrain.io import PNG_SUFFIXES, check_output_path, read_dem, write_png
    from terrain.surface.hillshade import hillshade

    check_output_path(output, [input_dem], suffixes=PNG_SUFFIXES, what="PNG")
    if not 0 < altitude <= 90:
        raise InvalidParameterError(f"altitude must lie in (0, 90] degrees; got {altitude}")
    if not 0 < abs(z_factor) <= MAX_Z_FACTOR:
        raise InvalidParameterError(
            f"--z-factor must be non-zero and at most {MAX_Z_FACTOR:g} in size; got {z_factor}")
    tile = read_dem(input_dem, band=band)
    image = hillshade(tile, azimuth=azimuth, altitude=altitude, z_factor=z_factor)
    with transaction():
        write_png(image, output, inputs=[input_dem])
    click.echo(f"wrote {output}", err=True)


@terrain.command()
@click.argument("input_dem", type=click.Path(path_type=Path))
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
def info(input_dem, band):
    """Describe a DEM: size, resolution, extent, valid fraction, heights, provenance."""
    import numpy as np

    from terrain.io import read_dem

    tile = read_dem(input_dem, band=band)
    h = tile.heights[tile.valid]
    report = dict(
        file=str(input_dem), width=tile.shape[1], height=tile.shape[0],
        resolution_m=tile.resolution, bounds=list(tile.bounds),
        crs=(tile.crs.split('"')[1] if tile.crs and '"' in tile.crs else tile.crs),
        valid_fraction=round(tile.valid_fraction, 6),
        height_min_m=float(np.min(h)), height_max_m=float(np.max(h)),
        height_mean_m=float(np.mean(h)), metadata=dict(tile.metadata),
    )
    click.echo(json.dumps(report, indent=2))


def _out_of_core(input_dem, band, times) -> bool:
    """Whether expanding the input ``times`` times needs more memory than is available."""
    from terrain.core import memory
    from terrain.core.zarrstore import is_zarr
    from terrain.fractal.expand import expanded_shape
    from terrain.io import RasterReader

    if Path(input_dem).is_dir() and is_zarr(input_dem):
        return True
    reader = RasterReader(input_dem, band)
    ny, nx = expanded_shape(reader.shape, times)
    need = ny * nx * (4 * 2 + 1 * 2) + reader.shape[0] * reader.shape[1] * 20
    return need > memory.available_bytes()


_roughness_options = [
    click.option("--fractal-dimension", type=float, default=None,
                 help="F in [2, 3); measured from the input by default."),
    click.option("--height-scale", type=float, default=None,
                 help="H of eq. 15 (height-range factor); measured from the input by default."),
    click.option("--uniform-roughness", is_flag=True,
                 help="One roughness everywhere instead of the input's local roughness map."),
]


@terrain.command()
@click.argument("input_dem", type=click.Path(path_type=Path))
@_store_output_option
@click.option("--times", type=click.IntRange(1, 16), default=1, show_default=True,
              help="Number of 2x expansions.")
@_seed_option
@with_options(_roughness_options)
@_window_option
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
@_dask_options
def expand(input_dem, output, times, seed, fractal_dimension, height_scale, uniform_roughness,
           window, band, workers, threads, scheduler, chunk, cog):
    """Double a DEM's resolution N times by fractal expansion (known heights kept).

    A result larger than memory runs chunk by chunk through Zarr (out of core) and is
    written as a Cloud Optimized GeoTIFF, instead of being refused.
    """
    from terrain.fractal.expand import expand as run_expand
    from terrain.io import check_output_path, read_dem, write_dem

    if _chunked_requested(output, workers, scheduler, chunk, cog, window):
        from terrain.execution.chunked import ExpandSource, estimate_parameters, open_reader
        from terrain.fractal.roughness import LOCAL_BOX

        reader = open_reader(input_dem, band)
        params = estimate_parameters(reader, fractal_dimension, height_scale,
                                     0 if uniform_roughness else LOCAL_BOX)
        _run_chunked(ExpandSource(reader, times, seed, params), output, workers=workers,
                     threads=threads, scheduler=scheduler, chunk=chunk, cog=cog,
                     label="expand", inputs=[input_dem])
        return
    if window is None and _out_of_core(input_dem, band, times):
        from terrain.execution.chunked import ExpandSource, estimate_parameters, open_reader
        from terrain.fractal.roughness import LOCAL_BOX

        reader = open_reader(input_dem, band)
        params = estimate_parameters(reader, fractal_dimension, height_scale,
                                     0 if uniform_roughness else LOCAL_BOX)
        _run_out_of_core(ExpandSource(reader, times, seed, params), output, workers=workers,
                         threads=threads, scheduler=scheduler, chunk=chunk, label="expand",
                         inputs=[input_dem])
        return

    from terrain.fractal.roughness import RoughnessChoice

    check_output_path(output, [input_dem])
    tile = read_dem(input_dem, band=band, exact=True)
    if window is not None:
        window.check_inside(*tile.shape)
    params = RoughnessChoice(fractal_dimension, height_scale, uniform_roughness).for_tile(tile)
    with progress_bar("expand", "level") as bar:
        out = run_expand(tile, times, seed=seed, params=params, window=window,
                         progress=bar)
    out = out.with_metadata(**{mk.COMMAND: "terrain expand", mk.VERSION: version(),
                            mk.PARAMETERS: dict(input=str(input_dem), times=times,
                                                        seed=seed, **params.as_dict())})
    with transaction():
        write_dem(out, output, inputs=[input_dem])
    click.echo(f"wrote {output} ({out.shape[1]}x{out.shape[0]} at {out.resolution:.6g} m; "
               f"F={params.fractal_dimension:.3f}, H={params.height_scale:.4g})", err=True)


_stack_dask_options = [
    *_chunk_options("Build the stack", "build"),
    click.option("--halo", type=click.IntRange(0, None), default=None,
                 help="Chunked builds: pixels around each chunk that every gap of the base "
                      "must fit in (default 256)."),
]


@terrain.command()
@click.argument("input_dem", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder for the layer stack (new or empty).")
@click.option("--site", type=PAIR, default=None, help="Landing site X,Y in map coordinates.")
@click.option("--site-lonlat", type=PAIR, default=None,
              help="Landing site as LON,LAT (degrees) on the DEM's body.")
@click.option("--levels", type=click.IntRange(0, None), default=None,
              help="Number of 2x expansions (layers = levels + 1).")
@click.option("--finest-resolution", type=float, default=None,
              help="Expand until the finest layer is at most this many metres per pixel.")
@click.option("--layer-size", type=int, default=1025, show_default=True,
              help="Pixels per side of each expanded layer (odd).")
@_seed_option
@with_options(_roughness_options)
@click.option("--min-crater-pixels", type=float, default=4.0, show_default=True,
              help="Smallest crater a layer takes, in its pixels.")
@click.option("--despike", type=float, default=None,
              help="Before filling, drop pixels this many robust sigmas from their median.")
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
@click.option("--rocks", "rocks_spec", default=None, metavar="MODEL:KEY=VALUE,...",
              help="Rocks on every layer that resolves them, e.g. golombek:k=0.01 or "
                   "power:a=3e-4,b=-2.482 (keys as `terrain rocks`; dmin defaults to two "
                   "pixels of the finest layer).")
@_crater_options
@with_options(_stack_dask_options)
def enhance(input_dem, output, site, site_lonlat, levels, finest_resolution, layer_size, seed,
            fractal_dimension, height_scale, uniform_roughness, min_crater_pixels, despike,
            band, rocks_spec, dmin, dmax, density, sfd_exponent, max_age, population, catalog,
            erosion_profile, erosion_exponent, no_roughness, workers, threads, scheduler,
            chunk, halo):
    """Build nested multi-resolution layers around a landing site.

    A stack too large for memory (or any stack with --workers, --scheduler or --chunk) is
    built chunk by chunk on Dask, bitwise equal to the in-memory build; its layers too large
    for memory are written as Zarr DEMs, the others as GeoTIFFs. Rerun an interrupted
    chunked build with the same command to resume it.
    """
    from terrain.fractal.gapfill import despike as run_despike
    from terrain.fractal.roughness import RoughnessChoice
    from terrain.io import lonlat_to_xy, read_dem
    from terrain.stack.build import build_stack
    from terrain.stack.plan import levels_for_resolution
    from terrain.stack.store import write_stack

    if (site is None) == (site_lonlat is None):
        raise InvalidParameterError("give exactly one of --site X,Y and --site-lonlat LON,LAT")
    if (levels is None) == (finest_resolution is None):
        raise InvalidParameterError("give exactly one of --levels and --finest-resolution")
    if catalog is not None:
        raise InvalidParameterError("enhance writes its catalogue into the output folder "
                                    "(craters.csv); drop --catalog")
    from terrain.stack.store import prepare_folder

    asked = any(v is not None for v in (workers, scheduler, chunk, halo))
    if asked or not _stack_fits(input_dem, band, site, site_lonlat, levels, finest_resolution,
                                layer_size):
        _enhance_chunked(auto=not asked, **locals())
        return
    prepare_folder(output, inputs=[input_dem])
    tile = read_dem(input_dem, band=band, exact=True)
    if site_lonlat is not None:
        site = lonlat_to_xy(tile.crs, *site_lonlat)
    if finest_resolution is not None:
        levels = levels_for_resolution(tile.resolution, finest_resolution)
    if despike is not None:
        tile, _ = run_despike(tile, despike)
    rocks, pop, model = _stack_content(tile.resolution, tuple(tile.shape), **locals())
    params = RoughnessChoice(fractal_dimension, height_scale, uniform_roughness)
    with progress_bar("enhance", "step") as bar:
        stack = build_stack(tile, site, levels=levels, layer_size=layer_size, seed=seed,
                            population=pop, model=model, params=params,
                            min_crater_pixels=min_crater_pixels,
                            progress=bar,
                            rocks=rocks)
    stack = stack.with_info(source=str(input_dem), command="terrain enhance",
                            craterscape_version=version())
    write_stack(stack, output, inputs=[input_dem])
    n_rocks = "" if stack.rocks is None else f", {len(stack.rocks)} rocks"
    click.echo(f"wrote {len(stack.tiles)} layers to {output} (finest "
               f"{stack.tiles[-1].resolution:.4g} m/pixel, {len(stack.catalog)} craters"
               f"{n_rocks})", err=True)




def _stack_content(resolution, shape, *, levels, rocks_spec, population, dmin, dmax, density,
                   sfd_exponent, max_age, erosion_profile, erosion_exponent, no_roughness,
                   **_):
    """Return the rocks, crater population and crater model `terrain enhance` adds.

    Parameters
    ----------
    resolution : float, metres per pixel
        The base DEM's.
    shape : (rows, cols)
        The base DEM's.
    levels : int
        Layers above the base; the finest layer's pixel sets the rocks' default smallest
        diameter (:data:`terrain.surface.rocks.MIN_ROCK_PIXELS` pixels) and the craters' resolution.
    rocks_spec, population, dmin, dmax, density, sfd_exponent, max_age : option values
        The command's rock and crater options.
    erosion_profile, erosion_exponent, no_roughness : option values
        The command's crater-model options.
    **_
        The command's other options, ignored.

    Returns
    -------
    rocks : RockModel or None
    population : Population or None
    model : CraterModel
    """
    finest = resolution / 2**levels
    rocks = None
    if rocks_spec is not None:
        from terrain.surface.rocks import MIN_ROCK_PIXELS, RockModel

        rocks = RockModel.from_spec(rocks_spec, defaults=dict(dmin=MIN_ROCK_PIXELS * finest))
    pop = _population(population, dmin=dmin, dmax=dmax, density=density,
                      sfd_exponent=sfd_exponent, max_age=max_age, resolution=finest,
                      extent=min(shape) * resolution, required=False, warn_small=False)
    return rocks, pop, _model(erosion_profile, erosion_exponent, no_roughness)


def _stack_geometry(input_dem, band, site, site_lonlat, levels, finest_resolution, layer_size):
    """(reader, site, levels, layer shapes) of a stack, from the input's header only."""
    from terrain.execution.chunked import open_reader
    from terrain.io import lonlat_to_xy
    from terrain.stack.plan import GridShape, layer_plan, levels_for_resolution

    reader = open_reader(input_dem, band)
    if site_lonlat is not None:
        site = lonlat_to_xy(reader.crs, *site_lonlat)
    if finest_resolution is not None:
        levels = levels_for_resolution(reader.resolution, finest_resolution)
    _, _, shapes, _ = layer_plan(GridShape(tuple(reader.shape), reader.transform),
                            tuple(float(v) for v in site), levels, layer_size)
    return reader, site, levels, shapes


def _stack_fits(input_dem, band, site, site_lonlat, levels, finest_resolution,
                layer_size) -> bool:
    """Whether the in-memory build of this stack fits in memory (else it runs chunked)."""
    from terrain.core.zarrstore import is_zarr
    from terrain.io import RasterReader
    from terrain.stack.chunkedlayers import stack_fits_in_memory

    if Path(input_dem).is_dir() and is_zarr(input_dem):
        return False  # a Zarr base is read by window
    reader = RasterReader(input_dem, band)
    if reader.wide:
        return True  # read exactly in memory (a chunked run would round it)
    try:
        _, _, _, shapes = _stack_geometry(input_dem, band, site, site_lonlat, levels,
                                          finest_resolution, layer_size)
    except InvalidParameterError:
        return True  # the in-memory path reports it as it always has
    return stack_fits_in_memory(reader.shape, shapes)


def _enhance_chunked(*, input_dem, output, site, site_lonlat, levels, finest_resolution,
                     layer_size, seed, fractal_dimension, height_scale, uniform_roughness,
                     min_crater_pixels, despike, band, rocks_spec, dmin, dmax, density,
                     sfd_exponent, max_age, population, erosion_profile, erosion_exponent,
                     no_roughness, workers, threads, scheduler, chunk, halo, auto, **_):
    """`terrain enhance` chunk by chunk (:func:`~.chunkedlayers.build_stack_chunked`)."""
    from terrain.execution.chunked import DEFAULT_CHUNK, dask_client
    from terrain.fractal.roughness import LOCAL_BOX
    from terrain.stack.chunkedlayers import build_stack_chunked

    if despike is not None:
        raise InvalidParameterError("a chunked enhance takes no --despike; run `terrain fill "
                                    "--despike` on the DEM first")
    from terrain.stack.store import prepare_folder

    prepare_folder(output, inputs=[input_dem], keep=(".craterscape.work",))
    reader, site, levels, shapes = _stack_geometry(input_dem, band, site, site_lonlat, levels,
                                                   finest_resolution, layer_size)
    rocks, pop, model = _stack_content(reader.resolution, tuple(reader.shape), **locals())
    estimate = dict(fractal_dimension=fractal_dimension, height_scale=height_scale,
                    local_box=0 if uniform_roughness else LOCAL_BOX)
    pixels = sum(h * w for h, w in shapes)
    (log.warning if auto else log.info)(
        "enhance: building %d layers (%.3g Mpixel) chunk by chunk in %s%s", levels + 1,
        pixels / 1e6, output, " (the stack does not fit in memory)" if auto else "")
    with contextlib.ExitStack() as bars:
        def progress(stage):
            return bars.enter_context(progress_bar(f"enhance {stage}", "chunk"))

        with dask_client(workers, scheduler, processes=not threads) as client:
            result = build_stack_chunked(
                reader, output, site, levels=levels, layer_size=layer_size, seed=seed,
                population=pop, model=model, estimate=estimate,
                min_crater_pixels=min_crater_pixels, rocks=rocks,
                chunk=chunk or DEFAULT_CHUNK, client=client, progress=progress,
                halo=256 if halo is None else halo, inputs=[input_dem],
                info=dict(source=str(input_dem), command="terrain enhance",
                          craterscape_version=version()))
    computed = sum(s["computed"] for s in result["stages"].values())
    total = sum(s["total"] for s in result["stages"].values())
    n_rocks = "" if result["rocks"] is None else f", {result['rocks']} rocks"
    click.echo(f"wrote {levels + 1} layers to {output} (finest {result['finest_resolution']:.4g}"
               f" m/pixel, {result['craters']} craters{n_rocks}; chunked: {computed} of "
               f"{total} chunks computed, {total - computed} already written)", err=True)


@terrain.command()
@click.argument("input_dem", type=click.Path(path_type=Path))
@_store_output_option
@click.option("--roughness", type=float, default=None,
              help="Gaussian per filled pixel, in units of the resolution; measured around "
                   "each gap by default.")
@click.option("--craters-at", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="CSV of crater gaps (x, y, diameter[, age]) to fill with craters.")
@click.option("--despike", type=float, default=None,
              help="First drop pixels this many robust sigmas from their local median.")
@click.option("--denoise", type=float, default=None,
              help="First smooth known pixels with a Gaussian of this many pixels.")
@_seed_option
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
@click.option("--halo", type=click.IntRange(0, None), default=None,
              help="Chunked runs: pixels around each chunk that every gap must fit in "
                   "(default 256).")
@_dask_options
def fill(input_dem, output, roughness, craters_at, despike, denoise, seed, band, halo, workers,
         threads, scheduler, chunk, cog):
    """Fill DEM gaps with fractal terrain (and craters), keeping every known height."""
    import numpy as np

    if _chunked_requested(output, workers, scheduler, chunk if halo is None else 0, cog):
        from terrain.execution.chunked import FillSource, open_reader

        if craters_at is not None or despike is not None or denoise is not None:
            raise InvalidParameterError("a chunked fill takes no --craters-at, --despike or "
                                        "--denoise; run those on the DEM first")
        source = FillSource(open_reader(input_dem, band), 256 if halo is None else halo, seed,
                            roughness)
        _run_chunked(source, output, workers=workers, threads=threads, scheduler=scheduler,
                     chunk=chunk, cog=cog, label="fill", inputs=[input_dem])
        return
    if halo is not None:
        raise InvalidParameterError("--halo is for chunked runs: give -o NAME.zarr or --chunk")
    from terrain.craters.catalog import read_circles
    from terrain.fractal.gapfill import denoise as run_denoise
    from terrain.fractal.gapfill import despike as run_despike
    from terrain.fractal.gapfill import fill_crater_gaps, fill_gaps
    from terrain.io import check_output_path, read_dem_exact, write_dem

    check_output_path(output, [input_dem, craters_at])
    if (craters_at is None and despike is None and denoise is None
            and not _input_fits(input_dem, band)):
        from terrain.execution.chunked import FillSource, open_reader

        _run_out_of_core(FillSource(open_reader(input_dem, band), 256, seed, roughness), output,
                         workers=workers, threads=threads, scheduler=scheduler, chunk=chunk,
                         label="fill", inputs=[input_dem])
        return
    tile, exact = read_dem_exact(input_dem, band=band)
    circles = read_circles(craters_at) if craters_at is not None else None
    removed = 0
    if despike is not None:
        tile, mask = run_despike(tile, despike)
        removed = int(mask.sum())
    if denoise is not None:
        tile = run_denoise(tile, denoise)
        exact = None  # smoothing changes the known heights on purpose
    if circles is not None:
        result = fill_crater_gaps(tile, circles, seed=seed, roughness=roughness)
    else:
        result = fill_gaps(tile, seed=seed, roughness=roughness)
    out = result.tile.with_metadata(
        **{mk.COMMAND: "terrain fill", mk.VERSION: version(),
        mk.PARAMETERS: dict(input=str(input_dem), roughness=roughness, seed=seed,
                                    despike=despike, denoise=denoise,
                                    craters_at=str(craters_at) if craters_at else None)})
    known = None if exact is None else np.where(result.filled, np.nan, exact)
    with transaction():  # known heights a float32 tile rounds go back bitwise (float64 file)
        write_dem(out, output, inputs=[input_dem], known=known)
    click.echo(f"wrote {output} ({int(result.filled.sum())} pixels filled"
               + (f", {removed} spikes removed" if despike is not None else "") + ")", err=True)


@terrain.command("replace-crater")
@click.argument("stack_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--at", "at", type=PAIR, required=True, help="Crater centre X,Y (map metres).")
@click.option("--diameter", type=float, required=True, help="Crater diameter (m).")
@click.option("--age", type=float, default=0.0, show_default=True, help="Age in Gyr.")
@click.option("--seed", type=click.IntRange(0, 2**63 - 1), default=None,
              help="Seed (default: the stack's).")
def replace_crater_cmd(stack_dir, at, diameter, age, seed):
    """Replace a crater in a layer stack with a sharp synthetic one (edits in place).

    The stack's rocks on the changed ground are stood on the new ground (rocks.csv follows).
    """
    from terrain.stack.edit import replace_crater

    if not stack_dir.is_dir():
        raise InvalidParameterError(f"'{stack_dir}' is not a layer-stack folder")
    done = replace_crater(stack_dir, at[0], at[1], diameter, age=age, seed=seed)
    click.echo(f"replaced crater at {at[0]:.6g},{at[1]:.6g} (D {diameter:g} m) in layer "
               f"{done['layer']}; updated layers {done['changed_layers']}", err=True)


@terrain.command()
@click.argument("input_dem", type=click.Path(path_type=Path))
@_output_option
@click.option("--model", type=click.Choice(["golombek", "power"]), default="golombek",
              show_default=True, help="Size-frequency model of the rocks.")
@click.option("--k", "k", type=float, default=None,
              help="golombek: fraction of the area covered by rocks, 0 < k < 1.")
@click.option("--a", "a", type=float, default=None, help="power: a of N(>=D) = a D^b per m^2.")
@click.option("--b", "b", type=float, default=None, help="power: b of N(>=D) = a D^b (< 0).")
@click.option("--dmin", type=float, default=None,
              help="Smallest rock diameter (m). Default: two pixels of the DEM.")
@click.option("--dmax", type=float, default=None,
              help="Largest rock diameter (m). Default: where the model has run out.")
@click.option("--craters", "craters_csv", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Crater catalogue CSV (x_m/x, y_m/y, diameter, age): rocks "
                                 "gather on the fresh ones.")
@click.option("--no-crater-rocks", is_flag=True,
              help="Do not raise the rock density on fresh craters.")
@_seed_option
@_window_option
@click.option("--catalog", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the rock catalogue (CSV) here.")
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
def rocks(input_dem, output, model, k, a, b, dmin, dmax, craters_csv, no_crater_rocks, seed,
          window, catalog, band):
    """Stand a rock field (Golombek-Rapp or power law) on a DEM, keyed by position."""
    from terrain.io import atomic_path, read_dem, write_dem
    from terrain.surface.rocks import MIN_ROCK_PIXELS, RockModel, add_rocks

    _check_outputs(output, catalog, [input_dem, craters_csv])
    if craters_csv is not None and no_crater_rocks:
        raise InvalidParameterError("--craters and --no-crater-rocks contradict each other")
    values = dict(model=model, k=k, a=a, b=b, dmin=dmin, dmax=dmax)
    values = {key: v for key, v in values.items() if v is not None}
    if no_crater_rocks:
        values["craters"] = False
    tile = read_dem(input_dem, band=band)
    if window is not None:
        window.check_inside(*tile.shape)
    rock_model = RockModel.from_mapping(values,
                                        defaults=dict(dmin=MIN_ROCK_PIXELS * tile.resolution))
    if rock_model.dmax <= MIN_ROCK_PIXELS * tile.resolution:
        log.warning("no rock of this model (dmax %.3g m) is two pixels (%.3g m) wide: the "
                    "heights will not change", rock_model.dmax, MIN_ROCK_PIXELS * tile.resolution)
    craters = None if craters_csv is None else _read_crater_list(craters_csv)
    out, cat = add_rocks(tile, rock_model, seed=seed, craters=craters, window=window)
    params = dict(input=str(input_dem), band=band, seed=seed, rocks=rock_model.as_dict(),
                  craters=str(craters_csv) if craters_csv else None,
                  window=None if window is None else
                  [window.col, window.row, window.width, window.height])
    out = out.with_metadata(**{mk.COMMAND: "terrain rocks", mk.PARAMETERS: params,
                            mk.VERSION: version()})
    with transaction(folders=[Path(output).parent]):  # the DEM and its catalogue as one set
        write_dem(out, output, inputs=[input_dem])
        if catalog is not None:
            with atomic_path(catalog, [input_dem, output]) as tmp:
                cat.to_csv(tmp)
    click.echo(f"wrote {output}" + (f" and {catalog}" if catalog else "")
               + f" ({len(cat)} rocks)", err=True)


def _read_crater_list(path):
    """Return the craters of a CSV: a craterscape catalogue or a plain list.

    A catalogue has (at least) the columns x_m, y_m, diameter_m, age_gyr; a plain list x, y,
    diameter and optionally age (:func:`terrain.craters.catalog.read_circles`).
    """
    import csv

    import numpy as np

    from terrain.core.errors import MissingInputError
    from terrain.craters.catalog import CraterTable, read_circles, read_columns

    if not Path(path).exists():
        raise MissingInputError(f"crater catalogue '{path}' does not exist")
    with open(path, newline="", encoding="utf-8") as f:
        header = next(csv.reader(f), [])
    if not {"x_m", "y_m", "diameter_m", "age_gyr"} <= set(header):
        return read_circles(path)
    try:
        cat = read_columns(path)
    except ValueError as exc:
        raise InvalidParameterError(f"crater catalogue '{path}' is malformed: {exc}") from None
    n = len(cat["x_m"])
    return CraterTable(cat["x_m"], cat["y_m"], cat["diameter_m"], cat["age_gyr"],
                       cat.get("id", np.zeros(n, np.uint64)), np.zeros(n, np.int64))


@terrain.command()
@click.argument("source", type=click.Path(path_type=Path))
@_output_option
@click.option("--lander-diameter", type=float, required=True,
              help="Diameter of the lander's footprint (m).")
@click.option("--max-slope", type=float, required=True,
              help="Steepest safe plane under the footprint (degrees).")
@click.option("--max-step", type=float, required=True,
              help="Largest safe height above that plane inside the footprint (m).")
@click.option("--layer", type=int, default=None,
              help="Layer of a stack (default: the finest with at most 72 pixels across the "
                   "footprint).")
@click.option("--png", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Picture for people (default: the output with .png).")
@click.option("--band", type=int, default=1, show_default=True, help="Band of a DEM input.")
def hazards(source, output, lander_diameter, max_slope, max_step, layer, png, band):
    """Hazard truth: slope of the plane under a lander, height above it, safe or not.

    SOURCE is a DEM or a layer-stack folder. Writes a GeoTIFF with three bands (slope in
    degrees, step in metres, safe 1 / unsafe 0; NaN where the footprint is not fully known),
    the safe fraction in its tags, and a PNG.
    """
    from terrain.io import check_output_path, read_dem, write_bands, write_png
    from terrain.surface.hazards import hazard_image, hazard_map, pick_layer
    from terrain.surface.hillshade import hillshade

    png = png or output.with_suffix(".png")
    check_output_path(output, [source])
    check_output_path(png, [source, output])
    if png.resolve() == output.resolve():
        raise InvalidParameterError("--png must differ from --output")
    if source.is_dir():
        from terrain.stack.store import read_stack

        stack = read_stack(source)
        resolutions = [t.resolution for t in stack.tiles]
        if layer is None:
            layer = pick_layer(resolutions, lander_diameter)
        if not 0 <= layer < len(stack.tiles):
            raise InvalidParameterError(
                f"layer {layer} does not exist; the stack has layers 0..{len(stack.tiles) - 1}")
        tile = stack.tiles[layer]
    else:
        if layer is not None:
            raise InvalidParameterError("--layer applies to a layer-stack folder, not a DEM")
        tile = read_dem(source, band=band)
    result = hazard_map(tile, lander_diameter=lander_diameter, max_slope=max_slope,
                        max_step=max_step)
    params = dict(source=str(source), layer=layer, lander_diameter=lander_diameter,
                  max_slope=max_slope, max_step=max_step)
    tags = dict(result.tags(), **{mk.COMMAND: "terrain hazards",
                mk.PARAMETERS: json.dumps(params, sort_keys=True),
                mk.VERSION: version()})
    shade = hillshade(tile, azimuth=315.0, altitude=30.0)
    with transaction(folders=[Path(output).parent]):  # the GeoTIFF and its PNG as one set
        write_bands([result.slope, result.step, result.safe], tile.replace(metadata={}),
                    output, descriptions=("slope (deg)", "step above plane (m)",
                                          "safe (1) / unsafe (0)"), tags=tags, inputs=[source])
        write_png(hazard_image(result, shade), png, inputs=[source, output])
    click.echo(f"wrote {output} and {png} ({100 * result.safe_fraction:.1f} % safe of the "
               f"{100 * result.known_fraction:.1f} % known, {tile.resolution:.4g} m pixels)",
               err=True)


def _run_out_of_core(source, output, *, workers, threads, scheduler, chunk, label,
                     catalog=None, inputs=()):
    """Run a request larger than memory chunk by chunk, instead of refusing it.

    The chunks go to a scratch Zarr store beside the output (resumed by a rerun of the same
    request, removed once the output is written); the output GeoTIFF is written from it as a
    COG.
    """
    import shutil

    from terrain.core import memory
    from terrain.io import check_output_path

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

    with scratch_store(source, output, chunk) as (scratch, chunk):
        if chunk is None:  # a chunk (with its halo) per worker well inside the memory there is
            halo = getattr(source, "halo", 0)
            share = memory.available_bytes() / (workers or 1) / 4
            chunk = DEFAULT_CHUNK
            while chunk > 64 and (chunk + 2 * halo) ** 2 * 64 > share:
                chunk //= 2
        log.warning("%s: %dx%d pixels do not fit in memory; running chunk by chunk through "
                    "%s", label, source.shape[1], source.shape[0], scratch)
        _run_chunked(source, scratch, workers=workers, threads=threads,
                     scheduler=scheduler, chunk=chunk, cog=output, label=label,
                     catalog=catalog, inputs=inputs)


def _input_fits(input_dem, band) -> bool:
    """Whether an input DEM and a whole-DEM operation's working copies fit in memory."""
    from terrain.core.zarrstore import is_zarr
    from terrain.io import RasterReader

    if Path(input_dem).is_dir() and is_zarr(input_dem):
        from terrain.core.zarrstore import ZarrDEM

        ny, nx = ZarrDEM(input_dem).shape
    else:
        ny, nx = RasterReader(input_dem, band).shape
    return _fits_in_memory(ny * nx * 40.0)


def _fits_in_memory(nbytes: float) -> bool:
    from terrain.core import memory
    return nbytes <= memory.available_bytes()


@terrain.command("cog")
@click.argument("input_zarr", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Output Cloud Optimized GeoTIFF.")
def cog_cmd(input_zarr, output):
    """Convert a chunked (Zarr) DEM into a tiled, compressed COG with overviews."""
    from terrain.core.zarrstore import ZarrDEM
    from terrain.io import write_cog

    store = ZarrDEM(input_zarr)
    store.check_complete()
    write_cog(store, output, inputs=[input_zarr])
    click.echo(f"wrote {output} ({store.shape[1]}x{store.shape[0]} Cloud Optimized GeoTIFF)",
               err=True)
