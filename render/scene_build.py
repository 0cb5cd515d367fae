"""Building a scenario's scene from its recipe, so a scenario runs where its scene is missing.

A scenario's ``[scene]`` names a layer stack (terrain) or an asteroid body (``.npz``). A
``[scene.build]`` table adds the recipe of that scene: the ``craterscape`` options that make
it, so the scenario runs on a fresh clone. Terrain scenes are a synthetic base enhanced in
nested layers around a site (what ``make demo``'s first two stages do)::

    [scene]
    type = "terrain"
    stack = "scenes/descent_stack"     # built here when it is missing

    [scene.build]
    seed = 2014                        # the seed of both stages (default 0)

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

The terrain tables are the stages' specs (:class:`terrain.stages.specs.SynthSpec` and
:class:`~terrain.stages.specs.EnhanceSpec`, whose field names are the commands' long options:
``--fractal-dimension`` is ``fractal_dimension``, a flag is ``true``, a pair a list); the body
table is ``asteroid build``'s options, read into an :class:`asteroid.recipe.Recipe`. Every
value is checked when the scenario is parsed, an unknown key refused with the nearest valid
one, so a recipe its stages would refuse leaves nothing behind. The outputs and the seed are
the builder's: the scene goes where ``[scene]`` says it lives, and a terrain base is kept
beside its stack (``STACK.base.tif``, its craters, where it has any, in
``STACK.base_craters.csv``). Nothing here calls the command line: the builds run through
:func:`terrain.stages.runner.run` and :mod:`asteroid.build`, the functions
:mod:`evaluation.campaign` shares (:func:`terrain_specs`, :func:`synth_then_enhance`).

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
import dataclasses
import hashlib
import json
import logging
import os
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from terrain.core import checks
from terrain.core.checks import check_keys
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import remove_path
from terrain.core.rng import check_seed

if TYPE_CHECKING:  # pragma: no cover
    from asteroid.recipe import Recipe
    from render.scenario import Scenario
    from terrain.stages.specs import EnhanceSpec, SynthSpec

__all__ = ["BODY_KEYS", "SceneBuild", "body_recipe", "build_body", "ensure_scene",
           "stamp_path", "synth_then_enhance", "terrain_specs"]

log = logging.getLogger(__name__)

#: The tables of a recipe, by scene type.
TABLES = {"terrain": ("base", "stack"), "asteroid": ("body",)}
#: The keys of a body table: ``craterscape asteroid build``'s long options but ``--output``.
BODY_KEYS = frozenset({"config", "preset", "magnitude", "radius", "base", "seed", "stretch",
                       "craters", "boulders", "shape_units", "shape_centre"})
#: Version of the build procedure, part of every recipe's key.
BUILD_VERSION = 1


# ------------------------------------------------------------------ the builds themselves


def terrain_specs(base: Mapping, stack: Mapping, seed: int, where: str, *,
                  site: str = "required") -> tuple[SynthSpec, EnhanceSpec]:
    """Return the specs of a terrain scene's two tables: a base, and its layer stack.

    The tables hold ``terrain synth`` and ``terrain enhance`` fields
    (:mod:`terrain.stages.specs`); the builder sets the seed of both, and the stack's layers
    are as large as the base unless ``layer_size`` says otherwise.

    Parameters
    ----------
    base, stack : mapping
        The tables (field names as the commands' long options, ``-`` as ``_``).
    seed : int
        The seed of both stages.
    where : str
        The tables' place in messages (``"campaign [lunar"``: ``.base]`` and ``.stack]``
        are added).
    site : {"required", "refused"}
        Whether the stack table must give the site (``site`` or ``site_lonlat``), or must not
        (the caller chooses it).

    Returns
    -------
    (SynthSpec, EnhanceSpec)
        The checked specs (the stack's site None where it is refused).

    Raises
    ------
    terrain.core.errors.InvalidParameterError
        An unknown key (named with the nearest valid one), a key the builder sets, a value
        of the wrong type or out of range, or a missing site.
    """
    from terrain.stages.specs import EnhanceSpec, SynthSpec

    owned = {"base": {"seed"}, "stack": {"seed"} | ({"site", "site_lonlat"}
                                                     if site == "refused" else set())}
    specs: dict[str, Any] = {}
    for name, table, cls in (("base", base, SynthSpec), ("stack", stack, EnhanceSpec)):
        label = f"{where}.{name}]"
        fields = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        table = check_keys(table, fields - owned[name], label)
        if name == "stack":
            table = {"layer_size": specs["base"].size, **table}
            if site == "required" and not {"site", "site_lonlat"} & set(table):
                raise InvalidParameterError(
                    f"{label} needs site = [x, y] (map metres) or site_lonlat = [lon, lat] "
                    "(degrees): where the layers close in")
        try:
            specs[name] = cls.from_mapping({**table, "seed": seed})
        except InvalidParameterError as exc:
            raise InvalidParameterError(f"{label}: {exc}") from None
    return specs["base"], specs["stack"]


def synth_base(spec: SynthSpec, output: Path, catalog: Path) -> Path:
    """Write a synthetic base (``terrain synth``) and, where it has craters, their catalogue.

    Parameters
    ----------
    spec : terrain.stages.specs.SynthSpec
        The base.
    output : pathlib.Path
        The GeoTIFF.
    catalog : pathlib.Path
        The crater catalogue (CSV), written only where the base has craters.

    Returns
    -------
    pathlib.Path
        ``output``.
    """
    from terrain.stages.runner import run

    craters = spec.density is not None or spec.population is not None
    log.info("%s", run(spec, None, output, catalog=catalog if craters else None).message)
    return output


def enhance_base(spec: EnhanceSpec, base: Path, output: Path) -> Path:
    """Write the layer stack of a base (``terrain enhance``) into the folder ``output``.

    Returns
    -------
    pathlib.Path
        ``output``.
    """
    from terrain.stages.runner import run

    remove_path(output)  # a stack is written whole, or not at all
    log.info("%s", run(spec, base, output).message)
    return output


def synth_then_enhance(base: SynthSpec, stack: EnhanceSpec, base_tif: Path, stack_dir: Path,
                       catalog: Path) -> Path:
    """Build a terrain scene: a synthetic base, then its layer stack.

    A campaign runs the two halves (:func:`synth_base`, :func:`enhance_base`) as two stages,
    choosing the site between them; a scene recipe gives its site.

    Parameters
    ----------
    base, stack : SynthSpec, EnhanceSpec
        The specs (:func:`terrain_specs`).
    base_tif : pathlib.Path
        The base's GeoTIFF.
    stack_dir : pathlib.Path
        The layer-stack folder.
    catalog : pathlib.Path
        The base's crater catalogue (written where it has craters).

    Returns
    -------
    pathlib.Path
        ``stack_dir``.
    """
    synth_base(base, base_tif, catalog)
    return enhance_base(stack, base_tif, stack_dir)


def _check_body_value(key: str, value: Any, where: str) -> Any:
    """Return a body table's value converted as ``asteroid build``'s option would be."""
    if key == "magnitude":
        return checks.integer(value, key, low=1, where=where)
    if key == "radius":
        return checks.number(value, key, low=0.0, low_open=True, where=where)
    if key == "seed":
        try:
            return check_seed(value)
        except ValueError as exc:
            raise InvalidParameterError(f"{where} seed: {exc}") from None
    if key == "shape_units":
        return checks.text(value, key, choices=("km", "m"), where=where)
    if key in ("stretch", "shape_centre") and isinstance(value, list):
        return list(checks.vector(value, key, 3, where=where))
    if key in ("craters", "boulders") and isinstance(value, Mapping):
        return dict(value)
    return checks.text(value, key, where=where, empty=False)


def body_recipe(table: Mapping, folder: Path, where: str) -> Recipe:
    """Return the asteroid recipe of a body table (``asteroid build`` options).

    ``config`` (a recipe file, relative to ``folder``) is read first and the other keys
    override it, as the command's flags do (:meth:`asteroid.recipe.Recipe.from_sources`);
    ``craters`` and ``boulders`` are ``key=value,...`` texts, ``"none"``, or tables.

    Parameters
    ----------
    table : mapping
        The body table.
    folder : pathlib.Path
        What relative paths are relative to.
    where : str
        The table's place in messages.

    Returns
    -------
    asteroid.recipe.Recipe
        The checked recipe.
    """
    from asteroid.recipe import Recipe, parse_spec

    t = {k: _check_body_value(k, v, where) for k, v in check_keys(table, BODY_KEYS,
                                                                  where).items()}
    flags: dict[str, Any] = {k: t.get(k) for k in ("magnitude", "radius", "base", "seed",
                                                   "stretch")}
    for key in ("craters", "boulders"):
        value = t.get(key)
        flags[key] = (value if value is None or isinstance(value, dict)
                      else parse_spec(value, key) or "none")
    shape = {k[len("shape_"):]: t[k] for k in ("shape_units", "shape_centre") if k in t}
    config = folder / t["config"] if "config" in t else None
    try:
        return Recipe.from_sources(preset=t.get("preset"), config=config, shape=shape or None,
                                   **flags)
    except InvalidParameterError as exc:
        raise InvalidParameterError(f"{where}: {exc}") from None


def build_body(recipe: Recipe, output: Path, *, inputs: tuple = ()) -> list[Path]:
    """Build an asteroid body and write its files (``asteroid build``'s set).

    Parameters
    ----------
    recipe : asteroid.recipe.Recipe
        The body.
    output : pathlib.Path
        The native model (``.npz``) or a mesh file; catalogues are written beside it.
    inputs : tuple of pathlib.Path
        Files the recipe was read from (never written over).

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    from asteroid.build import build, output_paths, write_outputs
    from terrain.core.outputs import protected

    inputs = (*inputs, *([recipe.shape_file] if recipe.shape_file else []))
    with protected(inputs):  # the build's own inputs, not the caller's (a scenario's scene)
        paths = output_paths(output, craters=recipe.craters is not None,
                             boulders=recipe.boulders is not None, inputs=inputs)
        written = write_outputs(build(recipe), paths, inputs=inputs)
    log.info("wrote %s", ", ".join(map(str, written)))
    return written


# ------------------------------------------------------------------ the recipe


@dataclass(frozen=True)
class SceneBuild:
    """A scenario's ``[scene.build]``: the recipe of its scene (see the module docstring).

    Parameters
    ----------
    type : {"terrain", "asteroid"}
        The scene's type (``[scene] type``).
    seed : int
        Terrain: the seed of the base and the stack.
    base : dict
        Terrain: the base's ``terrain synth`` fields (:class:`terrain.stages.specs.SynthSpec`).
    stack : dict
        Terrain: the stack's ``terrain enhance`` fields (``site`` or ``site_lonlat``).
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
        """Return the record of a ``[scene.build]`` table, every value checked.

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
            An unknown key (named with the nearest valid one), a value its stage would
            refuse, or a missing table or site.
        """
        names = TABLES[scene_type]
        allowed = set(names) | ({"seed"} if scene_type == "terrain" else set())
        t = check_keys(table, allowed, "scenario [scene.build]")
        for name in names:
            if name not in t:
                what = ("terrain synth" if name == "base" else "terrain enhance"
                        if name == "stack" else "asteroid build")
                raise InvalidParameterError(
                    f"scenario [scene.build] of a {scene_type} scene needs a "
                    f"[scene.build.{name}] table of `craterscape {what}` options")
        values: dict[str, Any] = {"type": scene_type}
        if "seed" in t:
            try:
                values["seed"] = check_seed(t["seed"])
            except ValueError as exc:
                raise InvalidParameterError(f"scenario [scene.build] seed: {exc}") from None
        if scene_type == "terrain":
            terrain_specs(t["base"], t["stack"], values.get("seed", 0), "scenario [scene.build")
            values["base"], values["stack"] = dict(t["base"]), dict(t["stack"])
        else:
            where = "scenario [scene.build.body]"
            values["body"] = {k: _check_body_value(k, v, where)
                              for k, v in check_keys(t["body"], BODY_KEYS, where).items()}
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
        for name in TABLES[self.type]:
            for k, path in self._paths(name, folder).items():
                files[f"{name}.{k}"] = (hashlib.sha256(path.read_bytes()).hexdigest()
                                        if path.is_file() else None)
        text = json.dumps({"recipe": self.to_mapping(), "files": files,
                           "version": BUILD_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def _paths(self, name: str, folder: Path) -> dict[str, Path]:
        """Return the keys of table ``name`` that are files, resolved against ``folder``."""
        from terrain.stages.specs import EnhanceSpec, SynthSpec

        options = getattr(self, name)
        if name == "body":
            return {"config": folder / options["config"]} if "config" in options else {}
        cls = SynthSpec if name == "base" else EnhanceSpec
        kinds = {f.name: f.metadata["kind"].cli
                 for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        return {k: folder / v for k, v in options.items() if kinds[k] == "path"}

    def terrain(self, folder: Path) -> tuple[SynthSpec, EnhanceSpec]:
        """Return the specs of a terrain recipe, its paths resolved against ``folder``.

        Returns
        -------
        (SynthSpec, EnhanceSpec)
            The base and the stack (:func:`terrain_specs`).
        """
        paths = {name: {k: str(p) for k, p in self._paths(name, folder).items()}
                 for name in ("base", "stack")}
        return terrain_specs({**self.base, **paths["base"]}, {**self.stack, **paths["stack"]},
                             self.seed, "scenario [scene.build")

    def recipe(self, folder: Path) -> Recipe:
        """Return the asteroid recipe of an asteroid scene (its config read from ``folder``)."""
        return body_recipe(self.body, folder, "scenario [scene.build.body]")


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
    from terrain.core.outputs import atomic_path

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
    spec = scenario.scene
    recipe = spec.build
    assert recipe is not None
    stamp = stamp_path(target)
    if spec.type == "terrain":  # checked before anything is written
        base, stack = recipe.terrain(folder)
    else:
        body = recipe.recipe(folder)
    log.warning("scene %s is missing: building it from the scenario's [scene.build] recipe "
                "(kept there for later runs)", shown)
    _write_stamp(stamp, {"key": key, "building": True})  # until the scene is whole
    t0 = time.perf_counter()
    if spec.type == "terrain":
        synth_then_enhance(base, stack, target.with_name(target.name + ".base.tif"), target,
                           target.with_name(target.name + ".base_craters.csv"))
    else:
        config = recipe.body.get("config")
        build_body(body, target, inputs=() if config is None else (folder / config,))
    seconds = time.perf_counter() - t0
    _write_stamp(stamp, {"key": key, "seconds": round(seconds, 3),
                         "recipe": recipe.to_mapping()})
    log.warning("built scene %s in %.0f s", shown, seconds)
    return target
