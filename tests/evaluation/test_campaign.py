"""The campaign file and its stages (evaluation/campaign.py); the whole campaign runs in
tests/test_demo.py."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from evaluation.campaign import Campaign, Stage, load_campaign, write_scenario
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


def test_stage_tables_become_the_stages_specs():
    """What the campaign file says is what the stages get, and the campaign's own values
    (its seed, layers as large as the base) fill in the rest."""
    c = load_campaign(DEMO)
    base = tomllib.loads(DEMO.read_text())["lunar"]["base"]
    assert c.synth.fractal_dimension == base["fractal_dimension"] and c.synth.size == 1025
    assert c.synth.repose == base["repose"]  # a synth option the file gives
    assert c.enhance.rocks == "viper-nominal" and c.enhance.levels == 15
    assert c.synth.seed == c.enhance.seed == 2014
    assert c.enhance.layer_size == c.synth.size and c.enhance.site is None
    assert c.recipe.magnitude == 256 and c.recipe.seed == 433  # examples/eros_like.toml
    assert load_campaign(DEMO, quick=True).recipe.magnitude == 96


@pytest.mark.parametrize("table, key, value, words", [
    (("lunar", "base"), "size", 1000, ["[lunar.base]", "2^n + 1"]),
    (("lunar", "base"), "relief", "high", ["[lunar.base]", "relief", "number"]),
    (("lunar", "stack"), "finest_resolution", 0.5, ["[lunar.stack]", "levels"]),
    (("asteroid", "body"), "magnitude", "big", ["[asteroid.body]", "magnitude"]),
])
def test_stage_values_are_checked_when_the_campaign_is_parsed(table, key, value, words):
    data = _demo()
    data[table[0]][table[1]][key] = value
    with pytest.raises(InvalidParameterError) as err:
        Campaign.from_mapping(data, DEMO)
    assert all(w in str(err.value) for w in words), str(err.value)


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


class _Started(Exception):
    """Raised by a campaign's first progress line: the test needs nothing beyond it."""


def _stop(message: str) -> None:
    raise _Started(message)


@pytest.mark.parametrize("fresh", [True, False])
def test_a_folder_that_holds_no_campaign_is_refused_untouched(tmp_path, fresh):
    from evaluation.campaign import run_campaign

    home = tmp_path / "home"
    (home / "lunar" / "base").mkdir(parents=True)
    (home / "notes.txt").write_text("mine")
    (home / "lunar" / "base" / "survey.tif").write_text("mine too")
    with pytest.raises(InvalidParameterError, match="holds no campaign"):
        run_campaign(load_campaign(DEMO, quick=True), home, fresh=fresh, say=_stop)
    assert (home / "notes.txt").read_text() == "mine"
    assert (home / "lunar" / "base" / "survey.tif").read_text() == "mine too"


def test_an_output_that_is_a_file_is_refused(tmp_path):
    from evaluation.campaign import run_campaign

    (tmp_path / "out").write_text("a file")
    with pytest.raises(InvalidParameterError, match="not a folder"):
        run_campaign(load_campaign(DEMO, quick=True), tmp_path / "out", say=_stop)
    assert (tmp_path / "out").read_text() == "a file"


def test_a_stage_never_empties_a_folder_it_did_not_write(tmp_path):
    (tmp_path / "evaluation").mkdir()
    (tmp_path / "evaluation" / "mine.txt").write_text("kept")
    stage = Stage(tmp_path, "evaluation", {"v": 1})
    with pytest.raises(InvalidParameterError, match="not written by a campaign"):
        stage.begin()
    assert (tmp_path / "evaluation" / "mine.txt").read_text() == "kept"


def test_fresh_removes_only_what_the_campaign_wrote(tmp_path):
    from evaluation.campaign import claim_output

    out = claim_output(tmp_path / "out")
    stage = Stage(out, "lunar/base", {"size": 257})
    stage.begin()
    (stage.dir / "base.tif").write_text("made by the campaign")
    stage.finish(1.0)
    (out / "notes.txt").write_text("the user's")
    assert claim_output(out) == out  # a campaign's folder is taken again as it is
    assert stage.done()
    claim_output(out, fresh=True)
    assert not stage.dir.exists() and not stage.marker.exists()
    assert not (out / "lunar").exists()  # emptied parents of the stages go too
    assert (out / "notes.txt").read_text() == "the user's"
    # and the emptied folder is still the campaign's
    assert claim_output(out) == out


@pytest.mark.parametrize("table, key", [
    (("lunar", "base"), "output"), (("lunar", "base"), "catalog"), (("lunar", "base"), "seed"),
    (("lunar", "stack"), "output"), (("lunar", "stack"), "seed"), (("lunar", "stack"), "site"),
    (("asteroid", "body"), "output"),
])
def test_options_the_campaign_sets_itself_are_refused(table, key):
    data = _demo()
    data[table[0]][table[1]][key] = "/tmp/elsewhere.tif" if key != "seed" else 3
    with pytest.raises(InvalidParameterError, match=f"'{key}'"):
        Campaign.from_mapping(data, DEMO)


def test_results_are_the_reports_figures_stamped_with_the_commit(tmp_path):
    import re

    from evaluation.campaign import source_commit, write_results

    out = tmp_path / "out"
    (out / "evaluation").mkdir(parents=True)
    report = out / "evaluation" / "report.html"
    checks = [dict(section="a", name="descent tracking median", value=0.27, limit=0.5,
                   relation="<=", unit="px", passed=True, note=""),
              dict(section="b", name="site |log10 ratio|", value=0.36, limit=0.2,
                   relation="<=", unit="", passed=False, note=""),
              dict(section="b", name="Hurst exponent", value=None, limit=0.1, relation="<=",
                   unit="", passed=None, note="too small")]
    report.with_suffix(".json").write_text(json.dumps({"verdict": "fail", "checks": checks}))
    Stage(out, "lunar/run", {}).finish(12.5, frames=16, fps=1.28)
    Stage(out, "evaluation", {}).finish(3.0, asteroid_ks=0.1,
                                        tracking_lunar=dict(tracks=40, median_px=0.27))
    text = write_results(load_campaign(DEMO), out, report, tmp_path / "results.md",
                         "0123abc").read_text(encoding="utf-8")
    assert "`0123abc`" in text and "**fail**" in text
    assert "| a | descent tracking median | 0.27 px | <= 0.5 px | pass |" in text
    assert "| b | site \\|log10 ratio\\| | 0.36 | <= 0.2 | fail |" in text
    assert "| b | Hurst exponent | not measured | <= 0.1 | not measured |" in text
    assert "| lunar/run | 12.5 | 16 | 1.28 |" in text
    assert "| asteroid against Eros: slope KS distance | 0.1 |" in text
    assert source_commit(tmp_path) == "unknown"
    assert re.fullmatch(r"[0-9a-f]{40}", source_commit(REPO))


def test_a_folder_with_finished_stages_is_a_campaigns(tmp_path):
    """An output folder a campaign wrote before folders were marked is still taken."""
    from evaluation.campaign import claim_output

    stage = Stage(tmp_path, "lunar/base", {"size": 257})
    stage.begin()
    stage.finish(1.0)
    assert claim_output(tmp_path) == tmp_path.resolve() and stage.done()
