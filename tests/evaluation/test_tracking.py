"""Harris tracking through rendered sequences of known motion, scored against truth."""

import dataclasses
import logging
import math
from pathlib import Path

import numpy as np
import pytest

from evaluation.tracking import TrackerSettings, median_by_age, score, track
from render.camera import Pose, quat_from_matrix, quat_to_matrix
from render.rundir import RunReader
from terrain.core.errors import InvalidParameterError, MissingInputError

from .conftest import copy_with_truth

#: Acceptance figure for tracking on a rendered sequence of known motion.
MEDIAN_ERROR_PX = 0.5


@pytest.fixture(scope="module")
def scored(planar_run):
    return score(track(planar_run), planar_run)


def test_tracking_error_against_truth_is_sub_pixel(scored):
    s = scored.summary()
    e, t = s["errors"], s["tracking"]
    print(f"planar descent: {t['tracks']} tracks, median {e['median_px']:.3f} px, p95 "
          f"{e['p95_px']:.3f} px, max {e['max_px']:.3f} px, outliers {e['outlier_fraction']}, "
          f"{e['observations']} observations")
    assert e["median_px"] <= MEDIAN_ERROR_PX
    assert e["outlier_fraction"] <= 0.01
    assert e["observations"] > 1000 and e["unlifted_tracks"] == 0
    assert t["tracks_per_frame_mean"] >= 250 and t["tracks_spanning_sequence"] > 50
    # drift grows with the age of a track, from the first step on
    ages = np.array(e["median_px_by_track_age"])
    assert ages[0, 1] < 0.1 and ages[-1, 1] > ages[0, 1]
    # the truth marks a layer change half way; survival is measured across it
    assert t["layer_changes"] == 1 and t["survival_at_layer_change"] > 0.8


def test_one_step_error_separates_drift_from_each_step(scored):
    """On exact images the one-step error stays flat with track age; accumulated grows."""
    e = scored.error_summary()
    one = np.array(e["one_step_median_px_by_track_age"])
    acc = np.array(e["median_px_by_track_age"])
    # a track's first step is both its one-step and its accumulated error
    assert one[0, 1] == pytest.approx(acc[0, 1]) and one[0, 2] == acc[0, 2]
    both = np.isfinite(scored.one_step) & np.isfinite(scored.errors)
    first = both & (np.arange(scored.tracks.n_frames)[None, :]
                    == scored.tracks.start[:, None] + 1)
    assert np.allclose(scored.one_step[first], scored.errors[first])
    # later steps: each step errs as little as the first, while the sum grows
    assert one[:, 1].max() < 2 * one[0, 1] and acc[-1, 1] > 4 * acc[0, 1]
    assert e["one_step"]["median_px"] < 0.5 * e["median_px"]


def test_prewarping_removes_the_drift_of_a_shift_only_window(planar_run, scored):
    """Plain Lucas-Kanade drifts under the descent's zoom and roll, step after step in the
    same direction; tracking from the homography-warped previous frame does not, and its
    tracks live as long and are as many."""
    plain = score(track(planar_run, TrackerSettings(prewarp=False)), planar_run)
    p, w = plain.error_summary(), scored.error_summary()
    assert scored.tracks.settings.prewarp
    assert w["median_px"] < 0.4 * p["median_px"]
    assert w["one_step"]["median_px"] < 0.5 * p["one_step"]["median_px"]
    tp, tw = plain.tracks.summary(), scored.tracks.summary()
    assert tw["track_length_mean"] >= tp["track_length_mean"]
    assert tw["tracks_per_frame_mean"] >= 0.95 * tp["tracks_per_frame_mean"]


@pytest.mark.slow
def test_ideal_tracker_tells_the_trackers_share_from_the_images(scored, planar_run,
                                                                tmp_path):
    """On exact frames the same tracker errs a few thousandths of a pixel on truth-warped
    frames and on real ones; on a frame whose content jumps (a popped frame) only the real
    error jumps."""
    import json
    import shutil

    import cv2

    from evaluation.tracking import ideal_one_step, truth_warped_frame

    ideal = ideal_one_step(scored, planar_run)
    both = np.isfinite(ideal) & np.isfinite(scored.one_step)
    assert both.sum() > 1000
    # exact frames: both tiny; what the real frames add is their fresh rounding to 8 bits
    assert np.median(ideal[both]) <= np.median(scored.one_step[both]) < 0.05
    # the warped frame is the next frame, up to resampling (8-bit, texture of 3-4 px)
    run = RunReader(planar_run)
    warped = truth_warped_frame(run, 3, 4).astype(np.float64)
    assert np.sqrt(np.mean((warped - run.image(4)) ** 2)) < 0.05 * run.image(4).std()
    # fresh sensor noise on the warped frames (as a new exposure would add) costs accuracy
    with pytest.raises(InvalidParameterError, match="no sensor"):
        ideal_one_step(scored, planar_run, sensor_noise=True)
    noisy_run = tmp_path / "noisy"
    shutil.copytree(planar_run, noisy_run)
    manifest = json.loads((noisy_run / "manifest.json").read_text())
    manifest["sensor"] = dict(bits=8, exposure=1.0, gain=2.0, read_noise=4.0)
    (noisy_run / "manifest.json").write_text(json.dumps(manifest))
    noisy = ideal_one_step(scored, noisy_run, sensor_noise=True)
    again_noisy = ideal_one_step(scored, noisy_run, sensor_noise=True)
    assert np.array_equal(noisy, again_noisy, equal_nan=True)  # keyed: the same noise
    # both at once (each warped frame made once) are each of them alone
    from evaluation.tracking import ideal_one_steps

    plain_and_noisy = ideal_one_steps(scored, noisy_run, noises=(None, 0))
    assert np.array_equal(plain_and_noisy[1], noisy, equal_nan=True)
    assert np.array_equal(plain_and_noisy[0], ideal_one_step(scored, noisy_run),
                          equal_nan=True)
    # every second step (the campaign takes every fourth on long runs): those steps' errors,
    # no others
    halves = ideal_one_steps(scored, noisy_run, noises=(None, 0), every=2)
    for full, half in zip(plain_and_noisy, halves, strict=True):
        np.testing.assert_array_equal(half[:, ::2], full[:, ::2])
        assert np.all(np.isnan(half[:, 1::2])) and np.isfinite(half).sum() > 100
    both = np.isfinite(noisy) & np.isfinite(ideal)
    assert np.median(noisy[both]) > 1.2 * np.median(ideal[both])
    # a frame shifted by 2 px (its content jumps under the features)
    popped = tmp_path / "popped"
    shutil.copytree(planar_run, popped)
    frame = popped / "frames" / "frame_000006.png"
    img = cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(frame), np.roll(img, 2, axis=1))
    again = score(track(popped), popped)
    real = again.one_step[:, 6]
    ideal = ideal_one_step(again, popped)[:, 6]
    ok = np.isfinite(real) & np.isfinite(ideal)
    assert np.median(real[ok]) > 1.5 and np.median(ideal[ok]) < 0.3


def test_a_wrong_position_is_detected_as_large_error(planar_run, tmp_path, scored):
    """A navigation truth drifting 0.5 m per frame (about 3.5 px per frame at 45 m)."""

    def drifting(t):
        p = np.asarray(t.pose.position) + [0.5 * t.index, 0.0, 0.0]
        return dataclasses.replace(t, pose=Pose(tuple(p), t.pose.attitude))

    wrong = copy_with_truth(planar_run, tmp_path / "wrong", drifting)
    bad = score(scored.tracks, wrong).error_summary()
    print(f"truth drifting 0.5 m per frame: median {bad['median_px']:.2f} px, outliers "
          f"{bad['outlier_fraction']:.3f}")
    assert bad["median_px"] > 5.0 and bad["outlier_fraction"] > 0.9


def test_a_wrong_attitude_is_detected_as_large_error(planar_run, tmp_path, scored):
    """An attitude truth drifting 0.5 degree per frame about the camera's y axis (3 px)."""

    def tilted(t):
        tilt = math.radians(0.5 * t.index)
        r = np.array([[math.cos(tilt), 0, math.sin(tilt)], [0, 1, 0],
                      [-math.sin(tilt), 0, math.cos(tilt)]])
        q = quat_from_matrix(quat_to_matrix(t.pose.attitude) @ r)
        return dataclasses.replace(t, pose=Pose(t.pose.position, tuple(q)))

    wrong = copy_with_truth(planar_run, tmp_path / "tilted", tilted)
    bad = score(scored.tracks, wrong).error_summary()
    print(f"truth tilting 0.5 deg per frame: median {bad['median_px']:.2f} px, outliers "
          f"{bad['outlier_fraction']:.3f}")
    assert bad["median_px"] > 5.0 and bad["outlier_fraction"] > 0.8


def test_a_rotating_body_frame_gives_the_same_errors(planar_run, tmp_path, scored):
    """World = body rotated by R_k each frame, camera carried along: nothing changes."""

    def rotated(t):
        angle = 0.3 * t.index
        c, s = math.cos(angle), math.sin(angle)
        rk = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ \
            np.array([[1.0, 0.0, 0.0], [0.0, math.cos(angle / 3), -math.sin(angle / 3)],
                      [0.0, math.sin(angle / 3), math.cos(angle / 3)]])
        pose = Pose(tuple(rk @ np.asarray(t.pose.position)),
                    tuple(quat_from_matrix(rk @ t.pose.rotation)))
        return dataclasses.replace(t, pose=pose, body_rotation=tuple(quat_from_matrix(rk)))

    spun = copy_with_truth(planar_run, tmp_path / "spun", rotated)
    again = score(scored.tracks, spun)
    both = np.isfinite(scored.errors)
    assert np.array_equal(both, np.isfinite(again.errors))
    assert np.allclose(again.errors[both], scored.errors[both], atol=1e-6)


def test_hidden_points_are_counted_not_scored(planar_run, tmp_path, scored):
    """An occluder in the range images of the last frame hides the points behind it."""
    from terrain.io import read_float_tiff, write_float_tiff

    copy = copy_with_truth(planar_run, tmp_path / "occluded", lambda t: t)
    last = RunReader(copy).truth[-1]
    rng = read_float_tiff(copy / last.range)
    rng[:, : rng.shape[1] // 2] *= 0.5  # something at half the distance, left half
    (copy / last.range).unlink()
    write_float_tiff(rng, copy / last.range)
    again = score(scored.tracks, copy)
    k = scored.tracks.n_frames - 1
    left = scored.predicted[:, k, 0] < rng.shape[1] // 2 - 2
    assert again.counts["hidden"] >= int((left & np.isfinite(scored.errors[:, k])).sum())
    assert not np.isfinite(again.errors[left, k]).any()
    assert np.array_equal(again.errors[:, :k], scored.errors[:, :k], equal_nan=True)


def test_without_truth_tracking_runs_and_error_metrics_are_omitted(run_without_truth, caplog):
    reader = RunReader(run_without_truth)
    assert not reader.has_truth
    tracks = track(reader)
    with caplog.at_level(logging.WARNING):
        s = score(tracks, reader)
    assert not s.has_errors and s.error_summary() is None
    assert "no truth.json" in caplog.text and s.notes
    summary = s.summary()
    assert summary["tracking"]["tracks"] > 300 and summary["errors"] is None
    assert summary["tracking"]["layer_changes"] == 0  # no truth: no layers known


def test_without_range_images_error_metrics_are_omitted(planar_run, tmp_path, caplog, scored):
    no_range = copy_with_truth(planar_run, tmp_path / "no_range",
                               lambda t: dataclasses.replace(t, range=None))
    with caplog.at_level(logging.WARNING):
        s = score(scored.tracks, no_range)
    assert s.errors is None and "without range images" in caplog.text


def test_silhouette_features_are_told_apart(scored):
    from evaluation.tracking import SILHOUETTE_PX, _near_silhouette

    rng = np.full((40, 60), 100.0)
    rng[:, 40:] = np.nan  # sky on the right
    rng[:10, :20] = 50.0  # a nearer surface occluding the top left corner
    uv = np.array([[10.0, 30.0], [40.0 - SILHOUETTE_PX, 20.0], [40.0 - SILHOUETTE_PX - 2, 20.0],
                   [25.0, 20.0], [10.0, 10.0 + SILHOUETTE_PX]])
    assert _near_silhouette(rng, uv).tolist() == [False, True, False, False, True]
    # a plane filling the frame has no silhouette: every track is a surface track
    e = scored.error_summary()
    assert e["silhouette_tracks"] == 0
    assert e["surface_tracks"]["median_px"] == pytest.approx(e["median_px"])


def _disc_run(run_dir, *, frames: int = 2) -> Path:
    """A textured disc on black sky, 200 px frames, with a deep shadow (a 30 px square) and
    a dark speck (3 px) on it; the disc slides 0.5 px right each frame."""
    import cv2

    from render.camera import Intrinsics, look_at
    from render.rundir import FrameTruth, RunWriter

    from .conftest import plane_texture

    tex = plane_texture(7)[:200, :200]
    tex = 60.0 + 140.0 * (tex - tex.min()) / (tex.max() - tex.min())
    k = Intrinsics.from_fov(200, 200, 40.0)
    writer = RunWriter(run_dir, dict(scene="textured disc (evaluation tests)", frames=frames,
                                     resolution=[200, 200], seed=7))
    rows, cols = np.mgrid[0:200, 0:200]
    for i in range(frames):
        inside = np.hypot(cols - 100.0 - 0.5 * i, rows - 100.0) <= 70.0
        image = np.where(inside, tex, 0.0)
        image[85:115, 60:90] = 0.0  # deep shadow
        image[100:103, 130:133] = 0.0  # a pit: surface detail
        image = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 0.6)
        rng = np.where(inside, 1000.0, np.nan).astype(np.float32)
        pose = look_at((0.0, 0.0, 1000.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
        writer.write_frame(FrameTruth(i, float(i), pose, k, (0.0, 0.0, 1.0)),
                           np.clip(np.rint(image), 0, 255).astype(np.uint8), rng, None)
    writer.finish()
    return Path(run_dir)


def test_no_corner_is_detected_beside_the_sky_or_a_deep_shadow(tmp_path):
    """A limb against black sky makes the strongest corners of a frame, and not one is a
    point of the surface; the tracker finds the sky (and deep shadow) in the image and
    detects no corner within its margin of it. A dark speck smaller than a window is
    surface detail and stays trackable."""
    from evaluation.tracking import DARK_MARGIN_SLACK

    run = _disc_run(tmp_path / "disc")
    plain = track(run, TrackerSettings(dark_margin=0))
    masked = track(run, TrackerSettings())
    margin = TrackerSettings().win_size // 2 + DARK_MARGIN_SLACK
    assert masked.settings.as_dict()["dark_margin"] == margin

    def first(tracks):  # where each track was detected, in frame 0's disc
        uv = tracks.positions[np.arange(tracks.n_tracks), tracks.start].astype(np.float64)
        return uv - np.stack([0.5 * tracks.start, 0.0 * tracks.start], axis=1)

    def limb_distance(tracks):
        uv = first(tracks)
        return 70.0 - np.hypot(uv[:, 0] - 100.0, uv[:, 1] - 100.0)

    def shadow_distance(tracks):
        uv = first(tracks)
        du = np.maximum(np.maximum(60.0 - uv[:, 0], uv[:, 0] - 89.0), 0.0)
        dv = np.maximum(np.maximum(85.0 - uv[:, 1], uv[:, 1] - 114.0), 0.0)
        return np.hypot(du, dv)

    # without the mask: limb and shadow corners; with it: none within the margin (the
    # blur and the pixel grid move the dark region's edge by up to 2 px)
    assert (limb_distance(plain) < 4).sum() >= 10 and (shadow_distance(plain) < 4).sum() >= 2
    assert limb_distance(masked).min() >= margin - 2
    assert shadow_distance(masked).min() >= margin - 2
    assert masked.n_tracks >= 20
    speck = first(masked) - np.array([131.0, 101.0])
    assert np.hypot(speck[:, 0], speck[:, 1]).min() < 3
    # tracks already live are followed into the margin: the mask only stops detection
    assert masked.alive()[:, 1].sum() >= masked.alive()[:, 0].sum() - 2


@pytest.mark.parametrize("margin", [0, 1, 5, 12, 30])
def test_near_dark_is_an_exact_euclidean_distance_within_the_margin(margin):
    """near_dark grows the dark regions by a disk: the pixels an exact distance transform
    puts within ``margin`` of them, no more and no fewer."""
    import cv2

    from evaluation.tracking import near_dark

    rng = np.random.default_rng(margin)
    img = np.full((120, 150), 100, np.uint8)
    for _ in range(6):  # dark blobs of several sizes, some at the border, left of column 130
        r0, c0 = rng.integers(-10, 120), rng.integers(-10, 100)
        img[max(r0, 0):r0 + rng.integers(3, 30), max(c0, 0):c0 + rng.integers(3, 30)] = 0
    img[60, 145] = 0  # a speck, smaller than min_area: surface detail
    near = near_dark(img, 2, margin, 9)
    dark = img <= 2
    _, labels, stats, _ = cv2.connectedComponentsWithStats(dark.astype(np.uint8),
                                                           connectivity=8)
    region = np.isin(labels, np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= 9)[1:])
    dist = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2,
                                 cv2.DIST_MASK_PRECISE)
    assert region.any() and not region[60, 145]
    assert np.array_equal(near, dist <= margin)
    # without the speck every dark region counts (near_dark then skips its table by label)
    img[60, 145] = 100
    assert np.array_equal(near_dark(img, 2, margin, 9), dist <= margin)



@pytest.mark.parametrize("kwargs", [dict(dark_level=-1), dict(dark_level=256),
                                    dict(dark_margin=-2), dict(dark_margin=2.5)])
def test_bad_dark_settings_are_refused(kwargs):
    with pytest.raises(InvalidParameterError, match="dark_"):
        TrackerSettings(**kwargs)


def test_resolution_changes_are_read_from_each_scene_kind():
    from evaluation.tracking import resolution_key as key

    terrain = {"layers": [{"level": 0, "triangles": 5, "lod": [1]}], "triangles": 5}
    finer = {"layers": [{"level": 0, "triangles": 9, "lod": [2]}], "triangles": 9}
    assert key(terrain) == key(finer)  # same layers, other counts: no change
    assert key(terrain) != key({"layers": [{"level": 0}, {"level": 1}]})
    body = {"body_magnitude": 64, "patches": 10, "triangles": 100, "imposter": False}
    assert key(body) == key(dict(body, patches=12, triangles=140))
    assert key(body) != key(dict(body, body_magnitude=128))
    assert key(body) != key(dict(body, imposter=True))
    assert key({"lod_edge_m": 2.0, "triangles": 4}) != key({"lod_edge_m": 1.0, "triangles": 4})
    assert key({"anything": 1}) != key({"anything": 2})


def test_bad_input_is_refused(planar_run, tmp_path):
    with pytest.raises(InvalidParameterError, match="fb_threshold"):
        TrackerSettings(fb_threshold=0.0)
    with pytest.raises(InvalidParameterError, match="integer"):
        TrackerSettings(max_corners=2.5)
    with pytest.raises(MissingInputError, match="does not exist"):
        track(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(MissingInputError, match="holds no frames"):
        track(tmp_path / "empty")
    short = track(planar_run, TrackerSettings(max_corners=20))
    assert short.alive().sum(axis=0).max() <= 20
    with pytest.raises(InvalidParameterError, match="outlier_px"):
        score(short, planar_run, outlier_px=0.0)


@pytest.mark.slow
def test_tracking_a_sequence_from_the_gl_renderer(tmp_path):
    """End to end with `craterscape render sequence` (skipped without headless OpenGL).

    The renderer runs in a child process, so this test shares no GL context or state with
    the render tests in the same session.
    """
    import subprocess
    import sys

    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(129, resolution=20.0, relief=300.0, seed=3).tile
    stack = build_stack(base, (1290.0, 1290.0), levels=2, layer_size=129, seed=4,
                        population=Population(dmin=10.0, dmax=600.0, density=2e3))
    folder = write_stack(stack, tmp_path / "stack")
    scenario = tmp_path / "descent.toml"
    scenario.write_text(f"""
name = "evaluation-test"
seed = 5
[scene]
type = "terrain"
stack = "{folder}"
curvature = false
[sun]
azimuth = 100.0
elevation = 25.0
[camera]
width = 256
height = 192
fov = 50.0
[sensor]
bits = 8
exposure = 4.0
gain = 10.0
read_noise = 1.0
[trajectory]
type = "descent"
frames = 12
duration = 12.0
start_altitude = 1000.0
end_altitude = 850.0
ground_track = [300.0, 100.0]
""")
    proc = subprocess.run([sys.executable, "-c", "from terrain.cli.commands import main; main()",
                           "render", "sequence", str(scenario), "-o", str(tmp_path / "run")],
                          capture_output=True, text=True, check=False)
    if proc.returncode != 0 and "OpenGL" in proc.stderr:
        pytest.skip(f"no headless OpenGL here: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stderr
    s = score(track(tmp_path / "run"), tmp_path / "run").error_summary()
    print(f"GL-rendered descent: median {s['median_px']:.3f} px, outliers "
          f"{s['outlier_fraction']:.4f}, {s['observations']} observations")
    assert s["median_px"] <= MEDIAN_ERROR_PX and s["outlier_fraction"] < 0.02


def test_median_by_age_is_each_age_group_median():
    # tracks starting at different frames, with gaps: each age's median and count, taken
    # one age at a time over the whole array
    rng = np.random.default_rng(3)
    n_tracks, n_frames = 40, 25
    start = rng.integers(0, n_frames, n_tracks)
    age = np.arange(n_frames)[None, :] - start[:, None]
    values = np.where(age >= 1, rng.exponential(0.2, (n_tracks, n_frames)), np.nan)
    values[rng.random(values.shape) < 0.3] = np.nan
    expected = []
    for a in range(1, int(age.max()) + 1):
        sel = np.isfinite(values) & (age == a)
        if sel.any():
            expected.append([a, float(np.median(values[sel])), int(sel.sum())])
    assert median_by_age(values, age) == expected
    assert median_by_age(np.full((3, 4), np.nan), np.ones((3, 4), int)) == []
