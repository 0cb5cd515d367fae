"""What each terrain stage takes: frozen, validated specs built once from a table.

A spec holds a stage's parameters, never where its work goes (inputs, outputs, catalogues)
nor how it runs (:class:`terrain.stages.runner.Execution`). Its field names are the command's
long options with ``-`` as ``_``, so a campaign or scene-recipe table of command options is
a spec mapping:

>>> SynthSpec.from_mapping({"size": 33, "relief": 5.0}).relief
5.0
>>> SynthSpec.from_mapping({"sise": 33})
Traceback (most recent call last):
...
terrain.core.errors.InvalidParameterError: unknown terrain synth key 'sise' (did you mean 'size'?)

Each field's default, help line and kind are declared once, by :func:`~.fields.option`; the
command line builds its options from them (:mod:`terrain.cli.options`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from terrain.core import checks
from terrain.core.errors import InvalidParameterError
from terrain.core.presets import PRESETS
from terrain.core.tile import Window
from terrain.stages.fields import (
    FLAG,
    OUTPUT_PATH,
    PAIR,
    PATH,
    REQUIRED,
    WINDOW,
    Spec,
    choice,
    integer,
    number,
    option,
    text,
)

__all__ = ["AddCraterSpec", "CratersSpec", "EnhanceSpec", "ExpandSpec", "FillSpec",
           "HazardsSpec", "HillshadeSpec", "RocksSpec", "SynthSpec"]

#: Largest tile relief (m): ten times Olympus Mons, far inside float32 heights.
MAX_RELIEF = 2.0e5
#: Largest crater add-crater takes, in DEM diagonals (its rim still reaches the DEM).
MAX_CRATER_TO_DEM = 100.0
#: Largest hillshade vertical exaggeration.
MAX_Z_FACTOR = 1.0e6
#: The body a synthetic DEM lies on unless asked otherwise (a local grid on request).
DEFAULT_BODY = "moon"
#: The preset `terrain enhance` draws its default small craters from: the lunar south pole,
#: where the landers go (Artemis, VIPER) and the demo's site; its crater numbers are those of
#: the highlands (``docs/roughness.md``).
DEFAULT_ENHANCE_TERRAIN = "south-polar"

_frozen = dataclasses.dataclass(frozen=True, kw_only=True)

SEED = option(0, "Keys every random draw.", integer(low=0, high=2**63 - 1))
BAND = option(1, "Band of the input.", integer(low=1))
WINDOW_FIELD = option(None, "Compute only this window (pixels); bitwise equal to the same "
                      "window of a full run.", WINDOW)
#: ``--terrain``: a preset of :mod:`terrain.core.presets` (south-polar, highlands, maria).
TERRAIN = option(None, "Terrain preset (south-polar, highlands, maria): crater density, ages "
                 "and degradation, the roughness law and the angle of repose, from published "
                 "lunar measurements (docs/presets.md); flags override.",
                 choice(*PRESETS))


@_frozen
class _ModelFields(Spec):
    """The crater model: degradation, roughness, complex craters."""

    erosion_profile: Path | None = option(
        None, "CSV baseline degradation profile (baseline_age_gyr, depth_fraction, "
        "rim_fraction).", PATH)
    erosion_exponent: float | None = option(
        None, "P of the Ross/Soderblom scaling T_b = T_x (D_b/D_x)^P (default 1.1).", number())
    no_roughness: bool = option(
        False, "Switch off the crater fractal overlay and the irregular rim.", FLAG)
    transition_diameter: float | None = option(
        None, "Craters wider than this (m) are complex: flat floor, terraced walls, central "
        "peak (default 15000, the lunar value; it scales as 1/g).",
        number(low=0.0, low_open=True))
    simple_craters_only: bool = option(
        False, "Make every crater simple, whatever its size.", FLAG)
    no_slope_degradation: bool = option(
        False, "Age craters on steep ground at the flat-ground rate.", FLAG)


@_frozen
class _CraterFields(_ModelFields):
    """A crater population and its model."""

    dmin: float | None = option(None, "Smallest crater diameter (m). Default: 3 pixels.",
                                number())
    dmax: float | None = option(
        None, "Largest crater diameter (m). Default: a quarter of the DEM's extent.", number())
    density: float | None = option(None, "Craters with D >= dmin per km^2.", number())
    sfd_exponent: float | None = option(
        None, "k of N_cum = c D^k (default -2; -1.8 for mare).", number())
    max_age: float | None = option(
        None, "Oldest crater age in Gyr; ages are uniform below it (default 3.5).", number())
    population: Path | None = option(
        None, "TOML file with a [population] table (flags override).", PATH)


@_frozen
class _RoughnessFields(Spec):
    """The fractal statistics of an expansion (measured from the input by default)."""

    fractal_dimension: float | None = option(
        None, "F in [2, 3); measured from the input by default.", number())
    height_scale: float | None = option(
        None, "H of eq. 15 (height-range factor); measured from the input by default.",
        number())
    uniform_roughness: bool = option(
        False, "One roughness everywhere instead of the input's local roughness map.", FLAG)


@_frozen
class SynthSpec(_CraterFields):
    """`terrain synth`: fractal terrain (RMD diamond-square), optionally cratered.

    The DEM lies on :data:`DEFAULT_BODY` in a projection centred on the tile unless
    ``local_grid`` asks for a local frame without a CRS.
    """

    STAGE = "synth"
    size: int = option(1025, "Tile side in pixels, 2^n + 1.", integer())
    resolution: float = option(1.0, "Metres per pixel.", number(low=0.0, low_open=True))
    terrain: str | None = TERRAIN
    fractal_dimension: float | None = option(
        None, "RMD fractal dimension F in [2, 3) (eq. 14). Default 2.2, or 3 - H of the "
        "terrain preset.", number())
    relief: float | None = option(
        None, "Tile-scale relief R = H * D_r * W of eq. 15 (m): the standard deviation of the "
        "corner heights. Default 30, or what gives the terrain preset's median slope at one "
        "pixel.", number(low=0.0, high=MAX_RELIEF))
    body: str = option(DEFAULT_BODY, "Body the DEM lies on (moon, mars, mercury): the DEM "
                       "gets a CRS on its sphere, centred on the tile.", text())
    crs: str | None = option(None, "Projection on the body: south-polar (default), "
                             "north-polar, or ortho:LON,LAT (a site-centred orthographic CRS).",
                             text())
    local_grid: bool = option(False, "A local grid in metres without CRS or body instead.",
                              FLAG)
    repose: float | None = option(
        None, "Relax slopes steeper than this angle (degrees) by mass wasting, as the terrain "
        "presets do (default: the preset's angle; none without a preset).",
        number(low=0.0, high=90.0, low_open=True, high_open=True))
    seed: int = SEED
    window: Window | None = WINDOW_FIELD

    def _check(self) -> None:
        from terrain.core.bodies import check_projection
        from terrain.fractal.rmd import check_fractal_dimension, check_tile_size

        check_tile_size(self.size)
        if self.fractal_dimension is not None:
            check_fractal_dimension(self.fractal_dimension)
        if self.window is not None:
            self.window.check_inside(self.size, self.size)
        if self.local_grid and self.crs is not None:
            raise InvalidParameterError(
                f"{self.label('crs')} is a projection on a body; drop {self.label('local_grid')}")
        check_projection(None if self.local_grid else self.body, self.crs)

    @property
    def projection(self) -> tuple[str, str | None] | None:
        """``(body, projection)`` of the DEM's CRS, or None for a local grid."""
        return None if self.local_grid else (self.body, self.crs)


@_frozen
class CratersSpec(_CraterFields):
    """`terrain craters`: a power-law crater population added to a DEM."""

    STAGE = "craters"
    terrain: str | None = TERRAIN
    seed: int = SEED
    window: Window | None = WINDOW_FIELD
    band: int = BAND

    def _check(self) -> None:
        if self.population is None and self.density is None and self.terrain is None:
            raise InvalidParameterError(f"give {self.label('density')} (craters per km^2), "
                                        f"{self.label('population')} FILE or "
                                        f"{self.label('terrain')} PRESET")


@_frozen
class AddCraterSpec(_ModelFields):
    """`terrain add-crater`: one crater at a map position."""

    STAGE = "add-crater"
    at: tuple[float, float] = option(
        REQUIRED, "Crater centre X,Y in the DEM's map coordinates (m).", PAIR)
    diameter: float = option(REQUIRED, "Crater diameter (m).", number())
    age: float = option(0.0, "Crater age in Gyr (0: fresh).", number())
    seed: int = SEED
    band: int = BAND

    def _check(self) -> None:
        if not self.diameter > 0:
            raise InvalidParameterError(
                f"{self.label('diameter')} must be positive metres; got {self.diameter}")
        if not self.age >= 0:
            raise InvalidParameterError(f"{self.label('age')} must be >= 0 Gyr; got {self.age}")


@_frozen
class ExpandSpec(_RoughnessFields):
    """`terrain expand`: a DEM's resolution doubled ``times`` times (known heights kept)."""

    STAGE = "expand"
    times: int = option(1, "Number of 2x expansions.", integer(low=1, high=16))
    seed: int = SEED
    window: Window | None = WINDOW_FIELD
    band: int = BAND


@_frozen
class FillSpec(Spec):
    """`terrain fill`: DEM gaps filled with fractal terrain (and craters)."""

    STAGE = "fill"
    roughness: float | None = option(
        None, "Gaussian per filled pixel, in units of the resolution; measured around each gap "
        "by default.", number())
    craters_at: Path | None = option(
        None, "CSV of crater gaps (x, y, diameter[, age]) to fill with craters.", PATH)
    despike: float | None = option(
        None, "First drop pixels this many robust sigmas from their local median.", number())
    denoise: float | None = option(
        None, "First smooth known pixels with a Gaussian of this many pixels.", number())
    seed: int = SEED
    band: int = BAND
    halo: int | None = option(
        None, "Chunked runs: pixels around each chunk that every gap must fit in (default "
        "256).", integer(low=0))


@_frozen
class EnhanceSpec(_RoughnessFields, _CraterFields):
    """`terrain enhance`: nested multi-resolution layers around a landing site."""

    STAGE = "enhance"
    site: tuple[float, float] | None = option(
        None, "Landing site X,Y in map coordinates (default: the DEM's centre).", PAIR)
    site_lonlat: tuple[float, float] | None = option(
        None, "Landing site as LON,LAT (degrees) on the DEM's body.", PAIR)
    levels: int | None = option(None, "Number of 2x expansions (layers = levels + 1).",
                                integer(low=0))
    finest_resolution: float | None = option(
        None, "Expand until the finest layer is at most this many metres per pixel.", number())
    layer_size: int = option(1025, "Pixels per side of each expanded layer (odd).", integer())
    seed: int = SEED
    min_crater_pixels: float = option(4.0, "Smallest crater a layer takes, in its pixels.",
                                      number())
    despike: float | None = option(
        None, "Before filling, drop pixels this many robust sigmas from their median.",
        number())
    band: int = BAND
    rocks: str | None = option(
        None, "Rocks on every layer that resolves them, e.g. viper-nominal, "
        "golombek-rapp-mars:k=0.01 or power:a=3e-4,b=-2.482 (keys as `terrain rocks`; dmin "
        "defaults to two pixels of the finest layer).", text())
    halo: int | None = option(
        None, "Chunked builds: pixels around each chunk that every gap of the base must fit "
        "in (default 256).", integer(low=0))
    terrain: str = option(
        DEFAULT_ENHANCE_TERRAIN, "Terrain preset whose small craters are added where neither "
        "--density nor --population is given: those the DEM cannot resolve (below "
        "--min-crater-pixels of its pixels), at the preset's equilibrium density, without "
        "moving a known height.", choice(*PRESETS))
    no_regolith: bool = option(
        False, "Continue the DEM's own roughness below 1 m instead of the lunar regolith's "
        "steeper law.", FLAG)

    def _check(self) -> None:
        if self.site is not None and self.site_lonlat is not None:
            raise InvalidParameterError(f"give at most one of {self.label('site')} X,Y and "
                                        f"{self.label('site_lonlat')} LON,LAT")
        if (self.levels is None) == (self.finest_resolution is None):
            raise InvalidParameterError(f"give exactly one of {self.label('levels')} and "
                                        f"{self.label('finest_resolution')}")


#: The rock models by name (:data:`terrain.surface.rocks.MODELS`, which checks the same names).
ROCK_MODELS = ("viper-nominal", "viper-low", "viper-high", "golombek-rapp-mars", "power")


@_frozen
class RocksSpec(Spec):
    """`terrain rocks`: a rock field (VIPER lunar laws, Golombek-Rapp or a power law) on a DEM."""

    STAGE = "rocks"
    model: str | None = option(
        None, "Size-frequency model of the rocks: viper-nominal, viper-low, viper-high (lunar), "
        "golombek-rapp-mars (Mars) or power (default: the --terrain preset's, else "
        "viper-nominal).", text())
    terrain: str | None = option(
        None, "Terrain preset whose rock model to use (south-polar, highlands, maria); an "
        "explicit --model wins.", choice(*PRESETS))
    k: float | None = option(
        None, "golombek-rapp-mars: fraction of the area covered by rocks, 0 < k < 1.",
        number())
    a: float | None = option(None, "power: a of N(>=D) = a D^b per m^2.", number())
    b: float | None = option(None, "power: b of N(>=D) = a D^b (< 0).", number())
    dmin: float | None = option(
        None, "Smallest rock diameter (m). Default: two pixels of the DEM.", number())
    dmax: float | None = option(
        None, "Largest rock diameter (m). Default: where the model has run out.", number())
    craters: Path | None = option(
        None, "Crater catalogue CSV (x_m/x, y_m/y, diameter, age): fresh craters get block "
        "fields.", PATH)
    no_crater_rocks: bool = option(
        False, "Give fresh craters no block fields.", FLAG)
    seed: int = SEED
    window: Window | None = WINDOW_FIELD
    band: int = BAND

    def _check(self) -> None:
        if self.model is not None:
            checks.text(self.model, "rock model", choices=ROCK_MODELS)
        if self.craters is not None and self.no_crater_rocks:
            raise InvalidParameterError(f"{self.label('craters')} and "
                                        f"{self.label('no_crater_rocks')} contradict each other")


@_frozen
class HazardsSpec(Spec):
    """`terrain hazards`: slope and step under a lander's footprint, safe or not."""

    STAGE = "hazards"
    lander_diameter: float = option(REQUIRED, "Diameter of the lander's footprint (m).",
                                    number())
    max_slope: float = option(
        REQUIRED, "Steepest safe plane under the footprint (degrees).", number())
    max_step: float = option(
        REQUIRED, "Largest safe height above that plane inside the footprint (m).", number())
    layer: int | None = option(
        None, "Layer of a stack (default: the finest with at most 72 pixels across the "
        "footprint).", integer())
    png: Path | None = option(None, "Picture for people (default: the output with .png).",
                              OUTPUT_PATH)
    band: int = BAND


@_frozen
class HillshadeSpec(Spec):
    """`terrain hillshade`: a shaded-relief picture of a DEM."""

    STAGE = "hillshade"
    azimuth: float = option(315.0, "Sun azimuth, degrees clockwise from north.", number())
    altitude: float = option(45.0, "Sun elevation above the horizon, degrees.",
                             number(low=0.0, high=90.0, low_open=True))
    z_factor: float = option(1.0, "Vertical exaggeration.", number())
    band: int = BAND

    def _check(self) -> None:
        if not 0 < abs(self.z_factor) <= MAX_Z_FACTOR:
            raise InvalidParameterError(
                f"{self.label('z_factor')} must be non-zero and at most {MAX_Z_FACTOR:g} in "
                f"size; got {self.z_factor}")
