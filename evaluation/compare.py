r"""Comparing a DEM with a reference DEM: slope distributions, quantiles and power spectra.

:func:`compare_dems` puts the two DEMs on a common footing first: the finer one is averaged
onto the coarser one's spacing (:func:`evaluation.slope.matched_baseline`), because a Horn
slope measures the slope over twice the pixel spacing and slopes steepen as the baseline
shortens. Then it reports

* the two-sample Kolmogorov-Smirnov distance ``D = max |F(s) - F_ref(s)|`` between the
  slope distributions (the statistic only: neighbouring slopes are correlated, so the
  textbook p-value, which assumes independent samples, would be meaningless), and the same
  distance between the slopes each divided by its own median: the distribution's *shape*,
  free of its amplitude, with the ratio of the medians (the amplitude) beside it;
* slope quantiles of both;
* the ratio of their radially averaged power spectra over the band both resolve, with the
  median and largest ``|log10 ratio|`` (the paper's Fig. 14 comparison as numbers), and
  the Hurst exponent of each from the median structure function over even lags
  (:func:`evaluation.validate.hurst_estimate`), which a period-2 pattern cannot bias.

A reference of another place (``shape_only``) is compared by shape: its terrain need not be
as rough as ours (a flat landing region against terrain built for a regional slope law), so
the amplitude is reported, not judged, and the spectra's ratio, which carries the amplitude
(and, for a shape-from-shading DEM, its period-2 pattern's power), with it. The spectral
*slope* is compared through the structure-function Hurst exponents, which even lags keep
free of that pattern.

DEMs in different coordinate reference systems are refused: their pixels are not the same
shape on the ground, so their slopes are not comparable until one is reprojected onto the
other (``gdalwarp -t_srs``). DEMs without a CRS (local frames) are taken as metres.

:func:`compare_slope_maps` checks a slope map against an independent one pixel by pixel
(for example the QuickMap slope band of ``aristarchus_IMP_quickmap_hsr_4p76m.tif``).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field

import numpy as np

from evaluation.slope import SlopeDistribution, horn_slope, matched_baseline, slope_distribution
from evaluation.spectrum import RadialSpectrum, radial_spectrum
from evaluation.validate import hurst_estimate
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.io import same_crs

__all__ = ["MIN_COMPARED_SLOPES", "Comparison", "SlopeMapAgreement", "check_same_crs",
           "compare_dems", "compare_slope_maps", "ks_distance", "spectrum_ratio"]

log = logging.getLogger(__name__)

#: Fewest slopes either DEM must have at the matched baseline: below this a KS distance or a
#: quantile says more about sampling than about the terrain (1000 slopes: the KS distance
#: between two samples of the same distribution is then about 0.06 or less, 95 % of the time).
MIN_COMPARED_SLOPES = 1000


def _crs_name(wkt: str) -> str:
    """Short description of a WKT CRS: its name and projection method."""
    name = re.match(r'\s*\w+\["([^"]*)"', wkt)
    method = re.search(r'(?:METHOD|PROJECTION)\["([^"]*)"', wkt)
    text = name.group(1) if name else wkt[:40]
    return f"{text}, {method.group(1)}" if method else text


def check_same_crs(a: DEMTile, b: DEMTile, *, names=("DEM", "reference")) -> None:
    """Raise :class:`InvalidDEMError` when both DEMs have a CRS and they differ.

    The comparison is GDAL's CRS equality (:func:`terrain.io.same_crs`), so equivalent CRSs
    written differently are the same.

    >>> t = DEMTile.from_array(np.zeros((3, 3)))
    >>> check_same_crs(t, t.replace(crs=None))   # local frames: nothing to check
    """
    if a.crs is None or b.crs is None:
        if (a.crs is None) != (b.crs is None):
            log.warning("%s has no CRS; taking its map units as metres in %s's frame",
                        names[0] if a.crs is None else names[1],
                        names[1] if a.crs is None else names[0])
        return
    if not same_crs(a.crs, b.crs):
        raise InvalidDEMError(
            f"{names[0]} and {names[1]} are in different coordinate reference systems "
            f"('{_crs_name(a.crs)}' vs '{_crs_name(b.crs)}'); reproject one onto the other "
            "first (for example gdalwarp -t_srs)")


def spectrum_ratio(ours: RadialSpectrum, reference: RadialSpectrum) -> tuple[np.ndarray,
                                                                              np.ndarray]:
    """``P / P_ref`` at our frequencies inside the band both spectra cover.

    The reference is interpolated linearly in log-log space.

    Returns
    -------
    frequency : (k,) float64, cycles per metre
    ratio : (k,) float64
    """
    lo = max(ours.frequency[0], reference.frequency[0])
    hi = min(ours.frequency[-1], reference.frequency[-1])
    sel = (ours.frequency >= lo) & (ours.frequency <= hi)
    f = ours.frequency[sel]
    if f.size == 0:
        return f, f.copy()
    ref = 10 ** np.interp(np.log10(f), np.log10(reference.frequency),
                          np.log10(reference.power))
    return f, ours.power[sel] / ref


@dataclass(frozen=True, eq=False)
class Comparison:
    """A DEM against a reference DEM at a matched baseline.

    Parameters
    ----------
    label, reference_label : str
    resolution_m : float
        Common pixel spacing (the coarser DEM's).
    resampled : str
        Which input was averaged onto the coarser grid ("DEM", "reference" or "none").
    ks_distance : float
        Two-sample Kolmogorov-Smirnov statistic of the slope distributions (0 to 1).
    distribution, reference_distribution : SlopeDistribution
    spectrum, reference_spectrum : RadialSpectrum or None
        None where a DEM is too small for a spectrum.
    ratio_frequency, ratio : (k,) float64
        ``P / P_ref`` over the common band (cycles per metre).
    hurst, reference_hurst : float or None
        From the median structure function over even lags (robust to period-2 patterns).
    shape_ks_distance : float or None
        KS distance of the slopes each divided by its own median (the shape alone).
    shape_only : bool
        The reference is another place: shape judged, amplitude reported (module docstring).
    """

    label: str
    reference_label: str
    resolution_m: float
    resampled: str
    ks_distance: float
    distribution: SlopeDistribution
    reference_distribution: SlopeDistribution
    spectrum: RadialSpectrum | None = None
    reference_spectrum: RadialSpectrum | None = None
    ratio_frequency: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ratio: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hurst: float | None = None
    reference_hurst: float | None = None
    shape_ks_distance: float | None = None
    shape_only: bool = False

    @property
    def amplitude_ratio(self) -> float | None:
        """Median slope over the reference's at the matched baseline (None if it is 0)."""
        ref = self.reference_distribution.quantiles["p50"]
        return self.distribution.quantiles["p50"] / ref if ref > 0 else None

    @property
    def log10_ratio_median(self) -> float | None:
        """Median ``|log10(P / P_ref)|`` over the common band (None without spectra)."""
        if self.ratio.size == 0:
            return None
        return float(np.median(np.abs(np.log10(self.ratio))))

    @property
    def log10_ratio_max(self) -> float | None:
        """The largest ``|log10|`` of the spectral power ratio, or None without a ratio."""
        if self.ratio.size == 0:
            return None
        return float(np.max(np.abs(np.log10(self.ratio))))

    def as_dict(self) -> dict:
        """Return the comparison as plain data for the report's JSON."""
        return dict(
            label=self.label, reference_label=self.reference_label,
            resolution_m=self.resolution_m, resampled=self.resampled,
            ks_distance=self.ks_distance,
            quantiles=self.distribution.quantiles,
            reference_quantiles=self.reference_distribution.quantiles,
            hurst=self.hurst, reference_hurst=self.reference_hurst,
            shape_ks_distance=self.shape_ks_distance, shape_only=self.shape_only,
            amplitude_ratio=self.amplitude_ratio,
            spectrum_log10_ratio_median=self.log10_ratio_median,
            spectrum_log10_ratio_max=self.log10_ratio_max,
            ratio_frequency_per_m=self.ratio_frequency.tolist(), ratio=self.ratio.tolist(),
            distribution=self.distribution.as_dict(),
            reference_distribution=self.reference_distribution.as_dict(),
            spectrum=self.spectrum.as_dict() if self.spectrum else None,
            reference_spectrum=(self.reference_spectrum.as_dict()
                                if self.reference_spectrum else None))


def _spectrum_and_hurst(tile, label):
    """Return the power spectrum and the Hurst exponent (or None where a DEM is too small).

    The exponent comes from the median structure function over even lags
    (:func:`evaluation.validate.hurst_estimate`): a period-2 row or column pattern, as in
    shape-from-shading DEMs, cancels on even lags where it would bend a spectral fit.
    """
    try:
        spectrum = radial_spectrum(tile, label=label)
    except InvalidDEMError as exc:
        log.warning("%s: no power spectrum (%s)", label, exc)
        spectrum = None
    try:
        return spectrum, hurst_estimate(tile).hurst
    except InvalidDEMError as exc:
        log.warning("%s: no Hurst exponent (%s)", label, exc)
        return spectrum, None


def compare_dems(tile: DEMTile, reference: DEMTile, *, label: str = "DEM",
                 reference_label: str = "reference", edges: str = "mask",
                 angles=None, shape_only: bool = False) -> Comparison:
    """Compare a DEM with a reference DEM (see the module docstring).

    Parameters
    ----------
    tile, reference : DEMTile
    label, reference_label : str
    edges : {"mask", "gdal"}
        Slope edge handling (:func:`evaluation.slope.horn`).
    angles : (k,) float, degrees, optional
        Thresholds of the cumulative distributions.
    shape_only : bool
        The reference is another place: judge the shape, report the amplitude.

    Returns
    -------
    Comparison

    Examples
    --------
    >>> from evaluation.spectrum import fractional_brownian_surface
    >>> a = fractional_brownian_surface(64, 0.8, rms=3.0, seed=1)
    >>> compare_dems(a, a).ks_distance
    0.0
    """
    for name, t in (("DEM", tile), ("reference", reference)):
        if not isinstance(t, DEMTile):
            raise InvalidParameterError(f"{name} must be a DEMTile; got {type(t).__name__}")
    check_same_crs(tile, reference, names=(label, reference_label))
    a, b = matched_baseline(tile, reference)
    if a is tile and b is reference:
        resampled = "none"
    else:
        resampled = "DEM" if a is not tile else "reference"
        log.info("compared at %.6g m: %s averaged from %.6g m", a.resolution,
                 label if resampled == "DEM" else reference_label,
                 (tile if resampled == "DEM" else reference).resolution)
    sa, sb = horn_slope(a, edges=edges), horn_slope(b, edges=edges)
    for name, t, s in ((label, a, sa), (reference_label, b, sb)):
        n = int(np.isfinite(s).sum())
        if n < MIN_COMPARED_SLOPES:
            raise InvalidDEMError(
                f"{name} has {n} slopes at the matched baseline of {a.resolution:.6g} m "
                f"({t.shape[1]}x{t.shape[0]} pixels); a comparison needs at least "
                f"{MIN_COMPARED_SLOPES}")
    da = slope_distribution(a, label=label, angles=angles, slopes=sa)
    db = slope_distribution(b, label=reference_label, angles=angles, slopes=sb)
    ks = ks_distance(sa, sb)
    fa, fb = sa[np.isfinite(sa)], sb[np.isfinite(sb)]
    ma, mb = float(np.median(fa)), float(np.median(fb))
    shape_ks = ks_distance(fa / ma, fb / mb) if ma > 0 and mb > 0 else None
    spec_a, hurst_a = _spectrum_and_hurst(a, label)
    spec_b, hurst_b = _spectrum_and_hurst(b, reference_label)
    freq = ratio = np.zeros(0)
    if spec_a is not None and spec_b is not None:
        freq, ratio = spectrum_ratio(spec_a, spec_b)
    return Comparison(label, reference_label, a.resolution, resampled, ks, da, db, spec_a,
                      spec_b, freq, ratio, hurst_a, hurst_b, shape_ks, bool(shape_only))


@dataclass(frozen=True)
class SlopeMapAgreement:
    """Pixel-by-pixel agreement of two slope maps (degrees) on the same grid."""

    pixels: int
    bias_deg: float
    median_abs_deg: float
    p99_abs_deg: float
    max_abs_deg: float
    correlation: float

    def as_dict(self) -> dict:
        """Return the agreement statistics (degrees) as plain data for the report's JSON."""
        return dict(pixels=self.pixels, bias_deg=self.bias_deg,
                    median_abs_deg=self.median_abs_deg, p99_abs_deg=self.p99_abs_deg,
                    max_abs_deg=self.max_abs_deg, correlation=self.correlation)


def compare_slope_maps(ours, reference) -> SlopeMapAgreement:
    """Agreement of a slope map with an independent one (same grid, degrees).

    Parameters
    ----------
    ours, reference : (ny, nx) float, degrees
        NaN (or non-finite) pixels of either are left out.

    Examples
    --------
    >>> a = np.array([[1.0, 2.0], [3.0, np.nan]])
    >>> compare_slope_maps(a, a + 0.5).bias_deg
    -0.5
    """
    a = np.asarray(ours, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape:
        raise InvalidParameterError(
            f"slope maps must share a grid: expected shape {a.shape}; got {b.shape}")
    both = np.isfinite(a) & np.isfinite(b)
    n = int(both.sum())
    if n < 2:
        raise InvalidParameterError("the slope maps share fewer than 2 valid pixels")
    d = a[both] - b[both]
    ad = np.abs(d)
    corr = float(np.corrcoef(a[both], b[both])[0, 1]) if np.std(a[both]) > 0 else math.nan
    return SlopeMapAgreement(n, float(d.mean()), float(np.median(ad)),
                             float(np.quantile(ad, 0.99)), float(ad.max()), corr)



def ks_distance(a, b, *, weights_a=None, weights_b=None) -> float:
    """Kolmogorov-Smirnov distance ``max |F_a - F_b|`` of two (weighted) samples.

    With weights (for example vertex areas) each empirical distribution function steps by
    its sample's weight share, so bodies meshed differently compare by area.

    >>> ks_distance([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    0.0
    >>> ks_distance([0.0, 1.0], [2.0, 3.0])
    1.0
    """
    xa = np.asarray(a, dtype=np.float64).reshape(-1)
    xb = np.asarray(b, dtype=np.float64).reshape(-1)
    wa = np.ones_like(xa) if weights_a is None else np.asarray(weights_a, np.float64).ravel()
    wb = np.ones_like(xb) if weights_b is None else np.asarray(weights_b, np.float64).ravel()
    if wa.shape != xa.shape or wb.shape != xb.shape:
        raise InvalidParameterError("weights must match their samples in length")
    ka = np.isfinite(xa) & (wa > 0)
    kb = np.isfinite(xb) & (wb > 0)
    xa, wa, xb, wb = xa[ka], wa[ka], xb[kb], wb[kb]
    if xa.size == 0 or xb.size == 0:
        raise InvalidParameterError("both samples need at least one finite value")
    oa, ob = np.argsort(xa), np.argsort(xb)
    xa, xb = xa[oa], xb[ob]
    ca = np.cumsum(wa[oa]) / wa.sum()
    cb = np.cumsum(wb[ob]) / wb.sum()
    grid = np.union1d(xa, xb)
    fa = np.concatenate([[0.0], ca])[np.searchsorted(xa, grid, side="right")]
    fb = np.concatenate([[0.0], cb])[np.searchsorted(xb, grid, side="right")]
    return float(np.max(np.abs(fa - fb)))
