"""Nested multi-resolution layer stacks: agreement between layers, crater sorting, edits."""

import json
import math
import multiprocessing
import os

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from terrain.core.errors import InvalidDEMError, InvalidParameterError, MemoryRequestError
from terrain.craters.cratering import CraterModel
from terrain.craters.population import Population
from terrain.fractal.synthetic import synthesize_tile
from terrain.stack.build import build_stack
from terrain.stack.edit import replace_crater
from terrain.stack.model import Layer, LayerStack
from terrain.stack.plan import MIN_CRATER_PIXELS
from terrain.stack.store import read_stack, write_stack

POP = Population(dmin=1.0, dmax=40000.0, density=1e5, max_age=2.0)


def base():
    tile = synthesize_tile(129, resolution=1000.0, relief=2500.0, seed=1).tile
    h = tile.heights.copy()
    h[20:26, 30:40] = np.nan  # a gap in the base
    return tile.replace(heights=h)


SITE = (70500.0, 60500.0)


@pytest.fixture(scope="module")
def stack():
    return build_stack(base(), SITE, levels=5, layer_size=129, seed=7, population=POP)


def test_layers_nest_around_the_site_and_halve_the_resolution(stack):
    assert len(stack.tiles) == 6
    for k, tile in enumerate(stack.tiles):
        assert tile.resolution == pytest.approx(1000.0 / 2**k)
        left, bottom, right, top = tile.bounds
        assert left <= SITE[0] <= right and bottom <= SITE[1] <= top
        assert tile.valid.all()
        if k:
            assert tile.shape == (129, 129)
            pl, pb, pr, pt = stack.tiles[k - 1].bounds
            assert pl <= left and right <= pr and pb <= bottom and top <= pt


def test_a_coarse_pixel_equals_the_co_located_fine_pixel(stack):
    for k in range(1, len(stack.tiles)):
        col, row, size, _ = stack.windows[k]
        coarse = stack.tiles[k - 1].heights[row:row + size, col:col + size]
        assert np.array_equal(coarse, stack.tiles[k].heights[::2, ::2])
        # and they are the same places on the ground
        assert stack.tiles[k].xy(0, 0) == stack.tiles[k - 1].xy(row, col)


def test_known_base_heights_survive_where_no_crater_or_finer_layer_reaches(stack):
    original = base()
    assert stack.info["base_filled_pixels"] == 60
    col, row, size, _ = stack.windows[1]
    untouched = original.valid.copy()
    untouched[row:row + size, col:col + size] = False
    rows, cols = np.mgrid[0:original.shape[0], 0:original.shape[1]]
    x, y = original.xy(rows, cols)
    cat = stack.catalog
    factor = CraterModel().footprint_factor
    for cx, cy, d in zip(cat.x_m[cat.layer == 0], cat.y_m[cat.layer == 0],
                         cat.diameter_m[cat.layer == 0], strict=True):
        untouched &= np.hypot(x - cx, y - cy) > d * factor + 1000.0
    assert untouched.sum() > 100
    assert np.array_equal(stack.tiles[0].heights[untouched], original.heights[untouched])


def test_each_crater_sits_in_the_finest_layer_that_holds_it(stack):
    cat = stack.catalog
    assert len(cat.id) > 100
    assert len(np.unique(cat.id)) == len(cat.id)
    factor = CraterModel().footprint_factor
    for x, y, d, k in zip(cat.x_m, cat.y_m, cat.diameter_m, cat.layer,
                          strict=True):
        tile = stack.tiles[k]
        assert d >= MIN_CRATER_PIXELS * tile.resolution
        assert stack.layer_of(x, y, d * factor) >= k
        if k + 1 < len(stack.tiles):
            finer = stack.tiles[k + 1]
            fits = stack.layer_of(x, y, d * factor) > k
            assert not (fits and d >= MIN_CRATER_PIXELS * finer.resolution)


def test_write_read_roundtrip_and_manifest(stack, tmp_path):
    out = write_stack(stack, tmp_path / "stack")
    manifest = json.loads((out / "manifest.json").read_text())
    assert [entry["level"] for entry in manifest["layers"]] == list(range(6))
    assert manifest["layers"][3]["parent"] == 2
    assert manifest["layers"][0]["resolution"] == 1000.0
    assert sum(manifest["crater_counts"]) == len(stack.catalog.id)
    again = read_stack(out)
    for a, b in zip(again.tiles, stack.tiles, strict=True):
        assert np.array_equal(a.heights, b.heights)
        assert a.transform == b.transform
    assert np.array_equal(again.catalog.layer, stack.catalog.layer)
    assert again.windows == stack.windows and again.origins == stack.origins
    assert [layer.file for layer in again.layers] == [e["file"] for e in manifest["layers"]]
    assert all((out / layer.file).is_file() for layer in again.layers)
    with pytest.raises(InvalidParameterError, match="not empty"):
        write_stack(stack, out)


def test_a_stack_is_frozen_and_checks_its_layers(stack):
    import dataclasses

    with pytest.raises(dataclasses.FrozenInstanceError):
        stack.catalog = {}
    with pytest.raises(dataclasses.FrozenInstanceError):
        stack.layers[0].tile = stack.tiles[1]
    base_layer, fine = stack.layers[0], stack.layers[1]
    with pytest.raises(InvalidParameterError, match="window"):
        LayerStack((base_layer, Layer(fine.tile, None, fine.origin)), stack.catalog)
    with pytest.raises(InvalidParameterError, match="base layer"):
        LayerStack((fine,), stack.catalog)
    with pytest.raises(InvalidParameterError, match="window must be 4 integers"):
        Layer(fine.tile, (1, 2, 3), fine.origin)
    edited = stack.with_info(note="x")
    assert edited.info["note"] == "x" and "note" not in stack.info


def test_same_seed_same_stack():
    a = build_stack(base(), SITE, levels=2, layer_size=65, seed=3, population=POP)
    b = build_stack(base(), SITE, levels=2, layer_size=65, seed=3, population=POP)
    for ta, tb in zip(a.tiles, b.tiles, strict=True):
        assert ta.heights.tobytes() == tb.heights.tobytes()


def test_replace_crater_edits_in_place_and_layers_still_match(stack, tmp_path):
    out = write_stack(stack, tmp_path / "stack")
    x, y = stack.tiles[3].xy(40, 64)
    diameter = 3000.0
    before = read_stack(out)
    done = replace_crater(out, float(x), float(y), diameter, age=0.0)
    after = read_stack(out)
    k = done["layer"]
    reach = diameter * CraterModel().footprint_factor
    assert k == before.layer_of(float(x), float(y), reach) == 3
    assert done["changed_layers"] == [0, 1, 2, 3, 4, 5]  # coarser and overlapping finer
    assert not np.array_equal(after.tiles[k].heights, before.tiles[k].heights)
    for j in range(1, len(after.tiles)):
        col, row, size, _ = after.windows[j]
        assert np.array_equal(after.tiles[j - 1].heights[row:row + size, col:col + size],
                              after.tiles[j].heights[::2, ::2])
    # a sharp bowl at the site
    r, c = after.tiles[k].rowcol(x, y)
    assert after.tiles[k].heights[int(r), int(c)] < before.tiles[k].heights[int(r), int(c)] - 50
    assert diameter in set(after.catalog.diameter_m.tolist())
    files = sorted(p.name for p in out.iterdir() if p.suffix == ".tif")
    assert len(files) == 6, "old versions of edited layers are removed"


def _edit(path, x, y):
    replace_crater(path, x, y, 300.0)


def test_two_edits_at_once_do_not_corrupt_the_stack(stack, tmp_path):
    out = write_stack(stack, tmp_path / "stack")
    x1, y1 = stack.tiles[4].xy(40, 40)
    x2, y2 = stack.tiles[4].xy(90, 90)
    ctx = multiprocessing.get_context("fork")
    procs = [ctx.Process(target=_edit, args=(out, float(x), float(y)))
             for x, y in ((x1, y1), (x2, y2))]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    final = read_stack(out)
    assert len(final.info["edits"]) == 2
    for j in range(1, len(final.tiles)):
        col, row, size, _ = final.windows[j]
        assert np.array_equal(final.tiles[j - 1].heights[row:row + size, col:col + size],
                              final.tiles[j].heights[::2, ::2])


def test_corrupt_manifest_is_a_clear_error(stack, tmp_path):
    out = write_stack(stack, tmp_path / "stack")
    (out / "manifest.json").write_text("{ not json")
    with pytest.raises(InvalidDEMError, match="corrupt"):
        read_stack(out)
    with pytest.raises(InvalidDEMError, match="corrupt"):
        replace_crater(out, SITE[0], SITE[1], 100.0)


@pytest.mark.parametrize("where", ["top", "layer"])
def test_a_manifest_key_no_writer_writes_is_refused_by_name(stack, tmp_path, where):
    """A manifest is machine-written: a key nobody writes means a foreign or altered file."""
    out = write_stack(stack, tmp_path / "s")
    manifest = json.loads((out / "manifest.json").read_text())
    (manifest if where == "top" else manifest["layers"][1])["sead"] = 3
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(InvalidDEMError, match="'sead'"):
        read_stack(out)
    with pytest.raises(InvalidParameterError, match="unknown layer-stack manifest key 'note'"):
        write_stack(stack.with_info(note="x"), tmp_path / "t")
    assert not (tmp_path / "t").exists()


def test_bad_requests():
    with pytest.raises(InvalidParameterError, match="outside the DEM"):
        build_stack(base(), (-5.0, 3.0), levels=2, layer_size=65)
    with pytest.raises(InvalidParameterError, match="odd"):
        build_stack(base(), SITE, levels=2, layer_size=64)


def test_more_levels_than_memory_allows_is_refused(monkeypatch):
    monkeypatch.setenv("CRATERSCAPE_MEMORY_LIMIT", "50M")
    with pytest.raises(MemoryRequestError, match="needs about"):
        build_stack(base(), SITE, levels=12, layer_size=2049)
    assert os.environ["CRATERSCAPE_MEMORY_LIMIT"] == "50M"


@given(st.floats(1e-3, 1e4), st.floats(1e-3, 1e4))
def test_levels_for_resolution_is_the_fewest_that_reach_the_finest(base, finest):
    from terrain.stack.plan import MAX_LEVELS, levels_for_resolution

    try:
        levels = levels_for_resolution(base, finest)
    except InvalidParameterError:
        assert math.log2(base / finest) > MAX_LEVELS - 1
        return
    assert base / 2**levels <= finest * (1 + 1e-9)
    assert levels == 0 or base / 2 ** (levels - 1) > finest * (1 - 1e-9)


def test_a_crater_below_what_its_layer_resolves_is_refused_and_nothing_moves(stack, tmp_path):
    from tests.cli_helpers import snapshot

    out = write_stack(stack, tmp_path / "stack")
    before = snapshot(out)
    x, y = stack.tiles[-1].xy(64, 64)
    finest = stack.tiles[-1].resolution
    for diameter in (0.001, 0.5 * finest, 3.9 * finest):
        with pytest.raises(InvalidParameterError, match="resolves"):
            replace_crater(out, float(x), float(y), diameter)
    assert snapshot(out) == before  # no known height moved, no crater recorded
    done = replace_crater(out, float(x), float(y), 4.0 * finest)
    assert done["layer"] == len(stack.tiles) - 1
