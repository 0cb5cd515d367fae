r"""Is this terrain lunar? Published statistics as calibrated checks, for any DEM or layer stack.

Every check compares one measure of the input with a published statistic of real terrain
(:mod:`evaluation.lunar_stats`: the source, the value and scatter, and how the threshold
follows) and gives a :class:`Result`: passed, failed (by how much, and what that means) or
not applicable (the input lacks what the check needs: no crater catalogue, no rocks, not a
body). The functions here are pure: a DEM tile or a layer stack in, results and the numbers
of every figure out; :mod:`evaluation.validate_report` draws them.

Estimators that real data cannot fool
-------------------------------------
Real DEMs carry artefacts a naive estimator mistakes for terrain. Shape-from-shading DEMs
can alternate rows (a period-2 pattern: the Malapert SfS DEM's median height difference
at one pixel is 7 times that at two), and pushbroom or stereo DEMs stripe along one axis. So:

* the structure function is the *median* absolute height difference at a lag (a few
  spikes do not move it), along each map axis separately;
* the Hurst exponent is fitted over even lags only (2, 4, 8, 16 px), on which a period-2
  pattern cancels exactly; the fit range, its R^2 and an uncertainty (the fit's standard
  error, or half the difference of the two axes if larger) are reported;
* striping adds uncorrelated differences along one axis and only lowers that axis's H: where
  the axes disagree by more than :data:`ANISOTROPY` the larger is used, and the report says;
* a lag of one pixel is dropped from the slope curve when it shows a period-2 pattern (the
  median difference at one pixel exceeds the one at two: no self-affine surface does that);
* the spectral smoothness check uses wavelengths of 4-16 px, away from the Nyquist
  frequency where a period-2 pattern puts its power.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from evaluation import lunar_stats as ls
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.tile import DEMTile

__all__ = ["GROUPS", "HurstEstimate", "body_slope_check", "boulder_check", "boulder_index",
           "facet_matched_slopes", "Result", "SlopeCurve", "Validation", "hurst_estimate",
           "not_applicable", "period2_ratio", "slope_curve", "steep_share", "validate_dem",
           "validate_stack"]

#: Check groups, in report order. Only the first two decide the verdict.
REALISM, RENDERER, TRACKER, COMPARISON = ("terrain realism", "renderer consistency",
                                          "tracker performance (informational)",
                                          "side-by-side comparison")
GROUPS = (REALISM, RENDERER, TRACKER, COMPARISON)
#: Lags (pixels) of the Hurst fit: even, so that a period-2 pattern cancels.
HURST_LAGS = (2, 4, 8, 16)
#: Axes whose H differ by more than this are anisotropic or striped.
ANISOTROPY = 0.2
#: Wavelength band (pixels) of the spectral smoothness check.
SMOOTH_BAND_PX = (4.0, 16.0)
#: Steepness of the angle-of-repose check (degrees; Kreslavsky and Head 2016).
REPOSE_DEG = 35.0
#: Craters per layer of at least this many pixels across are measured for depth/diameter.
MIN_CRATER_PX = 8.0
#: Depth/diameter range of the catalogue check (10-100 m craters).
DD_RANGE_M = (10.0, 100.0)
#: Most craters measured per layer (an even sample of those that fit).
MAX_CRATERS_MEASURED = 400
#: Lower end of a plausible median depth/diameter (Stopar et al. 2017: degraded ~0.05).
DD_MIN = 0.03


@dataclass(frozen=True)
class Result:
    """One check: a measured value against a published statistic.

    ``status`` is ``"pass"``, ``"fail"`` or ``"not applicable"``; ``meaning`` says, for a
    failure, by how much and what it means, and for a check not applied, why.
    """

    group: str
    name: str
    status: str
    value: float | None
    limit: float | None
    relation: str
    unit: str = ""
    source: str = ""
    derivation: str = ""
    meaning: str = ""

    def __post_init__(self):
        if self.status not in ("pass", "fail", "not applicable"):
            raise InvalidParameterError(f"status must be pass, fail or not applicable; got "
                                        f"{self.status!r}")
        if self.group not in GROUPS:
            raise InvalidParameterError(f"group must be one of {GROUPS}; got {self.group!r}")

    @property
    def informational(self) -> bool:
        """Whether the verdict ignores this check (tracker performance)."""
        return self.group == TRACKER

    def as_dict(self) -> dict:
        """Return the result as plain data."""
        return dict(group=self.group, name=self.name, status=self.status, value=self.value,
                    limit=self.limit, relation=self.relation, unit=self.unit,
                    source=self.source, derivation=self.derivation, meaning=self.meaning,
                    informational=self.informational)


def _judge(group, name, value, limit, relation, stat: ls.PublishedStat | None, *, unit="",
           fail_meaning="", pass_meaning="") -> Result:
    ok = value <= limit if relation == "<=" else value >= limit
    return Result(group, name, "pass" if ok else "fail", float(value), float(limit),
                  relation, unit, stat.source if stat else "",
                  stat.derivation if stat else "", pass_meaning if ok else fail_meaning)


def not_applicable(group: str, name: str, reason: str,
                   stat: ls.PublishedStat | None = None) -> Result:
    """Return a check that the input cannot answer, with the reason.

    >>> not_applicable(REALISM, "crater N(>=D)", "no crater catalogue").status
    'not applicable'
    """
    return Result(group, name, "not applicable", None, stat.threshold if stat else None, "",
                  "", stat.source if stat else "", stat.derivation if stat else "", reason)


# ---------------------------------------------------------------------------- estimators


def _heights(tile: DEMTile) -> np.ndarray:
    if not isinstance(tile, DEMTile):
        raise InvalidParameterError(f"expected a DEMTile; got {type(tile).__name__}")
    return np.where(tile.valid, tile.heights, np.nan).astype(np.float64)


def _median_abs_diff(z: np.ndarray, lag: int, axis: int) -> float:
    d = z[:, lag:] - z[:, :-lag] if axis == 1 else z[lag:, :] - z[:-lag, :]
    d = np.abs(d[np.isfinite(d)])
    return float(np.median(d)) if d.size else math.nan


def period2_ratio(tile: DEMTile) -> float:
    """Largest, over the two axes, of the median |dz| at one pixel over that at two.

    Below 1 for any self-affine surface (differences grow with the lag); above 1 where rows
    or columns alternate (a period-2 artefact of shape-from-shading or resampling).

    Examples
    --------
    >>> ramp = 0.1 * np.add.outer(np.arange(32.0), np.arange(32.0))
    >>> z = ramp + 0.5 * (np.arange(32) % 2)[:, None]  # odd rows raised by 0.5 m
    >>> period2_ratio(DEMTile.from_array(z)) > 1
    True
    """
    z = _heights(tile)
    ratios = []
    for axis in (0, 1):
        d1, d2 = _median_abs_diff(z, 1, axis), _median_abs_diff(z, 2, axis)
        if d2 > 0:
            ratios.append(d1 / d2)
    return max(ratios) if ratios else math.nan


@dataclass(frozen=True)
class SlopeCurve:
    """Median bidirectional slope against baseline (``baseline_m``, ``median_deg``)."""

    label: str
    baseline_m: np.ndarray
    median_deg: np.ndarray
    note: str = ""

    def as_dict(self) -> dict:
        """Return the curve as plain data."""
        return dict(label=self.label, baseline_m=self.baseline_m.tolist(),
                    median_deg=self.median_deg.tolist(), note=self.note)


def slope_curve(tile: DEMTile, *, label: str = "", max_lag: int | None = None) -> SlopeCurve:
    """Median bidirectional slope (degrees) at baselines of 1, 2, 4, ... pixels.

    Both map axes pooled; lags up to a quarter of the shorter side (or ``max_lag``). A lag of
    one pixel is dropped where :func:`period2_ratio` exceeds 1.

    Parameters
    ----------
    tile : DEMTile
    label : str
    max_lag : int, optional

    Returns
    -------
    SlopeCurve

    Examples
    --------
    >>> g = 0.5 * np.arange(64.0)  # rising 0.5 m per metre along both axes
    >>> [round(float(v), 1) for v in slope_curve(DEMTile.from_array(np.add.outer(g, g))).median_deg]
    [26.6, 26.6, 26.6, 26.6, 26.6]
    """
    z = _heights(tile)
    top = max(1, min(z.shape) // 4) if max_lag is None else int(max_lag)
    note = ""
    lags = [2 ** k for k in range(0, 30) if 2 ** k <= top]
    if period2_ratio(tile) > 1.0:
        lags = [g for g in lags if g > 1]
        note = "one-pixel baseline dropped: period-2 pattern"
    base, med = [], []
    for lag in lags:
        d = np.concatenate([(z[:, lag:] - z[:, :-lag]).ravel(),
                            (z[lag:, :] - z[:-lag, :]).ravel()])
        d = np.abs(d[np.isfinite(d)])
        if d.size < 16:
            continue
        base.append(lag * tile.resolution)
        med.append(math.degrees(math.atan(float(np.median(d)) / (lag * tile.resolution))))
    return SlopeCurve(label, np.array(base), np.array(med), note)


@dataclass(frozen=True)
class HurstEstimate:
    """A Hurst exponent with its fit range, quality and uncertainty."""

    hurst: float
    uncertainty: float
    r_squared: float
    lags_px: tuple
    band_m: tuple
    per_axis: tuple
    structure: dict = field(default_factory=dict)
    note: str = ""

    def as_dict(self) -> dict:
        """Return the estimate as plain data."""
        return dict(hurst=self.hurst, uncertainty=self.uncertainty, r_squared=self.r_squared,
                    lags_px=list(self.lags_px), band_m=list(self.band_m),
                    per_axis=list(self.per_axis), structure=self.structure, note=self.note)


def _fit(lags, values):
    x, y = np.log(np.asarray(lags, float)), np.log(np.asarray(values, float))
    coef, cov = np.polyfit(x, y, 1, cov=True) if len(x) > 2 else (np.polyfit(x, y, 1), None)
    resid = y - np.polyval(coef, x)
    ss = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum(resid ** 2)) / ss if ss > 0 else 1.0
    se = float(math.sqrt(cov[0, 0])) if cov is not None and np.isfinite(cov[0, 0]) else 0.0
    return float(coef[0]), r2, se


def hurst_estimate(tile: DEMTile, *, lags=HURST_LAGS) -> HurstEstimate:
    """Hurst exponent from the median structure function over even lags, per axis.

    See the module docstring for why even lags, medians and per-axis fits.

    Parameters
    ----------
    tile : DEMTile
    lags : sequence of int
        Pixel lags; those longer than a quarter of the shorter side are dropped.

    Returns
    -------
    HurstEstimate

    Raises
    ------
    InvalidDEMError
        Fewer than three lags fit in the DEM.

    Examples
    --------
    >>> from evaluation.spectrum import fractional_brownian_surface
    >>> est = hurst_estimate(fractional_brownian_surface(256, 0.8, seed=2))
    >>> abs(est.hurst - 0.8) < 0.1
    True
    """
    z = _heights(tile)
    use = [int(g) for g in lags if int(g) <= min(z.shape) // 4]
    if len(use) < 3:
        raise InvalidDEMError(f"a {z.shape[1]}x{z.shape[0]} DEM is too small for a Hurst fit "
                              f"over lags {tuple(lags)} px (needs 4x the third lag)")
    axes, structure = [], {}
    for axis, name in ((1, "x"), (0, "y")):
        s = [_median_abs_diff(z, g, axis) for g in use]
        structure[name] = s
        if all(v > 0 for v in s):
            axes.append(_fit(use, s))
    if not axes:
        raise InvalidDEMError("the DEM is flat: no Hurst exponent")
    hs = [a[0] for a in axes]
    note = ""
    if len(hs) == 2 and abs(hs[0] - hs[1]) > ANISOTROPY:
        k = int(np.argmax(hs))
        h, r2, se = axes[k]
        note = (f"axes disagree (H {hs[0]:.2f} along x, {hs[1]:.2f} along y): striping or "
                f"anisotropy; the {'xy'[k]} axis (the larger, which striping cannot raise) "
                "is used")
        unc = max(se, abs(hs[0] - hs[1]) / 2)
    else:
        h = float(np.mean(hs))
        r2 = float(np.mean([a[1] for a in axes]))
        unc = max(max(a[2] for a in axes), (max(hs) - min(hs)) / 2)
    return HurstEstimate(h, unc, r2, tuple(use), (use[0] * tile.resolution,
                                                  use[-1] * tile.resolution),
                         tuple(hs), dict(lags_px=use, **structure), note)


def fine_spectral_hurst(tile: DEMTile):
    """Spectral Hurst exponent over wavelengths of 4-16 px (None if the DEM is too small).

    Returns
    -------
    evaluation.spectrum.HurstFit or None
    """
    from evaluation.spectrum import fit_hurst, radial_spectrum

    if min(tile.shape) < 4 * SMOOTH_BAND_PX[1]:
        return None
    spec = radial_spectrum(tile)
    r = tile.resolution
    try:
        return fit_hurst(spec, f_low=1.0 / (SMOOTH_BAND_PX[1] * r),
                         f_high=1.0 / (SMOOTH_BAND_PX[0] * r))
    except InvalidDEMError:
        return None


def steep_share(tile: DEMTile, angle_deg: float = REPOSE_DEG) -> float:
    """Fraction of valid Horn slopes steeper than ``angle_deg``.

    >>> flat = DEMTile.from_array(np.zeros((16, 16)))
    >>> steep_share(flat)
    0.0
    """
    from evaluation.slope import horn_slope

    s = horn_slope(tile)
    s = s[np.isfinite(s)]
    return float(np.mean(s > angle_deg)) if s.size else math.nan


# ------------------------------------------------------------------------------- checks


def _slope_curve_check(curves, law: ls.TerrainLaw) -> Result:
    stat = ls.SLOPE_BAND_FACTOR
    name = f"median slope vs baseline within x{stat.threshold:g} of the {law.name} law"
    pts = [(b, m) for c in curves for b, m in zip(c.baseline_m, c.median_deg, strict=True)
           if m > 0]
    if not pts:
        return not_applicable(REALISM, name, "no baseline measured", stat)
    b, m = np.array(pts).T
    expect = law.median_slope_deg(b)
    factor = np.maximum(m / expect, expect / m)
    k = int(np.argmax(factor))
    worst = float(factor[k])
    side = "steeper" if m[k] > expect[k] else "smoother"
    return _judge(
        REALISM, name, worst, stat.threshold, "<=", stat, unit="x",
        fail_meaning=(f"at {b[k]:.3g} m the median slope is {m[k]:.3g} deg, {worst:.2g} times "
                      f"{side} than the {law.name} law's {expect[k]:.3g} deg: "
                      + ("the terrain is rougher than real terrain of this type"
                         if side == "steeper" else
                         "relief is missing at this scale (smoothed or too flat)")),
        pass_meaning=f"worst at {b[k]:.3g} m: {m[k]:.3g} deg against {expect[k]:.3g} deg")


def _hurst_check(est: HurstEstimate, law: ls.TerrainLaw, label: str) -> Result:
    stat = ls.HURST_TOLERANCE
    centre = math.sqrt(est.band_m[0] * est.band_m[1])
    h_law = law.hurst_at(centre)
    dh = abs(est.hurst - h_law)
    name = (f"{label}Hurst exponent {est.hurst:.2f} +- {est.uncertainty:.2f} (lags "
            f"{est.band_m[0]:.3g}-{est.band_m[1]:.3g} m, R^2 {est.r_squared:.2f}) vs "
            f"{h_law:g}")
    low = est.hurst < h_law
    return _judge(
        REALISM, name, dh, stat.threshold, "<=", stat,
        fail_meaning=(f"H differs from the {law.name} law's {h_law:g} by {dh:.2f} (limit "
                      f"{stat.threshold:g}): "
                      + ("heights are too rough at small scales relative to large ones, like a "
                         "random walk (H 0.5), not lunar regolith and craters"
                         if low else "the surface is smoother at small scales than "
                         "lunar terrain")) + (f"; {est.note}" if est.note else ""),
        pass_meaning=est.note)


def _smooth_check(fit, label: str) -> Result:
    stat = ls.SMOOTHNESS
    name = f"{label}fine-scale roughness: spectral H over {SMOOTH_BAND_PX[0]:g}-" \
           f"{SMOOTH_BAND_PX[1]:g} px wavelengths"
    if fit is None:
        return not_applicable(REALISM, name, f"DEM narrower than {4 * SMOOTH_BAND_PX[1]:g} "
                              "px", stat)
    return _judge(
        REALISM, name, fit.hurst, stat.threshold, "<=", stat,
        fail_meaning=(f"spectral H {fit.hurst:.2f} exceeds {stat.threshold:g}: power falls "
                      "off far faster than any self-affine terrain below "
                      f"{SMOOTH_BAND_PX[1]:g} px; the DEM is interpolated or smoothed and its "
                      "finest scales hold no roughness (R^2 "
                      f"{fit.r_squared:.2f})"),
        pass_meaning=f"R^2 {fit.r_squared:.2f}")


def _steep_check(share: float, label: str, resolution: float) -> Result:
    stat = ls.STEEP_SLOPE
    return _judge(
        REALISM, f"{label}area steeper than {REPOSE_DEG:g} deg at {resolution:.3g} m", share,
        stat.threshold, "<=", stat, unit="fraction",
        fail_meaning=(f"{100 * share:.3g} % of the area is steeper than the angle of repose "
                      f"({100 * stat.threshold:g} % allowed): loose regolith does not stand "
                      "there; real terrain has such slopes only on young crater walls and "
                      "central peaks"))


#: Fewest boulders the SFD index is fitted from.
MIN_BOULDERS = 20


def boulder_index(diameter_m, dmin: float | None = None) -> tuple[float, float, int]:
    """Cumulative SFD power-law index of boulders, by maximum likelihood.

    For N(>=D) ~ D^b above ``dmin``, b = -n / sum(ln(D / dmin)) (Clauset et al. 2009, SIAM
    Rev. 51, 661, eq. 3.1), with standard error |b| / sqrt(n).

    Parameters
    ----------
    diameter_m : (n,) float, metres
    dmin : float, optional
        Completeness limit (default: the smallest diameter).

    Returns
    -------
    (index, stderr, n) : (float, float, int)

    Examples
    --------
    >>> d = 2.0 * (1.0 - np.random.default_rng(1).random(4000)) ** (-1 / 3.0)
    >>> round(boulder_index(d, 2.0)[0], 1)
    -3.0
    """
    d = np.asarray(diameter_m, dtype=np.float64)
    d = d[np.isfinite(d) & (d > 0)]
    lo = float(d.min()) if dmin is None and d.size else float(dmin or 0.0)
    d = d[d >= lo]
    logs = np.log(d / lo)
    if d.size < 2 or logs.sum() <= 0:
        return math.nan, math.nan, int(d.size)
    b = -d.size / float(logs.sum())
    return b, abs(b) / math.sqrt(d.size), int(d.size)


def boulder_check(diameter_m, *, label: str = "", dmin: float | None = None) -> Result:
    """Judge a body's boulder SFD index against Ryugu, Bennu, Itokawa and Eros.

    >>> boulder_check([]).status
    'not applicable'
    """
    stat = ls.BODY_BOULDER_INDEX
    name = f"{label}boulder SFD index vs Ryugu, Bennu, Itokawa, Eros"
    b, se, n = boulder_index(diameter_m, dmin) if len(diameter_m) else (math.nan, 0.0, 0)
    if n < MIN_BOULDERS or not math.isfinite(b):
        return not_applicable(REALISM, name, f"{n} boulders: at least {MIN_BOULDERS} are "
                              "needed for an index", stat)
    off = abs(b - stat.value)
    return _judge(REALISM, f"{name}: {b:.2f} +- {se:.2f} ({n} boulders)", off,
                  stat.threshold, "<=", stat,
                  fail_meaning=(f"the index {b:.2f} lies {off:.2f} from {stat.value:g} "
                                f"(limit {stat.threshold:g}): "
                                + ("too many large boulders for the small ones"
                                   if b > stat.value else
                                   "too few large boulders for the small ones")
                                + "; no asteroid imaged so far has such a population"))


#: Most facets of the facet-matched slope comparison (gravity cost grows with their square).
MAX_BODY_FACES = 12288


def facet_matched_slopes(body, reference, *, density: float, spin=None,
                         max_faces: int = MAX_BODY_FACES, labels=("body", "reference")):
    """Slopes of a body and a real shape model coarsened to the same facet count.

    Parameters
    ----------
    body, reference : (vertices, faces)
        Closed meshes in metres about their centres.
    density : float, kg m^-3
    spin : evaluation.meshslope.Spin, optional
    max_faces : int
        The common count is the smaller mesh's, at most this.
    labels : (str, str)

    Returns
    -------
    (MeshSlopes, MeshSlopes)
        Each vertex's own slope (no cap average), so the facet count alone sets the scale.
    """
    from evaluation.gravity import coarsen
    from evaluation.meshslope import mesh_slopes

    n = min(len(body[1]), len(reference[1]), int(max_faces))
    out = []
    for (v, f), label in zip((body, reference), labels, strict=True):
        v, f = coarsen(np.asarray(v, float), np.asarray(f, np.int64), n)
        out.append(mesh_slopes(v, f, label=label, radius_deg=0.0, density=density, spin=spin))
    return out[0], out[1]


def _mean_slope(ms) -> float:
    g = ms.slopes("gravitational")
    ok = np.isfinite(g)
    return float(np.average(g[ok], weights=ms.vertex_area[ok]))


def body_slope_check(body, reference, *, label: str = "") -> Result:
    """Judge a body's mean gravitational slope against a real shape model's, same facets.

    Parameters
    ----------
    body, reference : evaluation.meshslope.MeshSlopes
        From :func:`facet_matched_slopes`.
    """
    stat = ls.MESH_SLOPE_RISE
    mb, mr = _mean_slope(body), _mean_slope(reference)
    off = abs(mb / mr - 1.0)
    return _judge(
        REALISM, f"{label}mean gravitational slope {mb:.3g} deg vs {reference.label} "
        f"{mr:.3g} deg at {reference.info['faces']} facets", off, stat.threshold, "<=", stat,
        unit="fraction",
        fail_meaning=(f"{100 * off:.3g} % {'steeper' if mb > mr else 'flatter'} than "
                      f"{reference.label} at the same facet count; real bodies differ by at "
                      f"most {100 * stat.threshold:g} %"))


def body_checks() -> list[Result]:
    """Return the small-body checks, not applicable to a DEM."""
    why = "a DEM, not a body (the campaign report judges its asteroid by these)"
    return [not_applicable(REALISM, "boulder SFD index vs Ryugu, Bennu, Itokawa, Eros", why,
                           ls.BODY_BOULDER_INDEX),
            not_applicable(REALISM, "gravitational slopes vs a real shape model at the same "
                           "facet count", why, ls.MESH_SLOPE_RISE)]


@dataclass
class Validation:
    """The results of validating one input, and the numbers of every figure."""

    label: str
    terrain: str
    results: list
    curves: list
    hurst: list  # (label, HurstEstimate)
    distributions: list
    data: dict = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """``"pass"`` unless a check that decides the verdict failed."""
        return "fail" if any(r.status == "fail" and not r.informational
                             and r.group != COMPARISON for r in self.results) else "pass"

    def failures(self) -> list[Result]:
        """Return the failed checks that decide the verdict."""
        return [r for r in self.results if r.status == "fail" and not r.informational
                and r.group != COMPARISON]

    def as_dict(self) -> dict:
        """Return the validation as plain data (the JSON report's core)."""
        return dict(label=self.label, terrain=self.terrain, verdict=self.verdict,
                    law=ls.terrain_law(self.terrain).as_dict(),
                    results=[r.as_dict() for r in self.results],
                    curves=[c.as_dict() for c in self.curves],
                    hurst=[dict(label=lb, **h.as_dict()) for lb, h in self.hurst],
                    distributions=[d.as_dict() for d in self.distributions],
                    stats=[s.as_dict() for s in ls.STATS], **self.data)


def _tile_checks(tile: DEMTile, law, label: str, prefix: str):
    from evaluation.slope import slope_distribution

    results, hurst = [], []
    try:
        est = hurst_estimate(tile)
        hurst.append((label, est))
        results.append(_hurst_check(est, law, prefix))
    except InvalidDEMError as exc:
        results.append(not_applicable(REALISM, f"{prefix}Hurst exponent", str(exc),
                                      ls.HURST_TOLERANCE))
    results.append(_smooth_check(fine_spectral_hurst(tile), prefix))
    results.append(_steep_check(steep_share(tile), prefix, tile.resolution))
    dist = slope_distribution(tile, label=label)
    return results, hurst, dist


def validate_dem(tile: DEMTile, terrain: str, *, label: str = "DEM") -> Validation:
    """Validate one DEM against a terrain type's published statistics.

    Parameters
    ----------
    tile : DEMTile
        Square pixels in metres.
    terrain : {"south-polar", "highlands", "maria"}
    label : str

    Returns
    -------
    Validation
    """
    law = ls.terrain_law(terrain)
    curve = slope_curve(tile, label=label)
    results = [_slope_curve_check([curve], law)]
    res, hurst, dist = _tile_checks(tile, law, label, "")
    results += res
    why = "a single DEM has no crater catalogue (a layer stack has one)"
    results += [not_applicable(REALISM, "crater N(>=D) vs equilibrium", why,
                               ls.CRATER_EQUILIBRIUM),
                not_applicable(REALISM, "depth/diameter of 10-100 m craters", why,
                               ls.FRESH_DEPTH_DIAMETER),
                not_applicable(REALISM, "rock abundance (rocks >= 1 m)",
                               "no rock catalogue (a layer stack built with rocks has one)",
                               ls.ROCK_ABUNDANCE)]
    results += body_checks()
    return Validation(label, terrain, results, [curve], hurst, [dist],
                      dict(period2_ratio=period2_ratio(tile), resolution_m=tile.resolution,
                           shape=list(tile.shape)))


# ------------------------------------------------------------------------------- stacks


def crater_density(catalog, extent, diameters) -> np.ndarray:
    """N(>=D) per m^2 of the catalogue's craters centred in ``extent``."""
    xmin, ymin, xmax, ymax = extent
    x, y, d = catalog.x_m, catalog.y_m, catalog.diameter_m
    sel = (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
    area = (xmax - xmin) * (ymax - ymin)
    ds = np.sort(d[sel])
    return (ds.size - np.searchsorted(ds, np.asarray(diameters), side="left")) / area


def measured_depths(tile: DEMTile, catalog, dmin: float, dmax: float) -> tuple:
    """Rim-to-floor depth of catalogue craters of ``dmin``-``dmax`` measured in ``tile``.

    Depth = mean height on the rim annulus (0.9-1.1 radii) minus the lowest height within
    half a radius, for craters wholly inside the tile and at least :data:`MIN_CRATER_PX`
    pixels across (at most :data:`MAX_CRATERS_MEASURED`, evenly sampled).

    Returns
    -------
    (diameter_m, depth_m) : (n,) float64 arrays
    """
    r = tile.resolution
    xmin, ymin, xmax, ymax = tile.bounds
    x_all, y_all, d_all = catalog.x_m, catalog.y_m, catalog.diameter_m
    sel = ((d_all >= dmin) & (d_all <= dmax) & (d_all >= MIN_CRATER_PX * r)
           & (x_all - 0.55 * d_all >= xmin) & (x_all + 0.55 * d_all <= xmax)
           & (y_all - 0.55 * d_all >= ymin) & (y_all + 0.55 * d_all <= ymax))
    idx = np.flatnonzero(sel)
    if idx.size > MAX_CRATERS_MEASURED:  # an even sample, the same every run
        idx = idx[np.linspace(0, idx.size - 1, MAX_CRATERS_MEASURED).astype(np.int64)]
    sel = np.zeros(d_all.shape, bool)
    sel[idx] = True
    z = _heights(tile)
    ny, nx = z.shape
    out_d, out_h = [], []
    for x, y, d in zip(catalog.x_m[sel], catalog.y_m[sel], catalog.diameter_m[sel],
                       strict=True):
        rows, cols = tile.rowcol(np.array([x]), np.array([y]))
        row, col = float(rows[0]), float(cols[0])
        rad = d / 2 / r
        reach = int(math.ceil(1.1 * rad)) + 1
        r0, r1 = int(row) - reach, int(row) + reach + 1
        c0, c1 = int(col) - reach, int(col) + reach + 1
        if r0 < 0 or c0 < 0 or r1 > ny or c1 > nx:
            continue
        win = z[r0:r1, c0:c1]
        yy, xx = np.mgrid[r0:r1, c0:c1]
        dist = np.hypot(yy - row, xx - col) / rad
        rim = win[(dist >= 0.9) & (dist <= 1.1)]
        floor = win[dist <= 0.5]
        if rim.size and floor.size and np.isfinite(rim).all() and np.isfinite(floor).all():
            out_d.append(d)
            out_h.append(float(rim.mean() - floor.min()))
    return np.array(out_d), np.array(out_h)


def _crater_checks(stack) -> tuple[list, dict]:
    cat = stack.catalog
    data: dict = {}
    if cat is None or len(cat.diameter_m) == 0:
        why = "the stack's crater catalogue is empty"
        return [not_applicable(REALISM, "crater N(>=D) vs equilibrium", why,
                               ls.CRATER_EQUILIBRIUM),
                not_applicable(REALISM, "depth/diameter of 10-100 m craters", why,
                               ls.FRESH_DEPTH_DIAMETER)], data
    from terrain.stack.plan import layer_bounds

    results = []
    # counts on the base, where the catalogue is complete from its smallest resolved crater
    base = stack.tiles[0]
    ext = layer_bounds(base.shape, base.transform)
    dmin = MIN_CRATER_PX * base.resolution
    ds = np.geomspace(dmin, max(dmin * 1.01, float(cat.diameter_m.max())), 12)
    n = crater_density(cat, ext, ds)
    eq = np.array([ls.equilibrium_density(d) for d in ds])
    ratio = n / eq
    data["crater_sfd"] = dict(diameter_m=ds, n_per_m2=n, equilibrium_per_m2=eq)
    stat = ls.CRATER_EQUILIBRIUM
    k = int(np.argmax(ratio))
    results.append(_judge(
        REALISM, f"crater N(>=D) over equilibrium (base, D >= {dmin:.3g} m)", ratio[k],
        stat.threshold, "<=", stat, unit="x",
        fail_meaning=(f"at D >= {ds[k]:.3g} m the base holds {ratio[k]:.3g} times the "
                      "equilibrium density: more craters than a surface can keep (new ones "
                      "erase old ones)"),
        pass_meaning=f"largest at D >= {ds[k]:.3g} m"))
    dd_d, dd_h = [], []
    for tile in stack.tiles:
        d, h = measured_depths(tile, cat, *DD_RANGE_M)
        dd_d.append(d)
        dd_h.append(h)
    d, h = np.concatenate(dd_d), np.concatenate(dd_h)
    name = f"median depth/diameter of {DD_RANGE_M[0]:g}-{DD_RANGE_M[1]:g} m craters"
    stat = ls.FRESH_DEPTH_DIAMETER
    if d.size < 5:
        results.append(not_applicable(REALISM, name, f"only {d.size} such craters resolved "
                                      f"({MIN_CRATER_PX:g} px across) in the stack", stat))
    else:
        ratio_dd = h / d
        med = float(np.median(ratio_dd))
        data["depth_diameter"] = dict(diameter_m=d, depth_m=h)
        if med < DD_MIN:
            results.append(Result(REALISM, name, "fail", med, DD_MIN, ">=", "", stat.source,
                                  stat.derivation, f"median d/D {med:.3g} is below {DD_MIN:g}: "
                                  "the craters are shallower than the most degraded lunar "
                                  "craters of this size"))
        else:
            results.append(_judge(
                REALISM, name + f" ({d.size} craters)", med, stat.threshold, "<=", stat,
                fail_meaning=(f"median d/D {med:.3g} reaches the fresh value: the population "
                              "has no degraded craters")))
    return results, data


def _rock_check(stack) -> tuple[list[Result], dict]:
    stat = ls.ROCK_ABUNDANCE
    name = "rock abundance (area under rocks >= 1 m)"
    rocks = stack.rocks
    if rocks is None or len(rocks.diameter_m) == 0:
        return [not_applicable(REALISM, name, "the stack has no rocks", stat)], {}
    from evaluation.hazards import rock_sfd
    from terrain.stack.plan import layer_bounds

    # the finest layer whose pixels resolve a 1 m rock, where the catalogue is complete
    k = max((i for i, t in enumerate(stack.tiles) if t.resolution <= 0.5), default=None)
    if k is None:
        return [not_applicable(REALISM, name, "no layer resolves a 1 m rock", stat)], {}
    tile = stack.tiles[k]
    sfd = rock_sfd(rocks, layer_bounds(tile.shape, tile.transform), 1.0)
    share = float(sfd["fractional_area"][0])
    abundance = _judge(REALISM, name + f" (layer {k})", share, stat.threshold, "<=", stat,
                       unit="fraction",
                       fail_meaning=(f"{100 * share:.3g} % of the area lies under rocks of a "
                                     "metre and more; Diviner sees that only on fresh ejecta"))
    return [abundance, _rock_density_check(sfd, k)], dict(rock_sfd=sfd, rock_layer=k)


#: Fewest rocks of 1 m the low VIPER model must expect over the measured area for a count to
#: tell a rocky surface from a bare one (Poisson: no rock at all is then below 5 % likely).
MIN_EXPECTED_ROCKS = 3.0


def _rock_density_check(sfd: dict, layer: int) -> Result:
    """Rocks of a metre and more per km^2 inside the VIPER specification's low-high band.

    The band's edges widen by two standard deviations of a Poisson count over the measured
    area, so a field drawn from an edge model passes as often as counting allows (97.7 %).
    """
    stat = ls.ROCK_DENSITY
    per_km2 = float(sfd["number_per_m2"][0]) * 1e6
    area_km2 = float(sfd["area_m2"]) / 1e6
    low0, high0 = (ls.VIPER_ROCK_MODELS[m][0] * 1e6 for m in ("low", "high"))
    name = f"rocks >= 1 m per km^2 within the VIPER low-high band (layer {layer})"
    if low0 * area_km2 < MIN_EXPECTED_ROCKS:
        return not_applicable(
            REALISM, name, f"layer {layer} covers {area_km2:.3g} km^2, where the low model "
            f"expects {low0 * area_km2:.2g} rocks of 1 m: too small to tell rocks from none",
            stat)
    low = low0 - 2.0 * math.sqrt(low0 * area_km2) / area_km2
    high = high0 + 2.0 * math.sqrt(high0 * area_km2) / area_km2
    if per_km2 < low:
        return _judge(REALISM, name, per_km2, low, ">=", stat, unit="per km^2",
                      fail_meaning=(f"{per_km2:.3g} per km^2, below the low model's {low0:.0f}: "
                                    "no metre-scale rocks where a lander meets them"))
    return _judge(REALISM, name, per_km2, high, "<=", stat, unit="per km^2",
                  fail_meaning=(f"{per_km2:.3g} per km^2, above the high model's {high0:.0f}: "
                                "rockier than the specification's rockiest site"))


def validate_stack(stack, terrain: str, *, label: str = "stack") -> Validation:
    """Validate every layer of a layer stack, its craters and its rocks.

    The slope curve pools every layer's baselines (each layer up to 8 px, the base to a
    quarter of its side), so one curve runs from the finest layer to the base.

    Parameters
    ----------
    stack : terrain.stack.model.LayerStack
    terrain : {"south-polar", "highlands", "maria"}
    label : str

    Returns
    -------
    Validation
    """
    law = ls.terrain_law(terrain)
    curves, results, hurst, dists = [], [], [], []
    per_layer = []
    for k, tile in enumerate(stack.tiles):
        name = f"layer {k}"
        curves.append(slope_curve(tile, label=f"{name} ({tile.resolution:.3g} m)",
                                  max_lag=None if k == 0 else 8))
        res, h, dist = _tile_checks(tile, law, name, f"{name}: ")
        results += res
        hurst += h
        dists.append(dist)
        per_layer.append(dict(layer=k, resolution_m=tile.resolution,
                              period2_ratio=period2_ratio(tile)))
    results.insert(0, _slope_curve_check(curves, law))
    cr, data = _crater_checks(stack)
    results += cr
    rock, rdata = _rock_check(stack)
    results += rock
    data.update(rdata)
    results += body_checks()
    data["layers"] = per_layer
    return Validation(label, terrain, results, curves, hurst, dists, data)


def compare_reference(v: Validation, tile: DEMTile, reference: DEMTile,
                      reference_label: str) -> None:
    """Add the side-by-side comparison with a real DEM to ``v`` (informational group).

    The KS distance of slope distributions at the coarser spacing (limit: two real DEMs of
    the same ground, :data:`evaluation.lunar_stats.KS_BETWEEN_REAL_DEMS`) and the robust
    Hurst exponents.
    """
    from evaluation.compare import ks_distance
    from evaluation.slope import horn_slope, matched_baseline

    stat = ls.KS_BETWEEN_REAL_DEMS
    name = f"KS distance of slopes vs {reference_label}"
    try:
        a, b = matched_baseline(tile.replace(crs=None), reference.replace(crs=None))
    except InvalidParameterError as exc:
        v.results.append(not_applicable(COMPARISON, name, f"no common baseline: {exc}", stat))
        a = None
    if a is not None:
        sa, sb = horn_slope(a), horn_slope(b)
        ks = ks_distance(sa[np.isfinite(sa)], sb[np.isfinite(sb)])
        v.results.append(_judge(
            COMPARISON, f"{name} at {a.resolution:.3g} m", ks, stat.threshold, "<=", stat,
            fail_meaning=(f"the slope distributions differ by KS {ks:.3g}, more than two real "
                          f"DEMs of the same ground ({stat.value:g})")))
    v.curves.append(slope_curve(reference, label=reference_label))
    try:
        est = hurst_estimate(reference)
        v.hurst.append((reference_label, est))
        mine = [h for lb, h in v.hurst if lb == v.label]
        if mine:
            dh = abs(mine[0].hurst - est.hurst)
            v.results.append(_judge(
                COMPARISON, f"Hurst difference vs {reference_label}", dh,
                ls.HURST_TOLERANCE.threshold, "<=", ls.HURST_TOLERANCE,
                fail_meaning=f"H {mine[0].hurst:.2f} against {est.hurst:.2f}"))
    except InvalidDEMError:
        pass
