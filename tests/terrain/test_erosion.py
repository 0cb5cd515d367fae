"""Ross/Soderblom erosion (Martin et al. 2014, eq. 11) and the baseline profile."""

import io

import numpy as np
import pytest

from terrain.core.errors import InvalidParameterError, MissingInputError
from terrain.craters.erosion import ErosionModel


def test_default_profile_is_fresh_at_age_zero_and_rim_decays_faster():
    m = ErosionModel.default()
    d, r = m.factors(0.0, 50.0)
    assert d == 1.0 and r == 1.0
    ages = np.linspace(0.0, 10.0, 400)
    depth, rim = m.factors(ages, np.full_like(ages, m.baseline_diameter))
    assert np.all(rim <= depth), "the rim decays faster than the depth"
    assert rim[-1] == 0.0 and depth[-1] > 0.0, "old craters are rimless depressions"


def test_erosion_is_monotone_in_age_and_diameter():
    m = ErosionModel.default()
    ages = np.linspace(0.0, 4.0, 200)
    for d in (2.0, 30.0, 1000.0, 10000.0):
        depth, rim = m.factors(ages, np.full_like(ages, d))
        assert np.all(np.diff(depth) <= 0) and np.all(np.diff(rim) <= 0)
    diam = np.geomspace(1.0, 20000.0, 200)
    for age in (0.01, 0.5, 3.0):
        depth, rim = m.factors(np.full_like(diam, age), diam)
        assert np.all(np.diff(depth) >= 0) and np.all(np.diff(rim) >= 0), \
            "larger craters of the same age are fresher"


@pytest.mark.parametrize("p", [1.0, 1.1, 1.2])
def test_eq11_maps_ages_to_the_baseline_crater(p):
    m = ErosionModel.default(exponent=p, density_ratio=1.0)
    # T_b = T_x (sigma_b / sigma_x) (D_b / D_x)^P
    assert m.baseline_age(0.3, 250.0) == pytest.approx(0.3 * (1000.0 / 250.0) ** p)
    # a crater D_x at age T_x looks like the baseline at T_b
    tb = float(m.baseline_age(0.3, 250.0))
    assert np.allclose(m.factors(0.3, 250.0), m.factors(tb, m.baseline_diameter))
    m2 = ErosionModel.default(exponent=p, density_ratio=2.0)
    assert m2.baseline_age(0.3, 250.0) == pytest.approx(2 * m.baseline_age(0.3, 250.0))


def test_profile_from_csv_replaces_the_default(tmp_path):
    path = tmp_path / "profile.csv"
    path.write_text("# my profile\nbaseline_age_gyr,depth_fraction,rim_fraction\n"
                    "0,1,1\n1,0.5,0.2\n2,0.4,0\n")
    m = ErosionModel.from_csv(path, baseline_diameter=500.0)
    assert m.factors(1.0, 500.0) == pytest.approx((0.5, 0.2))
    assert m.factors(0.5, 500.0) == pytest.approx((0.75, 0.6))


@pytest.mark.parametrize("text, message", [
    ("age,depth\n0,1\n", "needs columns"),
    ("baseline_age_gyr,depth_fraction,rim_fraction\n0,1,1\n", "at least two rows"),
    ("baseline_age_gyr,depth_fraction,rim_fraction\n0,1,1\n1,1.2,0\n", r"\[0, 1\]"),
    ("baseline_age_gyr,depth_fraction,rim_fraction\n0,1,1\n1,0.5,0.2\n2,0.6,0\n", "increase"),
    ("baseline_age_gyr,depth_fraction,rim_fraction\n0.5,1,1\n1,0.5,0.2\n", "start at 0"),
    ("baseline_age_gyr,depth_fraction,rim_fraction\n0,0.9,1\n1,0.5,0.2\n", "fresh"),
    ("baseline_age_gyr,depth_fraction,rim_fraction\n0,1,1\nx,0.5,0.2\n", "non-numeric"),
])
def test_bad_profiles_are_refused(text, message):
    with pytest.raises(InvalidParameterError, match=message):
        ErosionModel.from_csv(io.StringIO(text))


def test_missing_profile_file(tmp_path):
    with pytest.raises(MissingInputError):
        ErosionModel.from_csv(tmp_path / "nope.csv")


def test_slope_rate_is_the_mean_linearised_creep_diffusivity():
    """m(S) against a finite-difference linearisation of q(S) = S / (1 - (S/Sc)^2)."""
    from terrain.craters.erosion import SlopeDegradation

    deg = SlopeDegradation(critical_slope_deg=35.0)
    sc = np.tan(np.radians(35.0))

    def q(s):
        return s / (1.0 - (s / sc) ** 2)

    for angle in (5.0, 15.0, 25.0, 32.0):
        s = np.tan(np.radians(angle))
        h = 1e-6
        along = (q(s + h) - q(s - h)) / (2 * h)
        across = q(s) / s
        assert deg.rate(np.radians(angle)) == pytest.approx(0.5 * (along + across), rel=1e-6)
    assert deg.rate(0.0) == pytest.approx(1.0)
    assert np.isinf(deg.rate(np.radians(36.0)))
    assert deg.effective_age(0.0, np.radians(40.0)) == 0.0     # a fresh crater stays fresh
    off = SlopeDegradation(enabled=False)
    assert off.effective_age(1.2, np.radians(30.0)) == pytest.approx(1.2)
    with pytest.raises(ValueError, match="did you mean 'critical_slope_deg'"):
        SlopeDegradation.from_mapping({"critical_slope": 30})
