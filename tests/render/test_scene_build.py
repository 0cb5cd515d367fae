"""Scenes built from a scenario's [scene.build] recipe where they are missing."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from render.scenario import load_scenario, parse_scenario
from render.scene_build import SceneBuild, ensure_scene, stamp_path
from terrain.cli.commands import main
from terrain.core.errors import InvalidParameterError
from terrain.io import read_dem

REPO = Path(__file__).resolve().parents[2]

BASE = {"size": 65, "resolution": 20.0, "relief": 30.0, "dmin": 40.0, "dmax": 200.0,
        "density": 20.0}
STACK = {"site": [650.0, 650.0], "levels": 2, "dmin": 5.0, "dmax": 40.0, "density": 500.0}


def toml_value(v) -> str:
    return json.dumps(v)  # numbers, strings and lists of numbers are the same in TOML


def terrain_scenario(folder: Path, *, stack="scene/stack", base=None, extra_base="") -> Path:
    base = BASE if base is None else base
    lines = ['name = "built"', "seed = 3", "[scene]", 'type = "terrain"', f'stack = "{stack}"',
             "[scene.build]", "seed = 11", "[scene.build.base]"]
    lines += [f"{k} = {toml_value(v)}" for k, v in base.items()] + [extra_base]
    lines += ["[scene.build.stack]"] + [f"{k} = {toml_value(v)}" for k, v in STACK.items()]
    lines += ["[camera]", "width = 32", "height = 32", "[render]", "shadows = false",
              "[trajectory]", 'type = "descent"', "frames = 2", "start_altitude = 400.0",
              "end_altitude = 100.0"]
    path = folder / "scenario.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def layers(stack: Path) -> list[bytes]:
    return [read_dem(p).heights.tobytes() for p in sorted(stack.glob("layer_*.tif"))]


def test_a_missing_stack_is_built_as_its_commands_would_build_it(tmp_path, caplog):
    scenario = load_scenario(terrain_scenario(tmp_path))
    with caplog.at_level(logging.INFO, logger="render.scene_build"):
        built = ensure_scene(scenario)
    assert built == tmp_path / "scene" / "stack"
    assert "building it from the scenario's [scene.build] recipe" in caplog.text
    # the independent reference: the same two commands typed by hand
    runner = CliRunner()
    ref = tmp_path / "ref"
    flags = [a for k, v in BASE.items() for a in (f"--{k.replace('_', '-')}", str(v))]
    r = runner.invoke(main, ["terrain", "synth", "-o", str(tmp_path / "base.tif"), *flags,
                             "--seed", "11"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(main, ["terrain", "enhance", str(tmp_path / "base.tif"), "-o", str(ref),
                             "--site", "650,650", "--levels", "2", "--dmin", "5", "--dmax", "40",
                             "--density", "500", "--seed", "11", "--layer-size", "65"])
    assert r.exit_code == 0, r.output
    assert layers(built) == layers(ref) and len(layers(ref)) == 3
    assert (tmp_path / "scene" / "stack.base.tif").exists()
    stamp = json.loads(stamp_path(built).read_text())
    assert stamp["key"] == scenario.scene.build.key(tmp_path)
    assert stamp["recipe"]["stack"]["levels"] == 2


def test_a_built_scene_is_reused_and_rebuilt_when_its_recipe_changes(tmp_path, caplog):
    path = terrain_scenario(tmp_path)
    built = ensure_scene(load_scenario(path))
    manifest = built / "manifest.json"
    before = manifest.stat().st_mtime_ns, layers(built)
    with caplog.at_level(logging.INFO, logger="render.scene_build"):
        ensure_scene(load_scenario(path))
    assert "reused" in caplog.text and manifest.stat().st_mtime_ns == before[0]
    # another relief: another recipe, so another scene where the old one was
    path = terrain_scenario(tmp_path, base={**BASE, "relief": 60.0})
    with caplog.at_level(logging.INFO, logger="render.scene_build"):
        ensure_scene(load_scenario(path))
    assert "built from another recipe" in caplog.text
    after = layers(built)
    assert len(after) == len(before[1]) and after[0] != before[1][0]
    assert json.loads(stamp_path(built).read_text())["recipe"]["base"]["relief"] == 60.0


def test_a_scene_made_otherwise_is_used_as_it_is(tmp_path):
    stack = tmp_path / "scene" / "stack"
    stack.mkdir(parents=True)
    (stack / "manifest.json").write_text("{}")
    assert ensure_scene(load_scenario(terrain_scenario(tmp_path))) == stack
    assert [p.name for p in stack.iterdir()] == ["manifest.json"]
    assert not stamp_path(stack).exists()


def test_a_scenario_without_a_recipe_builds_nothing(tmp_path):
    s = parse_scenario({"scene": {"type": "terrain", "stack": "nowhere"},
                        "trajectory": {"type": "descent", "start_altitude": 9.0,
                                       "end_altitude": 1.0}}, tmp_path / "s.toml")
    assert ensure_scene(s) is None and not (tmp_path / "nowhere").exists()


@pytest.mark.parametrize("build, words", [
    ({"seed": 1, "base": {"sise": 65}, "stack": {"site": [1, 2]}}, ["sise", "'size'"]),
    ({"base": {"size": "big"}, "stack": {"site": [1, 2]}}, ["[scene.build.base]", "size",
                                                           "big"]),
    ({"base": {"size": 65}, "stack": {"levels": 2}}, ["site", "site_lonlat"]),
    ({"base": {"size": 65}, "stack": {"site": [1, 2]}, "body": {}}, ["'body'"]),
    ({"base": {"output": "x.tif"}, "stack": {"site": [1, 2]}}, ["'output'"]),
    ({"base": {"no_roughness": 1}, "stack": {"site": [1, 2]}}, ["true or false",
                                                               "no_roughness"]),
    ({"base": {"size": 64}, "stack": {"site": [1, 2], "levels": 2}}, ["2^n + 1"]),
    ({"base": {"size": 65}, "stack": {"site": [1, 2]}}, ["levels", "finest_resolution"]),
    ({"base": {"size": 65}, "stack": {"site": [1, 2], "levels": 1, "dmin": "x"}},
     ["[scene.build.stack]", "dmin"]),
    ({"stack": {"site": [1, 2]}}, ["[scene.build.base]"]),
    ({"seed": -1, "base": {}, "stack": {"site": [1, 2]}}, ["seed"]),
])
def test_a_bad_terrain_recipe_is_refused_when_parsed(build, words):
    with pytest.raises(InvalidParameterError) as err:
        SceneBuild.from_mapping(build, "terrain")
    assert all(w in str(err.value) for w in words), str(err.value)


def test_an_asteroid_recipe_takes_the_build_options_and_resolves_its_paths(tmp_path):
    with pytest.raises(InvalidParameterError, match="'magnitude'"):
        SceneBuild.from_mapping({"body": {"magnitud": 8}}, "asteroid")
    with pytest.raises(InvalidParameterError, match="seed"):
        SceneBuild.from_mapping({"seed": 3, "body": {}}, "asteroid")
    recipe = SceneBuild.from_mapping({"body": {"config": "r.toml", "magnitude": 8}}, "asteroid")
    # the recipe file is read from the scenario's folder, and the table's keys override it
    (tmp_path / "r.toml").write_text('magnitude = 4\nradius = 100.0\nbase = "perlin"\n')
    body = recipe.recipe(tmp_path)
    assert (body.magnitude, body.radius, body.base) == (8, 100.0, "perlin")
    # the key follows the recipe file's contents, not just its name
    first = recipe.key(tmp_path)
    (tmp_path / "r.toml").write_text('magnitude = 4\nradius = 200.0\nbase = "perlin"\n')
    assert recipe.key(tmp_path) != first


def test_render_frame_builds_the_missing_body_then_renders(tmp_path, gl):
    recipe = tmp_path / "tiny.toml"
    recipe.write_text('magnitude = 8\nradius = 500.0\nseed = 4\nbase = "perlin"\n',
                      encoding="utf-8")
    scenario = tmp_path / "approach.toml"
    scenario.write_text("\n".join([
        "[scene]", 'type = "asteroid"', 'body = "bodies/tiny.npz"', "boulders = false",
        "[scene.build.body]", 'config = "tiny.toml"', "[camera]", "width = 48", "height = 48",
        "[render]", "shadows = false", "[trajectory]", 'type = "approach"', "frames = 2",
        "start_distance = 3000.0", "end_distance = 2000.0"]) + "\n", encoding="utf-8")
    r = CliRunner().invoke(main, ["render", "frame", str(scenario), "-o",
                                  str(tmp_path / "one.png")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "bodies" / "tiny.npz").exists()
    assert (tmp_path / "bodies" / "tiny.npz.build.json").exists()
    from PIL import Image

    image = np.asarray(Image.open(tmp_path / "one.png"))
    assert image.shape == (48, 48) and image.max() > 0  # the body is in view and lit


def test_the_example_scenarios_build_make_demos_scenes():
    """The recipes in examples/ are the reduced demo campaign's own tables (so a scene the
    scenario builds is the one `make demo DEMO_ARGS=--quick` builds)."""
    from evaluation.campaign import load_campaign

    campaign = load_campaign(REPO / "examples" / "demo.toml", quick=True)
    for name in ("lunar_descent.toml", "lunar_descent_camera.toml"):
        recipe = load_scenario(REPO / "examples" / name).scene.build
        assert recipe is not None and recipe.seed == campaign.seed
        assert recipe.base == dict(campaign.base)
        assert {k: v for k, v in recipe.stack.items() if k != "site"} == dict(campaign.stack)
    recipe = load_scenario(REPO / "examples" / "asteroid_approach.toml").scene.build
    assert recipe is not None
    assert str(REPO / "examples" / recipe.body["config"]) == campaign.body["config"]
    assert recipe.body["magnitude"] == campaign.body["magnitude"]


@pytest.mark.slow
def test_the_example_site_is_the_one_the_demo_chooses(tmp_path):
    """The lunar recipes' site is where the campaign lands on that base (its flattest spot)."""
    from evaluation.slope import horn_slope
    from terrain.stages.runner import run
    from terrain.surface.site import landing_site

    recipe = load_scenario(REPO / "examples" / "lunar_descent.toml").scene.build
    assert recipe is not None
    run(recipe.terrain(tmp_path)[0], None, tmp_path / "base.tif")
    tile = read_dem(tmp_path / "base.tif")
    assert landing_site(tile, horn_slope(tile)) == tuple(recipe.stack["site"])


def test_a_build_that_did_not_finish_is_done_again(tmp_path):
    path = terrain_scenario(tmp_path)
    built = ensure_scene(load_scenario(path))
    reference = layers(built)
    # a build killed after enhance began: a partial folder, a stamp still saying "building"
    for p in sorted(built.glob("layer_*.tif"))[1:]:
        p.unlink()
    stamp = stamp_path(built)
    stamp.write_text(json.dumps({"key": json.loads(stamp.read_text())["key"],
                                 "building": True}))
    ensure_scene(load_scenario(path))
    assert layers(built) == reference
    assert "building" not in json.loads(stamp.read_text())


@pytest.mark.parametrize("scene", [
    {"type": "terrain", "stack": ""}, {"type": "terrain", "stack": "/"},
    {"type": "terrain", "stack": "."}, {"type": "terrain", "stack": "scenes/.."},
    {"type": "asteroid", "body": ""}, {"type": "asteroid", "body": "/"},
])
def test_a_scene_must_name_a_file_or_folder(tmp_path, scene):
    kind = scene["type"]
    build = ({"base": dict(BASE), "stack": dict(STACK)} if kind == "terrain"
             else {"body": {"magnitude": 8}})
    trajectory = ({"type": "descent", "start_altitude": 9.0, "end_altitude": 1.0}
                  if kind == "terrain" else
                  {"type": "approach", "start_distance": 3000.0, "end_distance": 2000.0})
    key = "stack" if kind == "terrain" else "body"
    for data in ({"scene": scene}, {"scene": {**scene, "build": build}}):
        with pytest.raises(InvalidParameterError, match=rf"scenario \[scene\] {key} must name"):
            parse_scenario({**data, "trajectory": trajectory}, tmp_path / "s.toml")


def test_two_first_runs_build_the_scene_once(tmp_path):
    """Two runs of one scenario started together: one builds, the other waits and uses it."""
    import os
    import subprocess
    import sys

    path = terrain_scenario(tmp_path)
    code = ("import logging; logging.basicConfig(level=logging.WARNING); "
            "from render.scenario import load_scenario; "
            "from render.scene_build import ensure_scene; "
            f"print(ensure_scene(load_scenario({str(path)!r})))")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    runs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [(p.returncode, *p.communicate(timeout=300)) for p in runs]
    results = [(p.returncode, out, err) for p, (_, out, err) in zip(runs, results, strict=True)]
    for rc, out, err in results:
        assert rc == 0, err
        assert out.strip() == str(tmp_path / "scene" / "stack")
    built = [err for _, _, err in results if "is missing: building it" in err]
    assert len(built) == 1, [err for _, _, err in results]
    scenario = load_scenario(path)
    assert json.loads(stamp_path(tmp_path / "scene" / "stack").read_text())["key"] == \
        scenario.scene.build.key(tmp_path)
    assert len(layers(tmp_path / "scene" / "stack")) == 3


def test_a_base_without_craters_builds(tmp_path):
    base = {k: v for k, v in BASE.items() if k not in ("dmin", "dmax", "density")}
    built = ensure_scene(load_scenario(terrain_scenario(tmp_path, base=base)))
    assert len(layers(built)) == 3
    assert not (tmp_path / "scene" / "stack.base_craters.csv").exists()


def test_a_recipe_refused_when_parsed_leaves_nothing(tmp_path):
    """A stack table the enhance stage would refuse stops the scenario before the base is
    made: no base, no stamp, no folder."""
    path = terrain_scenario(tmp_path)
    text = path.read_text().replace("levels = 2", "levels = 2\nfinest_resolution = 0.5")
    path.write_text(text)
    with pytest.raises(InvalidParameterError, match="levels"):
        ensure_scene(load_scenario(path))
    assert not (tmp_path / "scene").exists()
