"""A campaign: a lunar descent and an asteroid approach, built, rendered and evaluated.

A campaign file (TOML, parsed into a frozen :class:`Campaign`) names what each stage
makes; :func:`run_campaign` runs the stages in order into one output folder:

1. ``lunar/base/``: a synthetic base (``craterscape terrain synth`` with the campaign's
   ``[lunar.base]`` options) and its hillshade.
2. ``lunar/stack/stack/``: the base enhanced in nested layers around the flattest spot
   near its centre (:func:`terrain.surface.site.landing_site`; ``craterscape terrain enhance``
   with the ``[lunar.stack]`` options).
3. ``lunar/run/run/``: the descent scenario rendered onto that stack, under the sun azimuth
   that lights the site (:func:`terrain.surface.site.lit_sun_azimuth`); ``lunar/closed_loop/``: a
   landing flown through ``craterscape render serve`` by the ``[lunar.closed_loop]`` script
   (``examples/closed_loop.py``: guidance that sees only the altimeter and the camera).
4. ``asteroid/body/``: a body built from the ``[asteroid.body]`` recipe, with a PLY copy.
5. ``asteroid/run/run/``: the approach scenario rendered around it.
6. ``evaluation/``: feature tracks of both runs against truth, slope distributions and
   spectra of every layer, comparisons with real DEMs where the shared data folder holds
   them, the hazard map of the site, the asteroid's slopes against real Eros, and
   ``report.html``.

Each stage is skipped when its marker (``.<stage with _>.done.json``) holds the key of the
same parameters; a stage interrupted part-way resumes where it can (rendering) or starts
again. ``campaign.json`` (``demo.json`` for the demo) holds the time of every stage. Nothing
outside the output folder is written, and every file is written atomically.

A campaign removes only what a campaign wrote: the output folder holds
``.craterscape-campaign`` (written before the first stage) and every stage folder its
``.stage-key``. A non-empty folder without the first is refused, and so is a stage folder
without the second, so a campaign pointed at a home directory writes and removes nothing.

Scenario overrides (the scene, the sun, ``--quick``'s frames and image size) are merged
into the scenario's tables and parsed by :func:`render.scenario.parse_scenario`; the
scenario as run is written beside the run.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

from render.scene_build import (
    BODY_KEYS,
    body_recipe,
    build_body,
    enhance_base,
    synth_base,
    terrain_specs,
)
from terrain.core.checks import check_keys, number
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import remove_path
from terrain.core.tomlfile import merge_tables, read_toml, toml_text

if TYPE_CHECKING:  # pragma: no cover
    from asteroid.recipe import Recipe
    from terrain.stages.specs import EnhanceSpec, SynthSpec

__all__ = ["STAGES", "Campaign", "Stage", "claim_output", "load_campaign", "run_campaign"]

log = logging.getLogger(__name__)

#: The stages in the order they run (their markers are ``.<stage with _>.done.json``).
STAGES = ("lunar/base", "lunar/stack", "lunar/run", "lunar/closed_loop", "asteroid/body",
          "asteroid/run", "evaluation")

#: The file that marks a folder as a campaign's output (see :func:`claim_output`).
CAMPAIGN_MARKER = ".craterscape-campaign"
#: The file that marks a stage's folder as written by a campaign (its key).
STAGE_STAMP = ".stage-key"
_TOP = {"title", "seed", "summary", "lunar", "asteroid", "evaluation", "quick"}
_RUN_KEYS = {"scenario", "frames", "image", "sun_elevation"}
_LOOP_KEYS = {"script", "size", "dt"}
_EVAL_KEYS = {"shared_data", "ldem", "sfs", "eros", "eros_density", "eros_period_h",
              "lander_diameter", "max_slope", "max_step"}


def _optional_int(table: dict, key: str, where: str) -> int | None:
    if key not in table:
        return None
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise InvalidParameterError(f"{where} {key} must be a positive integer; got {v!r}")
    return v


@dataclass(frozen=True)
class RunSpec:
    """A rendered run of a campaign: its scenario and what the campaign overrides in it.

    Attributes
    ----------
    scenario : pathlib.Path
        The scenario file (its scene is replaced by the campaign's own).
    frames : int or None
        Frame count override.
    image : int or None
        Square image side override (pixels; field of view kept).
    sun_elevation : float or None
        Sun elevation (degrees) under which the lit azimuth is chosen (terrain runs).
    """

    scenario: Path
    frames: int | None = None
    image: int | None = None
    sun_elevation: float | None = None

    @classmethod
    def from_mapping(cls, table, where: str, folder: Path) -> RunSpec:
        """Build from a campaign table (paths relative to ``folder``); see :class:`Campaign`."""
        t = check_keys(table, _RUN_KEYS, where)
        if "scenario" not in t or not isinstance(t["scenario"], str):
            raise InvalidParameterError(f"{where} needs scenario = \"FILE.toml\"")
        elev = t.get("sun_elevation")
        return cls(folder / t["scenario"], _optional_int(t, "frames", where),
                   _optional_int(t, "image", where),
                   None if elev is None else number(elev, "sun_elevation", low=0.0,
                                                    low_open=True, high=90.0, where=where))

    def overrides(self) -> dict:
        """Return the scenario tables this run overrides (frames and image size)."""
        out: dict = {}
        if self.frames is not None:
            out["trajectory"] = {"frames": self.frames}
        if self.image is not None:
            out["camera"] = {"width": self.image, "height": self.image}
        return out


@dataclass(frozen=True)
class Campaign:
    """A campaign file, parsed and checked (see the module docstring).

    Attributes
    ----------
    title : str
        The report's title.
    seed : int
        Seed of the base and the stack (``--seed`` of synth and enhance).
    summary : str
        The report's opening paragraph.
    base : Mapping
        The ``[lunar.base]`` table: ``terrain synth`` fields of the lunar base (names as
        the command's long options, e.g. ``fractal_dimension``).
    stack : Mapping
        The ``[lunar.stack]`` table: ``terrain enhance`` fields of the layer stack (the
        seed, the site and the layer size are the campaign's).
    lunar_run, asteroid_run : RunSpec
        The descent and the approach.
    body : Mapping
        The ``[asteroid.body]`` table: ``asteroid build`` options (``config`` resolved
        against the campaign file).
    synth : terrain.stages.specs.SynthSpec
        The base's spec (the campaign's seed).
    enhance : terrain.stages.specs.EnhanceSpec
        The stack's spec, but its site (chosen on the base when it is built).
    recipe : asteroid.recipe.Recipe
        The body's recipe.
    evaluation : Mapping
        Real data (``ldem``, ``sfs``, ``eros`` relative to ``shared_data``), Eros's density
        (kg m^-3) and spin period (h), and the lander of the hazard map
        (``lander_diameter`` m, ``max_slope`` degrees, ``max_step`` m).
    closed_loop : Mapping or None
        The closed-loop landing: ``script`` (a Python file with ``main(argv)``, relative to
        the campaign file), its image ``size`` (pixels) and guidance step ``dt`` (s); None:
        no closed loop.
    path : pathlib.Path or None
        The campaign file.
    quick : bool
        Whether the ``[quick]`` tables were merged in (a reduced campaign).
    """

    title: str
    seed: int
    summary: str
    base: Mapping
    stack: Mapping
    lunar_run: RunSpec
    body: Mapping
    asteroid_run: RunSpec
    synth: SynthSpec
    enhance: EnhanceSpec
    recipe: Recipe
    evaluation: Mapping = field(default_factory=dict)
    closed_loop: Mapping | None = None
    path: Path | None = None
    quick: bool = False

    @classmethod
    def from_mapping(cls, data, path=None, *, quick: bool = False) -> Campaign:
        """Build a campaign from its parsed TOML; ``quick`` merges the ``[quick]`` tables in.

        Parameters
        ----------
        data : dict
            The campaign file's tables.
        path : path-like, optional
            The file, which relative paths are resolved against.
        quick : bool, optional
            Merge the ``[quick]`` tables over the others (a reduced campaign).

        Returns
        -------
        Campaign
            The checked record.
        """
        from terrain.core.rng import check_seed

        data = check_keys(data, _TOP, "campaign")
        if quick:
            data = merge_tables(data, check_keys(data.get("quick", {}), _TOP - {"quick"},
                                                 "campaign [quick]"))
        folder = Path(path).resolve().parent if path is not None else Path.cwd()
        lunar = check_keys(data.get("lunar", {}), {"base", "stack", "run", "closed_loop"},
                           "campaign [lunar]")
        ast = check_keys(data.get("asteroid", {}), {"body", "run"}, "campaign [asteroid]")
        try:
            seed = check_seed(data.get("seed", 0))
        except ValueError as exc:
            raise InvalidParameterError(f"campaign seed: {exc}") from None
        for key in ("base", "stack", "run"):
            if key not in lunar:
                raise InvalidParameterError(f"campaign needs a [lunar.{key}] table")
        for key in ("body", "run"):
            if key not in ast:
                raise InvalidParameterError(f"campaign needs an [asteroid.{key}] table")
        synth, enhance = terrain_specs(lunar["base"], lunar["stack"], seed, "campaign [lunar",
                                       site="refused")
        recipe = body_recipe(ast["body"], folder, "campaign [asteroid.body]")
        body = check_keys(ast["body"], BODY_KEYS, "campaign [asteroid.body]")
        if "config" in body:
            body["config"] = str(folder / body["config"])
        evaluation = check_keys(data.get("evaluation", {}), _EVAL_KEYS, "campaign [evaluation]")
        evaluation.setdefault("shared_data", "shared-data")
        loop: Mapping | None = None
        if "closed_loop" in lunar:
            loop = check_keys(lunar["closed_loop"], _LOOP_KEYS, "campaign [lunar.closed_loop]")
            if not isinstance(loop.get("script"), str):
                raise InvalidParameterError("campaign [lunar.closed_loop] needs "
                                            "script = \"FILE.py\"")
            loop["script"] = str(folder / loop["script"])
            loop["size"] = int(number(loop.get("size", 256), "size", low=8,
                                      where="campaign [lunar.closed_loop]"))
            loop["dt"] = number(loop.get("dt", 1.0), "dt", low=0.0, low_open=True,
                                where="campaign [lunar.closed_loop]")
            loop = MappingProxyType(loop)
        return cls(
            title=str(data.get("title", "craterscape campaign")), seed=seed,
            summary=str(data.get("summary", "")),
            base=MappingProxyType(dict(lunar["base"])),
            stack=MappingProxyType(dict(lunar["stack"])),
            synth=synth, enhance=enhance, recipe=recipe,
            lunar_run=RunSpec.from_mapping(lunar["run"], "campaign [lunar.run]", folder),
            body=MappingProxyType(body),
            asteroid_run=RunSpec.from_mapping(ast["run"], "campaign [asteroid.run]", folder),
            evaluation=MappingProxyType(evaluation), closed_loop=loop,
            path=Path(path) if path else None,
            quick=quick)

    def real_data(self, shared: Path | None = None) -> dict:
        """Paths of the real data the report compares with (``ldem``, ``sfs``, ``eros``).

        Parameters
        ----------
        shared : pathlib.Path, optional
            The shared data folder (default: ``shared_data`` of the campaign file).

        Returns
        -------
        dict
            ``{"ldem": Path, "sfs": Path, "eros": Path}``; the files may be absent.
        """
        ev = self.evaluation
        if shared is None:
            base = self.path.resolve().parent if self.path else Path.cwd()
            shared = base / ev["shared_data"]
        shared = Path(os.path.normpath(Path(shared).absolute()))
        return {k: shared / ev[k] for k in ("ldem", "sfs", "eros") if k in ev}


def load_campaign(path, *, quick: bool = False) -> Campaign:
    """Parse and check a campaign file (see :meth:`Campaign.from_mapping`).

    Parameters
    ----------
    path : path-like
        The campaign TOML file.
    quick : bool, optional
        The reduced campaign (the file's ``[quick]`` tables merged in).

    Returns
    -------
    Campaign
        The checked record.
    """
    return Campaign.from_mapping(read_toml(path, "campaign file"), path, quick=quick)


# ------------------------------------------------------------------------------ stages


class Stage:
    """A step whose outputs are complete when its marker file holds the same parameters.

    Parameters
    ----------
    out : pathlib.Path
        The campaign's output folder.
    name : str
        The stage (one of :data:`STAGES`); its folder is ``out / name``.
    params : dict
        Everything the stage's outputs depend on (JSON-able); its hash is the stage's key.
    """

    def __init__(self, out: Path, name: str, params: dict):
        self.dir = out / name
        self.name = name
        self.params = params
        self.marker = out / f".{name.replace('/', '_')}.done.json"
        self.key = hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()

    def done(self) -> bool:
        """Whether the stage's marker holds this key (its outputs are complete)."""
        if not self.marker.exists():
            return False
        try:
            return json.loads(self.marker.read_text())["key"] == self.key
        except (ValueError, KeyError):
            return False

    def begin(self) -> None:
        """Make the stage's folder ready.

        It is kept when it holds a partial run of these same parameters (so rendering resumes),
        emptied when a campaign wrote it for other parameters.

        Raises
        ------
        terrain.core.errors.InvalidParameterError
            When the folder exists but no campaign wrote it (it has no stage stamp).
        """
        stamp = self.dir / STAGE_STAMP
        if stamp.is_file() and stamp.read_text() == self.key:
            return
        if self.dir.is_symlink() or (self.dir.exists() and not stamp.is_file()):
            raise InvalidParameterError(
                f"campaign stage folder '{self.dir}' was not written by a campaign (it has no "
                f"{STAGE_STAMP}): move it away or choose another output folder")
        remove_path(self.dir)
        self.dir.mkdir(parents=True)
        stamp.write_text(self.key)

    def finish(self, seconds: float, **facts) -> dict:
        """Write the marker (atomically) with the key, the stage's seconds and ``facts``."""
        info = dict(key=self.key, seconds=seconds, **facts)
        tmp = self.marker.with_suffix(".partial")
        tmp.write_text(json.dumps(info, indent=2))
        tmp.replace(self.marker)
        return info


def _holds_campaign(out: Path) -> bool:
    """Whether ``out`` is a campaign's folder.

    It is when marked, or when it holds a finished stage's marker (a folder a campaign wrote
    before folders were marked).
    """
    return (out / CAMPAIGN_MARKER).is_file() or any(
        (out / f".{name.replace('/', '_')}.done.json").is_file() for name in STAGES)


def claim_output(out, *, fresh: bool = False) -> Path:
    """Make ``out`` a campaign's output folder, or refuse it before anything is written.

    A missing or empty folder is created and marked (``.craterscape-campaign``); a folder
    already marked is taken as it is. With ``fresh`` the stages a campaign wrote there are
    removed (their folders, which hold a stage stamp, and their markers); nothing else is.

    Parameters
    ----------
    out : path-like
        The output folder.
    fresh : bool, optional
        Remove the finished and partial stages first.

    Returns
    -------
    pathlib.Path
        The folder, resolved.

    Raises
    ------
    terrain.core.errors.InvalidParameterError
        When ``out`` is not a folder, or is a non-empty folder that holds no campaign.
    """
    from terrain.core.outputs import atomic_path

    out = Path(out).expanduser().resolve()
    if out.exists() and not out.is_dir():
        raise InvalidParameterError(f"campaign output '{out}' is not a folder")
    if out.is_dir() and not _holds_campaign(out) and any(out.iterdir()):
        raise InvalidParameterError(
            f"campaign output folder '{out}' is not empty and holds no campaign (no "
            f"{CAMPAIGN_MARKER}): choose a new or empty folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        if not _holds_campaign(out):
            with atomic_path(out / CAMPAIGN_MARKER) as tmp:
                tmp.write_text("A craterscape campaign's output folder (evaluation.campaign): "
                               "a campaign removes only the stage folders it stamped here.\n",
                               encoding="utf-8")
    except OSError as exc:
        raise InvalidParameterError(
            f"cannot write the campaign output folder '{out}': {exc.strerror or exc}") from None
    if fresh:
        for name in STAGES:
            stage_dir = out / name
            if (stage_dir / STAGE_STAMP).is_file() and not stage_dir.is_symlink():
                remove_path(stage_dir)
            remove_path(out / f".{name.replace('/', '_')}.done.json")
            for parent in Path(name).parents[:-1]:  # lunar/, asteroid/ when they are empty
                with contextlib.suppress(OSError):
                    (out / parent).rmdir()
    return out


def write_scenario(template: Path, target: Path, overrides: dict):
    """Return the scenario ``template`` with ``overrides`` merged into its tables.

    The result is checked by the scenario parser and written to ``target`` (the scenario as
    run).

    Parameters
    ----------
    template : pathlib.Path
        A scenario file.
    target : pathlib.Path
        Where the scenario as run is written (atomically).
    overrides : dict
        Tables to merge (e.g. ``{"sun": {"azimuth": 210.0}}``).

    Returns
    -------
    render.scenario.Scenario
        The parsed scenario, read from ``target``.
    """
    from render.scenario import load_scenario, parse_scenario
    from terrain.core.outputs import atomic_path

    data = merge_tables(read_toml(template, "scenario"), overrides)
    if {"stack", "body"} & set(overrides.get("scene", {})):
        data["scene"].pop("build", None)  # the campaign builds the scene the run uses
    parse_scenario(data, target)  # refused before anything is written
    with atomic_path(target) as tmp:
        tmp.write_text(f"# {template.name} as run by a campaign\n" + toml_text(data),
                       encoding="utf-8")
    return load_scenario(target)


def _render(stage: Stage, scenario_file: Path, run_dir: Path) -> dict:
    from render.scenario import load_scenario
    from render.sequence import run_sequence

    t0 = time.perf_counter()
    run_sequence(load_scenario(scenario_file), run_dir, resume=True)
    seconds = time.perf_counter() - t0
    n = len(json.loads((run_dir / "truth.json").read_text()))
    return stage.finish(seconds, frames=n, fps=n / seconds)


def lunar(c: Campaign, out: Path, say: Callable[[str], None]) -> dict:
    """Build the base, the layer stack and the descent (stages 1 to 3).

    Parameters
    ----------
    c : Campaign
        The campaign.
    out : pathlib.Path
        The output folder.
    say : callable
        Called with one line of progress per stage.

    Returns
    -------
    dict
        ``stack`` and ``run``: the layer-stack folder and the run folder.
    """
    from evaluation.slope import horn_slope
    from terrain.io import read_dem
    from terrain.stages.runner import run
    from terrain.stages.specs import EnhanceSpec, HillshadeSpec
    from terrain.surface.site import landing_site, lit_sun_azimuth

    base = Stage(out, "lunar/base", dict(spec=c.synth.as_dict(), v=5))
    base_tif = base.dir / "base.tif"
    if not base.done():
        say(f"lunar 1/3: synthetic base, {c.synth.resolution:g} m per pixel")
        base.begin()
        t0 = time.perf_counter()
        synth_base(c.synth, base_tif, base.dir / "base_craters.csv")
        run(HillshadeSpec.from_mapping({"azimuth": 45.0, "altitude": 10.0}), base_tif,
            base.dir / "base_hillshade.png")
        base.finish(time.perf_counter() - t0)
    tile = read_dem(base_tif)
    site = landing_site(tile, horn_slope(tile))
    enhance = EnhanceSpec.from_mapping({**c.enhance.as_dict(), "site": site})
    stack = Stage(out, "lunar/stack", dict(base=base.key, spec=enhance.as_dict(), v=5))
    stack_dir = stack.dir / "stack"
    if not stack.done():
        say(f"lunar 2/3: enhancing the base in {enhance.levels} nested layers around "
            f"the site ({site[0] / 1000:.1f} km, {site[1] / 1000:.1f} km)")
        stack.begin()
        t0 = time.perf_counter()
        enhance_base(enhance, base_tif, stack_dir)
        stack.finish(time.perf_counter() - t0)
    spec = c.lunar_run
    elevation = spec.sun_elevation
    if elevation is None:
        elevation = read_toml(spec.scenario, "scenario").get("sun", {}).get("elevation", 10.0)
    azimuth = lit_sun_azimuth(tile, site, elevation)
    overrides = merge_tables(spec.overrides(), {
        "scene": {"stack": str(stack_dir)},
        "sun": {"azimuth": float(azimuth), "elevation": elevation}})
    render = Stage(out, "lunar/run", dict(
        stack=stack.key, overrides=overrides,
        scenario=read_toml(spec.scenario, "scenario"), v=2))
    run_dir = render.dir / "run"
    if not render.done():
        say(f"lunar 3/3: rendering the descent (sun azimuth {azimuth:.0f}, elevation "
            f"{elevation:.0f} degrees)")
        render.begin()
        write_scenario(spec.scenario, render.dir / "descent.toml", overrides)
        _render(render, render.dir / "descent.toml", run_dir)
    return {"stack": str(stack_dir), "run": str(run_dir)}


def closed_loop(c: Campaign, out: Path, say: Callable[[str], None]) -> dict | None:
    """Fly a landing through the render server on the descent's scenario (stage 3b).

    The campaign's ``[lunar.closed_loop]`` script is loaded from its file and its
    ``main(argv)`` called with the descent scenario as run, ``--out``, ``--size`` and
    ``--dt``; it writes ``summary.json`` (with ``steps``) into the stage's folder.

    Parameters
    ----------
    c : Campaign
        The campaign.
    out : pathlib.Path
        The output folder (the descent's stage has run).
    say : callable
        Called with one line of progress.

    Returns
    -------
    dict or None
        ``dir``: the stage's folder; None where the campaign has no closed loop.
    """
    import importlib.util

    if c.closed_loop is None:
        return None
    script = Path(c.closed_loop["script"])
    scenario = out / "lunar" / "run" / "descent.toml"
    args = ["--size", c.closed_loop["size"], "--dt", c.closed_loop["dt"]]
    stage = Stage(out, "lunar/closed_loop", dict(
        scenario=scenario.read_text(encoding="utf-8"), args=args,
        code=hashlib.sha256(script.read_bytes()).hexdigest(), v=1))
    if not stage.done():
        say("lunar closed loop: landing from 2 km through the render server")
        stage.begin()
        spec = importlib.util.spec_from_file_location(f"campaign_{script.stem}", script)
        if spec is None or spec.loader is None:
            raise InvalidParameterError(f"cannot load the closed-loop script '{script}'")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        t0 = time.perf_counter()
        module.main([str(scenario), "--out", str(stage.dir), *map(str, args)])
        seconds = time.perf_counter() - t0
        steps = json.loads((stage.dir / "summary.json").read_text())["steps"]
        stage.finish(seconds, frames=steps, fps=steps / seconds)
    return {"dir": str(stage.dir)}


def asteroid(c: Campaign, out: Path, say: Callable[[str], None]) -> dict:
    """Build the body and the approach (stages 4 and 5); see :func:`lunar` for the parameters.

    Returns
    -------
    dict
        ``body`` and ``run``: the body's ``.npz`` and the run folder.
    """
    from asteroid.build import export_model

    recipe = Path(c.body["config"]).read_text(encoding="utf-8") if "config" in c.body else ""
    body = Stage(out, "asteroid/body", dict(
        recipe=recipe, options={k: v for k, v in c.body.items() if k != "config"}, v=2))
    body_npz = body.dir / "body.npz"
    if not body.done():
        say("asteroid 1/2: building an Eros-like body (Perlin base, craters, boulders)")
        body.begin()
        t0 = time.perf_counter()
        config = c.body.get("config")
        build_body(c.recipe, body_npz, inputs=() if config is None else (Path(config),))
        # a mesh to open in a viewer: the body with its boulders at their coarsest level
        # (the finest levels, which the renderer uses close up, would make it 0.6 GB)
        export_model(body_npz, body.dir / "body.ply", level=0)
        body.finish(time.perf_counter() - t0)
    spec = c.asteroid_run
    overrides = merge_tables(spec.overrides(), {"scene": {"body": str(body_npz)}})
    render = Stage(out, "asteroid/run", dict(
        body=body.key, overrides=overrides,
        scenario=read_toml(spec.scenario, "scenario"), v=2))
    run_dir = render.dir / "run"
    if not render.done():
        say("asteroid 2/2: rendering the approach")
        render.begin()
        write_scenario(spec.scenario, render.dir / "approach.toml", overrides)
        _render(render, render.dir / "approach.toml", run_dir)
    return {"body": str(body_npz), "run": str(run_dir)}


def source_commit(folder: Path) -> str:
    """Return the git commit checked out at ``folder`` (``"unknown"`` outside a checkout).

    Parameters
    ----------
    folder : pathlib.Path
        A folder of the checkout (the campaign file's).

    Returns
    -------
    str
        ``git rev-parse HEAD``, or ``"unknown"``.
    """
    import subprocess

    try:
        done = subprocess.run(["git", "rev-parse", "HEAD"], cwd=folder, capture_output=True,
                              text=True, timeout=30, check=True)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return done.stdout.strip() or "unknown"


def _escape(text) -> str:
    """Return ``text`` safe inside a Markdown table cell."""
    return str(text).replace("|", "\\|")


def _cell(value) -> str:
    if value is None:
        return "not measured"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def results_text(c: Campaign, out: Path, report: Path, commit: str) -> str:
    """Return the figures a campaign run measured, as Markdown (see :func:`write_results`).

    Parameters
    ----------
    c : Campaign
        The campaign.
    out : pathlib.Path
        Its output folder (the stage markers are read).
    report : pathlib.Path
        The report (its JSON beside it is read).
    commit : str
        The commit the run was made at.

    Returns
    -------
    str
        The page.
    """
    doc = json.loads(report.with_suffix(".json").read_text(encoding="utf-8"))
    name = c.path.name if c.path is not None else "the campaign"
    lines = [f"# {c.title}: measured results", "",
             f"Generated by the campaign ({name}{', reduced by --quick' if c.quick else ''}) "
             f"at commit `{commit}`; do not edit by hand, run the campaign again. The report "
             f"is `{os.path.relpath(report, out)}` in its output folder.", "",
             f"Verdict at the default thresholds: **{doc.get('verdict', 'unknown')}**.", "",
             "## Checks", "", "| section | check | value | limit | result |",
             "|---|---|---|---|---|"]
    for check in doc.get("checks", []):
        result = {True: "pass", False: "fail", None: "not measured"}[check.get("passed")]
        unit = f" {check['unit']}" if check.get("unit") else ""
        lines.append(f"| {_escape(check['section'])} | {_escape(check['name'])} | "
                     f"{_cell(check['value'])}{unit} | "
                     f"{check['relation']} {_cell(check['limit'])}{unit} | {result} |")
    lines += ["", "## Stages (wall time on the machine that ran them)", "",
              "| stage | seconds | frames | frames per second |", "|---|---|---|---|"]
    for stage in STAGES:
        marker = out / f".{stage.replace('/', '_')}.done.json"
        if marker.exists():
            info = json.loads(marker.read_text())
            lines.append(f"| {stage} | {info['seconds']:.1f} | {info.get('frames', '')} | "
                         f"{_cell(info.get('fps')) if info.get('fps') else ''} |")
    facts = {}
    evaluation_marker = out / ".evaluation.done.json"
    if evaluation_marker.exists():
        facts = json.loads(evaluation_marker.read_text())
    rows = []
    for run in ("lunar", "asteroid"):
        t = facts.get(f"tracking_{run}", {})
        if t:
            rows += [(f"{run}: tracks", t.get("tracks")),
                     (f"{run}: tracking error against truth, median (px)", t.get("median_px")),
                     (f"{run}: one-step error on truth-warped frames, median (px)",
                      t.get("ideal_one_step_median_px")),
                     (f"{run}: truth round trip, median (px)", t.get("truth_round_trip_px"))]
    for comparison in facts.get("dem_comparisons", []):
        pair = f"{comparison['label']} against {comparison['reference']}"
        rows.append((f"{pair}: slope KS distance", comparison["ks"]))
        if comparison.get("shape_ks") is not None:
            rows.append((f"{pair}: KS distance of slopes over their median (shape)",
                         comparison["shape_ks"]))
        if comparison.get("amplitude_ratio") is not None:
            why = ", not judged: another place" if comparison.get("shape_only") else ""
            rows.append((f"{pair}: median slope ratio (amplitude{why})",
                         comparison["amplitude_ratio"]))
    if "site" in facts:
        rows += [("landing site: safe fraction", facts["site"].get("safe_fraction")),
                 ("landing site: rocks", facts["site"].get("rocks"))]
    if "asteroid_ks" in facts:
        rows.append(("asteroid against Eros: slope KS distance", facts["asteroid_ks"]))
    if rows:
        lines += ["", "## Measured", "", "| quantity | value |", "|---|---|"]
        lines += [f"| {label} | {_cell(value)} |" for label, value in rows]
    terrain = facts.get("terrain_figures")
    if terrain:
        lines += ["", f"## The lunar stack against the {terrain['terrain']} preset", "",
                  "Slopes at each baseline on the layer fit for it, steep ground outside young "
                  "craters, the visible small craters and the rocks "
                  "(evaluation.validate.preset_figures).", "", "| quantity | value |",
                  "|---|---|"]
        lines += [f"| {_escape(label)} | {_cell(value)} |" for label, value in terrain["rows"]]
    return "\n".join(lines) + "\n"


def write_results(c: Campaign, out: Path, report: Path, target, commit: str) -> Path:
    """Write :func:`results_text` to ``target`` (atomically).

    Returns
    -------
    pathlib.Path
        ``target``.
    """
    from terrain.core.outputs import atomic_path

    target = Path(target)
    with atomic_path(target) as tmp:
        tmp.write_text(results_text(c, out, report, commit), encoding="utf-8")
    return target


def run_campaign(c: Campaign, out, *, shared=None, fresh: bool = False,
                 say: Callable[[str], None] | None = None, summary_name: str = "campaign.json",
                 results=None) -> Path:
    """Run every stage of a campaign into ``out`` (finished stages are reused).

    Parameters
    ----------
    c : Campaign
        The campaign.
    out : path-like
        The output folder: new, empty, or a campaign's (see :func:`claim_output`).
    shared : path-like, optional
        The real-data folder (default: the campaign's ``shared_data``).
    fresh : bool, optional
        Remove what a campaign wrote there first (see :func:`claim_output`).
    say : callable, optional
        Called with one line per step (default: the log, at INFO).
    summary_name : str, optional
        Name of the JSON file of stage timings written in ``out``.
    results : path-like, optional
        Where the measured figures go as Markdown, stamped with the commit
        (:func:`write_results`; default ``out / "results.md"``).

    Returns
    -------
    pathlib.Path
        The report (``out/evaluation/report.html``).
    """
    from evaluation.campaign_report import evaluate
    from terrain.core.memory import keep_freed_memory

    say = say or log.info
    out = claim_output(out, fresh=fresh)
    # a campaign's process makes and drops frame-sized arrays from start to end
    keep_freed_memory()
    if fresh:
        remove_path(out / summary_name)
    t0 = time.perf_counter()
    lunar_facts = lunar(c, out, say)
    closed_loop(c, out, say)
    asteroid_facts = asteroid(c, out, say)
    report = evaluate(c, out, lunar_facts, asteroid_facts, c.real_data(
        None if shared is None else Path(shared)), say, summary_name)
    timings = {}
    for name in STAGES:
        marker = out / f".{name.replace('/', '_')}.done.json"
        if marker.exists():
            timings[name.replace("/", "_")] = json.loads(marker.read_text())
    summary = dict(seconds=time.perf_counter() - t0, stages=timings, report=str(report))
    from terrain.core.outputs import atomic_path

    with atomic_path(out / summary_name) as tmp:
        tmp.write_text(json.dumps(summary, indent=2))
    folder = c.path.resolve().parent if c.path is not None else Path.cwd()
    written = write_results(c, out, report, out / "results.md" if results is None else results,
                            source_commit(folder))
    say(f"measured figures in {written}")
    say(f"done in {summary['seconds']:.0f} s; open {report}")
    return report

