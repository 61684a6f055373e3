"""Expert settings from the command line: `--config FILE.json` and `--set KEY=VALUE` onto a
frozen dataclass of settings (`SlamConfig`, `MatchConfig`, the places `Config`), checked
field by field so that a wrong key or value is one line naming it, before any work starts.

The types are `toolkit.typed`'s (as the formats' and the simulator's options); only the
standard library besides: the commands import it on use, and `toolkit --help` not.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import types
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

from toolkit.app.cli.options import key_values
from toolkit.errors import ToolkitError
from toolkit.typed import coerce, field_types

T = TypeVar("T")


def read_json(path: Path) -> dict[str, Any]:
    """FILE of `--config`: a JSON object (a missing or malformed file is a one-line error)."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ToolkitError("no such file", file=path) from None
    except IsADirectoryError:
        raise ToolkitError("a directory, not a JSON file", file=path) from None
    except UnicodeDecodeError:
        raise ToolkitError("not a JSON text file", file=path) from None
    except json.JSONDecodeError as e:
        raise ToolkitError(f"invalid JSON: {e.msg}", file=path, record=e.lineno) from None
    if not isinstance(data, dict):
        raise ToolkitError("expected a JSON object of setting: value", file=path)
    return data


def parse_sets(pairs: list[str] | None, flag: str = "--set") -> dict[str, Any]:
    """`--set KEY=VALUE`s as a nested dict (`slam.loop.radius=3` -> {"slam": {"loop":
    {"radius": 3}}}); each value parsed as JSON where it parses (numbers, lists, true, false,
    null), else kept as text."""
    out: dict[str, Any] = {}
    for key, text in key_values(pairs, flag).items():
        try:
            value: Any = json.loads(text)
        except json.JSONDecodeError:
            value = text
        *parents, name = key.split(".")
        node = out
        for i, part in enumerate(parents):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ToolkitError(f"{flag} {key}: {'.'.join(parents[: i + 1])} is set apart")
            node = child
        if isinstance(node.get(name), dict):
            raise ToolkitError(f"{flag} {key}: its keys are set apart as well")
        node[name] = value
    return out


def apply(settings: T, changes: dict[str, Any], source: str, prefix: str = "") -> T:
    """`settings` (a frozen dataclass) with the fields `changes` names replaced, nested
    dataclasses from nested objects; an unknown key, a value of the wrong type or one the
    dataclass refuses raises a ToolkitError naming `source` (the file or --set) and the key."""
    fields = field_types(type(settings))
    new: dict[str, Any] = {}
    for name, value in changes.items():
        key = prefix + name
        if name not in fields:
            near = difflib.get_close_matches(name, sorted(fields), n=1)
            hint = f" (did you mean {prefix}{near[0]}?)" if near else ""
            raise ToolkitError(f"unknown setting {key}{hint}", file=source)
        current = getattr(settings, name)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ToolkitError(f"{key}: expected an object of settings", file=source)
            new[name] = apply(current, value, source, key + ".")
        else:
            new[name] = _typed(value, fields[name], key, source)
    try:
        return dataclasses.replace(settings, **new)  # type: ignore[type-var]
    except ToolkitError as e:  # the dataclass's own check (__post_init__)
        keys = ", ".join(prefix + n for n in new)
        raise ToolkitError(f"{keys}: {e.what}", file=source) from None
    except (TypeError, ValueError) as e:
        keys = ", ".join(prefix + n for n in new)
        raise ToolkitError(f"{keys}: {e}", file=source) from None


def _typed(value: object, hint: object, key: str, source: str) -> object:
    """`value` as a field of type `hint` takes it (`typed.coerce`: an int for a float, a list
    for a tuple), or a ToolkitError saying, in JSON's words, what the field takes."""
    ok, out = coerce(value, hint)
    if not ok:
        raise ToolkitError(
            f"{key}: expected {_describe(hint)}, not {json.dumps(value)}", file=source
        )
    return out


def _describe(hint: object) -> str:
    origin, args = get_origin(hint), get_args(hint)
    if origin in (Union, types.UnionType):
        return " or ".join(_describe(a) for a in args)
    if hint is type(None):
        return "null"
    if origin is Literal:
        return "one of " + ", ".join(json.dumps(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_describe(args[0])}"
        return f"a list of {len(args)}: " + ", ".join(_describe(a) for a in args)
    names: dict[object, str] = {
        bool: "true or false",
        int: "an integer",
        float: "a number",
        str: "a string",
    }
    return names.get(hint) or str(getattr(hint, "__name__", hint))
