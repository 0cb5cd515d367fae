"""The ``terrain`` command group: each stage command is options -> spec -> run.

The stage commands come from their specs (:mod:`terrain.stages.specs`) through
:func:`terrain.cli.options.stage_command`; the root command is :mod:`terrain.cli.root`.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from terrain.cli.options import stage_command
from terrain.cli.root import main
from terrain.cli.tools import PAIR
from terrain.core.errors import InvalidParameterError
from terrain.stages import specs

__all__ = ["main", "terrain"]  # main: the root, for callers that start it from here


@click.group()
def terrain():
    """DEM tiles: synthetic terrain, craters, hillshades."""


stage_command(terrain, "synth", specs.SynthSpec, output="store", source=False, catalog=True,
              execution="dem", help="Synthesise fractal terrain (RMD diamond-square), "
              "optionally cratered, on the Moon (south-polar CRS centred on the tile) unless "
              "--body, --crs or --local-grid say otherwise.")
stage_command(terrain, "craters", specs.CratersSpec, output="store", catalog=True,
              execution="dem", help="Add a power-law crater population to a DEM.")
stage_command(terrain, "add-crater", specs.AddCraterSpec, catalog=True,
              help="Add one crater at a map position.")
stage_command(terrain, "hillshade", specs.HillshadeSpec, output="png",
              help="Write a shaded-relief PNG of a DEM.")
stage_command(terrain, "expand", specs.ExpandSpec, output="store", execution="dem",
              help="Double a DEM's resolution N times by fractal expansion (known heights "
              "kept). A result larger than memory runs chunk by chunk through Zarr (out of "
              "core) and is written as a Cloud Optimized GeoTIFF, instead of being refused.")
stage_command(terrain, "enhance", specs.EnhanceSpec, output="stack", execution="stack",
              help="Build nested multi-resolution layers around a landing site (default: the "
              "DEM's centre). A stack too large for memory (or any stack with --workers, "
              "--scheduler or --chunk) is built chunk by chunk on Dask, bitwise equal to the "
              "in-memory build; rerun an interrupted chunked build to resume it.")
stage_command(terrain, "fill", specs.FillSpec, output="store", execution="dem",
              help="Fill DEM gaps with fractal terrain (and craters), keeping every known "
              "height.")
stage_command(terrain, "rocks", specs.RocksSpec, catalog=True,
              help="Stand a rock field (VIPER lunar laws, Golombek-Rapp for Mars, or a power "
              "law; block fields on fresh craters) on a DEM, keyed by position.")
stage_command(terrain, "hazards", specs.HazardsSpec,
              help="Hazard truth: slope of the plane under a lander, height above it, safe or "
              "not. SOURCE is a DEM or a layer-stack folder. Writes a GeoTIFF with three bands "
              "(slope in degrees, step in metres, safe 1 / unsafe 0; NaN where the footprint "
              "is not fully known), the safe fraction in its tags, and a PNG.")


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
