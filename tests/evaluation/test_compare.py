"""Comparing DEMs with a reference: KS distance, quantiles, spectrum ratio, CRS checks."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import stats

from evaluation.compare import (
    check_same_crs,
    compare_dems,
    compare_slope_maps,
    ks_distance,
)
from evaluation.spectrum import fractional_brownian_surface
from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.io import read_dem

WKT_A = ('PROJCRS["moon stereographic",BASEGEOGCRS["Moon",DATUM["Moon",ELLIPSOID["Moon",'
         '1737400,0]]],CONVERSION["ps",METHOD["Polar Stereographic (variant B)"]]]')
WKT_B = ('PROJCRS["moon orthographic",BASEGEOGCRS["Moon",DATUM["Moon",ELLIPSOID["Moon",'
         '1737400,0]]],CONVERSION["o",METHOD["Orthographic"]]]')


def test_same_process_compares_close_and_a_rougher_one_does_not():
    a = fractional_brownian_surface(256, 0.8, resolution=2.0, rms=5.0, seed=1)
    b = fractional_brownian_surface(256, 0.8, resolution=2.0, rms=5.0, seed=2)
    rough = fractional_brownian_surface(256, 0.4, resolution=2.0, rms=5.0, seed=3)
    same = compare_dems(a, b, label="a", reference_label="b")
    other = compare_dems(rough, b, label="rough", reference_label="b")
    assert same.resampled == "none" and same.resolution_m == 2.0
    # two realisations differ (their rms is set over all scales); a rougher process far more
    assert same.ks_distance < 0.2 and other.ks_distance > 0.5
    assert same.log10_ratio_median < 0.3 and other.log10_ratio_median > 0.5
    assert abs(same.hurst - same.reference_hurst) < 0.1
    assert other.hurst < 0.6
    doc = other.as_dict()
    assert doc["quantiles"]["p50"] > doc["reference_quantiles"]["p50"]


def test_two_real_dems_of_the_same_ground_agree_on_their_hurst_exponent(shared_file):
    """The shared NAC SfS DEM carries a period-2 row/column pattern (RMS height difference
    1.22 m at 1 px, 0.20 m at 2 px) that bent a spectral fit to H 0.27, and the stereo DEM of
    the same ground fitted to 1.34: the compared exponents must not be fooled by either, so
    the two agree within the report's calibrated Hurst difference."""
    from evaluation.report import DEFAULT_THRESHOLDS
    from terrain.io import read_dem

    sfs = read_dem(shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif"))
    stereo = read_dem(shared_file("lunar", "southpole_85S_nac_asp_stereo_dem_1p08m.tif"))
    c = compare_dems(sfs, stereo, label="SfS", reference_label="stereo")
    assert 0.7 < c.hurst < 1.0 and 0.7 < c.reference_hurst < 1.0
    assert abs(c.hurst - c.reference_hurst) <= DEFAULT_THRESHOLDS["dem"]["max_hurst_difference"]


def test_different_resolutions_are_compared_at_the_coarser_baseline():
    fine = fractional_brownian_surface(256, 0.8, resolution=1.0, rms=5.0, seed=4)
    coarse = fractional_brownian_surface(64, 0.8, resolution=4.0, rms=5.0, seed=5)
    c = compare_dems(fine, coarse)
    assert c.resampled == "DEM" and c.resolution_m == 4.0
    assert c.distribution.resolution_m == 4.0
    c2 = compare_dems(coarse, fine)
    assert c2.resampled == "reference"


def test_different_crs_are_refused_and_local_frames_allowed(caplog):
    t = fractional_brownian_surface(16, 0.8, seed=1)
    with pytest.raises(InvalidDEMError, match="different coordinate reference systems.*"
                                              "Polar Stereographic.*Orthographic"):
        compare_dems(t.replace(crs=WKT_A), t.replace(crs=WKT_B))
    check_same_crs(t.replace(crs=WKT_A), t.replace(crs=WKT_A))
    check_same_crs(t.replace(crs=WKT_A), t)
    assert "has no CRS" in caplog.text


def test_real_dems_in_different_crs_are_refused(shared_file):
    a = read_dem(shared_file("lunar", "southpole_85S_nac_asp_stereo_dem_1p08m.tif"))
    b = read_dem(shared_file("lunar", "aristarchus_CP_quickmap_hsr_26p5m.tif"))
    with pytest.raises(InvalidDEMError, match="reproject"):
        compare_dems(a, b)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # scipy's p-value for tiny samples
@given(st.lists(st.floats(-50, 50), min_size=1, max_size=40),
       st.lists(st.floats(-50, 50), min_size=1, max_size=40))
def test_ks_distance_equals_scipys_statistic(a, b):
    assert ks_distance(a, b) == pytest.approx(
        stats.ks_2samp(a, b, method="asymp").statistic, abs=1e-12)


def test_weighted_ks_counts_weights_like_repetitions():
    a, wa = np.array([1.0, 2.0, 5.0]), np.array([2.0, 1.0, 3.0])
    b = np.array([1.5, 4.0])
    assert ks_distance(a, b, weights_a=wa) == pytest.approx(
        ks_distance(np.repeat(a, wa.astype(int)), b))


def test_slope_map_agreement_needs_a_shared_grid():
    with pytest.raises(InvalidParameterError, match="share a grid"):
        compare_slope_maps(np.zeros((3, 3)), np.zeros((3, 4)))
    a = compare_slope_maps(np.arange(9.0).reshape(3, 3), np.arange(9.0).reshape(3, 3) + 1)
    assert a.bias_deg == -1.0 and a.max_abs_deg == 1.0 and a.correlation == pytest.approx(1.0)


def test_another_place_is_compared_by_shape_and_its_amplitude_shown():
    """The same kind of terrain at 2.3 times the relief (a rougher place): the plain KS
    distance is large, the KS distance of slopes over their median is small, and the
    amplitude ratio reads the relief's factor (slopes of a few degrees scale with it)."""
    a = fractional_brownian_surface(256, 0.8, resolution=2.0, rms=2.0, seed=1)
    rough = a.replace(heights=a.heights * 2.3)
    c = compare_dems(rough, a, shape_only=True)
    assert c.shape_only and c.ks_distance > 0.5
    assert c.shape_ks_distance < 0.05
    assert c.amplitude_ratio == pytest.approx(2.3, rel=0.1)
    # smooth plains beside rough ground: a wider distribution, whatever its amplitude (a
    # random walk's slopes have the same form as any Gaussian surface's: its Hurst exponent,
    # compared beside the shape, tells it apart)
    mixed = a.replace(heights=a.heights * np.where(np.arange(256) < 128, 0.2, 1.0)[None, :])
    assert compare_dems(mixed, a, shape_only=True).shape_ks_distance > 0.1


def test_a_period_2_row_pattern_does_not_move_the_shape_or_the_hurst_exponent():
    """Rows alternately raised and lowered by 0.6 m, as in the shared SfS DEM: Horn slopes
    (differences over two pixels) and the even-lag Hurst fit do not see it."""
    a = fractional_brownian_surface(256, 0.8, resolution=1.0, rms=3.0, seed=1)
    b = fractional_brownian_surface(256, 0.8, resolution=1.0, rms=3.0, seed=2)
    striped = b.replace(heights=b.heights + 0.6 * (-1.0) ** np.arange(256)[:, None])
    clean = compare_dems(a, b, shape_only=True)
    dirty = compare_dems(a, striped, shape_only=True)
    assert dirty.shape_ks_distance == pytest.approx(clean.shape_ks_distance, abs=1e-6)
    assert dirty.reference_hurst == pytest.approx(clean.reference_hurst, abs=1e-6)
