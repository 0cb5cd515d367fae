"""The ``craterscape`` command and its ``terrain`` group.

The root command lives in the lowest layer and discovers the stage groups through the
``craterscape.groups`` entry points, so ``terrain`` never imports a higher package (rasterio's
``rio`` registers its subcommands the same way). Errors that craterscape raises on purpose
become one line on stderr and exit code 2; ``-v`` shows the traceback.
"""

from __future__ import annotations

import json
import logging
import sys
import traceback
from importlib.metadata import entry_points
from pathlib import Path

import click

from terrain.errors import CraterscapeError, InvalidParameterError

__all__ = ["main", "terrain"]

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "craterscape.groups"
EXIT_BAD_INPUT = 2


class _Root(click.Group):
    """Loads stage groups from entry points and turns errors into one line."""

    def list_commands(self, ctx):
        names = {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)}
        return sorted(names | set(self.commands))

    def get_command(self, ctx, name):
        if name in self.commands:
            return self.commands[name]
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            if ep.name == name:
                return ep.load()
        return None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except CraterscapeError as exc:
            _fail(ctx, exc, EXIT_BAD_INPUT)
        except KeyboardInterrupt:
            click.echo("craterscape: interrupted", err=True)
            ctx.exit(130)
        except (MemoryError, OSError) as exc:
            _fail(ctx, exc, 1)


def _fail(ctx, exc, code):
    verbose = (ctx.obj or {}).get("verbosity", 0) > 0
    if verbose:
        traceback.print_exception(exc, file=sys.stderr)
    message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    click.echo(f"craterscape: error: {message}", err=True)
    ctx.exit(code)


@click.group(cls=_Root, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output; tracebacks on errors.")
@click.option("-q", "--quiet", count=True, help="Less log output.")
@click.version_option(package_name="craterscape")
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


class _WindowType(click.ParamType):
    name = "COL,ROW,WIDTH,HEIGHT"

    def convert(self, value, param, ctx):
        from terrain.tile import Window

        if value is None or isinstance(value, Window):
            return value
        try:
            return Window.parse(value)
        except InvalidParameterError as exc:
            self.fail(str(exc), param, ctx)


class _PairType(click.ParamType):
    name = "X,Y"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        parts = str(value).split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            return float(parts[0]), float(parts[1])
        except ValueError:
            self.fail(f"expected two numbers X,Y; got {value!r}", param, ctx)


WINDOW = _WindowType()
PAIR = _PairType()

_output_option = click.option(
    "-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
    help="Output GeoTIFF (written atomically; never over an input).")
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
    ]
    for option in reversed(options):
        func = option(func)
    return func


def _model(erosion_profile, erosion_exponent, no_roughness):
    from terrain.cratering import CraterModel
    from terrain.erosion import ErosionModel

    kwargs = {} if erosion_exponent is None else {"exponent": erosion_exponent}
    if erosion_profile is not None:
        erosion = ErosionModel.from_csv(erosion_profile, **kwargs)
    else:
        erosion = ErosionModel.default(**kwargs)
    model = CraterModel(erosion=erosion)
    return model.smooth() if no_roughness else model


def _population(population_file, *, dmin, dmax, density, sfd_exponent, max_age, resolution,
                extent, required):
    from terrain.population import Population

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
    if pop.dmin < 2.0 * resolution:
        log.warning("dmin %.3g m is below two pixels (%.3g m): such craters are aliased",
                    pop.dmin, 2.0 * resolution)
    return pop


def _progress(label):
    """A tqdm bar on a terminal, nothing in pipes and tests."""
    from tqdm import tqdm

    if not sys.stderr.isatty():
        return None, lambda: None
    bar = tqdm(total=None, desc=label, unit="class", leave=False)

    def update(done, total):
        bar.total = total
        bar.n = done
        bar.refresh()

    return update, bar.close


def _write_outputs(result, output, catalog, inputs, command, params):
    from terrain.catalog import write_catalog
    from terrain.io import atomic_path, check_output_path, write_dem

    tile = result.tile.with_metadata(CRATERSCAPE_COMMAND=command,
                                     CRATERSCAPE_PARAMETERS=params,
                                     CRATERSCAPE_VERSION=_version())
    write_dem(tile, output, inputs=inputs)
    if catalog is not None:
        check_output_path(catalog, [*inputs, output])
        with atomic_path(catalog, [*inputs, output]) as tmp:
            write_catalog(tmp, result.catalog)
        click.echo(f"wrote {output} and {catalog} ({len(result.catalog['id'])} craters)",
                   err=True)
    else:
        click.echo(f"wrote {output}", err=True)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("craterscape")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "unknown"


def _check_outputs(output, catalog, inputs):
    from terrain.io import check_output_path

    check_output_path(output, inputs)
    if catalog is not None:
        check_output_path(catalog, [*inputs, output])
        if Path(catalog).resolve() == Path(output).resolve():
            raise InvalidParameterError("--catalog must differ from --output")


# --------------------------------------------------------------------------------------
# the terrain group


@click.group()
def terrain():
    """DEM tiles: synthetic terrain, craters, hillshades."""


@terrain.command()
@_output_option
@click.option("--size", type=int, default=1025, show_default=True,
              help="Tile side in pixels, 2^n + 1.")
@click.option("--resolution", type=float, default=1.0, show_default=True,
              help="Metres per pixel.")
@click.option("--fractal-dimension", type=float, default=2.2, show_default=True,
              help="RMD fractal dimension F in [2, 3) (eq. 14).")
@click.option("--relief", type=float, default=30.0, show_default=True,
              help="Tile-scale relief R = H * D_r * W of eq. 15 (m): the standard deviation "
                   "of the corner heights.")
@_seed_option
@_window_option
@_crater_options
def synth(output, size, resolution, fractal_dimension, relief, seed, window, dmin, dmax,
          density, sfd_exponent, max_age, population, catalog, erosion_profile,
          erosion_exponent, no_roughness):
    """Synthesise fractal terrain (RMD diamond-square), optionally cratered."""
    from terrain.rmd import check_fractal_dimension, check_tile_size
    from terrain.synthetic import synthesize_tile

    check_tile_size(size)
    check_fractal_dimension(fractal_dimension)
    if not resolution > 0:
        raise InvalidParameterError(f"resolution must be positive; got {resolution}")
    if window is not None:
        window.check_inside(size, size)
    _check_outputs(output, catalog, [])
    pop = _population(population, dmin=dmin, dmax=dmax, density=density,
                      sfd_exponent=sfd_exponent, max_age=max_age, resolution=resolution,
                      extent=(size - 1) * resolution, required=False)
    if pop is None and catalog is not None:
        raise InvalidParameterError("--catalog needs craters: give --density or --population")
    model = _model(erosion_profile, erosion_exponent, no_roughness)
    update, close = _progress("craters")
    try:
        result = synthesize_tile(size, resolution=resolution,
                                 fractal_dimension=fractal_dimension, relief=relief, seed=seed,
                                 craters=pop, model=model, window=window, progress=update)
    finally:
        close()
    params = dict(size=size, resolution=resolution, fractal_dimension=fractal_dimension,
                  relief=relief, seed=seed, population=pop.as_dict() if pop else None,
                  window=None if window is None else
                  [window.col, window.row, window.width, window.height])
    _write_outputs(result, output, catalog, [], "terrain synth", params)


@terrain.command()
@click.argument("input_dem", type=click.Path(path_type=Path))
@_output_option
@_seed_option
@_window_option
@click.option("--band", type=int, default=1, show_default=True, help="Band of the input.")
@_crater_options
def craters(input_dem, output, seed, window, band, dmin, dmax, density, sfd_exponent, max_age,
            population, catalog, erosion_profile, erosion_exponent, no_roughness):
    """Add a power-law crater population to a DEM."""
    from terrain.cratering import add_craters
    from terrain.io import read_dem

    _check_outputs(output, catalog, [input_dem])
    tile = read_dem(input_dem, band=band)
    if window is not None:
        window.check_inside(*tile.shape)
    extent = min(tile.shape) * tile.resolution
    pop = _population(population, dmin=dmin, dmax=dmax, density=density,
                      sfd_exponent=sfd_exponent, max_age=max_age, resolution=tile.resolution,
                      extent=extent, required=True)
    model = _model(erosion_profile, erosion_exponent, no_roughness)
    update, close = _progress("craters")
    try:
        result = add_craters(tile, pop, seed=seed, model=model, window=window, progress=update)
    finally:
        close()
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
def add_crater(input_dem, output, at, diameter, age, seed, band, catalog, erosion_profile,
               erosion_exponent, no_roughness):
    """Add one crater at a map position."""
    from terrain.catalog import Crater, CraterTable
    from terrain.cratering import add_craters
    from terrain.io import read_dem
    from terrain.rng import hash64, stream_id

    _check_outputs(output, catalog, [input_dem])
    tile = read_dem(input_dem, band=band)
    x, y = at
    left, bottom, right, top = tile.bounds
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
    from terrain.hillshade import hillshade
    from terrain.io import check_output_path, read_dem, write_png

    check_output_path(output, [input_dem])
    if not 0 < altitude <= 90:
        raise InvalidParameterError(f"altitude must lie in (0, 90] degrees; got {altitude}")
    tile = read_dem(input_dem, band=band)
    write_png(hillshade(tile, azimuth=azimuth, altitude=altitude, z_factor=z_factor), output,
              inputs=[input_dem])
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
