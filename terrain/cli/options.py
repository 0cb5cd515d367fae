"""Options of the terrain commands, made from the stage specs' fields.

A spec field (:mod:`terrain.stages.specs`) declares its default, help line and kind once;
:func:`spec_options` turns every field into its ``--option``, and :func:`stage_command` makes a
command that is options -> spec -> :func:`terrain.stages.runner.run`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from terrain.cli.tools import PAIR, WINDOW, progress_bar, with_options

__all__ = ["EXECUTION", "OUTPUTS", "spec_options", "stage_command"]

_TYPES = {"int": click.INT, "float": click.FLOAT, "text": click.STRING, "pair": PAIR,
          "window": WINDOW, "path": click.Path(dir_okay=False, path_type=Path)}

_OUT = "Output {} (written atomically; never over an input)"
#: The ``-o`` of each kind of output.
OUTPUTS = {
    "dem": click.option("-o", "--output", required=True,
                        type=click.Path(dir_okay=False, path_type=Path),
                        help=_OUT.format("GeoTIFF") + "."),
    "store": click.option("-o", "--output", required=True, type=click.Path(path_type=Path),
                          help=_OUT.format("GeoTIFF") + ", or a Zarr store (NAME.zarr: a "
                          "chunked run, resumed if it exists)."),
    "png": click.option("-o", "--output", required=True,
                        type=click.Path(dir_okay=False, path_type=Path),
                        help="Output PNG (8-bit grey)."),
    "stack": click.option("-o", "--output", required=True,
                          type=click.Path(file_okay=False, path_type=Path),
                          help="Output folder for the layer stack (new or empty)."),
}
CATALOG = click.option("--catalog", type=click.Path(dir_okay=False, path_type=Path),
                       default=None, help="Write the catalogue (CSV) here.")


def _execution(lead: str, run: str, pool_note: str = "", cog: bool = True) -> list:
    """--workers, --threads, --scheduler, --chunk (and --cog) of :class:`~.runner.Execution`."""
    return [
        click.option("--workers", type=click.IntRange(1, None), default=None,
                     help=f"{lead} chunk by chunk on a local Dask pool of N workers{pool_note}."),
        click.option("--threads", is_flag=True,
                     help="Local workers are threads of this process instead of processes."),
        click.option("--scheduler", default=None, metavar="tcp://HOST:PORT",
                     help=f"{lead} chunk by chunk on the Dask cluster at this address."),
        click.option("--chunk", type=click.IntRange(16, None), default=None,
                     help=f"Chunk side in pixels (default 1024); implies a chunked {run}."),
        *([click.option("--cog", type=click.Path(dir_okay=False, path_type=Path), default=None,
                        help="After a chunked run, also convert the Zarr output into this "
                             "Cloud Optimized GeoTIFF.")] if cog else []),
    ]


#: The execution options of a chunked DEM command and of `terrain enhance`.
EXECUTION = {"dem": _execution("Run", "run", " (writes Zarr)"),
             "stack": _execution("Build the stack", "build", cog=False)}


def spec_options(spec: type) -> Callable[[Any], Any]:
    """Return a decorator adding one ``--option`` per field of a stage spec, in field order."""
    options = []
    own = spec.__dict__.get("__annotations__", {})  # the stage's own fields first
    for field in sorted(dataclasses.fields(spec), key=lambda f: f.name not in own):
        kind, name = field.metadata["kind"], "--" + field.name.replace("_", "-")
        required = field.default is dataclasses.MISSING
        default = None if required else field.default
        if kind.cli == "flag":
            options.append(click.option(name, is_flag=True, help=field.metadata["help"]))
            continue
        kind_type = (click.Choice(kind.bounds["choices"]) if kind.cli == "choice"
                     else _TYPES[kind.cli])
        options.append(click.option(name, type=kind_type, default=default, required=required,
                                    show_default=default is not None,
                                    help=field.metadata["help"]))
    return with_options(options)


def stage_command(group: click.Group, name: str, spec: type, *, help: str,  # noqa: A002
                  output: str = "dem", source: bool = True, catalog: bool = False,
                  execution: str | None = None) -> click.Command:
    """Add to ``group`` the command ``name``: options -> ``spec`` -> :func:`~.runner.run`.

    Parameters
    ----------
    group : click.Group
        The group it joins.
    name : str
        The command's name.
    spec : type
        Its stage spec; every field becomes an option.
    help : str
        The command's help.
    output : str
        The kind of ``-o`` (a key of :data:`OUTPUTS`).
    source : bool
        Whether it reads an input (the ``SOURCE`` argument).
    catalog : bool
        Whether it takes ``--catalog``.
    execution : str, optional
        Its execution options (a key of :data:`EXECUTION`); none where None.
    """
    from terrain.stages.fields import named_as_options
    from terrain.stages.runner import Execution, run

    names = {f.name for f in dataclasses.fields(Execution)}

    def command(output: Path, source: Path | None = None, catalog: Path | None = None,
                **options: Any) -> None:
        fields = {k: v for k, v in options.items() if k not in names}
        with named_as_options():
            stage = spec.from_mapping(fields)  # type: ignore[attr-defined]
        how = Execution(**{k: v for k, v in options.items() if k in names})
        done = run(stage, source, output, how, catalog=catalog, progress=progress_bar)
        click.echo(done.message, err=True)

    params = [OUTPUTS[output], spec_options(spec), *EXECUTION.get(execution or "", [])]
    if catalog:
        params.insert(1, CATALOG)
    if source:
        params.insert(0, click.argument("source", type=click.Path(path_type=Path)))
    return group.command(name, help=help)(with_options(params)(command))
