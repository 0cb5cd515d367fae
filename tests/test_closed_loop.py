"""examples/closed_loop.py's navigation: optical flow after altitude scaling, against a known
warp (the closed loop itself runs in `make demo`, tests/test_demo.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def loop():
    spec = importlib.util.spec_from_file_location("closed_loop", REPO / "examples" /
                                                  "closed_loop.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("zoom, du, dv", [(1.0, 2.5, -1.25), (1.08, -3.0, 0.75),
                                           (1.15, 0.4, 4.0)])
def test_flow_recovers_the_shift_left_after_the_altitude_zoom(loop, rng, zoom, du, dv):
    import cv2

    n, c = 160, 79.5
    ground = cv2.GaussianBlur(rng.random((n, n)).astype(np.float32), (0, 0), 2.0)
    # the next frame: the ground seen 'zoom' times larger about the centre, then shifted
    m = np.array([[zoom, 0.0, (1 - zoom) * c + du], [0.0, zoom, (1 - zoom) * c + dv]])
    later = cv2.warpAffine(ground, m, (n, n), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REFLECT)
    got_u, got_v, peak = loop.optical_flow(ground, later, zoom, (c, c))
    assert (got_u, got_v) == pytest.approx((du, dv), abs=0.1)
    assert peak > 0.3
