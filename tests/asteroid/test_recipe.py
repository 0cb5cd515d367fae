"""Recipes: presets, TOML files, flags, and the paper's c."""

import numpy as np
import pytest

from asteroid.build import build
from asteroid.recipe import PRESETS, CraterSpec, Recipe, parse_spec
from terrain.core.errors import InvalidParameterError, MissingInputError


@pytest.mark.parametrize("seed", [0, 4, 10])
def test_fig9_preset_builds_a_body_twice_as_long_as_it_is_wide(seed):
    """Fig. 9's faulted asteroid is stretched 2:1:1: for seeds of low and high relief the
    built body's extent along x is twice its extent along z and y matches z (within 20 %:
    the faults' own relief reaches a few tens of per cent of the radius), and the mesh has
    the 6 M^2 + 2 vertices of magnitude M."""
    recipe = Recipe.from_sources(preset="fig9-faulting", magnitude=12, seed=seed,
                                 craters="none")
    body = build(recipe).body
    v = body.vertices()
    extent = v.max(axis=0) - v.min(axis=0)
    assert extent[0] / extent[2] == pytest.approx(2.0, rel=0.20)
    assert extent[1] / extent[2] == pytest.approx(1.0, rel=0.20)
    assert len(v) == 6 * 12**2 + 2


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_builds_at_a_small_magnitude(name):
    radius = PRESETS[name]["radius"]
    recipe = Recipe.from_sources(preset=name, magnitude=12, craters={"dmin": radius / 8})
    result = build(recipe)
    assert result.body.mesh.n_vertices == 6 * 144 + 2
    assert result.craters is not None and result.craters.applied.sum() > 10


def test_papers_c_becomes_a_density():
    spec = CraterSpec(c=0.5, k=-2.0, dmin=2.0, dmax=40.0)
    pop = spec.population(radius=100.0, spacing=0.4)
    # N_cum(2 m) = 0.5 / 4 per m^2 = 125,000 per km^2
    assert pop.density == pytest.approx(125_000.0)
    assert pop.cumulative(10.0) / 1e6 == pytest.approx(0.5 / 100.0)
    # defaults: dmin = 4 spacings, dmax = the maximum extent
    default = CraterSpec(c=0.5).population(radius=100.0, spacing=0.4)
    assert default.dmin == pytest.approx(1.6) and default.dmax == pytest.approx(100 * np.pi / 6)
    with pytest.raises(InvalidParameterError, match="exactly one of c"):
        CraterSpec(c=0.5, density=3.0)
    with pytest.raises(InvalidParameterError, match="exactly one of c"):
        CraterSpec()


def test_toml_file_flags_and_preset_merge(tmp_path):
    shape = tmp_path / "models" / "ball.obj"
    shape.parent.mkdir()
    shape.write_text("v 0 0 0\n")
    config = tmp_path / "r.toml"
    config.write_text(
        'preset = "fig9-faulting"\nmagnitude = 20\nseed = 4\n'
        '[faulting]\nfaults = 10\n[craters]\ndmin = 3.0\n'
        '[boulders]\nc = 0.01\nflattening = [0.3, 0.6]\n')
    r = Recipe.from_sources(config=config, seed=9, craters={"max_age": 1.0})
    assert r.magnitude == 20 and r.seed == 9                      # flag beats file
    assert r.faulting.faults == 10 and r.faulting.fine_faults == 20000   # file over preset
    assert r.craters.c == 0.5 and r.craters.dmin == 3.0 and r.craters.max_age == 1.0
    assert r.boulders.settings.flattening == (0.3, 0.6) and r.boulders.c == 0.01
    assert r.preset == "fig9-faulting"
    none = Recipe.from_sources(config=config, craters="none", boulders="none")
    assert none.craters is None and none.boulders is None
    config.write_text('magnitude = 8\nbase = "shape:models/ball.obj"\n')
    assert Recipe.from_sources(config=config).shape_file == str(shape)   # relative to the file


def test_spec_strings():
    assert parse_spec("paper", "craters") == {"c": 0.5, "k": -2.0}
    assert parse_spec("none", "craters") is None
    assert parse_spec("c=0.1,dmin=2,dmax=50", "craters") == {"c": 0.1, "dmin": 2.0, "dmax": 50.0}
    with pytest.raises(InvalidParameterError, match="key=value"):
        parse_spec("c0.5", "craters")
    with pytest.raises(InvalidParameterError, match="must be a number"):
        parse_spec("c=abc", "craters")


def test_bad_recipes(tmp_path):
    with pytest.raises(InvalidParameterError, match="needs --radius"):
        Recipe.from_sources(magnitude=4, base="perlin")
    with pytest.raises(InvalidParameterError, match="magnitude M must be"):
        Recipe.from_sources(magnitude=0, base="perlin", radius=1.0)
    with pytest.raises(InvalidParameterError, match="unknown preset"):
        Recipe.from_sources(preset="fig99")
    with pytest.raises(InvalidParameterError,
                       match=r"unknown recipe \[perlin\] key 'octave' "
                             r"\(did you mean 'octaves'\?\)"):
        Recipe.from_dict(dict(magnitude=4, radius=1.0, base="perlin", perlin={"octave": 3}))
    with pytest.raises(InvalidParameterError, match="unknown recipe key 'colour'"):
        Recipe.from_dict(dict(magnitude=4, radius=1.0, base="perlin", colour="red"))
    with pytest.raises(InvalidParameterError, match="base must be"):
        Recipe.from_sources(magnitude=4, radius=1.0, base="fractal")
    with pytest.raises(MissingInputError):
        Recipe.from_sources(config=tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("magnitude = = 3")
    with pytest.raises(InvalidParameterError, match="not valid TOML"):
        Recipe.from_sources(config=bad)


def test_crater_morphology_and_slope_degradation_come_from_the_recipe():
    spec = CraterSpec(c=0.5, transition_diameter=50.0, slope_degradation=False)
    model = spec.settings().model
    assert model.morphology.transition_diameter == 50.0
    assert model.morphology.is_complex(np.array([40.0, 60.0])).tolist() == [False, True]
    assert not model.slope.enabled
    lunar = CraterSpec(c=0.5).settings().model
    assert lunar.morphology.transition_diameter == 15000.0 and lunar.slope.enabled
    with pytest.raises(InvalidParameterError, match="transition_diameter"):
        Recipe.from_sources(preset="fig5-smooth", craters={"transition_diametr": 10.0})
    with pytest.raises(InvalidParameterError, match="positive"):
        CraterSpec(c=0.5, transition_diameter=-1.0)
