"""Terrain presets: the published numbers that make a tile look like one kind of lunar ground.

``--terrain south-polar|highlands|maria`` (synth, enhance and rocks; scenarios and campaign files
as ``terrain = "..."``) chooses one :class:`TerrainPreset`. Each field is a measured quantity, and
each preset lists the measurements it comes from in :attr:`TerrainPreset.sources`; the table is
repeated, with the sources, in ``docs/presets.md``.

Roughness is given as the LOLA bidirectional-slope law: the median slope ``slope_17m_deg`` at a
17 m baseline and the Hurst exponent ``hurst``, so that the median slope at baseline ``L`` is
``atan(tan(slope_17m) (L / 17 m)^(hurst - 1))`` up to ``self_affine_max_m``, beyond which the
surface stops being self-affine and the slope falls faster (Rosenburg et al. 2011, JGR 116,
E02001, Table 1 and Figs. 5-8; Kreslavsky et al. 2013, Icarus 226, 52).

Examples
--------
>>> preset("south-polar").hurst
0.95
>>> preset("south polar")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
terrain.core.errors.InvalidParameterError: terrain preset 'south polar' is not known (did you ...
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from terrain.core.checks import text

__all__ = ["EQUILIBRIUM_EXPONENT", "HURST_BEYOND_SELF_AFFINE", "LAW_BASELINE_M",
           "MEDIAN_ABS_GAUSSIAN", "PRESETS", "TRASK_EQUILIBRIUM", "TerrainPreset",
           "equilibrium_density", "preset"]

#: Baseline (m) of the slope law's anchor: LOLA's 17 m bidirectional slopes (Rosenburg et al.
#: 2011).
LAW_BASELINE_M = 17.0
#: Median of |x| over the standard deviation of a zero-mean Gaussian x (sqrt(2) erf^-1(1/2)):
#: a median slope over a baseline is this times the RMS gradient of Gaussian height differences.
MEDIAN_ABS_GAUSSIAN = 0.6744897501960817
#: Hurst exponent of the slope law beyond a preset's self-affine range: LOLA's slopes fall
#: faster there (Rosenburg et al. 2011, Figs. 5-8); 0.5, independent increments, is our
#: choice, the one ``terrain synth`` gives a base above the range.
HURST_BEYOND_SELF_AFFINE = 0.5


#: Cumulative size-frequency exponent of the empirical crater equilibrium.
EQUILIBRIUM_EXPONENT = -2.0


def equilibrium_density(diameter_m):
    """Empirical equilibrium N(>=D) per m^2 (Trask 1966: 10^-1.1 D_km^-2 per km^2).

    The density at which small lunar craters are erased as fast as they form (Trask 1966,
    Ranger VIII and IX counts; as used by Gault 1970): 0.079 D^-2 per m^2 with D in metres.

    >>> round(float(equilibrium_density(1000.0)) * 1e6, 4)
    0.0794
    >>> round(float(equilibrium_density(10.0)) * 1e6)
    794
    """
    import numpy as np

    d_km = np.asarray(diameter_m, dtype=float) / 1000.0
    return 10 ** -1.1 * d_km ** EQUILIBRIUM_EXPONENT / 1e6

#: The empirical crater equilibrium ``N(>=D) = c D^-2`` per m^2 with D in metres: Trask (1966,
#: Ranger VIII and IX) found log N = 10.9 - 2 log D per 10^6 km^2, i.e. c = 10^-1.1 = 0.079
#: (Gault 1970; Melosh 1989, ch. 10; the same number :mod:`evaluation.lunar_stats` judges by).
TRASK_EQUILIBRIUM = 10.0 ** -1.1


@dataclass(frozen=True)
class TerrainPreset:
    """One kind of lunar ground, as published measurements.

    Parameters
    ----------
    name : str
        The preset's name (``--terrain NAME``).
    description : str
        One line for listings.
    slope_17m_deg : float
        Median bidirectional slope at a 17 m baseline, degrees (LOLA).
    hurst : float
        Hurst exponent of the slope-baseline law from 17 m up to ``self_affine_max_m``.
    self_affine_max_m : float
        Largest baseline (m) over which the surface stays self-affine.
    crater_equilibrium : float
        Density of small craters as a multiple of the empirical equilibrium
        ``N(>=D) = 10^-1.1 D^-2`` per m^2, D in metres (:data:`TRASK_EQUILIBRIUM`).
    surface_age_gyr : float
        Age of the surface (Gyr): the oldest crater it keeps.
    repose_deg : float
        Angle of repose of the regolith (degrees): old slopes relax to it.
    diffusivity_m2_per_myr : float
        Topographic diffusivity (m^2/Myr) that degrades craters (Fassett and Thomson 2014).
    visible_depth_ratio : float
        d/D below which a degraded crater is no longer seen (Stopar et al. 2017).
    rock_model : str
        Rock model name (the VIPER environment specification's ``viper-low``,
        ``viper-nominal`` or ``viper-high``).
    regolith_m : float
        Regolith thickness (m): craters whose excavation stays in it throw out no blocks
        (:mod:`terrain.surface.rocks`).
    sources : tuple of str
        Where each number comes from.
    """

    name: str
    description: str
    slope_17m_deg: float
    hurst: float
    self_affine_max_m: float
    crater_equilibrium: float
    surface_age_gyr: float
    repose_deg: float
    rock_model: str
    sources: tuple[str, ...]
    diffusivity_m2_per_myr: float = 5.5
    visible_depth_ratio: float = 0.04
    regolith_m: float = 5.0

    def median_slope_deg(self, baseline_m: float) -> float:
        """Median bidirectional slope (deg) of the preset's law at ``baseline_m`` metres.

        ``atan(tan(slope_17m) (L / 17 m)^(H - 1))`` up to the self-affine range (Rosenburg et
        al. 2011), continued beyond it with :data:`HURST_BEYOND_SELF_AFFINE`.

        >>> round(preset("south-polar").median_slope_deg(17.0), 2)
        7.6
        >>> round(preset("south-polar").median_slope_deg(1000.0), 2)
        6.21
        """
        if not baseline_m > 0:
            raise ValueError(f"baseline must be positive metres; got {baseline_m}")
        t = math.tan(math.radians(self.slope_17m_deg))
        top = self.self_affine_max_m
        if baseline_m <= top:
            t *= (baseline_m / LAW_BASELINE_M) ** (self.hurst - 1.0)
        else:
            t *= (top / LAW_BASELINE_M) ** (self.hurst - 1.0) \
                * (baseline_m / top) ** (HURST_BEYOND_SELF_AFFINE - 1.0)
        return math.degrees(math.atan(t))

    def rms_gradient(self, baseline_m: float) -> float:
        """RMS gradient (m/m) over ``baseline_m`` of Gaussian differences of the law's median.

        >>> round(preset("south-polar").rms_gradient(17.0), 4)
        0.1978
        """
        return math.tan(math.radians(self.median_slope_deg(baseline_m))) / MEDIAN_ABS_GAUSSIAN


#: The presets by name. Numbers: LOLA slopes and Hurst exponents from Rosenburg et al. (2011,
#: JGR 116, E02001); the issue-quoted south-polar 7.6 deg at 17 m is their polar value; maria
#: 2.0 deg at 17 m with H 0.76 self-affine to ~0.5 km and highlands 7.5 deg with H 0.95 to ~1 km
#: (same paper, Table 1); crater equilibrium from Trask (1966); surface ages from crater counts
#: (south-polar and highlands ~3.9 Gyr: Stöffler and Ryder 2001; maria ~3.5 Gyr: Hiesinger et
#: al. 2011); angle of repose 35 deg for lunar regolith (Carrier et al. 1991, Lunar Sourcebook
#: ch. 9, 30-50 deg measured, 35 deg typical at the surface's low density); rocks from the VIPER
#: environment specification (NASA VIPER-ENV, after Haworth and Li et al.); regolith 4-5 m
#: thick on the maria and 10-15 m on the highlands (McKay et al. 1991, Lunar Sourcebook ch. 7;
#: Bandfield et al. 2011, JGR 116, E00H02, find the highlands' rocky craters larger, the
#: regolith thicker, than the maria's).
PRESETS: dict[str, TerrainPreset] = {
    p.name: p for p in (
        TerrainPreset(
            name="south-polar",
            description="lunar south-polar highland terrain (the demo's site)",
            slope_17m_deg=7.6, hurst=0.95, self_affine_max_m=1000.0,
            crater_equilibrium=1.0, surface_age_gyr=3.9, repose_deg=35.0,
            rock_model="viper-nominal", regolith_m=10.0,
            sources=("Rosenburg et al. 2011 (LOLA slopes and Hurst exponent, polar)",
                     "Trask 1966 (crater equilibrium)",
                     "Fassett and Thomson 2014 (topographic diffusivity)",
                     "Stopar et al. 2017 (d/D of counted small craters)",
                     "Carrier et al. 1991 (angle of repose)",
                     "VIPER environment specification (rock SFD, nominal)",
                     "McKay et al. 1991 (highland regolith 10-15 m)")),
        TerrainPreset(
            name="highlands",
            description="lunar highlands (heavily cratered, rough at km scale)",
            slope_17m_deg=7.5, hurst=0.95, self_affine_max_m=1000.0,
            crater_equilibrium=1.0, surface_age_gyr=3.9, repose_deg=35.0,
            rock_model="viper-nominal", regolith_m=10.0,
            sources=("Rosenburg et al. 2011 (LOLA highlands slopes and Hurst exponent)",
                     "Trask 1966 (crater equilibrium)",
                     "Fassett and Thomson 2014 (topographic diffusivity)",
                     "Stopar et al. 2017 (d/D of counted small craters)",
                     "Carrier et al. 1991 (angle of repose)",
                     "VIPER environment specification (rock SFD, nominal)",
                     "McKay et al. 1991 (highland regolith 10-15 m)")),
        TerrainPreset(
            name="maria",
            description="lunar mare plains (smooth, self-affine to ~0.5 km)",
            slope_17m_deg=2.0, hurst=0.76, self_affine_max_m=500.0,
            crater_equilibrium=1.0, surface_age_gyr=3.5, repose_deg=35.0,
            rock_model="viper-low", regolith_m=5.0,
            sources=("Rosenburg et al. 2011 (LOLA maria slopes and Hurst exponent)",
                     "Trask 1966 (crater equilibrium)",
                     "Fassett and Thomson 2014 (topographic diffusivity)",
                     "Stopar et al. 2017 (d/D of counted small craters)",
                     "Hiesinger et al. 2011 (mare ages)",
                     "Carrier et al. 1991 (angle of repose)",
                     "VIPER environment specification (rock SFD, low)",
                     "McKay et al. 1991 (mare regolith 4-5 m)")),
    )
}


def preset(name: str) -> TerrainPreset:
    """Return the preset called ``name``; an unknown name is refused naming the nearest.

    Parameters
    ----------
    name : str
        ``south-polar``, ``highlands`` or ``maria``.

    Returns
    -------
    TerrainPreset
        Its published numbers.
    """
    return PRESETS[text(name, "terrain preset", choices=PRESETS)]
