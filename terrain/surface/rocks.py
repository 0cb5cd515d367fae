r"""Rock fields at lander scale: size-frequency models, shapes, placement and heights.

Models
------
The size-frequency models, selected by name (:class:`RockModel`). The lunar default is
``viper-nominal``.

``viper-nominal``, ``viper-low``, ``viper-high``
    The lunar rock populations of the VIPER environment specification (NASA's VIPER
    rover; the high case after Haworth), power laws of the cumulative number of rocks per
    m^2 (D in metres):
    ``N(>=D) = 3e-4 D^-2.482`` (nominal), ``1e-4 D^-1.755`` (low) and ``2e-3 D^-2.661``
    (high, Haworth). At 1 m they give 300, 100 and 2,000 rocks per km^2. Their range is
    ``dmin`` (two pixels of the finest layer, down to centimetres) to :data:`VIPER_DMAX`
    (5 m): the counts behind the laws reach a few metres, and larger boulders away from
    fresh craters are rare; the larger ones sit in fresh craters' block fields (below),
    which the model adds wherever it is given craters.
``golombek-rapp-mars``
    Golombek and Rapp (1997, JGR 102, 4117), eqs. 2-3, fitted to Viking and Pathfinder rock
    counts on Mars: the cumulative fractional area covered by rocks of diameter >= D is
    ``F_k(D) = k exp(-q(k) D)`` with ``q(k) = 1.79 + 0.152 / k`` (D in metres), k the total
    fraction of area covered by rocks (about 0.002 at Chang'E-4's site, up to 0.2 on rocky
    Mars sites). Differentiating, rocks of diameter D cover ``-dF/dD = q k exp(-q D)`` of the
    area per metre of D, so their number per m^2 per metre is
    ``n(D) = (4 q k / pi) exp(-q D) / D^2`` and

        N(>=D) = (4 q k / pi) (exp(-q D) / D - q E1(q D))

    with E1 the exponential integral (check: ``dN/dD = -n(D)``).
``power``
    ``N(>=D) = a D^b`` rocks per m^2 (b < 0; e.g. a = 3e-4, b = -2.482).

Diameters between ``dmin`` and ``dmax`` are drawn by inverse-transform sampling of N(>=D):
exact for the power law, and for Golombek-Rapp through a 4097-point table of log N(>=D)
against log D (interpolation error below 1e-5 relative).

Shapes
------
A rock is a perturbed, partly buried ellipsoid. Its horizontal axes a >= b and vertical
axis c follow the fragment shape statistics of laboratory impact fragments, a : b : c about
2 : sqrt(2) : 1 (Fujiwara et al. 1978, Icarus 31, 277), which is also what boulders on
Itokawa show (Michikami et al. 2010, Earth Planets Space 62, 151) and matches the height of
about half the diameter Golombek and Rapp (1997) assume for Mars rocks. Per rock,
``b/a ~ N(0.71, 0.1)`` and ``c/a ~ N(0.5, 0.1)``, clipped to [0.4, 1] and [0.25, b/a]. The
*diameter* D is the equal-area diameter ``sqrt(a b)``, so the rock's footprint covers
``pi D^2 / 4`` of the ground, exactly what F_k counts. A random yaw in [0, pi) orients the
long axis; three harmonics (orders 2-4, amplitudes up to :data:`SHAPE_PERTURBATION`)
perturb the outline and the height, so no two rocks are the same ellipsoid. A fraction
``beta ~ U(0, 0.5)`` of c is buried: at most half the rock, so no rock is sunk out of sight.

Resting: the base level z0 of a rock is the terrain height at its centre (bilinear in the
rock-free terrain). The rock's top is ``z0 + c (0.5 - beta) + (c / 2) sqrt(1 - rho^2)`` for a
normalised radius rho < 1 inside the outline, and the new height is the maximum of the
terrain and that top: a height field cannot hold an overhang, so the rock meets the terrain
with no gap below it (a vertical face down to the ground on its downhill side), and its
uphill side may be buried in the slope, as real rocks are.

Block fields around fresh craters
---------------------------------
The VIPER laws are site averages: they already hold the rocks of ordinary small craters'
ejecta. A fresh crater that digs through the regolith throws out blocks onto its rim and
ejecta, far denser than on the plains (Bart and Melosh 2010, Icarus 209, 337), and those
fade within a few hundred Myr; the block fields add what such craters add. Given craters
(x, y, diameter, age), each crater of diameter Dc gets:

* **Which craters**: the rock share of its excavated volume. A simple crater excavates to
  about ``0.1 Dc`` (:data:`EXCAVATION_DEPTH`; Melosh 1989, Impact Cratering, ch. 5), a
  paraboloid whose part below the regolith (``regolith_m``) is a paraboloid of depth
  ``0.1 Dc - regolith_m``: a share ``s = (1 - regolith_m / (0.1 Dc))^2`` of the volume is
  rock, 0 for craters that stay in the regolith (Quaide and Oberbeck 1968, JGR 73, 5247:
  craters of 4-10 regolith thicknesses reach the substrate; a 5 m regolith makes craters
  blocky from 50 m, a 10 m highland regolith from 100 m).
* **How many and how large**: ``N_c(>=d) = block_count s (d / d_ref)^block_index`` with
  ``d_ref = 4.4 m (Dc / 2.2 km)^0.66``. Linne (Dc 2.2 km) has 12,000 boulders >= 4.4 m with
  a cumulative index of -4.03 (Pajola et al. 2019, Planet. Space Sci. 165, 99); block sizes
  scale as Dc^0.66, as the largest boulder does (Bart and Melosh 2010: ``0.29 Dc^0.66`` m
  over 18 craters hundreds of metres across; the exponent, not geometric similarity). The
  size of which one block is expected is then ``45 m s^0.25 (Dc / 2.2 km)^0.66``, Bart and
  Melosh's largest boulder within 5 % for a crater in rock (Linne's measured largest is
  30.8 m). The law runs from there down to the size at which the blocks cover
  ``block_cover`` (10 %) of the field's area: fresh ejecta is bouldery, not paved.
* **Places**: uniform inside the rim, and falling as ``(R / r)^3`` outside it out to
  ``reach`` radii (ejecta thickness falls as r^-3, McGetchin et al. 1973, EPSL 20, 226;
  Linne's largest boulders lie within about two radii of its centre).
* **Age**: boulders are ground down by micrometeorites and thermal cycling; half of them
  survive about 40-80 Myr and 99 % are gone within 150-300 Myr (Basilevsky et al. 2013,
  Planet. Space Sci. 89, 118; the median survival of 40-80 Myr is confirmed by the
  boulder counts around young small craters of Watkins et al. 2019, JGR Planets 124,
  doi:10.1029/2019JE005963). Each block survives a crater's age t with probability
  ``2^(-t / half_life_gyr)`` (60 Myr), drawn per block, so an older field is a thinned
  subset of the same blocks.

Craters formed at the Neukum production rate (:mod:`terrain.craters.chronology`) then add,
averaged over a large area, 10-75 % to the nominal law between 6 cm and 1.25 m with a 5 m
regolith and 3-45 % with 10 m: a typical site stays within the VIPER low-high band, and a
site next to a young blocky crater is as rocky as its field.

Seamless placement
------------------
Diameters are split into octave bins from dmin (as craters are, :mod:`terrain.craters.population`);
each bin tiles the map plane with square cells anchored at (0, 0), sized so that a cell
expects :data:`CELL_EXPECTATION` rocks, and every number a rock needs is keyed
``(seed, "rocks", bin, cell column, cell row, counter)``. A rock is therefore a property of
the map: any window, tile or layer computed alone holds exactly the rocks of the full run,
and the heights are a pixel-wise maximum, independent of order.

Examples
--------
>>> round(float(RockModel.from_spec("viper-nominal:dmin=0.05").cumulative(1.0)) * 1e6)
300
>>> m = RockModel.from_spec("golombek-rapp-mars:k=0.02,dmin=0.1")
>>> round(float(m.fractional_area(0.0)), 6), round(m.q, 3)
(0.02, 9.39)
>>> RockModel.from_mapping({"model": "power", "a": 3e-4, "b": -2.482, "dmin": 0.5}).b
-2.482
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, fields

import numba
import numpy as np

from terrain.core import memory
from terrain.core import metakeys as mk
from terrain.core.checks import reject_unknown, text
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed, gaussian, hash64, poisson, stream_id, uniform_scalar
from terrain.craters.catalog import ROCK_COLUMNS, RockCatalog

__all__ = ["CELL_EXPECTATION", "DEFAULT_MODEL", "MIN_ROCK_PIXELS", "ROCK_COLUMNS", "VIPER",
           "VIPER_DMAX", "RockModel", "RockTable", "add_rocks", "rock_catalog", "rock_heights"]

log = logging.getLogger(__name__)

#: Expected rocks per generation cell of a bin (before thinning).
CELL_EXPECTATION = 16.0
#: A layer or DEM holds the rocks at least this many of its pixels across.
MIN_ROCK_PIXELS = 2.0
#: Largest relative amplitude of each of the three outline harmonics.
SHAPE_PERTURBATION = 0.08
#: Numbers drawn per rock (the counter stride in the rng key).
_NPAR = 14
#: Bytes held per rock while generating (columns and temporaries).
_BYTES_PER_ROCK = 200
#: Golombek-Rapp coefficients of q(k) = Q0 + Q1 / k (Golombek and Rapp 1997, eq. 3).
Q0, Q1 = 1.79, 0.152
#: Fragment axis ratios b/a and c/a, mean and spread (Fujiwara et al. 1978).
B_RATIO = (0.71, 0.1)
C_RATIO = (0.5, 0.1)

#: The VIPER environment specification's lunar rock laws, N(>=D) = a D^b per m^2 (D in m):
#: (a, b) by model name; the high case after Haworth.
VIPER: dict[str, tuple[float, float]] = {
    "viper-nominal": (3e-4, -2.482),
    "viper-low": (1e-4, -1.755),
    "viper-high": (2e-3, -2.661),
}
#: Largest background rock of the VIPER laws (m): "several metres"; bigger ones are blocks of
#: fresh craters' fields (module docstring).
VIPER_DMAX = 5.0
#: The lunar default rock model.
DEFAULT_MODEL = "viper-nominal"

#: Block fields (module docstring). Linne (Dc 2.2 km): 12,000 boulders >= 4.4 m with a
#: cumulative index of -4.03 (Pajola et al. 2019), the reference crater of the size law.
LINNE_DIAMETER = 2200.0
LINNE_BLOCK = 4.4
BLOCK_COUNT = 12000.0
BLOCK_INDEX = -4.03
#: Block sizes scale as Dc^0.66 (Bart and Melosh 2010, largest boulder 0.29 Dc^0.66 m).
BLOCK_SIZE_EXPONENT = 0.66
#: Excavation depth of a simple crater as a fraction of its diameter (Melosh 1989, ch. 5).
EXCAVATION_DEPTH = 0.1
#: Largest share of a block field's area its blocks cover (sets the smallest block).
BLOCK_COVER = 0.1
#: Block sizes run up to where this many blocks are expected per crater.
BLOCK_TOP_COUNT = 1.0
#: Ejecta reach of the block field, crater radii (Linne: about 2).
BLOCK_REACH = 2.0
#: Median boulder survival (Gyr): 40-80 Myr (Basilevsky et al. 2013; Watkins et al. 2019).
BLOCK_HALF_LIFE_GYR = 0.06
#: Block fields of craters whose blocks survive with less than this probability are skipped.
BLOCK_MIN_SURVIVAL = 1e-3
#: Geometric bins of a block field's sizes.
_BLOCK_BINS = 8

STREAM_COUNT = stream_id("rocks-count")
STREAM_ROCK = stream_id("rocks")
STREAM_UID = stream_id("rocks-uid")
STREAM_BLOCK_COUNT = stream_id("rock-blocks-count")
STREAM_BLOCK = stream_id("rock-blocks")
STREAM_BLOCK_UID = stream_id("rock-blocks-uid")

MODELS = ("golombek-rapp-mars", "power", *VIPER)


@dataclass(frozen=True)
class RockModel:
    """A rock population: size-frequency model, diameter range, shapes and crater block fields.

    Parameters
    ----------
    model : {"viper-nominal", "viper-low", "viper-high", "golombek-rapp-mars", "power"}
    k : float
        Golombek-Rapp total rock fraction, 0 < k < 1.
    a, b : float
        Power law N(>=D) = a D^b per m^2: a > 0, b < 0 (set by the VIPER models).
    dmin, dmax : float
        Diameter range (m). dmax defaults to :data:`VIPER_DMAX` for the VIPER models, else to
        the diameter above which fewer than 1e-6 of the model's area (Golombek-Rapp) or
        number (power) remains, capped at 30 m.
    craters : bool
        Give fresh craters block fields (module docstring) when craters are given.
    block_count : float
        Blocks >= 4.4 m around a fresh crater of Linne's size (2.2 km) that excavates
        only rock; other sizes scale as the module docstring says.
    block_index : float
        Cumulative index of the block sizes (< -2).
    block_cover : float
        Largest share of a block field's area its blocks cover, 0 < cover < 1.
    half_life_gyr : float
        Median survival of a boulder on the surface (Gyr).
    reach : float
        Extent of a block field in crater radii (>= 1).
    regolith_m : float
        Regolith thickness (m): craters excavate rock below it, none when
        ``0.1 D <= regolith_m``.
    """

    model: str = DEFAULT_MODEL
    k: float | None = None
    a: float | None = None
    b: float | None = None
    dmin: float | None = None
    dmax: float | None = None
    craters: bool = True
    block_count: float = BLOCK_COUNT
    block_index: float = BLOCK_INDEX
    block_cover: float = BLOCK_COVER
    half_life_gyr: float = BLOCK_HALF_LIFE_GYR
    reach: float = BLOCK_REACH
    regolith_m: float = 5.0

    def __post_init__(self):
        text(self.model, "rock model", choices=MODELS)
        for f in fields(self):
            if f.name in ("model", "craters"):
                continue
            value = getattr(self, f.name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise InvalidParameterError(f"rock {f.name} must be a number; got {value!r}")
            value = float(value)
            if not math.isfinite(value):
                raise InvalidParameterError(f"rock {f.name} must be finite; got {value}")
            object.__setattr__(self, f.name, value)
        if not isinstance(self.craters, bool):
            raise InvalidParameterError(f"rock craters must be true or false; got "
                                        f"{self.craters!r}")
        if self.model in VIPER:
            fixed = dict(zip(("a", "b"), VIPER[self.model], strict=True))
            for name in ("a", "b", "k"):
                # the model's own published value (a record read back) is no override
                if getattr(self, name) is not None and getattr(self, name) != fixed.get(name):
                    raise InvalidParameterError(
                        f"'{name}' is fixed by the {self.model} rock model (use the power "
                        "model for another law)")
            a, b = VIPER[self.model]
            object.__setattr__(self, "a", a)
            object.__setattr__(self, "b", b)
            if self.dmax is None:
                object.__setattr__(self, "dmax", VIPER_DMAX)
        elif self.model == "golombek-rapp-mars":
            if self.k is None:
                raise InvalidParameterError("the golombek-rapp-mars rock model needs k (rock "
                                            "area fraction, 0 < k < 1)")
            if not 0 < self.k < 1:
                raise InvalidParameterError(
                    f"golombek-rapp-mars k (fraction of area covered by rocks) must lie in "
                    f"(0, 1); got {self.k:g}")
            for name in ("a", "b"):
                if getattr(self, name) is not None:
                    raise InvalidParameterError(f"'{name}' belongs to the power rock model, "
                                                "not golombek-rapp-mars")
        else:
            if self.a is None or self.b is None:
                raise InvalidParameterError("the power rock model needs a and b "
                                            "(N(>=D) = a D^b per m^2)")
            if not self.a > 0:
                raise InvalidParameterError(f"power a must be positive; got {self.a:g}")
            if not self.b < 0:
                raise InvalidParameterError(
                    f"power b must be negative (N(>=D) = a D^b falls with D); got {self.b:g}")
            if self.k is not None:
                raise InvalidParameterError("'k' belongs to the golombek-rapp-mars rock "
                                            "model, not power")
        if self.dmin is None:
            raise InvalidParameterError("rock dmin (smallest diameter, m) is needed")
        if not self.dmin > 0:
            raise InvalidParameterError(f"rock dmin must be positive; got {self.dmin:g}")
        if self.dmax is None:
            object.__setattr__(self, "dmax", self._default_dmax())
        if not self.dmax > self.dmin:
            raise InvalidParameterError(
                f"rock dmin must be smaller than dmax; got dmin={self.dmin:g}, "
                f"dmax={self.dmax:g}")
        for name in ("block_count", "half_life_gyr", "reach", "regolith_m"):
            if not getattr(self, name) > 0:
                raise InvalidParameterError(f"rock {name} must be positive; got "
                                            f"{getattr(self, name):g}")
        if self.reach < 1:
            raise InvalidParameterError(f"rock reach must be >= 1 crater radius; got "
                                        f"{self.reach:g}")
        if not self.block_index < -2:
            raise InvalidParameterError(f"rock block_index must be below -2 (blocks cover a "
                                        f"finite area); got {self.block_index:g}")
        if not 0 < self.block_cover < 1:
            raise InvalidParameterError(f"rock block_cover must lie in (0, 1); got "
                                        f"{self.block_cover:g}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_mapping(cls, data, *, defaults=None) -> RockModel:
        """Model from a dict (TOML table, parsed spec); unknown keys are refused by name.

        >>> RockModel.from_mapping({"model": "golombek-rapp-mars", "kk": 0.1})
        Traceback (most recent call last):
        ...
        terrain.core.errors.InvalidParameterError: unknown rock key 'kk' (did you mean 'k'?)
        """
        data = dict(data)
        reject_unknown(data, [f.name for f in fields(cls)], "rock")
        return cls(**{**(defaults or {}), **data})

    @classmethod
    def from_spec(cls, spec: str, *, defaults=None) -> RockModel:
        """Model from ``NAME:key=value,...`` (``viper-nominal``, ``power:a=3e-4,b=-2.5``).

        Values are numbers, or true/false for ``craters``.
        """
        text = str(spec).strip()
        name, _, rest = text.partition(":")
        data: dict = {"model": name.strip()}
        for item in filter(None, (p.strip() for p in rest.split(","))):
            key, eq, value = item.partition("=")
            if not eq:
                raise InvalidParameterError(
                    f"rock spec '{spec}': expected key=value, got '{item}'")
            key, value = key.strip(), value.strip()
            if value.lower() in ("true", "false", "on", "off"):
                data[key] = value.lower() in ("true", "on")
                continue
            try:
                data[key] = float(value)
            except ValueError:
                raise InvalidParameterError(
                    f"rock spec '{spec}': {key} must be a number; got '{value}'") from None
        return cls.from_mapping(data, defaults=defaults)

    def as_dict(self) -> dict:
        """Return the model's set parameters as plain data for metadata."""
        return {k: v for k, v in asdict(self).items() if v is not None}

    # ------------------------------------------------------------------ statistics
    # The parameters a validated model always has for its kind (``__post_init__`` refuses a
    # model without them and fills in dmax), as floats for the statistics below.
    @property
    def _k(self) -> float:
        return _given(self.k, "k")

    @property
    def _a(self) -> float:
        return _given(self.a, "a")

    @property
    def _b(self) -> float:
        return _given(self.b, "b")

    @property
    def _dmin(self) -> float:
        return _given(self.dmin, "dmin")

    @property
    def _dmax(self) -> float:
        return _given(self.dmax, "dmax")

    @property
    def q(self) -> float:
        """q(k) = 1.79 + 0.152 / k (Golombek and Rapp 1997, eq. 3), per metre."""
        return Q0 + Q1 / self._k

    def _default_dmax(self) -> float:
        if self.model == "golombek-rapp-mars":
            d = -math.log(1e-6) / self.q  # F_k(d) = 1e-6 k
        else:
            d = self._dmin * 1e-6 ** (1.0 / self._b)
        return float(min(max(d, 2.0 * self._dmin), 30.0))

    def fractional_area(self, diameter):
        """Cumulative fractional area of rocks >= D (untruncated model), dimensionless."""
        d = np.asarray(diameter, dtype=float)
        if self.model == "golombek-rapp-mars":
            return self._k * np.exp(-self.q * d)  # Golombek and Rapp 1997, eq. 2
        # power law: F(>=D) = int_D^inf (pi x^2 / 4) (-a b x^(b-1)) dx, finite for b < -2
        if self._b >= -2:
            return np.full(d.shape, np.inf)
        return math.pi / 4 * self._a * (-self._b) / (-self._b - 2) * d ** (self._b + 2)

    def cumulative(self, diameter):
        """N(>=D), rocks per m^2 (untruncated model)."""
        d = np.asarray(diameter, dtype=float)
        if self.model != "golombek-rapp-mars":
            return self._a * d ** self._b
        from scipy.special import exp1

        q = self.q
        return 4 * q * self._k / math.pi * (np.exp(-q * d) / d - q * exp1(q * d))

    def bins(self) -> np.ndarray:
        """(n, 2) octave diameter bins from dmin, the last truncated at dmax."""
        edges = [self._dmin]
        while edges[-1] * 2 < self._dmax * (1 - 1e-12):
            edges.append(edges[-1] * 2)
        edges.append(self._dmax)
        return np.column_stack([edges[:-1], edges[1:]])

    def bin_density(self, d_lo: float, d_hi: float) -> float:
        """Rocks per m^2 with diameter in [d_lo, d_hi)."""
        return float(self.cumulative(d_lo) - self.cumulative(d_hi))

    def expected_count(self, area_m2: float, min_diameter: float = 0.0) -> float:
        """Background rocks in [max(dmin, min_diameter), dmax) over an area (m^2)."""
        lo = max(self._dmin, min_diameter)
        if lo >= self._dmax:
            return 0.0
        return self.bin_density(lo, self._dmax) * float(area_m2)

    # ------------------------------------------------------------------ block fields
    @property
    def blocky_diameter(self) -> float:
        """Smallest crater diameter (m) whose excavation reaches below the regolith."""
        return self.regolith_m / EXCAVATION_DEPTH

    def rock_share(self, crater_diameter):
        """Share of a crater's excavated volume that is rock below the regolith.

        The excavation cavity is a paraboloid of depth ``0.1 Dc``; the part below the regolith
        is a paraboloid of depth ``0.1 Dc - regolith_m``, so its share of the volume is
        ``(1 - regolith_m / (0.1 Dc))^2`` (0 for craters that stay in the regolith).
        """
        dc = np.asarray(crater_diameter, float)
        depth = EXCAVATION_DEPTH * dc
        with np.errstate(divide="ignore", invalid="ignore"):
            share = np.where(depth > self.regolith_m,
                             (1.0 - self.regolith_m / np.maximum(depth, 1e-300)) ** 2, 0.0)
        return share

    def _block_law(self, crater_diameter):
        """Per crater: the law's coefficient c (N(>=d) = c d^index) and its size range.

        Returns (c, lo, hi) arrays: the smallest block, where the blocks >= it cover
        ``block_cover`` of the field ``pi (reach Dc / 2)^2``, and the largest, where
        ``BLOCK_TOP_COUNT`` block is expected (lo = hi = 0 where a crater has no field).
        """
        dc = np.atleast_1d(np.asarray(crater_diameter, float))
        alpha = self.block_index
        scale = LINNE_BLOCK * (dc / LINNE_DIAMETER) ** BLOCK_SIZE_EXPONENT
        c = self.block_count * self.rock_share(dc) * scale ** -alpha
        ok = c > 0
        cs = np.where(ok, c, 1.0)
        hi = (BLOCK_TOP_COUNT / cs) ** (1.0 / alpha)
        # blocks >= d cover c (-alpha) / (-alpha - 2) (pi / 4) d^(alpha + 2) of the ground
        field = self.block_cover * (self.reach * dc) ** 2
        lo = (field * (-alpha - 2) / (-alpha * cs)) ** (1.0 / (alpha + 2))
        ok &= lo < hi
        return np.where(ok, c, 0.0), np.where(ok, lo, 0.0), np.where(ok, hi, 0.0)

    def block_cumulative(self, d, crater_diameter, age_gyr=0.0):
        """Return the expected blocks >= d (m) in one crater's field (its age's survivors)."""
        c, lo, hi = self._block_law(crater_diameter)
        dd = np.clip(np.asarray(d, float), lo, hi)
        with np.errstate(divide="ignore"):
            n = np.where(c > 0, c * np.where(dd > 0, dd, 1.0) ** self.block_index
                         - BLOCK_TOP_COUNT, 0.0)
        n = n * self.block_survival(age_gyr)
        return n if np.ndim(d) or np.ndim(crater_diameter) else float(n[0])

    def largest_block(self, crater_diameter) -> np.ndarray:
        """Size (m) of which one block is expected in a fresh crater's field (0: none)."""
        return self._block_law(crater_diameter)[2]

    def block_survival(self, age_gyr):
        """Share of a crater's blocks that survive its age (Gyr)."""
        return 2.0 ** (-np.asarray(age_gyr, float) / self.half_life_gyr)

    def crater_margin(self, crater_diameter: float) -> float:
        """Distance (m) from a crater's centre beyond which none of its blocks reaches."""
        hi = float(self._block_law(crater_diameter)[2][0])
        return self.reach * crater_diameter / 2 + _half_length(hi)

    def _block_sources(self, craters) -> np.ndarray:
        """(n, 7) x, y, diameter, survival, law coefficient, smallest and largest block."""
        if craters is None or not self.craters or not len(craters):
            return np.empty((0, 7))
        d = np.asarray(craters.diameter, float)
        surv = self.block_survival(craters.age)
        c, lo, hi = self._block_law(d)
        keep = (c > 0) & (surv >= BLOCK_MIN_SURVIVAL)
        return np.ascontiguousarray(np.column_stack([
            np.asarray(craters.x, float)[keep], np.asarray(craters.y, float)[keep], d[keep],
            surv[keep], c[keep], lo[keep], hi[keep]]))

    def _table(self, d_lo, d_hi):
        """(log D, log N(>=D)) table of one bin for inverse-transform sampling."""
        d = np.geomspace(d_lo, d_hi, 4097)
        return np.log(d), np.log(self.cumulative(d))

    # ------------------------------------------------------------------ placement
    def generate(self, seed: int, extent, *, min_diameter: float = 0.0, craters=None,
                 margin: bool = True) -> RockTable:
        """Every rock whose outline may touch ``extent`` (or whose centre lies in it).

        Parameters
        ----------
        seed : int
        extent : (xmin, ymin, xmax, ymax), map metres
        min_diameter : float
            Drop rocks smaller than this (bins wholly below it are never enumerated).
        craters : CraterTable, optional
            Craters (map metres, ages in Gyr) whose block fields are added when
            ``self.craters`` (module docstring).
        margin : bool
            Grow the extent by each bin's largest half-length, so rocks centred outside that
            reach into it are included (heights); False: centres inside only (catalogues).
        """
        seed = check_seed(seed)
        xmin, ymin, xmax, ymax = (float(v) for v in extent)
        if not (xmax >= xmin and ymax >= ymin):
            raise InvalidParameterError(f"rock extent must have xmin <= xmax and ymin <= ymax; "
                                        f"got {extent}")
        bins = self.bins()
        plans = []
        expected = 0.0
        for b, (d_lo, d_hi) in enumerate(bins):
            if d_hi <= min_diameter:
                continue
            grow = _half_length(d_hi) if margin else 0.0
            box = (xmin - grow, ymin - grow, xmax + grow, ymax + grow)
            n = self.bin_density(d_lo, d_hi)
            if n <= 0:
                continue
            cell = math.sqrt(CELL_EXPECTATION / n)
            area = (box[2] - box[0] + 2 * cell) * (box[3] - box[1] + 2 * cell)
            expected += n * area
            plans.append((b, d_lo, d_hi, cell, box))
        src = self._block_sources(craters)
        if len(src):
            lo = np.maximum(src[:, 5], np.minimum(float(min_diameter), src[:, 6]))
            n_lo = src[:, 4] * lo ** self.block_index - BLOCK_TOP_COUNT
            expected += float(np.sum(np.maximum(n_lo, 0.0) * src[:, 3]))
        memory.require(expected * _BYTES_PER_ROCK,
                       f"a rock field of about {expected:.3g} rocks")
        parts = []
        for b, d_lo, d_hi, cell, box in plans:
            logd, logn = self._table(d_lo, d_hi)
            ix0, ix1 = math.floor(box[0] / cell), math.floor(box[2] / cell)
            iy0, iy1 = math.floor(box[1] / cell), math.floor(box[3] / cell)
            lam = self.bin_density(d_lo, d_hi) * cell * cell
            args = (seed, b, cell, lam, logd, logn, ix0, ix1, iy0, iy1, *box)
            n = _place(*args, np.empty((0, _OUT)), np.empty(0, np.uint64), True)
            out = np.empty((n, _OUT))
            uid = np.empty(n, np.uint64)
            _place(*args, out, uid, False)
            keep = out[:, 2] >= min_diameter
            parts.append((out[keep], uid[keep]))
        if len(src):
            blocks = (seed, src, self.block_index, self.reach, xmin, ymin,
                      xmax, ymax, bool(margin), float(min_diameter))
            n = _place_blocks(*blocks, np.empty((0, _OUT)), np.empty(0, np.uint64), True)
            out = np.empty((n, _OUT))
            uid = np.empty(n, np.uint64)
            _place_blocks(*blocks, out, uid, False)
            parts.append((out, uid))
        if parts:
            out = np.concatenate([p[0] for p in parts])
            uid = np.concatenate([p[1] for p in parts])
        else:
            out, uid = np.empty((0, _OUT)), np.empty(0, np.uint64)
        return RockTable(out, uid)


def _given(value: float | None, name: str) -> float:
    """Return a model parameter ``__post_init__`` has checked is present for the model."""
    if value is None:  # pragma: no cover - __post_init__ refuses such a model
        raise InvalidParameterError(f"rock {name} is needed by this rock model")
    return value


def _half_length(d: float) -> float:
    """Return the largest half-length of a rock of diameter d.

    a = d / sqrt(b/a) with b/a >= 0.4, and the outline perturbation.
    """
    return 0.5 * d / math.sqrt(0.4) * (1 + 3 * SHAPE_PERTURBATION)


# ---------------------------------------------------------------------------- kernels

#: Columns of the generator's output rows.
_X, _Y, _D, _A, _B, _C, _YAW, _BETA, _H0 = range(9)
_OUT = 9 + 6  # and three (amplitude, phase) outline harmonics


@numba.njit(cache=True)
def _interp(x, xs, ys):
    """Linear interpolation of decreasing ys (log N) at x, xs increasing (log D)."""
    n = xs.size
    lo, hi = 0, n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ys[mid] > x:
            lo = mid
        else:
            hi = mid
    t = (x - ys[lo]) / (ys[hi] - ys[lo]) if ys[hi] != ys[lo] else 0.0
    return xs[lo] + t * (xs[hi] - xs[lo])


@numba.njit(cache=True)
def _clip(v, lo, hi):
    return min(max(v, lo), hi)


@numba.njit(cache=True)
def _shape(out, n, x, y, d, seed, stream, b, ix, iy, k0):
    """Write rock n's row: centre, diameter and a fragment shape from keys k0 + 4 ... k0 + 13."""
    rb = _clip(0.71 + 0.1 * gaussian(uniform_scalar(seed, stream, b, ix, iy, k0 + 4)), 0.4, 1.0)
    rc = _clip(0.5 + 0.1 * gaussian(uniform_scalar(seed, stream, b, ix, iy, k0 + 5)), 0.25, rb)
    a = d / math.sqrt(rb)
    out[n, _X] = x
    out[n, _Y] = y
    out[n, _D] = d
    out[n, _A] = a
    out[n, _B] = a * rb
    out[n, _C] = a * rc
    out[n, _YAW] = math.pi * uniform_scalar(seed, stream, b, ix, iy, k0 + 6)
    out[n, _BETA] = 0.5 * uniform_scalar(seed, stream, b, ix, iy, k0 + 7)
    out[n, _H0] = 0.0
    for h in range(3):
        out[n, 9 + 2 * h] = SHAPE_PERTURBATION * (2.0 * uniform_scalar(
            seed, stream, b, ix, iy, k0 + 8 + 2 * h) - 1.0)
        out[n, 10 + 2 * h] = 2.0 * math.pi * uniform_scalar(seed, stream, b, ix, iy,
                                                             k0 + 9 + 2 * h)


@numba.njit(cache=True)
def _place(seed, b, cell, lam, logd, logn, ix0, ix1, iy0, iy1, lo_x, lo_y, hi_x, hi_y,
           out, uid, count_only):
    n = 0
    n_lo = math.exp(logn[0])
    n_hi = math.exp(logn[-1])
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            count = poisson(uniform_scalar(seed, STREAM_COUNT, b, ix, iy, 0), lam)
            for j in range(count):
                k0 = _NPAR * j
                x = (ix + uniform_scalar(seed, STREAM_ROCK, b, ix, iy, k0)) * cell
                y = (iy + uniform_scalar(seed, STREAM_ROCK, b, ix, iy, k0 + 1)) * cell
                if x < lo_x or x > hi_x or y < lo_y or y > hi_y:
                    continue
                if not count_only:
                    u = uniform_scalar(seed, STREAM_ROCK, b, ix, iy, k0 + 2)
                    # N(>=D) between the bin's ends, inverted through the log table
                    target = math.log(n_lo - u * (n_lo - n_hi))
                    d = math.exp(_interp(target, logd, logn))
                    _shape(out, n, x, y, d, seed, STREAM_ROCK, b, ix, iy, k0)
                    uid[n] = hash64(seed, STREAM_UID, b, ix, iy, j)
                n += 1
    return n


@numba.njit(cache=True)
def _place_blocks(seed, src, alpha, reach, xmin, ymin, xmax, ymax, margin, min_d, out, uid,
                  count_only):
    """Blocks of the craters' fields (module docstring) whose outline may touch the extent.

    A block is keyed by its crater's position (millimetres), its size bin and its number in
    the bin, so every window and layer sees the same blocks of a crater.
    """
    n = 0
    # uniform inside the rim (area pi R^2) and (R / r)^3 out to reach R (2 pi R^2 (1 - 1/reach))
    inner = 1.0 / (3.0 - 2.0 / reach)
    for c in range(src.shape[0]):
        cx, cy, dc, surv = src[c, 0], src[c, 1], src[c, 2], src[c, 3]
        coef, d_lo, d_hi = src[c, 4], src[c, 5], src[c, 6]
        step = (d_hi / d_lo) ** (1.0 / _BLOCK_BINS)
        ix = np.int64(round(cx * 1000.0))
        iy = np.int64(round(cy * 1000.0))
        rad = 0.5 * dc
        for bi in range(_BLOCK_BINS):
            lo = d_lo * step ** bi
            hi = d_hi if bi == _BLOCK_BINS - 1 else d_lo * step ** (bi + 1)
            if hi <= min_d:
                continue
            grow = 0.5 * hi / math.sqrt(0.4) * (1 + 3 * SHAPE_PERTURBATION) if margin else 0.0
            lo_x, hi_x, lo_y, hi_y = xmin - grow, xmax + grow, ymin - grow, ymax + grow
            gx = max(lo_x - cx, 0.0, cx - hi_x)
            gy = max(lo_y - cy, 0.0, cy - hi_y)
            if math.hypot(gx, gy) > reach * rad:
                continue
            count = poisson(uniform_scalar(seed, STREAM_BLOCK_COUNT, bi, ix, iy, 0),
                            coef * (lo ** alpha - hi ** alpha))
            for j in range(count):
                k0 = _NPAR * j
                if uniform_scalar(seed, STREAM_BLOCK, bi, ix, iy, k0 + 3) >= surv:
                    continue  # ground down since the crater formed
                u = uniform_scalar(seed, STREAM_BLOCK, bi, ix, iy, k0 + 1)
                if u < inner:
                    r = rad * math.sqrt(u / inner)
                else:
                    r = rad / (1.0 - (u - inner) / (2.0 * inner))
                theta = 2.0 * math.pi * uniform_scalar(seed, STREAM_BLOCK, bi, ix, iy, k0)
                x = cx + r * math.cos(theta)
                y = cy + r * math.sin(theta)
                if x < lo_x or x > hi_x or y < lo_y or y > hi_y:
                    continue
                # N(>=d) ~ d^alpha between the bin's ends
                v = uniform_scalar(seed, STREAM_BLOCK, bi, ix, iy, k0 + 2)
                d = (lo ** alpha - v * (lo ** alpha - hi ** alpha)) ** (1.0 / alpha)
                if d < min_d:
                    continue
                if not count_only:
                    _shape(out, n, x, y, d, seed, STREAM_BLOCK, bi, ix, iy, k0)
                    uid[n] = hash64(seed, STREAM_BLOCK_UID, bi, ix, iy, j)
                n += 1
    return n


class RockTable:
    """Columns of rocks (map metres): see :data:`ROCK_COLUMNS` and the module docstring.

    ``rows`` is (n, 15) float64: x, y, diameter, axes a, b, c, yaw (rad), burial fraction,
    unused, then three (amplitude, phase) outline harmonics; ``uid`` (n,) uint64.
    """

    def __init__(self, rows: np.ndarray, uid: np.ndarray):
        rows = np.asarray(rows, dtype=np.float64).reshape(-1, _OUT)
        uid = np.asarray(uid, dtype=np.uint64).reshape(-1)
        if len(uid) != len(rows):
            raise InvalidParameterError("rock rows and ids differ in length")
        order = np.lexsort((uid,))  # one order, whatever window enumerated them
        self.rows = np.ascontiguousarray(rows[order])
        self.uid = uid[order]

    def __len__(self) -> int:
        return len(self.uid)

    x = property(lambda self: self.rows[:, _X])
    y = property(lambda self: self.rows[:, _Y])
    diameter = property(lambda self: self.rows[:, _D])
    axes = property(lambda self: self.rows[:, _A:_C + 1])
    yaw = property(lambda self: self.rows[:, _YAW])
    burial_fraction = property(lambda self: self.rows[:, _BETA])

    @property
    def height(self):
        """Exposed height above the base level z0 (m)."""
        return self.rows[:, _C] * (1.0 - self.rows[:, _BETA])

    @property
    def outline_radius(self):
        """Farthest reach of each rock's outline from its centre (m).

        Half its long axis stretched by its harmonics: what :func:`rasterise_rocks` may touch.
        """
        return 0.5 * self.rows[:, _A] * (1.0 + np.abs(self.rows[:, 9]) + np.abs(self.rows[:, 11])
                                         + np.abs(self.rows[:, 13]))

    def take(self, index) -> RockTable:
        """Return the rocks selected by ``index`` (an index array or boolean mask)."""
        return RockTable(self.rows[index], self.uid[index])

    def inside(self, extent) -> RockTable:
        """Rocks whose centre lies in (xmin, ymin, xmax, ymax)."""
        xmin, ymin, xmax, ymax = extent
        return self.take(np.flatnonzero((self.x >= xmin) & (self.x <= xmax)
                                        & (self.y >= ymin) & (self.y <= ymax)))


# ---------------------------------------------------------------------------- heights


@numba.njit(cache=True)
def bilinear_at(T, tr0, tc0, ny, nx, x0, y0, res, x, y):
    """Return the bilinear height of a layer at map (x, y), clamped to the layer's edges.

    Parameters
    ----------
    T : (h, w) float array, metres
        The part of the layer starting at its pixel (tr0, tc0) (the whole layer: 0, 0); it
        must hold the pixels around (x, y).
    tr0, tc0 : int
    ny, nx : int
        The whole layer's size.
    x0, y0 : float, map metres
        The whole layer's upper-left corner.
    res : float, metres
        Pixel size.
    x, y : float, map metres

    Returns
    -------
    float, metres
    """
    c = (x - x0) / res - 0.5
    r = (y0 - y) / res - 0.5
    c = min(max(c, 0.0), nx - 1.0)
    r = min(max(r, 0.0), ny - 1.0)
    i0 = min(int(r), ny - 2) if ny > 1 else 0
    j0 = min(int(c), nx - 2) if nx > 1 else 0
    i1 = min(i0 + 1, ny - 1)
    j1 = min(j0 + 1, nx - 1)
    ti = r - i0
    tj = c - j0
    i0 -= tr0
    i1 -= tr0
    j0 -= tc0
    j1 -= tc0
    return ((T[i0, j0] * (1 - tj) + T[i0, j1] * tj) * (1 - ti)
            + (T[i1, j0] * (1 - tj) + T[i1, j1] * tj) * ti)


@numba.njit(cache=True)
def _base_levels(T, x0, y0, res, rows, out):
    ny, nx = T.shape
    for i in range(rows.shape[0]):
        out[i] = bilinear_at(T, 0, 0, ny, nx, x0, y0, res, rows[i, _X], rows[i, _Y])


@numba.njit(cache=True)
def rasterise_rocks(z, r0, c0, x0, y0, res, rows, z0):
    """Raise z (a window starting at global pixel r0, c0) to every rock's top."""
    ny, nx = z.shape
    for i in range(rows.shape[0]):
        cx, cy = rows[i, _X], rows[i, _Y]
        a2, b2, c = 0.5 * rows[i, _A], 0.5 * rows[i, _B], rows[i, _C]
        beta = rows[i, _BETA]
        cy_, sy_ = math.cos(rows[i, _YAW]), math.sin(rows[i, _YAW])
        smax = 1.0 + abs(rows[i, 9]) + abs(rows[i, 11]) + abs(rows[i, 13])
        smax2 = smax * smax
        reach = a2 * smax
        col_lo = max(int(math.floor((cx - reach - x0) / res - 0.5)) - c0, 0)
        col_hi = min(int(math.ceil((cx + reach - x0) / res - 0.5)) - c0, nx - 1)
        row_lo = max(int(math.floor((y0 - cy - reach) / res - 0.5)) - r0, 0)
        row_hi = min(int(math.ceil((y0 - cy + reach) / res - 0.5)) - r0, ny - 1)
        base = z0[i] + c * (0.5 - beta)
        for rr in range(row_lo, row_hi + 1):
            py = y0 - (rr + r0 + 0.5) * res
            for cc in range(col_lo, col_hi + 1):
                px = x0 + (cc + c0 + 0.5) * res
                dx, dy = px - cx, py - cy
                u = dx * cy_ + dy * sy_
                v = -dx * sy_ + dy * cy_
                e2 = (u / a2) ** 2 + (v / b2) ** 2
                if e2 >= smax2:  # outside even the largest outline: skip the harmonics
                    continue
                phi = math.atan2(v * a2, u * b2)
                s = 1.0
                for h in range(3):
                    s += rows[i, 9 + 2 * h] * math.cos((h + 2) * phi + rows[i, 10 + 2 * h])
                rho2 = e2 / (s * s)
                if rho2 >= 1.0:
                    continue
                top = base + 0.5 * c * s * math.sqrt(1.0 - rho2)
                if top > z[rr, cc]:
                    z[rr, cc] = top


def rock_heights(tile, rocks: RockTable, *, window=None, min_pixels: float = MIN_ROCK_PIXELS):
    """Heights of ``tile`` with every rock it resolves standing on it.

    Parameters
    ----------
    tile : DEMTile
        Rock-free terrain (metres). Each rock's base level is the bilinear height of this tile
        at its centre, so a window computed alone equals the same window of a full run.
    rocks : RockTable
    window : terrain.core.tile.Window, optional
    min_pixels : float
        Rocks narrower than this many pixels are left out (the tile cannot resolve them).

    Returns
    -------
    heights : (ny, nx) float32, metres (the window's shape when given)
    z0 : (n,) float64, metres: each rock's base level (NaN for rocks left out)
    drawn : (n,) bool: the rocks this tile resolves
    """
    res = tile.resolution
    t = tile.transform
    base = tile.heights  # float32; the kernels compute in float64
    if not tile.valid.all():
        from scipy import ndimage

        idx = ndimage.distance_transform_edt(~tile.valid, return_distances=False,
                                             return_indices=True)
        base = base[tuple(idx)]
    drawn = rocks.diameter >= min_pixels * res
    rows = np.ascontiguousarray(rocks.rows[drawn])
    z0 = np.full(len(rocks), np.nan)
    zz = np.empty(len(rows))
    _base_levels(base, t.c, t.f, res, rows, zz)
    z0[drawn] = zz
    if window is None:
        (r0, c0), (h, w) = (0, 0), tile.shape
    else:
        window.check_inside(*tile.shape)
        r0, c0, h, w = window.row, window.col, window.height, window.width
    z = tile.heights[r0:r0 + h, c0:c0 + w].astype(np.float64)
    rasterise_rocks(z, r0, c0, t.c, t.f, res, rows, zz)
    out = z.astype(np.float32)
    out[~tile.valid[r0:r0 + h, c0:c0 + w]] = np.nan
    return out, z0, drawn


def add_rocks(tile, model: RockModel, *, seed: int, craters=None, window=None):
    """Generate the rocks a tile resolves and stand them on it.

    Returns
    -------
    tile : DEMTile
        The rocky tile (the window, if given), provenance in its metadata.
    catalog : RockCatalog
        The rocks whose centre lies in the tile (or window), layer 0.
    """
    seed = check_seed(seed)
    dmin = MIN_ROCK_PIXELS * tile.resolution
    sub = tile.window(window) if window is not None else tile
    rocks = model.generate(seed, sub.bounds, min_diameter=dmin, craters=craters)
    heights, z0, drawn = rock_heights(tile, rocks, window=window)
    out = sub.replace(heights=heights, valid=sub.valid).with_metadata(
        **{mk.SEED: str(seed), mk.ROCKS: model.as_dict()})
    inside = _centre_inside(rocks, sub.bounds) & drawn
    catalog = rock_catalog(rocks.take(np.flatnonzero(inside)), z0[inside],
                           np.zeros(int(inside.sum()), np.int64))
    log.info("%d rocks (D >= %.3g m) on the tile, %d centred in it", len(rocks), dmin,
             int(inside.sum()))
    return out, catalog


def _centre_inside(rocks, extent):
    xmin, ymin, xmax, ymax = extent
    return (rocks.x >= xmin) & (rocks.x < xmax) & (rocks.y > ymin) & (rocks.y <= ymax)


def rock_catalog(rocks: RockTable, z0, layer) -> RockCatalog:
    """Return the catalogue of a rock table (written with :meth:`RockCatalog.to_csv`).

    Parameters
    ----------
    rocks : RockTable
    z0 : (n,) float, metres
        Ground height under each rock's centre.
    layer : (n,) int
        Each rock's layer (0 outside a layer stack).

    Returns
    -------
    RockCatalog
    """
    c = rocks.rows[:, _C]
    beta = rocks.rows[:, _BETA]
    return RockCatalog(
        id=rocks.uid, x_m=rocks.x, y_m=rocks.y, z_base_m=np.asarray(z0, float),
        diameter_m=rocks.diameter, height_m=c * (1 - beta), burial_m=c * beta,
        axis_a_m=rocks.rows[:, _A], axis_b_m=rocks.rows[:, _B], axis_c_m=c,
        orientation_deg=np.degrees(rocks.yaw), layer=np.asarray(layer, np.int64))
