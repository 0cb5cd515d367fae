"""The mutual orbit of a binary asteroid and the spins of its two bodies.

Two bodies of mass ratio ``q = m_secondary / m_primary`` move on one Keplerian ellipse of
their relative position (secondary minus primary) about their common barycentre, which is the
world origin: the primary sits at ``-q / (1 + q)`` and the secondary at ``1 / (1 + q)`` times
the relative vector (Murray & Dermott 1999, *Solar System Dynamics*, section 2.7). The
relative orbit's elements are those of a heliocentric orbit measured in the world frame:
inclination from the world x-y plane, the ascending node from +x, the argument of periapsis
from the node, and the mean anomaly at time 0 (the scenario's first frame; ``t`` counts
seconds from there, as a trajectory's times do). The period fixes the system's mass through
Kepler's third law, ``G (m1 + m2) = 4 pi^2 a^3 / P^2``.

Spins: each body turns about its own axis (world frame) at its own period from a phase at
time 0 (:func:`render.trajectory.spin_rotation`). A secondary without a spin is tidally
locked: it rotates synchronously about the orbit normal, uniformly at the mean motion, with
its body +x axis pointing at the primary at periapsis (and always, on a circular orbit); on
an eccentric orbit it librates as a synchronous rotator does.

Defaults are the Didymos-Dimorphos system before DART's impact (named constants below).

>>> orbit = MutualOrbit()
>>> p, s = orbit.positions(0.0)
>>> round(float(np.linalg.norm(s - p)), 3)
1190.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import numpy.typing as npt

from render.camera import quat_from_matrix
from render.trajectory import spin_rotation
from terrain.core.checks import check_keys, number, vector
from terrain.core.errors import InvalidParameterError

__all__ = ["DIDYMOS_MASS_RATIO", "DIDYMOS_PERIOD_S", "DIDYMOS_SEPARATION_M",
           "DIDYMOS_SPIN_PERIOD_S", "MutualOrbit", "Spin", "eccentric_anomaly"]

#: Didymos-Dimorphos separation (semi-major axis of the mutual orbit), m: 1.19 +- 0.03 km
#: (Naidu et al. 2020, Icarus 348, 113777).
DIDYMOS_SEPARATION_M = 1190.0
#: Its orbital period before DART's impact, s: 11.921 h (Naidu et al. 2020; Scheirich &
#: Pravec 2009, Icarus 200, 531).
DIDYMOS_PERIOD_S = 11.921 * 3600.0
#: Mass ratio m_Dimorphos / m_Didymos of equal bulk densities with the diameters of Naidu et
#: al. 2020 (780 m and 164 m): (164 / 780)^3.
DIDYMOS_MASS_RATIO = (164.0 / 780.0) ** 3
#: Didymos's spin period, s: 2.2600 h (Pravec et al. 2006, Icarus 181, 63).
DIDYMOS_SPIN_PERIOD_S = 2.26 * 3600.0
#: Newton iterations of Kepler's equation: quadratic convergence from ``E0 = M + e sin M``
#: reaches double precision within this many for any e < 1.
KEPLER_ITERATIONS = 50
#: Keys of an ``[scene.orbit]`` table and of a ``[scene.*_spin]`` table.
ORBIT_KEYS = frozenset({"semi_major_axis", "eccentricity", "inclination", "node", "periapsis",
                        "mean_anomaly", "period", "mass_ratio"})
SPIN_KEYS = frozenset({"axis", "period", "phase"})


def eccentric_anomaly(mean_anomaly: npt.ArrayLike, eccentricity: float) -> np.ndarray:
    """Solve Kepler's equation ``E - e sin E = M`` by Newton's method.

    Parameters
    ----------
    mean_anomaly : float or (n,) float, radians
        Mean anomaly M.
    eccentricity : float
        e in [0, 1).

    Returns
    -------
    float64 array of M's shape, radians
        Eccentric anomaly E (same branch as M).

    >>> float(eccentric_anomaly(math.pi, 0.5))
    3.141592653589793
    """
    m = np.asarray(mean_anomaly, dtype=np.float64)
    e = float(eccentricity)
    ecc = m + e * np.sin(m)
    for _ in range(KEPLER_ITERATIONS):
        step = (ecc - e * np.sin(ecc) - m) / (1.0 - e * np.cos(ecc))
        ecc = ecc - step
        if np.all(np.abs(step) < 1e-15 * np.maximum(1.0, np.abs(ecc))):
            break
    return ecc


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class MutualOrbit:
    """The Keplerian mutual orbit of a binary (see the module docstring).

    Parameters
    ----------
    semi_major_axis : float, metres
        Of the relative orbit (the mean separation of the centres).
    eccentricity : float
        In [0, 1).
    inclination, node, periapsis : float, degrees
        Inclination from the world x-y plane, longitude of the ascending node from +x,
        argument of periapsis from the node.
    mean_anomaly : float, degrees
        At time 0.
    period : float, seconds
        Orbital period.
    mass_ratio : float
        m_secondary / m_primary, in (0, 1].
    """

    semi_major_axis: float = DIDYMOS_SEPARATION_M
    eccentricity: float = 0.0
    inclination: float = 0.0
    node: float = 0.0
    periapsis: float = 0.0
    mean_anomaly: float = 0.0
    period: float = DIDYMOS_PERIOD_S
    mass_ratio: float = DIDYMOS_MASS_RATIO

    def __post_init__(self):
        where = "binary orbit"
        for f in fields(self):
            object.__setattr__(self, f.name, number(getattr(self, f.name), f.name, where=where))
        number(self.semi_major_axis, "semi_major_axis", low=0, low_open=True, where=where)
        number(self.eccentricity, "eccentricity", low=0, high=1, high_open=True, where=where)
        number(self.period, "period", low=0, low_open=True, where=where)
        number(self.mass_ratio, "mass_ratio", low=0, low_open=True, high=1, where=where)

    @classmethod
    def from_mapping(cls, table: dict, where: str = "scenario [scene.orbit]") -> MutualOrbit:
        """Build the orbit of a ``[scene.orbit]`` table; an unknown key names the nearest.

        Parameters
        ----------
        table : dict
            Keys :data:`ORBIT_KEYS`; the missing ones keep the Didymos defaults.
        where : str
            What the table is called in messages.

        Returns
        -------
        MutualOrbit
        """
        t = check_keys(table, ORBIT_KEYS, where)
        return cls(**{k: number(v, k, where=where) for k, v in t.items()})

    @property
    def mean_motion(self) -> float:
        """Mean motion ``2 pi / period``, rad/s."""
        return 2.0 * math.pi / self.period

    @property
    def gm(self) -> float:
        """G (m1 + m2) from Kepler's third law, m^3 s^-2."""
        return self.mean_motion**2 * self.semi_major_axis**3

    @property
    def periapsis_distance(self) -> float:
        """Closest separation of the centres, ``a (1 - e)``, metres."""
        return self.semi_major_axis * (1.0 - self.eccentricity)

    @property
    def apoapsis_distance(self) -> float:
        """Largest separation of the centres, ``a (1 + e)``, metres."""
        return self.semi_major_axis * (1.0 + self.eccentricity)

    def orbit_rotation(self) -> np.ndarray:
        """Rotation from the perifocal frame (x to periapsis, z along the orbit normal) to world.

        Returns
        -------
        (3, 3) float64
            ``Rz(node) Rx(inclination) Rz(periapsis)``.
        """
        return (_rz(math.radians(self.node)) @ _rx(math.radians(self.inclination))
                @ _rz(math.radians(self.periapsis)))

    def mean_anomaly_at(self, t: npt.ArrayLike) -> np.ndarray:
        """Mean anomaly (radians) at time ``t`` (s)."""
        return math.radians(self.mean_anomaly) + self.mean_motion * np.asarray(t, np.float64)

    def relative(self, t: npt.ArrayLike) -> np.ndarray:
        """Position of the secondary relative to the primary at time ``t``.

        Parameters
        ----------
        t : float or (n,) float, seconds
            Times from the scenario's start.

        Returns
        -------
        (3,) or (n, 3) float64, metres, world frame
        """
        e, a = self.eccentricity, self.semi_major_axis
        ecc = eccentric_anomaly(self.mean_anomaly_at(t), e)
        x = a * (np.cos(ecc) - e)
        y = a * math.sqrt(1.0 - e * e) * np.sin(ecc)
        perifocal = np.stack([x, y, np.zeros_like(x)], axis=-1)
        return perifocal @ self.orbit_rotation().T

    def positions(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Centres of the primary and the secondary about the barycentre at time ``t``.

        Parameters
        ----------
        t : float, seconds

        Returns
        -------
        primary, secondary : (3,) float64, metres, world frame
        """
        r = self.relative(float(t))
        q = self.mass_ratio
        return -q / (1.0 + q) * r, 1.0 / (1.0 + q) * r

    def locked_rotation(self, t: float) -> np.ndarray:
        """R_WB (quaternion [w, x, y, z]) of a tidally locked secondary at time ``t``.

        Synchronous rotation about the orbit normal at the mean motion; body +x points at
        the primary at periapsis (module docstring).
        """
        angle = float(self.mean_anomaly_at(float(t))) + math.pi
        return quat_from_matrix(self.orbit_rotation() @ _rz(angle))

    def as_dict(self) -> dict:
        """Return the elements as plain data (the names of :data:`ORBIT_KEYS`)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


@dataclass(frozen=True)
class Spin:
    """A body's spin: axis (world frame), period (s; 0 for none), phase at time 0 (degrees).

    Parameters
    ----------
    axis : (3,) float
        Spin axis, world frame (any non-zero length).
    period : float, seconds
        Sidereal spin period; 0: the body does not turn.
    phase : float, degrees
        Rotation about the axis at time 0.
    """

    axis: tuple = (0.0, 0.0, 1.0)
    period: float = DIDYMOS_SPIN_PERIOD_S
    phase: float = 0.0

    def __post_init__(self):
        a = np.asarray(vector(self.axis, "axis", 3, where="body spin"), dtype=np.float64)
        if not np.linalg.norm(a) > 0:
            raise InvalidParameterError(f"body spin axis must be a non-zero vector; got {a}")
        object.__setattr__(self, "axis", tuple(a.tolist()))
        object.__setattr__(self, "period", number(self.period, "period", low=0,
                                                  where="body spin"))
        object.__setattr__(self, "phase", number(self.phase, "phase", where="body spin"))

    @classmethod
    def from_mapping(cls, table: dict, where: str, period: float = DIDYMOS_SPIN_PERIOD_S
                     ) -> Spin:
        """Build a spin from a ``[scene.primary_spin]`` or ``[scene.secondary_spin]`` table.

        Parameters
        ----------
        table : dict
            Keys ``axis``, ``period``, ``phase`` (:data:`SPIN_KEYS`).
        where : str
            What the table is called in messages.
        period : float
            The period where the table gives none (s).

        Returns
        -------
        Spin
        """
        if not isinstance(table, dict):
            raise InvalidParameterError(f"{where} must be a table; got {table!r}")
        t = check_keys(table, SPIN_KEYS, where)
        return cls(tuple(vector(t.get("axis", (0.0, 0.0, 1.0)), "axis", 3, where=where)),
                   number(t.get("period", period), "period", low=0, where=where),
                   number(t.get("phase", 0.0), "phase", where=where))

    def rotation(self, t: float) -> np.ndarray:
        """R_WB (quaternion [w, x, y, z]) at time ``t`` (s)."""
        return spin_rotation(float(t), self.axis, float(self.period), float(self.phase))

    def as_dict(self) -> dict:
        """Return the spin as plain data."""
        return {"axis": list(self.axis), "period": self.period, "phase": self.phase}
