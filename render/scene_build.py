"""Building a scenario's scene from its recipe, so a scenario runs where its scene is missing.

A scenario's ``[scene]`` names a layer stack (terrain) or an asteroid body (``.npz``). A
``[scene.build]`` table adds the recipe of that scene: the ``craterscape`` options that make
it, so the scenario runs on a fresh clone. Terrain scenes are a synthetic base enhanced in
nested layers around a site (what ``make demo``'s first two stages do)::

    [scene]
    type = "terrain"
    stack = "scenes/descent_stack"     # built here when it is missing

    [scene.build]
    seed = 2014                        # --seed of both commands (default 0)

    [scene.build.base]                 # `craterscape terrain synth` options
    body = "moon"
    size = 257
    resolution = 1000.0

    [scene.build.stack]                # `craterscape terrain enhance` options
    site = [128500.0, 128500.0]        # or site_lonlat = [lon, lat]; required
    levels = 8                         # layer_size: the base's size unless given

Asteroid scenes are one ``craterscape asteroid build``::

    [scene.build.body]                 # `craterscape asteroid build` options
    config = "eros_like.toml"          # paths relative to the scenario file
    magnitude = 96

Option names are those of the command's long options (``--fractal-dimension`` is
``fractal_dimension``; a flag is ``true``; a list is joined with commas); unknown names are
refused with the nearest valid one and values are checked when the scenario is parsed. The
output options are the builder's: ``-o`` is where ``[scene]`` says the scene lives, and a
terrain base is kept beside its stack (``STACK.base.tif``, its craters in
``STACK.base_craters.csv``).

The cache is the scene itself. :func:`ensure_scene` builds a missing scene where the
scenario says it lives and writes a stamp beside it (``STACK.build.json`` or
``BODY.npz.build.json``) holding the recipe's key (a hash of the recipe and of the files it
names) and the build's seconds. A scene that exists is used: as it is when it has no stamp
(it was made otherwise, e.g. by ``make demo``), and built again when its stamp holds another
key (the recipe changed). The build is deterministic (every draw is keyed by the seed: the
same recipe gives the same heights) and every file is written atomically; the stamp says
``building`` until the scene is whole, so a build killed part-way is done again. A build
holds a lock beside the scene (``STACK.build.lock``): a second run of the scenario started
meanwhile waits for it, then uses the scene it built. Every step is reported in the log.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from render.records import check_keys
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import remove_path
from terrain.core.rng import check_seed

if TYPE_CHECKING:  # pragma: no cover
    from render.scenario import Scenario

__all__ = ["SceneBuild", "ensure_scene", "stamp_path"]

log = logging.getLogger(__name__)

#: The commands a recipe's tables hold the options of, by scene type and table.
COMMANDS = {"terrain": {"base": ("terrain", "synth"), "stack": ("terrain", "enhance")},
            "asteroid": {"body": ("asteroid", "build")}}
#: Options the builder sets itself (the outputs, and the terrain recipe's one seed).
BUILDER_OPTIONS = {"base": frozenset({"output", "catalog", "seed"}),
                   "stack": frozenset({"output", "seed"}), "body": frozenset({"output"})}
#: Version of the build procedure, part of every recipe's key.
BUILD_VERSION = 1


def _parameters(command: click.Command) -> dict[str, click.Parameter]:
    """Return the command's parameters by long-option name (``fractal_dimension``)."""
    return {o[2:].replace("-", "_"): p for p in command.params for o in getattr(p, "opts", ())
            if o.startswith("--")}


def _check_value(key: str, value: Any, param: click.Parameter, where: str) -> Any:
    """Return a TOML value for ``param``, checked as its command line would check it."""
    label = f"scenario {where}.{key}"
    if isinstance(param, click.Option) and param.is_flag:
        if not isinstance(value, bool):
            raise InvalidParameterError(f"{label} is a flag: true or false; got {value!r}")
        return value
    if isinstance(value, (dict, bool)) or value is None:
        raise InvalidParameterError(f"{label} must be a number, a string or a list; "
                                    f"got {value!r}")
    if isinstance(value, list):
        if not all(isinstance(v, (int, float, str)) and not isinstance(v, bool) for v in value):
            raise InvalidParameterError(f"{label} must be a list of numbers; got {value!r}")
        text: Any = ",".join(str(v) for v in value)
    else:
        text = value
    if isinstance(param.type, click.Path):
        if not isinstance(value, str):
            raise InvalidParameterError(f"{label} must be a path (a string); got {value!r}")
        return value  # resolved against the scenario and checked when the scene is built
    try:
        param.type.convert(text, param, None)
    except click.BadParameter as exc:
        raise InvalidParameterError(f"{label}: {exc.format_message()}") from None
    return value


@dataclass(frozen=True)
class SceneBuild:
    """A scenario's ``[scene.build]``: the recipe of its scene (see the module docstring).

    Parameters
    ----------
    type : {"terrain", "asteroid"}
        The scene's type (``[scene] type``).
    seed : int
        Terrain: ``--seed`` of ``terrain synth`` and ``terrain enhance``.
    base : dict
        Terrain: ``craterscape terrain synth`` options, by long-option name.
    stack : dict
        Terrain: ``craterscape terrain enhance`` options (``site`` or ``site_lonlat``).
    body : dict
        Asteroid: ``craterscape asteroid build`` options (``config`` and other paths
        relative to the scenario file).
    """

    type: str
    seed: int = 0
    base: dict = field(default_factory=dict)
    stack: dict = field(default_factory=dict)
    body: dict = field(default_factory=dict)

    @classmethod
    def from_mapping(cls, table: Any, scene_type: str) -> SceneBuild:
        """Return the record of a ``[scene.build]`` table, checked against the commands.

        Parameters
        ----------
        table : dict
            The TOML table.
        scene_type : {"terrain", "asteroid"}
            The scene's type, which decides the tables allowed.

        Returns
        -------
        SceneBuild
            The checked recipe.

        Raises
        ------
        terrain.core.errors.InvalidParameterError
            An unknown key (named with the nearest valid one), a value its command would
            refuse, or a missing table or site.
        """
        from terrain.cli.tools import command

        names = COMMANDS[scene_type]
        allowed = set(names) | ({"seed"} if scene_type == "terrain" else set())
        t = check_keys(table, allowed, "scenario [scene.build]")
        values: dict[str, Any] = {"type": scene_type}
        for name in names:
            if name not in t:
                raise InvalidParameterError(
                    f"scenario [scene.build] of a {scene_type} scene needs a "
                    f"[scene.build.{name}] table of `craterscape {' '.join(names[name])}` "
                    "options")
            where = f"[scene.build.{name}]"
            params = _parameters(command(*names[name]))
            options = check_keys(t[name], set(params) - BUILDER_OPTIONS[name],
                                 f"scenario {where}")
            values[name] = {k: _check_value(k, v, params[k], where) for k, v in options.items()}
        if "seed" in t:
            try:
                values["seed"] = check_seed(t["seed"])
            except ValueError as exc:
                raise InvalidParameterError(f"scenario [scene.build] seed: {exc}") from None
        if scene_type == "terrain" and not {"site", "site_lonlat"} & set(values["stack"]):
            raise InvalidParameterError(
                "scenario [scene.build.stack] needs site = [x, y] (map metres) or "
                "site_lonlat = [lon, lat] (degrees): where the layers close in")
        return cls(**values)

    def to_mapping(self) -> dict:
        """Return the ``[scene.build]`` table this record was built from.

        Returns
        -------
        dict
            The tables of the scene's type (and the terrain recipe's seed).
        """
        if self.type == "terrain":
            return {"seed": self.seed, "base": dict(self.base), "stack": dict(self.stack)}
        return {"body": dict(self.body)}

    def key(self, folder: Path) -> str:
        """Return the recipe's key: a hash of its tables and of the files they name.

        Parameters
        ----------
        folder : pathlib.Path
            The scenario's folder, which paths in the recipe are relative to.

        Returns
        -------
        str
            A SHA-256 hex digest; a stamp with another key means another recipe.
        """
        files = {}
        for name, options in self._tables().items():
            for k, path in self._paths(name, options, folder).items():
                files[f"{name}.{k}"] = (hashlib.sha256(path.read_bytes()).hexdigest()
                                        if path.is_file() else None)
        text = json.dumps({"recipe": self.to_mapping(), "files": files,
                           "version": BUILD_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def _tables(self) -> dict[str, dict]:
        return {name: getattr(self, name) for name in COMMANDS[self.type]}

    def _paths(self, name: str, options: dict, folder: Path) -> dict[str, Path]:
        """Return the options of ``name`` that are paths, resolved against the scenario's folder."""
        from terrain.cli.tools import command

        params = _parameters(command(*COMMANDS[self.type][name]))
        return {k: folder / v for k, v in options.items()
                if isinstance(params[k].type, click.Path)}

    def arguments(self, name: str, folder: Path) -> list:
        """Return the command-line options of table ``name``, paths resolved.

        Parameters
        ----------
        name : {"base", "stack", "body"}
            The table.
        folder : pathlib.Path
            The scenario's folder.

        Returns
        -------
        list
            Arguments for :func:`terrain.cli.tools.run_command` (the seed included for
            terrain tables).
        """
        from terrain.cli.tools import cli_args

        options = dict(getattr(self, name))
        options.update({k: str(p) for k, p in self._paths(name, options, folder).items()})
        if self.type == "terrain":
            options["seed"] = self.seed
        return cli_args(options)


def stamp_path(scene: Path) -> Path:
    """Return the stamp of a built scene: ``STACK.build.json`` or ``BODY.npz.build.json``.

    Parameters
    ----------
    scene : pathlib.Path
        The layer-stack folder or the body file.

    Returns
    -------
    pathlib.Path
        The stamp beside it.
    """
    return scene.with_name(scene.name + ".build.json")


def _stamped_key(stamp: Path) -> str | None:
    """Return the key of a finished build's stamp; ``""`` for a build that did not finish."""
    try:
        doc = json.loads(stamp.read_text(encoding="utf-8"))
        return "" if doc.get("building") else str(doc["key"])
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return ""


def _write_stamp(stamp: Path, doc: dict) -> None:
    from terrain.io import atomic_path

    with atomic_path(stamp) as tmp:
        tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")


def ensure_scene(scenario: Scenario) -> Path | None:
    """Build the scenario's scene from its ``[scene.build]`` recipe where it is missing.

    Parameters
    ----------
    scenario : render.scenario.Scenario
        A parsed scenario.

    Returns
    -------
    pathlib.Path or None
        The scene (the stack folder or the body file) when the scenario has a recipe,
        None when it has none (the scene is then whatever the scenario names).

    Raises
    ------
    terrain.core.errors.CraterscapeError
        When a build command refuses the recipe (one line naming the problem).
    """
    spec = scenario.scene
    recipe = spec.build
    if recipe is None:
        return None
    where = spec.stack if spec.type == "terrain" else spec.body
    assert where is not None  # required of each scene type by SceneSpec.from_mapping
    target = scenario.resolve(where)
    shown = os.path.normpath(target)  # in messages: demo-output/..., not examples/../demo-output
    folder = scenario.path.parent if scenario.path is not None else Path.cwd()
    key = recipe.key(folder)
    stamp = stamp_path(target)
    if target.exists() and _stamped_key(stamp) in (None, key):
        return _use(target, stamp, shown)
    target.parent.mkdir(parents=True, exist_ok=True)
    with _build_lock(target, shown):
        if target.exists():  # another run may have built it while this one waited
            stamped = _stamped_key(stamp)
            if stamped in (None, key):
                return _use(target, stamp, shown)
            log.warning("scene %s was built from another recipe, or its build did not "
                        "finish: building it again", shown)
            remove_path(target)
        return _build(scenario, target, key, shown, folder)


def _use(target: Path, stamp: Path, shown: str) -> Path:
    """Return a scene that exists, saying why it is used."""
    if _stamped_key(stamp) is None:
        log.info("scene %s exists and was not built from a recipe: used as it is", shown)
    else:
        log.info("scene %s was built from this scenario's recipe: reused", shown)
    return target


@contextlib.contextmanager
def _build_lock(target: Path, shown: str) -> Iterator[None]:
    """Hold the scene's build lock (``STACK.build.lock`` beside it) while building it.

    A second run of the scenario waits here for the first to finish, then uses its scene.
    The lock file stays: removing it would let a third run lock a file the second no longer
    sees.
    """
    import fcntl

    lock = target.with_name(target.name + ".build.lock")
    with open(lock, "a+b") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log.warning("scene %s is being built by another run: waiting for it", shown)
            fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _build(scenario: Scenario, target: Path, key: str, shown: str, folder: Path) -> Path:
    """Build the scene at ``target`` from the scenario's recipe (the build lock is held)."""
    from terrain.cli.tools import run_command
    from terrain.io import read_dem

    spec = scenario.scene
    recipe = spec.build
    assert recipe is not None
    stamp = stamp_path(target)
    log.warning("scene %s is missing: building it from the scenario's [scene.build] recipe "
                "(kept there for later runs)", shown)
    _write_stamp(stamp, {"key": key, "building": True})  # until the scene is whole
    t0 = time.perf_counter()
    if spec.type == "terrain":
        base = target.with_name(target.name + ".base.tif")
        run_command("terrain", "synth", "-o", base, *recipe.arguments("base", folder),
                    "--catalog", target.with_name(target.name + ".base_craters.csv"))
        stack_args = recipe.arguments("stack", folder)
        if "layer_size" not in recipe.stack:  # layers as large as the base, as make demo's
            stack_args += ["--layer-size", read_dem(base).shape[0]]
        run_command("terrain", "enhance", base, "-o", target, *stack_args)
    else:
        run_command("asteroid", "build", "-o", target, *recipe.arguments("body", folder))
    seconds = time.perf_counter() - t0
    _write_stamp(stamp, {"key": key, "seconds": round(seconds, 3),
                         "recipe": recipe.to_mapping()})
    log.warning("built scene %s in %.0f s", shown, seconds)
    return target
