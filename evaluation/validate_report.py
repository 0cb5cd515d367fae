"""The validation report: a :class:`evaluation.validate.Validation` as report sections.

The checks become :class:`evaluation.report.Check` records (their group as the section, the
source and what a failure means as the note; checks not applicable and the side-by-side
comparison never decide the verdict), and the figures are drawn with
:mod:`evaluation.figures`: the slope-vs-baseline curve over the terrain law and its band,
the structure functions of the Hurst fits, the per-layer slope distributions, and, where a
catalogue gives them, crater depth/diameter and N(>=D) against equilibrium.
"""

from __future__ import annotations

from evaluation import lunar_stats as ls
from evaluation.report import Check, Report, Section, figure_record, fmt, jsonable
from evaluation.validate import COMPARISON, TRACKER, Result, Validation

__all__ = ["as_check", "base_catalog_for", "validation_report", "validation_sections"]


def as_check(r: Result) -> Check:
    """Return a result as a report check (the source follows what it means).

    >>> from evaluation.validate import not_applicable, REALISM
    >>> as_check(not_applicable(REALISM, "rocks", "no rocks")).applicable
    False
    """
    note = r.meaning
    if r.source:
        note = f"{note} [source: {r.source}]" if note else f"[source: {r.source}]"
    return Check(r.group, r.name, r.value, r.limit, r.relation or "<=", r.unit, note,
                 applicable=r.status != "not applicable",
                 informational=r.group in (TRACKER, COMPARISON))


def _sources_table() -> tuple:
    rows = [[s.quantity, f"{fmt(s.value, 3)} +- {fmt(s.scatter, 2)} {s.unit}".strip(),
             fmt(s.threshold, 3), s.source, s.derivation,
             "yes" if s.calibrated else "no"] for s in ls.STATS]
    return ("Published statistics, thresholds and their derivation",
            ["quantity", "published value +- scatter", "threshold", "source",
             "how the threshold follows", "widened for real DEMs"], rows)


def validation_sections(v: Validation, *, key: str = "") -> list[Section]:
    """Return the report sections of one validation.

    Parameters
    ----------
    v : Validation
    key : str
        Distinguishes the sections of several validations in one report.

    Returns
    -------
    list of Section
        The checks and figures, then the sources of every threshold.
    """
    from evaluation.figures import (
        crater_sfd_figure,
        depth_diameter_figure,
        slope_baseline_figure,
        slope_distribution_figure,
        structure_function_figure,
    )

    law = ls.terrain_law(v.terrain)
    suffix = f"-{key}" if key else ""
    sec = Section(f"realism{suffix}", f"Terrain realism: {v.label} as {v.terrain} terrain")
    fails = v.failures()
    if fails:
        sec.paragraphs.append(
            f"{v.label} is not {v.terrain} lunar terrain: {len(fails)} check(s) failed. "
            + " ".join(f"{r.name}: {r.meaning}." for r in fails))
    else:
        sec.paragraphs.append(
            f"{v.label} keeps to every published statistic of {v.terrain} terrain that "
            "applies to it.")
    if "slope_table" in v.data:  # a layer stack: each baseline on the layer fit for it
        sec.paragraphs.append(
            f"The {v.terrain} law: {law.source}. Median bidirectional slope (absolute height "
            "difference over a baseline, as LOLA's slope maps use) at each baseline on the "
            "widest layer where it spans at least 4 pixels: within "
            f"{ls.SLOPE_LAW_DEG.threshold:g} deg of the law from 17 m to 1 km, and the RMS "
            "slope with the site's tilt removed at centimetres. The curve below pools every "
            "layer's baselines and is drawn, not judged.")
    else:
        sec.paragraphs.append(
            f"The {v.terrain} law: {law.source}. Median bidirectional slope (absolute height "
            "difference over a baseline, as LOLA's slope maps use) from every baseline the "
            f"input holds, against the law and a band of x/{ls.SLOPE_BAND_FACTOR.threshold:g}.")
    sec.checks = [as_check(r) for r in v.results]
    sec.tables.append(("Checks with their sources",
                       ["group", "check", "value", "threshold", "result", "source"],
                       [[r.group, r.name, fmt(r.value), f"{r.relation} {fmt(r.limit)}"
                         if r.limit is not None else "", r.status, r.source]
                        for r in v.results]))
    if "slope_table" in v.data:
        from evaluation.validate import preset_figures

        sec.tables.append((f"The figures a {v.terrain} terrain is judged by",
                           ["quantity", "value"],
                           [[q, fmt(x) if isinstance(x, float) else str(x)]
                            for q, x in preset_figures(v)]))
    if v.hurst:
        sec.tables.append(("Hurst exponents (median structure function, even lags)",
                           ["DEM", "H", "+-", "R^2", "fit range (m)", "H along x, y", "note"],
                           [[lb, fmt(h.hurst, 3), fmt(h.uncertainty, 2), fmt(h.r_squared, 3),
                             f"{h.band_m[0]:.3g} - {h.band_m[1]:.3g}",
                             ", ".join(f"{x:.2f}" for x in h.per_axis), h.note]
                            for lb, h in v.hurst]))
    sec.figures.append(figure_record(
        "slope_baseline", "Median slope against baseline",
        slope_baseline_figure(v.curves, law, ls.SLOPE_BAND_FACTOR.threshold),
        dict(curves=[c.as_dict() for c in v.curves], law=law.as_dict(),
             band_factor=ls.SLOPE_BAND_FACTOR.threshold),
        f"the {v.terrain} law (line) and its band (shaded); points: the input"))
    if v.hurst:
        sec.figures.append(figure_record(
            "structure", "Structure functions and Hurst fits",
            structure_function_figure(v.hurst),
            dict(hurst=[dict(label=lb, **h.as_dict()) for lb, h in v.hurst])))
    if v.distributions:
        sec.figures.append(figure_record(
            "distributions", "Slope distributions (per layer)",
            slope_distribution_figure(v.distributions),
            dict(distributions=[d.as_dict() for d in v.distributions])))
    if "depth_diameter" in v.data:
        dd = v.data["depth_diameter"]
        sec.figures.append(figure_record(
            "depth_diameter", "Crater depth against diameter (measured in the DEM)",
            depth_diameter_figure(dd["diameter_m"], dd["depth_m"]), dd))
    if "crater_sfd" in v.data:
        c = v.data["crater_sfd"]
        sec.figures.append(figure_record(
            "crater_sfd", "Crater N(>=D) against equilibrium",
            crater_sfd_figure(c["diameter_m"], c["n_per_m2"], c["equilibrium_per_m2"]), c))
    sec.data = jsonable(v.as_dict())
    sources = Section(f"sources{suffix}", "Sources and thresholds")
    sources.tables.append(_sources_table())
    sources.tables.append(("Terrain laws", ["terrain", "median slope at 17 m (deg)", "H",
                                            "self-affine to (m)", "H beyond", "source"],
                           [[t.name, fmt(t.slope_17m_deg), fmt(t.hurst), fmt(t.break_m),
                             fmt(t.hurst_large), t.source] for t in ls.TERRAINS.values()]))
    return [sec, sources]


def validation_report(v: Validation, *, inputs: dict | None = None) -> Report:
    """Return the whole validation report of one input.

    Parameters
    ----------
    v : Validation
    inputs : dict, optional
        What was validated (paths, terrain), shown at the top.

    Returns
    -------
    Report
    """
    return Report(f"craterscape validation: {v.label} ({v.terrain})",
                  validation_sections(v), {}, dict(inputs or {}))


#: Mean radius of the Moon (m), the sphere of LOLA's simple-cylindrical products.
MOON_RADIUS = 1_737_400.0
#: Half the side of the polar grid a global simple-cylindrical DEM is validated on (m).
POLAR_HALF_WIDTH_M = 600_000.0


def _is_global_cylindrical(tile) -> bool:
    """Whether a DEM is a simple-cylindrical map reaching a pole (non-square ground pixels)."""
    import math

    crs = (tile.crs or "").lower()
    if "equirectangular" not in crs and "cylindrical" not in crs:
        return False
    xmin, ymin, xmax, ymax = tile.bounds
    pole = MOON_RADIUS * math.pi / 2
    return min(abs(ymin + pole), abs(ymax - pole)) <= 2 * tile.resolution


def load_input(path, *, band: int = 1):
    """Read what ``craterscape evaluation validate`` takes: a DEM or a layer stack.

    A global simple-cylindrical DEM (LOLA's LDEM products) has pixels far from square near the
    poles, so it is validated around the south pole on a polar stereographic grid
    (:func:`terrain.io.reproject_polar`, 600 km either side).

    Parameters
    ----------
    path : path
        A DEM GDAL reads, a layer-stack folder or its ``manifest.json``.
    band : int
        The DEM's height band.

    Returns
    -------
    (label, tile or None, stack or None, note) : tuple
    """
    from pathlib import Path

    from terrain.io import read_dem, reproject_polar
    from terrain.stack.store import read_stack

    path = Path(path)
    if path.is_dir() or path.name == "manifest.json":
        folder = path if path.is_dir() else path.parent
        return folder.name, None, read_stack(folder), ""
    tile = read_dem(path, band=band)
    note = ""
    if _is_global_cylindrical(tile):
        tile = reproject_polar(tile, radius=MOON_RADIUS, half_width_m=POLAR_HALF_WIDTH_M)
        note = (f"global simple-cylindrical DEM: validated around the south pole, "
                f"reprojected onto a polar stereographic grid {2 * POLAR_HALF_WIDTH_M / 1000:g}"
                " km across")
    return path.stem, tile, None, note


def base_catalog_for(stack):
    """Return the crater catalogue of a stack's base, where it lies beside the base, or None.

    ``terrain synth --catalog`` writes it anywhere; a campaign writes ``NAME_craters.csv``
    beside the base ``NAME.tif``, and the stack's manifest names the base (``source``).

    Returns
    -------
    (CraterCatalog, path) or None
    """
    from pathlib import Path

    from terrain.craters.catalog import CraterCatalog

    source = (stack.info or {}).get("source")
    if not source:
        return None
    path = Path(source).with_name(f"{Path(source).stem}_craters.csv")
    return (CraterCatalog.from_csv(path), path) if path.is_file() else None


def run_validation(path, terrain: str, output, *, reference=None, band: int = 1,
                   reference_band: int = 1):
    """Validate a DEM or layer stack and write the HTML report and its JSON twin.

    Parameters
    ----------
    path : path
        The DEM or layer stack (:func:`load_input`).
    terrain : {"south-polar", "highlands", "maria"}
    output : path
        The HTML report; the JSON goes beside it.
    reference : path, optional
        A real DEM to compare with side by side.
    band, reference_band : int

    Returns
    -------
    (Validation, html_path, json_path)
    """
    from pathlib import Path

    from evaluation.report import write_report
    from evaluation.validate import compare_reference, validate_dem, validate_stack
    from terrain.core.outputs import transaction
    from terrain.io import check_output_path

    ls.terrain_law(terrain)  # refuse a bad name before any work
    srcs = [Path(path)] + ([Path(reference)] if reference else [])
    check_output_path(output, srcs, suffixes=(".html", ".htm"), what="HTML")
    check_output_path(Path(output).with_suffix(".json"), srcs)
    label, tile, stack, note = load_input(path, band=band)
    if stack is not None:
        found = base_catalog_for(stack)
        v = validate_stack(stack, terrain, label=label,
                           base_catalog=found[0] if found else None)
        finest = stack.tiles[-1]
        if found:
            note = f"{note}; " if note else ""
            note += f"the base's craters counted from {found[1]}"
    else:
        v = validate_dem(tile, terrain, label=label)
        finest = tile
    inputs = dict(input=str(path), terrain=terrain)
    if reference is not None:
        rlabel, rtile, rstack, _ = load_input(reference, band=reference_band)
        rtile = rtile if rtile is not None else rstack.tiles[-1]
        compare_reference(v, finest, rtile, rlabel)
        inputs["reference"] = str(reference)
    rep = validation_report(v, inputs=inputs)
    if note:
        rep.sections[0].notes.append(note)
    with transaction():
        html_path, json_path = write_report(rep, output, inputs=srcs)
    return v, html_path, json_path


#: Truth round trip through consecutive frames: the truth is exact to float32 range
#: precision, so anything above a tenth of a pixel is a broken truth, not a hard scene.
MAX_TRUTH_ROUND_TRIP_PX = 0.1
#: One step of tracking (median px): the tracking acceptance figure applied to one step,
#: where a tracker's drift has not accumulated and what is left is how frames change.
MAX_ONE_STEP_PX = 0.5


def regroup_campaign_checks(sections, facts: dict) -> None:
    """Sort a campaign report's checks into realism, renderer consistency and tracker groups.

    Tracking against truth over whole tracks measures the tracker's drift and outliers, not
    the renderer or the terrain: those checks become informational. Frame-to-frame
    consistency, the layers drawn against the GSD, the one-step tracking error and the
    truth round trip judge the renderer; the comparisons of single layers with real DEMs of
    other places, and of meshes at different facet counts, are side by side
    (informational), and realism is decided by :func:`evaluation.validate.validate_stack`'s
    checks and the facet-matched body checks. Sections are changed in place.

    Parameters
    ----------
    sections : list of evaluation.report.Section
    facts : dict
        The campaign's facts (``tracking_lunar`` and ``tracking_asteroid`` with
        ``one_step_median_px`` and ``truth_round_trip_px``).
    """
    from dataclasses import replace

    from evaluation.validate import COMPARISON, REALISM, RENDERER

    for sec in sections:
        out = []
        run = ""
        for c in sec.checks:
            where = c.section.split(" ")[0]
            if where == "tracking":
                run = c.section[len("tracking "):]
                c = replace(c, section=f"{TRACKER}: {c.section[len('tracking '):]}".rstrip(": "),
                            informational=True)
            elif where in ("consistency", "site"):
                c = replace(c, section=f"{RENDERER}: {c.section}")
            elif where == "dem" or (where == "asteroid" and c.name.startswith("KS distance")):
                # other places, or meshes of other facet counts: shown side by side
                c = replace(c, section=f"{COMPARISON}: {c.section}", informational=True)
            elif where == "asteroid":
                c = replace(c, section=f"{REALISM}: {c.section}")
            out.append(c)
        sec.checks = out
        if run:
            name = "lunar" if "lunar" in run else "asteroid" if "asteroid" in run else run
            f = facts.get(f"tracking_{name}", {})
            one, trip = f.get("one_step_median_px"), f.get("truth_round_trip_px")
            sec.checks.append(Check(f"{RENDERER}: {run}", "one-step tracking error (median)",
                                    one, MAX_ONE_STEP_PX, "<=", "px",
                                    "" if one is not None else "no truth"))
            sec.checks.append(Check(f"{RENDERER}: {run}",
                                    "truth round trip through consecutive frames (median)",
                                    trip, MAX_TRUTH_ROUND_TRIP_PX, "<=", "px",
                                    "" if trip is not None else "no truth"))
