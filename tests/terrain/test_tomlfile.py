"""Reading users' TOML files: anything malformed is one line naming the file."""

import pytest

from terrain.core.errors import InvalidParameterError
from terrain.core.tomlfile import MAX_DEPTH, read_toml


@pytest.mark.parametrize("text", [
    "a = " + "[" * 50_000 + "]" * 50_000,
    "a = " + "{b = " * 50_000 + "1" + "}" * 50_000,
    "[" + ".".join(["t"] * 5_000) + "]\nx = 1\n",
])
def test_a_file_nested_absurdly_deep_is_refused_in_one_line(tmp_path, text):
    path = tmp_path / "deep.toml"
    path.write_text(text)
    with pytest.raises(InvalidParameterError, match="nests deeper than") as info:
        read_toml(path, "population file")
    assert "deep.toml" in str(info.value) and "\n" not in str(info.value)


def test_nesting_up_to_the_limit_is_read():
    import tempfile
    from pathlib import Path

    path = Path(tempfile.mkdtemp()) / "ok.toml"
    path.write_text("a = " + "[" * (MAX_DEPTH - 1) + "1" + "]" * (MAX_DEPTH - 1) + "\n")
    value = read_toml(path, "scenario")["a"]
    for _ in range(MAX_DEPTH - 1):
        value = value[0]
    assert value == 1
