"""Dispersions of a campaign: tables and sampling rules read, checked and drawn; the flown
trajectory offset as a scenario's [dispersion] says."""

import math

import numpy as np
import pytest

from render.camera import Pose
from render.dispersions import Dispersions, case_table, read_dispersions
from render.scenario import Dispersion, parse_scenario
from render.trajectory import Sample
from terrain.core.errors import InvalidParameterError


def test_a_csv_table_gives_one_case_a_row_and_an_empty_cell_keeps_the_scenario(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("seed,sun.elevation,position.z\n1,10,\n2,,-5.5\n")
    d = read_dispersions(path)
    assert d.keys == ("position.z", "seed", "sun.elevation")
    assert d.cases == ({"seed": 1, "sun.elevation": 10.0},
                       {"position.z": -5.5, "seed": 2})
    table = case_table({"sun": {"azimuth": 90.0, "elevation": 3.0}}, d.cases[1], "c")
    assert table["sun"] == {"azimuth": 90.0, "elevation": 3.0} and table["seed"] == 2
    assert table["dispersion"] == {"position": [0.0, 0.0, -5.5]}


@pytest.mark.parametrize("text, fragments", [
    ("seed,sun.elevaton\n1,2\n", ("sun.elevaton", "did you mean 'sun.elevation'")),
    ("sensor.gian\n1\n", ("sensor.gian", "did you mean 'sensor.gain'")),
    ("seed\n1.5\n", ("line 2", "seed")),
    ("seed,sun.azimuth\n1\n", ("line 2", "1 cells")),
    ("seed\n", ("no cases",)),
])
def test_a_bad_csv_is_refused_naming_what_was_wrong(tmp_path, text, fragments):
    path = tmp_path / "d.csv"
    path.write_text(text)
    with pytest.raises(InvalidParameterError) as err:
        read_dispersions(path)
    for fragment in fragments:
        assert fragment in str(err.value)


def test_toml_cases_read_vectors_and_tables_as_their_dotted_keys():
    d = Dispersions.from_mapping({"case": [
        {"position": [1.0, 2.0, 3.0], "sun": {"azimuth": 45.0}},
        {"sensor": {"gain": 4.0}, "attitude.z": 0.5}]})
    assert d.cases[0] == {"position.x": 1.0, "position.y": 2.0, "position.z": 3.0,
                          "sun.azimuth": 45.0}
    assert d.cases[1] == {"attitude.z": 0.5, "sensor.gain": 4.0}
    with pytest.raises(InvalidParameterError, match="did you mean 'velocity.x'"):
        Dispersions.from_mapping({"case": [{"velocity": {"xx": 1.0}}]})


def test_sampled_cases_follow_their_rules_and_do_not_depend_on_the_case_count():
    rules = {"seed": 3, "sample": {"position.x": {"normal": [10.0, 2.0]},
                                   "sun.elevation": {"uniform": [4.0, 6.0]},
                                   "sensor.bits": {"choice": [8, 12]}, "seed": "per-case"}}
    d = Dispersions.from_mapping(dict(rules, cases=4000))
    x = np.array([c["position.x"] for c in d.cases])
    # mean within 4 standard errors, sd within 5 % (4000 draws: its standard error is 1.1 %)
    assert abs(x.mean() - 10.0) < 4 * 2.0 / math.sqrt(4000)
    assert abs(x.std() / 2.0 - 1.0) < 0.05
    el = np.array([c["sun.elevation"] for c in d.cases])
    assert el.min() >= 4.0 and el.max() <= 6.0 and abs(el.mean() - 5.0) < 0.03
    bits = [c["sensor.bits"] for c in d.cases]
    assert set(bits) == {8, 12} and abs(bits.count(8) / 4000 - 0.5) < 0.04
    assert len({c["seed"] for c in d.cases}) == 4000  # every case its own sensor seed
    few = Dispersions.from_mapping(dict(rules, cases=5))
    assert few.cases == d.cases[:5]
    other = Dispersions.from_mapping(dict(rules, cases=5, seed=4))
    assert other.cases != few.cases


@pytest.mark.parametrize("rules, fragment", [
    ({"cases": 2, "sample": {"sun.elevation": {"unifrom": [1, 2]}}}, "did you mean 'uniform'"),
    ({"cases": 2, "sample": {"sun.elevation": {"normal": [1, -2]}}}, "sd must be >= 0"),
    ({"cases": 2, "sample": {"sun.elevation": {"uniform": [3, 2]}}}, "low <= high"),
    ({"cases": 2, "sample": {"seed": "each"}}, "per-case"),
    ({"cases": 0, "sample": {}}, "cases"),
    ({"cases": 2, "seed": 1, "smaple": {}}, "did you mean 'sample'"),
])
def test_bad_rules_are_refused_by_name(rules, fragment):
    with pytest.raises(InvalidParameterError, match=fragment):
        Dispersions.from_mapping(rules)


def test_a_sun_dispersion_needs_a_sun_given_by_angles():
    with pytest.raises(InvalidParameterError, match="gives a direction"):
        case_table({"sun": {"direction": [0.0, 0.0, 1.0]}}, {"sun.elevation": 5.0}, "c")


def _samples():
    poses = [Pose((100.0 * i, 0.0, 1000.0), (0.0, 1.0, 0.0, 0.0)) for i in range(3)]
    return [Sample(2.0 * i, p) for i, p in enumerate(poses)]


def test_the_flown_trajectory_is_shifted_drifts_and_turns_as_dispersed():
    nominal = _samples()
    flown = Dispersion((5.0, -3.0, 1.0), (0.5, 0.0, -1.0), (0.0, 0.0, 2.0)).apply(nominal)
    for s, f in zip(nominal, flown, strict=True):
        dt = s.time - nominal[0].time
        expect = np.add(s.pose.position, [5.0 + 0.5 * dt, -3.0, 1.0 - dt])
        assert np.allclose(f.pose.position, expect) and f.time == s.time
        # the boresight (camera +z) keeps its direction under a turn about itself ...
        assert np.allclose(f.pose.rotation[:, 2], s.pose.rotation[:, 2])
        # ... and the image axes turn by the attitude's 2 degrees
        cos = float(np.dot(f.pose.rotation[:, 0], s.pose.rotation[:, 0]))
        assert math.isclose(math.degrees(math.acos(min(cos, 1.0))), 2.0, rel_tol=1e-9)
    assert Dispersion().apply(nominal) is nominal


def test_a_scenario_dispersion_table_is_checked_by_name():
    base = {"scene": {"type": "terrain", "stack": "s"},
            "trajectory": {"type": "keyframes", "keyframe": [
                {"time": 0.0, "position": [0.0, 0.0, 10.0], "look_at": [0.0, 0.0, 0.0]}]}}
    assert parse_scenario(dict(base, dispersion={"velocity": [1, 2, 3]})).dispersion.velocity \
        == (1.0, 2.0, 3.0)
    with pytest.raises(InvalidParameterError, match="did you mean 'attitude'"):
        parse_scenario(dict(base, dispersion={"atitude": [1, 2, 3]}))


def test_the_example_dispersions_give_every_case_of_the_example_scenario():
    from pathlib import Path

    from render.montecarlo import case_scenarios
    from render.scenario import load_scenario

    examples = Path(__file__).resolve().parents[2] / "examples"
    d = read_dispersions(examples / "descent_dispersions.toml")
    texts = case_scenarios(load_scenario(examples / "lunar_descent.toml"), d)
    assert len(texts) == len(d.cases) == 100
    elevations = [c["sun.elevation"] for c in d.cases]
    assert 3.0 <= min(elevations) and max(elevations) <= 12.0
