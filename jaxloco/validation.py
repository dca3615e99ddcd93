"""Validation of the parameter dataclasses: one rule shape and one message for all of them.

A rule is ``(field, ok, must_be)``: the field's name, whether its value passes, and what it
must be (its valid range, in words). :func:`check_fields` raises on the first rule that
fails, ``ValueError("Owner.field must be <must_be>; got <value>")``, so every config error
names the class, the field, the valid range and the value given. The rule builders cover
the common ranges; comparisons are written so that NaN fails every one of them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

Rule = tuple[str, bool, str]


def check_fields(obj, rules: Iterable[Rule]) -> None:
    """Raise ``ValueError`` naming the first field of ``obj`` whose rule fails."""
    owner = type(obj).__name__
    for field, ok, must_be in rules:
        if not ok:
            raise ValueError(f"{owner}.{field} must be {must_be}; got {getattr(obj, field)!r}")


def positive(obj, *names: str) -> list[Rule]:
    """Each named field > 0."""
    return [(n, getattr(obj, n) > 0, "> 0") for n in names]


def non_negative(obj, *names: str) -> list[Rule]:
    """Each named field >= 0."""
    return [(n, getattr(obj, n) >= 0, ">= 0") for n in names]


def unit_interval(obj, *names: str) -> list[Rule]:
    """Each named field in [0, 1]."""
    return [(n, 0 <= getattr(obj, n) <= 1, "in [0, 1]") for n in names]


def integer(obj, name: str, minimum: int) -> Rule:
    """The field is a whole number >= ``minimum`` (an int, or a float with no fraction)."""
    value = getattr(obj, name)
    ok = isinstance(value, (int, float)) and math.isfinite(value) and int(value) == value
    return (name, ok and value >= minimum, f"an int >= {minimum}")


def one_of(obj, name: str, options) -> Rule:
    """The field is one of ``options``."""
    return (name, getattr(obj, name) in tuple(options), f"one of {list(options)}")
