"""Surface reflectance models: Lambert, Lommel-Seeliger, lunar-Lambert (McEwen) and Hapke.

The first three return the reflectance factor I/F for incidence cosine mu0 (surface normal and
sun), emission cosine mu (normal and camera) and phase angle g, with albedo A scaling them so
that every model gives A at normal incidence and emission:

* Lambert: ``I/F = A mu0``.
* Lommel-Seeliger, the single-scattering law of dark regoliths: ``I/F = A 2 mu0 / (mu0 + mu)``.
* Lunar-Lambert (McEwen 1991, Icarus 92, 298): a phase-dependent mix of the two,
  ``I/F = A [L(g) 2 mu0 / (mu0 + mu) + (1 - L(g)) mu0]`` with
  ``L(g) = 1 + a g + b g^2 + c g^3`` (g in degrees). The default coefficients are McEwen's
  fit for the Moon (a = -0.019, b = 2.42e-4, c = -1.46e-6; McEwen 1996, LPSC XXVII 841), which
  make the limb darkening vanish near g = 80 degrees, as observed.

Hapke's model (Hapke 2012, *Theory of Reflectance and Emittance Spectroscopy*, 2nd ed., the
form Sato et al. 2014 fit to LROC WAC, JGR Planets 119, 1775-1805, their eqs. 1-8)::

    I/F = K w/4 mu0e / (mu0e + mue) [p(g) (1 + Bs0 Bs(g)) + M(mu0e / K, mue / K)]
          [1 + Bc0 Bc(g)] S(i, e, psi)

with the two-term Henyey-Greenstein phase function ``p(g) = (1 + c)/2 (1 - b^2) / (1 - 2 b cos g
+ b^2)^1.5 + (1 - c)/2 (1 - b^2) / (1 + 2 b cos g + b^2)^1.5`` (c > 0: backscattering), the
shadow-hiding opposition effect ``Bs = 1 / (1 + tan(g/2) / hs)``, the coherent-backscatter one
``Bc = (1 + (1 - exp(-x)) / x) / (2 (1 + x)^2)``, ``x = tan(g/2) / hc`` (Hapke 2002, Icarus 157,
523, eq. 31), isotropic multiple scattering ``M = H(x0) H(x) - 1`` with Hapke's (2002, eq. 13)
H-function, the porosity factor K (1 unless a filling factor ``phi`` is given, Hapke 2008) and
the macroscopic-roughness correction of Hapke (1984, Icarus 59, 41) that turns mu0, mu into the
effective mu0e, mue and multiplies by the shadowing function S. :data:`SATO_643NM` holds the
lunar defaults (Sato et al. 2014, WAC 643 nm band: w 0.222, b 0.254, c 0.160, Bs0 1.993,
hs 0.0597, theta-bar 23.657 degrees). Sato et al. held the coherent-backscatter and porosity
terms at constant values; the defaults leave them out (Bc0 = 0, K = 1): set ``bc0``, ``hc``
and ``phi`` to include them.

A per-pixel albedo map (a raster on a terrain, a value per vertex on a body) multiplies the
albedo A of the first three models and Hapke's w (capped below 1).

The shader (``render/shaders/shade.frag``) implements the same formulas; the functions here
are the numpy reference for CPU use (tests check the rendered Hapke I/F against a separate
implementation written from the papers).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from terrain.core.checks import check_keys, number
from terrain.core.errors import InvalidParameterError

__all__ = ["BRDF_CODES", "MCEWEN_MOON", "SATO_643NM", "Hapke", "check_brdf", "hapke",
           "reflectance"]

#: Codes of the models in the shader.
BRDF_CODES = {"lambert": 0, "lommel-seeliger": 1, "lunar-lambert": 2, "hapke": 3}
#: McEwen's lunar-Lambert L(g) polynomial for the Moon (g in degrees).
MCEWEN_MOON = (-0.019, 2.42e-4, -1.46e-6)


@dataclass(frozen=True)
class Hapke:
    """Hapke parameters (see the module docstring); defaults: Sato et al. (2014), 643 nm.

    w : single-scattering albedo in [0, 1); b, c : two-term Henyey-Greenstein asymmetry in
    [0, 1) and backscatter fraction in [-1, 1]; bs0, hs : shadow-hiding opposition amplitude
    (>= 0) and angular width (> 0 where bs0 > 0); bc0, hc : coherent-backscatter amplitude and
    width; theta_bar : mean slope angle of the macroscopic roughness, degrees in [0, 60];
    phi : filling factor in [0, 0.752) for the porosity factor K (0: K = 1).
    """

    w: float = 0.222
    b: float = 0.254
    c: float = 0.160
    bs0: float = 1.993
    hs: float = 0.0597
    bc0: float = 0.0
    hc: float = 0.0
    theta_bar: float = 23.657
    phi: float = 0.0

    def __post_init__(self):
        limits = dict(w=(0.0, 0.999999), b=(0.0, 0.999), c=(-1.0, 1.0), bs0=(0.0, None),
                      hs=(0.0, None), bc0=(0.0, None), hc=(0.0, None), theta_bar=(0.0, 60.0),
                      phi=(0.0, 0.75))
        for name, (lo, hi) in limits.items():
            object.__setattr__(self, name, number(getattr(self, name), name, low=lo, high=hi,
                                                  where="Hapke"))
        if self.bs0 > 0 and self.hs <= 0:
            raise InvalidParameterError("Hapke hs must be > 0 where bs0 > 0")
        if self.bc0 > 0 and self.hc <= 0:
            raise InvalidParameterError("Hapke hc must be > 0 where bc0 > 0")

    @classmethod
    def from_mapping(cls, mapping) -> Hapke:
        """Parameters from a table (unknown keys are errors); missing ones keep the defaults.

        >>> Hapke.from_mapping({"w": 0.3}).w
        0.3
        """
        return cls(**check_keys(mapping, set(cls.__dataclass_fields__), "Hapke parameters"))

    @property
    def porosity_k(self) -> float:
        """K = -ln(1 - 1.209 phi^(2/3)) / (1.209 phi^(2/3)) (Hapke 2008, eq. 23); 1 at phi = 0."""
        if self.phi == 0:
            return 1.0
        x = 1.209 * self.phi ** (2.0 / 3.0)
        return -math.log(1.0 - x) / x

    def as_dict(self) -> dict:
        """Return the photometric parameters as plain data for run manifests."""
        return asdict(self)


#: Mean slope (radians) below which a surface counts as smooth (S = 1; the roughness
#: formulas divide by tan(theta-bar)^2, which underflows for smaller angles).
ROUGH_MIN = 1e-6

#: The lunar Hapke parameters of Sato et al. (2014), LROC WAC 643 nm band (no CBOE, K = 1).
SATO_643NM = Hapke()


def _h_function(x, w):
    """Hapke (2002) eq. 13 approximation of Chandrasekhar's H-function."""
    gam = np.sqrt(1.0 - w)
    r0 = (1.0 - gam) / (1.0 + gam)
    x = np.maximum(x, 1e-6)
    return 1.0 / (1.0 - w * x * (r0 + 0.5 * (1.0 - 2.0 * r0 * x) * np.log((1.0 + x) / x)))


def hapke(mu0, mu, phase_deg, params: Hapke = SATO_643NM, scale=1.0) -> np.ndarray:
    """Hapke I/F (see the module docstring) for cosines mu0, mu and phase angle g (degrees).

    The azimuth psi between the planes of incidence and emission follows from the three
    angles. ``scale`` multiplies w (an albedo map). Zero where the sun is below the surface.

    >>> round(float(hapke(np.cos(np.radians(30)), 1.0, 30.0)), 4)
    0.0503
    """
    mu0 = np.asarray(mu0, dtype=np.float64)
    mu = np.maximum(np.asarray(mu, dtype=np.float64), 1e-4)
    g = np.radians(np.asarray(phase_deg, dtype=np.float64))
    lit = mu0 > 0
    mu0 = np.where(lit, mu0, 1.0)
    w = np.minimum(params.w * np.asarray(scale, dtype=np.float64), 0.999999)
    b, c = params.b, params.c
    cg = np.cos(g)
    tg2 = np.tan(g / 2)
    p = (0.5 * (1 + c) * (1 - b * b) / (1 - 2 * b * cg + b * b) ** 1.5
         + 0.5 * (1 - c) * (1 - b * b) / (1 + 2 * b * cg + b * b) ** 1.5)
    bs = 1.0 / (1.0 + tg2 / params.hs) if params.hs > 0 else 0.0
    bc = 0.0
    if params.bc0 > 0:
        x = np.maximum(tg2 / params.hc, 1e-12)
        bc = (1 + (1 - np.exp(-x)) / x) / (2 * (1 + x) ** 2)
    mu0e, mue, shadow = mu0, mu, 1.0
    if math.radians(params.theta_bar) > ROUGH_MIN:
        mu0e, mue, shadow = _roughness(mu0, mu, cg, math.radians(params.theta_bar))
    k = params.porosity_k
    m = _h_function(mu0e / k, w) * _h_function(mue / k, w) - 1.0
    out = (k * w / 4 * mu0e / (mu0e + mue) * (p * (1 + params.bs0 * bs) + m)
           * (1 + params.bc0 * bc) * shadow)
    return np.where(lit, out, 0.0)


def _roughness(mu0, mu, cg, theta):
    """Effective cosines and shadowing S of Hapke (1984) (Hapke 2012, eqs. 12.46-12.55)."""
    si = np.sqrt(np.maximum(1 - mu0 * mu0, 0.0))
    se = np.sqrt(np.maximum(1 - mu * mu, 0.0))
    denom = si * se
    cpsi = np.where(denom > 1e-12, (cg - mu0 * mu) / np.maximum(denom, 1e-300), 1.0)
    psi = np.arccos(np.clip(cpsi, -1.0, 1.0))
    f = np.where(psi < math.pi - 1e-9, np.exp(-2 * np.tan(np.minimum(psi, 3.1415) / 2)), 0.0)
    tt = math.tan(theta)
    chi = 1 / math.sqrt(1 + math.pi * tt * tt)
    cot_i = np.minimum(mu0 / np.maximum(si, 1e-10), 1e6)
    cot_e = np.minimum(mu / np.maximum(se, 1e-10), 1e6)
    e1i, e1e = np.exp(-2 / math.pi / tt * cot_i), np.exp(-2 / math.pi / tt * cot_e)
    e2i = np.exp(-1 / math.pi / tt**2 * cot_i**2)
    e2e = np.exp(-1 / math.pi / tt**2 * cot_e**2)
    eta_i = chi * (mu0 + si * tt * e2i / (2 - e1i))
    eta_e = chi * (mu + se * tt * e2e / (2 - e1e))
    s2 = np.sin(psi / 2) ** 2
    first = mu0 >= mu  # i <= e
    d1 = 2 - e1e - psi / math.pi * e1i
    d2 = 2 - e1i - psi / math.pi * e1e
    mu0e = np.where(first, chi * (mu0 + si * tt * (np.cos(psi) * e2e + s2 * e2i) / d1),
                    chi * (mu0 + si * tt * (e2i - s2 * e2e) / d2))
    mue = np.where(first, chi * (mu + se * tt * (e2e - s2 * e2i) / d1),
                   chi * (mu + se * tt * (np.cos(psi) * e2i + s2 * e2e) / d2))
    q = np.where(first, mu0 / eta_i, mu / eta_e)
    shadow = mue / eta_e * mu0 / eta_i * chi / (1 - f + f * chi * q)
    return mu0e, mue, shadow


def check_brdf(name: str) -> str:
    """Normalise a reflectance name ('lambert', 'lommel-seeliger', 'lunar-lambert', 'hapke')."""
    key = str(name).strip().lower().replace("_", "-").replace(" ", "-")
    if key not in BRDF_CODES:
        raise InvalidParameterError(
            f"reflectance must be one of {sorted(BRDF_CODES)}; got {name!r}")
    return key


def reflectance(brdf: str, mu0, mu, phase_deg, albedo: float = 1.0,
                mcewen=MCEWEN_MOON, hapke_params: Hapke = SATO_643NM) -> np.ndarray:
    """I/F of a model (see the module docstring); zero where the sun is below the surface.

    For Hapke, ``albedo`` is the albedo-map factor on w (1: the parameters as given).

    >>> float(reflectance("lunar-lambert", 1.0, 1.0, 0.0, 0.2))
    0.2
    """
    brdf = check_brdf(brdf)
    if brdf == "hapke":
        return hapke(mu0, mu, phase_deg, hapke_params, albedo)
    mu0 = np.asarray(mu0, dtype=np.float64)
    mu = np.maximum(np.asarray(mu, dtype=np.float64), 1e-4)
    g = np.asarray(phase_deg, dtype=np.float64)
    lit = mu0 > 0
    mu0c = np.where(lit, mu0, 0.0)
    if brdf == "lambert":
        out = albedo * mu0c
    else:
        ls = 2.0 * mu0c / (mu0c + mu)
        if brdf == "lommel-seeliger":
            out = albedo * ls
        else:
            a, b, c = mcewen
            lg = 1.0 + g * (a + g * (b + g * c))
            out = albedo * (lg * ls + (1.0 - lg) * mu0c)
    return np.where(lit, out, 0.0)
