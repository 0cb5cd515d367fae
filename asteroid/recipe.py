r"""What to build: the recipe of an asteroid, from presets, a TOML file and command-line flags.

A :class:`Recipe` names everything that decides the bytes of a model: magnitude, radius,
seed, base (Perlin noise, two-phase faulting or a shape model file), stretch, craters and
boulders. Sources are merged in this order, later winning key by key: a preset, the
``--config`` file, the command-line flags.

TOML layout (every key optional; units in the comments)::

    preset = "fig9-faulting"     # start from a preset (see PRESETS)
    magnitude = 400              # M: 6 M^2 + 2 vertices
    radius = 100.0               # reference radius R, metres
    seed = 7
    base = "faulting"            # "perlin", "faulting", "shape" or "shape:FILE"
    stretch = [2.0, 1.0, 1.0]    # affine stretch along x, y, z

    [perlin]                     # asteroid.noise.PerlinNoise
    octaves = 10
    frequency = 1.0              # lattice cells per body radius
    persistence = 0.5
    lacunarity = 2.0
    amplitude = 0.25             # fraction of R
    bands = [{octave = 1, amplitude = 0.12}]

    [faulting]                   # asteroid.faulting.Faulting (metres)
    faults = 1000
    max_fault = 5.0
    passes = 3
    filter_width = 20.0
    fine_faults = 20000
    fine_max_fault = 0.03

    [shape]
    file = "eros.obj"            # relative to the TOML file
    units = "km"                 # of the file's coordinates
    centre = "centroid"          # or "origin", or [x, y, z] in the file's units

    [craters]                    # N_cum(D) = c D^k per m^2, D in metres
    c = 0.5                      # or density = craters with D >= dmin per km^2
    k = -2.0
    dmin = 2.0                   # default 4 mean vertex spacings
    dmax = 40.0                  # default the largest the maximum extent allows
    max_age = 3.5                # Gyr
    max_extent_deg = 60.0
    slope_start_deg = 30.0
    slope_stop_deg = 50.0
    slope_erosion = true
    roughness = true             # fractal overlay and irregular rims
    erosion_exponent = 1.1
    transition_diameter = 15000.0  # m: wider craters are complex (lunar; scales as 1/g)
    slope_degradation = true     # craters on steep ground degrade faster

    [boulders]                   # N_cum(D) = c D^k per m^2
    c = 0.05                     # or density
    k = -3.0
    dmin = 1.0                   # default 1 mean vertex spacing
    dmax = 20.0                  # default 20 dmin
    levels = 4
    roughness = 0.12
    hurst = 0.8
    flattening = [0.5, 0.9]
    elongation = [1.0, 1.5]
    max_burial = 0.4
    max_tilt_deg = 20.0

On the command line ``--craters`` and ``--boulders`` take the same keys as
``key=value,key=value`` (ranges as ``lo:hi``), or ``paper`` (craters: the paper's
``N_cum = 0.5 D^-2``) or ``none``.

The paper's ``c``: "when k = -2, N_cum is dimensionless so the crater population appears the
same at all resolutions" (section V.B): with D in metres and areas in square metres,
``N_cum = 0.5 D^-2`` means 0.5 craters per m^2 larger than 1 m. It is converted to the
:class:`terrain.craters.population.Population` density (per km^2, D >= dmin) as ``c dmin^k 10^6``.

Presets
-------
``fig5-smooth``, ``fig5-lumpy``, ``fig5-rugged``
    The three ten-octave Perlin bases of Fig. 5 (our reconstructions, see
    :mod:`asteroid.noise`), M = 400, R = 1000 m, craters ``N_cum = 0.5 D^-2`` as in Fig. 9
    (bottom).
``fig9-faulting``
    Section VI.B's faulting model, also Fig. 8 (top right): 1000 faults up to 5 m, three
    smoothing passes with 20 m filters, 20,000 faults up to 0.03 m, a factor 2 stretch on x,
    ``N_cum = 0.5 D^-2``, M = 400. R = 100 m: the fault sizes are absolute, and Fig. 4
    describes "a 100 m stretched model" built with the same first phase.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from asteroid.body import Stretch
from asteroid.boulder_presets import BOULDER_PRESETS
from asteroid.boulders import BoulderSettings
from asteroid.craters import DEFAULT_MAX_EXTENT_DEG, CraterSettings, SlopeErosion, max_diameter
from asteroid.faulting import FIG8_FAULTING, Faulting
from asteroid.noise import FIG5_PRESETS, PerlinNoise
from asteroid.shape import UNITS
from asteroid.sphere import check_magnitude
from terrain.core.checks import check_keys, number
from terrain.core.errors import InvalidParameterError
from terrain.core.rng import check_seed
from terrain.core.tomlfile import read_toml
from terrain.craters.crater import (
    DEFAULT_PEAK_RING_DIAMETER,
    DEFAULT_TRANSITION_DIAMETER,
    Morphology,
)
from terrain.craters.cratering import CraterModel
from terrain.craters.erosion import ErosionModel, SlopeDegradation
from terrain.craters.population import Population

__all__ = ["PRESETS", "BoulderSpec", "CraterSpec", "Recipe", "parse_spec"]

#: Default smallest crater, in mean vertex spacings (smaller bowls are not resolved).
CRATER_DMIN_SPACINGS = 4.0
#: Default smallest boulder, in mean vertex spacings.
BOULDER_DMIN_SPACINGS = 1.0
#: Default boulder size range (dmax / dmin).
BOULDER_RANGE = 20.0
#: The paper's crater distribution, N_cum = 0.5 D^-2 (sections VI.A-B).
PAPER_CRATERS = {"c": 0.5, "k": -2.0}

#: Largest reference radius (m): beyond any asteroid or moon a lander would visit, and far
#: inside float32 vertex coordinates.
MAX_RADIUS = 1.0e7

_TOP_KEYS = {"preset", "magnitude", "radius", "seed", "base", "stretch"}
_TABLES = {"perlin", "faulting", "shape", "packing", "craters", "boulders"}
#: When a shape model is kept as its own mesh (:mod:`asteroid.surface`) instead of being
#: projected onto the 6M^2 + 2 mesh: "auto" keeps it when more than
#: :data:`KEEP_NON_STAR_FRACTION` of the mesh directions cross its surface more than once.
SHAPE_KEEP = ("auto", "always", "never")
#: Fraction of non-star-shaped directions above which "auto" keeps a shape model's mesh
#: (Itokawa's folded neck, 0.24 %, still projects within 0.15 % of its volume).
KEEP_NON_STAR_FRACTION = 0.01


def _crater_dict(**extra) -> dict:
    return dict(PAPER_CRATERS, **extra)


#: Named starting points (plain dicts in the TOML layout; see the module docstring).
PRESETS: dict[str, dict] = {
    **{name: dict(magnitude=400, radius=1000.0, base="perlin", perlin=noise.as_dict(),
                  craters=_crater_dict())
       for name, noise in FIG5_PRESETS.items()},
    "fig9-faulting": dict(magnitude=400, radius=100.0, base="faulting",
                          faulting=FIG8_FAULTING.as_dict(), stretch=[2.0, 1.0, 1.0],
                          craters=_crater_dict()),
}


def _density(table: str, c, density, k, dmin) -> float:
    """Craters (or boulders) with D >= dmin per km^2, from the paper's c or a density."""
    if (c is None) == (density is None):
        raise InvalidParameterError(
            f"{table} need exactly one of c (N_cum = c D^k per m^2) or density (per km^2 with "
            f"D >= dmin); got {'both' if c is not None else 'neither'}")
    if density is not None:
        return number(density, "density", where=table)
    c = number(c, "c", low=0, where=table)
    return c * dmin**k * 1e6


@dataclass(frozen=True)
class CraterSpec:
    """Crater population and settings, with defaults that depend on the body."""

    c: float | None = None
    density: float | None = None
    k: float = -2.0
    dmin: float | None = None
    dmax: float | None = None
    max_age: float = 3.5
    max_extent_deg: float = DEFAULT_MAX_EXTENT_DEG
    slope_start_deg: float = 30.0
    slope_stop_deg: float = 50.0
    slope_erosion: bool = True
    roughness: bool = True
    erosion_exponent: float | None = None
    transition_diameter: float = DEFAULT_TRANSITION_DIAMETER
    slope_degradation: bool = True

    def __post_init__(self):
        if (self.c is None) == (self.density is None):
            _density("craters", self.c, self.density, -2.0, 1.0)
        self.settings()  # validates the settings now, not at build time

    def settings(self) -> CraterSettings:
        """Return the crater settings this spec describes, with the paper's defaults filled in."""
        kwargs = {} if self.erosion_exponent is None else {"exponent": self.erosion_exponent}
        ring = max(DEFAULT_PEAK_RING_DIAMETER, 2.0 * float(self.transition_diameter))
        model = CraterModel(erosion=ErosionModel.default(**kwargs),
                            morphology=Morphology(self.transition_diameter, ring),
                            slope=SlopeDegradation(bool(self.slope_degradation)))
        if not self.roughness:
            model = model.smooth()
        return CraterSettings(model, self.max_extent_deg,
                              SlopeErosion(self.slope_start_deg, self.slope_stop_deg,
                                           self.slope_erosion))

    def population(self, radius: float, spacing: float) -> Population:
        """Return the population on a body of ``radius`` and mean vertex ``spacing`` (metres)."""
        dmin = CRATER_DMIN_SPACINGS * spacing if self.dmin is None else float(self.dmin)
        dmax = max_diameter(radius, self.max_extent_deg) if self.dmax is None \
            else float(self.dmax)
        if dmin >= dmax:
            raise InvalidParameterError(
                f"crater dmin {dmin:.4g} m must be below dmax {dmax:.4g} m (the default dmax is "
                "the largest crater the maximum extent allows)")
        density = _density("craters", self.c, self.density, self.k, dmin)
        return Population(dmin=dmin, dmax=dmax, density=density, sfd_exponent=self.k,
                          max_age=self.max_age)


@dataclass(frozen=True)
class BoulderSpec:
    """Boulder population and shape settings."""

    c: float | None = None
    density: float | None = None
    k: float = -3.0
    dmin: float | None = None
    dmax: float | None = None
    settings: BoulderSettings = field(default_factory=BoulderSettings)

    def __post_init__(self):
        _density("boulders", self.c, self.density, -3.0, 1.0)

    def population(self, spacing: float) -> Population:
        """Return the boulder population for a mesh of this mean vertex spacing (metres)."""
        dmin = BOULDER_DMIN_SPACINGS * spacing if self.dmin is None else float(self.dmin)
        dmax = BOULDER_RANGE * dmin if self.dmax is None else float(self.dmax)
        density = _density("boulders", self.c, self.density, self.k, dmin)
        return Population(dmin=dmin, dmax=dmax, density=density, sfd_exponent=self.k,
                          max_age=0.0)


def parse_spec(text: str, what: str) -> dict | None:
    """``"key=value,key=value"`` (ranges ``lo:hi``), ``"paper"`` or ``"none"`` as a dict.

    >>> parse_spec("c=0.5,k=-2,roughness=false", "craters")
    {'c': 0.5, 'k': -2.0, 'roughness': False}
    >>> parse_spec("density=20,flattening=0.4:0.8", "boulders")
    {'density': 20.0, 'flattening': [0.4, 0.8]}
    """
    text = str(text).strip()
    if text.lower() == "none":
        return None
    if text.lower() == "paper":
        if what != "craters":
            raise InvalidParameterError("only craters have a 'paper' distribution")
        return dict(PAPER_CRATERS)
    out: dict = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        if "=" not in part and what == "boulders" and part.lower() in BOULDER_PRESETS:
            out.update(copy.deepcopy(BOULDER_PRESETS[part.lower()]))
            continue
        if "=" not in part:
            raise InvalidParameterError(
                f"--{what} expects key=value pairs separated by commas, 'paper' or 'none'; "
                f"got {part!r}")
        key, value = (s.strip() for s in part.split("=", 1))
        low = value.lower()
        try:
            if low in ("true", "yes", "on"):
                out[key] = True
            elif low in ("false", "no", "off"):
                out[key] = False
            elif ":" in value:
                out[key] = [float(v) for v in value.split(":")]
            else:
                out[key] = float(value)
        except ValueError:
            raise InvalidParameterError(f"--{what} {key} must be a number; got {value!r}") \
                from None
    return out


def _merge(base: dict, update: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in update.items():
        if key in _TABLES and isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = copy.deepcopy(value)
    return out


def _build_dataclass(cls, table: str, values: dict, rename: dict | None = None):
    names = {f.name for f in fields(cls)}
    rename = rename or {}
    check_keys(values, names | set(rename), f"recipe [{table}]")
    kwargs = {}
    for key, value in values.items():
        key2 = rename.get(key, key)
        kwargs[key2] = int(value) if isinstance(value, float) and value.is_integer() and \
            key2 in ("octaves", "faults", "passes", "fine_faults", "levels") else value
    return cls(**kwargs)


def _resolve_shape_file(data: dict, folder: Path) -> None:
    """Make a config file's shape model path relative to the config file's folder."""
    base = data.get("base")
    if isinstance(base, str) and base.startswith("shape:"):
        file = Path(base.split(":", 1)[1])
        if not file.is_absolute():
            data["base"] = f"shape:{folder / file}"
    shape = data.get("shape")
    if isinstance(shape, dict) and "file" in shape and not Path(shape["file"]).is_absolute():
        shape["file"] = str(folder / shape["file"])


@dataclass(frozen=True)
class Recipe:
    """Everything that decides a model's bytes (see the module docstring)."""

    magnitude: int
    radius: float | None
    seed: int
    base: str
    perlin: PerlinNoise = field(default_factory=PerlinNoise)
    faulting: Faulting = field(default_factory=Faulting)
    shape_file: str | None = None
    shape_units: str = "km"
    shape_centre: str | Sequence[float] = "centroid"
    shape_keep: str = "auto"
    packing: str | None = None
    packing_cells: int | None = None
    stretch: Stretch = field(default_factory=Stretch)
    craters: CraterSpec | None = None
    boulders: BoulderSpec | None = None
    preset: str | None = None

    def __post_init__(self):
        object.__setattr__(self, "magnitude", check_magnitude(self.magnitude))
        try:
            object.__setattr__(self, "seed", check_seed(self.seed))
        except ValueError as exc:
            raise InvalidParameterError(str(exc)) from None
        if self.base not in ("perlin", "faulting", "shape", "packing"):
            raise InvalidParameterError(
                f"base must be perlin, faulting, shape:FILE or packing:NAME; got {self.base!r}")
        if self.shape_keep not in SHAPE_KEEP:
            raise InvalidParameterError(
                f"shape keep must be one of {', '.join(SHAPE_KEEP)}; got {self.shape_keep!r}")
        if self.base == "packing":
            from asteroid.packing import PACKINGS

            if self.packing not in PACKINGS:
                raise InvalidParameterError(
                    f"unknown packing {self.packing!r}; choose one of "
                    f"{', '.join(sorted(PACKINGS))}")
        if self.radius is not None:
            if isinstance(self.radius, bool) or not isinstance(self.radius, (int, float)):
                raise InvalidParameterError(f"radius must be a number (metres); got "
                                            f"{self.radius!r}")
            r = float(self.radius)
            if not (r > 0 and math.isfinite(r)):
                raise InvalidParameterError(f"radius must be positive metres; got {r}")
            if r > MAX_RADIUS:
                raise InvalidParameterError(
                    f"radius {r:g} m is larger than any asteroid (at most {MAX_RADIUS:g} m; "
                    "Ceres is 4.7e5 m)")
            object.__setattr__(self, "radius", r)
        elif self.base not in ("shape",):
            raise InvalidParameterError(
                f"a {self.base} base needs --radius (metres); only a shape model has a size of "
                "its own")
        if self.base == "shape" and not self.shape_file:
            raise InvalidParameterError("a shape base needs a file: --base shape:FILE")
        if self.shape_units not in UNITS:
            raise InvalidParameterError(
                f"shape units must be one of {sorted(UNITS)}; got {self.shape_units!r}")

    @classmethod
    def from_dict(cls, data: dict) -> Recipe:
        """Build a recipe from the TOML layout (a preset named in it is applied underneath)."""
        check_keys(data, _TOP_KEYS | _TABLES, "recipe")
        preset = data.get("preset")
        if preset is not None:
            if preset not in PRESETS:
                raise InvalidParameterError(
                    f"unknown preset {preset!r}; choose one of {', '.join(sorted(PRESETS))}")
            data = _merge(PRESETS[preset], data)
        base = data.get("base")
        if base is None:
            raise InvalidParameterError("give a base: --base perlin|faulting|shape:FILE")
        shape = check_keys(data.get("shape") or {}, {"file", "units", "centre", "keep"},
                           "recipe [shape]")
        packing = check_keys(data.get("packing") or {}, {"name", "cells"}, "recipe [packing]")
        if isinstance(base, str) and base.startswith("packing:"):
            packing["name"] = base.split(":", 1)[1]
            base = "packing"
        if isinstance(base, str) and base.startswith("shape:"):
            shape["file"] = base.split(":", 1)[1]
            base = "shape"
        shape_file = shape.pop("file", None)
        units = shape.pop("units", "km")
        centre = shape.pop("centre", "centroid")
        keep = shape.pop("keep", "auto")
        keep = {True: "always", False: "never"}.get(keep, keep)
        if "magnitude" not in data:
            raise InvalidParameterError("give the magnitude: --magnitude M")
        craters = data.get("craters")
        boulders = data.get("boulders")
        if boulders is not None:
            b = dict(boulders)
            pop_keys = {k: b.pop(k) for k in ("c", "density", "k", "dmin", "dmax") if k in b}
            settings = _build_dataclass(BoulderSettings, "boulders", b)
            boulders = BoulderSpec(settings=settings, **pop_keys)
        return cls(
            magnitude=data["magnitude"],
            radius=data.get("radius"),
            seed=data.get("seed", 0),
            base=str(base),
            perlin=_build_dataclass(PerlinNoise, "perlin", data.get("perlin") or {}),
            faulting=_build_dataclass(Faulting, "faulting", data.get("faulting") or {}),
            shape_file=shape_file,
            shape_units=units,
            shape_centre=tuple(centre) if isinstance(centre, list) else centre,
            shape_keep=str(keep),
            packing=packing.get("name"),
            packing_cells=None if packing.get("cells") is None else int(packing["cells"]),
            stretch=Stretch.parse(data.get("stretch")),
            craters=None if craters is None else _build_dataclass(CraterSpec, "craters",
                                                                  craters),
            boulders=boulders,
            preset=preset,
        )

    @classmethod
    def from_sources(cls, *, preset: str | None = None, config=None, **flags) -> Recipe:
        """Merge a preset, a TOML file and flags (None flags are ignored).

        ``craters`` and ``boulders`` flags are dicts from :func:`parse_spec` (merged into the
        file's or preset's table key by key), or the string ``"none"`` (no craters / boulders).
        """
        data: dict = {}
        if config is not None:
            path = Path(config)
            data = read_toml(path, "config file")
            _resolve_shape_file(data, path.parent)
        if preset is not None:
            data["preset"] = preset
        for key, value in flags.items():
            if key in ("craters", "boulders"):
                if value == "none":
                    data[key] = None
                elif value is not None:
                    data[key] = {**(data.get(key) or {}), **value}
            elif key == "shape":
                if value is not None:
                    data[key] = {**(data.get(key) or {}), **value}
            elif value is not None:
                data[key] = value
        return cls.from_dict(data)

    @property
    def base_radius(self) -> float:
        """The reference radius R in metres of a Perlin or faulting base (which need one)."""
        if self.radius is None:
            raise InvalidParameterError(
                f"a {self.base} base needs --radius (metres); only a shape model has a size of "
                "its own")
        return self.radius

    def as_dict(self) -> dict:
        """JSON-friendly record of the recipe (provenance)."""
        out: dict[str, Any] = dict(magnitude=self.magnitude, radius=self.radius, seed=self.seed,
                                   base=self.base, stretch=self.stretch.as_list(),
                                   preset=self.preset)
        if self.base == "perlin":
            out["perlin"] = self.perlin.as_dict()
        elif self.base == "faulting":
            out["faulting"] = self.faulting.as_dict()
        elif self.base == "packing":
            out["packing"] = dict(name=self.packing, cells=self.packing_cells)
        else:
            out["shape"] = dict(file=self.shape_file, units=self.shape_units,
                                centre=self.shape_centre if isinstance(self.shape_centre, str)
                                else list(self.shape_centre))
            if self.shape_keep != "auto":
                out["shape"]["keep"] = self.shape_keep
        if self.craters is not None:
            out["craters"] = asdict(self.craters)
        if self.boulders is not None:
            b = asdict(self.boulders)
            b["settings"] = self.boulders.settings.as_dict()
            out["boulders"] = b
        return out
