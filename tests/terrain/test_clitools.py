"""The shared CLI pieces: parameter types refuse bad values by name; bars stay out of pipes."""

import click
import pytest
from hypothesis import given
from hypothesis import strategies as st

from terrain.cli.tools import FINITE, PAIR, TRIPLE, ImageSizeType, progress_bar

finite = st.floats(allow_nan=False, allow_infinity=False)


@given(st.tuples(finite, finite))
def test_pair_reads_back_what_was_written(pair):
    assert PAIR.convert(f"{pair[0]!r},{pair[1]!r}", None, None) == pair


@given(st.tuples(finite, finite, finite))
def test_triple_reads_back_what_was_written(triple):
    assert TRIPLE.convert(",".join(repr(v) for v in triple), None, None) == triple


@pytest.mark.parametrize("kind, text", [
    (PAIR, "1,nan"), (PAIR, "1,2,3"), (PAIR, "1"), (PAIR, "inf,0"), (PAIR, "a,b"),
    (TRIPLE, "1,2"), (TRIPLE, "1,2,-inf"), (FINITE, "nan"), (FINITE, "1e999"), (FINITE, "x"),
])
def test_bad_numbers_are_usage_errors(kind, text):
    with pytest.raises(click.BadParameter):
        kind.convert(text, None, None)


@given(st.integers(1, 64), st.integers(1, 64), st.integers(1, 64))
def test_image_size_is_refused_exactly_above_the_largest_side(w, h, largest):
    kind = ImageSizeType(lambda: largest)
    if max(w, h) > largest:
        with pytest.raises(click.BadParameter, match=f"{largest} pixels"):
            kind.convert(f"{w}x{h}", None, None)
    else:
        assert kind.convert(f"{w}X{h}", None, None) == (w, h)


def test_progress_bar_is_silent_off_a_terminal(capsys):
    with progress_bar("test") as update:
        assert update is None
    assert capsys.readouterr().err == ""

