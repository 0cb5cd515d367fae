"""`craterscape evaluation` as a user runs it (click's CliRunner): outputs, exit codes, errors."""

import csv
import json

import numpy as np
import pytest
import rasterio
import trimesh

from evaluation.spectrum import fractional_brownian_surface
from terrain.io import read_dem, write_dem
from tests.cli_helpers import one_line_error, run

WKT_ORTHO = ('PROJCS["moon orthographic",GEOGCS["Moon",DATUM["Moon",SPHEROID["Moon",1737400,0]],'
             'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
             'PROJECTION["Orthographic"],PARAMETER["latitude_of_origin",0],'
             'PARAMETER["central_meridian",0],UNIT["metre",1]]')


@pytest.fixture
def dems(tmp_path):
    a = fractional_brownian_surface(96, 0.8, resolution=2.0, rms=4.0, seed=1)
    b = fractional_brownian_surface(48, 0.8, resolution=4.0, rms=4.0, seed=2)
    pa, pb = tmp_path / "fine.tif", tmp_path / "coarse.tif"
    write_dem(a, pa)
    write_dem(b, pb)
    return pa, pb


def test_slopes_writes_georeferenced_slope_maps_and_distributions(dems, tmp_path):
    fine, coarse = dems
    out = tmp_path / "out"
    r = run("evaluation", "slopes", fine, "--reference", coarse, "-o", out)
    assert r.exit_code == 0, r.output
    assert "KS" in r.output
    slope = read_dem(out / "fine_slope.tif")
    with rasterio.open(out / "fine_slope.tif") as src:
        assert src.dtypes[0] == "float32"
        assert src.transform == read_dem(fine).transform
    assert slope.metadata["CRATERSCAPE_QUANTITY"] == "Horn slope (degrees)"
    rows = list(csv.reader((out / "slope_distributions.csv").open()))
    assert rows[0] == ["angle_deg", "fine", "reference coarse"]
    assert float(rows[1][1]) == pytest.approx(100.0)
    summary = list(csv.DictReader((out / "slope_summary.csv").open()))
    assert summary[0]["label"] == "fine" and float(summary[0]["ks_vs_reference"]) >= 0
    doc = json.loads((out / "comparison.json").read_text())
    assert doc["comparisons"][0]["resolution_m"] == 4.0  # matched baseline: the coarser
    assert doc["comparisons"][0]["resampled"] == "DEM"
    for name in ("spectra.csv", "slope_distributions.png", "spectra.png"):
        assert (out / name).stat().st_size > 0


@pytest.mark.slow
def test_slopes_of_a_layer_stack_one_distribution_per_layer(tmp_path):
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(33, resolution=8.0, relief=30.0, seed=3).tile
    folder = write_stack(build_stack(base, (128.0, 128.0), levels=2, layer_size=17, seed=4),
                         tmp_path / "stack")
    r = run("evaluation", "slopes", folder / "manifest.json", "-o", tmp_path / "out",
            "--compute-edges")
    assert r.exit_code == 0, r.output
    header = next(csv.reader((tmp_path / "out" / "slope_distributions.csv").open()))
    assert header == ["angle_deg", "stack_layer_00", "stack_layer_01", "stack_layer_02"]
    assert (tmp_path / "out" / "stack_layer_02_slope.tif").exists()


def test_a_stack_is_compared_with_a_reference_only_where_its_layers_can_be(tmp_path):
    """Layers span kilometres to metres: those too coarse for a small reference are skipped
    with a warning (a DEM given alone is refused instead, with one line)."""
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(129, resolution=8.0, relief=30.0, seed=3).tile
    folder = write_stack(build_stack(base, (512.0, 512.0), levels=2, layer_size=129, seed=4),
                         tmp_path / "stack")
    ref = tmp_path / "ref.tif"  # 64 x 64 at 2 m: 128 m across, like the finest layer
    write_dem(fractional_brownian_surface(64, 0.8, resolution=2.0, rms=2.0, seed=5), ref)
    r = run("evaluation", "slopes", folder, "--reference", ref, "-o", tmp_path / "out")
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "out" / "comparison.json").read_text())
    assert [c["label"] for c in doc["comparisons"]] == ["stack_layer_02"]
    assert "stack_layer_00 not compared with the reference" in r.output
    assert "a comparison needs at least 1000" in r.output
    one_line_error(run("evaluation", "slopes", folder / "layer_00.tif", "--reference", ref,
                       "-o", tmp_path / "out2"), "a comparison needs at least 1000")


def test_slopes_checks_an_independent_slope_band(tmp_path, shared_file):
    path = shared_file("lunar", "aristarchus_IMP_quickmap_hsr_4p76m.tif")
    r = run("evaluation", "slopes", path, "--slope-band", 2, "-o", tmp_path / "out")
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "out" / "comparison.json").read_text())
    agreement = doc["slope_map_agreement"][0]
    assert agreement["median_abs_deg"] < 0.01 and agreement["correlation"] > 0.9999


def test_dems_in_different_crs_are_refused_before_any_output(dems, tmp_path):
    fine, coarse = dems
    other = tmp_path / "ortho.tif"
    write_dem(read_dem(coarse).replace(crs=WKT_ORTHO), other)
    r = run("evaluation", "slopes", fine, "--reference", other, "-o", tmp_path / "out")
    assert r.exit_code == 0, r.output  # a local frame (no CRS) is compared, with a warning
    stereo = tmp_path / "stereo.tif"
    write_dem(read_dem(fine).replace(crs=WKT_ORTHO.replace("Orthographic",
                                                           "Polar_Stereographic")), stereo)
    r = run("evaluation", "slopes", stereo, "--reference", other, "-o", tmp_path / "out2")
    one_line_error(r, "different coordinate reference systems", "reproject")
    assert not (tmp_path / "out2").exists()


def test_slopes_bad_input(dems, tmp_path):
    fine, _ = dems
    one_line_error(run("evaluation", "slopes", tmp_path / "missing.tif", "-o", tmp_path / "o"),
                   "does not exist")
    one_line_error(run("evaluation", "slopes", fine, "--band", 3, "-o", tmp_path / "o"),
                   "band 3")
    one_line_error(run("evaluation", "slopes", fine, "--baseline", -1, "-o", tmp_path / "o"),
                   "--baseline")
    (tmp_path / "file").write_text("x")
    r = run("evaluation", "slopes", fine, "-o", tmp_path / "file")
    assert r.exit_code == 2 and "is a file" in r.output  # click's own usage error


def test_memory_busting_requests_are_refused_before_work(dems, tmp_path):
    fine, _ = dems
    r = run("evaluation", "slopes", fine, "-o", tmp_path / "out",
            env={"CRATERSCAPE_MEMORY_LIMIT": "200K"})
    one_line_error(r, "Horn slope", "memory")
    assert not (tmp_path / "out" / "fine_slope.tif").exists()


@pytest.mark.slow
def test_asteroid_slopes_command(tmp_path):
    s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    body = trimesh.Trimesh(np.asarray(s.vertices) * [3.0, 1.2, 1.0], s.faces)
    body.export(tmp_path / "body.ply")
    r = run("evaluation", "asteroid-slopes", tmp_path / "body.ply", "--units", "km",
            "--period-hours", 5.27, "--coarse-faces", 600, "-o", tmp_path / "out")
    assert r.exit_code == 0, r.output
    assert "gravitational median" in r.output
    out = tmp_path / "out"
    rows = list(csv.DictReader((out / "slope_area_histograms.csv").open()))
    grav = [float(row["area_percent"]) for row in rows if row["kind"] == "gravitational"]
    assert sum(grav) == pytest.approx(100.0, abs=0.01) and len(grav) == 60
    vertices = list(csv.DictReader((out / "body_vertex_slopes.csv").open()))
    assert len(vertices) == len(s.vertices)
    summary = json.loads((out / "asteroid_slopes.json").read_text())
    assert summary["bodies"][0]["info"]["spin_period_h"] == 5.27
    assert summary["bodies"][0]["info"]["equivalent_radius_m"] > 1000.0  # km were read
    assert (out / "slope_area_gravitational.png").exists()


def test_asteroid_slopes_refuses_open_meshes(tmp_path):
    s = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    trimesh.Trimesh(s.vertices, s.faces[:-1], process=False).export(tmp_path / "open.obj")
    one_line_error(run("evaluation", "asteroid-slopes", tmp_path / "open.obj", "-o",
                       tmp_path / "out"), "not a closed surface")
    one_line_error(run("evaluation", "asteroid-slopes", tmp_path / "open.obj", "--density", 1,
                       "--mass", 1, "-o", tmp_path / "out"))


def test_track_command_with_and_without_truth(planar_run, run_without_truth, tmp_path):
    r = run("evaluation", "track", planar_run, "-o", tmp_path / "t")
    assert r.exit_code == 0, r.output
    assert "median error" in r.output and "one-step median" in r.output
    doc = json.loads((tmp_path / "t" / "tracking.json").read_text())
    assert doc["errors"]["median_px"] <= 0.5
    # one step of tracking errs less than a whole track; both are given by track age
    assert doc["errors"]["one_step"]["median_px"] < doc["errors"]["median_px"]
    assert doc["errors"]["one_step_median_px_by_track_age"][0][0] == 1
    rows = list(csv.DictReader((tmp_path / "t" / "tracks.csv").open()))
    assert {"track", "frame", "u_px", "v_px", "true_u_px", "true_v_px", "error_px"} <= set(rows[0])
    assert (tmp_path / "t" / "tracks.png").exists()
    assert (tmp_path / "t" / "tracking_error.png").exists()

    r = run("evaluation", "track", run_without_truth, "-o", tmp_path / "n")
    assert r.exit_code == 0, r.output
    assert "no truth" in r.output
    doc = json.loads((tmp_path / "n" / "tracking.json").read_text())
    assert doc["errors"] is None and doc["notes"]
    assert "error_px" not in next(csv.DictReader((tmp_path / "n" / "tracks.csv").open()))
    one_line_error(run("evaluation", "track", tmp_path / "nowhere", "-o", tmp_path / "x"),
                   "does not exist")
    # the tracker's settings as given, and bad ones refused in one line
    r = run("evaluation", "track", run_without_truth, "-o", tmp_path / "m", "--dark-margin", 5,
            "--dark-level", 4)
    assert r.exit_code == 0, r.output
    settings = json.loads((tmp_path / "m" / "tracking.json").read_text())["tracking"]["settings"]
    assert settings["dark_margin"] == 5 and settings["dark_level"] == 4
    one_line_error(run("evaluation", "track", run_without_truth, "-o", tmp_path / "y",
                       "--dark-margin", -1), "dark_margin")


@pytest.mark.slow
def test_report_command_and_thresholds(planar_run, dems, tmp_path):
    fine, coarse = dems
    thresholds = tmp_path / "t.toml"
    r = run("evaluation", "thresholds")
    assert r.exit_code == 0 and "[tracking]" in r.output
    thresholds.write_text(r.output.replace("max_median_error_px = 0.5",
                                           "max_median_error_px = 0.01"))
    out = tmp_path / "report.html"
    r = run("evaluation", "report", planar_run, "-o", out, "--thresholds", thresholds,
            "--dem", fine, "--reference", coarse)
    assert r.exit_code == 0, r.output
    assert "verdict fail" in r.output and "median tracking error" in r.output
    doc = json.loads(out.with_suffix(".json").read_text())
    assert doc["thresholds"]["tracking"]["max_median_error_px"] == 0.01
    assert {s["id"] for s in doc["sections"]} == {"tracking", "consistency", "dem"}
    assert any(c["name"] == "largest per-frame residual over the median" and c["passed"]
               for c in doc["checks"])
    text = out.read_text()
    assert "data:image/png;base64," in text and "<script" not in text

    # several runs in one report: one tracking section each, told apart by name
    r = run("evaluation", "report", planar_run, planar_run, "-o", tmp_path / "two.html")
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "two.json").read_text())
    name = f"{planar_run.resolve().parent.name}/{planar_run.resolve().name}"  # names clash
    assert [s["id"] for s in doc["sections"]] == [f"tracking-{name}", f"consistency-{name}",
                                                  f"tracking-{name}_2",
                                                  f"consistency-{name}_2"]
    assert {c["section"] for c in doc["checks"]} == {f"tracking {name}",
                                                     f"tracking {name}_2",
                                                     f"consistency {name}",
                                                     f"consistency {name}_2"}
    figure_ids = [f["id"] for f in doc["figures"]]
    assert len(figure_ids) == len(set(figure_ids)) == 6
    assert doc["inputs"]["run_dirs"] == [str(planar_run)] * 2

    one_line_error(run("evaluation", "report", "-o", tmp_path / "r.html"), "nothing to report")
    bad = tmp_path / "bad.toml"
    bad.write_text("[tracking]\nmedian = 1\n")
    one_line_error(run("evaluation", "report", planar_run, "-o", tmp_path / "r.html",
                       "--thresholds", bad), "[tracking] key 'median'")
    # an output never enters an input folder (here it would also replace the run's truth)
    one_line_error(run("evaluation", "report", planar_run, "-o", planar_run / "truth.html"),
                   "inside the input folder")
    one_line_error(run("evaluation", "report", "--dem", fine, "-o", fine), "same file as input")


def test_every_tracker_setting_is_an_option_and_reaches_the_tracker(tmp_path):
    import dataclasses

    from evaluation.tracking import TrackerSettings

    usage = run("evaluation", "track", "--help").output
    for f in dataclasses.fields(TrackerSettings):
        assert "--" + f.name.replace("_", "-") in usage, f.name
    # a value the record refuses is refused before the run folder is even looked at
    one_line_error(run("evaluation", "track", tmp_path / "no_run", "-o", tmp_path / "t",
                       "--quality", 2.0), "tracker quality must lie in (0, 1)")
    one_line_error(run("evaluation", "track", tmp_path / "no_run", "-o", tmp_path / "t",
                       "--block-size", 1), "block_size >= 3")
    assert not (tmp_path / "t").exists()
