"""The campaign file and its stages (evaluation/campaign.py); the whole campaign runs in
tests/test_demo.py."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from evaluation.campaign import Campaign, Stage, load_campaign, write_scenario
from terrain.cli.tools import cli_args
from terrain.core.errors import InvalidParameterError

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "examples" / "demo.toml"


def _demo() -> dict:
    return tomllib.loads(DEMO.read_text(encoding="utf-8"))


def test_the_demo_campaign_parses_and_quick_merges_over_it():
    full, quick = load_campaign(DEMO), load_campaign(DEMO, quick=True)
    assert isinstance(full, Campaign) and not full.quick and quick.quick
    assert full.lunar_run.scenario.exists() and full.asteroid_run.scenario.exists()
    # --quick shrinks what it names and keeps everything else
    assert quick.base["size"] < full.base["size"]
    assert {k: v for k, v in quick.base.items() if k not in ("size", "relief", "dmax")} == \
        {k: v for k, v in full.base.items() if k not in ("size", "relief", "dmax")}
    assert quick.lunar_run.frames and full.lunar_run.frames is None
    with pytest.raises(TypeError):  # frozen options
        full.base["size"] = 3


@pytest.mark.parametrize("table, key, near", [
    (("lunar", "base"), "fractal_dimensoin", "fractal_dimension"),
    (("lunar", "stack"), "rock", "rocks"),
    (("lunar", "run"), "frame", "frames"),
    (("lunar", "closed_loop"), "sise", "size"),
    (("evaluation",), "max_slop", "max_slope"),
    ((), "titel", "title"),
])
def test_unknown_keys_are_named_with_the_nearest(table, key, near):
    data = _demo()
    where = data
    for name in table:
        where = where[name]
    where[key] = 1
    with pytest.raises(InvalidParameterError, match=rf"'{key}'.*did you mean '{near}'"):
        Campaign.from_mapping(data, DEMO)


def test_stage_options_become_the_commands_own_flags():
    c = load_campaign(DEMO)
    args = cli_args(c.stack)
    assert "--rocks" in args and "--fractal-dimension" in args
    assert cli_args({"no_roughness": True, "cog": False}) == ["--no-roughness"]


def test_scenario_overrides_go_through_the_parser(tmp_path):
    template = REPO / "examples" / "lunar_descent.toml"
    scenario = write_scenario(template, tmp_path / "run.toml",
                              {"sun": {"azimuth": 210.0}, "trajectory": {"frames": 3},
                               "scene": {"stack": str(tmp_path / "stack")}})
    assert scenario.trajectory.frames == 3
    written = tomllib.loads((tmp_path / "run.toml").read_text(encoding="utf-8"))
    original = tomllib.loads(template.read_text(encoding="utf-8"))
    assert written["sun"] == dict(original["sun"], azimuth=210.0)
    assert written["camera"] == original["camera"]
    # a bad override is refused by the parser before anything is written
    with pytest.raises(InvalidParameterError, match="azimuth"):
        write_scenario(template, tmp_path / "bad.toml", {"sun": {"azimuth": "south"}})
    with pytest.raises(InvalidParameterError, match="did you mean"):
        write_scenario(template, tmp_path / "bad.toml", {"camera": {"widht": 5}})
    assert not (tmp_path / "bad.toml").exists()


def test_a_stage_is_done_only_for_the_same_parameters(tmp_path):
    a = Stage(tmp_path, "lunar/base", {"size": 257})
    assert not a.done()
    a.begin()
    (a.dir / "partial.txt").write_text("kept while resuming")
    a.begin()  # same parameters: a partial run is kept
    assert (a.dir / "partial.txt").exists()
    a.finish(1.5, frames=3)
    assert a.done()
    assert json.loads(a.marker.read_text())["frames"] == 3
    b = Stage(tmp_path, "lunar/base", {"size": 1025})
    assert not b.done()
    b.begin()  # other parameters: emptied
    assert not (b.dir / "partial.txt").exists()
