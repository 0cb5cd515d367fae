"""The crater-navigation reference solves poses on a labelled descent, and the report shows it."""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_crater_navigation_solves_a_labelled_descent_and_feeds_the_report(tmp_path):
    pytest.importorskip("cv2")
    from evaluation.campaign_report import crater_navigation_section

    # the lunar descent's own scene (built from its recipe into tmp_path), its first 3 km
    text = (ROOT / "examples/lunar_descent.toml").read_text()
    text = re.sub(r'(?m)^stack = .*$', 'stack = "stack"', text)
    text = re.sub(r"(?m)^frames = .*$", "frames = 3", text)
    text = re.sub(r"(?m)^end_altitude = .*$", "end_altitude = 4000.0", text)
    # a mid-latitude sun: under the scenario's 7 deg polar sun 98 % of these frames of the
    # reduced demo's site lie in cast shadow (34 % facing away from the sun), and the detector
    # takes only lit rims; the navigation, not the polar light, is what is tested here
    text = re.sub(r"(?m)^elevation = .*$", "elevation = 30.0", text)
    scenario = tmp_path / "descent.toml"
    scenario.write_text(text)
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        import crater_navigation
    finally:
        sys.path.remove(str(ROOT / "examples"))
    from render.errors import RenderUnavailableError

    out = tmp_path / "nav"
    try:
        done = crater_navigation.main([str(scenario), "--out", str(out), "--resolution", "256"])
    except RenderUnavailableError as exc:
        pytest.skip(f"no headless OpenGL here: {exc}")
    assert done == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["frames"] == 3 and s["solved"] >= 1
    solved = [r for r in s["per_frame"] if math.isfinite(r["error_percent"])]
    # the solve must beat the prior it started from
    assert all(r["error_percent"] < r["prior_error_percent"] for r in solved)
    sec = crater_navigation_section(out, tmp_path)
    assert len(sec.tables[0][2]) == 3 and "TRON" in sec.paragraphs[0]
