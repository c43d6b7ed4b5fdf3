"""Value checks shared by the hand-written validators of YAML mappings: benchgen's scene and suite
specs (benchgen.spec), eval's experiment suites (eval.records.suite). YAML reads `true` / `false` as
Python booleans, which are ints too, so "a number" and "an integer" exclude bool here."""

from __future__ import annotations

import math
from typing import Any, Container, List, Mapping


def is_number(v: Any, *, finite: bool = False) -> bool:
    """v is an int or float and not a bool (finite=True: also not inf / nan)."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    return math.isfinite(float(v)) if finite else True


def is_integer(v: Any) -> bool:
    """v is an int and not a bool."""
    return isinstance(v, int) and not isinstance(v, bool)


def unknown_keys(mapping: Mapping, allowed: Container) -> List:
    """The keys of `mapping` that `allowed` does not contain, in the mapping's order."""
    return [k for k in mapping if k not in allowed]
