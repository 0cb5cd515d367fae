"""Monte Carlo campaigns: one scenario rendered once per case of a table of dispersions.

``craterscape render campaign SCENARIO DISPERSIONS -o OUT`` (or :func:`run_campaign`)
renders every case (:mod:`render.dispersions`) in this process, on a local pool of worker
processes (``--workers N``) or on a Dask cluster (``--scheduler tcp://HOST:PORT``). Layout::

    OUT/
      campaign.json            what the campaign renders: scenario, dispersions, every case
      summary.csv              one row per finished case (below), written at the end
      cases/NNNNNN.toml        case NNNNNN's scenario: the scenario with its values set
      cases/NNNNNN/            its run directory (render.rundir), as `render sequence` writes

A case is its own scenario file: ``craterscape render sequence OUT/cases/000007.toml -o
DIR`` renders it alone, byte for byte as the campaign did (frames, range, normals,
radiance, truth; the manifest's timings aside). Every case is pure: its files are a
function of its scenario file and the scene, never of the worker, the order, or the cases
rendered before it on the same worker.

Each worker process makes its own EGL context (:mod:`render.context`) and loads the scene
once, for all the cases it renders. A case renders into ``cases/.NNNNNN.rendering/``,
renamed to ``cases/NNNNNN/`` when complete, so a run directory under its final name is a
finished case: resuming (``--resume``) skips those and renders the others again from the
start. On a cluster, ``OUT`` and the scene must be on a file system every worker reads and
writes at the same path, and every worker must run the same craterscape.

``summary.csv`` columns: ``case``, ``name``, ``seed``, each dispersion key (empty where the
case keeps the scenario's value), ``frames``, ``render_seconds`` (the case's frames, on its
worker; empty, as is ``worker``, for a case an earlier run finished), ``start_x/y/z`` and
``end_x/y/z`` (camera position of the first and last frame, m, world), ``worker`` (host and
process that rendered it) and ``run`` (its folder).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import socket
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from render.dispersions import Dispersions, case_table, read_dispersions
from render.scenario import Scenario, load_scenario, parse_scenario
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import atomic_path, check_output_folder, make_output_folder
from terrain.core.progress import Progress
from terrain.core.tomlfile import toml_text

__all__ = ["FORMAT", "case_scenarios", "render_case", "run_campaign"]

log = logging.getLogger(__name__)

FORMAT = "craterscape-render-campaign"
#: Where a case renders until it is complete (beside its final folder).
_WORKING = ".rendering"
#: The scene a worker process has loaded: (key, renderer, scene).
_LOADED: list = []


def _case_name(k: int) -> str:
    return f"{k:06d}"


def _absolute(scenario: Scenario, raw: dict) -> dict:
    """Return the scenario's tables with its files named absolutely and no build recipe.

    A case's scenario file lives in the campaign's folder, not beside the scenario, and the
    campaign builds a missing scene once before any case starts.
    """
    table = json.loads(json.dumps(raw))
    scene = table.get("scene", {})
    scene.pop("build", None)
    for section, key in (("scene", "stack"), ("scene", "body"), ("surface", "albedo_map"),
                         ("sensor", "psf_kernel")):
        value = table.get(section, {}).get(key)
        if isinstance(value, str):
            table[section][key] = str(scenario.resolve(value).absolute())
    return table


def case_scenarios(scenario: Scenario, dispersions: Dispersions) -> list[str]:
    """Return each case's scenario file text, every one parsed and checked first.

    Parameters
    ----------
    scenario : render.scenario.Scenario
        The nominal scenario.
    dispersions : render.dispersions.Dispersions
        The cases.

    Returns
    -------
    list of str
        One TOML text per case, in case order; its paths are absolute.

    Raises
    ------
    terrain.core.errors.InvalidParameterError
        A case whose scenario is refused, naming the case and what was wrong.
    """
    base = _absolute(scenario, scenario.raw)
    texts = []
    for k, values in enumerate(dispersions.cases):
        name = f"{scenario.name}-{_case_name(k)}"
        try:
            table = case_table(base, values, name)
            parse_scenario(table, scenario.path)
        except InvalidParameterError as exc:
            raise InvalidParameterError(f"dispersions case {k}: {exc}") from None
        texts.append(toml_text(table))
    return texts


def _scene_key(scenario: Scenario) -> str:
    s = scenario.scene
    return json.dumps([s.type, str(scenario.resolve(s.stack or "")), str(scenario.resolve(
        s.body or "")), s.curvature, s.radius, s.boulders, s.imposter_pixels,
        str(scenario.resolve(s.albedo_map)) if s.albedo_map else None])


def _worker_scene(scenario: Scenario):
    """Return this process's renderer and the scenario's scene, loaded once per process."""
    from render.renderer import Renderer
    from render.sequence import load_scene

    key = _scene_key(scenario)
    if not _LOADED or _LOADED[0] != key:
        _LOADED[:] = [key, Renderer(), load_scene(scenario)]
        log.info("worker %s loaded the scene", _worker())
    return _LOADED[1], _LOADED[2]


def _worker() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def render_case(case_file: str, run_dir: str) -> dict:
    """Render one case into its run directory (a worker's task).

    Parameters
    ----------
    case_file : str
        The case's scenario file.
    run_dir : str
        Its run directory; it must not exist yet (rendered in a working folder beside it,
        renamed into place when complete).

    Returns
    -------
    dict
        The case's row of the summary: ``frames``, ``render_seconds``, ``worker``.
    """
    from render.context import keep_current
    from render.sequence import run_sequence

    final = Path(run_dir)
    working = final.with_name(f".{final.name}{_WORKING}")
    if working.exists():
        shutil.rmtree(working)
    scenario = load_scenario(case_file)
    with keep_current():
        renderer, scene = _worker_scene(scenario)
        t0 = time.perf_counter()
        manifest = run_sequence(scenario, working, renderer=renderer, scene=scene)
    seconds = time.perf_counter() - t0
    os.replace(working, final)
    fd = os.open(final.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    return {"frames": int(manifest["frames_written"]), "render_seconds": seconds,
            "worker": _worker()}


def _finished(run_dir: Path) -> dict | None:
    """Return a finished case's summary facts, or None when the folder holds no such case."""
    try:
        manifest = json.loads((run_dir / "manifest.json").read_text(encoding="utf-8"))
        truth = json.loads((run_dir / "truth.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(manifest, dict) or manifest.get("frames_written") != manifest.get(
            "frames") or not isinstance(truth, list) or not truth:
        return None
    truth = sorted(truth, key=lambda t: t["index"])
    return {"frames": manifest["frames"],
            "start": truth[0]["camera"]["position"], "end": truth[-1]["camera"]["position"]}


def _campaign_key(texts: Iterable[str]) -> str:
    h = hashlib.sha256()
    for t in texts:
        h.update(hashlib.sha256(t.encode("utf-8")).digest())
    return h.hexdigest()


def _check_folder(out: Path, key: str, resume: bool, inputs: list[Path]) -> None:
    """Refuse an output folder that holds something other than this campaign."""
    check_output_folder(out, inputs)
    if not (out.is_dir() and any(out.iterdir())):
        return
    record = out / "campaign.json"
    try:
        old = json.loads(record.read_text(encoding="utf-8"))
        ok = isinstance(old, dict) and old.get("format") == FORMAT
    except (OSError, ValueError, RecursionError):
        ok = False
    if not ok:
        raise InvalidParameterError(
            f"output folder '{out}' is not empty and holds no campaign; choose a new one")
    if not resume:
        raise InvalidParameterError(
            f"output folder '{out}' holds a campaign; resume it (--resume) or choose a new one")
    if old.get("key") != key:
        raise InvalidParameterError(
            f"output folder '{out}' holds a campaign of another scenario or other "
            "dispersions; resume with the same files or choose a new folder")


def _summary_rows(out: Path, dispersions: Dispersions, scenario: Scenario,
                  rendered: dict[int, dict]) -> dict[str, list]:
    cols: dict[str, list] = {c: [] for c in _summary_order(dispersions)}
    for k, values in enumerate(dispersions.cases):
        name = _case_name(k)
        facts = _finished(out / "cases" / name)
        if facts is None:
            continue
        row = rendered.get(k, {})
        cols["case"].append(k)
        cols["name"].append(f"{scenario.name}-{name}")
        cols["seed"].append(values.get("seed", scenario.seed))
        for key in dispersions.keys:
            if key != "seed":
                cols[key].append(values.get(key, float("nan")))
        cols["frames"].append(facts["frames"])
        cols["render_seconds"].append(row.get("render_seconds", float("nan")))
        for end in ("start", "end"):
            for axis, v in zip("xyz", facts[end], strict=True):
                cols[f"{end}_{axis}"].append(v)
        cols["worker"].append(row.get("worker", ""))
        cols["run"].append(f"cases/{name}")
    return cols


def _summary_order(dispersions: Dispersions) -> list[str]:
    return (["case", "name", "seed"] + [k for k in dispersions.keys if k != "seed"]
            + ["frames", "render_seconds"] + [f"{e}_{a}" for e in ("start", "end")
                                              for a in "xyz"] + ["worker", "run"])


def _write_summary(path: Path, cols: dict[str, list], order: list[str]) -> None:
    import csv

    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(order)
        for i in range(len(cols["case"])):
            w.writerow(["" if isinstance(v, float) and v != v else
                        repr(v) if isinstance(v, float) else v
                        for v in (cols[c][i] for c in order)])


def _prepare_folder(out: Path, texts: list[str], key: str, scenario: Scenario,
                    dispersions: Dispersions, inputs: list[Path]) -> tuple[list, dict]:
    """Make the campaign's folder, record it, and write the scenarios of the cases to do."""
    cases_dir = out / "cases"
    make_output_folder(cases_dir, inputs)
    record = dict(format=FORMAT, version=1, key=key, scenario=scenario.name,
                  scenario_file=str(inputs[0]), dispersions_file=str(inputs[1]),
                  dispersions=dispersions.source, keys=list(dispersions.keys),
                  cases=len(texts))
    with atomic_path(out / "campaign.json") as tmp:
        tmp.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    for stale in cases_dir.glob(f".*{_WORKING}"):  # cases an interrupted run left half done
        shutil.rmtree(stale)
    todo = []
    for k, text in enumerate(texts):
        name = _case_name(k)
        run_dir = cases_dir / name
        if _finished(run_dir) is not None:
            continue
        if run_dir.exists():  # not a finished case: never renamed into place by a case
            raise InvalidParameterError(f"'{run_dir}' is not a finished case; remove it")
        case_file = cases_dir / f"{name}.toml"
        if not (case_file.is_file() and case_file.read_text(encoding="utf-8") == text):
            with atomic_path(case_file) as tmp:
                tmp.write_text(text, encoding="utf-8")
        todo.append((k, str(case_file.absolute()), str(run_dir.absolute())))
    return todo, record


def run_campaign(scenario_file: str | Path, dispersions_file: str | Path, out: str | Path, *,
                 workers: int | None = None, scheduler: str | None = None,
                 resume: bool = False, progress: Progress | None = None) -> dict:
    """Render every case of a campaign into ``out`` (see the module docstring).

    Parameters
    ----------
    scenario_file : str or pathlib.Path
        The nominal scenario.
    dispersions_file : str or pathlib.Path
        The cases (:func:`render.dispersions.read_dispersions`).
    out : str or pathlib.Path
        The campaign's folder (new or empty; with ``resume``, an interrupted campaign of
        the same files).
    workers : int, optional
        Render on a local pool of this many worker processes.
    scheduler : str, optional
        Render on the Dask cluster at this address (``tcp://HOST:PORT``).
    resume : bool
        Skip the cases already finished in ``out``.
    progress : terrain.core.progress.Progress, optional
        Called as ``progress(done, total, detail)`` after every case.

    Returns
    -------
    dict
        The campaign's record (also ``campaign.json``): ``cases``, ``cases_rendered``,
        ``seconds`` (with ``start_seconds``, the pool's or the client's start),
        ``cases_per_second`` of this run, and the workers.
    """
    from render.scene_build import ensure_scene
    from terrain.execution.chunked import dask_client

    out = Path(out)
    scenario_file, dispersions_file = Path(scenario_file), Path(dispersions_file)
    scenario = load_scenario(scenario_file)
    dispersions = read_dispersions(dispersions_file)
    texts = case_scenarios(scenario, dispersions)
    key = _campaign_key(texts)
    _check_folder(out, key, resume, [scenario_file, dispersions_file])
    if workers is not None and scheduler is not None:
        raise InvalidParameterError("give --workers or --scheduler, not both")
    t0 = time.perf_counter()
    with dask_client(workers, scheduler) as client:  # reach the cluster before writing
        started = time.perf_counter() - t0
        ensure_scene(scenario)  # once, here: workers never build
        todo, record = _prepare_folder(out, texts, key, scenario, dispersions,
                                       [scenario_file, dispersions_file])
        log.info("campaign %s: %d cases, %d to render", scenario.name, len(texts), len(todo))
        rendered: dict[int, dict] = {}
        n_workers = 1 if client is None else len(client.scheduler_info()["workers"])
        for k, row in _render_all(client, todo, key):
            rendered[k] = row
            if progress is not None:
                rate = len(rendered) / max(time.perf_counter() - t0, 1e-9)
                progress(len(rendered), len(todo), f"{rate:.2f} case/s")
    seconds = time.perf_counter() - t0
    _write_summary(out / "summary.csv", _summary_rows(out, dispersions, scenario, rendered),
                   _summary_order(dispersions))
    record.update(cases_rendered=len(rendered), seconds=seconds, start_seconds=started,
                  workers=max(n_workers, len({r["worker"] for r in rendered.values()})),
                  cases_per_second=len(rendered) / seconds if rendered else 0.0)
    with atomic_path(out / "campaign.json") as tmp:
        tmp.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return record


def _render_all(client: Any, todo: list[tuple[int, str, str]], key: str):
    """Yield ``(case, summary row)`` as cases finish, in this process or on the cluster."""
    if client is None:
        for k, case_file, run_dir in todo:
            yield k, render_case(case_file, run_dir)
        return
    from dask.distributed import as_completed

    futures = {client.submit(render_case, case_file, run_dir, pure=False,
                             key=f"case-{key[:12]}-{k}"): k for k, case_file, run_dir in todo}
    try:
        for future in as_completed(futures):
            yield futures[future], future.result()
    finally:
        client.cancel(list(futures))
