r"""How many craters a lunar surface of a given age has received: the production side.

The lunar chronology of Neukum (1983; Neukum et al. 2001, Space Sci. Rev. 96, 55, eq. 5)
gives the cumulative density of craters of 1 km and larger produced on a surface of age T
(Gyr), per km^2::

    N(>=1 km) = 5.44e-14 (exp(6.93 T) - 1) + 8.38e-4 T

(0.033 per km^2 at 3.9 Gyr, 0.0048 at 3.5 Gyr). Around
1 km the production size-frequency distribution is steep below and shallower above: its
cumulative slope is close to -3 for 100 m - 1 km (Neukum et al. 2001, Fig. 2; Shoemaker's
-2.9) and close to -2 for 1 - 64 km (Hartmann 1984's flat R-plot of the highlands),
:data:`SLOPE_BELOW_1KM` and :data:`SLOPE_ABOVE_1KM`. A surface keeps at each size the
smaller of what was produced and the equilibrium that degradation allows
(:mod:`terrain.craters.population`): with Trask's equilibrium, 10^-1.1 D^-2 per m^2, the
production of a 3.9 Gyr surface falls below it above about 420 m, where the diffusion lifetime
of a crater (:mod:`terrain.craters.diffusion`) reaches the surface's age as well.

Examples
--------
>>> round(neukum_n1(3.9), 4), round(neukum_n1(3.5), 4)
(0.033, 0.0048)
>>> round(float(production_cumulative(2000.0, 3.9) / production_cumulative(1000.0, 3.9)), 3)
0.25
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SLOPE_ABOVE_1KM", "SLOPE_BELOW_1KM", "neukum_n1", "production_cumulative"]

#: Cumulative production SFD slope from 100 m to 1 km (Neukum et al. 2001).
SLOPE_BELOW_1KM = -3.0
#: Cumulative production SFD slope from 1 km to 64 km (Hartmann 1984).
SLOPE_ABOVE_1KM = -2.0


def neukum_n1(age_gyr: float) -> float:
    """Craters >= 1 km per km^2 produced in ``age_gyr`` Gyr (Neukum et al. 2001, eq. 5)."""
    t = float(age_gyr)
    return 5.44e-14 * (math.exp(6.93 * t) - 1.0) + 8.38e-4 * t


def production_cumulative(diameter, age_gyr: float) -> np.ndarray:
    """Craters >= D (metres) per km^2 produced in ``age_gyr`` Gyr (the broken power law)."""
    d = np.asarray(diameter, dtype=float) / 1000.0
    slope = np.where(d < 1.0, SLOPE_BELOW_1KM, SLOPE_ABOVE_1KM)
    return neukum_n1(age_gyr) * d ** slope
