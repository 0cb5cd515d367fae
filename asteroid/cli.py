r"""The ``craterscape asteroid`` commands.

They are registered through the ``craterscape.groups`` entry point, so the root command in
:mod:`terrain.cli.commands` never imports this package.

::

    craterscape asteroid build -o BODY.ply --magnitude M --radius R \
        --base perlin|faulting|shape:FILE --seed S [--stretch A,B,C] \
        [--craters SPEC] [--boulders SPEC] [--config FILE.toml] [--preset NAME]
    craterscape asteroid export BODY.npz -o BODY.glb [--level L] [--no-boulders]
    craterscape asteroid info BODY.npz
    craterscape asteroid presets

Errors craterscape raises on purpose become one line on stderr and exit code 2 (the root
group does this; ``-v`` shows the traceback).
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import click

from terrain.cli.tools import progress_bar
from terrain.core.errors import InvalidParameterError

__all__ = ["asteroid"]

log = logging.getLogger(__name__)


@click.group()
def asteroid():
    """Asteroid models: sphere mesh, bases, craters, boulders, mesh files."""


@asteroid.command()
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Mesh file (.ply, .obj, .stl, .glb) or .npz for the native model only. "
                   "The native BODY.npz and the catalogues BODY_craters.csv and "
                   "BODY_boulders.csv are written beside it; an earlier build's BODY mesh or "
                   "catalogue that this one does not write is removed.")
@click.option("--magnitude", type=int, default=None,
              help="M: rings per hemisphere; the mesh has 6 M^2 + 2 vertices.")
@click.option("--radius", type=float, default=None,
              help="Reference radius R in metres (a shape model keeps its own size if absent: "
                   "it is then scaled to this volume-equivalent radius).")
@click.option("--base", type=str, default=None,
              help="perlin, faulting or shape:FILE (an OBJ/PLY/STL shape model).")
@click.option("--seed", type=click.IntRange(0, 2**63 - 1), default=None,
              help="Keys every random draw (default 0).")
@click.option("--stretch", type=str, default=None, help="Affine stretch A,B,C along x, y, z.")
@click.option("--craters", "craters", type=str, default=None,
              help="Crater population: key=value,... (c or density, k, dmin, dmax, max_age, "
                   "max_extent_deg, slope_start_deg, slope_stop_deg, roughness, ...), "
                   "'paper' (N_cum = 0.5 D^-2) or 'none'.")
@click.option("--boulders", "boulders", type=str, default=None,
              help="Boulder population: key=value,... (c or density, k, dmin, dmax, levels, "
                   "max_burial, flattening=LO:HI, ...) or 'none'.")
@click.option("--config", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="TOML recipe (flags override it; see asteroid/recipe.py).")
@click.option("--preset", type=str, default=None,
              help="Start from a preset of the paper's examples (see 'asteroid presets').")
@click.option("--shape-units", type=click.Choice(["km", "m"]), default=None,
              help="Units of the shape model file (default km, as PDS shape models).")
@click.option("--shape-centre", type=str, default=None,
              help="Body centre of a shape model: centroid (default), origin, or X,Y,Z in the "
                   "file's units.")
def build(output, magnitude, radius, base, seed, stretch, craters, boulders, config, preset,
          shape_units, shape_centre):
    """Build an asteroid model and write its mesh, native model and catalogues."""
    from asteroid.build import build as run_build
    from asteroid.build import output_paths, write_outputs
    from asteroid.recipe import Recipe, parse_spec

    shape = {}
    if shape_units is not None:
        shape["units"] = shape_units
    if shape_centre is not None:
        if shape_centre in ("centroid", "origin"):
            shape["centre"] = shape_centre
        else:
            try:
                shape["centre"] = [float(v) for v in shape_centre.split(",")]
                if len(shape["centre"]) != 3 or not all(map(math.isfinite, shape["centre"])):
                    raise ValueError
            except ValueError:
                raise InvalidParameterError(
                    f"--shape-centre must be centroid, origin or X,Y,Z; got {shape_centre!r}") \
                    from None
    crater_spec = None if craters is None else (parse_spec(craters, "craters") or "none")
    boulder_spec = None if boulders is None else (parse_spec(boulders, "boulders") or "none")
    recipe = Recipe.from_sources(
        preset=preset, config=config, magnitude=magnitude, radius=radius, base=base, seed=seed,
        stretch=stretch, craters=crater_spec, boulders=boulder_spec,
        shape=shape or None)
    inputs = [p for p in (config, recipe.shape_file) if p is not None]
    paths = output_paths(output, craters=recipe.craters is not None,
                         boulders=recipe.boulders is not None, inputs=inputs)
    with progress_bar("asteroid", "step") as update:
        result = run_build(recipe, progress=update)
    written = write_outputs(result, paths, inputs=inputs)
    r = result.report
    extra = []
    if "craters" in r:
        extra.append(f"{r['craters_applied']} of {r['craters']} craters applied")
    if "boulders" in r:
        extra.append(f"{r['boulders']} boulders")
    if "non_star_fraction" in r:
        extra.append(f"{100 * r['non_star_fraction']:.3f} % of directions not star-shaped")
    click.echo(f"wrote {', '.join(str(p) for p in written)} ({r['vertices']:,} vertices"
               + "".join(f"; {e}" for e in extra) + ")", err=True)


@asteroid.command()
@click.argument("model", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Mesh file: .ply, .obj, .stl or .glb.")
@click.option("--level", type=int, default=None,
              help="Boulder level of detail (default the finest).")
@click.option("--no-boulders", is_flag=True, help="Write the body alone.")
def export(model, output, level, no_boulders):
    """Write a native model (.npz, lat/lon or mesh body) as a mesh file."""
    from asteroid.build import export_model

    export_model(model, output, boulders=not no_boulders, level=level)
    click.echo(f"wrote {output}", err=True)


@asteroid.command()
@click.argument("model", type=click.Path(path_type=Path))
def info(model):
    """Describe a native model (either kind): size, volume, catalogues, provenance (JSON)."""
    from asteroid.build import describe_model

    click.echo(json.dumps(describe_model(model), indent=2, default=float))


@asteroid.command()
def presets():
    """List the presets (JSON): the paper's Fig. 5 Perlin bases and Fig. 9 faulting model."""
    from asteroid.recipe import PRESETS

    click.echo(json.dumps(PRESETS, indent=2))
