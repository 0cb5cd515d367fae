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

__all__ = ["OUTPUTS", "spec_options", "stage_command"]

_FILE = click.Path(dir_okay=False, path_type=Path)
_TYPES = {"int": click.INT, "float": click.FLOAT, "text": click.STRING, "pair": PAIR,
          "window": WINDOW, "path": _FILE}
_SAFE = "Output GeoTIFF (written atomically; never over an input)"
#: The click type and help of ``-o`` for each kind of output.
OUTPUTS = {"dem": (_FILE, _SAFE + "."),
           "store": (click.Path(path_type=Path), _SAFE + ", or a Zarr store (NAME.zarr: a "
                     "chunked run, resumed if it exists)."),
           "png": (_FILE, "Output PNG (8-bit grey)."),
           "stack": (click.Path(file_okay=False, path_type=Path),
                     "Output folder for the layer stack (new or empty).")}


def spec_options(spec: type, skip: tuple = ()) -> Callable[[Any], Any]:
    """Return a decorator adding one ``--option`` per field of a spec (its own fields first)."""
    options = []
    own = spec.__dict__.get("__annotations__", {})
    for field in sorted(dataclasses.fields(spec), key=lambda f: f.name not in own):
        if field.name in skip:
            continue
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

    ``output`` is the kind of ``-o`` (a key of :data:`OUTPUTS`), ``source`` whether it reads
    an input (the ``SOURCE`` argument), ``catalog`` whether it takes ``--catalog``;
    ``execution`` ``"dem"`` adds every option of :class:`~.runner.Execution`, ``"stack"`` all
    but ``--cog``, None none.
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

    out_type, out_help = OUTPUTS[output]
    params = [click.option("-o", "--output", required=True, type=out_type, help=out_help),
              spec_options(spec)]
    if execution is not None:
        params.append(spec_options(Execution, skip=("cog",) if execution == "stack" else ()))
    if catalog:
        params.insert(1, click.option("--catalog", type=_FILE, default=None,
                                      help="Write the catalogue (CSV) here."))
    if source:
        params.insert(0, click.argument("source", type=click.Path(path_type=Path)))
    return group.command(name, help=help)(with_options(params)(command))
