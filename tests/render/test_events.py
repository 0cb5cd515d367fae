"""The event camera against a panning step edge, whose log-intensity history is known exactly.

A bright half-plane (I/F 0.3) slides over a dark one (0.01) at 40 px/s; each pixel integrates
its area, so while the edge crosses it its intensity rises linearly in time. The number of ON
events a pixel emits is the log-intensity change over the threshold, and the time of each
crossing of ``ref + k C`` is solvable in closed form: every timestamp must lie within one
rendered step of it.
"""

from __future__ import annotations

import numpy as np
import pytest

from render.events import EventCamera, EventSimulator, event_frame, simulate, write_events
from terrain.core.errors import InvalidParameterError

LO, HI, SPEED, X0, W = 0.01, 0.3, 40.0, 2.0, 48


def edge(t: float) -> np.ndarray:
    """Rows of pixels under a bright half-plane whose edge is at X0 + SPEED t (from the
    left: pixels left of the edge are bright), each pixel's covered fraction exact."""
    xe = X0 + SPEED * t
    cover = np.clip(xe - np.arange(W), 0.0, 1.0)
    return np.tile(LO + (HI - LO) * cover, (3, 1))


def crossing_time(col: int, level: float, eps: float) -> float:
    """When pixel ``col``'s log intensity reaches ``level`` (inverse of ``edge``)."""
    frac = (np.exp(level) - eps - LO) / (HI - LO)
    return (col + frac - X0) / SPEED


def test_events_count_the_log_change_and_time_each_crossing_within_a_step():
    cam = EventCamera(contrast_on=0.3, contrast_off=0.3, contrast_spread=0.0,
                      max_step=2e-3, min_step=1e-5, max_crossings=2.0)
    events, stats = simulate(edge, 0.0, 1.0, cam, seed=3)
    assert stats["largest_crossings"] <= cam.max_crossings + 1e-9
    assert set(events.p.tolist()) == {1}  # the edge only brightens pixels
    dl = np.log(HI + cam.log_eps) - np.log(LO + cam.log_eps)
    swept = range(int(X0) + 1, int(X0 + SPEED) - 1)
    for col in swept:
        mine = (events.x == col) & (events.y == 1)
        assert abs(int(mine.sum()) - dl / 0.3) <= 1.0
        times = np.sort(events.t[mine])
        l0 = np.log(LO + cam.log_eps)
        exact = np.array([crossing_time(col, l0 + k * 0.3, cam.log_eps)
                          for k in range(1, times.size + 1)])
        assert np.max(np.abs(times - exact)) <= cam.max_step


def test_a_pixel_that_jumps_at_every_step_does_not_pin_the_step_to_its_minimum():
    """A rendered image has pixels that jump at any step, however short (an edge crossing a
    pixel centre, sub-pixel flicker). Held to every pixel, the step shrinks towards min_step
    (each longer step rejected and rendered again); with the outlier allowance the rest of
    the image sets it, and the slow ramp's events are the same count either way."""
    h, w = 40, 50  # 2,000 pixels: 1e-3 of them is 2
    ramp = np.linspace(0.05, 0.2, w)[None, :].repeat(h, axis=0)

    calls = [0]

    def render(t):
        img = ramp * (1.0 + 20.0 * t)  # log change ln(1.4) over 20 ms: about 1.7 thresholds
        calls[0] += 1
        img[7, 9] = 0.5 if calls[0] % 2 else 0.05  # a different surface at every render
        return img

    runs = {}
    for frac in (0.0, 1e-3):
        cam = EventCamera(contrast_on=0.2, contrast_off=0.2, contrast_spread=0.0,
                          min_step=1e-4, max_step=5e-3, outlier_fraction=frac)
        ev, stats = simulate(render, 0.0, 0.02, cam, seed=3)
        smooth = ~((ev.y == 7) & (ev.x == 9))
        runs[frac] = (stats, int(np.count_nonzero(smooth & (ev.p > 0))))
    pinned, allowed = runs[0.0][0], runs[1e-3][0]
    assert pinned["instants"] + pinned["rejected"] >= 200  # renders, steps near min_step
    assert allowed["instants"] <= 10 and allowed["rejected"] == allowed["forced"] == 0
    # each smooth pixel crosses floor(ln 1.4 / 0.2) = 1 ON threshold either way
    assert runs[0.0][1] == runs[1e-3][1] == (h * w - 1)
    assert allowed["largest_crossings"] > 5  # the flicker is still reported


def test_spread_thresholds_refractory_and_noise_stay_deterministic():
    cam = EventCamera(contrast_on=0.2, contrast_off=0.2, contrast_spread=0.1,
                      refractory=5e-3, noise_rate=2.0, leak_rate=0.5, max_step=2e-3)
    a, _ = simulate(edge, 0.0, 0.5, cam, seed=11)
    b, _ = simulate(edge, 0.0, 0.5, cam, seed=11)
    c, _ = simulate(edge, 0.0, 0.5, cam, seed=12)
    for k in "xytp":
        assert np.array_equal(getattr(a, k), getattr(b, k))
    assert len(a) != len(c) or not np.array_equal(a.t, c.t)
    # the refractory period separates a pixel's events
    for col in range(5, 15):
        mine = np.sort(a.t[(a.x == col) & (a.y == 0) & (a.p == 1)])
        assert np.all(np.diff(mine) >= 5e-3 - 1e-12)
    assert np.all(np.diff(a.t) >= 0)


def test_a_still_scene_emits_only_leak_and_noise_at_their_rates():
    still = np.full((32, 32), 0.1)
    cam = EventCamera(leak_rate=1.0, noise_rate=0.0, contrast_spread=0.0, max_step=0.01)
    ev, _ = simulate(lambda t: still, 0.0, 4.0, cam, seed=1)
    per_pixel = len(ev) / still.size
    assert 3.0 <= per_pixel <= 4.5 and set(ev.p.tolist()) == {1}
    cam = EventCamera(leak_rate=0.0, noise_rate=5.0, contrast_spread=0.0, max_step=0.01)
    ev, _ = simulate(lambda t: still, 0.0, 2.0, cam, seed=1)
    rate = len(ev) / still.size / 2.0
    assert rate == pytest.approx(5.0, rel=0.1)
    assert abs(np.mean(ev.p == 1) - 0.5) < 0.05


def test_readout_limit_drops_events_and_counts_them():
    cam = EventCamera(contrast_spread=0.0, max_event_rate=2000.0, max_step=2e-3)
    ev, stats = simulate(edge, 0.0, 1.0, cam)
    free, _ = simulate(edge, 0.0, 1.0, EventCamera(contrast_spread=0.0, max_step=2e-3))
    assert stats["dropped"] > 0 and len(ev) + stats["dropped"] == len(free)


def test_file_preview_and_refusals(tmp_path):
    cam = EventCamera(contrast_spread=0.0)
    ev, _ = simulate(edge, 0.0, 0.2, cam)
    path = write_events(tmp_path / "events.npz", ev, (3, W), cam, scenario="edge")
    with np.load(path) as f:
        assert f["t"].dtype == np.int64 and int(f["width"]) == W
        assert np.array_equal(f["x"], ev.x) and np.array_equal(f["t"], np.round(ev.t * 1e6))
    img = event_frame(ev, (3, W))
    assert img.shape == (3, W, 3) and img[..., 0].max() == 255 and img[..., 2].max() == 0
    with pytest.raises(InvalidParameterError, match="contrast_on"):
        EventCamera.from_mapping({"contrast_on": -1})
    with pytest.raises(InvalidParameterError, match="did you mean 'refractory'"):
        EventCamera.from_mapping({"refractroy": 1e-3})
    sim = EventSimulator(cam, (2, 2))
    with pytest.raises(InvalidParameterError, match="shape"):
        sim.reset(0.0, np.zeros((3, 3)))


@pytest.mark.slow
def test_a_descent_with_an_event_camera_writes_its_events_and_repeats_them(tmp_path, gl):
    """A scenario's [events] table runs the camera over the whole descent: the events file
    reads back, the adaptive step kept pixels within their crossing limit but where the
    rendering itself jumps (levels of detail switching), and the same scenario renders the
    same events."""
    from render.scenario import load_scenario
    from render.sequence import run_sequence
    from tests.render.scenes import cratered_stack, descent_scenario

    stack = cratered_stack(tmp_path / "stack")
    text = descent_scenario(stack, "events", frames=2).replace(
        "end_altitude = 100.0", "end_altitude = 1400.0") + """
[events]
contrast_on = 0.3
contrast_off = 0.3
max_step = 0.05
min_step = 0.001
"""
    (tmp_path / "s.toml").write_text(text)
    runs = []
    for k in range(2):
        manifest = run_sequence(load_scenario(tmp_path / "s.toml"), tmp_path / f"run{k}")
        runs.append(manifest["events"])
    assert runs[0]["forced"] <= 0.15 * runs[0]["instants"]
    assert runs[0]["events"] > 100 and runs[0]["instants"] > 3
    a, b = ((tmp_path / f"run{k}" / "events.npz").read_bytes() for k in range(2))
    with np.load(tmp_path / "run0" / "events.npz") as f:
        assert f["t"].min() >= 0 and f["t"].max() <= 4_000_000
        assert set(np.unique(f["p"]).tolist()) <= {-1, 1}
    with np.load(tmp_path / "run1" / "events.npz") as g, \
            np.load(tmp_path / "run0" / "events.npz") as f:
        assert all(np.array_equal(f[k], g[k]) for k in "xytp")
    assert (tmp_path / "run0" / "events_preview.png").exists() and len(a) == len(b)
