"""The ``craterscape`` command: the root group, its error policy, -v/-q and SIGTERM.

The root lives in the lowest layer and discovers the stage groups through the
``craterscape.groups`` entry points, so ``terrain`` never imports a higher package (rasterio's
``rio`` registers its subcommands the same way). Errors that craterscape raises on purpose
become one line on stderr and exit code 2; ``-v`` shows the traceback.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import traceback
from importlib.metadata import entry_points

import click

from terrain.cli.tools import FINITE, version_option
from terrain.core.errors import CraterscapeError, InvalidParameterError
from terrain.core.outputs import cannot_write, is_write_error, protected, remove_temporaries

__all__ = ["main"]

ENTRY_POINT_GROUP = "craterscape.groups"
EXIT_BAD_INPUT = 2
#: Exit code after SIGTERM (128 + 15, as a shell reports it).
EXIT_TERMINATED = 143
#: Path parameters that name what a command writes; every other path parameter is an input
#: that no output may replace or enter (:func:`terrain.core.outputs.protect`).
OUTPUT_PARAMS = frozenset({"output", "catalog", "cog", "png"})
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
