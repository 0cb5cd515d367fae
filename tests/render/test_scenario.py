"""Scenario records: [scene] and [trajectory] are frozen, validated, and round-trip."""

import dataclasses
from pathlib import Path

import pytest

from render.scenario import (
    NOT_BINARY_KEYS,
    SCENE_KEYS,
    TRAJECTORY_KEYS,
    SceneSpec,
    TrajectorySpec,
    load_scenario,
)
from terrain.core.errors import InvalidParameterError

#: The example files that are scenarios (the others are recipes and populations).
EXAMPLES = [p for p in sorted((Path(__file__).resolve().parents[2] / "examples").glob("*.toml"))
            if "[trajectory]" in p.read_text(encoding="utf-8")]


def _table(record) -> dict:
    """A record back as the TOML table it came from (lists, no unset keys)."""
    out = {}
    for key in (f.name for f in dataclasses.fields(record)):
        value = getattr(record, key)
        if value is None or key == "albedo_map":
            continue
        if key == "build":  # [scene.build], the scene's recipe
            out[key] = value.to_mapping()
            continue
        if hasattr(value, "as_dict"):  # a binary's [scene.orbit] and [scene.*_spin]
            out[key] = value.as_dict()
            continue
        if isinstance(value, tuple):
            value = [dict(v) if isinstance(v, dict) else v for v in value]
        out[key] = value
    if out.get("type") == "binary":  # the single-body fields' defaults are not its keys
        out = {k: v for k, v in out.items() if k not in NOT_BINARY_KEYS}
    return out


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_example_scenarios_round_trip_through_their_tables(path):
    scenario = load_scenario(path)
    assert SceneSpec.from_mapping(_table(scenario.scene)) == dataclasses.replace(
        scenario.scene, albedo_map=None)
    assert TrajectorySpec.from_mapping(_table(scenario.trajectory)) == scenario.trajectory


@pytest.mark.parametrize("spec, keys, table", [
    (SceneSpec, SCENE_KEYS, {"type": "terrain", "stack": "s"}),
    (TrajectorySpec, TRAJECTORY_KEYS, {"type": "approach", "start_distance": 9.0,
                                       "end_distance": 5.0}),
])
def test_a_misspelt_key_is_named_with_the_nearest_valid_one(spec, keys, table):
    for key in sorted(keys - {"type"}):
        wrong = key[:-1] + ("x" if key[-1] != "x" else "y")
        with pytest.raises(InvalidParameterError) as err:
            spec.from_mapping({**table, wrong: 1})
        assert wrong in str(err.value) and f"did you mean {key!r}" in str(err.value)


def test_records_are_frozen():
    scene = SceneSpec.from_mapping({"type": "asteroid", "body": "b.npz"})
    with pytest.raises(dataclasses.FrozenInstanceError):
        scene.boulders = False
    traj = TrajectorySpec.from_mapping({"type": "keyframes", "frames": 2, "keyframe": [
        {"time": 0.0, "position": [0.0, 0.0, 10.0], "look_at": [0.0, 0.0, 0.0]}]})
    with pytest.raises(dataclasses.FrozenInstanceError):
        traj.frames = 3


@pytest.mark.parametrize("table, message", [
    ({"type": "cube"}, "type must be 'terrain' or 'asteroid'"),
    ({"type": "terrain"}, "needs 'stack'"),
    ({"type": "asteroid", "body": "b", "spin_axis": [0, 1]}, "spin_axis"),
    ({"type": "asteroid", "body": "b", "imposter_pixels": -1}, "imposter_pixels"),
])
def test_bad_scene_tables_are_refused_by_field(table, message):
    with pytest.raises(InvalidParameterError, match=message):
        SceneSpec.from_mapping(table)


@pytest.mark.parametrize("bits", [8.7, 12.0, "8", True, 0, 17])
def test_a_sensor_bit_depth_must_be_a_toml_integer_in_range(tmp_path, bits):
    # like every integer key of a scenario, 12.0 is refused too: TOML writes integers bare
    text = (Path(__file__).parents[2] / "examples" / "lunar_descent.toml").read_text()
    assert "\nbits = 8\n" in text
    value = repr(bits).lower() if not isinstance(bits, str) else f'"{bits}"'
    path = tmp_path / "s.toml"
    path.write_text(text.replace("\nbits = 8\n", f"\nbits = {value}\n"))
    with pytest.raises(InvalidParameterError, match="sensor bits must be an integer"):
        load_scenario(path)
