r"""The lunar regolith's roughness below a metre: a second, steeper self-affine law.

Orbital data (LOLA, 17 m - 1 km) give a Hurst exponent near 0.95, so slopes barely change
with baseline there. Below a metre the regolith is rougher than that law continued: the
Chang'e-4 rover's 5 mm/pixel stereo terrain model has a median bidirectional slope of ~10 deg
at a 7 mm baseline with a Hurst exponent of 0.6-0.85 (Guo et al. 2021, GRL 48, e2021GL094931),
and Apollo close-up stereo photographs of undisturbed regolith give 0.5-0.7 at sub-millimetre
to centimetre scales (Helfenstein and Shepard 1999, Icarus 141, 107); RMS slopes of 10-20 deg
at centimetre scales follow (Shepard et al. 2001, JGR 106, 32777, for the scale-dependent
parameters; Hayne et al. 2021, Nat. Astron. 5, 169, for the slopes at these scales).

The law, with the numbers above (median bidirectional slope ``theta`` at baseline ``L``):

    tan theta(L) = tan(REGOLITH_SLOPE_DEG) (L / REGOLITH_BASELINE_M)^(REGOLITH_HURST - 1)

For Gaussian height differences the median of ``|dz| / L`` is 0.6745 times its RMS, so the
law is an fBm whose variogram is ``V r^(2 H)`` (r in metres) with
``sqrt(V) = tan(theta(L0)) / 0.6745 * L0^(1 - H)``. An expansion continuing this fBm below
:data:`REGOLITH_ONSET_M` (:meth:`RegolithLaw.variance`) displaces every new pixel by at least
the fBm's prediction error there (:meth:`terrain.fractal.roughness.ExpansionParameters.sigmas`),
so the slope rises below a metre toward the measured centimetre values
(``docs/roughness.md``).

Examples
--------
>>> law = RegolithLaw()
>>> round(law.median_slope_deg(0.007), 1)
10.0
>>> law.median_slope_deg(0.01) > law.median_slope_deg(0.1) > law.median_slope_deg(1.0)
True
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from terrain.core.errors import InvalidParameterError

__all__ = ["MEDIAN_OVER_RMS", "REGOLITH_BASELINE_M", "REGOLITH_HURST", "REGOLITH_ONSET_M",
           "REGOLITH_SLOPE_DEG", "RegolithLaw"]

#: Median bidirectional slope (deg) at :data:`REGOLITH_BASELINE_M` (Guo et al. 2021, Chang'e-4
#: terrain model at 5 mm/pixel: "median value of ~10 deg" at the 7 mm scale).
REGOLITH_SLOPE_DEG = 10.0
#: Baseline (m) of :data:`REGOLITH_SLOPE_DEG` (Guo et al. 2021).
REGOLITH_BASELINE_M = 0.007
#: Hurst exponent of the regolith below a metre: inside both Guo et al. 2021's 0.6-0.85 and
#: Helfenstein and Shepard 1999's 0.5-0.7.
REGOLITH_HURST = 0.7
#: Baseline (m) below which the regolith law is a floor on the expansion's roughness.
REGOLITH_ONSET_M = 1.0
#: Median of |x| over the RMS of x for a zero-mean Gaussian (erf^-1(1/2) sqrt(2)).
MEDIAN_OVER_RMS = 0.6745


@dataclass(frozen=True)
class RegolithLaw:
    """A self-affine roughness law of the regolith, applied below ``onset_m``.

    Parameters
    ----------
    slope_deg : float
        Median bidirectional slope (deg) at ``baseline_m``.
    baseline_m : float
        Its baseline (m).
    hurst : float
        Hurst exponent in (0, 1).
    onset_m : float
        Largest pixel spacing (m) of an expansion level the law applies to.
    """

    slope_deg: float = REGOLITH_SLOPE_DEG
    baseline_m: float = REGOLITH_BASELINE_M
    hurst: float = REGOLITH_HURST
    onset_m: float = REGOLITH_ONSET_M

    def __post_init__(self):
        for name in ("slope_deg", "baseline_m", "hurst", "onset_m"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if not 0.0 < self.slope_deg < 90.0:
            raise InvalidParameterError(
                f"regolith slope must lie in (0, 90) degrees; got {self.slope_deg}")
        if not (self.baseline_m > 0 and self.onset_m > 0):
            raise InvalidParameterError(
                f"regolith baseline and onset must be positive metres; got {self.baseline_m}, "
                f"{self.onset_m}")
        if not 0.0 < self.hurst < 1.0:
            raise InvalidParameterError(
                f"regolith Hurst exponent must lie in (0, 1); got {self.hurst}")

    def median_slope_deg(self, baseline_m: float) -> float:
        """Median bidirectional slope (deg) the law gives at ``baseline_m`` metres."""
        t = math.tan(math.radians(self.slope_deg))
        return math.degrees(math.atan(t * (baseline_m / self.baseline_m) ** (self.hurst - 1)))

    def rms_slope_deg(self, baseline_m: float) -> float:
        """RMS slope (deg, as atan of the RMS gradient) at ``baseline_m`` metres."""
        t = math.tan(math.radians(self.median_slope_deg(baseline_m))) / MEDIAN_OVER_RMS
        return math.degrees(math.atan(t))

    def variance(self, resolution: float) -> float:
        """V of the law's fBm variogram ``V r^(2 H)`` with r in pixels of ``resolution`` m."""
        t = math.tan(math.radians(self.slope_deg)) / MEDIAN_OVER_RMS
        v_metres = (t * self.baseline_m ** (1.0 - self.hurst)) ** 2
        return v_metres * resolution ** (2.0 * self.hurst)

    def as_dict(self) -> dict:
        """Return the law as plain data for metadata."""
        return asdict(self)
