"""Typed settings from text: a dataclass's fields say what each setting is, and text from the
command line (`-O KEY=VALUE`, `-p KEY=VALUE`) or JSON becomes that type here, once.

A field's annotation is the whole contract: `float`, `int`, `bool`, `str`, `Path`, a
`Literal[...]` of choices, a tuple of those (`tuple[float, float]`, `tuple[str, ...]`: from a
list or tuple), or a union of those with `None`. Conversion and checking live in one
place so that every format and the simulator reject the same mistakes with the same words.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

from toolkit.errors import ToolkitError

T = TypeVar("T")

_TRUE = frozenset({"true", "yes", "on", "1"})
_FALSE = frozenset({"false", "no", "off", "0"})


_FIELD_TYPES: dict[type, dict[str, Any]] = {}


def field_types(cls: type) -> dict[str, Any]:
    """The resolved annotation of each dataclass field of `cls`, by name (cached)."""
    if cls not in _FIELD_TYPES:
        hints = typing.get_type_hints(cls)
        _FIELD_TYPES[cls] = {f.name: hints[f.name] for f in dataclasses.fields(cls) if f.init}
    return _FIELD_TYPES[cls]


_LITERAL: object = Literal  # compared by identity with get_origin()


def _members(kind: object) -> list[Any]:
    """A union's members (Literal choices first, None last), or [kind]."""
    if get_origin(kind) in (Union, types.UnionType):
        members = list(get_args(kind))
    else:
        members = [kind]
    return sorted(members, key=lambda m: (m is type(None), get_origin(m) is not _LITERAL))


def choices(kind: object) -> tuple[object, ...]:
    """The Literal choices a field's type allows (empty if it allows more than choices)."""
    out: list[object] = []
    for m in _members(kind):
        if get_origin(m) is Literal:
            out.extend(get_args(m))
        elif m is not type(None):
            return ()
    return tuple(out)


def words(kind: object) -> str:
    """A type in plain words, short: number, integer, text, path, true|false, a|b|c. (None,
    "not given", is left out: the default says what happens then.)"""
    names = {float: "number", int: "integer", str: "text", bool: "true|false", Path: "path"}
    parts: list[str] = []
    for m in _members(kind):
        if get_origin(m) is Literal:
            parts.extend(str(c) for c in get_args(m))
        elif m is not type(None):
            parts.append(names.get(m, getattr(m, "__name__", str(m))))
    return "|".join(parts)


def convert(value: object, kind: object, key: str, owner: str) -> object:
    """`value` (text, or a value from JSON or Python) as the type `kind`; `key` and `owner`
    name it in the one-line error ("range_max=abc for carmen: expected none|number")."""
    ok, out = coerce(value, kind)
    if ok:
        return out
    raise ToolkitError(f"{key}={_show(value)} for {owner}: expected {words(kind)}")


def coerce(value: object, kind: object) -> tuple[bool, object]:
    """(True, `value` as the type `kind`), or (False, None) if it is not one; for callers that
    word their own error (`convert` words the command line's)."""
    for m in _members(kind):
        ok, out = _try(value, m)
        if ok:
            return True, out
    return False, None


def _show(value: object) -> str:
    """Text as typed, unless it holds line breaks or control characters (then quoted)."""
    return value if isinstance(value, str) and value.isprintable() else repr(value)


def _try(value: object, kind: object) -> tuple[bool, object]:
    if kind is type(None):
        if value is None or (isinstance(value, str) and value.strip().lower() in ("", "none")):
            return True, None
        return False, None
    if value is None:
        return False, None
    if get_origin(kind) is Literal:
        for choice in get_args(kind):
            if isinstance(value, str) and value.strip().lower() == str(choice).lower():
                return True, choice
            if not isinstance(value, str) and type(value) is type(choice) and value == choice:
                return True, choice
        return False, None
    text = value.strip() if isinstance(value, str) else None
    if kind is bool:
        if isinstance(value, bool):
            return True, value
        if text is not None and text.lower() in _TRUE | _FALSE:
            return True, text.lower() in _TRUE
        return False, None
    if kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return True, value
        try:
            return (True, int(text)) if text is not None else (False, None)
        except ValueError:
            return False, None
    if kind is float:
        if isinstance(value, bool):
            return False, None
        if isinstance(value, int | float):
            number = float(value)
        else:
            try:
                number = float(text) if text is not None else math.nan
            except ValueError:
                return False, None
        return (True, number) if not math.isnan(number) else (False, None)
    if kind is str:
        return (True, value) if isinstance(value, str) else (False, None)
    if kind is Path:
        if isinstance(value, Path):
            return True, value
        return (True, Path(text)) if text else (False, None)
    if get_origin(kind) is tuple:
        return _items(value, get_args(kind))
    if isinstance(kind, type):
        return (True, value) if isinstance(value, kind) else (False, None)
    return False, None


def _items(value: object, kinds: tuple[Any, ...]) -> tuple[bool, object]:
    """A list or tuple as a tuple of `kinds` (`tuple[X, ...]`: any length of X)."""
    if not isinstance(value, list | tuple):
        return False, None
    if len(kinds) == 2 and kinds[1] is Ellipsis:
        kinds = kinds[:1] * len(value)
    if len(kinds) != len(value):
        return False, None
    items = [coerce(v, k) for v, k in zip(value, kinds, strict=True)]
    if not all(ok for ok, _ in items):
        return False, None
    return True, tuple(v for _, v in items)


def build(cls: type[T], values: Mapping[str, object], what: str) -> T:
    """An instance of the dataclass `cls` from `values` (text or plain values), every one
    converted to its field's type; an unknown name is an error listing the known ones."""
    kinds = field_types(cls)
    unknown = [k for k in values if k not in kinds]
    if unknown:
        raise ToolkitError(
            f"unknown option {unknown[0]!r} for {what}; known: {', '.join(kinds) or 'none'}"
        )
    typed = {k: convert(v, kinds[k], k, what) for k, v in values.items()}
    return cls(**typed)


def check_fields(obj: object, what: str) -> None:
    """Convert and check every field of the (frozen) dataclass `obj` in place; for
    `__post_init__`, so that objects built in Python are held to the same types as parsed ones."""
    for name, kind in field_types(type(obj)).items():
        value = getattr(obj, name)
        fixed = convert(value, kind, name, what)
        if fixed is not value:
            object.__setattr__(obj, name, fixed)


def int_ranges(text: str) -> tuple[int, ...]:
    """The integers '0-19,2000-2019' (or '7', or '0,3,5') names, in order: seeds, rows."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += range(int(lo), int(hi or lo) + 1)
    return tuple(out)
