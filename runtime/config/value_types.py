"""Decoded JSON (a spec, a recording's configuration, a run file) held against the
annotated types of the configuration's fields (:mod:`.sections`)."""

from __future__ import annotations

import math
import types
import typing
from typing import Any


def has_type(value: Any, tp: Any) -> bool:
    """``value`` (decoded JSON) is of the annotated type: ``int``, ``float`` (an int is
    one), ``str``, ``bool``, ``X | None``, ``list[str]``, ``dict[str, str]``; bool is no
    number; a float must be finite."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return any(has_type(value, a) for a in args)
    if tp is type(None):
        return value is None
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is float:
        return (isinstance(value, (int, float)) and not isinstance(value, bool)
                and math.isfinite(value))
    if tp is str:
        return isinstance(value, str)
    if origin is list:
        return isinstance(value, list) and all(has_type(x, args[0]) for x in value)
    if origin is dict:
        return isinstance(value, dict) and all(
            has_type(k, args[0]) and has_type(x, args[1]) for k, x in value.items())
    return False


def type_name(tp: Any) -> str:
    """How an error names the annotated type ``tp`` to a user."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(type_name(a) for a in args)
    names = {type(None): "null", bool: "true or false", int: "an integer",
             float: "a finite number", str: "a string"}
    if tp in names:
        return names[tp]
    if origin is list:
        return f"a list of {type_name(args[0]).removeprefix('a ')}s"
    if origin is dict:
        return "an object of strings"
    return str(tp)


__all__ = ["has_type", "type_name"]
