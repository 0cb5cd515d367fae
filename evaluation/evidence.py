"""A DEM's evidence: slope distributions, power spectra, Hurst fits and comparisons.

:func:`dem_evidence` measures labelled DEMs (files or the layers of a stack) once and
returns one frozen :class:`DEMEvidence`; ``craterscape evaluation slopes``, ``evaluation
report`` and the campaign (:mod:`evaluation.campaign_report`) all use it, and its CSV
writers (:func:`write_evidence_csvs`) are the ``slopes`` command's tables.
"""

from __future__ import annotations

import csv
import io
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from terrain.core import metakeys as mk
from terrain.core.errors import InvalidDEMError, InvalidParameterError

__all__ = ["STACK_LAYER", "DEMEvidence", "at_baseline", "dem_evidence", "write_csv",
           "write_evidence_csvs"]

log = logging.getLogger(__name__)

#: Metadata key marking a tile as a layer of a stack (its index).
STACK_LAYER = mk.STACK_LAYER
#: Slope quantiles written per DEM in ``slope_summary.csv``.
SUMMARY_KEYS = ("p10", "p25", "p50", "p75", "p90", "p95", "p99", "mean", "max")


@dataclass(frozen=True)
class DEMEvidence:
    """What the evaluation measured of a set of DEMs.

    Attributes
    ----------
    distributions : tuple of evaluation.slope.SlopeDistribution
        One per DEM, then the reference's (where there is one).
    spectra : tuple of evaluation.spectrum.RadialSpectrum
        One per DEM large enough for a spectrum.
    fits : tuple of evaluation.spectrum.HurstFit or None
        One per spectrum (None where no power law could be fitted).
    comparisons : tuple of evaluation.compare.Comparison
        Each DEM against the reference (where there is one).
    agreements : tuple of (str, evaluation.compare.SlopeMapAgreement)
        The Horn slope against an independent slope band, per DEM.
    """

    distributions: tuple = ()
    spectra: tuple = ()
    fits: tuple = ()
    comparisons: tuple = ()
    agreements: tuple = ()


def at_baseline(tile, baseline: float | None, label: str):
    """Return the tile averaged onto ``baseline`` metres per pixel where it is finer; else itself.

    Parameters
    ----------
    tile : DEMTile
        The DEM.
    baseline : float or None
        Pixel spacing to measure at (m); None keeps the tile's own.
    label : str
        The DEM's name, for the warning given when it is coarser than ``baseline``.

    Returns
    -------
    DEMTile
        The tile to measure.
    """
    from evaluation.slope import resample

    if baseline is None or baseline <= tile.resolution * (1 + 1e-9):
        if baseline is not None and baseline < tile.resolution * (1 - 1e-9):
            log.warning("%s is coarser (%.6g m) than --baseline %.6g m; kept at its own "
                        "resolution", label, tile.resolution, baseline)
        return tile
    return resample(tile, baseline)


def dem_evidence(dems: Sequence, *, reference: str | None = None, ref_tile=None,
                 slope_band: int | None = None, baseline: float | None = None,
                 edges: str = "mask") -> DEMEvidence:
    """Slope distributions, spectra, fits, comparisons and slope-map checks of DEMs.

    Parameters
    ----------
    dems : sequence of (str, DEMTile)
        Labelled DEMs; layers of a stack carry ``STACK_LAYER`` in their metadata.
    reference : str, optional
        The reference's name (its file's stem labels the comparisons).
    ref_tile : DEMTile, optional
        The reference DEM every input is compared with.
    slope_band : int, optional
        Band of each input's file holding an independent slope map (degrees).
    baseline : float, optional
        Measure the distributions and spectra at this pixel spacing (m).
    edges : {"mask", "gdal"}
        Edge handling of the Horn slope (:func:`evaluation.slope.horn`).

    Returns
    -------
    DEMEvidence
        The record.
    """
    from evaluation.compare import compare_dems, compare_slope_maps
    from evaluation.memo import radial_spectrum_of, slope_distribution_of
    from evaluation.slope import horn_slope, slope_distribution
    from evaluation.spectrum import fit_hurst
    from terrain.io import read_dem

    distributions: list = []
    spectra: list = []
    fits: list = []  # HurstFit, or None where no exponent could be fitted
    comparisons: list = []
    agreements: list = []
    ref_name = Path(reference).stem if reference is not None else "reference"
    for label, tile in dems:
        measured = at_baseline(tile, baseline, label)
        distributions.append(slope_distribution_of(measured, label, edges))
        try:
            spec = radial_spectrum_of(measured, label)
            spectra.append(spec)
            try:
                fits.append(fit_hurst(spec))
            except InvalidDEMError as exc:
                log.warning("%s: no Hurst exponent (%s)", label, exc)
                fits.append(None)
        except InvalidDEMError as exc:
            log.warning("%s: no power spectrum (%s)", label, exc)
        if ref_tile is not None:
            try:
                comparisons.append(compare_dems(tile, ref_tile, label=label,
                                                reference_label=ref_name,
                                                edges=edges))
            except (InvalidDEMError, InvalidParameterError) as exc:
                if STACK_LAYER not in tile.metadata:
                    raise
                # a stack spans scales from kilometres to centimetres: its layers far coarser
                # than the reference (or far finer and smaller) cannot be compared with it
                log.warning("%s not compared with the reference: %s", label, exc)
        if slope_band is not None:
            source = tile.metadata.get(mk.SOURCE)
            if not source:
                raise InvalidParameterError(f"--slope-band needs a DEM file; {label} is a "
                                            "layer of a stack")
            theirs = read_dem(source, band=slope_band)
            if theirs.shape != tile.shape:
                raise InvalidDEMError(f"band {slope_band} of '{source}' is not on the height "
                                      "band's grid")
            agreements.append((f"{label} band {slope_band}",
                               compare_slope_maps(horn_slope(tile, edges=edges),
                                                  theirs.heights)))
    if ref_tile is not None:
        ref_label = f"reference {ref_name}"
        distributions.append(slope_distribution(ref_tile, label=ref_label, edges=edges))
    return DEMEvidence(tuple(distributions), tuple(spectra), tuple(fits), tuple(comparisons),
                       tuple(agreements))


def write_csv(path, header, rows, inputs=()) -> Path:
    """Write a CSV table atomically.

    Parameters
    ----------
    path : path-like
        The CSV file.
    header : sequence of str
        Column names.
    rows : iterable of sequences
        The rows.
    inputs : iterable of path-like, optional
        Files the output must not replace.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from terrain.core.outputs import atomic_path

    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    with atomic_path(path, inputs) as tmp:
        tmp.write_text(buf.getvalue(), encoding="utf-8")
    return Path(path)


def _num(v) -> str:
    return "" if v is None else f"{v:.6g}"


def write_evidence_csvs(evidence: DEMEvidence, folder, inputs=()) -> list[Path]:
    """Write ``slope_distributions.csv``, ``slope_summary.csv`` and ``spectra.csv``.

    Parameters
    ----------
    evidence : DEMEvidence
        What was measured (at least one distribution).
    folder : path-like
        The output folder (existing).
    inputs : iterable of path-like, optional
        Files the outputs must not replace.

    Returns
    -------
    list of pathlib.Path
        The three files.
    """
    folder = Path(folder)
    distributions = evidence.distributions
    angles = distributions[0].angles_deg
    out = [write_csv(folder / "slope_distributions.csv",
                     ["angle_deg"] + [d.label for d in distributions],
                     [[f"{a:g}"] + [f"{d.percent_steeper[i]:.6g}" for d in distributions]
                      for i, a in enumerate(angles)], inputs)]
    fit_of = {s.label: f for s, f in zip(evidence.spectra, evidence.fits, strict=True)}
    ks_of = {c.label: c.ks_distance for c in evidence.comparisons}
    out.append(write_csv(
        folder / "slope_summary.csv",
        ["label", "resolution_m", "slopes"] + [f"{k}_deg" for k in SUMMARY_KEYS]
        + ["hurst", "ks_vs_reference"],
        [[d.label, f"{d.resolution_m:.6g}", d.pixels]
         + [f"{d.quantiles[k]:.6g}" for k in SUMMARY_KEYS]
         + [_num(fit_of[d.label].hurst) if fit_of.get(d.label) else "",
            _num(ks_of.get(d.label))] for d in distributions], inputs))
    out.append(write_csv(
        folder / "spectra.csv",
        ["label", "frequency_per_m", "wavelength_m", "power_m4", "samples"],
        [[s.label, f"{f:.6g}", f"{1 / f:.6g}", f"{p:.6g}", int(c)]
         for s in evidence.spectra for f, p, c in zip(s.frequency, s.power, s.counts,
                                                      strict=True)], inputs))
    return out
