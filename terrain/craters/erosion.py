"""Ross/Soderblom crater degradation: depth and rim height as functions of age and diameter.

Martin et al. (2014, section III.B) scale the fresh depth and rim height by erosion factors
read from a *baseline* degradation profile, after mapping a crater's age to the age at which
the baseline crater reaches the same state (Ross 1968; Soderblom 1970):

    T_b = T_x (sigma_b / sigma_x) (D_b / D_x)^P          (Martin et al. 2014, eq. 11)

with P between 1.0 and 1.2 (Soderblom 1970) and the relative surface density
sigma_b / sigma_x = 1 unless the materials differ. Small craters therefore degrade faster
than large ones of the same age.

No baseline profile is published, so the paper used the outline figures of Ross's model; we
ship a table of the same shape (``terrain/craters/data/ross_baseline.csv``, baseline D_b = 1 km,
ages
in Gyr): rim height decays faster than depth, and an old crater ends as a rimless, shallow
depression. The table is piecewise-linear, and any CSV with columns ``baseline_age_gyr,
depth_fraction,rim_fraction`` replaces it (non-increasing fractions starting at 1).

Slope-dependent degradation
---------------------------
Martin et al. (2014) age every crater at the same rate wherever it lies; their further work
asks for craters on steep ground to lose relief faster, and so they do on the Moon, where
downslope creep of regolith accelerates as slopes approach the angle of repose.
:class:`SlopeDegradation` models this with the nonlinear creep law of Roering et al. (1999),
the flux ``q(S) = K S / (1 - (S / Sc)^2)`` for a gradient S and a critical gradient Sc. A
crater is a small relief h on ground of regional gradient S (the tilt of the plane fitted over
its bowl). Linearising the flux about S, ``q(S + dh) = q(S) + q'(S) dh``: relief decays with
diffusivity ``q'(S) = K (1 + r^2) / (1 - r^2)^2`` along the slope and ``q(S) / S =
K / (1 - r^2)`` across it (r = S / Sc). A radially symmetric relief diffusing anisotropically
decays at the mean of the two, so the crater degrades as on flat ground, where the two are
K, at the rate

    m(S) = [ (1 + r^2) / (1 - r^2)^2 + 1 / (1 - r^2) ] / 2        (1 at S = 0)

and since diffusive degradation depends on ``K t`` only (Soderblom 1970), a crater of age T on
slope S looks as one of age ``m(S) T`` on flat ground: the age entered into the table. At
r = 0.3 (about 12 degrees for Sc = tan 35 degrees) m = 1.21; at r = 0.7 (26 degrees),
m = 3.8; at and beyond the critical slope nothing of age > 0 survives and the crater takes
the table's last state.
Sc defaults to the tangent of 35 degrees, the angle of repose of lunar regolith (Carrier et al.
1991, Lunar Sourcebook).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from terrain.core.checks import reject_unknown
from terrain.core.errors import InvalidParameterError, MissingInputError

__all__ = ["DEFAULT_BASELINE_DIAMETER", "DEFAULT_CRITICAL_SLOPE_DEG", "DEFAULT_EXPONENT",
           "ErosionModel", "SlopeDegradation"]

#: Diameter of the baseline crater of the default profile (metres).
DEFAULT_BASELINE_DIAMETER = 1000.0
#: Ross/Soderblom size exponent P; Soderblom (1970) puts it between 1.0 and 1.2.
DEFAULT_EXPONENT = 1.1
#: Critical slope of the creep law, degrees: the angle of repose of lunar regolith.
DEFAULT_CRITICAL_SLOPE_DEG = 35.0


def _load_table(source) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if hasattr(source, "read"):
        lines = source.read().splitlines()
        name = getattr(source, "name", "erosion profile")
    else:
        path = Path(source)
        if not path.exists():
            raise MissingInputError(f"erosion profile '{path}' does not exist")
        lines = path.read_text(encoding="utf-8").splitlines()
        name = str(path)
    rows = [line for line in lines if line.strip() and not line.lstrip().startswith("#")]
    reader = csv.DictReader(rows)
    need = {"baseline_age_gyr", "depth_fraction", "rim_fraction"}
    if reader.fieldnames is None or not need <= {f.strip() for f in reader.fieldnames}:
        raise InvalidParameterError(
            f"erosion profile '{name}' needs columns {sorted(need)}; got {reader.fieldnames}")
    ages, depth, rim = [], [], []
    try:
        for row in reader:
            row = {k.strip(): v for k, v in row.items()}
            ages.append(float(row["baseline_age_gyr"]))
            depth.append(float(row["depth_fraction"]))
            rim.append(float(row["rim_fraction"]))
    except (TypeError, ValueError) as exc:
        raise InvalidParameterError(f"erosion profile '{name}' has a non-numeric value") from exc
    return np.array(ages), np.array(depth), np.array(rim)


@dataclass(frozen=True)
class ErosionModel:
    """Degradation of a crater of diameter D (m) and age T (Gyr) into depth and rim factors.

    Parameters
    ----------
    ages, depth, rim : tuple of float
        Baseline profile: baseline age (Gyr, strictly increasing from 0), normalised depth
        H/H0 and normalised rim height Hr/Hr0 (each in [0, 1], non-increasing, 1 at age 0).
    baseline_diameter : float
        D_b of eq. 11, metres.
    exponent : float
        P of eq. 11.
    density_ratio : float
        sigma_b / sigma_x of eq. 11.

    Examples
    --------
    >>> m = ErosionModel.default()
    >>> [float(f) for f in m.factors(0.0, 100.0)]
    [1.0, 1.0]
    >>> d, r = m.factors(0.1, 100.0)   # a 100 m crater 100 Myr old
    >>> bool(r < d < 1.0)
    True
    """

    ages: tuple
    depth: tuple
    rim: tuple
    baseline_diameter: float = DEFAULT_BASELINE_DIAMETER
    exponent: float = DEFAULT_EXPONENT
    density_ratio: float = 1.0

    def __post_init__(self):
        ages = np.asarray(self.ages, dtype=float)
        depth = np.asarray(self.depth, dtype=float)
        rim = np.asarray(self.rim, dtype=float)
        if not (ages.ndim == 1 and ages.size >= 2 and ages.shape == depth.shape == rim.shape):
            raise InvalidParameterError(
                "erosion profile needs at least two rows of age, depth and rim fractions")
        if not np.all(np.isfinite(ages)) or ages[0] != 0 or np.any(np.diff(ages) <= 0):
            raise InvalidParameterError(
                "erosion profile ages must start at 0 and increase strictly")
        for name, values in (("depth", depth), ("rim", rim)):
            if not np.all((values >= 0) & (values <= 1)):
                raise InvalidParameterError(f"erosion profile {name} fractions must lie in [0, 1]")
            if values[0] != 1.0:
                raise InvalidParameterError(
                    f"erosion profile {name} fraction must be 1 at age 0 (a fresh crater)")
            if np.any(np.diff(values) > 0):
                raise InvalidParameterError(
                    f"erosion profile {name} fractions must not increase with age")
        if depth[-1] <= 0:
            raise InvalidParameterError(
                "erosion profile depth fraction must stay above 0 (an eroded crater remains a "
                "depression)")
        for name in ("baseline_diameter", "exponent", "density_ratio"):
            value = float(getattr(self, name))
            if not (value > 0 and math.isfinite(value)):
                raise InvalidParameterError(f"erosion {name} must be positive; got {value}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "ages", tuple(ages.tolist()))
        object.__setattr__(self, "depth", tuple(depth.tolist()))
        object.__setattr__(self, "rim", tuple(rim.tolist()))

    @classmethod
    def from_csv(cls, source, **kwargs) -> ErosionModel:
        """Model from a CSV profile (path or open text file); ``kwargs`` set eq. 11's constants."""
        ages, depth, rim = _load_table(source)
        return cls(tuple(ages), tuple(depth), tuple(rim), **kwargs)

    @classmethod
    def default(cls, **kwargs) -> ErosionModel:
        """Return the shipped Ross-shaped profile (baseline D_b = 1 km, ages in Gyr)."""
        with resources.files("terrain.craters").joinpath("data/ross_baseline.csv").open(
                encoding="utf-8") as f:
            return cls.from_csv(f, **kwargs)

    def baseline_age(self, age, diameter) -> np.ndarray:
        """T_b of eq. 11 for crater age(s) ``age`` (Gyr) and diameter(s) ``diameter`` (m)."""
        age = np.asarray(age, dtype=float)
        diameter = np.asarray(diameter, dtype=float)
        return age * self.density_ratio * (self.baseline_diameter / diameter) ** self.exponent

    def factors(self, age, diameter) -> tuple[np.ndarray, np.ndarray]:
        """Normalised (depth H/H0, rim height Hr/Hr0) for age(s) in Gyr and diameter(s) in m."""
        tb = self.baseline_age(age, diameter)
        return (np.interp(tb, self.ages, self.depth), np.interp(tb, self.ages, self.rim))

    def as_dict(self) -> dict:
        """Return the model as plain data (Gyr, metres, fractions) for metadata."""
        return dict(baseline_diameter=self.baseline_diameter, exponent=self.exponent,
                    density_ratio=self.density_ratio, ages=list(self.ages),
                    depth=list(self.depth), rim=list(self.rim))


@dataclass(frozen=True)
class SlopeDegradation:
    """Faster degradation on steep ground (see the module docstring).

    Parameters
    ----------
    enabled : bool
        False ages every crater at the flat-ground rate.
    critical_slope_deg : float
        The slope (degrees, in (0, 90)) at which creep runs away: Sc = tan of it.

    Examples
    --------
    >>> s = SlopeDegradation()
    >>> [round(float(s.rate(np.radians(a))), 3) for a in (0.0, 12.0, 26.1)]
    [1.0, 1.213, 3.837]
    >>> float(s.effective_age(1.0, np.radians(40.0)))
    inf
    """

    enabled: bool = True
    critical_slope_deg: float = DEFAULT_CRITICAL_SLOPE_DEG

    def __post_init__(self):
        v = float(self.critical_slope_deg)
        if not 0.0 < v < 90.0:
            raise InvalidParameterError(
                f"slope degradation critical_slope_deg must lie in (0, 90); got {v}")
        object.__setattr__(self, "critical_slope_deg", v)
        object.__setattr__(self, "enabled", bool(self.enabled))

    @classmethod
    def from_mapping(cls, data) -> SlopeDegradation:
        """Build from a mapping (a TOML table), rejecting unknown keys by name."""
        if not isinstance(data, dict):
            raise InvalidParameterError(
                f"slope degradation must be a table; got {type(data).__name__}")
        reject_unknown(data, ["enabled", "critical_slope_deg"], "slope degradation")
        return cls(**data)

    def rate(self, slope) -> np.ndarray:
        """m(S): degradation rate relative to flat ground at slope(s) in radians (inf at Sc)."""
        r = np.tan(np.abs(np.asarray(slope, dtype=float))) / math.tan(
            math.radians(self.critical_slope_deg))
        if not self.enabled:
            return np.ones_like(r)
        r2 = np.minimum(r * r, 1.0)
        with np.errstate(divide="ignore"):
            m = 0.5 * ((1.0 + r2) / (1.0 - r2) ** 2 + 1.0 / (1.0 - r2))
        return np.where(np.isfinite(r), m, np.inf)

    def effective_age(self, age, slope) -> np.ndarray:
        """m(S) T: the flat-ground age (Gyr) a crater of age T (Gyr) on slope S looks."""
        age = np.asarray(age, dtype=float)
        m = self.rate(slope)
        with np.errstate(invalid="ignore"):
            return np.where(age > 0.0, age * m, 0.0)

    def as_dict(self) -> dict:
        """Return the settings as plain data for metadata."""
        return dict(enabled=self.enabled, critical_slope_deg=self.critical_slope_deg)
