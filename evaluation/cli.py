"""The ``craterscape evaluation`` commands.

They are registered through the ``craterscape.groups`` entry point, so the root command in
:mod:`terrain.cli.commands` never imports this package.

::

    craterscape evaluation slopes DEM_OR_STACK... -o OUTDIR [--band N] [--reference REF.tif]
        [--reference-band N] [--slope-band N] [--baseline M] [--compute-edges]
    craterscape evaluation asteroid-slopes MESH... -o OUTDIR [--units km] [--density D | --mass M]
        [--period-hours H] [--spin-axis X,Y,Z] [--reference MESH] [--no-gravity]
    craterscape evaluation track RUN_DIR -o OUTDIR [--max-corners N] [--fb-threshold PX]
    craterscape evaluation consistency RUN_DIR -o OUTDIR [--edge-px N]
    craterscape evaluation report [RUN_DIR] -o REPORT.html [--thresholds T.toml]
        [--dem DEM ...] [--reference REF.tif] [--mesh MESH ...] [--reference-mesh MESH]
    craterscape evaluation thresholds          # print the default thresholds (TOML)
    craterscape evaluation validate DEM_OR_STACK --terrain south-polar|highlands|maria
        [-o REPORT.html] [--reference REAL_DEM]

Every file is written atomically and never over an input; errors craterscape raises on
purpose become one line on stderr and exit code 2 (the root group does this; ``-v`` shows the
traceback).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import click

from evaluation.evidence import write_csv
from terrain.cli.tools import TRIPLE, progress_bar, version, with_options
from terrain.core import metakeys as mk
from terrain.core.errors import InvalidParameterError, MissingInputError

__all__ = ["evaluation"]

log = logging.getLogger(__name__)


def _outdir(path: Path, inputs=()) -> Path:
    """Return the output folder, checked (never an input or inside one) and created.

    Commands call it after their checks and computations, inside the transaction that
    writes their files, so a command that fails leaves no folder and no file behind.
    """
    from terrain.core.outputs import make_output_folder

    return make_output_folder(path, inputs)


def _write_text(path: Path, text: str, inputs=()) -> None:
    from terrain.core.outputs import atomic_path

    with atomic_path(path, inputs) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _unique(names):
    seen: dict = {}
    out = []
    for name in names:
        k = seen.get(name, 0)
        seen[name] = k + 1
        out.append(name if k == 0 else f"{name}_{k + 1}")
    return out


# ------------------------------------------------------------------------------ inputs


def _dem_inputs(paths, band: int) -> list:
    """(label, tile) for every DEM, expanding layer stacks (a folder or its manifest.json)."""
    from terrain.io import read_dem
    from terrain.stack.store import read_stack

    items = []
    for path in paths:
        path = Path(path)
        if path.is_dir() or path.name == "manifest.json":
            folder = path if path.is_dir() else path.parent
            if not (folder / "manifest.json").exists():
                raise MissingInputError(f"'{folder}' is a folder without manifest.json; give "
                                        "DEM files or layer-stack folders")
            stack = read_stack(folder)
            items += [(f"{folder.name}_layer_{k:02d}",
                       t.replace(metadata={**t.metadata, mk.STACK_LAYER: str(k)}))
                      for k, t in enumerate(stack.tiles)]
        else:
            items.append((path.stem, read_dem(path, band=band)))
    labels = _unique([label for label, _ in items])
    return [(label, tile) for label, (_, tile) in zip(labels, items, strict=True)]


def _with_stack_folders(paths) -> list:
    """Return the inputs, plus the folder of every layer stack named by its manifest.json.

    Nothing is ever written into an input stack.
    """
    out = list(paths)
    out += [Path(p).parent for p in paths if Path(p).name == "manifest.json"]
    return out


def _reference(dems, reference, reference_band):
    """Return the reference DEM, after checking every input shares its CRS (before any work)."""
    from evaluation.compare import check_same_crs
    from terrain.io import read_dem

    if reference is None:
        return None
    ref_tile = read_dem(reference, band=reference_band)
    for label, tile in dems:
        check_same_crs(tile, ref_tile, names=(label, Path(reference).stem))
    return ref_tile


# ------------------------------------------------------------------------------ group


@click.group()
def evaluation():
    """Evidence that a model is fit for testing a lander: slopes, spectra, tracking."""


_edges_option = click.option(
    "--compute-edges", is_flag=True,
    help="Extrapolate slopes at the DEM's edges and across gaps like gdaldem "
         "-compute_edges (default: edge pixels and gap neighbours are left out).")


@evaluation.command()
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (created if missing).")
@click.option("--band", type=int, default=1, show_default=True, help="Height band of the DEMs.")
@click.option("--reference", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Reference DEM to compare every input with (matched baseline).")
@click.option("--reference-band", type=int, default=1, show_default=True,
              help="Height band of the reference.")
@click.option("--slope-band", type=int, default=None,
              help="Band of each input holding an independent slope map (degrees) to check "
                   "the Horn slope against, pixel by pixel.")
@click.option("--baseline", type=float, default=None,
              help="Measure the distributions at this pixel spacing (m): finer DEMs are "
                   "averaged onto it.")
@_edges_option
def slopes(inputs, output, band, reference, reference_band, slope_band, baseline,
           compute_edges):
    """Slope maps, slope distributions and power spectra of DEMs or layer stacks."""
    from evaluation.evidence import dem_evidence
    from evaluation.slope import slope_tile

    if baseline is not None and not baseline > 0:
        raise InvalidParameterError(f"--baseline must be positive metres; got {baseline}")
    from terrain.core.outputs import check_output_folder, transaction

    edges = "gdal" if compute_edges else "mask"
    srcs = _with_stack_folders([*inputs] + ([reference] if reference else []))
    check_output_folder(output, srcs)
    dems = _dem_inputs(inputs, band)
    ref_tile = _reference(dems, reference, reference_band)
    # everything is measured before anything is written
    slope_maps = [(label, slope_tile(tile, edges=edges).with_metadata(
        **{mk.COMMAND: "evaluation slopes", mk.VERSION: version()}))
        for label, tile in dems]
    evidence = dem_evidence(dems, reference=reference, ref_tile=ref_tile,
                            slope_band=slope_band, baseline=baseline, edges=edges)
    with transaction():
        _write_slopes(output, srcs, slope_maps, evidence)
    message = f"wrote slopes of {len(dems)} DEM(s) to {output}"
    for c in evidence.comparisons:
        message += (f"; {c.label} vs {c.reference_label}: KS {c.ks_distance:.3f} at "
                    f"{c.resolution_m:.4g} m")
    for label, a in evidence.agreements:
        message += f"; {label}: median |diff| {a.median_abs_deg:.3g} deg"
    click.echo(message, err=True)


def _write_slopes(output, srcs, slope_maps, evidence):
    from evaluation.evidence import write_evidence_csvs
    from evaluation.figures import save_png, slope_distribution_figure, spectrum_figure
    from terrain.io import write_dem

    outdir = _outdir(output, srcs)
    for label, out in slope_maps:
        write_dem(out, outdir / f"{label}_slope.tif", inputs=srcs, description="slope (deg)")
    write_evidence_csvs(evidence, outdir, srcs)
    distributions, spectra, fits = evidence.distributions, evidence.spectra, evidence.fits
    comparisons, agreements = evidence.comparisons, evidence.agreements
    save_png(slope_distribution_figure(distributions), outdir / "slope_distributions.png",
             inputs=srcs)
    from terrain.core.outputs import discard

    if spectra:
        save_png(spectrum_figure(spectra, fits), outdir / "spectra.png", inputs=srcs)
    else:  # an earlier run's figure would be stale beside these results
        discard(outdir / "spectra.png")
    if comparisons or agreements:
        doc = dict(comparisons=[c.as_dict() for c in comparisons],
                   slope_map_agreement=[dict(label=label, **a.as_dict())
                                        for label, a in agreements])
        _write_text(outdir / "comparison.json", json.dumps(doc, indent=1), srcs)
    else:
        discard(outdir / "comparison.json")


def _gravity_options(func):
    options = [
        click.option("--units", type=click.Choice(["m", "km"]), default="m", show_default=True,
                     help="Units of mesh files (PDS shape models are in km; .npz is metres)."),
        click.option("--density", type=float, default=None,
                     help="Bulk density, kg/m^3 (default 2670, Eros)."),
        click.option("--mass", type=float, default=None,
                     help="Mass in kg, instead of the density."),
        click.option("--period-hours", type=float, default=None,
                     help="Spin period in hours (default: no spin; Eros: 5.27)."),
        click.option("--spin-axis", type=TRIPLE, default="0,0,1", show_default=True,
                     help="Spin axis in the body frame."),
        click.option("--radius-deg", type=float, default=3.0, show_default=True,
                     help="Cap radius of the per-vertex slope average (degrees)."),
        click.option("--coarse-faces", type=int, default=None,
                     help="Triangles of the coarsened body the gravity is computed from "
                          "(default 4000)."),
        click.option("--no-gravity", is_flag=True,
                     help="Radial slopes only (no gravitational slopes)."),
    ]
    return with_options(options)(func)


def _body_slopes(path, *, units, density, mass, period_hours, spin_axis, radius_deg,
                 coarse_faces, no_gravity):
    from evaluation.meshslope import DEFAULT_COARSE_FACES, Spin, load_body, mesh_slopes

    shape = load_body(path, units=units)
    with progress_bar(f"gravity {Path(path).name}") as update:
        return mesh_slopes(shape.vertices, shape.faces, label=Path(path).stem,
                           radius_deg=radius_deg, gravity=not no_gravity, density=density,
                           mass=mass, spin=Spin(period_hours, spin_axis),
                           coarse_faces=coarse_faces or DEFAULT_COARSE_FACES,
                           progress=update)


@evaluation.command("asteroid-slopes")
@click.argument("meshes", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (created if missing).")
@click.option("--reference", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="A real body (mesh) to compare every mesh with.")
@click.option("--reference-units", type=click.Choice(["m", "km"]), default=None,
              help="Units of the reference mesh (default: --units).")
@click.option("--bin-deg", type=float, default=3.0, show_default=True,
              help="Histogram bin width (degrees).")
@_gravity_options
def asteroid_slopes(meshes, output, reference, reference_units, bin_deg, units, density, mass,
                    period_hours, spin_axis, radius_deg, coarse_faces, no_gravity):
    """Radial and gravitational slopes of closed meshes, as slope-area histograms."""
    from evaluation.compare import ks_distance
    from evaluation.figures import save_png, slope_area_figure
    from terrain.core.outputs import check_output_folder, transaction

    common = dict(density=density, mass=mass, period_hours=period_hours, spin_axis=spin_axis,
                  radius_deg=radius_deg, coarse_faces=coarse_faces, no_gravity=no_gravity)
    srcs = [*meshes] + ([reference] if reference else [])
    check_output_folder(output, srcs)
    bodies = [_body_slopes(m, units=units, **common) for m in meshes]
    ref = None
    if reference is not None:
        ref = _body_slopes(reference, units=reference_units or units, **common)
    with transaction():  # every file or none
        outdir = _outdir(output, srcs)
        everyone = bodies + ([ref] if ref is not None else [])
        labels = _unique([b.label for b in everyone])
        kinds = ["radial"] if no_gravity else ["gravitational", "radial"]
        rows = []
        summary = dict(bodies=[], reference=None)
        for label, b in zip(labels, everyone, strict=True):
            vrows = []
            grav = b.gravitational_deg
            for i in range(b.vertex_area.size):
                row = [i, f"{b.vertex_area[i]:.6g}", f"{b.radial_deg[i]:.4f}"]
                if grav is not None:
                    row += [f"{grav[i]:.4f}"] + [f"{x:.6g}" for x in b.gravity[i]]
                vrows.append(row)
            header = ["vertex", "area_m2", "radial_slope_deg"]
            if grav is not None:
                header += ["gravitational_slope_deg", "g_x_m_s2", "g_y_m_s2", "g_z_m_s2"]
            write_csv(outdir / f"{label}_vertex_slopes.csv", header, vrows, srcs)
            for kind in kinds:
                h = b.histogram(kind, bin_deg=bin_deg)
                rows += [[label, kind, f"{h.edges_deg[i]:g}", f"{h.edges_deg[i + 1]:g}",
                          f"{h.area_percent[i]:.6g}", f"{h.percent_steeper[i]:.6g}"]
                         for i in range(h.area_percent.size)]
            entry = b.as_dict()
            entry["label"] = label
            if ref is not None and b is not ref:
                entry["ks_vs_reference"] = {
                    k: ks_distance(b.slopes(k), ref.slopes(k), weights_a=b.vertex_area,
                                   weights_b=ref.vertex_area) for k in kinds}
            if b is ref:
                summary["reference"] = entry
            else:
                summary["bodies"].append(entry)
        write_csv(outdir / "slope_area_histograms.csv",
                   ["label", "kind", "bin_low_deg", "bin_high_deg", "area_percent",
                    "percent_steeper_than_bin_low"], rows, srcs)
        _write_text(outdir / "asteroid_slopes.json", json.dumps(summary, indent=1), srcs)
        for kind in kinds:
            save_png(slope_area_figure([b.histogram(kind, bin_deg=bin_deg) for b in everyone]),
                     outdir / f"slope_area_{kind}.png", inputs=srcs)
    parts = []
    for label, b in zip(labels, everyone, strict=True):
        text = f"{label}: radial median {b.summary('radial')['p50']:.1f} deg"
        if b.gravitational_deg is not None:
            g = b.summary("gravitational")
            text += (f", gravitational median {g['p50']:.1f} deg "
                     f"({100 * g['area_fraction_below_35deg']:.1f} % of the area below 35)")
        parts.append(text)
    click.echo(f"wrote slopes of {len(everyone)} bodies to {output}; " + "; ".join(parts),
               err=True)


#: Help of each :class:`evaluation.tracking.TrackerSettings` field as a command-line option
#: (``--max-corners`` for ``max_corners``); types and defaults come from the record.
TRACKER_HELP = {
    "max_corners": "Live tracks kept (replenished every frame).",
    "quality": "Harris quality level (fraction of the strongest corner).",
    "min_distance": "Least distance between features (px).",
    "block_size": "Harris window (px).",
    "harris_k": "Harris detector free parameter.",
    "win_size": "Lucas-Kanade window (px).",
    "levels": "Pyramid levels.",
    "fb_threshold": "Largest forward-backward error of a kept point (px).",
    "border": "Points closer than this to the image edge are dropped (px).",
    "prewarp": "Track from the previous frame warped by the step's homography (no drift "
               "under zoom and roll), or plain Lucas-Kanade.",
    "dark_level": "Grey levels (of 255) above a frame's darkest pixel that carry no signal "
                  "(sky, deep shadow).",
    "dark_margin": "No corner is detected this close to a region without signal (px; 0: "
                   "anywhere; default: half the window plus 2).",
}


def _tracker_options(func):
    """Give a command one option per TrackerSettings field and pass it ``tracker``, the record.

    Also adds ``--outlier-px`` (a scoring option, passed on as ``outlier_px``).
    """
    import dataclasses
    import functools
    import typing

    from evaluation.tracking import TrackerSettings

    hints = typing.get_type_hints(TrackerSettings)
    fields = dataclasses.fields(TrackerSettings)
    names = [f.name for f in fields]
    if set(names) != set(TRACKER_HELP):
        raise RuntimeError(f"TRACKER_HELP must describe exactly {sorted(names)}")

    @functools.wraps(func)
    def command(**kwargs):
        tracker = TrackerSettings(**{name: kwargs.pop(name) for name in names})
        return func(tracker=tracker, **kwargs)

    options = []
    for f in fields:
        flag = "--" + f.name.replace("_", "-")
        kind = typing.get_args(hints[f.name]) or (hints[f.name],)
        kind = next(k for k in kind if k is not type(None))
        if kind is bool:
            options.append(click.option(f"{flag}/--no-{flag[2:]}", f.name, default=f.default,
                                        show_default=True, help=TRACKER_HELP[f.name]))
        else:
            options.append(click.option(flag, f.name, type=kind, default=f.default,
                                        show_default=f.default is not None,
                                        help=TRACKER_HELP[f.name]))
    options.append(click.option("--outlier-px", type=float, default=None,
                                help="Errors above this are outliers (px; default 2, or the "
                                     "thresholds file's tracking.outlier_px)."))
    return with_options(options)(command)


def _run_tracking(run_dir, tracker, outlier_px):
    from evaluation.tracking import load_run, score, track

    run = load_run(run_dir)
    with progress_bar("tracking") as update:
        tracks = track(run, tracker, progress=update)
    return run, score(tracks, run, outlier_px=outlier_px)


@evaluation.command("track")
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (created if missing).")
@_tracker_options
def track_cmd(run_dir, output, tracker, outlier_px):
    """Track Harris corners through a rendered run and score them against its truth."""
    from evaluation.tracking import save_tracks
    from terrain.core.outputs import check_output_folder, transaction

    if output.resolve() == run_dir.resolve():
        raise InvalidParameterError("the output folder must differ from the run directory")
    check_output_folder(output, [run_dir])
    run, scored = _run_tracking(run_dir, tracker, 2.0 if outlier_px is None else outlier_px)
    with transaction():  # every file or none
        s = save_tracks(scored, run, _outdir(output, [run_dir]),
                        inputs=[run_dir / "truth.json", run_dir / "manifest.json"])
    msg = (f"wrote {s['tracking']['tracks']} tracks over {s['tracking']['frames']} frames to "
           f"{output}")
    if s["errors"] is not None and s["errors"]["median_px"] is not None:
        msg += (f"; median error {s['errors']['median_px']:.3f} px, outliers "
                f"{100 * s['errors']['outlier_fraction']:.2f} %")
        one = s["errors"].get("one_step") or {}
        if one.get("median_px") is not None:
            msg += f"; one-step median {one['median_px']:.3f} px"
    else:
        msg += "; no truth, so no tracking errors"
    click.echo(msg, err=True)


@evaluation.command("consistency")
@click.argument("run_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (created if missing).")
@click.option("--edge-px", type=int, default=2, show_default=True,
              help="Margin around silhouettes and moving shadow edges (px).")
@click.option("--occlusion-tolerance", type=float, default=0.002, show_default=True,
              help="Relative range disagreement above which a point is hidden in the next "
                   "frame.")
def consistency_cmd(run_dir, output, edge_px, occlusion_tolerance):
    """Frame-to-frame consistency: each frame warped into the previous one through the truth."""
    from evaluation.consistency import consistency, save_consistency

    if output.resolve() == run_dir.resolve():
        raise InvalidParameterError("the output folder must differ from the run directory")
    with progress_bar("consistency") as update:
        result = consistency(run_dir, edge_px=edge_px, occlusion_tolerance=occlusion_tolerance,
                             progress=update)
    s = save_consistency(result, _outdir(output),
                         inputs=[run_dir / "truth.json", run_dir / "manifest.json"])
    msg = f"wrote the consistency of {s['pairs']} frame pairs to {output}"
    if s["rms_dn_median"] is not None:
        msg += (f"; residual rms median {s['rms_dn_median']:.3g} DN, largest "
                f"{s['rms_dn_max']:.3g} DN ({s['spike_ratio']:.2f} x the median)")
        if s["noise_floor_dn_median"] is not None:
            msg += f", sensor noise of a pair {s['noise_floor_dn_median']:.3g} DN"
    click.echo(msg, err=True)


@evaluation.command()
@click.argument("run_dirs", nargs=-1, type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Report HTML file; its JSON twin is written beside it (.json).")
@click.option("--thresholds", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="TOML file of pass/fail thresholds (see `craterscape evaluation "
                   "thresholds`).")
@click.option("--title", type=str, default="craterscape validation report",
              show_default=True, help="Report title.")
@click.option("--dem", "dems", multiple=True, type=click.Path(path_type=Path),
              help="DEM or layer stack to include (repeatable).")
@click.option("--band", type=int, default=1, show_default=True, help="Height band of --dem.")
@click.option("--reference", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Reference DEM the --dem inputs are compared with.")
@click.option("--reference-band", type=int, default=1, show_default=True,
              help="Height band of the reference.")
@click.option("--slope-band", type=int, default=None,
              help="Band of each --dem holding an independent slope map to check against.")
@click.option("--mesh", "meshes", multiple=True, type=click.Path(dir_okay=False,
                                                                 path_type=Path),
              help="Asteroid model (mesh or native .npz) to include (repeatable).")
@click.option("--reference-mesh", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Real body the --mesh inputs are compared with.")
@click.option("--reference-units", type=click.Choice(["m", "km"]), default=None,
              help="Units of the reference mesh (default: --units).")
@click.option("--hazards", "hazards", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Hazard map from `craterscape terrain hazards` to include "
                                 "(with its rocks against their model when made from a stack).")
@_gravity_options
@_tracker_options
@_edges_option
def report(run_dirs, output, thresholds, title, dems, band, reference, reference_band,
           slope_band, meshes, reference_mesh, reference_units, hazards, units, density, mass,
           period_hours, spin_axis, radius_deg, coarse_faces, no_gravity, tracker, outlier_px,
           compute_edges):
    """One self-contained HTML validation report (and its JSON) with pass/fail checks.

    Every RUN_DIR (rendered sequences, any number) gets a feature-tracking section; --dem and
    --mesh add DEM and asteroid sections.
    """
    from evaluation.report import (
        Report,
        asteroid_section,
        dem_section,
        load_thresholds,
        tracking_section,
        write_report,
    )
    from terrain.io import check_output_path

    if not run_dirs and not dems and not meshes and reference_mesh is None and hazards is None:
        raise InvalidParameterError("nothing to report: give a RUN_DIR, --dem, --mesh or "
                                    "--hazards")
    if reference is not None and not dems:
        raise InvalidParameterError("--reference compares --dem inputs; give at least one --dem")
    srcs = _with_stack_folders(
        [p for p in [*run_dirs, *dems, reference, *meshes, reference_mesh, thresholds,
                     hazards] if p])
    for run_dir in run_dirs:  # the report's JSON twin must never replace a run's own files
        srcs += [run_dir / "truth.json", run_dir / "manifest.json"]
    check_output_path(output, srcs, suffixes=(".html", ".htm"), what="HTML")
    check_output_path(output.with_suffix(".json"), srcs)
    limits = load_thresholds(thresholds)
    sections = []
    inputs: dict = {}
    keys = [Path(r).resolve().name or "run" for r in run_dirs]
    if len(set(keys)) < len(keys):  # lunar/run and asteroid/run: name them by their parents
        keys = [f"{Path(r).resolve().parent.name}/{k}" for r, k in zip(run_dirs, keys,
                                                                        strict=True)]
    keys = _unique(keys)
    for run_dir, key in zip(run_dirs, keys, strict=True):
        opx = limits["tracking"]["outlier_px"] if outlier_px is None else outlier_px
        run, scored = _run_tracking(run_dir, tracker, opx)
        sections.append(tracking_section(scored, run.image(len(run) - 1), limits,
                                         run_label=str(run_dir),
                                         key=key if len(run_dirs) > 1 else ""))
        if run.has_truth and len(run) > 1 and all(t.range for t in run.truth):
            from evaluation.consistency import consistency
            from evaluation.report import consistency_section

            sections.append(consistency_section(consistency(run), limits,
                                                run_label=str(run_dir),
                                                key=key if len(run_dirs) > 1 else ""))
    if len(run_dirs) == 1:
        inputs["run_dir"] = str(run_dirs[0])
    elif run_dirs:
        inputs["run_dirs"] = [str(r) for r in run_dirs]
    if dems:
        edges = "gdal" if compute_edges else "mask"
        dem_tiles = _dem_inputs(dems, band)
        from evaluation.evidence import dem_evidence

        evidence = dem_evidence(dem_tiles, reference=reference,
                                ref_tile=_reference(dem_tiles, reference, reference_band),
                                slope_band=slope_band, baseline=None, edges=edges)
        inputs["dems"] = [str(p) for p in dems]
        if reference is not None:
            inputs["reference_dem"] = str(reference)
        sections.append(dem_section(evidence.distributions, evidence.spectra, evidence.fits,
                                    evidence.comparisons, limits,
                                    slope_agreements=evidence.agreements))
    if meshes or reference_mesh is not None:
        common = dict(density=density, mass=mass, period_hours=period_hours,
                      spin_axis=spin_axis, radius_deg=radius_deg, coarse_faces=coarse_faces,
                      no_gravity=no_gravity)
        bodies = [_body_slopes(m, units=units, **common) for m in meshes]
        ref = None
        if reference_mesh is not None:
            ref = _body_slopes(reference_mesh, units=reference_units or units, **common)
            inputs["reference_mesh"] = str(reference_mesh)
        inputs["meshes"] = [str(m) for m in meshes]
        if no_gravity and limits["asteroid"]["slope_kind"] == "gravitational":
            limits["asteroid"]["slope_kind"] = "radial"
            log.warning("--no-gravity: the asteroid checks compare radial slopes")
        sections.append(asteroid_section(bodies, ref, limits))
    if hazards is not None:
        from evaluation.hazards import hazards_file_section

        sections.append(hazards_file_section(hazards))
        inputs["hazards"] = str(hazards)
    if thresholds is not None:
        inputs["thresholds"] = str(thresholds)
    rep = Report(title, sections, limits, inputs)
    from terrain.core.outputs import transaction

    with transaction():  # the HTML and its JSON twin as one set
        html_path, json_path = write_report(rep, output, inputs=srcs)
    failed = [c.name for c in rep.checks if c.passed is False]
    click.echo(f"wrote {html_path} and {json_path}: verdict {rep.verdict}"
               + (f" (failed: {', '.join(failed)})" if failed else ""), err=True)


@evaluation.command("thresholds")
def thresholds_cmd():
    """Print the default pass/fail thresholds as a TOML file to edit."""
    from evaluation.report import thresholds_toml

    click.echo(thresholds_toml(), nl=False)


@evaluation.command("validate")
@click.argument("dem_or_stack", type=click.Path(exists=True, path_type=Path))
@click.option("--terrain", required=True,
              type=click.Choice(["south-polar", "highlands", "maria"]),
              help="Terrain type whose published statistics the input is judged by.")
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              default=Path("validation.html"), show_default=True,
              help="HTML report; the JSON of every figure and check goes beside it.")
@click.option("--reference", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              default=None, help="A real DEM to compare with side by side.")
@click.option("--band", type=int, default=1, show_default=True, help="Height band of the DEM.")
def validate_cmd(dem_or_stack, terrain, output, reference, band):
    """Judge a DEM or layer stack by published lunar statistics (calibrated checks)."""
    from evaluation.validate_report import run_validation

    v, html_path, json_path = run_validation(dem_or_stack, terrain, output,
                                             reference=reference, band=band)
    fails = v.failures()
    click.echo(f"wrote {html_path} and {json_path}: verdict {v.verdict}"
               + "".join(f"\n  FAIL {r.name}: {r.meaning}" for r in fails), err=True)


@evaluation.command("binary-slopes")
@click.argument("scenario_file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (created if missing).")
@click.option("--time", "time_s", type=float, default=0.0, show_default=True,
              help="Seconds from the scenario's start (the bodies' poses).")
@click.option("--body", type=click.Choice(["primary", "secondary"]), default="primary",
              show_default=True, help="Whose surface.")
@click.option("--radius-deg", type=float, default=3.0, show_default=True,
              help="Cap radius of the per-vertex slope average (degrees).")
@click.option("--coarse-faces", type=int, default=None,
              help="Triangles of each coarsened body the gravity is computed from "
                   "(default 4000).")
def binary_slopes_cmd(scenario_file, output, time_s, body, radius_deg, coarse_faces):
    """Gravitational slopes of one body of a binary scenario (its tide, spin and orbit)."""
    from evaluation.meshslope import DEFAULT_COARSE_FACES, binary_slopes, load_body
    from render.scenario import load_scenario
    from terrain.core.outputs import check_output_folder, transaction

    scenario = load_scenario(scenario_file)
    spec = scenario.scene
    if spec.type != "binary":
        raise InvalidParameterError(f"binary-slopes needs a binary scenario ([scene] type = "
                                    f"\"binary\"); {scenario_file} is {spec.type}")
    assert spec.primary is not None and spec.secondary is not None  # a binary's, required
    paths = [scenario.resolve(spec.primary), scenario.resolve(spec.secondary)]
    shapes = [load_body(p) for p in paths]
    srcs = [scenario_file, *paths]
    check_output_folder(output, srcs)
    with progress_bar(f"gravity {body}") as update:
        s = binary_slopes((shapes[0].vertices, shapes[0].faces),
                          (shapes[1].vertices, shapes[1].faces), orbit=spec.orbit,
                          primary_spin=spec.primary_spin, secondary_spin=spec.secondary_spin,
                          t=time_s, which=body, radius_deg=radius_deg,
                          coarse_faces=coarse_faces or DEFAULT_COARSE_FACES, progress=update)
    with transaction():  # every file or none
        outdir = _outdir(output, srcs)
        rows = [[i, f"{s.vertex_area[i]:.6g}", f"{s.radial_deg[i]:.4f}",
                 f"{s.gravitational_deg[i]:.4f}"] + [f"{x:.6g}" for x in s.gravity[i]]
                for i in range(s.vertex_area.size)]
        write_csv(outdir / f"{body}_vertex_slopes.csv",
                  ["vertex", "area_m2", "radial_slope_deg", "gravitational_slope_deg",
                   "g_x_m_s2", "g_y_m_s2", "g_z_m_s2"], rows, srcs)
        _write_text(outdir / f"{body}_slopes.json", json.dumps(s.as_dict(), indent=1), srcs)
    g = s.summary("gravitational")
    click.echo(f"wrote {body} slopes at t = {time_s:g} s to {output}: gravitational median "
               f"{g['p50']:.1f} deg ({100 * g['area_fraction_below_35deg']:.1f} % of the area "
               "below 35)", err=True)
