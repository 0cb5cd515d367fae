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

import numba
import numpy as np

from evaluation import lunar_stats as ls
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.tile import DEMTile

__all__ = ["GROUPS", "HurstEstimate", "body_slope_check", "block_field_check", "boulder_check",
           "boulder_index", "facet_matched_slopes", "Result", "SlopeCurve", "Validation",
           "hurst_estimate", "not_applicable", "period2_ratio", "rock_sfd_check", "slope_curve",
           "steep_share", "validate_dem", "validate_stack"]

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


def _median_in_place(values: np.ndarray) -> float:
    """Return ``np.median(values)``, bit for bit, reordering ``values`` to find it.

    np.median partitions at both middle ranks at once, and numpy partitions at several ranks
    with a plain introselect, while a single rank takes its vectorised select: about five
    times faster on a million values. So the upper middle value is selected alone, the lower
    one is the largest value below it, and the two are averaged with np.mean as np.median
    averages them.

    Parameters
    ----------
    values : (n,) float64, finite, n >= 1
        Reordered in place. np.median would give NaN for a NaN among them; this does not
        look for one: every caller has kept only finite values.

    Returns
    -------
    float

    Examples
    --------
    >>> v = np.array([4.0, 1.0, 3.0, 2.0])
    >>> _median_in_place(v.copy()), float(np.median(v))
    (2.5, 2.5)
    """
    k = values.size // 2
    values.partition(k)
    if values.size % 2:
        # np.mean of the one middle value, as np.median takes it (it makes a -0.0 0.0)
        return float(np.mean(values[k:k + 1]))
    # the lower middle value is the largest of the k below rank k; moved next to the upper one
    j = int(np.argmax(values[:k]))
    values[j], values[k - 1] = values[k - 1], values[j]
    return float(np.mean(values[k - 1:k + 1]))


@numba.njit(cache=True, nogil=True)
def _abs_finite_diffs_into(z, lag, axis, out, start):
    # |z[r, c + lag] - z[r, c]| (axis 1) or |z[r + lag, c] - z[r, c]| (axis 0) in the
    # row-major order of numpy's sliced difference, the finite ones only (a NaN height, or a
    # difference that overflows, is left out), written to out from start; returns the end.
    # One pass where numpy made four full-size temporaries; the same IEEE subtraction.
    ny, nx = z.shape
    m = start
    if axis == 1:
        for r in range(ny):
            for c in range(nx - lag):
                d = z[r, c + lag] - z[r, c]
                if np.isfinite(d):
                    out[m] = abs(d)
                    m += 1
    else:
        for r in range(ny - lag):
            for c in range(nx):
                d = z[r + lag, c] - z[r, c]
                if np.isfinite(d):
                    out[m] = abs(d)
                    m += 1
    return m


def _abs_diffs(z: np.ndarray, lag: int, axes: tuple) -> np.ndarray:
    """Return the finite absolute height differences at ``lag`` pixels along ``axes``, pooled.

    Parameters
    ----------
    z : (ny, nx) float64, metres
        Heights, NaN where unknown (:func:`_heights`).
    lag : int
        Pixels, >= 1.
    axes : tuple of {0, 1}
        Map axes in the order pooled (1: along x, within rows; 0: along y).

    Returns
    -------
    (n,) float64, metres
        What ``np.abs(d[np.isfinite(d)])`` gives for the differences of each axis
        (``z[:, lag:] - z[:, :-lag]`` or ``z[lag:] - z[:-lag]``) concatenated.

    Examples
    --------
    >>> _abs_diffs(np.array([[0.0, 1.0, 3.0], [np.nan, 0.0, -2.0]]), 1, (1, 0)).tolist()
    [1.0, 2.0, 2.0, 1.0, 5.0]
    """
    z = np.ascontiguousarray(z, dtype=np.float64)
    ny, nx = z.shape
    out = np.empty(sum(max(0, ny * (nx - lag) if a == 1 else (ny - lag) * nx) for a in axes))
    end = 0
    for axis in axes:
        end = _abs_finite_diffs_into(z, lag, axis, out, end)
    return out[:end]


def _median_abs_diff(z: np.ndarray, lag: int, axis: int) -> float:
    d = _abs_diffs(z, lag, (axis,))
    return _median_in_place(d) if d.size else math.nan


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
    if _period2_once(tile) > 1.0:
        lags = [g for g in lags if g > 1]
        note = "one-pixel baseline dropped: period-2 pattern"
    base, med = [], []
    for lag in lags:
        d = _abs_diffs(z, lag, (1, 0))  # both map axes pooled
        if d.size < 16:
            continue
        base.append(lag * tile.resolution)
        med.append(math.degrees(math.atan(_median_in_place(d) / (lag * tile.resolution))))
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
    from evaluation.memo import radial_spectrum_of
    from evaluation.spectrum import fit_hurst

    if min(tile.shape) < 4 * SMOOTH_BAND_PX[1]:
        return None
    spec = radial_spectrum_of(tile)  # the evidence tables' spectrum of the layer, in a scope
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
    s = _horn_once(tile)
    s = s[np.isfinite(s)]
    return float(np.mean(s > angle_deg)) if s.size else math.nan


# ------------------------------------------------- measured once per tile (evaluation.memo)


def _horn_once(tile: DEMTile) -> np.ndarray:
    from evaluation.memo import horn_slope_of

    return horn_slope_of(tile)


def _distribution_once(tile: DEMTile, label: str):
    from evaluation.memo import slope_distribution_of

    return slope_distribution_of(tile, label)


def _period2_once(tile: DEMTile) -> float:
    from evaluation.memo import once

    return once("period2_ratio", tile, None, lambda: period2_ratio(tile))


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


@dataclass(frozen=True)
class HurstTarget:
    """The Hurst exponent (or range) a DEM's fit band is expected to show, and why."""

    low: float
    high: float
    what: str
    stat: ls.PublishedStat

    @classmethod
    def of_law(cls, law: ls.TerrainLaw, est: HurstEstimate) -> HurstTarget:
        """Return the terrain law's H at the centre of the fit band."""
        h = law.hurst_at(math.sqrt(est.band_m[0] * est.band_m[1]))
        return cls(h, h, f"the {law.name} law's {h:g}", ls.HURST_TOLERANCE)


def generator_hurst(tile: DEMTile) -> float | None:
    """Return H of the random midpoint displacement that made a synthetic DEM (3 - F), or None.

    Read from the metadata ``terrain synth`` records (:data:`terrain.core.metakeys.RMD`).

    >>> tile = DEMTile.from_array(np.zeros((4, 4)))
    >>> generator_hurst(tile) is None
    True
    """
    import json

    from terrain.core import metakeys as mk

    rmd = (tile.metadata or {}).get(mk.RMD)
    try:
        f = float(json.loads(rmd)["fractal_dimension"]) if rmd else None
    except (ValueError, KeyError, TypeError):
        return None
    return None if f is None else 3.0 - f  # terrain.fractal.rmd, eq. 14


def stack_hurst_target(stack, est: HurstEstimate, law: ls.TerrainLaw) -> HurstTarget:
    """Return what a stack layer's Hurst fit should show, from the scales its lags span.

    Lags of at least the base's pixel hold the base's heights (every finer layer keeps the
    coarser one's pixels): there the terrain law beyond its self-affine range applies (LOLA's
    H at kilometres), whether the base is real or synthetic. A synthetic base is more than its
    random midpoint displacement: its craters and slope relaxation raise H above the
    generator's 3 - F at these lags (docs/validation.md), so the generator's H is no target,
    only a note. Shorter lags hold what the layers added, built for the preset's law. A band
    across the base's pixel may lie anywhere between the two.
    """
    r0 = stack.tiles[0].resolution
    res = est.band_m[0] / est.lags_px[0]
    lags = np.array(est.lags_px, dtype=np.float64) * res
    at_base = lags >= r0 * (1.0 - 1e-9)
    h = law.hurst_at(float(np.exp(np.mean(np.log(lags[at_base])))) if at_base.any() else r0)
    h_gen = generator_hurst(stack.tiles[0])
    made = (f"; the base's RMD generator alone gives {h_gen:.3g} (H = 3 - F), which its craters "
            "and relaxation raise" if h_gen is not None else "")
    base = HurstTarget(h, h, f"the {law.name} law's {h:g} at the base's scales{made}",
                       ls.HURST_TOLERANCE)
    if at_base.all():
        return base
    h_law = law.hurst_at(float(np.exp(np.mean(np.log(lags[~at_base])))))
    if not at_base.any() or h_law == h:
        return HurstTarget(h_law, h_law, f"the {law.name} law's {h_law:g}", ls.HURST_TOLERANCE)
    return HurstTarget(min(base.low, h_law), max(base.high, h_law),
                       f"between the {law.name} law's {h:g} at the base's scales and its "
                       f"{h_law:g} below them (lags across the base's {r0:.3g} m pixel)",
                       ls.HURST_TOLERANCE)


def _hurst_check(est: HurstEstimate, law: ls.TerrainLaw, label: str,
                 target: HurstTarget | None = None) -> Result:
    t = target or HurstTarget.of_law(law, est)
    stat = t.stat
    dh = max(t.low - est.hurst, est.hurst - t.high, 0.0)
    want = f"{t.low:.3g}" if t.low == t.high else f"{t.low:.3g}-{t.high:.3g}"
    name = (f"{label}Hurst exponent {est.hurst:.2f} +- {est.uncertainty:.2f} (lags "
            f"{est.band_m[0]:.3g}-{est.band_m[1]:.3g} m, R^2 {est.r_squared:.2f}) vs "
            f"{want}")
    low = est.hurst < t.low
    return _judge(
        REALISM, name, dh, stat.threshold, "<=", stat,
        fail_meaning=(f"H differs from {t.what} by {dh:.2f} (limit {stat.threshold:g}): "
                      + ("heights are too rough at small scales relative to large ones, like a "
                         "random walk (H 0.5), not lunar regolith and craters"
                         if low else "the surface is smoother at small scales than "
                         "it should be")) + (f"; {est.note}" if est.note else ""),
        pass_meaning="; ".join(x for x in (f"expected {t.what}", est.note) if x))


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


def _tile_checks(tile: DEMTile, law, label: str, prefix: str, *, steep: bool = True,
                 target=None):
    results, hurst = [], []
    try:
        est = hurst_estimate(tile)
        hurst.append((label, est))
        results.append(_hurst_check(est, law, prefix, target(est) if target else None))
    except InvalidDEMError as exc:
        results.append(not_applicable(REALISM, f"{prefix}Hurst exponent", str(exc),
                                      ls.HURST_TOLERANCE))
    results.append(_smooth_check(fine_spectral_hurst(tile), prefix))
    if steep:
        results.append(_steep_check(steep_share(tile), prefix, tile.resolution))
    dist = _distribution_once(tile, label)
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


#: Fewest craters the equilibrium must expect over the base at a diameter for that diameter's
#: count to be judged: Poisson's standard deviation is then at most 18 % of it, and a base at
#: equilibrium reads below half or above twice it at any one size less than 0.3 % of the time.
MIN_EQUILIBRIUM_CRATERS = 30.0


def _base_crater_check(stack, base_catalog) -> tuple[Result, dict]:
    """Judge the base's crater counts N(>=D) against the empirical equilibrium.

    Counted over the base's whole extent from :data:`MIN_CRATER_PX` base pixels up to the
    largest diameter at which the equilibrium expects :data:`MIN_EQUILIBRIUM_CRATERS` craters.
    The counts come from the base's own catalogue (``base_catalog``, e.g. the
    ``base_craters.csv`` written by ``terrain synth``); a stack's catalogue lists only the
    craters its layers added.
    """
    from terrain.core.presets import TRASK_EQUILIBRIUM
    from terrain.stack.plan import layer_bounds

    stat = ls.CRATER_EQUILIBRIUM
    base = stack.tiles[0]
    ext = layer_bounds(base.shape, base.transform)
    area = (ext[2] - ext[0]) * (ext[3] - ext[1])
    dmin = MIN_CRATER_PX * base.resolution
    name = f"crater N(>=D) over equilibrium (base, D >= {dmin:.3g} m)"
    cat, which = base_catalog, "the base's catalogue"
    if cat is None:
        cat, which = stack.catalog, "the stack's catalogue"
        if cat is None or not np.any(cat.diameter_m >= dmin):
            return not_applicable(
                REALISM, name, f"no base crater catalogue given, and the stack's catalogue "
                f"holds no crater of {dmin:.3g} m or more (the base's resolved size): it lists "
                "only the craters the layers added", stat), {}
    # the equilibrium expects MIN_EQUILIBRIUM_CRATERS craters over the base at d_top
    d_top = math.sqrt(TRASK_EQUILIBRIUM * area / MIN_EQUILIBRIUM_CRATERS)
    if d_top <= dmin:
        return not_applicable(REALISM, name, f"the base ({area / 1e6:.3g} km^2) expects "
                              f"fewer than {MIN_EQUILIBRIUM_CRATERS:g} craters of {dmin:.3g} m",
                              stat), {}
    ds = np.geomspace(dmin, d_top, 12)
    n = crater_density(cat, ext, ds)
    eq = np.array([ls.equilibrium_density(d) for d in ds])
    ratio = n / eq
    data = dict(diameter_m=ds, n_per_m2=n, equilibrium_per_m2=eq, catalogue=which)
    k = int(np.argmax(np.maximum(ratio, 1.0 / np.maximum(ratio, 1e-12))))
    detail = (f"{which}: {ratio.min():.3g}-{ratio.max():.3g} x from {dmin:.3g} m to "
              f"{d_top:.3g} m ({int(round(n[0] * area))} craters of {dmin:.3g} m or more)")
    if ratio[k] < 1.0:
        return _judge(REALISM, name, ratio[k], 1.0 / stat.threshold, ">=", stat, unit="x",
                      fail_meaning=(f"at D >= {ds[k]:.3g} m the base holds {ratio[k]:.3g} times "
                                    f"the equilibrium density, too few craters; {detail}"),
                      pass_meaning=detail), data
    return _judge(REALISM, name, ratio[k], stat.threshold, "<=", stat, unit="x",
                  fail_meaning=(f"at D >= {ds[k]:.3g} m the base holds {ratio[k]:.3g} times the "
                                "equilibrium density: more craters than a surface can keep (new "
                                f"ones erase old ones); {detail}"),
                  pass_meaning=detail), data


def _crater_checks(stack, base_catalog=None) -> tuple[list, dict]:
    cat = stack.catalog
    data: dict = {}
    base_check, sfd = _base_crater_check(stack, base_catalog)
    if sfd:
        data["crater_sfd"] = sfd
    if cat is None or len(cat.diameter_m) == 0:
        why = "the stack's crater catalogue is empty"
        return [base_check if base_catalog is not None else
                not_applicable(REALISM, "crater N(>=D) vs equilibrium", why,
                               ls.CRATER_EQUILIBRIUM),
                not_applicable(REALISM, "depth/diameter of 10-100 m craters", why,
                               ls.FRESH_DEPTH_DIAMETER)], data
    results = [base_check]
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

    # the widest layer complete at 1 m (every rock layer holds the rocks it resolves)
    figures = _rocks_1m(stack)
    if figures is None:
        return [not_applicable(REALISM, name, "no layer resolves a 1 m rock", stat)], {}
    k = figures["layer"]
    tile = stack.tiles[k]
    sfd = rock_sfd(rocks, layer_bounds(tile.shape, tile.transform), 1.0)
    share = float(sfd["fractional_area"][0])
    abundance = _judge(REALISM, name + f" (layer {k})", share, stat.threshold, "<=", stat,
                       unit="fraction",
                       fail_meaning=(f"{100 * share:.3g} % of the area lies under rocks of a "
                                     "metre and more; Diviner sees that only on fresh ejecta"))
    return [abundance, _rock_density_check(sfd, k)], dict(rock_sfd=sfd, rock_layer=k,
                                                           rocks_1m=figures)


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


# ------------------------------------------------------------------ the preset's figures

#: Baselines (m) of the slope table: centimetres to a kilometre.
SLOPE_TABLE_M = (0.03, 0.3, 1.0, 5.0, 17.0, 57.0, 225.0, 1000.0)
#: Baselines (m) over which a terrain built for a law must match it within a degree.
LAW_RANGE_M = (17.0, 1000.0)
#: Fewest pixels a baseline spans in the layer it is measured on, where a layer allows it.
MIN_LAG_PX = 4
#: Craters younger than this (Gyr) may keep walls steeper than repose.
YOUNG_GYR = 0.1
#: The cells within this many radii of a young crater's centre are its walls and rim.
YOUNG_REACH = 1.2
#: Largest baseline (m) still counted as a centimetre scale of the regolith check.
REGOLITH_MAX_M = 0.05


def _plane_removed(z: np.ndarray) -> np.ndarray:
    """Heights less their least-squares plane (the site's tilt)."""
    ny, nx = z.shape
    yy, xx = np.mgrid[0:ny, 0:nx]
    ok = np.isfinite(z)
    a = np.column_stack([xx[ok], yy[ok], np.ones(int(ok.sum()))]).astype(np.float64)
    coef, *_ = np.linalg.lstsq(a, z[ok].astype(np.float64), rcond=None)
    return z - (coef[0] * xx + coef[1] * yy + coef[2])


def baseline_slopes(tile: DEMTile, lag: int) -> tuple[float, float]:
    """Median and RMS bidirectional slope (degrees) at ``lag`` pixels, both map axes pooled.

    The median is of the heights as they are (LOLA's slope maps); the RMS is of the heights
    less their plane (the site's tilt removed), as roughness at a scale is quoted.

    >>> g = 0.5 * np.arange(32.0)
    >>> [round(v, 1) for v in baseline_slopes(DEMTile.from_array(np.add.outer(g, g)), 2)]
    [26.6, 0.0]
    """
    z = _heights(tile)
    length = lag * tile.resolution

    def diffs(a):
        d = np.concatenate([(a[:, lag:] - a[:, :-lag]).ravel(),
                            (a[lag:, :] - a[:-lag, :]).ravel()])
        return d[np.isfinite(d)]

    raw, flat = diffs(z), diffs(_plane_removed(z))
    if raw.size < 16:
        return math.nan, math.nan
    med = math.degrees(math.atan(_median_in_place(np.abs(raw)) / length))
    rms = math.degrees(math.atan(math.sqrt(float(np.mean(flat**2))) / length))
    return med, rms


def median_2d_slope(tile: DEMTile, lag: int) -> float:
    """Median 2-D slope (degrees) at ``lag`` pixels: the gradient over one baseline each way.

    At every pixel the height differences to the pixels ``lag`` away along x and along y
    give the gradient, atan(hypot(dz_x, dz_y) / L). For an isotropic surface with Gaussian
    differences this is about 1.75 times the bidirectional median (in tangent): the ratio
    of the Rayleigh median (1.177 sigma) to the half-normal one (0.674 sigma).

    >>> g = 0.5 * np.arange(32.0)
    >>> round(median_2d_slope(DEMTile.from_array(np.add.outer(g, g)), 2), 1)  # sqrt(2) * 0.5
    35.3
    """
    z = _heights(tile)
    dx = z[:-lag, lag:] - z[:-lag, :-lag]
    dy = z[lag:, :-lag] - z[:-lag, :-lag]
    g = np.hypot(dx, dy)
    g = g[np.isfinite(g)]
    if g.size < 16:
        return math.nan
    return math.degrees(math.atan(_median_in_place(g) / (lag * tile.resolution)))


def stack_slope_table(stack, baselines=SLOPE_TABLE_M) -> list[dict]:
    """Median and RMS slope of a layer stack at each baseline, each from the layer fit for it.

    A baseline is measured on the coarsest layer (the widest area) where it spans at least
    :data:`MIN_LAG_PX` pixels, or else on the finest layer, and never on a layer narrower
    than four baselines.

    Returns
    -------
    list of dict
        ``baseline_m`` (as measured: whole pixels), ``layer``, ``lag_px``, ``median_deg``
        (bidirectional, the law's measure), ``rms_deg`` (plane removed) and
        ``median_2d_deg`` (:func:`median_2d_slope`); baselines no layer holds are left out.
    """
    rows = []
    tiles = list(enumerate(stack.tiles))
    for want in baselines:
        fits = [(k, t, max(1, int(round(want / t.resolution)))) for k, t in tiles]
        fits = [(k, t, lag) for k, t, lag in fits if 4 * lag <= min(t.shape)
                and abs(lag * t.resolution / want - 1.0) <= 0.35]
        if not fits:
            continue
        wide = [f for f in fits if f[2] >= MIN_LAG_PX]
        # layers run from the base (0, coarsest) to the finest
        k, tile, lag = (min(wide, key=lambda f: f[0]) if wide
                        else max(fits, key=lambda f: f[0]))
        med, rms = baseline_slopes(tile, lag)
        rows.append(dict(baseline_m=lag * tile.resolution, layer=k, lag_px=lag,
                         median_deg=med, rms_deg=rms,
                         median_2d_deg=median_2d_slope(tile, lag)))
    return rows


def _law_slope_check(table: list[dict], law: ls.TerrainLaw) -> Result:
    stat = ls.SLOPE_LAW_DEG
    lo, hi = LAW_RANGE_M
    name = (f"median slope at {lo:g} m - {hi:g} m within {stat.threshold:g} deg of the "
            f"{law.name} law")
    rows = [r for r in table if lo * 0.9 <= r["baseline_m"] <= hi * 1.1
            and np.isfinite(r["median_deg"])]
    if not rows:
        return not_applicable(REALISM, name, "no layer holds those baselines", stat)
    diff = [r["median_deg"] - float(law.median_slope_deg(r["baseline_m"])) for r in rows]
    k = int(np.argmax(np.abs(diff)))
    r = rows[k]
    detail = ", ".join(f"{x['baseline_m']:.3g} m: {x['median_deg']:.2f} vs "
                       f"{float(law.median_slope_deg(x['baseline_m'])):.2f}" for x in rows)
    return _judge(REALISM, name, abs(diff[k]), stat.threshold, "<=", stat, unit="deg",
                  fail_meaning=(f"at {r['baseline_m']:.3g} m (layer {r['layer']}) the median "
                                f"slope is {r['median_deg']:.2f} deg, {abs(diff[k]):.2f} deg "
                                + ("steeper" if diff[k] > 0 else "smoother")
                                + f" than the law ({detail})"),
                  pass_meaning=detail)


def _regolith_check(table: list[dict]) -> Result:
    stat = ls.REGOLITH_RMS_SLOPE
    name = "RMS slope at the finest centimetre baseline (plane removed), 10-20 deg"
    fine = [r for r in table if r["baseline_m"] <= REGOLITH_MAX_M and np.isfinite(r["rms_deg"])]
    if not fine:
        return not_applicable(REALISM, name, f"no layer of {100 * REGOLITH_MAX_M:g} cm or "
                              "finer", stat)
    r = min(fine, key=lambda x: x["baseline_m"])
    metre = [x for x in table if abs(math.log(x["baseline_m"])) < 0.4]
    rise = (f"; {metre[0]['rms_deg']:.3g} deg at {metre[0]['baseline_m']:.3g} m"
            if metre else "")
    value, low, high = r["rms_deg"], stat.value - stat.scatter, stat.value + stat.scatter
    where = f"{value:.3g} deg at {100 * r['baseline_m']:.2g} cm (layer {r['layer']}){rise}"
    if value > high:
        return _judge(REALISM, name, value, high, "<=", stat, unit="deg",
                      fail_meaning=f"{where}: rougher than measured regolith")
    return _judge(REALISM, name, value, low, ">=", stat, unit="deg",
                  fail_meaning=(f"{where}: the regolith is smoother at centimetres than "
                                "measured (10-20 deg)"), pass_meaning=where)


def young_crater_mask(tile: DEMTile, catalog, *, young_gyr: float = YOUNG_GYR,
                      reach: float = YOUNG_REACH) -> np.ndarray:
    """Cells of ``tile`` within ``reach`` radii of a crater younger than ``young_gyr``.

    >>> from terrain.craters.catalog import CraterCatalog
    >>> young_crater_mask(DEMTile.from_array(np.zeros((8, 8))), CraterCatalog.empty()).any()
    np.False_
    """
    import cv2

    mask = np.zeros(tile.shape, np.uint8)
    if catalog is None or len(catalog.diameter_m) == 0:
        return mask.astype(bool)
    xmin, ymin, xmax, ymax = tile.bounds
    d, x, y = catalog.diameter_m, catalog.x_m, catalog.y_m
    rad = reach * d / 2
    sel = ((catalog.age_gyr < young_gyr) & (x + rad >= xmin) & (x - rad <= xmax)
           & (y + rad >= ymin) & (y - rad <= ymax) & (rad >= 0.5 * tile.resolution))
    rows, cols = tile.rowcol(x[sel], y[sel])
    for r, c, rr in zip(rows, cols, rad[sel] / tile.resolution, strict=True):
        cv2.circle(mask, (int(round(c)), int(round(r))), int(math.ceil(rr)), 1, -1)
    return mask.astype(bool)


def _joined_craters(*catalogs):
    """Return the position, size and age columns of several crater catalogues as one.

    A catalogue without ages counts as old (no crater of it is known to be young).
    """
    from types import SimpleNamespace

    cats = [c for c in catalogs if c is not None and len(c.diameter_m)]
    if not cats:
        return None

    def column(c, k):
        v = getattr(c, k, None)
        return np.full(len(c.diameter_m), np.inf) if v is None else np.asarray(v, np.float64)

    return SimpleNamespace(**{k: np.concatenate([column(c, k) for c in cats])
                              for k in ("x_m", "y_m", "diameter_m", "age_gyr")})


def _steep_old_check(tile: DEMTile, catalog, label: str) -> Result:
    stat = ls.STEEP_OLD_TERRAIN
    s = _horn_once(tile)
    keep = np.isfinite(s) & ~young_crater_mask(tile, catalog)
    if not keep.any():
        return not_applicable(REALISM, f"{label}area steeper than {REPOSE_DEG:g} deg at "
                              f"{tile.resolution:.3g} m outside craters younger than "
                              f"{1000 * YOUNG_GYR:g} Myr", "every cell lies on a young crater",
                              stat)
    share = float(np.mean(s[keep] > REPOSE_DEG))
    return _judge(
        REALISM, f"{label}area steeper than {REPOSE_DEG:g} deg at {tile.resolution:.3g} m "
        f"outside craters younger than {1000 * YOUNG_GYR:g} Myr", share, stat.threshold, "<=",
        stat, unit="fraction",
        fail_meaning=(f"{100 * share:.3g} % of the old terrain stands steeper than repose "
                      f"({100 * stat.threshold:g} % allowed): old slopes have not relaxed"))


def _visible_depth_check(d: np.ndarray, h: np.ndarray) -> tuple[Result, dict]:
    stat = ls.SMALL_CRATER_DD
    name = f"mean depth/diameter of visible {DD_RANGE_M[0]:g}-{DD_RANGE_M[1]:g} m craters"
    if d.size < 5:
        return not_applicable(REALISM, name, f"only {d.size} such craters resolved "
                              f"({MIN_CRATER_PX:g} px across) in the stack", stat), {}
    dd = h / d
    figures = dict(mean=float(dd.mean()), p10=float(np.percentile(dd, 10)),
                   p90=float(np.percentile(dd, 90)), craters=int(dd.size))
    where = (f"mean {figures['mean']:.3g}, p10 {figures['p10']:.3g}, p90 {figures['p90']:.3g} "
             f"({dd.size} craters)")
    mean, low, high = figures["mean"], stat.value - stat.threshold, stat.value + stat.threshold
    if mean > high:
        return _judge(REALISM, name, mean, high, "<=", stat,
                      fail_meaning=f"{where}: deeper than the Moon's small craters"), figures
    return _judge(REALISM, name, mean, low, ">=", stat,
                  fail_meaning=(f"{where}: shallower than the Moon's visible small craters "
                                "(degraded craters are kept past visibility)"),
                  pass_meaning=where), figures


#: The diameter (m) of the small-crater density figure.
SMALL_CRATER_M = 10.0


def _small_crater_density(stack, terrain: str) -> tuple[Result, dict]:
    from terrain.core.presets import preset
    from terrain.stack.plan import layer_bounds

    stat = ls.CRATER_EQUILIBRIUM
    name = f"visible craters N(>={SMALL_CRATER_M:g} m) per km^2 over the {terrain} equilibrium"
    cat = stack.catalog
    k = min((i for i, t in enumerate(stack.tiles)
             if t.resolution * MIN_CRATER_PX <= SMALL_CRATER_M), default=None)
    if cat is None or k is None:
        return not_applicable(REALISM, name, f"no layer resolves {SMALL_CRATER_M:g} m craters "
                              "or no catalogue", stat), {}
    tile = stack.tiles[k]
    n = float(crater_density(cat, layer_bounds(tile.shape, tile.transform),
                             [SMALL_CRATER_M])[0])
    eq = preset(terrain).crater_equilibrium * ls.equilibrium_density(SMALL_CRATER_M)
    ratio = n / eq
    figures = dict(per_km2=n * 1e6, equilibrium_per_km2=eq * 1e6, layer=k)
    where = (f"{n * 1e6:.4g} per km^2 in layer {k} against {eq * 1e6:.4g} (ratio "
             f"{ratio:.2g})")
    if ratio < 1.0 / stat.threshold:
        return _judge(REALISM, name, ratio, 1.0 / stat.threshold, ">=", stat, unit="x",
                      fail_meaning=f"{where}: too few small craters survive"), figures
    return _judge(REALISM, name, ratio, stat.threshold, "<=", stat, unit="x",
                  fail_meaning=f"{where}: more craters than the surface keeps",
                  pass_meaning=where), figures


#: Rock sizes of the SFD check per decade (log-spaced from the smallest complete size).
ROCK_SFD_PER_DECADE = 4
#: Largest rock size (m) judged against the VIPER law: the generator stops the law at
#: :data:`terrain.surface.rocks.VIPER_DMAX` (5 m, "several metres"), which lowers N(>=D)
#: below the law by (D / 5 m)^-b, under 3 % (nominal and high) up to a quarter of it.
ROCK_SFD_MAX_M = 1.25
#: Fewest rocks the model must expect at a size for that size to be judged (Poisson: the
#: count's standard deviation is then at most a third of it).
ROCK_SFD_MIN_EXPECTED = 10.0
#: Tolerance of the rock SFD: the law within 15 %, plus this many Poisson standard deviations
#: of the count the model expects at that size (a field drawn from the law passes each size
#: at least 97.7 % of the time; on large areas the 15 % dominates).
ROCK_SFD_SIGMAS = 2.0


def rock_layers(stack) -> list[int]:
    """Return the layers whose rock catalogue is complete: the coarsest holding a rock and finer.

    A layer stack stands on every rock layer each rock at least
    :data:`terrain.surface.rocks.MIN_ROCK_PIXELS` of its pixels across, over the layer's whole
    extent, and records a rock once, with the coarsest layer that holds it: so from the
    coarsest layer any rock is recorded with, every finer layer is complete too.
    """
    rocks = stack.rocks
    if rocks is None or len(rocks.diameter_m) == 0:
        return []
    layer = getattr(rocks, "layer", None)
    first = int(np.min(layer)) if layer is not None and len(layer) else 0
    return list(range(first, len(stack.tiles)))


def pooled_rock_counts(stack, diameters, fields=None) -> list[dict]:
    """N(>=D) of a stack's rocks, each size counted on the widest layer complete for it.

    For each diameter D the layer is the coarsest of :func:`rock_layers` whose pixels resolve
    D (:data:`terrain.surface.rocks.MIN_ROCK_PIXELS` pixels across); every rock of D or more
    centred in that layer's whole extent is counted.

    Parameters
    ----------
    stack : terrain.stack.model.LayerStack
    diameters : sequence of float, metres
    fields : (BlockSite, FreshCraters), optional
        Fresh craters' block fields (:mod:`evaluation.blockfields`): each row then also
        splits the count and the area into inside and outside the fields' footprints.

    Returns
    -------
    list of dict
        ``diameter_m``, ``layer``, ``area_m2``, ``count`` and ``per_m2`` per size a layer
        resolves (sizes none resolves are left out); with ``fields``, also
        ``field_area_m2``, ``field_count`` (inside the footprints), ``outside_area_m2`` and
        ``outside_count``.
    """
    from evaluation.blockfields import footprint_area, in_footprints
    from terrain.stack.plan import layer_bounds
    from terrain.surface.rocks import MIN_ROCK_PIXELS

    layers = rock_layers(stack)
    rocks = stack.rocks
    out = []
    for d in np.asarray(diameters, dtype=np.float64):
        fits = [k for k in layers
                if MIN_ROCK_PIXELS * stack.tiles[k].resolution <= d * (1.0 + 1e-9)]
        if not fits:
            continue
        k = min(fits)
        t = stack.tiles[k]
        extent = layer_bounds(t.shape, t.transform)
        xmin, ymin, xmax, ymax = extent
        area = (xmax - xmin) * (ymax - ymin)
        sel = np.flatnonzero((rocks.x_m >= xmin) & (rocks.x_m <= xmax)
                             & (rocks.y_m >= ymin) & (rocks.y_m <= ymax)
                             & (rocks.diameter_m >= d * (1.0 - 1e-9)))
        row = dict(diameter_m=float(d), layer=k, area_m2=float(area), count=int(sel.size),
                   per_m2=sel.size / area)
        if fields is not None:
            site, craters = fields
            near = craters.touching(extent, site)
            inside = int(np.count_nonzero(in_footprints(near, site, rocks.x_m[sel],
                                                        rocks.y_m[sel])))
            f_area = footprint_area(near, site, extent)
            row.update(field_area_m2=f_area, field_count=inside,
                       outside_area_m2=float(area) - f_area, outside_count=int(sel.size) - inside)
        out.append(row)
    return out


def block_fields_of(stack, terrain: str):
    """Return the (BlockSite, FreshCraters) of a stack's block fields, or None.

    None where the stack has no crater catalogue or its rock model drew no fields; the site
    (regolith, reach, cover) is the rock model the stack recorded, the terrain preset's
    regolith where it recorded none.
    """
    from evaluation.blockfields import BlockSite, FreshCraters
    from terrain.core.presets import preset

    catalog = getattr(stack, "catalog", None)
    if catalog is None or not len(catalog.diameter_m) or getattr(catalog, "age_gyr",
                                                                   None) is None:
        return None
    site = BlockSite.of_stack(stack, preset(terrain).regolith_m)
    if not site.enabled:
        return None
    craters = FreshCraters.of_catalog(catalog, site)
    return (site, craters) if len(craters) else None


def _sfd_judgement(rows, name: str, stat, count_key: str, expect_key: str, what: str):
    """Judge measured/expected counts per size: within 15 % plus 2 Poisson sigmas."""
    ratio = np.array([r[count_key] / r[expect_key] for r in rows])
    tol = np.array([stat.threshold + ROCK_SFD_SIGMAS / math.sqrt(r[expect_key]) for r in rows])
    j = int(np.argmax(np.abs(ratio - 1.0) - tol))
    detail = ", ".join(f"{r['diameter_m']:.2g} m (layer {r['layer']}): {r[count_key]} vs "
                       f"{r[expect_key]:.1f}" for r in rows)
    return _judge(REALISM, name + f" ({rows[0]['diameter_m']:.2g}-{rows[-1]['diameter_m']:.2g}"
                  " m, each size on the widest layer resolving it)", abs(ratio[j] - 1.0),
                  float(tol[j]), "<=", stat,
                  fail_meaning=(f"N(>={rows[j]['diameter_m']:.2g} m) is {ratio[j]:.2g} times "
                                f"{what} ({detail})"), pass_meaning=detail)


def rock_sfd_check(stack, terrain: str) -> tuple[Result, dict]:
    """Judge the background rocks' N(>=D) over at least a decade of size against the VIPER law.

    Each size is counted on the widest layer complete for it (:func:`pooled_rock_counts`),
    from the smallest complete size up to :data:`ROCK_SFD_MAX_M`, at
    :data:`ROCK_SFD_PER_DECADE` sizes a decade, where the model expects at least
    :data:`ROCK_SFD_MIN_EXPECTED` rocks. Where the stack's crater catalogue holds fresh
    craters with block fields (:func:`block_fields_of`), only the rocks outside their
    footprints are background, counted over the area outside them; the rest are judged by
    :func:`block_field_check`. The model is the law as drawn: N(>=D) - N(>=5 m)
    (:data:`terrain.surface.rocks.VIPER_DMAX`). Each measured/model ratio may miss 1 by 15 %
    plus :data:`ROCK_SFD_SIGMAS` Poisson standard deviations of the expected count.
    """
    from terrain.core.presets import preset
    from terrain.surface.rocks import MIN_ROCK_PIXELS, VIPER_DMAX

    stat = ls.ROCK_SFD
    model = preset(terrain).rock_model
    fields = block_fields_of(stack, terrain)
    name = (f"background rock N(>=D) outside fresh craters' block fields against the {model} "
            "model" if fields else f"rock N(>=D) over a decade of size against the {model} model")
    layers = rock_layers(stack)
    if not layers:
        return not_applicable(REALISM, name, "the stack has no rocks", stat), {}
    d0 = MIN_ROCK_PIXELS * stack.tiles[layers[-1]].resolution
    if d0 >= ROCK_SFD_MAX_M:
        return not_applicable(REALISM, name, f"the finest layer resolves rocks of {d0:.3g} m "
                              f"and more only: no decade of size below {ROCK_SFD_MAX_M:g} m",
                              stat), {}
    n = int(math.floor(ROCK_SFD_PER_DECADE * math.log10(ROCK_SFD_MAX_M / d0) + 1e-9)) + 1
    ds = d0 * 10.0 ** (np.arange(n) / ROCK_SFD_PER_DECADE)
    rows = pooled_rock_counts(stack, ds, fields)
    for r in rows:
        law = float(ls.viper_cumulative(model, r["diameter_m"])
                    - ls.viper_cumulative(model, VIPER_DMAX))
        r["model_count"] = law * r["area_m2"]
        if fields:
            r["outside_model_count"] = law * r["outside_area_m2"]
            r["field_background_count"] = law * r["field_area_m2"]
    counted, expected = (("outside_count", "outside_model_count") if fields
                         else ("count", "model_count"))
    figures = dict(rows=rows, model=model, fields=bool(fields),
                   fresh_craters=len(fields[1]) if fields else 0)
    judged = [r for r in rows if r[expected] >= ROCK_SFD_MIN_EXPECTED]
    if not judged or judged[-1]["diameter_m"] < 10.0 * judged[0]["diameter_m"] * (1 - 1e-9):
        span = (f"{judged[0]['diameter_m']:.3g}-{judged[-1]['diameter_m']:.3g} m" if judged
                else "no size")
        return not_applicable(REALISM, name, f"the layers count {span} with at least "
                              f"{ROCK_SFD_MIN_EXPECTED:g} rocks expected: less than a decade",
                              stat), figures
    for r in judged:
        r["ratio"] = r[counted] / r[expected]
    return _sfd_judgement(judged, name, stat, counted, expected, "the model's"), figures


def block_field_check(stack, terrain: str, figures: dict) -> Result:
    """Judge the rocks inside fresh craters' footprints against background plus blocks.

    Per size of :func:`rock_sfd_check`'s rows: the rocks of D and more centred in the
    footprints against the VIPER law over the footprints' area plus the blocks the crater
    catalogue and the published calibration expect there
    (:func:`evaluation.blockfields.expected_blocks`), wherever that sum is at least
    :data:`ROCK_SFD_MIN_EXPECTED`; within 15 % plus :data:`ROCK_SFD_SIGMAS` Poisson standard
    deviations (a field's count is Poisson given the catalogue).
    """
    from evaluation.blockfields import expected_blocks
    from terrain.stack.plan import layer_bounds

    stat = ls.BLOCK_FIELDS
    model = figures.get("model") or "VIPER"
    name = (f"rock N(>=D) inside fresh craters' block fields against the {model} model plus "
            "the blocks the crater catalogue and the Linne calibration expect")
    fields = block_fields_of(stack, terrain)
    if not fields or not figures.get("rows"):
        why = ("no fresh crater of the catalogue has a block field" if not fields
               else "no rock size counted")
        return not_applicable(REALISM, name, why, stat)
    site, craters = fields
    rows = []
    for r in figures["rows"]:
        t = stack.tiles[r["layer"]]
        r["expected_blocks"] = expected_blocks(craters, site, layer_bounds(t.shape, t.transform),
                                               r["diameter_m"])
        r["field_model_count"] = r["field_background_count"] + r["expected_blocks"]
        if r["field_model_count"] >= ROCK_SFD_MIN_EXPECTED:
            r["field_ratio"] = r["field_count"] / r["field_model_count"]
            rows.append(r)
    if not rows:
        return not_applicable(REALISM, name, f"no size has {ROCK_SFD_MIN_EXPECTED:g} rocks "
                              "expected inside the block fields of the counted layers", stat)
    return _sfd_judgement(rows, name, stat, "field_count", "field_model_count",
                          "background plus blocks")


def _rocks_1m(stack) -> dict | None:
    """Rocks of a metre and more per km^2 on the widest layer complete at 1 m, largest rock."""
    rows = pooled_rock_counts(stack, [1.0])
    if not rows:
        return None
    r = rows[0]
    rocks = stack.rocks
    i = int(np.argmax(rocks.diameter_m))
    layer = getattr(rocks, "layer", None)
    return dict(layer=r["layer"], per_km2=r["per_m2"] * 1e6, count=r["count"],
                area_km2=r["area_m2"] / 1e6, largest_m=float(rocks.diameter_m[i]),
                largest_layer=int(layer[i]) if layer is not None else None)


def preset_figures(v: Validation) -> list[tuple[str, object]]:
    """Return the figures a terrain preset is judged by, as (quantity, value) rows.

    Median and RMS slope at each baseline of :data:`SLOPE_TABLE_M` against the law, the
    share steeper than 35 deg per layer outside young craters, the visible small craters'
    depth/diameter and density, and the rocks' density, largest size and SFD.
    """
    law = ls.terrain_law(v.terrain)
    rows: list[tuple[str, object]] = []
    for r in v.data.get("slope_table", []):
        rows.append((f"median bidirectional slope at {r['baseline_m']:.3g} m (layer "
                     f"{r['layer']}), deg; law {float(law.median_slope_deg(r['baseline_m'])):.3g}",
                     round(r["median_deg"], 3)))
        if "median_2d_deg" in r:
            rows.append((f"median 2-D slope at {r['baseline_m']:.3g} m, deg",
                         round(r["median_2d_deg"], 3)))
        rows.append((f"RMS slope, plane removed, at {r['baseline_m']:.3g} m, deg",
                     round(r["rms_deg"], 3)))
    for k, share in v.data.get("steep_old", []):
        rows.append((f"layer {k}: share steeper than 35 deg outside craters < 100 Myr",
                     share))
    dd = v.data.get("visible_dd")
    if dd:
        rows += [("visible 10-100 m craters: d/D mean", dd["mean"]),
                 ("visible 10-100 m craters: d/D p10", dd["p10"]),
                 ("visible 10-100 m craters: d/D p90", dd["p90"]),
                 ("visible 10-100 m craters measured", dd["craters"])]
    dens = v.data.get("small_craters")
    if dens:
        rows.append((f"craters N(>=10 m) per km^2 (layer {dens['layer']}); equilibrium "
                     f"{dens['equilibrium_per_km2']:.4g}", dens["per_km2"]))
    rk = v.data.get("rocks_1m")
    if rk:
        rows.append((f"rocks N(>=1 m) per km^2 (layer {rk['layer']}, {rk['area_km2']:.3g} "
                     "km^2)", rk["per_km2"]))
        rows.append(("largest rock, m", rk["largest_m"]))
        if rk.get("largest_layer") is not None:
            rows[-1] = (f"largest rock, m (layer {rk['largest_layer']})", rk["largest_m"])
    sfd = v.data.get("rock_model_sfd") or {}
    for r in sfd.get("rows", []):
        where = f"on layer {r['layer']}"
        if not sfd.get("fields"):
            rows.append((f"rocks N(>={r['diameter_m']:.2g} m) per km^2 {where} "
                         f"({r['area_m2'] / 1e6:.3g} km^2, {r['count']} rocks): measured / "
                         f"{sfd['model']}", f"{r['per_m2'] * 1e6:.4g} / "
                         f"{r['model_count'] / r['area_m2'] * 1e6:.4g}"))
            continue
        out_km2 = r["outside_area_m2"] / 1e6
        rows.append((f"rocks N(>={r['diameter_m']:.2g} m) per km^2 {where} outside block "
                     f"fields ({out_km2:.3g} of {r['area_m2'] / 1e6:.3g} km^2, "
                     f"{r['outside_count']} rocks): measured / {sfd['model']}",
                     f"{r['outside_count'] / max(out_km2, 1e-300):.4g} / "
                     f"{r['outside_model_count'] / max(out_km2, 1e-300):.4g}"
                     if out_km2 > 0 else "no area outside the fields"))
        if r["field_area_m2"] > 0 and "field_model_count" in r:
            rows.append((f"rocks >= {r['diameter_m']:.2g} m {where} inside block fields "
                         f"({r['field_area_m2'] / 1e6:.3g} km^2): measured / {sfd['model']} "
                         "+ expected blocks",
                         f"{r['field_count']} / {r['field_background_count']:.4g} + "
                         f"{r['expected_blocks']:.4g}"))
    return rows


def validate_stack(stack, terrain: str, *, label: str = "stack",
                   base_catalog=None) -> Validation:
    """Validate every layer of a layer stack, its craters and its rocks.

    The slope curve pools every layer's baselines (each layer up to 8 px, the base to a
    quarter of its side), so one curve runs from the finest layer to the base; it is drawn,
    not judged: slopes are judged on the layer fit for each baseline
    (:func:`stack_slope_table`): within a degree of the law from 17 m to 1 km, and by the
    plane-removed RMS at centimetres.

    Parameters
    ----------
    stack : terrain.stack.model.LayerStack
    terrain : {"south-polar", "highlands", "maria"}
    label : str
    base_catalog : terrain.craters.catalog.CraterCatalog, optional
        The base's own crater catalogue (``terrain synth --catalog``), which the base's
        crater counts are judged by; the stack's catalogue lists only the craters its
        layers added.

    Returns
    -------
    Validation
    """
    law = ls.terrain_law(terrain)
    curves, results, hurst, dists = [], [], [], []
    per_layer, steep_old = [], []
    # young craters' walls are excused wherever they are catalogued: the base's and the layers'
    young_from = _joined_craters(stack.catalog, base_catalog)
    for k, tile in enumerate(stack.tiles):
        name = f"layer {k}"
        curves.append(slope_curve(tile, label=f"{name} ({tile.resolution:.3g} m)",
                                  max_lag=None if k == 0 else 8))
        res, h, dist = _tile_checks(tile, law, name, f"{name}: ", steep=False,
                                    target=lambda est: stack_hurst_target(stack, est, law))
        old = _steep_old_check(tile, young_from, f"{name}: ")
        results += res + [old]
        steep_old.append((k, old.value))
        hurst += h
        dists.append(dist)
        per_layer.append(dict(layer=k, resolution_m=tile.resolution,
                              period2_ratio=_period2_once(tile)))
    table = stack_slope_table(stack)
    results[:0] = [_law_slope_check(table, law), _regolith_check(table)]
    cr, data = _crater_checks(stack, base_catalog)
    results += cr
    data["slope_table"] = table
    data["steep_old"] = steep_old
    if "depth_diameter" in data:
        dd = data["depth_diameter"]
        check, figures = _visible_depth_check(np.asarray(dd["diameter_m"]),
                                              np.asarray(dd["depth_m"]))
        results.append(check)
        data["visible_dd"] = figures
    if stack.catalog is not None and len(stack.catalog.diameter_m):
        check, figures = _small_crater_density(stack, terrain)
        results.append(check)
        if figures:
            data["small_craters"] = figures
    rock, rdata = _rock_check(stack)
    results += rock
    data.update(rdata)
    if stack.rocks is not None and len(stack.rocks.diameter_m):
        check, figures = rock_sfd_check(stack, terrain)
        results.append(check)
        if figures.get("fields"):
            results.append(block_field_check(stack, terrain, figures))
        data["rock_model_sfd"] = figures
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
