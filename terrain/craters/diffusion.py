r"""Crater degradation by topographic diffusion, and how long a crater stays visible.

Small lunar craters lose relief by the slow downslope creep of regolith that countless
smaller impacts stir up; averaged over time and area the relief obeys the diffusion equation
``dh/dt = kappa laplacian(h)`` (Soderblom 1970; Fassett and Thomson 2014, JGR Planets 119,
2255, who measured ``kappa`` of about 5.5 m^2/Myr on the Moon over the last ~3 Gyr from the
profiles of 800 m - 5 km craters, :data:`DEFAULT_DIFFUSIVITY`).

A diffusing profile depends on ``kappa t`` only through ``tau = kappa t / D^2``: a crater of
diameter D and age t has the shape of any other of the same tau (the fresh simple profile
scales with D, Pike's ``H0 = 0.196 D^1.01`` being linear to within 5 % from 1 m to 15 km).
:func:`degradation_table` therefore solves the axisymmetric equation once, on the fresh
profile of :mod:`terrain.craters.crater` (bowl, rim and ejecta; flat surroundings), and
tabulates the rim-to-floor depth and the rim height, as fractions of the fresh ones, against
tau. Its values (``docs/craters.md`` has the derivation)::

    tau      0      0.005  0.01   0.02   0.03   0.05   0.075  0.1
    H/H0     1      0.83   0.73   0.56   0.43   0.29   0.19   0.14
    Hr/Hr0   1      0.51   0.37   0.23   0.15   0.08   0.04   0.02

so a fresh bowl (d/D 0.19) reaches the d/D of about 0.04 below which crater counts stop
(:data:`DEFAULT_VISIBLE_DEPTH_RATIO`; Stopar et al. 2017, Icarus 298, 34; Mahanti et al.
2018, Icarus 299, 475) at ``tau_v = 0.068``: a crater lives ``tau_v D^2 / kappa``, 1.2 Myr
at 10 m, 125 Myr at 100 m and 12 Gyr at 1 km. Craters below a few hundred metres are
therefore in equilibrium on any surface older than their lifetime: production replaces what
diffusion erases, and the visible ones have ages spread evenly over ``[0, lifetime]``.

Examples
--------
>>> m = DiffusionModel()
>>> [round(float(v), 2) for v in m.factors(0.0, 10.0)]
[1.0, 1.0]
>>> round(float(m.lifetime(100.0)), 3)  # Gyr
0.125
>>> round(float(m.depth_ratio(m.lifetime(40.0), 40.0)), 3)  # d/D at the end of its life
0.04
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from terrain.core.errors import InvalidParameterError

__all__ = ["DEFAULT_DIFFUSIVITY", "DEFAULT_VISIBLE_DEPTH_RATIO", "DiffusionModel",
           "degradation_table"]

#: Topographic diffusivity of the lunar surface, m^2/Myr (Fassett and Thomson 2014, for the
#: last ~3 Gyr).
DEFAULT_DIFFUSIVITY = 5.5
#: d/D below which a crater is no longer counted (Stopar et al. 2017; Mahanti et al. 2018).
DEFAULT_VISIBLE_DEPTH_RATIO = 0.04
#: Diameter (m) whose fresh profile the table is derived on (any would do within 5 %).
_REFERENCE_DIAMETER = 100.0
#: Largest tau tabulated; beyond it depth decays as tau^-1 (a diffusing 2-D bump).
_TAU_MAX = 2.0
#: Radial nodes per crater radius of the solver, and its domain in radii.
_NODES_PER_RADIUS = 30
_DOMAIN_RADII = 6.0


@functools.lru_cache(maxsize=1)
def degradation_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (tau, depth fraction, rim fraction) of a diffusing fresh simple crater.

    Explicit finite volumes on ``r`` in ``[0, 6 R]`` (30 nodes per radius; zero flux at the
    centre and a fixed far field), time step 0.2 dr^2 / kappa, sampled on a logarithmic tau
    grid. Depth is rim crest to floor (the profile's maximum minus its minimum), rim height
    the maximum above the surroundings, both over the fresh values.

    Returns
    -------
    tau : (n,) float64
        ``kappa t / D^2``, starting at 0.
    depth_fraction, rim_fraction : (n,) float64
        Non-increasing, 1 at tau = 0.
    """
    from terrain.craters.crater import CraterShape, profile

    d = _REFERENCE_DIAMETER
    radius = d / 2.0
    n = int(_DOMAIN_RADII * _NODES_PER_RADIUS)
    dr = _DOMAIN_RADII * radius / n
    r = (np.arange(n) + 0.5) * dr
    x = np.minimum(r / radius - 1.0, 1.0)
    h = np.where(r <= d, profile(x, CraterShape.from_state(d)), 0.0)
    depth0 = h.max() - h.min()
    rim0 = h.max()
    outer = (r + dr / 2) / (r * dr * dr)
    inner = (r - dr / 2) / (r * dr * dr)
    dt = 0.2 * dr * dr
    taus = np.concatenate([[0.0], np.geomspace(1e-4, 0.3, 120)])
    depth = [1.0]
    rim = [1.0]
    t = 0.0
    for target in taus[1:]:
        steps = max(1, int(math.ceil((target * d * d - t) / dt)))
        step = (target * d * d - t) / steps
        for _ in range(steps):
            up = np.append(h[1:], 0.0)
            down = np.concatenate([h[:1], h[:-1]])
            h = h + step * (outer * (up - h) + inner * (down - h))
        t = target * d * d
        depth.append((h.max() - h.min()) / depth0)
        rim.append(max(0.0, h.max()) / rim0)
    tau = np.append(taus, _TAU_MAX)
    # beyond the last step, a diffusing bump's amplitude falls as 1 / tau
    depth.append(depth[-1] * taus[-1] / _TAU_MAX)
    rim.append(0.0)
    depth_a = np.minimum.accumulate(np.array(depth))
    rim_a = np.minimum.accumulate(np.array(rim))
    return tau, depth_a, rim_a


@dataclass(frozen=True)
class DiffusionModel:
    """Degradation of a crater of diameter D (m) and age T (Gyr) by topographic diffusion.

    Takes the place of :class:`terrain.craters.erosion.ErosionModel` in a
    :class:`terrain.craters.cratering.CraterModel` (the same ``factors`` and ``as_dict``).

    Parameters
    ----------
    diffusivity : float
        kappa, m^2/Myr (default :data:`DEFAULT_DIFFUSIVITY`).
    visible_depth_ratio : float
        d/D below which a crater is gone (default :data:`DEFAULT_VISIBLE_DEPTH_RATIO`).
    """

    diffusivity: float = DEFAULT_DIFFUSIVITY
    visible_depth_ratio: float = DEFAULT_VISIBLE_DEPTH_RATIO

    def __post_init__(self):
        k = float(self.diffusivity)
        v = float(self.visible_depth_ratio)
        if not (k > 0 and math.isfinite(k)):
            raise InvalidParameterError(
                f"crater diffusivity must be positive m^2/Myr; got {self.diffusivity}")
        if not 0.0 <= v < 0.19:
            raise InvalidParameterError(
                f"visible depth ratio must lie in [0, 0.19) (a fresh bowl's d/D); got {v}")
        object.__setattr__(self, "diffusivity", k)
        object.__setattr__(self, "visible_depth_ratio", v)

    def tau(self, age, diameter) -> np.ndarray:
        """``kappa t / D^2`` for age(s) in Gyr and diameter(s) in metres."""
        age = np.asarray(age, dtype=float)
        diameter = np.asarray(diameter, dtype=float)
        return self.diffusivity * age * 1000.0 / (diameter * diameter)

    def factors(self, age, diameter) -> tuple[np.ndarray, np.ndarray]:
        """Normalised (depth H/H0, rim height Hr/Hr0) for age(s) in Gyr and diameter(s) in m."""
        tau, depth, rim = degradation_table()
        t = self.tau(age, diameter)
        far = depth[-1] * tau[-1] / np.maximum(t, tau[-1])
        return (np.where(t > tau[-1], far, np.interp(t, tau, depth)), np.interp(t, tau, rim))

    def depth_ratio(self, age, diameter) -> np.ndarray:
        """d/D of a simple crater of this age (Gyr) and diameter (m)."""
        from terrain.craters.crater import fresh_depth

        diameter = np.asarray(diameter, dtype=float)
        return self.factors(age, diameter)[0] * fresh_depth(diameter) / diameter

    @property
    def visible_tau(self) -> float:
        """Tau at which a fresh 100 m bowl falls to the visible d/D (inf if it never does)."""
        from terrain.craters.crater import fresh_depth

        tau, depth, _ = degradation_table()
        target = self.visible_depth_ratio / (float(fresh_depth(_REFERENCE_DIAMETER))
                                             / _REFERENCE_DIAMETER)
        if target <= 0:
            return math.inf
        if target < depth[-1]:
            return float(tau[-1] * depth[-1] / target)
        # depth falls with tau: interpolate tau against the reversed depth
        return float(np.interp(target, depth[::-1], tau[::-1]))

    def lifetime(self, diameter) -> np.ndarray:
        """Age (Gyr) at which a crater of this diameter (m) falls below the visible d/D."""
        diameter = np.asarray(diameter, dtype=float)
        return self.visible_tau * diameter * diameter / (self.diffusivity * 1000.0)

    @property
    def lifetime_coefficient(self) -> float:
        """Gyr per m^2: ``lifetime(D) = coefficient D^2``."""
        return self.visible_tau / (self.diffusivity * 1000.0)

    def as_dict(self) -> dict:
        """Return the model as plain data (m^2/Myr, d/D) for metadata."""
        return dict(kind="diffusion", diffusivity_m2_per_myr=self.diffusivity,
                    visible_depth_ratio=self.visible_depth_ratio,
                    visible_tau=self.visible_tau)
