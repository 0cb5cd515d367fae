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

Erosion scales them to ``H = d H0`` and ``Hr = q Hr0`` (:mod:`terrain.craters.erosion`).

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

Complex craters (above the transition diameter)
-----------------------------------------------
Above the simple-to-complex transition (:attr:`Morphology.transition_diameter`; 15 km on the
Moon, where Pike's depth/diameter distribution inflects, Pike 1977) a fresh crater is shallow
and flat-floored, with slumped, terraced walls and a central peak, or a ring of peaks at
basin sizes (Melosh 1989, ch. 8; Li et al. 2022, section 3, kernel 4). Pike's (1977) lunar
fits for complex craters, D in km::

    H0 = 1.044 D^0.301      (rim crest to floor)
    Hr0 = 0.236 D^0.399     (rim crest above the surroundings)
    Df = 0.187 D^1.249      (floor diameter; Df / D at most FLOOR_FRACTION_MAX)

The fits do not meet the simple ones at the transition (at 15 km the complex depth is 2.4 km
against the simple fit's 3.0 km): real craters change form there, and the profile does too.
The central peak rises above the floor by ``Hp0 = 0.0049 D^1.297`` km (a power law of the form
and size of Hale and Head 1979; 1.6 km for an 86 km crater like Tycho, whose peak stands
about 1.6 km above its floor), at most :data:`PEAK_DEPTH_FRACTION_MAX` of the depth, on a base
of diameter :data:`PEAK_BASE_FRACTION` D. At and above
:attr:`Morphology.peak_ring_diameter` (200 km; lunar peak-ring basins, Baker et al. 2011) the
peak becomes a ring of diameter :data:`RING_FRACTION` D (Baker et al. 2011's ring/rim ratio
of about 0.5) and base width :data:`RING_WIDTH_FRACTION` D, of the same height.

With ``t = (x - xf) / (-xf)`` the position across the wall (0 at the floor's edge
``xf = Df / D - 1``, 1 at the rim), the interior relative to the plane is::

    floor:  h = C + Hp b(rho)                              x <= xf
    wall:   h = C + K g(t) + Hp b(rho)                     xf < x, t <= tc
    cap:    h = E - q (1 - t)^2                            tc < t <= 1

with ``C = Hr - H`` and ``E`` the rim as for simple craters, the peak bump
``b(rho) = (1 - rho^2)^2`` for ``rho < 1`` (rho the distance from the peak's axis, or from
the ring's crest line, over the base half-width: 0 with zero slope at its foot, so the floor
meets the peak smoothly) and the wall shape ``g(t) = s(t)^2``. ``s`` is the slumped
position: ``s = (1 - tau) t + tau (k + S(f)) / N`` with ``N t = k + f`` (k integer) and
``S(f) = 3 f^2 - 2 f^3``, which puts N terraces (flat benches at the integer points, steep
scarps between, :func:`terrace_count` of them) into a wall that is otherwise parabolic;
``g(0) = 0`` and ``g'(0) = 0`` (the wall leaves the floor with zero slope) and ``g(1) = 1``.
A fresh crater has ``tc = 1`` and ``K = E - C``: the wall meets the rim crest in a kink, as
the simple bowl does. An eroded crater's crest is rounded by a cap parabola over the top
``1 - tc = |alpha|`` of the wall (alpha as on flat ground for simple craters): the cap has
zero slope at the rim, like the eroded exterior's cubic, and matching value and slope with
the wall at ``tc`` fixes ``q = K g'(tc) / (2 (1 - tc))`` and
``K = (E - C) / (g(tc) + g'(tc) (1 - tc) / 2)`` (so the rim still stands at E). The terrace
strength tau = :data:`TERRACE_STRENGTH` times the rim fraction and the peak height
``Hp = Hp0 H / H0`` fade with erosion. The exterior (rim flank and ejecta) is the simple
crater's, with the complex rim height.

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
from typing import NamedTuple

import numba
import numpy as np

from terrain.core.checks import reject_unknown
from terrain.core.errors import InvalidParameterError

__all__ = [
    "Profile",
    "BETA_FROM_ALPHA",
    "COMPLEX_FIELDS",
    "Morphology",
    "complex_interior",
    "fresh_floor_fraction",
    "fresh_peak_height",
    "terrace_count",
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

#: Pike (1977) lunar complex craters: H0 = 1.044 D^0.301, Hr0 = 0.236 D^0.399 (D, H in km).
COMPLEX_DEPTH_COEFFICIENT = 1.044
COMPLEX_DEPTH_EXPONENT = 0.301
COMPLEX_RIM_COEFFICIENT = 0.236
COMPLEX_RIM_EXPONENT = 0.399
#: Pike (1977) floor diameter of lunar complex craters: Df = 0.187 D^1.249 (km).
FLOOR_COEFFICIENT = 0.187
FLOOR_EXPONENT = 1.249
#: Largest floor diameter over D (the fit passes 0.8 only for basins beyond 600 km).
FLOOR_FRACTION_MAX = 0.8
#: Central peak height above the floor, Hp0 = 0.0049 D^1.297 (km; after Hale and Head 1979).
PEAK_COEFFICIENT = 0.0049
PEAK_EXPONENT = 1.297
#: Largest peak height over the fresh depth: the power law is fitted to central peaks, and
#: capped here it does not raise a basin's peak ring above its rim (Tycho's peak stands about
#: a third of its depth above the floor).
PEAK_DEPTH_FRACTION_MAX = 0.4
#: Diameter of a central peak's base over D.
PEAK_BASE_FRACTION = 0.2
#: Peak-ring diameter over D (Baker et al. 2011: about 0.5 for lunar peak-ring basins).
RING_FRACTION = 0.5
#: Base width of the peak ring over D.
RING_WIDTH_FRACTION = 0.1
#: Slumping of a fresh complex crater's wall into terraces (0: a smooth parabolic wall).
TERRACE_STRENGTH = 0.5
#: Diameter per terrace (m): one terrace per 15 km of diameter, 2 to 6 of them.
TERRACE_SPACING = 15000.0
TERRACES_MIN = 2
TERRACES_MAX = 6
#: Lunar simple-to-complex transition (m): Pike's (1977) d/D distribution inflects at 15 km.
DEFAULT_TRANSITION_DIAMETER = 15000.0
#: Lunar central-peak to peak-ring transition (m; Baker et al. 2011).
DEFAULT_PEAK_RING_DIAMETER = 200000.0
#: Per-crater complex parameters (columns of the array the kernels take); floor_x <= -1
#: marks a simple crater.
COMPLEX_FIELDS = ("floor_x", "cap_t", "peak_height", "peak_x", "peak_halfwidth", "terraces",
                  "terrace_strength")


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
    """Return (a, b, c2, c3) of h3 and h4 from the constraints (see the module docstring).

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
    """Alpha (eq. 6, with the clamps of interior_height)."""
    c = min(floor, rim)
    d = rim - c
    a = max(bowl_curvature, d)
    if a <= 0.0:
        return -1.0
    return d / a - 1.0


@dataclass(frozen=True)
class Morphology:
    """Which craters are complex, and how (see the module docstring).

    Parameters
    ----------
    transition_diameter : float
        Craters wider than this (m) are complex. The lunar 15 km scales roughly as 1/g
        between bodies (Pike 1980), so on a small asteroid no crater reaches it.
    peak_ring_diameter : float
        Complex craters at least this wide (m) have a peak ring instead of a central peak.
    terraces : bool
        Terraced walls (False: smooth parabolic walls).
    enabled : bool
        False makes every crater simple, whatever its size.

    Examples
    --------
    >>> Morphology().is_complex(np.array([10e3, 40e3])).tolist()
    [False, True]
    >>> try:
    ...     Morphology.from_mapping({"transition_diametr": 5e3})
    ... except ValueError as exc:
    ...     print(exc)
    unknown crater morphology key 'transition_diametr' (did you mean 'transition_diameter'?)
    """

    transition_diameter: float = DEFAULT_TRANSITION_DIAMETER
    peak_ring_diameter: float = DEFAULT_PEAK_RING_DIAMETER
    terraces: bool = True
    enabled: bool = True

    def __post_init__(self):
        for name in ("transition_diameter", "peak_ring_diameter"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.number)):
                raise InvalidParameterError(f"crater morphology {name} must be a number of "
                                            f"metres; got {v!r}")
            v = float(v)
            if not (v > 0 and math.isfinite(v)):
                raise InvalidParameterError(
                    f"crater morphology {name} must be a positive number of metres; got {v}")
            object.__setattr__(self, name, v)
        if self.peak_ring_diameter <= self.transition_diameter:
            raise InvalidParameterError(
                "crater morphology peak_ring_diameter must exceed transition_diameter; got "
                f"{self.peak_ring_diameter} <= {self.transition_diameter}")
        for name in ("terraces", "enabled"):
            v = getattr(self, name)
            if not isinstance(v, (bool, np.bool_)):
                raise InvalidParameterError(f"crater morphology {name} must be true or false; "
                                            f"got {v!r}")
            object.__setattr__(self, name, bool(v))

    @classmethod
    def from_mapping(cls, data) -> Morphology:
        """Build from a mapping (a TOML table), rejecting unknown keys by name."""
        from dataclasses import fields

        if not isinstance(data, dict):
            raise InvalidParameterError(
                f"crater morphology must be a table; got {type(data).__name__}")
        reject_unknown(data, [f.name for f in fields(cls)], "crater morphology")
        return cls(**data)

    def is_complex(self, diameter) -> np.ndarray:
        """Boolean array: which diameters (m) make complex craters."""
        d = np.asarray(diameter, dtype=float)
        if not self.enabled:
            return np.zeros(d.shape, dtype=bool)
        return d > self.transition_diameter

    def as_dict(self) -> dict:
        """Return the morphology as plain data for metadata."""
        return dict(transition_diameter=self.transition_diameter,
                    peak_ring_diameter=self.peak_ring_diameter, terraces=self.terraces,
                    enabled=self.enabled)


def _km_fit(diameter, coefficient, exponent):
    d = np.asarray(diameter, dtype=float) / FIT_UNIT
    return coefficient * d**exponent * FIT_UNIT


def fresh_complex_depth(diameter):
    """Pike's (1977) complex-crater depth H0 (m) for diameter(s) in metres.

    >>> round(float(fresh_complex_depth(40e3)), 1)
    3169.0
    """
    return _km_fit(diameter, COMPLEX_DEPTH_COEFFICIENT, COMPLEX_DEPTH_EXPONENT)


def fresh_complex_rim_height(diameter):
    """Pike's (1977) complex-crater rim height Hr0 (m) for diameter(s) in metres.

    >>> round(float(fresh_complex_rim_height(40e3)), 1)
    1028.3
    """
    return _km_fit(diameter, COMPLEX_RIM_COEFFICIENT, COMPLEX_RIM_EXPONENT)


def fresh_floor_fraction(diameter):
    """Df / D of a complex crater (Pike 1977, capped at FLOOR_FRACTION_MAX).

    >>> round(float(fresh_floor_fraction(40e3)), 3)
    0.469
    """
    d = np.asarray(diameter, dtype=float)
    return np.minimum(FLOOR_FRACTION_MAX,
                      _km_fit(d, FLOOR_COEFFICIENT, FLOOR_EXPONENT) / d)


def fresh_peak_height(diameter):
    """Central peak (or peak ring) height above the floor, Hp0 (m), of a fresh crater.

    The power law, at most PEAK_DEPTH_FRACTION_MAX of the complex depth.

    >>> round(float(fresh_peak_height(86e3)))
    1582
    >>> round(float(fresh_peak_height(250e3) / fresh_complex_depth(250e3)), 2)
    0.4
    """
    return np.minimum(_km_fit(diameter, PEAK_COEFFICIENT, PEAK_EXPONENT),
                      PEAK_DEPTH_FRACTION_MAX * fresh_complex_depth(diameter))


def terrace_count(diameter):
    """Terraces on the wall: one per TERRACE_SPACING of diameter, TERRACES_MIN to _MAX."""
    d = np.asarray(diameter, dtype=float)
    return np.clip(np.round(d / TERRACE_SPACING), TERRACES_MIN, TERRACES_MAX)


@numba.njit(cache=True)
def _wall(t, terraces, strength):
    """g(t) and g'(t) of the terraced wall (see the module docstring)."""
    if strength > 0.0 and terraces >= 1.0:
        u = terraces * t
        k = math.floor(u)
        if k >= terraces:
            k = terraces - 1.0
        f = u - k
        s = (1.0 - strength) * t + strength * (k + f * f * (3.0 - 2.0 * f)) / terraces
        ds = (1.0 - strength) + strength * 6.0 * f * (1.0 - f)
    else:
        s = t
        ds = 1.0
    return s * s, 2.0 * s * ds


@numba.njit(cache=True)
def complex_interior(x, floor, rim, floor_x, cap_t, peak_height, peak_x, peak_halfwidth,
                     terraces, terrace_strength):
    """Interior of a complex crater at x in [-1, 0], relative to the plane (module docstring).

    ``floor`` is C = Hr - H, ``rim`` is E = Hr + Tr - Pr; the other arguments are the
    crater's :data:`COMPLEX_FIELDS`.
    """
    c = min(floor, rim)
    d = rim - c
    h = c
    if x > floor_x and d > 0.0:
        t = min(1.0, (x - floor_x) / (-floor_x))
        tc = cap_t
        g_c, dg_c = _wall(tc, terraces, terrace_strength)
        denom = g_c + 0.5 * dg_c * (1.0 - tc)
        if denom <= 0.0:
            h = rim
        else:
            k = d / denom
            if t <= tc:
                h = c + k * _wall(t, terraces, terrace_strength)[0]
            else:
                q = k * dg_c / (2.0 * (1.0 - tc))
                h = rim - q * (1.0 - t) ** 2
    if peak_height > 0.0 and peak_halfwidth > 0.0:
        rho = abs(x - peak_x) / peak_halfwidth
        if rho < 1.0:
            b = 1.0 - rho * rho
            h += peak_height * b * b
    return h


@numba.njit(cache=True)
def crater_interior(x, curvature, floor, rim, cplx):
    """Return the interior of a simple (``cplx[0] <= -1``) or complex crater at x (relative to P).

    ``cplx`` holds the crater's :data:`COMPLEX_FIELDS`.
    """
    if cplx[0] > -1.0:
        return complex_interior(x, floor, rim, cplx[0], cplx[1], cplx[2], cplx[3], cplx[4],
                                cplx[5], cplx[6])
    return interior_height(x, curvature, floor, rim)


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
    floor_x: float = -2.0
    cap_t: float = 1.0
    peak_height: float = 0.0
    peak_x: float = -1.0
    peak_halfwidth: float = 0.0
    terraces: float = 0.0
    terrace_strength: float = 0.0

    @classmethod
    def from_state(cls, diameter: float, depth_fraction: float = 1.0,
                   rim_fraction: float = 1.0,
                   morphology: Morphology | None = None) -> CraterShape:
        """Shape of a crater of ``diameter`` metres at the given erosion factors H/H0, Hr/Hr0.

        ``morphology`` decides whether it is complex (default: :class:`Morphology`'s lunar
        transition).
        """
        diameter = float(diameter)
        if not (diameter > 0 and math.isfinite(diameter)):
            raise InvalidParameterError(f"crater diameter must be positive; got {diameter}")
        for name, v in (("depth_fraction", depth_fraction), ("rim_fraction", rim_fraction)):
            if not 0.0 <= float(v) <= 1.0:
                raise InvalidParameterError(f"{name} must lie in [0, 1]; got {v}")
        arrays = shape_arrays(np.array([diameter]), np.array([float(depth_fraction)]),
                              np.array([float(rim_fraction)]), morphology)
        cplx = arrays.pop("complex")[0]
        fields = {k: float(v[0]) for k, v in arrays.items()}
        fields.update({k: float(v) for k, v in zip(COMPLEX_FIELDS, cplx, strict=True)})
        return cls(**fields)

    @property
    def is_complex(self) -> bool:
        """Whether the crater is complex (it has a flat floor)."""
        return self.floor_x > -1.0

    @property
    def complex_row(self) -> np.ndarray:
        """The :data:`COMPLEX_FIELDS` as the kernels take them."""
        return np.array([getattr(self, k) for k in COMPLEX_FIELDS], dtype=np.float64)

    @property
    def bowl_curvature(self) -> float:
        """A = Hr0 - Hr + H."""
        return self.fresh_rim_height - self.rim_height + self.depth

    @property
    def floor(self) -> float:
        """C = Hr - H: the floor relative to the plane."""
        return self.rim_height - self.depth


def shape_arrays(diameter, depth_fraction, rim_fraction,
                 morphology: Morphology | None = None) -> dict[str, np.ndarray]:
    """Vectorised :class:`CraterShape` fields for arrays of craters.

    Besides the fields of a simple crater, ``"complex"`` is an (n, 7) float64 array of the
    :data:`COMPLEX_FIELDS` (``floor_x`` = -2 for a simple crater).
    """
    morphology = morphology or Morphology()
    diameter = np.asarray(diameter, dtype=float)
    depth_fraction = np.broadcast_to(np.asarray(depth_fraction, dtype=float), diameter.shape)
    rim_fraction = np.broadcast_to(np.asarray(rim_fraction, dtype=float), diameter.shape)
    cx = morphology.is_complex(diameter)
    h0 = np.where(cx, fresh_complex_depth(diameter), fresh_depth(diameter))
    hr0 = np.where(cx, fresh_complex_rim_height(diameter), fresh_rim_height(diameter))
    h = h0 * depth_fraction
    hr = hr0 * rim_fraction
    ejecta = ejecta_amplitude(diameter) * rim_fraction
    curvature = hr0 - hr + h
    alpha = (hr - hr0) / curvature  # eq. 6 on flat ground (Tr = Pr)
    beta = np.minimum(BETA_MAX, BETA_FROM_ALPHA * np.abs(alpha))
    beta = np.where(beta < BETA_FRESH, 0.0, beta)
    a, b, c2, c3 = exterior_coefficients(hr, ejecta, beta)
    cplx = np.zeros((diameter.size, len(COMPLEX_FIELDS)))
    cplx[:, 0] = -2.0
    cplx[:, 1] = 1.0
    cplx[:, 3] = -1.0
    if cx.any():
        d = diameter.reshape(-1)[cx.reshape(-1)]
        ring = d >= morphology.peak_ring_diameter
        sel = cx.reshape(-1)
        cplx[sel, 0] = fresh_floor_fraction(d) - 1.0
        cplx[sel, 1] = 1.0 - np.abs(alpha.reshape(-1)[sel])
        cplx[sel, 2] = fresh_peak_height(d) * depth_fraction.reshape(-1)[sel]
        cplx[sel, 3] = np.where(ring, RING_FRACTION - 1.0, -1.0)
        cplx[sel, 4] = np.where(ring, RING_WIDTH_FRACTION, PEAK_BASE_FRACTION)
        if morphology.terraces:
            cplx[sel, 5] = terrace_count(d)
            cplx[sel, 6] = TERRACE_STRENGTH * rim_fraction.reshape(-1)[sel]
    return dict(diameter=diameter, depth=h, rim_height=hr, fresh_depth=h0,
                fresh_rim_height=hr0, ejecta=ejecta, alpha=alpha, beta=beta,
                a=a, b=b, c2=c2, c3=c3, complex=cplx)


class Profile(NamedTuple):
    """The coefficients of one crater's radial profile, as one numba argument.

    A namedtuple (numba passes it to a kernel as one value) of what
    :func:`crater_interior` and :func:`exterior_height` need.

    Attributes
    ----------
    curvature : float, metres
        Bowl curvature term (fresh rim height - rim height + depth).
    floor : float, metres
        Floor height relative to the fitted plane (rim height - depth).
    rim_height : float, metres
    ejecta, beta, a, b, c2, c3 : float
        Exterior profile coefficients (:class:`CraterShape`).
    complex : (7,) float64
        The :data:`COMPLEX_FIELDS` row (``floor_x`` = -2 for a simple crater).
    """

    curvature: float
    floor: float
    rim_height: float
    ejecta: float
    beta: float
    a: float
    b: float
    c2: float
    c3: float
    complex: np.ndarray


@numba.njit(cache=True)
def _profile_flat(x, shape, rim_offset, out):
    for i in range(x.size):
        xi = x[i]
        if xi <= 0.0:
            out[i] = crater_interior(xi, shape.curvature, shape.floor,
                                     shape.rim_height + rim_offset, shape.complex)
        elif xi <= 1.0:
            out[i] = exterior_height(xi, shape.rim_height, shape.ejecta, shape.beta, shape.a,
                                     shape.b, shape.c2, shape.c3)
        else:
            out[i] = 0.0


def profile(x, shape: CraterShape, rim_offset: float = 0.0) -> np.ndarray:
    """Return the radial profile at normalised distances ``x`` (float64 array, metres).

    Inside the rim (x <= 0) the value is relative to the fitted plane, outside it is the
    change added to the terrain; beyond x = 1 it is 0. ``rim_offset`` is ``Tr - Pr``.
    """
    x = np.asarray(x, dtype=float)
    out = np.empty(x.shape)
    coefficients = Profile(shape.bowl_curvature, shape.floor, shape.rim_height, shape.ejecta,
                           shape.beta, shape.a, shape.b, shape.c2, shape.c3, shape.complex_row)
    _profile_flat(np.ascontiguousarray(x).ravel(), coefficients, float(rim_offset),
                  out.reshape(-1))
    return out
