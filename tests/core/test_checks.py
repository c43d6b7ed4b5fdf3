"""m4dgs.core.checks (the validators' shared value checks) and m4dgs.core.io.find_file (the suite
lookups of benchgen and eval)."""

from __future__ import annotations

import math

import pytest

from m4dgs.core.checks import is_integer, is_number, unknown_keys
from m4dgs.core.io import find_file


@pytest.mark.parametrize(
    "v, number, finite, integer",
    [
        (1, True, True, True),
        (1.5, True, True, False),
        (True, False, False, False),  # YAML true is a bool, not a number
        (math.inf, True, False, False),
        (math.nan, True, False, False),
        ("1", False, False, False),
        (None, False, False, False),
    ],
)
def test_is_number_and_is_integer(v, number, finite, integer):
    assert is_number(v) is number
    assert is_number(v, finite=True) is finite
    assert is_integer(v) is integer


def test_unknown_keys_keeps_the_mapping_order():
    assert unknown_keys({"b": 1, "x": 2, "a": 3, "z": 4}, {"a", "b"}) == ["x", "z"]
    assert unknown_keys({}, ()) == []


def test_find_file_by_path_or_shipped_name(tmp_path):
    shipped = tmp_path / "suites"
    shipped.mkdir()
    (shipped / "tiny.yaml").write_text("name: tiny\n")
    own = tmp_path / "mine.yml"
    own.write_text("name: mine\n")
    assert find_file(own, shipped) == own  # an existing file by path
    assert find_file(str(own), shipped) == own
    assert find_file("tiny", shipped) == shipped / "tiny.yaml"  # a shipped name
    assert find_file("nope", shipped) is None
    assert find_file(tmp_path / "missing.yaml", shipped) is None
    assert find_file("suites", tmp_path) is None  # a folder is not a file
