r"""Validation reports a GNC team can file: one self-contained HTML page and a JSON twin.

A report gathers the evidence of :mod:`evaluation` into sections (feature tracking against
truth, DEM slopes and spectra, asteroid slopes), draws every figure (:mod:`evaluation.figures`)
and embeds it as a base64 PNG data URI, so the HTML file needs nothing else: no scripts, no
style sheets, no fonts or images from anywhere. Beside it, ``REPORT.json`` holds every figure's
data (the numbers plotted), every metric and every check, for machines and for archiving.

Checks and thresholds
---------------------
Each check compares one measured value with a threshold; the verdict is ``"fail"`` when any
check fails, ``"incomplete"`` when none fails but some could not be measured (a run without
truth, a DEM without a reference), and ``"pass"`` otherwise. Thresholds come from a TOML file
(``--thresholds``); every key is optional and the defaults are (``craterscape evaluation
thresholds`` prints them)::

    [tracking]
    max_median_error_px = 0.5          # median tracking error against truth (px)
    outlier_px = 2.0                   # an observation further than this is an outlier (px)
    max_outlier_fraction = 0.05        # of scored observations
    min_tracks_per_frame = 50.0        # mean live tracks per frame
    min_survival = 0.8                 # mean fraction of tracks kept from one frame to the next
    min_survival_at_layer_change = 0.8 # the same, across frames where the drawn layers change

    [dem]
    max_ks_distance = 0.3              # slope distributions vs the reference (matched baseline)
    max_spectrum_log10_ratio = 0.5     # median |log10(P / P_ref)| over the common band
    max_hurst_difference = 0.15        # |H - H_ref|
    max_shape_ks_distance = 0.2        # slopes over their median vs the reference's (shape)

    [asteroid]
    slope_kind = "gravitational"       # or "radial": which slopes the checks compare
    max_ks_distance = 0.2              # area-weighted slopes of each body vs the reference body
    steep_slope_deg = 35.0             # about the angle of repose of loose regolith
    max_area_fraction_steep = 0.05     # surface area steeper than steep_slope_deg

    [consistency]
    max_spike_ratio = 1.5              # largest per-frame residual rms over the median

The consistency bound asks for no spikes at layer or level-of-detail changes (see
:mod:`evaluation.consistency`). The tracking defaults are the acceptance figure for tracking
(median <= 0.5 px) and common practice for KLT front ends; 35 degrees is where lunar
slope-frequency distributions roll over (Kreslavsky and Head 2016) and below which nearly all
Eros slopes lie (Thomas et al. 2002); the DEM KS limit is what two real DEMs of the same
ground meet (:data:`evaluation.lunar_stats.KS_BETWEEN_REAL_DEMS`: the Malapert SfS and stereo
DEMs differ by 0.225); the spectrum limit is a starting point to tune per mission. Whether a
DEM is lunar at all is judged by :mod:`evaluation.validate`.
"""

from __future__ import annotations

import base64
import copy
import datetime as _dt
import html
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terrain.core.checks import check_keys, number, text
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import atomic_path
from terrain.core.tomlfile import read_toml

__all__ = ["DEFAULT_THRESHOLDS", "REPORT_FORMAT", "Check", "Figure", "Report", "Section",
           "asteroid_section", "consistency_section", "dem_section", "image_figure",
           "load_thresholds", "render_html", "thresholds_toml", "tracking_section",
           "write_report"]

log = logging.getLogger(__name__)

#: Identifier of the JSON report format.
REPORT_FORMAT = "craterscape-evaluation-report"
#: Thresholds used where the TOML file is silent (see the module docstring): table -> key ->
#: value, a float except ``asteroid.slope_kind`` (a str).
DEFAULT_THRESHOLDS: dict[str, dict[str, Any]] = {
    "tracking": {
        "max_median_error_px": 0.5,
        "outlier_px": 2.0,
        "max_outlier_fraction": 0.05,
        "min_tracks_per_frame": 50.0,
        "min_survival": 0.8,
        "min_survival_at_layer_change": 0.8,
    },
    "dem": {
        "max_ks_distance": 0.3,
        "max_spectrum_log10_ratio": 0.5,
        "max_hurst_difference": 0.15,
        # real DEMs of different places differ in shape by up to 0.14 (Aristarchus plateau
        # against its central peak at 26.5 m), of the same ground by 0.03-0.06
        # (docs/validation.md)
        "max_shape_ks_distance": 0.2,
    },
    "asteroid": {
        "slope_kind": "gravitational",
        "max_ks_distance": 0.2,
        "steep_slope_deg": 35.0,
        "max_area_fraction_steep": 0.05,
    },
    "consistency": {
        "max_spike_ratio": 1.5,
    },
}

_COMMENTS = {
    "max_median_error_px": "median tracking error against truth (px)",
    "outlier_px": "an observation further than this from truth is an outlier (px)",
    "max_outlier_fraction": "of scored observations",
    "min_tracks_per_frame": "mean live tracks per frame",
    "min_survival": "mean fraction of tracks kept from one frame to the next",
    "min_survival_at_layer_change": "the same, across frames where the drawn layers change",
    "max_ks_distance": "Kolmogorov-Smirnov distance of slope distributions vs the reference",
    "max_spectrum_log10_ratio": "median |log10(P / P_ref)| over the common band",
    "max_hurst_difference": "|H - H_ref|",
    "max_shape_ks_distance": "slopes over their median vs the reference's (shape)",
    "slope_kind": "'gravitational' or 'radial': the slopes the asteroid checks compare",
    "steep_slope_deg": "about the angle of repose of loose regolith (degrees)",
    "max_area_fraction_steep": "surface area steeper than steep_slope_deg",
    "max_spike_ratio": "largest per-frame consistency residual over the median",
}

#: Thresholds with a natural upper end: fractions and distances of distributions (1) and
#: slope angles (90 degrees).
_UPPER_BOUNDS = {
    "max_outlier_fraction": 1.0, "min_survival": 1.0, "min_survival_at_layer_change": 1.0,
    "max_ks_distance": 1.0, "max_area_fraction_steep": 1.0, "steep_slope_deg": 90.0,
}


def thresholds_toml(thresholds: dict | None = None) -> str:
    """Return the thresholds as a commented TOML document (defaults when none given).

    Parameters
    ----------
    thresholds : dict, optional
        Table -> key -> value, as :func:`load_thresholds` returns.

    Returns
    -------
    str
        One commented line per threshold, readable by :func:`load_thresholds`.

    Examples
    --------
    >>> import tomllib
    >>> text = thresholds_toml()
    >>> tomllib.loads(text) == DEFAULT_THRESHOLDS
    True
    """
    t = DEFAULT_THRESHOLDS if thresholds is None else thresholds
    lines = ["# craterscape evaluation thresholds (every key optional; these are the defaults)"]
    for section, values in t.items():
        lines.append("")
        lines.append(f"[{section}]")
        for key, value in values.items():
            text = json.dumps(value) if isinstance(value, str) else repr(float(value))
            lines.append(f"{key} = {text}  # {_COMMENTS.get(key, '')}".rstrip(" #"))
    return "\n".join(lines) + "\n"


def load_thresholds(path=None) -> dict:
    """Return the thresholds of a TOML file merged over :data:`DEFAULT_THRESHOLDS`.

    Unknown tables or keys, and values of the wrong type, are refused with the name of the
    offending key (a misspelt threshold must not silently fall back to its default).

    Parameters
    ----------
    path : path, optional
        The TOML file; None gives the defaults.

    Returns
    -------
    dict
        Table -> key -> value (floats; ``asteroid.slope_kind`` a str).

    Raises
    ------
    InvalidParameterError
        An unknown table or key, or a value of the wrong type or out of range.
    """
    out = copy.deepcopy(DEFAULT_THRESHOLDS)
    if path is None:
        return out
    data = read_toml(path, "thresholds file")
    where = f"thresholds file '{path}'"
    check_keys(data, out, where)
    for section, values in data.items():
        table = check_keys(values, out[section], f"{where} [{section}]")
        for key, value in table.items():
            if isinstance(out[section][key], str):
                out[section][key] = text(value, key, choices=("gravitational", "radial"),
                                         where=f"{where} [{section}]")
            else:
                out[section][key] = number(value, key, low=0, high=_UPPER_BOUNDS.get(key),
                                           where=f"{where} [{section}]")
    return out


# ------------------------------------------------------------------------------ values


@dataclass(frozen=True)
class Check:
    """One measured value against one threshold.

    ``passed`` is None when the value could not be measured (``note`` says why). A check
    that does not apply to the input (``applicable`` False: no catalogue, not a body) and an
    ``informational`` one (tracker performance) are shown but never decide the verdict.
    """

    section: str
    name: str
    value: float | None
    limit: float | None
    relation: str  # "<=" or ">="
    unit: str = ""
    note: str = ""
    applicable: bool = True
    informational: bool = False

    @property
    def passed(self) -> bool | None:
        """Whether the value keeps to the limit; None when it was not measured."""
        if (not self.applicable or self.value is None or self.limit is None
                or not math.isfinite(self.value)):
            return None
        return self.value <= self.limit if self.relation == "<=" else self.value >= self.limit

    @property
    def decides(self) -> bool:
        """Whether the check takes part in the verdict."""
        return self.applicable and not self.informational

    def as_dict(self) -> dict:
        """Return the check as plain data for the report's JSON (with ``passed``)."""
        return dict(section=self.section, name=self.name, value=self.value, limit=self.limit,
                    relation=self.relation, unit=self.unit, passed=self.passed,
                    note=self.note, applicable=self.applicable,
                    informational=self.informational)


@dataclass(frozen=True, eq=False)
class Figure:
    """A drawn figure: PNG bytes for the HTML, the plotted numbers for the JSON."""

    id: str
    title: str
    png: bytes
    data: dict
    caption: str = ""


@dataclass(eq=False)
class Section:
    """A part of the report: text, key figures (tables), figures and checks."""

    id: str
    title: str
    paragraphs: list = field(default_factory=list)
    tables: list = field(default_factory=list)  # (caption, header, rows)
    figures: list = field(default_factory=list)
    checks: list = field(default_factory=list)
    data: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    links: list = field(default_factory=list)  # (label, href): files beside the report

    def table(self, caption: str) -> list:
        """Return the rows of the table with this caption (a list to read or extend).

        Parameters
        ----------
        caption : str
            The table's caption, e.g. ``"Tracking"``.

        Returns
        -------
        list
            The table's rows, each a list of cells.

        Raises
        ------
        KeyError
            No table has that caption; the message names the captions there are.

        Examples
        --------
        >>> sec = Section("s", "S", tables=[("Tracking", ["measure", "value"], [])])
        >>> sec.table("Tracking").append(["tracks", "12"])
        >>> sec.tables[0][2]
        [['tracks', '12']]
        """
        for name, _, rows in self.tables:
            if name == caption:
                return rows
        raise KeyError(f"section {self.id!r} has no table {caption!r}; it has "
                       f"{[t[0] for t in self.tables]}")


@dataclass(eq=False)
class Report:
    """The whole report."""

    title: str
    sections: list
    thresholds: dict
    inputs: dict = field(default_factory=dict)
    created: str = ""

    @property
    def checks(self) -> list[Check]:
        """Every section's checks, in order."""
        return [c for s in self.sections for c in s.checks]

    @property
    def verdict(self) -> str:
        """The report's verdict: ``"fail"``, ``"incomplete"`` or ``"pass"``.

        ``"fail"`` if a check failed, else ``"incomplete"`` if one was not measured (or there
        are none), else ``"pass"``; checks not applicable and informational ones are left out.
        """
        results = [c.passed for c in self.checks if c.decides]
        if any(r is False for r in results):
            return "fail"
        if not results or any(r is None for r in results):
            return "incomplete"
        return "pass"

    def as_dict(self) -> dict:
        """Return the report as plain data: the document ``report.json`` holds."""
        from terrain.core.metakeys import version

        ver = version()
        return dict(
            format=REPORT_FORMAT, version=1, title=self.title, created=self.created,
            craterscape_version=ver, verdict=self.verdict, inputs=self.inputs,
            thresholds=self.thresholds, checks=[c.as_dict() for c in self.checks],
            sections=[dict(id=s.id, title=s.title, data=s.data, notes=s.notes,
                           links=[dict(label=lb, href=h) for lb, h in s.links],
                           tables=[dict(caption=c, header=h, rows=r) for c, h, r in s.tables])
                      for s in self.sections],
            figures=[dict(id=f.id, section=s.id, title=f.title, caption=f.caption,
                          data=f.data) for s in self.sections for f in s.figures])


def _keyed(sec: Section, key: str) -> Section:
    """``sec`` with its figure ids and its checks' section names made unique by ``key``."""
    if not key:
        return sec
    sec.figures = [Figure(f"{key}-{f.id}", f.title, f.png, f.data, f.caption)
                   for f in sec.figures]
    sec.checks = [Check(f"{c.section} {key}", c.name, c.value, c.limit, c.relation, c.unit,
                        c.note, c.applicable, c.informational) for c in sec.checks]
    return sec


def image_figure(fig_id, title, path, caption="") -> Figure:
    """Return a figure made of an existing PNG file (a frame, a hillshade), embedded as is.

    Parameters
    ----------
    fig_id, title : str
        The figure's anchor and heading.
    path : path
        The PNG; the figure's JSON data names it.
    caption : str

    Returns
    -------
    Figure
    """
    path = Path(path)
    return Figure(fig_id, title, path.read_bytes(), dict(file=str(path)), caption)


def figure_record(fig_id, title, fig, data, caption="") -> Figure:
    """Return a report figure: the drawing as PNG bytes and its numbers made JSON-safe.

    Parameters
    ----------
    fig_id, title : str
        The figure's anchor and heading.
    fig : matplotlib.figure.Figure or bytes
        The drawing (closed once rendered), or its PNG bytes already drawn.
    data : dict
        The plotted numbers, written to the report's JSON (:func:`jsonable`).
    caption : str

    Returns
    -------
    Figure
    """
    from evaluation.figures import as_png

    return Figure(fig_id, title, as_png(fig), jsonable(data), caption)


def jsonable(obj):
    """Return ``obj`` in plain JSON types.

    Parameters
    ----------
    obj : object
        Dicts, lists, tuples, NumPy arrays and scalars, nested.

    Returns
    -------
    object
        Dicts with str keys, lists, float, int, bool, str and None; NaN and infinities
        become None.

    Examples
    --------
    >>> jsonable({1: np.array([0.5, np.nan]), "n": np.int64(3)})
    {'1': [0.5, None], 'n': 3}
    """
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        plain = _plain_floats(obj)
        return plain if plain is not None else [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _array_jsonable(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


#: Types :func:`jsonable` returns unchanged (a float only when finite).
_JSON_ATOMS = frozenset({float, int, bool, str, type(None)})


def _plain_floats(items) -> list | None:
    """Return ``items`` as a new list when :func:`jsonable` would keep every one, else None."""
    for v in items:
        t = type(v)
        if t not in _JSON_ATOMS or (t is float and not math.isfinite(v)):
            return None
    return list(items)


def _array_jsonable(a: np.ndarray):
    """Return an array as :func:`jsonable` does, converting it at once where it can."""
    if a.dtype.kind in "iub":  # integers and booleans: tolist gives Python int and bool
        return a.tolist()
    if a.dtype.kind == "f":
        finite = np.isfinite(a)
        if bool(finite.all()):
            return a.tolist()  # Python floats, none of them NaN or infinite
        # an object array holds Python floats; the NaN and infinities become None in place
        plain = a.astype(object)
        plain[~finite] = None
        return plain.tolist()
    return jsonable(a.tolist())


def fmt(value, digits=4) -> str:
    """Return a number as report text.

    Parameters
    ----------
    value : number, bool or None
    digits : int
        Significant digits of a float.

    Returns
    -------
    str
        Integers with thousands separators, floats to ``digits`` significant digits,
        ``"n/a"`` for None and non-finite values.

    Examples
    --------
    >>> fmt(1234567), fmt(0.123456), fmt(float("nan"))
    ('1,234,567', '0.1235', 'n/a')
    """
    if value is None:
        return "n/a"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return f"{int(value):,}"
    v = float(value)
    if not math.isfinite(v):
        return "n/a"
    return f"{v:.{digits}g}"


# ---------------------------------------------------------------------------- sections


def tracking_section(scored, last_image, thresholds: dict | None = None, *,
                     run_label: str = "", key: str = "", drawn: dict | None = None) -> Section:
    """Feature tracking against truth: tracks over the last frame, errors, survival.

    Parameters
    ----------
    scored : evaluation.tracking.ScoredTracks
    last_image : array
        The sequence's last frame (for the Fig. 15 overlay).
    thresholds : dict, optional
        :func:`load_thresholds` output.
    run_label : str
        How the text names the run.
    key : str
        Distinguishes this section from other tracking sections of the same report (its id,
        figure ids and the section named by its checks); empty for a report of one run.
    drawn : dict, optional
        Figures already drawn by :func:`evaluation.tracking.save_tracks` for the same tracks
        and frame (:func:`evaluation.figures.drawn_once`): used, not drawn again.
    """
    from evaluation.figures import drawn_once, error_figure, tracks_figure

    t = (thresholds or DEFAULT_THRESHOLDS)["tracking"]
    summary = scored.summary()
    tr = summary["tracking"]
    err = summary["errors"]
    sec = Section("tracking", "Feature tracking against truth")
    if key:
        sec.id, sec.title = f"tracking-{key}", f"Feature tracking against truth: {key}"
    warp = (" (from each previous frame warped by the step's homography)"
            if tr["settings"].get("prewarp") else "")
    sec.paragraphs.append(
        f"Harris corners tracked with pyramidal Lucas-Kanade{warp}, forward-backward checked "
        f"and replenished, through {tr['frames']} frames of {run_label or 'the run'}. Each "
        "feature is lifted to 3-D with the range image and pose of its first frame and "
        "projected into every later frame with that frame's truth; the error is the distance "
        "between the tracked and the true position.")
    sec.notes.extend(summary["notes"])
    rows = [["tracks", fmt(tr["tracks"])],
            ["live tracks per frame (mean / min)",
             f"{fmt(tr['tracks_per_frame_mean'])} / {fmt(tr['tracks_per_frame_min'])}"],
            ["track length, frames (mean / median / max)",
             f"{fmt(tr['track_length_mean'])} / {fmt(tr['track_length_median'])} / "
             f"{fmt(tr['track_length_max'])}"],
            ["tracks spanning the whole sequence", fmt(tr["tracks_spanning_sequence"])],
            ["survival per step (ordinary)", fmt(tr["survival_mean"])],
            [f"survival across layer changes ({tr['layer_changes']})",
             fmt(tr["survival_at_layer_change"])]]
    if err is not None:
        rows += [["scored observations", fmt(err["observations"])],
                 ["error median / mean / p95 / max (px)",
                  f"{fmt(err['median_px'])} / {fmt(err['mean_px'])} / "
                  f"{fmt(err.get('p95_px'))} / {fmt(err['max_px'])}"],
                 [f"outlier fraction (> {err['outlier_px']:g} px)",
                  fmt(err["outlier_fraction"])]]
        one = err.get("one_step")
        if one is not None:
            rows += [["one-step error median / mean / p90 (px)",
                      f"{fmt(one['median_px'])} / {fmt(one['mean_px'])} / "
                      f"{fmt(one['p90_px'])}"]]
        rows += [["not scored: hidden / outside / unliftable tracks",
                  f"{err['hidden']} / {err['outside']} / {err['unlifted_tracks']}"]]
        surface = err.get("surface_tracks")
        if surface is not None:
            rows += [[f"tracks starting on a silhouette (of {tr['tracks']})",
                      fmt(err["silhouette_tracks"])],
                     ["without them: error median (px) / outlier fraction",
                      f"{fmt(surface['median_px'])} / {fmt(surface['outlier_fraction'])}"]]
    sec.tables.append(("Tracking", ["measure", "value"], rows))
    sec.data = jsonable(summary)
    tracks = scored.tracks
    sec.figures.append(figure_record(
        "tracks", "Tracks over the last frame",
        drawn_once(drawn, "tracks", lambda: tracks_figure(last_image, scored)),
        dict(positions=tracks.positions, start=tracks.start, stop=tracks.stop,
             final_error_px=(scored.errors[:, -1] if scored.errors is not None else None)),
        "Each line is one feature's track; the paper's Fig. 15."))
    no_truth = "no truth: tracking errors not measured"
    median = err["median_px"] if err else None
    outliers = err["outlier_fraction"] if err else None
    sec.checks += [
        Check("tracking", "median tracking error", median, t["max_median_error_px"], "<=",
              "px", "" if err else no_truth),
        Check("tracking", f"outlier fraction (> {t['outlier_px']:g} px)", outliers,
              t["max_outlier_fraction"], "<=", "", "" if err else no_truth),
        Check("tracking", "mean live tracks per frame", tr["tracks_per_frame_mean"],
              t["min_tracks_per_frame"], ">="),
        Check("tracking", "survival per step", tr["survival_mean"], t["min_survival"], ">=",
              "", "" if tr["survival_mean"] is not None else "fewer than two frames"),
    ]
    if tr["layer_changes"]:
        sec.checks.append(Check("tracking", "survival across layer changes",
                                tr["survival_at_layer_change"],
                                t["min_survival_at_layer_change"], ">="))
    if err is not None and err["observations"]:
        sec.figures.append(figure_record(
            "tracking_error", "Tracking error",
            drawn_once(drawn, "tracking_error", lambda: error_figure(scored)),
            dict(errors_px=scored.error_values(),
                 median_px_by_track_age=err["median_px_by_track_age"],
                 one_step_median_px_by_track_age=err.get("one_step_median_px_by_track_age")),
            "Left: every scored observation; right: median error against track age, "
            "accumulated (what a track delivers) and one-step (what each step of tracking "
            "adds)."))
    return _keyed(sec, key)


def consistency_section(result, thresholds: dict | None = None, *, run_label: str = "",
                        key: str = "", drawn: dict | None = None) -> Section:
    """Frame-to-frame consistency of a run (:mod:`evaluation.consistency`).

    Parameters
    ----------
    result : evaluation.consistency.Consistency
    thresholds : dict, optional
        :func:`load_thresholds` output.
    run_label : str
        How the text names the run.
    key : str
        Distinguishes this section from other consistency sections of the same report.
    drawn : dict, optional
        Figures already drawn by :func:`evaluation.consistency.save_consistency` for the
        same result (:func:`evaluation.figures.drawn_once`): used, not drawn again.
    """
    from evaluation.figures import consistency_figure, drawn_once

    t = (thresholds or DEFAULT_THRESHOLDS)["consistency"]
    s = result.summary()
    sec = Section("consistency", "Frame-to-frame consistency")
    if key:
        sec.id, sec.title = f"consistency-{key}", f"Frame-to-frame consistency: {key}"
    sec.paragraphs.append(
        f"Each frame of {run_label or 'the run'} warped into the previous one through the "
        "truth (range, pose and body rotation), and the photometric residual measured on the "
        "pixels seen and lit in both (occlusions, silhouettes and shadow edges that move are "
        "masked). A renderer whose levels of detail or layers switch between frames shows a "
        "spike at the switch; the sensor's own noise sets the floor.")
    sec.notes.extend(result.notes)
    rows = [["frame pairs", fmt(s["pairs"])],
            ["residual rms, median / largest (DN)",
             f"{fmt(s['rms_dn_median'])} / {fmt(s['rms_dn_max'])}"],
            ["largest over median", fmt(s["spike_ratio"])],
            ["sensor noise of a pair, median (DN)", fmt(s["noise_floor_dn_median"])],
            ["residual beyond the noise, median / largest (DN)",
             f"{fmt(s['excess_dn_median'])} / {fmt(s['excess_dn_max'])}"],
            ["worst 32 px tile, median / largest (DN)",
             f"{fmt(s['worst_tile_dn_median'])} / {fmt(s['worst_tile_dn_max'])}"],
            [f"median at layer or level changes ({s['lod_changes']}) / elsewhere (DN)",
             f"{fmt(s['rms_dn_median_at_changes'])} / {fmt(s['rms_dn_median_elsewhere'])}"],
            ["pixels counted (median fraction)", fmt(s["counted_fraction_median"])]]
    sec.tables.append(("Consistency", ["measure", "value"], rows))
    sec.data = jsonable(result.as_dict())
    sec.figures.append(figure_record(
        "consistency", "Consistency residual per frame",
        drawn_once(drawn, "consistency", lambda: consistency_figure(result)),
        dict(frames=result.frames),
        "Residual rms of each frame warped into the previous one, with the sensor noise of a "
        "pair; orange lines: the drawn layers change, green: levels of detail change."))
    sec.checks.append(Check("consistency", "largest per-frame residual over the median",
                            s["spike_ratio"], t["max_spike_ratio"], "<=", "",
                            "" if s["spike_ratio"] is not None else "nothing counted"))
    return _keyed(sec, key)


def dem_section(distributions, spectra=(), fits=(), comparisons=(), thresholds=None, *,
                slope_agreements=(), key: str = "") -> Section:
    """DEM slopes (Fig. 11-13), power spectra (Fig. 14) and comparisons with a reference.

    Parameters
    ----------
    distributions : sequence of SlopeDistribution
    spectra : sequence of RadialSpectrum
    fits : sequence of HurstFit or None (one per spectrum)
    comparisons : sequence of Comparison
    slope_agreements : sequence of (label, SlopeMapAgreement)
        Pixel-by-pixel checks against independent slope maps.
    key : str
        Distinguishes this section from other DEM sections of the same report.
    """
    from evaluation.figures import slope_distribution_figure, spectrum_figure

    t = (thresholds or DEFAULT_THRESHOLDS)["dem"]
    sec = Section("dem", "DEM slopes and power spectra")
    if key:
        sec.id, sec.title = f"dem-{key}", f"DEM slopes and power spectra: {key}"
    sec.paragraphs.append(
        "Horn slopes computed as gdaldem computes them; distributions give the percentage of "
        "terrain steeper than each angle (Martin et al. 2014, Fig. 11). DEMs of different "
        "resolution are compared at the coarser one's pixel spacing.")
    rows = [[d.label, fmt(d.resolution_m), fmt(d.pixels)]
            + [fmt(d.quantiles[k]) for k in ("p50", "p90", "p99", "mean", "max")]
            for d in distributions]
    sec.tables.append(("Slope quantiles (degrees)",
                       ["DEM", "pixel (m)", "slopes", "median", "p90", "p99", "mean", "max"],
                       rows))
    if distributions:
        sec.figures.append(figure_record(
            "slope_distributions", "Cumulative slope-frequency distributions",
            slope_distribution_figure(distributions),
            dict(distributions=[d.as_dict() for d in distributions])))
    if spectra:
        fits = list(fits) if fits else [None] * len(spectra)
        sec.figures.append(figure_record(
            "spectra", "Radially averaged power spectra", spectrum_figure(spectra, fits),
            dict(spectra=[s.as_dict() for s in spectra],
                 fits=[f.as_dict() if f else None for f in fits])))
        sec.tables.append(("Hurst exponents", ["DEM", "H", "beta", "band (cycles/m)", "R^2"],
                           [[s.label, fmt(f.hurst, 3), fmt(f.beta, 3),
                             f"{f.f_low:.3g} - {f.f_high:.3g}", fmt(f.r_squared, 3)]
                            if f else [s.label, "n/a", "n/a", "n/a", "n/a"]
                            for s, f in zip(spectra, fits, strict=True)]))
    for c in comparisons:
        q, rq = c.distribution.quantiles, c.reference_distribution.quantiles
        sec.tables.append((
            f"{c.label} against {c.reference_label} at {c.resolution_m:.4g} m",
            ["measure", c.label, c.reference_label],
            [["median slope (deg)", fmt(q["p50"]), fmt(rq["p50"])],
             ["p90 slope (deg)", fmt(q["p90"]), fmt(rq["p90"])],
             ["p90 / median slope (shape)", fmt(q["p90"] / q["p50"]) if q["p50"] > 0 else "",
              fmt(rq["p90"] / rq["p50"]) if rq["p50"] > 0 else ""],
             ["median slope ratio (amplitude)", fmt(c.amplitude_ratio), ""],
             ["Hurst exponent", fmt(c.hurst, 3), fmt(c.reference_hurst, 3)],
             ["KS distance", fmt(c.ks_distance), ""],
             ["KS distance of slopes over their median (shape)", fmt(c.shape_ks_distance), ""],
             ["spectrum median |log10 ratio|", fmt(c.log10_ratio_median), ""]]))
        pair = f"{c.label} vs {c.reference_label}"
        if c.shape_only:
            # another place: its roughness is its own, so the amplitude (which the plain KS
            # distance and the spectra's ratio carry) is reported, not judged
            sec.notes.append(
                f"{c.reference_label} is another place: {c.label} is judged against it by the "
                "shape of its slope distribution and its Hurst exponent; the amplitude (median "
                f"slope ratio {fmt(c.amplitude_ratio)}, KS distance {fmt(c.ks_distance)}, "
                f"spectrum median |log10 ratio| {fmt(c.log10_ratio_median)}) is shown, not "
                "judged")
            sec.checks.append(Check("dem", f"KS distance of slopes over their median (shape) "
                                    f"{pair}", c.shape_ks_distance, t["max_shape_ks_distance"],
                                    "<=", "", "" if c.shape_ks_distance is not None
                                    else "a median slope of 0"))
        else:
            sec.checks.append(Check("dem", f"KS distance {pair}", c.ks_distance,
                                    t["max_ks_distance"], "<="))
            sec.checks.append(Check(
                "dem", f"spectrum median |log10 ratio| {pair}", c.log10_ratio_median,
                t["max_spectrum_log10_ratio"], "<=", "",
                "" if c.log10_ratio_median is not None else "no common spectral band"))
        dh = (abs(c.hurst - c.reference_hurst)
              if c.hurst is not None and c.reference_hurst is not None else None)
        sec.checks.append(Check("dem", f"Hurst difference {pair}",
                                dh, t["max_hurst_difference"], "<=", "",
                                "" if dh is not None else "DEM too small for a Hurst fit"))
    if comparisons:
        sec.figures.append(figure_record(
            "comparison_distributions", "Slope distributions at matched baselines",
            slope_distribution_figure([d for c in comparisons
                                       for d in (c.distribution, c.reference_distribution)]),
            dict(comparisons=[c.as_dict() for c in comparisons])))
    if slope_agreements:
        sec.tables.append((
            "Agreement with independent slope maps (degrees)",
            ["map", "pixels", "bias", "median |diff|", "p99 |diff|", "max |diff|",
             "correlation"],
            [[label, fmt(a.pixels), fmt(a.bias_deg), fmt(a.median_abs_deg),
              fmt(a.p99_abs_deg), fmt(a.max_abs_deg), fmt(a.correlation, 6)]
             for label, a in slope_agreements]))
    if not comparisons and distributions:
        sec.notes.append("no reference DEM given: the DEM checks were not run")
        sec.checks.append(Check("dem", "slope distributions vs a reference", None,
                                t["max_ks_distance"], "<=", "", "no reference DEM given"))
    sec.data = jsonable(dict(
        distributions=[d.as_dict() for d in distributions],
        comparisons=[c.as_dict() for c in comparisons],
        slope_agreements=[dict(label=label, **a.as_dict()) for label, a in slope_agreements]))
    return _keyed(sec, key)


def asteroid_section(bodies, reference=None, thresholds=None) -> Section:
    """Slope-area histograms of asteroid models (the asteroid paper's Fig. 9).

    Parameters
    ----------
    bodies : sequence of MeshSlopes
        Synthetic (or any) bodies.
    reference : MeshSlopes, optional
        The real body the others are compared with (for example Gaskell's Eros).
    """
    from evaluation.compare import ks_distance
    from evaluation.figures import slope_area_figure

    t = (thresholds or DEFAULT_THRESHOLDS)["asteroid"]
    kind = t["slope_kind"]
    everyone = ([reference] if reference is not None else []) + list(bodies)
    sec = Section("asteroid", "Asteroid slopes")
    sec.paragraphs.append(
        "Per-vertex slopes averaged over every vertex's 3 degree cap, collated by area into 3 "
        "degree bins (Martin et al., asteroid paper, Fig. 9). Radial slopes take the direction "
        "from the centre as up; gravitational slopes take the local effective gravity "
        "(constant-density polyhedron gravity, Werner and Scheeres 1997, plus the spin's "
        f"centrifugal term). Checks compare {kind} slopes.")
    rows = []
    for b in everyone:
        rad = b.summary("radial")
        grav = b.summary("gravitational") if b.gravitational_deg is not None else None
        rows.append([b.label + (" (reference)" if b is reference else ""),
                     fmt(b.info.get("vertices")), fmt(rad["p50"]),
                     fmt(grav["p50"]) if grav else "n/a",
                     fmt(grav["area_fraction_below_35deg"]) if grav else "n/a",
                     fmt(b.info.get("density_kg_m3")), fmt(b.info.get("spin_period_h"))])
    sec.tables.append(("Slope medians (area-weighted, degrees)",
                       ["body", "vertices", "radial median", "gravitational median",
                        "area below 35 deg (grav.)", "density (kg/m^3)", "spin period (h)"],
                       rows))
    histograms = []
    for b in everyone:
        for k in ("radial", "gravitational"):
            if k == "gravitational" and b.gravitational_deg is None:
                continue
            histograms.append(b.histogram(k))
    chosen = [h for h in histograms if h.kind == kind] or histograms
    sec.figures.append(figure_record(
        "slope_area", f"Slope-area histograms ({kind} slopes)", slope_area_figure(chosen),
        dict(histograms=[h.as_dict() for h in chosen])))
    other = [h for h in histograms if h not in chosen]
    if other:
        sec.figures.append(figure_record(
            "slope_area_other", f"Slope-area histograms ({other[0].kind} slopes)",
            slope_area_figure(other), dict(histograms=[h.as_dict() for h in other])))
    for b in everyone:
        try:
            values = b.slopes(kind)
        except InvalidParameterError:
            sec.checks.append(Check("asteroid", f"{b.label}: area steeper than "
                                    f"{t['steep_slope_deg']:g} deg", None,
                                    t["max_area_fraction_steep"], "<=", "",
                                    f"{kind} slopes not computed"))
            continue
        ok = np.isfinite(values)
        steep = float(b.vertex_area[ok][values[ok] > t["steep_slope_deg"]].sum()
                      / b.vertex_area[ok].sum())
        sec.checks.append(Check("asteroid", f"{b.label}: area steeper than "
                                f"{t['steep_slope_deg']:g} deg ({kind})", steep,
                                t["max_area_fraction_steep"], "<="))
    if reference is not None:
        for b in bodies:
            try:
                d = ks_distance(b.slopes(kind), reference.slopes(kind),
                                weights_a=b.vertex_area, weights_b=reference.vertex_area)
                note = ""
            except InvalidParameterError as exc:
                d, note = None, str(exc)
            sec.checks.append(Check("asteroid", f"KS distance {b.label} vs {reference.label} "
                                    f"({kind})", d, t["max_ks_distance"], "<=", "", note))
    sec.data = jsonable(dict(bodies=[b.as_dict() for b in everyone],
                              reference=reference.label if reference is not None else None))
    return sec


# ------------------------------------------------------------------------------ output


_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:2em auto;
max-width:60em;color:#222;line-height:1.45;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;
margin-top:2em}table{border-collapse:collapse;margin:1em 0;font-size:.92em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}th{background:#f3f3f3}
caption{text-align:left;font-weight:600;padding:.3em 0}
.pass{color:#fff;background:#2e7d32}.fail{color:#fff;background:#c62828}
.incomplete,.na{color:#222;background:#ffe082}.verdict{display:inline-block;padding:.2em .8em;
border-radius:.3em;font-weight:700;text-transform:uppercase}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}
figure.thumb{display:inline-block;width:31%;margin:.4em .6em .4em 0;vertical-align:top}
figcaption{font-size:.9em;color:#555}.note{background:#fff8e1;border-left:4px solid #ffb300;
padding:.4em .8em;margin:.5em 0}.meta{color:#555;font-size:.9em}pre{background:#f6f6f6;
padding:.6em;overflow-x:auto;font-size:.85em}
"""


def _table(caption, header, rows) -> str:
    e = html.escape
    head = "".join(f"<th>{e(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table><caption>{e(caption)}</caption><tr>{head}</tr>{body}</table>"


def render_html(report: Report) -> str:
    """Return the report as one self-contained HTML document (figures as data URIs).

    Parameters
    ----------
    report : Report

    Returns
    -------
    str
    """
    e = html.escape
    verdict = report.verdict
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<title>{e(report.title)}</title><style>{_CSS}</style></head><body>",
             f"<h1>{e(report.title)}</h1>",
             f'<p class="meta">Created {e(report.created)} by craterscape. Verdict: '
             f'<span class="verdict {verdict}">{verdict}</span></p>']
    if report.inputs:
        parts.append(_table("Inputs", ["input", "value"],
                            [[k, json.dumps(v) if not isinstance(v, str) else v]
                             for k, v in report.inputs.items()]))
    rows = []
    for c in report.checks:
        state = {True: "pass", False: "fail", None: "not measured"}[c.passed]
        if not c.applicable:
            state = "not applicable"
        elif c.informational and c.passed is not None:
            state += " (informational)"
        rows.append((c, state))
    if rows:
        head = "".join(f"<th>{h}</th>" for h in ("section", "check", "value", "threshold",
                                                  "result", "note"))
        body = []
        for c, state in rows:
            cls = {"pass": "pass", "fail": "fail"}.get(state, "na")
            if c.informational and c.applicable:
                cls = "na"
            limit = e(fmt(c.limit)) if c.limit is not None else ""
            body.append(
                f"<tr><td>{e(c.section)}</td><td>{e(c.name)}</td><td>{e(fmt(c.value))}"
                f"{(' ' + e(c.unit)) if c.unit else ''}</td><td>{e(c.relation)} "
                f"{limit}</td><td class=\"{cls}\">{e(state)}</td>"
                f"<td>{e(c.note)}</td></tr>")
        parts.append(f"<table><caption>Checks</caption><tr>{head}</tr>{''.join(body)}"
                     "</table>")
    for s in report.sections:
        parts.append(f'<h2 id="{e(s.id)}">{e(s.title)}</h2>')
        parts += [f"<p>{e(p)}</p>" for p in s.paragraphs]
        parts += [f'<p class="note">{e(n)}</p>' for n in s.notes]
        parts += [_table(*t) for t in s.tables]
        if s.links:
            parts.append("<ul>" + "".join(f'<li><a href="{e(href)}">{e(label)}</a></li>'
                                          for label, href in s.links) + "</ul>")
        for f in s.figures:
            uri = "data:image/png;base64," + base64.b64encode(f.png).decode("ascii")
            cap = e(f.title + (": " + f.caption if f.caption else ""))
            thumb = ' class="thumb"' if "file" in f.data else ""  # pictures, not plots
            parts.append(f'<figure id="fig-{e(f.id)}"{thumb}><img alt="{e(f.title)}" '
                         f'src="{uri}">'
                         f"<figcaption>{cap}</figcaption></figure>")
    if report.thresholds:
        parts.append("<h2>Thresholds</h2><pre>" + e(thresholds_toml(report.thresholds))
                     + "</pre>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(report: Report, path, *, inputs=()) -> tuple[Path, Path]:
    """Write ``path`` (HTML) and the JSON twin beside it (same name, ``.json``), atomically.

    Parameters
    ----------
    report : Report
        Its ``created`` time is set now if empty.
    path : path
        The HTML file (not ending in ``.json``).
    inputs : iterable of path
        Files the report was made from (never written over).

    Returns
    -------
    (html_path, json_path) : Path
    """
    path = Path(path)
    json_path = path.with_suffix(".json")
    if json_path == path:
        raise InvalidParameterError(f"report '{path}' must not end in .json; name it .html")
    if not report.created:
        report.created = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    text = render_html(report)
    doc = json.dumps(jsonable(report.as_dict()), allow_nan=False)
    with atomic_path(json_path, inputs) as tmp:
        tmp.write_text(doc, encoding="utf-8")
    with atomic_path(path, inputs) as tmp:
        tmp.write_text(text, encoding="utf-8")
    log.info("wrote %s and %s (verdict %s)", path, json_path, report.verdict)
    return path, json_path
