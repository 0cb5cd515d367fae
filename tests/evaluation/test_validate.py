"""Validation against published lunar statistics: real DEMs pass, plainly non-lunar ones fail.

Every real lunar DEM of the shared data must pass for its terrain type; three surfaces no
planetary scientist would take for the Moon must fail, each on the check that says why:
pure fBm with H = 0.5 (a random walk: the Hurst check), the SfS DEM interpolated from 8x
coarser pixels (no roughness below 16 px: the smoothness check), and a surface saturated by
fresh craters, walls everywhere (slopes beyond the angle of repose).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evaluation import lunar_stats as ls
from evaluation.counterexamples import fresh_crater_field, smoothed_8x
from evaluation.spectrum import fractional_brownian_surface
from evaluation.validate import (
    _abs_diffs,
    _median_in_place,
    compare_reference,
    crater_density,
    hurst_estimate,
    measured_depths,
    period2_ratio,
    slope_curve,
    validate_dem,
    validate_stack,
)
from evaluation.validate_report import load_input, validation_report
from terrain.core.tile import DEMTile
from terrain.craters.crater import CraterShape, profile
from tests.cli_helpers import one_line_error, run

REAL = {  # file -> terrain type
    "southpole_85S_nac_asp_sfs_dem_1p08m.tif": "south-polar",
    "southpole_85S_nac_asp_stereo_dem_1p08m.tif": "south-polar",
    "LDEM_4.LBL": "south-polar",
    "aristarchus_IMP_quickmap_hsr_4p76m.tif": "maria",
    "aristarchus_CP_quickmap_hsr_26p5m.tif": "highlands",
}


# ----------------------------------------------------------------------- real DEMs pass


@pytest.mark.parametrize("name", sorted(REAL))
def test_every_real_lunar_dem_passes_for_its_terrain(shared_file, name):
    label, tile, _, _ = load_input(shared_file("lunar", name))
    v = validate_dem(tile, REAL[name], label=label)
    assert v.verdict == "pass", [(r.name, r.meaning) for r in v.failures()]
    applied = [r for r in v.results if r.status != "not applicable"]
    assert len(applied) >= 4  # slope curve, Hurst, smoothness, steep share
    # what the input cannot answer is said, not failed
    na = {r.name: r.meaning for r in v.results if r.status == "not applicable"}
    assert "crater catalogue" in na["crater N(>=D) vs equilibrium"]


def test_two_real_dems_of_the_same_ground_agree_within_the_thresholds(shared_file):
    """The calibration: SfS and stereo DEMs of Malapert, and halves of the SfS DEM."""
    _, sfs, _, _ = load_input(shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif"))
    _, st, _, _ = load_input(shared_file("lunar", "southpole_85S_nac_asp_stereo_dem_1p08m.tif"))
    v = validate_dem(sfs, "south-polar", label="sfs")
    compare_reference(v, sfs, st, "stereo")
    side = {r.name.split(" vs")[0]: r for r in v.results if r.group.startswith("side")}
    assert side["KS distance of slopes"].status == "pass"
    assert 0.2 < side["KS distance of slopes"].value <= ls.KS_BETWEEN_REAL_DEMS.threshold
    assert side["Hurst difference"].value <= ls.HURST_TOLERANCE.threshold
    half = sfs.heights.shape[1] // 2
    left = hurst_estimate(DEMTile.from_array(sfs.heights[:, :half], resolution=sfs.resolution))
    right = hurst_estimate(DEMTile.from_array(sfs.heights[:, half:], resolution=sfs.resolution))
    assert abs(left.hurst - right.hurst) <= ls.HURST_TOLERANCE.threshold


def test_the_sfs_period_2_pattern_does_not_fool_the_hurst_estimate(shared_file):
    """The SfS DEM alternates rows: a 1-16 px RMS fit gives H 0.27; ours stays near 0.8."""
    _, sfs, _, _ = load_input(shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif"))
    assert period2_ratio(sfs) > 2.0
    est = hurst_estimate(sfs)
    assert 0.7 <= est.hurst <= 0.95 and est.r_squared > 0.9
    assert est.band_m[0] == pytest.approx(2 * sfs.resolution)
    assert slope_curve(sfs).baseline_m[0] == pytest.approx(2 * sfs.resolution)


# ------------------------------------------------------------------- estimators, alone


def test_hurst_is_robust_to_period_2_rows_and_to_striping():
    clean = fractional_brownian_surface(256, 0.85, resolution=1.0, rms=5.0, seed=3)
    est0 = hurst_estimate(clean)
    h0 = est0.hurst
    assert abs(h0 - 0.85) < 0.08
    z = clean.heights
    rows = z + 0.5 * np.where(np.arange(256) % 2, 1.0, -1.0)[:, None]  # alternate rows
    assert abs(hurst_estimate(DEMTile.from_array(rows)).hurst - h0) < 0.03
    offsets = np.random.default_rng(7).normal(0.0, 1.0, 256)[None, :]  # one per column
    weak = hurst_estimate(DEMTile.from_array(z + 0.3 * offsets))
    assert abs(weak.hurst - h0) < 0.1
    strong = hurst_estimate(DEMTile.from_array(z + 1.5 * offsets))
    # striping along x: the y axis, which column offsets cannot touch, is used and said
    assert strong.hurst == pytest.approx(est0.per_axis[1], abs=0.01)
    assert "striping" in strong.note and strong.uncertainty > 0.2


def test_median_slope_of_a_known_plane_at_every_baseline():
    """A plane rising tan(10 deg) along both axes: 10 degrees at every baseline, 2-m pixels."""
    g = np.tan(np.radians(10.0)) * 2.0 * np.arange(64.0)
    curve = slope_curve(DEMTile.from_array(np.add.outer(g, g), resolution=2.0))
    assert np.allclose(curve.median_deg, 10.0)
    assert curve.baseline_m.tolist() == [2.0, 4.0, 8.0, 16.0, 32.0]


@given(st.lists(st.sampled_from([0.0, -0.0, 0.5, 1.0, 3.0, 1e-300, 1e308]) | st.floats(
    allow_nan=False, allow_infinity=False), min_size=1, max_size=64))
def test_the_one_rank_median_is_numpys_median_bit_for_bit(values):
    """Even and odd counts, ties, signed zeros, sums that overflow: np.median's very bits."""
    v = np.array(values, dtype=np.float64)
    with np.errstate(over="ignore"):
        want = np.float64(np.median(v))
        got = np.float64(_median_in_place(v.copy()))
    assert got.tobytes() == want.tobytes()


@pytest.mark.parametrize("lag", [1, 2, 5, 9, 40])
def test_the_compiled_differences_are_numpys_bit_for_bit(lag):
    """Unknown and infinite heights, signed zeros, overflowing differences, lags past the edge."""
    rng = np.random.default_rng(lag)
    z = rng.normal(size=(11, 9)) * 10.0 ** rng.integers(-5, 309, size=(11, 9))
    z[rng.random(z.shape) < 0.2] = np.nan
    z[rng.random(z.shape) < 0.05] = np.inf
    z[rng.random(z.shape) < 0.1] = -0.0
    with np.errstate(all="ignore"):
        dx, dy = (z[:, lag:] - z[:, :-lag]).ravel(), (z[lag:] - z[:-lag]).ravel()
        d = np.concatenate([dx, dy])
    assert _abs_diffs(z, lag, (1, 0)).tobytes() == np.abs(d[np.isfinite(d)]).tobytes()
    assert _abs_diffs(z, lag, (0,)).tobytes() == np.abs(dy[np.isfinite(dy)]).tobytes()


# ----------------------------------------------------------- plainly not lunar: fails


def test_fbm_with_hurst_one_half_fails_on_the_hurst_check():
    tile = fractional_brownian_surface(256, 0.5, resolution=1.0, rms=3.0, seed=1)
    v = validate_dem(tile, "south-polar", label="fBm H 0.5")
    assert v.verdict == "fail"
    hurst = [r for r in v.failures() if "Hurst" in r.name]
    assert hurst and "random walk" in hurst[0].meaning
    assert abs(hurst[0].value - 0.45) < 0.1  # |0.5 - 0.95|


def test_a_smoothed_real_dem_fails_on_fine_scale_roughness(shared_file):
    _, sfs, _, _ = load_input(shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif"))
    v = validate_dem(smoothed_8x(sfs), "south-polar", label="SfS smoothed 8x")
    assert v.verdict == "fail"
    fails = [r for r in v.failures() if "fine-scale roughness" in r.name]
    assert fails and "smoothed" in fails[0].meaning
    assert fails[0].value > 2 * ls.SMOOTHNESS.value + 1  # far beyond any self-affine H


def test_fresh_crater_walls_everywhere_fail_on_the_angle_of_repose():
    tile = fresh_crater_field()
    v = validate_dem(tile, "highlands", label="fresh craters everywhere")
    assert v.verdict == "fail"
    steep = [r for r in v.failures() if "steeper than 35" in r.name]
    assert steep and steep[0].value > 2 * ls.STEEP_SLOPE.threshold
    assert "angle of repose" in steep[0].meaning


# ------------------------------------------------------------------ stacks and reports


def test_a_layer_stack_is_judged_layer_by_layer():
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack

    base = synthesize_tile(65, resolution=8.0, relief=30.0, seed=3).tile
    stack = build_stack(base, (256.0, 256.0), levels=1, layer_size=65, seed=4)
    v = validate_stack(stack, "highlands", label="stack")
    names = [r.name for r in v.results]
    assert sum(n.startswith("layer ") and "Hurst" in n for n in names) == 2
    assert len(v.curves) == 2 and len(v.distributions) == 2
    na = {r.name: r.meaning for r in v.results if r.status == "not applicable"}
    assert na["crater N(>=D) vs equilibrium"] == "the stack's crater catalogue is empty"
    assert na["rock abundance (area under rocks >= 1 m)"] == "the stack has no rocks"


def test_depth_of_a_fresh_crater_is_measured_from_the_dem():
    """A fresh 40 m crater on flat ground: rim-to-floor depth as Melosh's H0 + Hr0 says."""
    from types import SimpleNamespace

    from terrain.craters.crater import fresh_depth

    yy, xx = np.mgrid[0:96, 0:96] + 0.5
    x = 2.0 * np.hypot(xx - 48.0, yy - 48.0) / 40.0 - 1.0
    z = np.where(x <= 1.0, profile(np.minimum(x, 1.0), CraterShape.from_state(40.0)), 0.0)
    tile = DEMTile.from_array(z, resolution=1.0)  # y runs down from 96 m at the top
    cat = SimpleNamespace(x_m=np.array([48.0]), y_m=np.array([48.0]),
                          diameter_m=np.array([40.0]))
    d, h = measured_depths(tile, cat, 10.0, 100.0)
    assert d.tolist() == [40.0]
    assert h[0] == pytest.approx(float(fresh_depth(40.0)), rel=0.1)
    assert crater_density(cat, (0.0, 0.0, 96.0, 96.0), [10.0, 50.0]).tolist() == \
        [1 / 96.0**2, 0.0]


def test_report_lists_every_check_with_value_threshold_and_source():
    tile = fractional_brownian_surface(128, 0.5, resolution=1.0, rms=3.0, seed=1)
    rep = validation_report(validate_dem(tile, "maria", label="fbm"))
    assert rep.verdict == "fail"
    doc = rep.as_dict()
    assert {f["id"] for f in doc["figures"]} >= {"slope_baseline", "structure",
                                                 "distributions"}
    for c in doc["checks"]:
        assert "[source:" in c["note"]
    na = [c for c in doc["checks"] if not c["applicable"]]
    assert na and all(c["passed"] is None for c in na)


def test_cli_writes_html_and_json_and_refuses_a_bad_terrain(tmp_path):
    from terrain.io import write_dem

    dem = tmp_path / "fbm.tif"
    write_dem(fractional_brownian_surface(128, 0.5, resolution=1.0, rms=3.0, seed=1), dem)
    out = tmp_path / "v.html"
    r = run("evaluation", "validate", dem, "--terrain", "highlands", "-o", out)
    assert r.exit_code == 0, r.output
    assert "verdict fail" in r.output and "FAIL" in r.output and "Hurst" in r.output
    doc = json.loads(out.with_suffix(".json").read_text())
    assert doc["verdict"] == "fail"
    assert "<img" in out.read_text() and "Rosenburg" in out.read_text()
    one_line_error(run("evaluation", "validate", dem, "--terrain", "mars", "-o", out),
                   "mars")


def test_campaign_checks_are_grouped_and_tracker_drift_never_decides_the_verdict():
    from evaluation.report import Check, Report, Section
    from evaluation.validate_report import regroup_campaign_checks

    tracking = Section("tracking", "t", checks=[
        Check("tracking lunar descent", "median tracking error", 3.0, 0.5, "<="),
        Check("tracking lunar descent", "outlier fraction (> 2 px)", 0.4, 0.05, "<=")])
    consistency = Section("consistency", "c", checks=[
        Check("consistency lunar descent", "largest per-frame residual over the median", 1.2,
              1.5, "<=")])
    dem = Section("dem", "d", checks=[Check("dem lunar layers", "KS distance", 0.3, 0.1, "<=")])
    facts = {"tracking_lunar": dict(one_step_median_px=0.2, truth_round_trip_px=0.001)}
    sections = [tracking, consistency, dem]
    regroup_campaign_checks(sections, facts)
    rep = Report("r", sections, {})
    assert rep.verdict == "pass"  # drift, outliers and a side-by-side KS are information
    by_name = {c.name: c for c in rep.checks}
    assert by_name["median tracking error"].informational
    assert by_name["median tracking error"].section.startswith("tracker performance")
    assert by_name["one-step tracking error (median)"].section.startswith("renderer")
    assert by_name["truth round trip through consecutive frames (median)"].passed
    facts["tracking_lunar"]["one_step_median_px"] = 0.9  # a renderer that jitters fails
    sections = [Section("tracking", "t", checks=[
        Check("tracking lunar descent", "median tracking error", 3.0, 0.5, "<=")])]
    regroup_campaign_checks(sections, facts)
    assert Report("r", sections, {}).verdict == "fail"


@pytest.mark.parametrize("index, verdict", [(-2.65, "pass"), (-3.1, "pass"), (-1.6, "fail"),
                                            (-4.5, "fail")])
def test_boulder_sfd_index_against_the_imaged_asteroids(index, verdict):
    """Boulders drawn from N(>=D) ~ D^index above 2 m: Ryugu's and Itokawa's indices pass,
    a crater-like -1.6 and a far steeper -4.5 fail."""
    from evaluation.validate import boulder_check, boulder_index

    u = 1.0 - np.random.default_rng(11).random(3000)
    d = 2.0 * u ** (1.0 / index)
    b, se, n = boulder_index(d, 2.0)
    assert n == 3000 and abs(b - index) < 4 * se
    r = boulder_check(d, dmin=2.0)
    assert r.status == verdict
    if verdict == "fail":
        assert ("too many large" in r.meaning) == (index > -2.9)
    assert boulder_check(d[:10]).status == "not applicable"


@pytest.mark.slow
def test_real_bodies_agree_at_the_same_facet_count_and_a_smooth_ellipsoid_does_not(shared_file):
    """Itokawa against Eros, both at Itokawa's 3,000-odd facets of a coarsened copy, passes;
    Itokawa's vertices pushed onto a smooth ellipsoid fail (no relief, hardly any slope)."""
    from evaluation.meshslope import Spin, load_body
    from evaluation.validate import body_slope_check, facet_matched_slopes

    eros = load_body(shared_file("asteroids", "eros_gaskell_q64.obj"), units="km")
    itokawa = load_body(shared_file("asteroids", "itokawa_gaskell_q32.obj"), units="km")
    spin = Spin(12.13, (0.0, 0.0, 1.0))
    body, ref = facet_matched_slopes((itokawa.vertices, itokawa.faces),
                                     (eros.vertices, eros.faces), density=1900.0, spin=spin,
                                     max_faces=3072, labels=("Itokawa", "Eros"))
    assert abs(body.info["faces"] - ref.info["faces"]) < 0.3 * ref.info["faces"]
    assert body_slope_check(body, ref).status == "pass"
    v = itokawa.vertices
    u = v / np.linalg.norm(v, axis=1)[:, None]
    axes = np.array([270.0, 150.0, 110.0])  # metres, about Itokawa's semi-axes
    smooth = u / np.sqrt(((u / axes) ** 2).sum(axis=1))[:, None]
    body, ref = facet_matched_slopes((smooth, itokawa.faces), (eros.vertices, eros.faces),
                                     density=1900.0, spin=spin, max_faces=3072,
                                     labels=("ellipsoid", "Eros"))
    r = body_slope_check(body, ref)
    assert r.status == "fail" and "flatter" in r.meaning


@pytest.mark.parametrize("model, verdict", [
    ("nominal", "pass"), ("high", "pass"), ("low", "pass"), ("none", "fail"), ("dense", "fail")])
def test_metre_rocks_are_judged_against_the_viper_specification(model, verdict):
    """Rocks drawn from the VIPER specification's own models over 1 km^2 pass; a field with no
    metre-scale rock, or ten times the high model, fails with the reason."""
    from evaluation.hazards import rock_sfd
    from evaluation.lunar_stats import VIPER_ROCK_MODELS
    from evaluation.validate import _rock_density_check
    from terrain.surface.rocks import RockModel, rock_catalog

    a, b = {"none": (1e-7, -2.5), "dense": (2e-2, -2.661)}.get(model) or VIPER_ROCK_MODELS[model]
    rocks = RockModel.from_spec(f"power:a={a},b={b},dmin=1,dmax=10").generate(
        3, (0.0, 0.0, 1000.0, 1000.0), margin=False)
    cat = rock_catalog(rocks, np.zeros(len(rocks)), np.zeros(len(rocks), int))
    result = _rock_density_check(rock_sfd(cat, (0.0, 0.0, 1000.0, 1000.0), 1.0), 15)
    assert result.status == verdict, result
    if verdict == "fail":
        assert "model" in result.meaning


def test_a_rock_count_over_too_small_an_area_is_not_judged():
    """0.001 km^2 holds 0.1 rocks of 1 m at the low model: finding none says nothing."""
    from evaluation.validate import _rock_density_check

    sfd = {"number_per_m2": np.zeros(4), "area_m2": 1000.0}
    result = _rock_density_check(sfd, 15)
    assert result.status == "not applicable" and "too small" in result.meaning


# ------------------------------------------------------- a terrain built for its preset


def _scaled_fbm(size, hurst, resolution, baseline_m, target_deg, *, median=True, seed=5):
    """An fBm surface (evaluation.spectrum, independent of terrain's generators) scaled so
    its median (or plane-removed RMS) slope at ``baseline_m`` is ``target_deg``."""
    from evaluation.validate import baseline_slopes

    tile = fractional_brownian_surface(size, hurst, resolution=resolution, seed=seed)
    lag = int(round(baseline_m / resolution))
    med, rms = baseline_slopes(tile, lag)
    now = np.tan(np.radians(med if median else rms))
    z = np.asarray(tile.heights, dtype=np.float64)
    return DEMTile.from_array(z * np.tan(np.radians(target_deg)) / now, resolution=resolution)


def test_the_law_check_passes_a_surface_of_the_law_and_fails_a_random_walk():
    """fBm of the maria law's H (0.76), scaled to the law at 16 m, keeps within a degree of
    it to 1 km; a random walk (H 0.5) scaled to the south-polar law at 16 m is far too
    smooth at a kilometre. (Spectral synthesis realises H near 1 with a bias of ~0.05 over
    these lags, so the highland H 0.95 is not used to make the passing surface.)"""
    from types import SimpleNamespace

    from evaluation.validate import _law_slope_check, stack_slope_table

    results = {}
    for name, h in (("maria", 0.76), ("south-polar", 0.5)):
        law = ls.terrain_law(name)
        tile = _scaled_fbm(2048, h, 4.0, 16.0, float(law.median_slope_deg(16.0)))
        table = stack_slope_table(SimpleNamespace(tiles=[tile]), (17.0, 57.0, 225.0, 1000.0))
        assert [round(r["baseline_m"]) for r in table] == [16, 56, 224, 1000]
        results[name] = _law_slope_check(table, law)
    assert results["maria"].status == "pass", results["maria"]
    assert results["south-polar"].status == "fail"
    assert "smoother" in results["south-polar"].meaning


def test_centimetre_regolith_roughness_is_judged_with_the_tilt_removed():
    """Regolith at 15 deg RMS over 3 cm on a 10 deg tilted site passes; the same surface
    smoothed over 8 px (a DEM with no centimetre roughness) fails as too smooth."""
    from types import SimpleNamespace

    from scipy.ndimage import uniform_filter

    from evaluation.validate import _regolith_check, stack_slope_table

    rough = _scaled_fbm(256, 0.6, 0.03, 0.03, 15.0, median=False)
    yy = np.mgrid[0:256, 0:256][0] * 0.03
    z = np.asarray(rough.heights, dtype=np.float64) + np.tan(np.radians(10.0)) * yy
    tilted = DEMTile.from_array(z, resolution=0.03)
    smooth = DEMTile.from_array(uniform_filter(z, 8), resolution=0.03)
    verdicts = {}
    for name, tile in (("rough", tilted), ("smooth", smooth)):
        table = stack_slope_table(SimpleNamespace(tiles=[tile]), (0.03, 0.3))
        verdicts[name] = _regolith_check(table)
    assert verdicts["rough"].status == "pass", verdicts["rough"]
    assert abs(verdicts["rough"].value - 15.0) < 0.5
    assert verdicts["smooth"].status == "fail" and "smoother" in verdicts["smooth"].meaning


@pytest.mark.parametrize("age_gyr, verdict", [(0.05, "pass"), (2.0, "fail")])
def test_only_young_crater_walls_may_stand_beyond_repose(age_gyr, verdict):
    """A fresh-shaped 60 m crater on a plane: excused when the catalogue says it is 50 Myr
    old, a failure of mass wasting when it claims 2 Gyr."""
    from types import SimpleNamespace

    from evaluation.validate import _steep_old_check

    n, res, d = 128, 1.0, 60.0
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) * res
    x = 2.0 * np.hypot(xx - 64.0, yy - 64.0) / d - 1.0
    z = np.where(x <= 1.0, profile(np.minimum(x, 1.0), CraterShape.from_state(d)), 0.0)
    tile = DEMTile.from_array(z, resolution=res)
    cat = SimpleNamespace(x_m=np.array([64.0]), y_m=np.array([n * res - 64.0]),
                          diameter_m=np.array([d]), age_gyr=np.array([age_gyr]))
    r = _steep_old_check(tile, cat, "")
    assert r.status == verdict, r


@pytest.mark.parametrize("scale, verdict", [(1.0, "pass"), (3.0, "fail")])
def test_rock_sfd_is_judged_against_the_presets_viper_model(scale, verdict):
    """Rocks drawn from the south-polar preset's VIPER nominal law over a decade of size
    match it within 15 % (plus counting noise); three times as many rocks fail."""
    from types import SimpleNamespace

    from affine import Affine

    from evaluation.validate import rock_sfd_check
    from terrain.surface.rocks import RockModel, rock_catalog

    a, b = ls.VIPER_ROCK_MODELS["nominal"]
    extent = (0.0, 0.0, 200.0, 200.0)
    rocks = RockModel.from_spec(f"power:a={a * scale},b={b},dmin=0.1,dmax=10").generate(
        7, extent, margin=False)
    cat = rock_catalog(rocks, np.zeros(len(rocks)), np.zeros(len(rocks), int))
    # one 5 cm layer (what the count reads of a tile): complete from 2 px, 0.1 m
    tile = SimpleNamespace(shape=(4000, 4000), resolution=0.05,
                           transform=Affine(0.05, 0.0, 0.0, 0.0, -0.05, 200.0))
    r, figures = rock_sfd_check(SimpleNamespace(tiles=[tile], rocks=cat), "south-polar")
    assert r.status == verdict, r
    assert figures["rows"][0]["diameter_m"] == pytest.approx(0.1)
