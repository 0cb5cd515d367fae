"""Hostile input to the asteroid commands: absurd sizes, inputs as outputs, and "cannot write here".
Refusals are exit code 2 with one line on stderr, every input byte-identical, no output."""

from tests.cli_helpers import file_size_limit, refused, run, snapshot, unwritable_folder

BUILD = ["asteroid", "build", "--magnitude", 8, "--base", "perlin", "--seed", 1]


def test_absurd_sizes_are_refused(tmp_path):
    out = tmp_path / "a.ply"
    for radius, fragment in ((1e300, "larger than any asteroid"), ("nan", "finite"),
                             ("inf", "finite"), (-3, "positive")):
        refused(run(*BUILD, "--radius", radius, "-o", out), {}, out, tmp_path / "a.npz",
                fragments=[fragment], folder=tmp_path)


def test_a_recipe_is_never_overwritten_by_a_build(tmp_path):
    recipe = tmp_path / "b_craters.csv"  # a recipe named like the catalogue -o b.npz writes
    recipe.write_text("magnitude = 8\nradius = 500.0\nbase = \"perlin\"\n")
    before = snapshot(recipe)
    refused(run("asteroid", "build", "--config", recipe, "-o", tmp_path / "b.npz",
                "--craters", "c=0.5,dmin=50"), before, tmp_path / "b.npz",
            fragments=["same file as input"], folder=tmp_path)


def test_cannot_write_here_is_exit_2(tmp_path):
    ro = unwritable_folder(tmp_path)
    refused(run(*BUILD, "--radius", 500, "-o", ro / "a.ply"), {}, fragments=["cannot write"])
    with file_size_limit(20_000):  # a full disk: the mesh fits, the native model does not
        r = run(*BUILD, "--radius", 500, "--craters", "c=0.5,dmin=50",
                "-o", tmp_path / "a.ply")
    refused(r, {}, tmp_path / "a.ply", tmp_path / "a.npz", tmp_path / "a_craters.csv",
            fragments=["cannot write"], folder=tmp_path)
