r"""The radial profile of a simple crater: four connected polynomials (Martin et al. 2014, III.A).

Notation
--------
``x = 2 r / D - 1`` is the normalised radial distance (eq. 3): -1 at the centre, 0 at the
rim (r = D/2), 1 at the edge of the ejecta blanket (r = D). Inside the rim the terrain is
*obliterated*: heights are a plane P fitted to the pre-impact terrain plus the interior
profile. Outside, the profile is a *change* added to the pre-impact terrain T. Along each
radius, ``Tr`` is the terrain height at the rim and ``Pr`` the plane's height there.

Fresh depth (rim crest to floor) and rim height (Melosh 1989, after Pike 1977; fits in
kilometres, so D is converted to km and the result back to metres)::

    H0 = 0.196 D^1.01,   Hr0 = 0.036 D^1.01                     (eqs. 1-2)

Erosion scales them to ``H = d H0`` and ``Hr = q Hr0`` (:mod:`terrain.erosion`).

Interior (bowl and interior rim), heights relative to the plane
---------------------------------------------------------------
With ``E = Hr + Tr - Pr`` (the rim's height above the plane on this radius),
``C = Hr - H`` (the floor) and the bowl curvature ``A = Hr0 - Hr + H``::

    h1(x) = A (x + 1)^2 + C,          -1 <= x <= alpha           (eq. 4)
    h2(x) = B x^2 + E,               alpha <= x <= 0             (eq. 5)

h2 has zero slope at the rim, and matching h1 and h2 in value and slope at alpha gives
``B = A (alpha + 1) / alpha`` and ``alpha = (E - C) / A - 1`` (eq. 6; the printed
eqs. 4-6 are consistent with these constraints). On flat ground ``alpha = (Hr - Hr0) / A``:
0 for a fresh crater (the bowl meets the rim crest in a kink), moving towards the centre as
the rim erodes. Where the terrain makes the rim so high above the plane that alpha > 0, the
bowl is steepened (``A = E - C``, alpha = 0, a sharp crest); where the rim would be below the
floor, the floor rises to it (``C = E``).

Exterior (rim and ejecta), change added to the terrain
------------------------------------------------------
The printed eqs. 7-10 do not satisfy the constraints the text states: eq. 8 makes beta
negative for an eroded crater although beta moves outwards, and eq. 9 plus the corrective
function F_c (eq. 10) does not vanish at the ejecta edge. We impose the constraints instead.
An exterior cubic from the rim to beta, and McGetchin's ejecta (McGetchin et al. 1973,
t = 0.14 R^0.74 (r/R)^-3, metres, with r/R = x + 1) plus a linear corrective function::

    h3(x) = Hr + c2 x^2 + c3 x^3,                0 <= x <= beta
    h4(x) = e (x + 1)^-3 + a + b x,             beta <= x <= 1

h3 already has value Hr and zero slope at the rim. The remaining conditions are linear in
(a, b, c2, c3): ``h4(1) = 0`` and equal value, slope and curvature at beta. Writing
``E0 = e (1+beta)^-3``, ``E1 = -3 e (1+beta)^-4``, ``E2 = 12 e (1+beta)^-5`` (h4's ejecta
term and its derivatives at beta), elimination gives::

    c3 = (E0 - e/8 - (beta - 1) E1 - Hr - E2 (2 beta - beta^2) / 2) / (beta^2 (beta - 3))
    c2 = E2 / 2 - 3 c3 beta
    b  = 2 c2 beta + 3 c3 beta^2 - E1
    a  = -e/8 - b

A fresh crater has beta = 0: h4 alone runs from the crest (``a = Hr - e``) to zero at x = 1
(``b = -e/8 - a``), with a kink at the crest. For an eroded crater we keep the magnitude of
the printed eq. 8 with the sign the text asks for: ``beta = 1.5 |alpha_flat|`` (at most
:data:`BETA_MAX`), so beta grows monotonically with erosion. The ejecta thickness erodes with
the rim, ``e = 0.14 (D/2)^0.74 Hr / Hr0``, which makes the exterior proportional to Hr: a
fully eroded crater (Hr = 0) leaves the outside untouched, a rimless depression.

Examples
--------
>>> s = CraterShape.from_state(100.0)          # fresh 100 m crater
>>> x = np.array([-1.0, 0.0, 1.0])
>>> np.round(profile(x, s), 3)                  # floor, rim crest, ejecta edge
array([-15.636,   3.518,   0.   ])
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from terrain.errors import InvalidParameterError

__all__ = [
    "BETA_FROM_ALPHA",
    "BETA_MAX",
    "CraterShape",
    "ejecta_amplitude",
    "exterior_coefficients",
    "fresh_depth",
    "fresh_rim_height",
    "profile",
]

#: Melosh (1989) / Pike (1977) fresh simple crater depth: H0 = 0.196 D^1.01 (D, H0 in km).
DEPTH_COEFFICIENT = 0.196
#: Melosh (1989) fresh rim height: Hr0 = 0.036 D^1.01 (D, Hr0 in km).
RIM_COEFFICIENT = 0.036
#: Exponent of eqs. 1-2.
DEPTH_EXPONENT = 1.01
#: The unit of the eqs. 1-2 fits, in metres.
FIT_UNIT = 1000.0
#: McGetchin et al. (1973) ejecta thickness t = 0.14 R^0.74 (r/R)^-3 (metres).
EJECTA_COEFFICIENT = 0.14
EJECTA_EXPONENT = 0.74
#: |beta| / |alpha| for an eroded crater on flat ground (magnitude of the printed eq. 8).
BETA_FROM_ALPHA = 1.5
#: Upper bound of beta, leaving the ejecta at least 20 % of the exterior.
BETA_MAX = 0.8
#: Below this beta the exterior is treated as fresh (no rim cubic).
BETA_FRESH = 1e-6


def fresh_depth(diameter):
    """H0 (metres, rim crest to floor) for diameter(s) in metres (eq. 1).

    >>> round(float(fresh_depth(1000.0)), 3)
    196.0
    """
    d = np.asarray(diameter, dtype=float) / FIT_UNIT
    return DEPTH_COEFFICIENT * d**DEPTH_EXPONENT * FIT_UNIT


def fresh_rim_height(diameter):
    """Hr0 (metres) for diameter(s) in metres (eq. 2).

    >>> round(float(fresh_rim_height(1000.0)), 3)
    36.0
    """
    d = np.asarray(diameter, dtype=float) / FIT_UNIT
    return RIM_COEFFICIENT * d**DEPTH_EXPONENT * FIT_UNIT


def ejecta_amplitude(diameter):
    """McGetchin's ejecta thickness at the rim, 0.14 (D/2)^0.74 metres, for a fresh crater."""
    return EJECTA_COEFFICIENT * (np.asarray(diameter, dtype=float) / 2.0) ** EJECTA_EXPONENT


def exterior_coefficients(rim_height, ejecta, beta):
    """(a, b, c2, c3) of h3 and h4 from the constraints (see the module docstring).

    All arguments broadcast; returns four float64 arrays.
    """
    hr, e, beta = np.broadcast_arrays(np.asarray(rim_height, float), np.asarray(ejecta, float),
                                      np.asarray(beta, float))
    fresh = beta < BETA_FRESH
    bt = np.where(fresh, 1.0, beta)  # placeholder avoids 0/0 on the fresh branch
    e0 = e * (1 + bt) ** -3
    e1 = -3 * e * (1 + bt) ** -4
    e2 = 12 * e * (1 + bt) ** -5
    rhs = e0 - e / 8 - (bt - 1) * e1 - hr
    c3 = (rhs - e2 * (2 * bt - bt**2) / 2) / (bt**2 * (bt - 3))
    c2 = e2 / 2 - 3 * c3 * bt
    b = 2 * c2 * bt + 3 * c3 * bt**2 - e1
    a = -e / 8 - b
    a_fresh = hr - e
    b_fresh = -e / 8 - a_fresh
    return (np.where(fresh, a_fresh, a), np.where(fresh, b_fresh, b),
            np.where(fresh, 0.0, c2), np.where(fresh, 0.0, c3))


@numba.njit(cache=True)
def interior_height(x, bowl_curvature, floor, rim):
    """Interior profile (h1 or h2) at x in [-1, 0], relative to the plane.

    ``bowl_curvature`` is A, ``floor`` is C = Hr - H, ``rim`` is E = Hr + Tr - Pr.
    """
    c = min(floor, rim)
    d = rim - c
    a = max(bowl_curvature, d)
    if a <= 0.0:
        return rim
    alpha = d / a - 1.0
    if x <= alpha:
        return a * (x + 1.0) ** 2 + c
    if alpha >= 0.0:
        return rim
    b = a * (alpha + 1.0) / alpha
    return b * x * x + rim


@numba.njit(cache=True)
def interior_alpha(bowl_curvature, floor, rim):
    """alpha (eq. 6, with the clamps of interior_height)."""
    c = min(floor, rim)
    d = rim - c
    a = max(bowl_curvature, d)
    if a <= 0.0:
        return -1.0
    return d / a - 1.0


@numba.njit(cache=True)
def exterior_height(x, rim_height, ejecta, beta, a, b, c2, c3):
    """Exterior profile (h3 or h4) at x in [0, 1], change added to the terrain."""
    if x < beta:
        return rim_height + (c2 + c3 * x) * x * x
    return ejecta / (1.0 + x) ** 3 + a + b * x


@dataclass(frozen=True)
class CraterShape:
    """Profile parameters of one crater (all metres except the dimensionless x positions).

    Build with :meth:`from_state`; ``depth`` and ``rim_height`` are H and Hr after erosion.
    """

    diameter: float
    depth: float
    rim_height: float
    fresh_depth: float
    fresh_rim_height: float
    ejecta: float
    alpha: float
    beta: float
    a: float
    b: float
    c2: float
    c3: float

    @classmethod
    def from_state(cls, diameter: float, depth_fraction: float = 1.0,
                   rim_fraction: float = 1.0) -> CraterShape:
        """Shape of a crater of ``diameter`` metres at the given erosion factors H/H0, Hr/Hr0."""
        diameter = float(diameter)
        if not (diameter > 0 and math.isfinite(diameter)):
            raise InvalidParameterError(f"crater diameter must be positive; got {diameter}")
        for name, v in (("depth_fraction", depth_fraction), ("rim_fraction", rim_fraction)):
            if not 0.0 <= float(v) <= 1.0:
                raise InvalidParameterError(f"{name} must lie in [0, 1]; got {v}")
        arrays = shape_arrays(np.array([diameter]), np.array([float(depth_fraction)]),
                              np.array([float(rim_fraction)]))
        return cls(**{k: float(v[0]) for k, v in arrays.items()})

    @property
    def bowl_curvature(self) -> float:
        """A = Hr0 - Hr + H."""
        return self.fresh_rim_height - self.rim_height + self.depth

    @property
    def floor(self) -> float:
        """C = Hr - H: the floor relative to the plane."""
        return self.rim_height - self.depth


def shape_arrays(diameter, depth_fraction, rim_fraction) -> dict[str, np.ndarray]:
    """Vectorised :class:`CraterShape` fields for arrays of craters."""
    diameter = np.asarray(diameter, dtype=float)
    h0 = fresh_depth(diameter)
    hr0 = fresh_rim_height(diameter)
    h = h0 * depth_fraction
    hr = hr0 * rim_fraction
    ejecta = ejecta_amplitude(diameter) * rim_fraction
    curvature = hr0 - hr + h
    alpha = (hr - hr0) / curvature  # eq. 6 on flat ground (Tr = Pr)
    beta = np.minimum(BETA_MAX, BETA_FROM_ALPHA * np.abs(alpha))
    beta = np.where(beta < BETA_FRESH, 0.0, beta)
    a, b, c2, c3 = exterior_coefficients(hr, ejecta, beta)
    return dict(diameter=diameter, depth=h, rim_height=hr, fresh_depth=h0,
                fresh_rim_height=hr0, ejecta=ejecta, alpha=alpha, beta=beta,
                a=a, b=b, c2=c2, c3=c3)


@numba.njit(cache=True)
def _profile_flat(x, curvature, floor, rim_height, rim_offset, ejecta, beta, a, b, c2, c3,
                  out):
    for i in range(x.size):
        xi = x[i]
        if xi <= 0.0:
            out[i] = interior_height(xi, curvature, floor, rim_height + rim_offset)
        elif xi <= 1.0:
            out[i] = exterior_height(xi, rim_height, ejecta, beta, a, b, c2, c3)
        else:
            out[i] = 0.0


def profile(x, shape: CraterShape, rim_offset: float = 0.0) -> np.ndarray:
    """The radial profile at normalised distances ``x`` (float64 array, metres).

    Inside the rim (x <= 0) the value is relative to the fitted plane, outside it is the
    change added to the terrain; beyond x = 1 it is 0. ``rim_offset`` is ``Tr - Pr``.
    """
    x = np.asarray(x, dtype=float)
    out = np.empty(x.shape)
    _profile_flat(np.ascontiguousarray(x).ravel(), shape.bowl_curvature, shape.floor,
                  shape.rim_height, float(rim_offset), shape.ejecta, shape.beta, shape.a,
                  shape.b, shape.c2, shape.c3, out.reshape(-1))
    return out
