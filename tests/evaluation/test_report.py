"""Validation reports: self-contained HTML, a JSON of every figure, pass/fail thresholds."""

import json
import re

import numpy as np
import pytest

from evaluation.meshslope import Spin, load_body, mesh_slopes
from evaluation.report import (
    DEFAULT_THRESHOLDS,
    Check,
    Report,
    asteroid_section,
    dem_section,
    jsonable,
    load_thresholds,
    render_html,
    thresholds_toml,
    tracking_section,
    write_report,
)
from evaluation.slope import slope_distribution
from evaluation.spectrum import fit_hurst, fractional_brownian_surface, radial_spectrum
from evaluation.tracking import score, track
from render.rundir import RunReader
from terrain.core.errors import InvalidParameterError


def assert_self_contained(text):
    """No scripts, style sheets, fonts or images fetched from anywhere."""
    assert "<script" not in text.lower()
    assert "<link" not in text.lower() and "@import" not in text
    assert not re.search(r"""(src|href)\s*=\s*["'](?!data:|#)""", text)
    assert "url(" not in text
    assert text.count("data:image/png;base64,") >= 1


def eros_like_body(tmp_path):
    """A synthetic Eros-like body from the asteroid package: an elongated Perlin base with the
    paper's crater population (N_cum = 0.5 D^-2), 14 x 6 x 6 km, saved as a native model."""
    from asteroid.body import save_native
    from asteroid.build import build
    from asteroid.recipe import Recipe

    recipe = Recipe.from_dict(dict(magnitude=40, radius=6000.0, seed=3, base="perlin",
                                   stretch=[2.6, 1.0, 0.95], perlin=dict(amplitude=0.12),
                                   craters=dict(c=0.5, k=-2.0)))
    result = build(recipe)
    path = tmp_path / "eros_like.npz"
    save_native(path, result.body, result.tables())
    return path


@pytest.mark.slow
def test_report_with_tracking_and_the_real_eros_beside_a_synthetic_one(planar_run, tmp_path,
                                                                       shared_file):
    eros_path = shared_file("asteroids", "eros_gaskell_q64.obj")
    spin = Spin(5.27)
    eros = load_body(eros_path, units="km")
    real = mesh_slopes(eros.vertices, eros.faces, label="Eros (Gaskell)", spin=spin,
                       coarse_faces=2000)
    like = load_body(eros_like_body(tmp_path))
    synthetic = mesh_slopes(like.vertices, like.faces, label="Eros-like", spin=spin,
                            coarse_faces=2000)
    reader = RunReader(planar_run)
    scored = score(track(reader), reader)
    limits = load_thresholds()
    sections = [tracking_section(scored, reader.image(len(reader) - 1), limits),
                asteroid_section([synthetic], real, limits)]
    report = Report("Planar descent and Eros", sections, limits, {"run_dir": str(planar_run)})
    html_path, json_path = write_report(report, tmp_path / "report.html")
    text = html_path.read_text(encoding="utf-8")
    assert_self_contained(text)
    doc = json.loads(json_path.read_text(encoding="utf-8"))
    assert doc["format"] == "craterscape-evaluation-report"
    ids = {f["id"] for f in doc["figures"]}
    assert {"tracks", "tracking_error", "slope_area", "slope_area_other"} <= ids
    # every figure's plotted numbers are in the JSON
    slope_area = next(f for f in doc["figures"] if f["id"] == "slope_area")
    labels = [h["label"] for h in slope_area["data"]["histograms"]]
    assert labels == ["Eros (Gaskell)", "Eros-like"]
    assert all(h["kind"] == "gravitational" for h in slope_area["data"]["histograms"])
    for h in slope_area["data"]["histograms"]:
        assert sum(h["area_percent"]) == pytest.approx(100.0)
    names = {c["name"]: c for c in doc["checks"]}
    assert names["median tracking error"]["passed"] is True
    ks = next(c for n, c in names.items() if n.startswith("KS distance Eros-like"))
    print(f"Eros-like vs Eros gravitational slopes: KS {ks['value']:.3f}; medians "
          f"{synthetic.summary('gravitational')['p50']:.1f} vs "
          f"{real.summary('gravitational')['p50']:.1f} deg (radial "
          f"{synthetic.summary('radial')['p50']:.1f} vs {real.summary('radial')['p50']:.1f})")
    assert ks["passed"] is True
    assert doc["verdict"] == "pass"
    assert "Eros (Gaskell)" in text and "verdict pass" in text


def test_dem_section_checks_against_a_reference(tmp_path):
    from evaluation.compare import compare_dems

    a = fractional_brownian_surface(128, 0.8, resolution=2.0, rms=5.0, seed=1)
    b = fractional_brownian_surface(128, 0.3, resolution=2.0, rms=5.0, seed=2)
    spectra = [radial_spectrum(a, label="a"), radial_spectrum(b, label="b")]
    section = dem_section([slope_distribution(a, label="a"), slope_distribution(b, label="b")],
                          spectra, [fit_hurst(s) for s in spectra],
                          [compare_dems(a, b, label="a", reference_label="b")])
    report = Report("DEMs", [section], load_thresholds())
    assert report.verdict == "fail"
    failed = [c.name for c in report.checks if c.passed is False]
    assert any(name.startswith("KS distance") for name in failed)
    assert_self_contained(render_html(report))


def test_another_place_is_judged_by_shape_with_its_amplitude_noted():
    """A reference of another place: the shape and the Hurst exponent are checked, the plain
    KS distance and the spectra's ratio (the amplitude) are shown in the table and a note,
    not judged."""
    from evaluation.compare import compare_dems

    a = fractional_brownian_surface(128, 0.8, resolution=2.0, rms=2.0, seed=1)
    b = fractional_brownian_surface(128, 0.8, resolution=2.0, rms=2.0, seed=2)
    rough = a.replace(heights=a.heights * 3.0)
    section = dem_section([slope_distribution(rough, label="a")], (), (),
                          [compare_dems(rough, b, label="a", reference_label="b",
                                        shape_only=True)])
    names = [c.name for c in section.checks]
    assert names == ["KS distance of slopes over their median (shape) a vs b",
                     "Hurst difference a vs b"]
    assert all(c.passed for c in section.checks)
    assert any("another place" in n and "median slope ratio" in n for n in section.notes)
    (table,) = [t for t in section.tables if t[0].startswith("a against b")]
    assert any(row[0] == "median slope ratio (amplitude)" for row in table[2])


def test_missing_evidence_makes_a_report_incomplete_not_passed(run_without_truth):
    reader = RunReader(run_without_truth)
    scored = score(track(reader), reader)
    section = tracking_section(scored, reader.image(0))
    report = Report("no truth", [section], DEFAULT_THRESHOLDS)
    assert report.verdict == "incomplete"
    median = next(c for c in report.checks if c.name == "median tracking error")
    assert median.passed is None and "no truth" in median.note
    assert "no truth.json" in render_html(report)
    assert [f.id for f in section.figures] == ["tracks"]


def test_thresholds_file_overrides_defaults_and_refuses_typos(tmp_path):
    good = tmp_path / "t.toml"
    good.write_text("[tracking]\nmax_median_error_px = 0.25\n[asteroid]\nslope_kind = 'radial'\n")
    t = load_thresholds(good)
    assert t["tracking"]["max_median_error_px"] == 0.25
    assert t["tracking"]["outlier_px"] == DEFAULT_THRESHOLDS["tracking"]["outlier_px"]
    assert t["asteroid"]["slope_kind"] == "radial"
    for text, fragment in [("[tracking]\nmax_median_error = 1.0\n",
                            "[tracking] key 'max_median_error' (did you mean "),
                           ("[slopes]\nx = 1\n", "key 'slopes' (expected one of"),
                           ("[dem]\nmax_ks_distance = 'low'\n", "max_ks_distance must be a number"),
                           ("[dem]\nmax_ks_distance = 1.5\n", "max_ks_distance must be <= 1.0"),
                           ("[asteroid]\nslope_kind = 'normal'\n",
                            "slope_kind 'normal' is not known"),
                           ("[dem\n", "not valid TOML")]:
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(InvalidParameterError, match=re.escape(fragment)):
            load_thresholds(bad)
    # the printed defaults are a valid thresholds file
    (tmp_path / "d.toml").write_text(thresholds_toml())
    assert load_thresholds(tmp_path / "d.toml") == DEFAULT_THRESHOLDS


def test_checks_compare_in_the_stated_direction():
    assert Check("s", "n", 0.4, 0.5, "<=").passed is True
    assert Check("s", "n", 0.6, 0.5, "<=").passed is False
    assert Check("s", "n", 60.0, 50.0, ">=").passed is True
    assert Check("s", "n", None, 50.0, ">=").passed is None
    assert Check("s", "n", float("nan"), 50.0, ">=").passed is None


def test_report_json_has_no_nan(tmp_path):
    section = dem_section([slope_distribution(fractional_brownian_surface(32, 0.7, seed=1))])
    section.data["odd"] = [np.nan, np.inf, 1.0]
    _, json_path = write_report(Report("x", [section], DEFAULT_THRESHOLDS), tmp_path / "r.html")
    doc = json.loads(json_path.read_text())
    assert doc["sections"][0]["data"]["odd"] == [None, None, 1.0]
    with pytest.raises(InvalidParameterError, match=r"\.html"):
        write_report(Report("x", [section], DEFAULT_THRESHOLDS), tmp_path / "r.json")


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("shape", [(), (7,), (5, 4), (3, 2, 6)])
def test_jsonable_float_arrays_match_element_by_element(dtype, shape):
    # every element, on its own: a finite value as the Python float of its dtype, else None
    rng = np.random.default_rng(7)
    a = rng.normal(size=shape).astype(dtype)
    flat = a.reshape(-1)
    flat[::3] = np.nan
    flat[1::5] = np.inf
    flat[2::7] = -np.inf

    def reference(x):
        if isinstance(x, list):
            return [reference(y) for y in x]
        return x if np.isfinite(x) else None

    out = jsonable({"a": a})["a"]
    assert out == reference(a.tolist())
    assert json.dumps(out) == json.dumps(reference(a.tolist()))
    assert "NaN" not in json.dumps(out) and "Infinity" not in json.dumps(out)


def test_figures_written_with_the_tracks_are_the_reports_drawn_once(planar_run, tmp_path,
                                                                    monkeypatch):
    """save_tracks and tracking_section show the same two figures: drawn once, shared, and
    the bytes each would draw alone."""
    import evaluation.figures as figures
    from evaluation.tracking import save_tracks

    reader = RunReader(planar_run)
    scored = score(track(reader), reader)
    last = reader.image(len(reader) - 1)
    alone = {f.id: f.png for f in tracking_section(scored, last).figures}
    drawn: dict = {}
    calls = []
    real_png = figures.png_bytes
    monkeypatch.setattr(figures, "png_bytes", lambda fig: calls.append(1) or real_png(fig))
    save_tracks(scored, reader, tmp_path / "tracks", drawn=drawn)
    shared = {f.id: f.png for f in tracking_section(scored, last, drawn=drawn).figures}
    assert set(alone) == set(shared) == {"tracks", "tracking_error"}
    assert len(calls) == 2  # two figures, each drawn once for the folder and the report
    assert shared == alone
    assert (tmp_path / "tracks" / "tracks.png").read_bytes() == alone["tracks"]
    assert (tmp_path / "tracks" / "tracking_error.png").read_bytes() == alone["tracking_error"]
