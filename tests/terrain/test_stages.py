"""terrain.stages: a Python caller's spec + run gives the command line's bytes, every command,
in memory and out of core; specs are closed, typed tables whose fields are the options."""

import dataclasses
import logging
import math
import re
from pathlib import Path

import numpy as np
import pytest

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.fractal.synthetic import synthesize_tile
from terrain.io import lonlat_to_xy, read_dem, write_dem
from terrain.stages import specs
from terrain.stages.runner import Execution, run
from tests.cli_helpers import one_line_error, snapshot
from tests.cli_helpers import run as cli

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def dem(tmp_path_factory):
    path = tmp_path_factory.mktemp("stages") / "dem.tif"
    write_dem(synthesize_tile(65, resolution=2.0, relief=20.0, seed=1).tile, path)
    return path


@pytest.fixture(scope="module")
def gappy(tmp_path_factory):
    tile = synthesize_tile(65, resolution=2.0, relief=20.0, seed=2).tile
    rows, cols = np.mgrid[:65, :65]
    valid = np.hypot(rows - 30, cols - 34) > 6
    path = tmp_path_factory.mktemp("stages") / "gappy.tif"
    write_dem(DEMTile(np.where(valid, tile.heights, np.nan).astype(np.float32), valid,
                      tile.transform, tile.crs, -9999.0, {}), path)
    return path


def arguments(table):
    """The command line of a spec table: ``--key value``, a bare flag, a list joined by ','."""
    out = []
    for key, value in table.items():
        flag = "--" + key.replace("_", "-")
        if value is True:
            out.append(flag)
        elif isinstance(value, (list, tuple)):
            out += [flag, ",".join(str(v) for v in value)]
        else:
            out += [flag, value]
    return out


def files(folder):
    """Bytes of every file under ``folder``, by path relative to it."""
    return {p.relative_to(folder): b for p, b in snapshot(folder).items()}


# (command, spec, table, input fixture, output name, with a catalogue)
COMMANDS = [
    ("synth", specs.SynthSpec, {"size": 65, "relief": 5.0, "seed": 3, "density": 400.0,
                                "dmax": 20.0}, None, "out.tif", True),
    ("craters", specs.CratersSpec, {"density": 500.0, "dmax": 20.0, "seed": 2}, "dem",
     "out.tif", True),
    ("add-crater", specs.AddCraterSpec, {"at": [60.0, 70.0], "diameter": 24.0, "age": 0.1},
     "dem", "out.tif", True),
    ("hillshade", specs.HillshadeSpec, {"altitude": 30.0, "z_factor": 2.0}, "dem", "out.png",
     False),
    ("expand", specs.ExpandSpec, {"times": 2, "seed": 4, "uniform_roughness": True}, "dem",
     "out.tif", False),
    ("fill", specs.FillSpec, {"seed": 5}, "gappy", "out.tif", False),
    ("enhance", specs.EnhanceSpec, {"levels": 2, "layer_size": 33, "density": 300.0,
                                    "rocks": "golombek-rapp-mars:k=0.05"}, "dem", "stack", False),
    ("rocks", specs.RocksSpec, {"terrain": "maria", "seed": 6}, "dem", "out.tif", True),
    ("hazards", specs.HazardsSpec, {"lander_diameter": 8.0, "max_slope": 10.0,
                                    "max_step": 0.5}, "dem", "out.tif", False),
]


@pytest.mark.parametrize("command, spec, table, source, name, catalog", COMMANDS,
                         ids=[c[0] for c in COMMANDS])
def test_python_and_command_line_write_the_same_bytes(request, tmp_path, command, spec,
                                                      table, source, name, catalog):
    source = None if source is None else request.getfixturevalue(source)
    (tmp_path / "cli").mkdir()
    (tmp_path / "py").mkdir()
    args = [] if source is None else [source]
    extra = ["--catalog", tmp_path / "cli" / "cat.csv"] if catalog else []
    result = cli("terrain", command, *args, "-o", tmp_path / "cli" / name, *extra,
                 *arguments(table))
    assert result.exit_code == 0, result.output
    written = run(spec.from_mapping(table), source, tmp_path / "py" / name,
                  catalog=tmp_path / "py" / "cat.csv" if catalog else None)
    assert written.message.startswith("wrote")
    assert all(p.exists() for p in written.paths)
    cli_files, py_files = files(tmp_path / "cli"), files(tmp_path / "py")
    assert len(py_files) >= 1 + catalog
    assert cli_files == py_files


# requests larger than the memory limit: (command, spec, table, input, limit)
TOO_LARGE = [
    ("synth", specs.SynthSpec, {"size": 129, "seed": 8, "density": 300.0}, None, "500K"),
    ("craters", specs.CratersSpec, {"density": 500.0, "dmax": 20.0}, "dem", "150K"),
    ("expand", specs.ExpandSpec, {"times": 2, "seed": 4}, "dem", "500K"),
    ("fill", specs.FillSpec, {"seed": 5}, "gappy", "150K"),
]


@pytest.mark.parametrize("command, spec, table, source, limit", TOO_LARGE,
                         ids=[c[0] for c in TOO_LARGE])
def test_a_request_larger_than_memory_runs_out_of_core_from_python_as_from_the_cli(
        request, tmp_path, monkeypatch, caplog, command, spec, table, source, limit):
    source = None if source is None else request.getfixturevalue(source)
    args = [] if source is None else [source]
    in_memory = run(spec.from_mapping(table), source, tmp_path / "memory.tif").paths[0]
    monkeypatch.setenv("CRATERSCAPE_MEMORY_LIMIT", limit)
    with caplog.at_level(logging.WARNING):
        run(spec.from_mapping(table), source, tmp_path / "py.tif")
    assert "do not fit in memory" in caplog.text  # no MemoryRequestError: out of core
    result = cli("terrain", command, *args, "-o", tmp_path / "cli.tif", *arguments(table))
    assert result.exit_code == 0, result.output
    assert "do not fit in memory" in result.output
    monkeypatch.delenv("CRATERSCAPE_MEMORY_LIMIT")
    assert (tmp_path / "py.tif").read_bytes() == (tmp_path / "cli.tif").read_bytes()
    ooc, single = read_dem(tmp_path / "py.tif"), read_dem(in_memory)
    assert ooc.transform == single.transform and ooc.crs == single.crs
    assert np.array_equal(ooc.heights, single.heights, equal_nan=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cli.tif", "memory.tif", "py.tif"]


def test_a_chunked_execution_from_python_equals_the_command_line(tmp_path, dem):
    table = {"times": 1, "seed": 3}
    result = cli("terrain", "expand", dem, "-o", tmp_path / "cli.zarr", "--chunk", 48,
                 "--threads", "--workers", 1, "--cog", tmp_path / "cli.tif", *arguments(table))
    assert result.exit_code == 0, result.output
    run(specs.ExpandSpec.from_mapping(table), dem, tmp_path / "py.zarr",
        Execution.from_mapping({"chunk": 48, "threads": True, "workers": 1,
                                "cog": tmp_path / "py.tif"}))
    assert (tmp_path / "py.tif").read_bytes() == (tmp_path / "cli.tif").read_bytes()


# ---------------------------------------------------------------- specs are closed and typed


@pytest.mark.parametrize("spec, table, fragment", [
    (specs.SynthSpec, {"fractal_dimenson": 2.3}, "did you mean 'fractal_dimension'"),
    (specs.EnhanceSpec, {"levels": 1, "layersize": 33}, "did you mean 'layer_size'"),
    (specs.RocksSpec, {"dnsity": 1}, "unknown terrain rocks key 'dnsity'"),
    (specs.SynthSpec, {"size": "65"}, "size must be an integer"),
    (specs.SynthSpec, {"relief": float("nan")}, "relief must be finite"),
    (specs.SynthSpec, {"no_roughness": "yes"}, "true or false"),
    (specs.ExpandSpec, {"times": 17}, "times must lie in [1, 16]"),
    (specs.RocksSpec, {"model": "golombek"}, "did you mean 'golombek-rapp-mars'"),
    (specs.HazardsSpec, {"lander_diameter": 3.0, "max_slope": 10.0}, "needs max_step"),
    (specs.EnhanceSpec, {}, "exactly one of levels and finest_resolution"),
    (specs.CratersSpec, {}, "give density"),
])
def test_spec_tables_are_closed_and_typed(spec, table, fragment):
    with pytest.raises(InvalidParameterError, match=re.escape(fragment)):
        spec.from_mapping(table)


def test_a_spec_is_frozen_and_its_fields_are_the_commands_options():
    from terrain.cli.commands import terrain

    spec = specs.SynthSpec.from_mapping({"size": 33})
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.size = 65
    where = {"output", "catalog", "workers", "threads", "scheduler", "chunk", "cog", "help"}
    for name, cls, *_ in COMMANDS:
        options = {o[2:].replace("-", "_") for p in terrain.commands[name].params
                   for o in getattr(p, "opts", ()) if o.startswith("--")}
        assert options - where == {f.name for f in dataclasses.fields(cls)}, name


# ---------------------------------------------------------------- defaults a newcomer expects


def test_synth_is_on_the_moon_by_default_and_a_local_grid_on_request(tmp_path):
    moon, local = tmp_path / "moon.tif", tmp_path / "local.tif"
    run(specs.SynthSpec.from_mapping({"size": 33, "resolution": 10.0}), None, moon)
    assert cli("terrain", "synth", "--size", 33, "--resolution", 10.0, "--local-grid",
               "-o", local).exit_code == 0
    a, b = read_dem(moon), read_dem(local)
    assert b.crs is None and a.crs is not None
    centre = a.transform @ (16.5, 16.5)
    assert np.allclose(lonlat_to_xy(a.crs, 0.0, -90.0), centre, atol=1e-6)  # the south pole
    assert np.array_equal(a.heights, b.heights) and a.transform == b.transform


def test_enhance_without_a_site_centres_the_stack_on_the_dem(tmp_path, dem):
    import json

    table = {"levels": 1, "layer_size": 17}
    run(specs.EnhanceSpec.from_mapping(table), dem, tmp_path / "auto")
    tile = read_dem(dem)
    left, bottom, right, top = tile.bounds
    centre = ((left + right) / 2, (bottom + top) / 2)
    run(specs.EnhanceSpec.from_mapping({**table, "site": centre}), dem, tmp_path / "given")
    assert files(tmp_path / "auto") == files(tmp_path / "given")
    finest = read_dem(sorted((tmp_path / "auto").glob("layer_01*"))[0])
    l1, b1, r1, t1 = finest.bounds
    assert math.isclose((l1 + r1) / 2, centre[0], abs_tol=tile.resolution)
    assert math.isclose((b1 + t1) / 2, centre[1], abs_tol=tile.resolution)
    assert json.loads((tmp_path / "auto" / "manifest.json").read_text())


# ---------------------------------------------------------------- bad input: one line, exit 2


def test_hazards_into_a_png_name_is_told_to_write_a_geotiff(tmp_path, dem):
    r = cli("terrain", "hazards", dem, "-o", tmp_path / "x.png", "--lander-diameter", 4,
            "--max-slope", 10, "--max-step", 0.3)
    one_line_error(r, "GeoTIFF", ".tif")
    assert "same file" not in r.output and not (tmp_path / "x.png").exists()


def test_rocks_with_a_binary_crater_file_is_one_line(tmp_path, dem):
    binary = tmp_path / "craters.csv"
    binary.write_bytes(bytes(range(256)) * 4)
    r = cli("terrain", "rocks", dem, "-o", tmp_path / "r.tif", "--k", 0.05, "--craters", binary)
    one_line_error(r, "craters.csv", "not a CSV text file")
    assert not (tmp_path / "r.tif").exists()


def test_run_refuses_what_a_stage_does_not_take(tmp_path, dem):
    with pytest.raises(InvalidParameterError, match="takes one input"):
        run(specs.ExpandSpec.from_mapping({}), None, tmp_path / "x.tif")
    with pytest.raises(InvalidParameterError, match="writes no separate catalogue"):
        run(specs.ExpandSpec.from_mapping({}), dem, tmp_path / "x.tif", catalog="c.csv")
    with pytest.raises(InvalidParameterError, match="unknown terrain execution key 'worker'"):
        Execution.from_mapping({"worker": 2})


# ---------------------------------------------------------------- thin commands


def test_the_command_line_is_thin():
    sources = {p: p.read_text() for p in (ROOT / "terrain").rglob("*.py")}
    assert not [p for p, text in sources.items() if "**locals()" in text]
    cli_lines = sum(text.count("\n") for p, text in sources.items() if p.parent.name == "cli")
    assert cli_lines < 700, cli_lines
