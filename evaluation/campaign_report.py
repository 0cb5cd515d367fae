"""The evaluation stage of a campaign (:mod:`evaluation.campaign`): tracks, slopes, report.

Both runs are tracked and scored against their truth (with the truth's own round trip,
:func:`evaluation.tracking.truth_round_trip`); every layer of the stack gets its slope
distribution and spectrum (:func:`evaluation.evidence.dem_evidence`); the base is compared
with LOLA's LDEM_4 reprojected onto the south pole (:func:`terrain.io.reproject_polar`) and
the landing-site layer with the LROC shape-from-shading DEM; the site's hazard map, its
rocks and the layers drawn under the descent; the asteroid's slopes against Gaskell's Eros.
Real data are used where the shared data folder holds them, and their absence is said.

The verdict means realism: the stack is judged layer by layer against published lunar
statistics (:mod:`evaluation.validate`), and the renderer by its frame-to-frame consistency,
one-step tracking error, truth round trip and the layers drawn against the GSD; drift and
outliers of long tracks measure the tracker and are shown as information
(:func:`evaluation.validate_report.regroup_campaign_checks`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from evaluation.campaign import STAGES, Campaign, Stage
from terrain.core import metakeys as mk
from terrain.core.memory import keep_freed_memory

__all__ = ["asteroid_slopes", "evaluate"]

log = logging.getLogger(__name__)

#: Mean radius of the Moon (m), the sphere of LOLA's LDEM products.
MOON_RADIUS = 1_737_400.0
#: Half the side of the polar grid LDEM_4 is reprojected onto (m): about 70 to 90 degrees S.
LDEM_HALF_WIDTH_M = 600_000.0
#: Vertices of a body its gravity is evaluated at; at the others it is interpolated
#: (:func:`evaluation.meshslope.sampled_attraction`; docs/speed.md gives what that changes).
#: Gaskell's Eros (24,578 vertices) and the facet-matched bodies are below it: exact.
BODY_FIELD_POINTS = 2 ** 15
#: Largest miss of an interpolating plane the campaign keeps, as a fraction of the field
#: (:func:`evaluation.meshslope.sampled_attraction`; the library's default is 1 %). Measured
#: on the demo body (393,218 vertices) against the field at every vertex (docs/speed.md):
#: the field is evaluated at 37,363 vertices instead of 66,026, per-vertex slopes err by
#: 0.016 deg median and 0.14 deg at the 99th percentile (0.012 and 0.11 at 1 %), and the
#: body's slope quantiles by at most 0.013 deg (0.008 at 1 %).
BODY_FIELD_TOLERANCE = 2e-2
#: Steps of a run from which the tracker on truth-warped frames follows only every
#: :data:`IDEAL_STEP_STRIDE`-th step. On the demo's descent (119 steps) every fourth step
#: moves the medians of its one-step errors by +0.8 % without noise and -0.3 % with it
#: (every second: +0.3 / -0.4 %; every fifth: +0.5 / +2.1 %; docs/speed.md); on the
#: approach's 29 steps even every second would move them by 4 %, so shorter runs are
#: measured at every step.
IDEAL_SAMPLED_STEPS = 100
IDEAL_STEP_STRIDE = 4

TRACKING_NOTES = {
    "lunar": (
        "The surface is grey (uniform albedo), so every corner is a shading corner, and the "
        "camera closes in by several per cent between frames: Lucas-Kanade, which models "
        "the motion of a patch as a shift, would drift a little under that zoom at every "
        "step, so the tracker follows each feature from the previous frame warped by the "
        "step's homography; what drift is left grows with a track's age. No corner is "
        "detected within half a window of a shadow too deep to show anything: its edge is "
        "an outline, not a point of the surface. The round trip "
        "through the truth and range images of consecutive frames (last row of the table) "
        "shows the ground truth itself is exact."),
    "asteroid": (
        "The body turns about 1.2 degrees between frames under a fixed sun. With a uniform "
        "albedo every corner is a shading corner, and shading moves over the surface as "
        "the local lighting angle changes: features slide, and the error grows with a "
        "track's age, as the right-hand panel shows. This is what a real tracker meets on "
        "a spinning body; the round trip through the truth (last row) shows the ground "
        "truth itself is exact. Two things would add to it and are kept out: corners on "
        "the limb, which slide along the outline as the body turns (the tracker detects no "
        "corner within half a window of the sky, from the image alone), and boulders "
        "smaller than a pixel, which a renderer taking one sample a pixel draws on one "
        "pixel or three as they move (the approach is rendered with 3x3 samples a pixel)."),
}

DEM_NOTE = (
    "The synthetic base and the real DEMs are different places: the comparisons ask "
    "whether the model's slopes are those of real polar terrain at the same scale, not "
    "whether it reproduces a site. LDEM_4 (reprojected, 7.58 km pixels) judges the base; "
    "the LROC NAC shape-from-shading DEM near Malapert (1.08 m, 0.5 km across) judges the "
    "0.5 m layer, the landing site, at its spacing, by shape only: that site is a flat "
    "landing region (median slope a few degrees at 2-17 m) while the layers follow LOLA's "
    "regional polar slope law (8-9 degrees there), so the slopes are compared each over "
    "its own median, and the Hurst exponent from even lags, which the SFS DEM's period-2 row "
    "pattern cannot bias (its power spectrum below 16 px is that pattern's); the amplitude is "
    "shown, not judged. The base has craters up to 150 km, "
    "complex above 15 km (flat floors, terraced walls, central peaks; Pike 1977's "
    "depths and rim heights), which give its slopes the tail LOLA's polar slopes have; "
    "basins beyond 150 km and the south pole's own shape are not modelled.")


def polar_ldem(ldem: Path, target: Path) -> Path:
    """Reproject LOLA's LDEM_4 around the south pole onto a polar stereographic grid.

    Written to ``target`` (see :func:`terrain.io.reproject_polar`).

    Parameters
    ----------
    ldem : pathlib.Path
        The LDEM_4 label (``LDEM_4.LBL``).
    target : pathlib.Path
        The GeoTIFF to write.

    Returns
    -------
    pathlib.Path
        ``target``.
    """
    from terrain.io import read_dem, reproject_polar, write_dem

    tile = reproject_polar(read_dem(ldem), radius=MOON_RADIUS, half_width_m=LDEM_HALF_WIDTH_M)
    write_dem(tile.replace(metadata={mk.SOURCE: str(ldem)}), target, inputs=[ldem])
    return target


def evaluate(c: Campaign, out: Path, lunar_facts: dict, asteroid_facts: dict, real: dict,
             say, summary_name: str = "campaign.json") -> Path:
    """Tracks, slopes and the report (stage 6 of :mod:`evaluation.campaign`).

    Parameters
    ----------
    c : Campaign
        The campaign.
    out : pathlib.Path
        The output folder.
    lunar_facts, asteroid_facts : dict
        What :func:`evaluation.campaign.lunar` and :func:`evaluation.campaign.asteroid`
        returned.
    real : dict
        Paths of the real data (``ldem``, ``sfs``, ``eros``), present or not.
    say : callable
        Called with one line per step.
    summary_name : str, optional
        The campaign's timing file, linked from the report.

    Returns
    -------
    pathlib.Path
        The report.
    """
    ev = c.evaluation
    have = {k: Path(p).exists() for k, p in real.items()}
    keys = sorted(p.name for p in out.glob(".*.done.json") if "evaluation" not in p.name)
    stage = Stage(out, "evaluation", dict(
        inputs=[json.loads((out / k).read_text())["key"] for k in keys], real=have,
        evaluation=dict(ev), v=4))
    report_path = stage.dir / "report.html"
    if stage.done() and report_path.exists():
        return report_path
    from evaluation.report import DEFAULT_THRESHOLDS

    say("evaluation: feature tracks, slope distributions, asteroid slopes, report")
    stage.begin()
    t0 = time.perf_counter()
    # Independent parts run in two worker processes while this one tracks the descent (most
    # of it on one core): the asteroid's slopes and its section (polyhedron gravity), the
    # lunar layers (slopes, realism, real DEMs, hazards), the descent's consistency, the
    # approach's tracking. Each part computes what it computed in one process: the same
    # figures, sooner. Fresh interpreters ("spawn"): this process runs threads (frame
    # readers, numba's), which a forked child would inherit half-made. The workers keep
    # freed memory for their large arrays, as the campaign's process does.
    with ProcessPoolExecutor(max_workers=2, mp_context=get_context("spawn"),
                             initializer=_worker_setup) as pool, _fewer_collections():
        # the two longest parts first, one per worker; the descent's consistency (wanted
        # after this process has tracked the descent) and the approach's tracking next
        slopes = pool.submit(asteroid_report, Path(asteroid_facts["body"]),
                             Path(real["eros"]) if have.get("eros") else None,
                             float(ev.get("eros_density", 2670.0)),
                             float(ev.get("eros_period_h", 5.27)), str(real.get("eros")),
                             json.loads(json.dumps(DEFAULT_THRESHOLDS)))
        layers = pool.submit(lunar_layers, getattr(c.synth, "terrain", None) or "south-polar",
                             dict(ev), stage.dir, Path(lunar_facts["stack"]),
                             Path(lunar_facts["run"]), real, have,
                             json.loads(json.dumps(DEFAULT_THRESHOLDS)))
        descent = pool.submit(measure_consistency, Path(lunar_facts["run"]),
                              stage.dir / "lunar_consistency")
        approach = pool.submit(tracking_report, "asteroid", Path(asteroid_facts["run"]),
                               stage.dir, json.loads(json.dumps(DEFAULT_THRESHOLDS)), c.seed)
        return _evaluate_stage(c, out, stage, t0, lunar_facts, asteroid_facts, real, have,
                               descent, layers, approach, slopes, say, summary_name)


#: CPython's collector thresholds in the evaluation's processes (default (700, 10, 10)): the
#: tracker and the report make millions of short-lived containers (a tuple per tracked point
#: and frame, the figures' artists), and at 700 allocations per collection the collector
#: took 1.4 s of the stage's main process (1,800 collections, measured in the demo). Objects
#: made before the stage are frozen out of its collections.
EVALUATION_GC_THRESHOLDS = (20000, 50, 100)


def _collect_less() -> tuple:
    """Set :data:`EVALUATION_GC_THRESHOLDS`, what exists now frozen out; return the old ones."""
    import gc

    before = gc.get_threshold()
    gc.freeze()  # what exists now lives through the stage: not traversed again
    gc.set_threshold(*EVALUATION_GC_THRESHOLDS)
    return before


@contextlib.contextmanager
def _fewer_collections():
    """Collect less often inside the block (:func:`_collect_less`), as before after."""
    import gc

    before = _collect_less()
    try:
        yield
    finally:
        gc.set_threshold(*before)
        gc.unfreeze()


def _worker_setup() -> None:
    """Prepare an evaluation worker process (for its life): its allocator and collector."""
    keep_freed_memory()
    _collect_less()


def asteroid_slopes(body_path: Path, eros_path: Path | None, density: float, period_h: float):
    """Return the campaign body's slopes, Gaskell's Eros's, and both at one facet count.

    Parameters
    ----------
    body_path : pathlib.Path
        The body's native ``.npz`` (metres).
    eros_path : pathlib.Path or None
        Gaskell's Eros shape model (km), where the shared data hold it.
    density : float, kg m^-3
        Of both bodies.
    period_h : float, hours
        Spin period of both, about their z axis.

    Returns
    -------
    body, reference : evaluation.meshslope.MeshSlopes
        The reference None without ``eros_path``.
    matched : (MeshSlopes, MeshSlopes) or None
        :func:`evaluation.validate.facet_matched_slopes` of the two; None without
        ``eros_path``.
    """
    from evaluation.meshslope import Spin, load_body, mesh_slopes
    from evaluation.validate import facet_matched_slopes

    spin = Spin(period_h, (0.0, 0.0, 1.0))
    shape = load_body(body_path)
    body = mesh_slopes(shape.vertices, shape.faces, label="synthetic Eros-like body",
                       density=density, spin=spin, field_points=BODY_FIELD_POINTS,
                       field_tolerance=BODY_FIELD_TOLERANCE)
    if eros_path is None:
        return body, None, None
    eros = load_body(eros_path, units="km")
    reference = mesh_slopes(eros.vertices, eros.faces, label="433 Eros (Gaskell)",
                            density=density, spin=spin, field_points=BODY_FIELD_POINTS,
                            field_tolerance=BODY_FIELD_TOLERANCE)
    # slopes rise with facet count: compare at the same count
    matched = facet_matched_slopes((shape.vertices, shape.faces), (eros.vertices, eros.faces),
                                   density=density, spin=spin,
                                   labels=("synthetic body", "433 Eros (Gaskell)"))
    return body, reference, matched


def asteroid_report(body_path: Path, eros_path: Path | None, density: float, period_h: float,
                    eros_name: str, limits: dict):
    """Return the report's asteroid section and its KS distance against Eros (or None).

    :func:`asteroid_slopes`, and the section drawn from them with the body's boulder check
    and the facet-matched comparison, in the process that computed them (the per-vertex
    slopes stay there).
    """
    from asteroid.body import load_native
    from asteroid.build import boulders_of
    from evaluation.report import asteroid_section
    from evaluation.validate import body_slope_check, boulder_check
    from evaluation.validate_report import as_check

    body, reference, matched = asteroid_slopes(body_path, eros_path, density, period_h)
    sec = asteroid_section([body], reference, limits)
    if "field_points" in body.info:
        sec.notes.append(
            f"The synthetic body's gravity is evaluated at {body.info['field_points']:,} of "
            f"its {body.info['vertices']:,} vertices and interpolated at the others "
            "(evaluation.meshslope.sampled_attraction). Measured on the demo's body against "
            "the field evaluated at every vertex (docs/speed.md): per-vertex slopes within "
            "0.14 deg at the 99th percentile, the body's slope quantiles within 0.02 deg, "
            "the KS distance against Eros within 0.001.")
    if reference is None:
        sec.notes.append(f"{eros_name} not found: the body is not compared with real Eros")
    boulders = boulders_of(load_native(body_path))
    sec.checks.append(as_check(boulder_check(
        boulders.catalog.diameter_m if boulders is not None else [], label="body: ")))
    if matched is not None:
        sec.checks.append(as_check(body_slope_check(*matched, label="body: ")))
    ks = [x for x in sec.checks if x.name.startswith("KS distance")]
    return sec, ks[0].value if ks else None


def _evaluate_stage(c: Campaign, out: Path, stage: Stage, t0: float, lunar_facts: dict,
                    asteroid_facts: dict, real: dict, have: dict, descent, layers, approach,
                    slopes, say, summary_name: str) -> Path:
    """Do :func:`evaluate`'s work once its stage has begun.

    ``descent``, ``layers``, ``approach`` and ``slopes`` are the futures of
    :func:`measure_consistency` (the descent's), :func:`lunar_layers`,
    :func:`tracking_report` (the approach's) and :func:`asteroid_report`; the other
    parameters are :func:`evaluate`'s, ``have`` which real data exist, ``t0`` when the stage
    began.
    """
    from evaluation.report import DEFAULT_THRESHOLDS, Report, write_report
    from evaluation.tracking import load_run
    from evaluation.validate_report import regroup_campaign_checks

    report_path = stage.dir / "report.html"
    limits = json.loads(json.dumps(DEFAULT_THRESHOLDS))
    sections: list = []
    facts: dict = {}

    # -- feature tracking against truth, both runs (the approach's in a second process)
    lunar_sections, facts["tracking_lunar"], _ = tracking_report(
        "lunar", Path(lunar_facts["run"]), stage.dir, limits, c.seed, say, descent)
    tracked = {"lunar": load_run(Path(lunar_facts["run"])),
               "asteroid": load_run(Path(asteroid_facts["run"]))}

    # -- what needs no other process, made while the others finish: the closed-loop landing
    # through the render server, crater-based navigation on the descent
    # (examples/crater_navigation.py) and the campaign overview (timings, gallery, links)
    late: list = []
    summary_path = out / "lunar" / "closed_loop" / "summary.json"
    if summary_path.exists():
        late.append(closed_loop_section(summary_path.parent, stage.dir))
    nav_path = out / "lunar" / "crater_navigation" / "summary.json"
    if nav_path.exists():
        late.append(crater_navigation_section(nav_path.parent, stage.dir))
    overview = campaign_section(c, out, stage.dir, lunar_facts, asteroid_facts, tracked,
                                summary_name)

    say("evaluation: tracking Harris corners through the asteroid approach")
    approach_sections, facts["tracking_asteroid"], messages = approach.result()
    for message in messages[1:]:
        say(message)
    sections += lunar_sections + approach_sections

    # -- slopes per layer, realism, real DEMs, the site (computed in the second process)
    say("evaluation: slope distributions and spectra of every layer")
    layer_sections, layer_facts, messages = layers.result()
    for message in messages:
        say(message)
    sections += layer_sections
    facts.update(layer_facts)

    # -- the asteroid's slopes next to real Eros (section made in the second process)
    say("evaluation: asteroid slopes (polyhedron gravity and spin)")
    sec, facts["asteroid_ks"] = slopes.result()
    sections.append(sec)
    sections += late

    regroup_campaign_checks(sections, facts)
    rep = Report(c.title, [overview] + sections, limits,
                 dict(output=str(out), seed=c.seed, quick=c.quick,
                      real_data={k: bool(v) for k, v in have.items()}))
    write_report(rep, report_path)
    facts["verdict"] = rep.verdict
    facts["checks"] = [x.as_dict() for x in rep.checks]
    stage.finish(time.perf_counter() - t0, **facts)
    return report_path


def tracking_report(name: str, run_dir: Path, folder: Path, limits: dict, seed: int,
                    say=None, measured=None):
    """Return a run's tracking and consistency sections and their figures.

    The run's Harris corners tracked and scored against truth (the files go to
    ``folder / f"{name}_tracks"``), the truth round trip, and :func:`consistency_report`.

    Parameters
    ----------
    name : {"lunar", "asteroid"}
        The run.
    run_dir : pathlib.Path
        Its folder.
    folder : pathlib.Path
        The evaluation folder.
    limits : dict
        The report's thresholds.
    seed : int
        Seed of the fresh sensor noise.
    say : callable, optional
        Called with one line per step (they are also returned).
    measured : concurrent.futures.Future, optional
        Of the run's :func:`measure_consistency`, when another process measures it.

    Returns
    -------
    sections : list of evaluation.report.Section
        Tracking, then consistency.
    facts : dict
        The run's figures (``tracking_<name>`` of the stage's facts).
    messages : list of str
        The progress lines, in order.
    """
    from evaluation.report import tracking_section
    from evaluation.tracking import (
        TrackerSettings,
        load_run,
        save_tracks,
        score,
        track,
        truth_round_trip,
    )

    messages: list = []

    def tell(message):
        messages.append(message)
        if say is not None:
            say(message)

    key = {"lunar": "lunar descent", "asteroid": "asteroid approach"}[name]
    tell(f"evaluation: tracking Harris corners through the {key}")
    run = load_run(run_dir)
    scored = score(track(run, TrackerSettings()), run,
                   outlier_px=limits["tracking"]["outlier_px"])
    drawn: dict = {}  # the tracks' figures, drawn once for their folder and the report
    summary = save_tracks(scored, run, folder / f"{name}_tracks", drawn=drawn)
    facts = dict(tracks=summary["tracking"]["tracks"],
                 median_px=(summary["errors"] or {}).get("median_px"))
    sec = tracking_section(scored, run.image(len(run) - 1), limits,
                           run_label=f"the {key} ({run_dir})", key=key, drawn=drawn)
    consistency = truth_round_trip(run)
    facts["truth_round_trip_px"] = consistency
    sec.table("Tracking").append(
        ["truth round trip through consecutive frames (median px)", f"{consistency:.2g}"])
    sec.paragraphs.append(TRACKING_NOTES[name])
    return [sec, consistency_report(run, scored, sec, folder / f"{name}_consistency", limits,
                                    key, facts, seed, tell, measured)], facts, messages


def lunar_layers(terrain: str, ev: dict, folder: Path, stack_dir: Path, run_dir: Path,
                 real: dict, have: dict, limits: dict):
    """Return the lunar stack's sections: slopes, spectra, realism, real DEMs and the site.

    Each layer's slope distribution and spectrum (:func:`evaluation.evidence.dem_evidence`),
    its realism (:func:`evaluation.validate.validate_stack`), the base and the site against
    the real DEMs where ``have`` says they exist, and the site's hazards
    (:func:`site`). Files go to ``folder`` (the evaluation folder).

    Parameters
    ----------
    terrain : str
        The terrain type the stack is judged as (its synth preset).
    ev : dict
        The campaign's ``[evaluation]`` table (the lander of the hazard map).
    folder : pathlib.Path
        The evaluation folder.
    stack_dir, run_dir : pathlib.Path
        The layer stack and the descent.
    real, have : dict
        Paths of the real data, and which exist.
    limits : dict
        The report's thresholds.

    Returns
    -------
    sections : list of evaluation.report.Section
    facts : dict
        ``realism``, ``terrain_figures``, ``dem_comparisons`` and ``site``.
    messages : list of str
        The progress lines, in order, for the caller to say.
    """
    from evaluation.compare import compare_dems
    from evaluation.evidence import dem_evidence
    from evaluation.memo import measured_once
    from evaluation.report import dem_section
    from evaluation.tracking import load_run
    from evaluation.validate import preset_figures, validate_stack
    from evaluation.validate_report import base_catalog_for, validation_sections
    from terrain.core.errors import InvalidDEMError, InvalidParameterError
    from terrain.io import read_dem
    from terrain.stack.store import read_stack

    messages: list = []
    say = messages.append
    sections: list = []
    facts: dict = {}
    # -- slopes per layer, and against real DEMs at the two ends of the stack
    stack = read_stack(stack_dir)
    with measured_once():  # each layer's slopes measured once for the evidence and realism
        evidence = dem_evidence([(f"layer {k}", t) for k, t in enumerate(stack.tiles)])
        # realism is judged by published lunar statistics, layer by layer
        # (evaluation.validate); the comparisons with real DEMs of other places below are
        # side by side. The stack is judged as the terrain type it was built for (its
        # synth preset).
        say("evaluation: terrain realism of every layer (published lunar statistics)")
        found = base_catalog_for(stack)  # the base's own craters (the stack's are the layers')
        realism = validate_stack(stack, terrain, label="lunar layer stack",
                                 base_catalog=found[0] if found else None)
    comparisons, notes = [], []

    def compare(tile, ref, label, ref_label, shape_only=False):
        # different places compared as slope distributions: the layer's CRS is not the
        # reference's, and need not be (both are metres on square pixels)
        try:
            comparisons.append(compare_dems(tile.replace(crs=None), ref.replace(crs=None),
                                            label=label, reference_label=ref_label,
                                            shape_only=shape_only))
        except (InvalidDEMError, InvalidParameterError) as exc:  # --quick: too small to say
            notes.append(f"{label} not compared with {ref_label}: {exc}")

    if have.get("ldem"):
        ref = read_dem(polar_ldem(real["ldem"], folder / "reference_ldem4_south_pole.tif"))
        compare(stack.tiles[0], ref, "layer 0 (base)", "LOLA LDEM_4 south pole")
    else:
        notes.append(f"{real.get('ldem')} not found: the base is not compared with LOLA")
    if have.get("sfs"):
        # the layer of about 0.5 m is the landing site as wide as the SFS DEM (0.5 km), and
        # finer, so it is averaged onto the SFS DEM's 1.08 m pixels before the comparison
        # (the centimetre layers below it are far narrower than one SFS pixel row is long).
        # The SFS DEM is another place, a flat landing region, while the layers follow the
        # terrain's regional slope law: compared by shape, its amplitude shown (compare_dems)
        ref = read_dem(real["sfs"])
        k = min(range(len(stack.tiles)),
                key=lambda i: abs(math.log(stack.tiles[i].resolution / 0.5)))
        compare(stack.tiles[k], ref, f"layer {k} (site)", "LROC NAC SFS DEM (85 S)",
                shape_only=True)
    else:
        notes.append(f"{real.get('sfs')} not found: the finest layers are not compared with "
                     "real data")
    sec = dem_section(evidence.distributions, evidence.spectra, evidence.fits,
                      comparisons, limits, key="lunar layers")
    sec.notes += notes
    sec.paragraphs.append(DEM_NOTE)
    sections.append(sec)
    sections += validation_sections(realism, key="lunar")
    facts["realism"] = dict(verdict=realism.verdict,
                            failed=[f"{r.name}: {r.meaning}" for r in realism.failures()])
    facts["terrain_figures"] = dict(terrain=terrain, rows=[
        [label, value] for label, value in preset_figures(realism)])
    facts["dem_comparisons"] = [dict(label=x.label, reference=x.reference_label,
                                     ks=x.ks_distance, resolution_m=x.resolution_m,
                                     shape_ks=x.shape_ks_distance, shape_only=x.shape_only,
                                     amplitude_ratio=x.amplitude_ratio,
                                     median=x.distribution.quantiles["p50"],
                                     reference_median=x.reference_distribution.quantiles["p50"])
                                for x in comparisons]

    # -- the landing site at lander scale: hazards, rocks, the layers under the descent
    say("evaluation: hazard map, rocks and the layers drawn under the descent")
    sections.append(site(ev, folder, stack_dir, load_run(run_dir), facts, say, stack=stack))
    return sections, facts, messages



def measure_consistency(run_dir: Path, folder: Path):
    """Measure a run's frame-to-frame consistency and write it to ``folder``.

    Large frames are measured on a grid of pixels
    (:func:`evaluation.consistency.sampling_stride`; docs/speed.md: the uncertainty).

    Returns
    -------
    result : evaluation.consistency.Consistency
    summary : dict
        What :func:`evaluation.consistency.save_consistency` returned.
    drawn : dict
        The figure it drew, as PNG bytes (:func:`evaluation.figures.drawn_once`), for the
        report's consistency section.
    """
    from evaluation.consistency import consistency, sampling_stride, save_consistency
    from evaluation.tracking import load_run

    run = load_run(run_dir)
    result = consistency(run, stride=sampling_stride(run.image(0).shape))
    drawn: dict = {}
    return result, save_consistency(result, folder, drawn=drawn), drawn


def consistency_report(run, scored, tracking_sec, folder: Path, limits, key, facts, seed,
                       say, measured=None):
    """Consistency of a run's frames and the tracker's own share of its one-step error.

    Writes ``folder`` (:func:`evaluation.consistency.save_consistency`), adds the one-step
    error of the same tracker on truth-warped frames to the tracking table and ``facts``, and
    returns the report's consistency section.

    Parameters
    ----------
    run : render.rundir.RunReader
        The rendered run.
    scored : evaluation.tracking.ScoredTracks
        Its tracks, scored against truth.
    tracking_sec : evaluation.report.Section
        The run's tracking section (its "Tracking" table and paragraphs are extended).
    folder : pathlib.Path
        Where the consistency files go.
    limits : dict
        The report's thresholds.
    key : str
        The run's name in the report (``"lunar descent"``).
    facts : dict
        The run's facts, extended with the one-step and consistency figures.
    seed : int
        Seed of the fresh sensor noise.
    say : callable
        Called with one line of progress.
    measured : concurrent.futures.Future, optional
        Of :func:`measure_consistency` of this run into ``folder``, when another process
        measures it (else it is measured here).

    Returns
    -------
    evaluation.report.Section
        The consistency section.
    """
    import numpy as np

    from evaluation.report import consistency_section
    from evaluation.tracking import ideal_one_steps

    say(f"evaluation: frame-to-frame consistency of the {key}")
    # without and with fresh sensor noise, each truth-warped frame made once for both; a
    # long run on every fourth step (docs/speed.md: the uncertainty). Measured before the
    # consistency is asked for, so that another process measuring it has the time to.
    every = IDEAL_STEP_STRIDE if len(run) - 1 >= IDEAL_SAMPLED_STEPS else 1
    ideal, noisy = ideal_one_steps(scored, run, noises=(None, seed), every=every)
    result, summary, drawn = (measure_consistency(Path(run.dir), folder) if measured is None
                              else measured.result())
    ideal = ideal[np.isfinite(ideal)]
    noisy = noisy[np.isfinite(noisy)]
    errors = scored.error_summary() or {}
    one = (errors.get("one_step") or {}).get("median_px")
    facts.update(one_step_median_px=one,
                 one_step_surface_median_px=(errors.get("one_step") or {}).get(
                     "surface_median_px"),
                 ideal_one_step_median_px=float(np.median(ideal)) if ideal.size else None,
                 ideal_noisy_one_step_median_px=(float(np.median(noisy)) if noisy.size
                                                 else None),
                 consistency_spike_ratio=summary["spike_ratio"],
                 consistency_rms_dn_median=summary["rms_dn_median"],
                 consistency_noise_floor_dn_median=summary["noise_floor_dn_median"])
    if ideal.size and noisy.size and one is not None:
        if every > 1:
            ordinal = {2: "second", 3: "third", 4: "fourth"}.get(every, f"{every}th")
            tracking_sec.notes.append(
                f"The tracker on truth-warped frames follows every {ordinal} step of this run; "
                "measured on the demo's descent against every step (docs/speed.md), every "
                "fourth step moves its medians by 0.8 % at most.")
        tracking_sec.table("Tracking").append(
            ["one-step error of the same tracker on truth-warped frames, without / with "
             "fresh sensor noise (median px)", f"{np.median(ideal):.3g} / "
             f"{np.median(noisy):.3g}"])
        tracking_sec.paragraphs.append(
            f"The one-step error (median {one:.3g} px) is what one step of tracking adds. "
            f"The same tracker following frames warped through the truth, which agree with "
            f"the truth exactly, errs by {np.median(ideal):.3g} px per step: that much is "
            "the tracker's own (its shift-only motion model under zoom and rotation). With "
            f"the sensor's fresh noise added to those frames it errs by "
            f"{np.median(noisy):.3g} px: the rest of the real error comes from how the "
            "frames themselves change (shading that truly changes with the view and the "
            "sun, and anything the renderer changes between frames; the consistency "
            "section measures that). The accumulated error grows with a track's age by "
            "the sum of those steps.")
    return consistency_section(result, limits, run_label=f"the {key}", key=key, drawn=drawn)


def site(ev, folder: Path, stack_dir: Path, run, facts: dict, say, *, stack=None):
    """Return the site section: hazards, rocks and the layers drawn under the descent.

    The hazard map of the site (:class:`terrain.stages.specs.HazardsSpec`), the rocks against their
    model and the finest layer drawn under each descent frame's centre.

    Parameters
    ----------
    ev : Mapping
        The campaign's ``[evaluation]`` table (its lander).
    folder : pathlib.Path
        The evaluation folder.
    stack_dir : pathlib.Path
        The layer stack.
    run : render.rundir.RunReader
        The descent.
    facts : dict
        The stage's facts, extended with ``site``.
    say : callable
        Called with one line per frame reported.
    stack : terrain.stack.model.LayerStack, optional
        The stack at ``stack_dir``, already read (not read again for the rocks and descent).

    Returns
    -------
    evaluation.report.Section
        The site section.
    """
    from evaluation.hazards import hazards_file_section
    from terrain.stages.runner import run as run_stage
    from terrain.stages.specs import HazardsSpec

    tif = folder / "hazards.tif"
    spec = HazardsSpec.from_mapping({"lander_diameter": ev.get("lander_diameter", 4.0),
                                     "max_slope": ev.get("max_slope", 12.0),
                                     "max_step": ev.get("max_step", 0.3)})
    log.info("%s", run_stage(spec, stack_dir, tif).message)
    n = len(run)
    frames = (60, 90, 110, 119) if n == 120 else sorted({n // 2, 3 * n // 4, n - 2, n - 1})
    sec = hazards_file_section(tif, run=run, frames=frames, stack=stack)
    sec.links = [("hazard bands: slope, step, safe (GeoTIFF)", "hazards.tif"),
                 ("hazard map (PNG)", "hazards.png"),
                 ("rock catalogue (CSV)", os.path.relpath(stack_dir / "rocks.csv", folder))]
    descent = sec.data.get("descent", [])
    facts["site"] = dict(safe_fraction=sec.data["safe_fraction"], layer=sec.data["layer"],
                         rocks=sec.data.get("rocks", {}).get("total"),
                         descent=[r for r in descent if r["frame"] in frames])
    for r in facts["site"]["descent"]:
        say(f"frame {r['frame']}: GSD {r['gsd_m']:.3g} m at the centre, finest layer drawn "
            f"{r['layer']} ({r['layer_resolution_m']:.3g} m)")
    return sec


def campaign_section(c: Campaign, out, folder, lunar_facts, asteroid_facts, tracked,
                     summary_name: str = "campaign.json"):
    """Return the report's first section: what was made, how long it took, pictures, links.

    Parameters
    ----------
    c : Campaign
        The campaign (its summary paragraph).
    out, folder : pathlib.Path
        The output folder and the evaluation folder (links are relative to it).
    lunar_facts, asteroid_facts : dict
        The runs' folders.
    tracked : dict
        ``{"lunar": run, "asteroid": run}`` (:class:`render.rundir.RunReader`).
    summary_name : str, optional
        The campaign's timing file.

    Returns
    -------
    evaluation.report.Section
        The overview section.
    """
    from evaluation.figures import range_thumbnail, read_png, thumbnail
    from evaluation.report import Section, image_figure

    sec = Section("campaign", "The campaign")
    if c.summary:
        sec.paragraphs.append(c.summary)
    rows = []
    for name in STAGES[:-1]:
        marker = out / f".{name.replace('/', '_')}.done.json"
        if not marker.exists():
            continue
        info = json.loads(marker.read_text())
        fps = info.get("fps")
        rows.append([name, f"{info['seconds']:.1f}", info.get("frames", ""),
                     f"{fps:.2f}" if fps else ""])
    sec.tables.append(("Stages (seconds of wall time on this machine)",
                       ["stage", "seconds", "frames", "frames per second"], rows))
    gallery = folder / "gallery"
    gallery.mkdir(exist_ok=True)
    res = c.base.get("resolution", 1.0)
    figures = [("base", f"Base DEM, hillshaded ({res / 1000:g} km per pixel)"
                if res >= 1000 else f"Base DEM, hillshaded ({res:g} m per pixel)",
                thumbnail(read_png(out / "lunar" / "base" / "base_hillshade.png"),
                          gallery / "lunar_base.png"))]
    for name, label in (("lunar", "Lunar descent"), ("asteroid", "Asteroid approach")):
        run = tracked[name]
        n = len(run)
        for k, when in ((0, "first frame"), (n // 2, "middle frame"), (n - 1, "last frame")):
            figures.append((f"{name}-{k}", f"{label}, {when} ({k})",
                            thumbnail(run.image(k), gallery / f"{name}_frame_{k:03d}.png")))
        rng = run.range(n - 1)
        if rng is not None:
            figures.append((f"{name}-range", f"{label}, LIDAR range of the last frame",
                            range_thumbnail(rng, gallery / f"{name}_range_{n - 1:03d}.png")))
    sec.figures += [image_figure(fid, title, path) for fid, title, path in figures]

    def rel(path: Path) -> str:
        return Path(os.path.relpath(path, folder)).as_posix()

    lunar_run, asteroid_run = Path(lunar_facts["run"]), Path(asteroid_facts["run"])
    body = Path(asteroid_facts["body"])
    links = [
        ("lunar base DEM (GeoTIFF)", out / "lunar" / "base" / "base.tif"),
        ("lunar base craters (CSV)", out / "lunar" / "base" / "base_craters.csv"),
        ("layer stack manifest (layers, windows, crater counts)",
         Path(lunar_facts["stack"]) / "manifest.json"),
        ("descent frames", lunar_run / "frames"),
        ("descent LIDAR range images (metres, float32 GeoTIFF)", lunar_run / "range"),
        ("descent truth: pose, intrinsics, sun, drawn layers per frame", lunar_run / "truth.json"),
        ("descent scenario as run", lunar_run / "scenario.toml"),
        ("descent feature tracks (CSV)", folder / "lunar_tracks" / "tracks.csv"),
        ("asteroid model (PLY; boulders at their coarsest level)", body.with_suffix(".ply")),
        ("asteroid model (native .npz: body, craters, boulders at every level)", body),
        ("asteroid craters and boulders (CSV)", body.parent / "body_craters.csv"),
        ("approach frames", asteroid_run / "frames"),
        ("approach LIDAR range images", asteroid_run / "range"),
        ("approach truth", asteroid_run / "truth.json"),
        ("approach feature tracks (CSV)", folder / "asteroid_tracks" / "tracks.csv"),
        ("descent frame-to-frame consistency (JSON)",
         folder / "lunar_consistency" / "consistency.json"),
        ("approach frame-to-frame consistency (JSON)",
         folder / "asteroid_consistency" / "consistency.json"),
        ("this report's numbers (JSON)", folder / "report.json"),
        ("stage timings (JSON)", out / summary_name),
    ]
    sec.links = [(label, rel(path)) for label, path in links if path.exists()
                 or path.name in ("report.json", summary_name)]
    return sec


def closed_loop_section(folder: Path, report_dir: Path):
    """Return the closed-loop landing: where it went, what navigation believed, how wrong it was.

    Parameters
    ----------
    folder : pathlib.Path
        The closed-loop stage's folder (``summary.json``, ``closed_loop.png``, ``frames/``).
    report_dir : pathlib.Path
        The evaluation folder (links are relative to it).

    Returns
    -------
    evaluation.report.Section
        The closed-loop section.
    """
    from evaluation.figures import read_png, thumbnail
    from evaluation.report import Section, image_figure

    s = json.loads((folder / "summary.json").read_text())
    sec = Section("closed-loop", "Closed loop: a landing flown through the render server")
    sec.paragraphs.append(
        f"examples/closed_loop.py drove `craterscape render serve` on the descent's scenario: "
        f"every {s['dt']:g} s the guidance asked the server for a laser-altimeter range (RAY) "
        f"and a {s['size']} x {s['size']} nadir image (SET_POSE, GET_IMAGE), and nothing else. "
        "Lateral velocity is optical flow (phase correlation after scaling the previous image "
        "by the altimeter's altitude ratio); position integrates it from an initial guess "
        f"{math.hypot(*s['initial_error']):.0f} m off, fixed above {s['trn_above']:.0f} m by "
        "terrain-relative navigation (the server's view from the estimated position, standing "
        "in for an onboard map, correlated with the real image). The vehicle's true motion, "
        "with thruster noise, is simulated beside it and used only to score the navigation.")
    sec.tables.append(("The landing", ["quantity", "value"], [
        ["start", f"{s['start_altitude']:.0f} m above the site, "
                  f"{math.hypot(*s['offset']):.0f} m off it"],
        ["steps, time to touchdown", f"{s['steps']}, {s['touchdown_time_s']:.0f} s"],
        ["touchdown", "ground contact between steps" if s["crashed"]
         else f"altimeter {s['touchdown_altimeter_m']:.2f} m, "
              f"{s['touchdown_speed_mps']:.2f} m/s"],
        ["landing error from the site (truth)", f"{s['landing_error_m']:.1f} m"],
        ["lateral navigation error: start, median, at touchdown",
         f"{s['nav_error_lateral_m']['initial']:.1f}, {s['nav_error_lateral_m']['median']:.1f},"
         f" {s['nav_error_lateral_m']['final']:.1f} m"],
        ["lateral velocity error (median)", f"{s['nav_error_velocity_mps']['median']:.2f} m/s"],
    ]))
    frames = sorted((folder / "frames").glob("frame_*.png"))
    gallery = report_dir / "gallery"
    gallery.mkdir(exist_ok=True)
    sec.figures.append(image_figure("closed-loop-track", "Ground track, descent and navigation "
                                    "error against truth", folder / "closed_loop.png"))
    for k in (0, len(frames) // 2, len(frames) - 1):
        sec.figures.append(image_figure(
            f"closed-loop-frame-{k}", f"What the camera returned, step {k}",
            thumbnail(read_png(frames[k]), gallery / f"closed_loop_{k:04d}.png")))
    sec.data = s
    sec.links = [(label, Path(os.path.relpath(folder / name, report_dir)).as_posix())
                 for label, name in (("closed-loop trajectory, estimates and errors (CSV)",
                                      "trajectory.csv"),
                                     ("closed-loop camera frames", "frames"),
                                     ("closed-loop summary (JSON)", "summary.json"))]
    return sec


def crater_navigation_section(folder: Path, report_dir: Path):
    """Return crater-based navigation on the descent: position error per frame against truth.

    Parameters
    ----------
    folder : pathlib.Path
        What ``examples/crater_navigation.py --out`` wrote (``summary.json``, ``frames.csv``).
    report_dir : pathlib.Path
        The evaluation folder (links are relative to it).

    Returns
    -------
    evaluation.report.Section
        The crater-navigation section.
    """
    from evaluation.report import Section

    s = json.loads((folder / "summary.json").read_text())
    lo, hi = s["tron_percent"]
    det, prior = s["detector"], s["prior"]
    sec = Section("crater-navigation", "Crater-based navigation against truth")
    median = s.get("median_error_percent")
    if median is None:
        where = "solved no frame"
    elif median < lo:
        where = f"lands below that band (median {median:.2f} %)"
    elif median <= hi:
        where = f"lands inside that band (median {median:.2f} %)"
    else:
        where = f"lands above that band (median {median:.2f} %)"
    sec.paragraphs.append(
        "examples/crater_navigation.py detected craters in the labelled descent (the truth "
        f"rims perturbed by {det['sigma_px']:g} px plus {100 * det['sigma_rel']:g} % of the "
        f"rim's semi-major axis, {100 * det['miss']:g} % missed, lit rims only), matched them "
        "to the catalogue through a prior pose "
        f"({100 * prior['position_fraction_of_range']:g} % of range, "
        f"{prior['attitude_deg']:g} degrees off), and solved the camera pose by PnP on the "
        f"matched rim centres. Field-tested feature TRN reaches {lo:g}-{hi:g} % of "
        f"line-of-sight range (DLR's TRON laboratory); this reference {where} over "
        f"{s['solved']} of {s['frames']} frames. Its detector is an idealised one: exact "
        "matching identities, no false detections, and an error that is white, where a real "
        "detector's is correlated with the lighting; so its figure bounds what the geometry "
        "allows, not what a flight detector achieves.")
    sec.tables.append(("Position error per frame", [
        "frame", "range (m)", "detected", "matched", "inliers", "error (m)", "error (% range)",
        "prior (% range)"], [
        [r["frame"], f"{r['range_m']:.0f}", r["detected"], r["matched"], r["inliers"],
         f"{r['error_m']:.2f}", f"{r['error_percent']:.2f}", f"{r['prior_error_percent']:.1f}"]
        for r in s["per_frame"]]))
    sec.data = {k: v for k, v in s.items() if k != "per_frame"}
    sec.links = [(label, Path(os.path.relpath(folder / name, report_dir)).as_posix())
                 for label, name in (("per-frame navigation errors (CSV)", "frames.csv"),
                                     ("crater-navigation summary (JSON)", "summary.json"))]
    return sec
