r"""Published statistics of real planetary terrain, and the thresholds that follow from them.

One table, one place: every number :mod:`evaluation.validate` judges a DEM by is here, with
its source, the published value and scatter, and how the check's threshold follows from
them. Where a threshold had to be widened so that real DEMs of the terrain pass (two real
DEMs of the same ground, or two halves of one, must agree within it), the entry says so
and ``docs/validation.md`` shows the figures measured on the real DEMs of the shared data
(written by ``docs/validation_figures.py``, not retyped).

Slope against baseline
----------------------
Slopes here are *bidirectional* (Rosenburg et al. 2011, JGR 116, E02001): the absolute
height difference of two points a baseline L apart, over L, as an angle; the median over
both map axes. A self-affine surface of Hurst exponent H has RMS height differences
growing as L^H, so its median slope goes as L^(H-1). A terrain law is that power law,
anchored at 17 m (LOLA's shot spacing), up to the end of its self-affine range, and a
second exponent beyond it:

    theta(L) = theta17 (L / 17 m)^(H - 1)                          L <= L_break
    theta(L) = theta(L_break) (L / L_break)^(H_large - 1)          L > L_break

Below a metre the law continues with the same H, as Helfenstein and Shepard (1999, Icarus
141, 107: photometric roughness of regolith, self-affine from millimetres to centimetres)
and Hayne et al. (2021, Nat. Astron. 5, 169: sub-metre roughness from Diviner thermal
emission, RMS slopes of a few tens of degrees at centimetre scales) find for regolith.
"""

from __future__ import annotations

from dataclasses import dataclass

from terrain.core.errors import InvalidParameterError
from terrain.surface.rocks import VIPER as _ROCKS_VIPER

__all__ = ["BLOCK_FIELDS", "BODY_BOULDER_INDEX", "CRATER_EQUILIBRIUM", "FRESH_DEPTH_DIAMETER",
           "HURST_TOLERANCE", "KS_BETWEEN_REAL_DEMS", "MESH_SLOPE_RISE",
           "REGOLITH_RMS_SLOPE",
           "ROCK_ABUNDANCE", "ROCK_SFD", "SLOPE_BAND_FACTOR", "SLOPE_LAW_DEG", "SMALL_CRATER_DD",
           "SMOOTHNESS", "STATS", "STEEP_OLD_TERRAIN", "STEEP_SLOPE", "TERRAINS",
           "PublishedStat", "TerrainLaw", "terrain_law", "viper_cumulative"]


@dataclass(frozen=True)
class PublishedStat:
    """One published statistic and the threshold a check derives from it.

    Parameters
    ----------
    key : str
        Short identifier (the JSON's name for it).
    quantity : str
        What is measured, in words.
    value : float
        The published value.
    scatter : float
        Its published (or, where ``calibrated``, measured) scatter, same unit.
    unit : str
    source : str
        Author, year, journal.
    threshold : float
        The check's limit (or half-width of its band).
    derivation : str
        How the threshold follows from value and scatter.
    calibrated : bool
        True where the threshold was widened to let the real DEMs of the shared data pass.
    """

    key: str
    quantity: str
    value: float
    scatter: float
    unit: str
    source: str
    threshold: float
    derivation: str
    calibrated: bool = False

    def as_dict(self) -> dict:
        """Return the entry as plain data."""
        return dict(key=self.key, quantity=self.quantity, value=self.value,
                    scatter=self.scatter, unit=self.unit, source=self.source,
                    threshold=self.threshold, derivation=self.derivation,
                    calibrated=self.calibrated)


@dataclass(frozen=True)
class TerrainLaw:
    """The median bidirectional slope against baseline of one terrain type.

    Parameters
    ----------
    name : str
        ``"south-polar"``, ``"highlands"`` or ``"maria"``.
    slope_17m_deg : float
        Median slope at a 17 m baseline (degrees).
    hurst : float
        Hurst exponent of the self-affine range.
    break_m : float
        End of the self-affine range (m).
    hurst_large : float
        Hurst exponent beyond ``break_m``.
    source : str
        Where the numbers come from.

    Examples
    --------
    >>> law = TERRAINS["highlands"]
    >>> round(float(law.median_slope_deg(17.0)), 2), round(law.hurst_at(100.0), 2)
    (7.5, 0.95)
    """

    name: str
    slope_17m_deg: float
    hurst: float
    break_m: float
    hurst_large: float
    source: str

    def median_slope_deg(self, baseline_m):
        """Median slope (degrees) at baseline(s) ``baseline_m`` (metres)."""
        import numpy as np

        b = np.asarray(baseline_m, dtype=float)
        small = self.slope_17m_deg * (np.minimum(b, self.break_m) / 17.0) ** (self.hurst - 1.0)
        return small * (np.maximum(b, self.break_m) / self.break_m) ** (self.hurst_large - 1.0)

    def hurst_at(self, baseline_m: float) -> float:
        """Return the law's Hurst exponent at a baseline (metres)."""
        return self.hurst if baseline_m <= self.break_m else self.hurst_large

    def as_dict(self) -> dict:
        """Return the law as plain data."""
        return dict(name=self.name, slope_17m_deg=self.slope_17m_deg, hurst=self.hurst,
                    break_m=self.break_m, hurst_large=self.hurst_large, source=self.source)


#: Hurst exponent of lunar topography beyond the self-affine range (kilometres to hundreds of
#: kilometres), measured on LOLA's LDEM_4 around the south pole with the estimator of
#: :mod:`evaluation.validate` (0.55-0.6 over 15-120 km); the laws take 0.5.
_H_LARGE = 0.5

def _laws() -> dict[str, TerrainLaw]:
    from terrain.core.presets import PRESETS

    return {name: TerrainLaw(name, p.slope_17m_deg, p.hurst, p.self_affine_max_m, _H_LARGE,
                             "; ".join(p.sources[:1]) + f"; H {p.hurst:g} self-affine to "
                             f"{p.self_affine_max_m:g} m; beyond it H from LOLA LDEM_4 (Smith "
                             "et al. 2010)")
            for name, p in PRESETS.items()}


#: The slope laws of the terrain presets (:mod:`terrain.core.presets`, where each number's
#: source is given): the generator and the validation read the same table.
TERRAINS: dict[str, TerrainLaw] = _laws()


def terrain_law(name: str) -> TerrainLaw:
    """Return the law of a terrain type by name.

    >>> terrain_law("maria").hurst
    0.76
    """
    try:
        return TERRAINS[name]
    except KeyError:
        raise InvalidParameterError(
            f"terrain must be one of {', '.join(TERRAINS)}; got {name!r}") from None


#: Median slope band: measured/law within a factor of this at every baseline.
SLOPE_BAND_FACTOR = PublishedStat(
    "slope_band_factor", "median slope / terrain law at every measured baseline", 1.0, 2.0,
    "factor", "Rosenburg et al. 2011 (17 m median-slope maps)", 4.0,
    "The published maps vary by about a factor 2 either side of a terrain type's median "
    "from one kilometre-size area to the next; the Malapert NAC DEMs (SfS and stereo) lie up "
    "to a factor 3.2 below the polar law (the stereo DEM at 1 m), and the Aristarchus "
    "central-peak export, whose widest baselines cross the flat crater floor, 3.2 below the "
    "highlands law at 850 m, so the band is widened to a factor 4.", calibrated=True)

#: Hurst exponent: |H - H_law| at the fit band's centre.
HURST_TOLERANCE = PublishedStat(
    "hurst_tolerance", "|H - H_law| (structure function, even lags 2-16 px)", 0.95, 0.1,
    "", "Rosenburg et al. 2011 (H 0.95 highlands, 0.76 maria)", 0.25,
    "Published H ranges over about +-0.1 within a terrain type; two real DEMs of the same "
    "ground (Malapert SfS vs stereo) differ by 0.12, the SfS DEM lies 0.10 below the polar "
    "law and the Aristarchus plateau 0.18 above the maria law, so the tolerance is 0.25 (H of "
    "0.5, a random walk, is outside it for every law at metre scales).",
    calibrated=True)

#: Smoothness: spectral H over wavelengths 4-16 px at most this.
SMOOTHNESS = PublishedStat(
    "fine_spectral_hurst_max", "spectral Hurst exponent over wavelengths 4-16 px", 1.0, 0.3,
    "", "self-affine terrain: H <= 1 (Shepard et al. 2001, JGR 106, 32777)", 3.0,
    "A self-affine surface has H <= 1; DEMs made by stereo or interpolation are smoother "
    "than that at their finest scales (the QuickMap exports reach H 2.3 over 4-16 px), "
    "while a DEM interpolated from 8x coarser pixels reaches 4-6. Limit 3.0 lets every real "
    "DEM of the shared data pass.", calibrated=True)

#: Share of slopes steeper than the angle of repose.
STEEP_SLOPE = PublishedStat(
    "steep_share", "area steeper than 35 deg (Horn slope at the DEM's spacing)", 0.0, 0.02,
    "fraction", "Kreslavsky and Head 2016 (Icarus): slope-frequency distributions roll over "
    "steeply at the angle of repose (32-35 deg); old terrain has almost none steeper", 0.05,
    "Only the walls of young craters and central peaks exceed 35 deg; Aristarchus' central "
    "peak (a Copernican crater, 26 m pixels) has 2.1 %. The limit is 5 %.", calibrated=True)

#: Crater counts against the empirical equilibrium.
CRATER_EQUILIBRIUM = PublishedStat(
    "crater_equilibrium", "N(>=D) per km^2 over the empirical equilibrium 10^-1.1 D_km^-2",
    1.0, 0.5, "ratio", "Trask 1966 (Ranger VIII/IX), as used by Gault 1970", 2.0,
    "Cratered surfaces saturate at about the equilibrium density (scatter about a factor 2 "
    "between counts); a surface at more than twice it holds more craters than the Moon "
    "keeps.")

#: Depth/diameter of small craters.
FRESH_DEPTH_DIAMETER = PublishedStat(
    "depth_diameter", "median depth/diameter of 10-100 m craters", 0.11, 0.04, "",
    "Stopar et al. 2017 (Icarus 298, 34): 10-100 m craters d/D 0.05-0.2, fresh 0.2; Melosh "
    "1989: fresh simple craters H0 = 0.196 D^1.01", 0.2,
    "The population's median must lie between 0.03 and 0.2: fresh craters are the deepest "
    "(0.196) and degraded ones shallower; a population whose median reaches the fresh "
    "value has no degradation.")

#: Rock abundance (area fraction covered by rocks of about a metre and more).
ROCK_ABUNDANCE = PublishedStat(
    "rock_abundance", "area covered by rocks >= 1 m", 0.005, 0.005, "fraction",
    "Bandfield et al. 2011 (JGR 116, E00H02): Diviner rock abundance, regolith typically "
    "below 1 %, only fresh crater ejecta above 10 %", 0.1,
    "More than 10 % of the area under metre-size rocks is found only on the ejecta of fresh "
    "craters.")

#: VIPER environment specification's rock size-frequency models, N(>=D) = a D^b per m^2 (D in
#: metres): (a, b) of the low, nominal and high (after Haworth) models, as the generator draws
#: them (:data:`terrain.surface.rocks.VIPER`).
VIPER_ROCK_MODELS = {k.removeprefix("viper-"): v for k, v in _ROCKS_VIPER.items()}

#: Rocks of a metre and more per km^2, against the VIPER environment specification.
ROCK_DENSITY = PublishedStat(
    "rock_density_1m", "rocks >= 1 m per km^2", 300.0, 200.0, "per km^2",
    "VIPER environment specification (NASA): rock SFD models N(>=D) = 3e-4 D^-2.482 per m^2 "
    "(nominal), 1e-4 D^-1.755 (low) and 2e-3 D^-2.661 (high, after Haworth)", 100.0,
    "At D = 1 m the low and high models give 100 and 2,000 rocks per km^2 (nominal 300): a "
    "surface with fewer than the low model has no metre-scale rocks where landers meet "
    "them; one above the high model is rockier than the specification's rockiest site.")

#: Boulder cumulative SFD power-law index on small bodies.
BODY_BOULDER_INDEX = PublishedStat(
    "boulder_sfd_index", "cumulative boulder SFD power-law index", -2.9, 0.3, "",
    "Ryugu -2.65+-0.05 (Michikami et al. 2019), Bennu -2.9+-0.3 (DellaGiustina et al. 2019), "
    "Itokawa -3.1+-0.1 (Michikami et al. 2008), Eros -3.2 (Thomas et al. 2001)", 0.6,
    "The four bodies span -2.65 to -3.2; the index must lie within 0.6 of -2.9.")

#: Mean gravitational slope against a real shape model at the same facet count.
MESH_SLOPE_RISE = PublishedStat(
    "mesh_slope_same_facets", "|mean gravitational slope / real model's - 1|, same facets",
    0.175, 0.075, "fraction",
    "measured on the shared shape models (Gaskell's Eros and Itokawa, OSIRIS-REx Bennu): mean "
    "slope rises 7-19 % from ~3k to ~12k facets", 0.25,
    "Shape models resolve more slope at more facets (10-25 % per 4x), so a body is compared "
    "with a real one coarsened to the same facet count. At ~12k facets the real bodies' mean "
    "gravitational slopes are 11.1 (Eros), 12.7 (Itokawa) and 13.7 deg (Bennu), all within "
    "23 % of Eros: the limit is 25 %.", calibrated=True)

#: KS distance of two real DEMs of the same ground (the side-by-side comparison's limit).
KS_BETWEEN_REAL_DEMS = PublishedStat(
    "ks_between_real_dems", "KS distance of slope distributions, same ground", 0.225, 0.05,
    "", "measured: Malapert SfS vs stereo NAC DEMs 0.225; halves of the SfS DEM 0.10-0.20",
    0.3, "Two real DEMs of one area differ by 0.225; the limit 0.3 lets them agree.",
    calibrated=True)

#: Median slope of a terrain built for a law, against the law, from 17 m to 1 km.
SLOPE_LAW_DEG = PublishedStat(
    "slope_law_deg", "|median slope - law| at 17 m to 1 km baselines, terrain built for the law",
    0.0, 1.0, "deg", "Rosenburg et al. 2011 (LOLA median bidirectional slopes, 17 m - 2.7 km)",
    1.0,
    "A synthetic site is built to its terrain law, so it must reproduce the law's median "
    "slope at the baselines LOLA measures to within 1 deg (13 % of the polar 7.6 deg at 17 m), "
    "well inside the factor-2 scatter between real sites: a miss means the generator missed "
    "its target. Real DEMs are judged by the wider band of slope_band_factor instead.")

#: RMS slope of regolith at centimetre baselines, rock-free, the site's tilt removed.
REGOLITH_RMS_SLOPE = PublishedStat(
    "regolith_rms_slope", "RMS slope at the finest centimetre baseline (plane removed)",
    15.0, 5.0, "deg",
    "Helfenstein and Shepard 1999 (Icarus 141, 107: Apollo stereo photographs of regolith, "
    "self-affine from millimetres to centimetres); Hayne et al. 2021 (Nat. Astron. 5, 169: "
    "sub-metre roughness from Diviner thermal emission): RMS slopes ~10-20 deg at ~1 cm",
    10.0,
    "The regolith's RMS slope rises from a few degrees at a metre to 10-20 deg at "
    "centimetres; at the finest layer's baseline (at most 5 cm) it must lie in 10-20 deg "
    "(the threshold is the lower edge; the upper edge is checked as well).")

#: Share steeper than the angle of repose away from young craters.
STEEP_OLD_TERRAIN = PublishedStat(
    "steep_share_old", "area steeper than 35 deg outside craters younger than 100 Myr",
    0.0, 0.005, "fraction",
    "Kreslavsky and Head 2016 (Icarus 273, 329): lunar slope-frequency distributions roll "
    "over at the angle of repose (32-35 deg, Carrier et al. 1991); only young crater walls "
    "stand steeper", 0.005,
    "Away from fresh craters (younger than 100 Myr, within 1.2 radii of the centre) old "
    "terrain has relaxed to repose: at most 0.5 % of it may be steeper than 35 deg.")

#: Depth/diameter of the visible 10-100 m craters (a population, not only fresh ones).
SMALL_CRATER_DD = PublishedStat(
    "small_crater_dd_mean", "mean depth/diameter of visible 10-100 m craters", 0.12, 0.04, "",
    "Stopar et al. 2017 (Icarus 298, 34) and Mahanti et al. 2018 (Icarus 299, 475): small "
    "craters' d/D is near log-normal, fresh 0.14-0.2, degraded down to ~0.04 where they stop "
    "being counted; population means ~0.1-0.14", 0.04,
    "The mean must lie within 0.04 of 0.12 (0.08-0.16): a population stuck at its degraded "
    "floor (mean 0.02-0.05) or all fresh (0.2) fails.")

#: Rock size-frequency distribution against the terrain preset's VIPER model.
ROCK_SFD = PublishedStat(
    "rock_sfd_model", "|N(>=D) / model - 1| over a decade of rock size outside fresh craters' "
    "block fields, each size on the widest layer resolving it", 0.0, 0.15, "",
    "VIPER environment specification (NASA): N(>=D) = 3e-4 D^-2.482 per m^2 (nominal), "
    "1e-4 D^-1.755 (low), 2e-3 D^-2.661 (high, after Haworth)", 0.15,
    "A terrain built for the model must follow it within 15 % at every size, plus two "
    "Poisson standard deviations of the count the model expects over the counted area "
    "(2 / sqrt(N)): a field drawn from the model passes each size at least 97.7 % of the "
    "time, and the limit is reported per size.")

#: Rocks inside fresh craters' block fields against the background law plus the blocks expected.
BLOCK_FIELDS = PublishedStat(
    "rock_block_fields", "|N(>=D) inside fresh craters' block fields / (background + expected "
    "blocks) - 1|, each size on the widest layer resolving it", 0.0, 0.15, "",
    "Pajola et al. 2019 (Planet. Space Sci. 165, 99: Linne, Dc 2.2 km, 12,000 boulders >= "
    "4.4 m, cumulative index -4.03); Bart and Melosh 2010 (Icarus 209, 337: block sizes as "
    "Dc^0.66); Basilevsky et al. 2013 (Planet. Space Sci. 89, 118: median boulder survival "
    "40-80 Myr); excavation to 0.1 Dc below the regolith (Melosh 1989)", 0.15,
    "The blocks expected in the footprints (reach crater radii) of the catalogue's fresh "
    "craters follow from each crater's diameter, age and place by the published calibration "
    "(evaluation.blockfields); with the background law over the footprints' area they must "
    "match the count within 15 % plus two Poisson standard deviations of the expected count "
    "(2 / sqrt(N)), as the background does.")

#: Every entry, for the report's sources table.
STATS = (SLOPE_BAND_FACTOR, SLOPE_LAW_DEG, REGOLITH_RMS_SLOPE, HURST_TOLERANCE, SMOOTHNESS,
         STEEP_SLOPE, STEEP_OLD_TERRAIN, CRATER_EQUILIBRIUM, FRESH_DEPTH_DIAMETER,
         SMALL_CRATER_DD, ROCK_ABUNDANCE, ROCK_DENSITY, ROCK_SFD, BLOCK_FIELDS,
         BODY_BOULDER_INDEX, MESH_SLOPE_RISE, KS_BETWEEN_REAL_DEMS)


def equilibrium_density(diameter_m) -> float:
    """Empirical equilibrium N(>=D) per m^2 (Trask 1966), the generator's own table.

    >>> round(equilibrium_density(1000.0) * 1e6, 4)
    0.0794
    """
    from terrain.core.presets import equilibrium_density as trask

    return float(trask(diameter_m))


def viper_cumulative(model: str, diameter_m):
    """N(>=D) per m^2 of a VIPER environment specification rock model.

    Parameters
    ----------
    model : str
        ``"low"``, ``"nominal"`` or ``"high"`` (a ``viper-`` prefix is accepted).
    diameter_m : float or array
        Diameters, metres.

    >>> round(float(viper_cumulative("viper-nominal", 1.0)) * 1e6)
    300
    """
    import numpy as np

    a, b = VIPER_ROCK_MODELS[model.removeprefix("viper-")]
    return a * np.asarray(diameter_m, dtype=float) ** b
