"""Hapke photometry: rendered I/F against a separate evaluation from the papers, lunar defaults
against McEwen's published lunar limb-darkening curve."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from render.camera import Intrinsics, look_at
from render.reflectance import MCEWEN_MOON, SATO_643NM, Hapke, hapke
from render.renderer import Lighting, RenderOptions, View
from render.terrain_scene import TerrainScene
from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterCatalog
from terrain.stack.model import Layer, LayerStack


def hapke_from_the_papers(i, e, g, w, b, c, bs0, hs, bc0, hc, theta_deg, phi):
    """I/F of Hapke's model written out from the papers, angle by angle (radians).

    Hapke (2012) eqs. 12.55 (I/F), 6.7 (double Henyey-Greenstein), 9.22 (shadow hiding),
    9.43 (coherent backscatter), 8.56 (H-function, Hapke 2002 eq. 13), 7.45 (porosity K,
    Hapke 2008 eq. 23) and the roughness of Hapke (1984) eqs. 46-52 (2012: 12.45-12.54).
    """
    K = 1.0
    if phi > 0:
        K = -math.log(1 - 1.209 * phi ** (2 / 3)) / (1.209 * phi ** (2 / 3))
    P = ((1 + c) / 2 * (1 - b**2) / (1 - 2 * b * math.cos(g) + b**2) ** 1.5
         + (1 - c) / 2 * (1 - b**2) / (1 + 2 * b * math.cos(g) + b**2) ** 1.5)
    BS = bs0 / (1 + math.tan(g / 2) / hs)
    if bc0 > 0:
        y = math.tan(g / 2) / hc
        BC = bc0 * (1 + (1 - math.exp(-y)) / y) / (2 * (1 + y) ** 2) if y > 0 else bc0
    else:
        BC = 0.0

    def H(x):
        r0 = (1 - math.sqrt(1 - w)) / (1 + math.sqrt(1 - w))
        return 1 / (1 - w * x * (r0 + (1 - 2 * r0 * x) / 2 * math.log((1 + x) / x)))

    if theta_deg == 0:
        m0, m, S = math.cos(i), math.cos(e), 1.0
    else:
        th = math.radians(theta_deg)
        X = 1 / math.sqrt(1 + math.pi * math.tan(th) ** 2)
        # azimuth between the planes of incidence and emission (spherical law of cosines)
        if math.sin(i) * math.sin(e) < 1e-12:
            psi = 0.0
        else:
            psi = math.acos(max(-1.0, min(1.0, (math.cos(g) - math.cos(i) * math.cos(e))
                                          / (math.sin(i) * math.sin(e)))))
        f = math.exp(-2 * math.tan(psi / 2)) if psi < math.pi else 0.0

        def E1(x):
            return math.exp(-2 / math.pi / math.tan(th) / math.tan(x)) if x > 0 else 0.0

        def E2(x):
            return math.exp(-1 / math.pi / math.tan(th) ** 2 / math.tan(x) ** 2) if x > 0 else 0.0

        def eta(x):
            return X * (math.cos(x) + math.sin(x) * math.tan(th) * E2(x) / (2 - E1(x)))

        if i <= e:
            den = 2 - E1(e) - psi / math.pi * E1(i)
            m0 = X * (math.cos(i) + math.sin(i) * math.tan(th)
                      * (math.cos(psi) * E2(e) + math.sin(psi / 2) ** 2 * E2(i)) / den)
            m = X * (math.cos(e) + math.sin(e) * math.tan(th)
                     * (E2(e) - math.sin(psi / 2) ** 2 * E2(i)) / den)
            S = m / eta(e) * math.cos(i) / eta(i) * X / (1 - f + f * X * math.cos(i) / eta(i))
        else:
            den = 2 - E1(i) - psi / math.pi * E1(e)
            m0 = X * (math.cos(i) + math.sin(i) * math.tan(th)
                      * (E2(i) - math.sin(psi / 2) ** 2 * E2(e)) / den)
            m = X * (math.cos(e) + math.sin(e) * math.tan(th)
                     * (math.cos(psi) * E2(i) + math.sin(psi / 2) ** 2 * E2(e)) / den)
            S = m / eta(e) * math.cos(i) / eta(i) * X / (1 - f + f * X * math.cos(e) / eta(e))
    return (K * w / 4 * m0 / (m0 + m) * (P * (1 + BS) + H(m0 / K) * H(m / K) - 1)
            * (1 + BC) * S)


@pytest.fixture(scope="module")
def flat_patch():
    tile = DEMTile.from_array(np.zeros((65, 65)), resolution=1.0)
    cat = CraterCatalog.empty(layered=True)
    stack = LayerStack((Layer(tile, None, (0, 0)),), cat, {"site": [32.5, 32.5]})
    return TerrainScene(stack, curvature=False)


PARAMS = {
    "sato-643nm": SATO_643NM,
    "all-terms": Hapke(w=0.55, b=0.31, c=-0.2, bs0=1.2, hs=0.08, bc0=0.6, hc=0.04,
                       theta_bar=15.0, phi=0.35),
}


@pytest.mark.parametrize("name", sorted(PARAMS))
def test_rendered_hapke_matches_the_formula_over_a_grid_of_angles(renderer, flat_patch, name):
    params = PARAMS[name]
    k = Intrinsics.from_fov(24, 24, 8.0)
    target = np.array([32.5, 32.5, 0.0])
    seen = []
    worst = 0.0
    for inc in (3.0, 30.0, 55.0, 75.0):
        light = Lighting.from_angles(90.0, 90.0 - inc, brdf="hapke", hapke=params)
        sun = np.asarray(light.sun)
        for emi in (1.0, 25.0, 50.0, 68.0):
            for az in (80.0, 170.0, 270.0):  # camera azimuth: near the sun's, across, opposite
                a, el = math.radians(az), math.radians(90.0 - emi)
                pos = target + 40.0 * np.array([math.sin(a) * math.cos(el),
                                                math.cos(a) * math.cos(el), math.sin(el)])
                pose = look_at(tuple(pos), tuple(target))
                fr = renderer.render(flat_patch, View(pose, k), light,
                                     RenderOptions(shadows=False))
                ok = np.isfinite(fr.range)
                uv = np.stack(np.meshgrid(np.arange(24), np.arange(24)), -1).reshape(-1, 2)
                pts = pose.unproject(uv[ok.ravel()], fr.range[ok], k)
                v = pos - pts
                v /= np.linalg.norm(v, axis=1, keepdims=True)
                i = math.acos(sun[2])
                e = np.arccos(v[:, 2])
                g = np.arccos(np.clip(v @ sun, -1, 1))
                want = np.array([hapke_from_the_papers(i, ee, gg, params.w, params.b, params.c,
                                                       params.bs0, params.hs, params.bc0,
                                                       params.hc, params.theta_bar, params.phi)
                                 for ee, gg in zip(e, g, strict=True)])
                got = fr.radiance[ok].astype(np.float64)
                worst = max(worst, float(np.max(np.abs(got - want) / want)))
                seen.append((math.degrees(i), np.degrees(e).mean(), np.degrees(g).mean()))
    seen = np.array(seen)
    # the grid spans incidence 3-75, emission 1-68 and phase ~2-140 degrees
    assert seen[:, 2].min() < 5 and seen[:, 2].max() > 120
    assert worst < 1e-4, f"largest relative difference {worst:.2e}"


def test_numpy_reference_matches_the_formula():
    for params in PARAMS.values():
        for i, e, g in [(0.3, 0.2, 0.45), (1.0, 0.1, 1.05), (0.2, 1.1, 1.2), (0.7, 0.7, 0.01)]:
            want = hapke_from_the_papers(i, e, g, *[getattr(params, f) for f in (
                "w", "b", "c", "bs0", "hs", "bc0", "hc", "theta_bar", "phi")])
            got = float(hapke(math.cos(i), math.cos(e), math.degrees(g), params))
            assert got == pytest.approx(want, rel=1e-10)


def test_h_function_against_chandrasekhars_table():
    """Hapke's (2002) H-function approximation is within 1 % of Chandrasekhar's (1960,
    Radiative Transfer, his tabulated H) exact H for conservative isotropic scattering: H(0) = 1,
    H(1) = 2.9078; it is exact for w = 0."""
    from render.reflectance import _h_function

    assert float(_h_function(np.array(1e-9), 1.0)) == pytest.approx(1.0, abs=1e-4)
    assert float(_h_function(np.array(1.0), 1.0)) == pytest.approx(2.9078, rel=0.01)
    assert float(_h_function(np.array(0.6), 0.0)) == 1.0


def test_lunar_defaults_reproduce_mcewens_lunar_limb_darkening_curve():
    """McEwen (1991, Icarus 92, 298; polynomial of McEwen 1996, LPSC XXVII 841) fitted the
    lunar-Lambert mix L(g) of Lommel-Seeliger and Lambert to the Moon's disk-resolved
    photometry: L(g) = 1 - 0.019 g + 2.42e-4 g^2 - 1.46e-6 g^3. Across the photometric equator
    at each phase the Sato et al. (2014) Hapke Moon must show the same limb darkening: the
    L(g) that best describes it lies within 0.1 of McEwen's up to g = 60 degrees (beyond,
    the roughness term darkens the limb faster than the polynomial), and at full Moon there
    is no limb darkening (L = 1, the classic observation of a uniformly bright full Moon)."""
    a1, a2, a3 = MCEWEN_MOON
    for gd in (0.0, 10.0, 20.0, 30.0, 45.0, 60.0):
        g = math.radians(gd)
        lon = np.radians(np.linspace(-75 + gd, 75, 41))  # i = |lon - g|, e = |lon|, all < 80
        mu0, mu = np.cos(lon - g), np.cos(lon)
        r = hapke(mu0, mu, np.full_like(mu, gd))
        ls = 2 * mu0 / (mu0 + mu)
        coef, *_ = np.linalg.lstsq(np.stack([ls - mu0, mu0], 1), r, rcond=None)
        fitted = coef[0] / coef[1]
        mcewen = 1 + gd * (a1 + gd * (a2 + gd * a3))
        assert abs(fitted - mcewen) < 0.1, (gd, fitted, mcewen)
        if gd == 0.0:
            assert abs(fitted - 1.0) < 0.02


def test_hapke_records_reject_bad_values_and_unknown_keys():
    with pytest.raises(InvalidParameterError, match="'hs'"):
        Hapke.from_mapping({"h_s": 0.05})
    with pytest.raises(InvalidParameterError, match="w"):
        Hapke(w=1.2)
    with pytest.raises(InvalidParameterError, match="hc"):
        Hapke(bc0=0.5, hc=0.0)


@given(w=st.floats(0.0, 0.99), b=st.floats(0.0, 0.9), c=st.floats(-1.0, 1.0),
       bs0=st.floats(0.0, 3.0), hs=st.floats(0.01, 0.3), theta=st.floats(0.0, 45.0),
       i=st.floats(0.0, 88.0), e=st.floats(0.5, 88.0), t=st.floats(0.0, 1.0))
def test_hapke_is_finite_non_negative_and_continuous_where_its_branches_meet(
        w, b, c, bs0, hs, theta, i, e, t):
    params = Hapke(w=w, b=b, c=c, bs0=bs0, hs=hs, theta_bar=theta)
    g = abs(i - e) + t * (i + e - abs(i - e))  # any phase the two angles allow
    r = float(hapke(math.cos(math.radians(i)), math.cos(math.radians(e)), g, params))
    assert math.isfinite(r) and r >= 0.0
    # the roughness formulas switch between i <= e and i > e: no step where they meet
    a = float(hapke(math.cos(math.radians(i)), math.cos(math.radians(i) + 1e-7), 30.0, params))
    z = float(hapke(math.cos(math.radians(i)), math.cos(math.radians(i) - 1e-7), 30.0, params))
    assert a == pytest.approx(z, rel=1e-5, abs=1e-12)
