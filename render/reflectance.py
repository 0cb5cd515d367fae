"""Surface reflectance models: Lambert, Lommel-Seeliger and lunar-Lambert (McEwen).

All three return the reflectance factor I/F for incidence cosine mu0 (surface normal and
sun), emission cosine mu (normal and camera) and phase angle g, with albedo A scaling them so
that every model gives A at normal incidence and emission:

* Lambert: ``I/F = A mu0``.
* Lommel-Seeliger, the single-scattering law of dark regoliths: ``I/F = A 2 mu0 / (mu0 + mu)``.
* Lunar-Lambert (McEwen 1991, Icarus 92, 298): a phase-dependent mix of the two,
  ``I/F = A [L(g) 2 mu0 / (mu0 + mu) + (1 - L(g)) mu0]`` with
  ``L(g) = 1 + a g + b g^2 + c g^3`` (g in degrees). The default coefficients are McEwen's
  fit for the Moon (a = -0.019, b = 2.42e-4, c = -1.46e-6; McEwen 1996, LPSC XXVII 841), which
  make the limb darkening vanish near g = 80 degrees, as observed.

The shader (``render/shaders/scene.frag``) implements the same formulas; the functions here
are the numpy reference the tests compare rendered pixels against.
"""

from __future__ import annotations

import numpy as np

from terrain.errors import InvalidParameterError

__all__ = ["BRDF_CODES", "MCEWEN_MOON", "check_brdf", "reflectance"]

#: Codes of the models in the shader.
BRDF_CODES = {"lambert": 0, "lommel-seeliger": 1, "lunar-lambert": 2}
#: McEwen's lunar-Lambert L(g) polynomial for the Moon (g in degrees).
MCEWEN_MOON = (-0.019, 2.42e-4, -1.46e-6)


def check_brdf(name: str) -> str:
    """Normalise a reflectance name ('lambert', 'lommel-seeliger', 'lunar-lambert')."""
    key = str(name).strip().lower().replace("_", "-").replace(" ", "-")
    if key not in BRDF_CODES:
        raise InvalidParameterError(
            f"reflectance must be one of {sorted(BRDF_CODES)}; got {name!r}")
    return key


def reflectance(brdf: str, mu0, mu, phase_deg, albedo: float = 1.0,
                mcewen=MCEWEN_MOON) -> np.ndarray:
    """I/F of a model (see the module docstring); zero where the sun is below the surface.

    >>> float(reflectance("lunar-lambert", 1.0, 1.0, 0.0, 0.2))
    0.2
    """
    brdf = check_brdf(brdf)
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
