"""`make demo`'s campaign (examples/demo.py), run in its reduced --quick form.

What a new user would check: one command writes everything under one folder, the report
opens with every figure in it and links that lead to real files, nothing is left
half-written, and a second run reuses what is finished.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote

import pytest

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "examples" / "demo.py"

# The whole campaign runs once for this module (about 3 minutes on 2 cores).
pytestmark = pytest.mark.slow


def run_demo(out: Path, env=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(DEMO), "--quick", "--out", str(out)],
                          cwd=REPO, env={**os.environ, **(env or {})}, capture_output=True,
                          text=True, timeout=900)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    root = tmp_path_factory.mktemp("demo")
    out = root / "out"
    first = run_demo(out)
    assert first.returncode == 0, first.stdout + first.stderr
    return root, out, first


def test_demo_writes_one_folder_and_a_report_with_every_figure(demo):
    root, out, first = demo
    assert [p.name for p in root.iterdir()] == ["out"]  # nothing beside the output folder
    report = out / "evaluation" / "report.html"
    assert f"open {report}" in first.stdout  # it says where the report is
    text = report.read_text(encoding="utf-8")
    doc = json.loads(report.with_suffix(".json").read_text(encoding="utf-8"))
    ids = [s["id"] for s in doc["sections"]]
    assert ids == ["campaign", "tracking-lunar descent", "consistency-lunar descent",
                   "tracking-asteroid approach", "consistency-asteroid approach",
                   "dem-lunar layers", "realism-lunar", "sources-lunar", "site", "asteroid",
                   "closed-loop"]
    # every figure is embedded, and none is empty
    images = re.findall(r'<img alt="[^"]*" src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert len(images) == len(doc["figures"]) >= 15
    assert all(len(b) > 1000 for b in images)
    for needed in ("tracks", "tracking_error", "slope_distributions", "spectra", "slope_area"):
        assert any(f["id"].endswith(needed) for f in doc["figures"]), needed
    # the report links every product, and every link leads somewhere
    hrefs = re.findall(r'<a href="([^"]+)"', text)
    assert len(hrefs) >= 12
    for href in hrefs:
        assert (report.parent / unquote(href)).exists(), href
    # tracking was scored against truth for both runs; the truth itself closes exactly
    for name in ("lunar", "asteroid"):
        summary = json.loads((out / "evaluation" / f"{name}_tracks" / "tracking.json")
                             .read_text())
        assert summary["errors"]["median_px"] is not None
    facts = json.loads((out / ".evaluation.done.json").read_text())
    assert facts["tracking_lunar"]["truth_round_trip_px"] < 0.01
    assert facts["tracking_asteroid"]["truth_round_trip_px"] < 0.01
    # frame-to-frame consistency and the tracker's own share were measured for both runs
    for name in ("lunar", "asteroid"):
        cons = json.loads((out / "evaluation" / f"{name}_consistency" / "consistency.json")
                          .read_text())
        assert len(cons["frames"]) == len(json.loads(
            (out / name / "run" / "run" / "truth.json").read_text())) - 1
        assert facts[f"tracking_{name}"]["ideal_one_step_median_px"] is not None
    assert doc["verdict"] in ("pass", "fail", "incomplete")


def test_the_base_and_every_layer_open_at_the_south_pole(demo):
    """GDAL places every DEM the campaign makes: the base's centre is the pole."""
    import rasterio
    from rasterio.warp import transform

    _, out, _ = demo
    base = out / "lunar" / "base" / "base.tif"
    layers = sorted((out / "lunar" / "stack" / "stack").rglob("*.tif"))
    assert len(layers) >= 10
    for path in [base, *layers]:
        with rasterio.open(path) as ds:
            assert ds.crs is not None and ds.crs.is_projected, path
    with rasterio.open(base) as ds:
        x, y = ds.transform * (ds.width / 2, ds.height / 2)
        geographic = rasterio.crs.CRS.from_user_input(
            json.dumps(ds.crs.to_dict(projjson=True)["base_crs"]))
        _, (lat,) = transform(ds.crs, geographic, [x], [y])
    assert lat == pytest.approx(-90.0, abs=1e-6)


def test_demo_leaves_no_partial_files_and_times_every_stage(demo):
    _, out, _ = demo
    leftovers = [p for p in out.rglob("*") if p.name.endswith(".partial")]
    assert leftovers == []
    timings = json.loads((out / "demo.json").read_text())["stages"]
    assert set(timings) == {"lunar_base", "lunar_stack", "lunar_run", "lunar_closed_loop",
                            "asteroid_body", "asteroid_run", "evaluation"}
    assert all(t["seconds"] > 0 for t in timings.values())
    assert timings["lunar_run"]["frames"] == 16 and timings["asteroid_run"]["frames"] == 6


def test_real_data_comparisons_are_in_the_report_where_the_data_is(demo, shared_file):
    shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif")
    shared_file("asteroids", "eros_gaskell_q64.obj")
    _, out, _ = demo
    doc = json.loads((out / "evaluation" / "report.json").read_text())
    names = [c["name"] for c in doc["checks"]]
    notes = [n for s in doc["sections"] for n in s["notes"]]
    assert any("LROC NAC SFS" in n and n.startswith("KS distance") for n in names)
    # the quick base (257 km) holds too few 7.6 km pixels for a fair comparison: it says so
    assert any("LOLA LDEM_4" in n for n in names + notes)
    assert any("433 Eros" in n and n.startswith("KS distance") for n in names)


def test_a_second_run_reuses_finished_stages_and_absent_data_is_said(demo, tmp_path):
    _, out, _ = demo
    report = out / "evaluation" / "report.html"
    before = report.stat().st_mtime_ns
    again = run_demo(out)
    assert again.returncode == 0, again.stderr
    assert "lunar 1/3" not in again.stdout and "evaluation:" not in again.stdout
    assert report.stat().st_mtime_ns == before
    # without the real data only the evaluation is redone (if the first run had it), and the
    # report says what is missing
    had_data = any(json.loads(report.with_suffix(".json").read_text())["inputs"]["real_data"]
                   .values())
    missing = run_demo(out, env={"CRATERSCAPE_SHARED_DATA": str(tmp_path / "nowhere")})
    assert missing.returncode == 0, missing.stderr
    assert "lunar 1/3" not in missing.stdout
    assert ("evaluation:" in missing.stdout) == had_data
    doc = json.loads(report.with_suffix(".json").read_text())
    notes = [n for s in doc["sections"] for n in s["notes"]]
    assert any("not compared with LOLA" in n for n in notes)
    assert any("not compared with real Eros" in n for n in notes)


def test_demo_base_matches_lolas_south_pole_slopes(tmp_path, shared_file):
    """Stage 1's base (complex craters to 150 km) against LDEM_4 at its 7.58 km pixels."""
    from evaluation.campaign import load_campaign
    from evaluation.campaign_report import polar_ldem
    from evaluation.compare import compare_dems
    from terrain.io import read_dem
    from terrain.stages.runner import run

    ldem = shared_file("lunar", "LDEM_4.LBL")
    campaign = load_campaign(DEMO.with_suffix(".toml"))
    base = tmp_path / "base.tif"
    run(campaign.synth, None, base)
    reference = read_dem(polar_ldem(ldem, tmp_path / "ldem.tif"))
    # different places, compared as slope distributions: the base's CRS is its own
    comparison = compare_dems(read_dem(base).replace(crs=None), reference)
    assert comparison.ks_distance <= 0.10
