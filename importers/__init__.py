"""Importers: one module per source format, found by a registry.

A module in this package that defines an `Importer` subclass decorated with `@register`
is picked up by `toolkit import` and by format auto-detection; nothing else to edit.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

from importers.base import FLAGS, FormatOptions, Importer, ImportOptions, check_readable, not_a_log
from toolkit.errors import ToolkitError

__all__ = [
    "FormatOptions",
    "ImportOptions",
    "Importer",
    "detect",
    "get",
    "import_log",
    "names",
    "not_a_log",
    "read_options",
    "register",
    "resolve",
    "write_options",
]

AnyImporter = Importer[Any, Any]
_REGISTRY: dict[str, type[AnyImporter]] = {}
_BROKEN: dict[str, str] = {}  # module name -> why it failed to import
_loaded = False


def register(cls: type[AnyImporter]) -> type[AnyImporter]:
    """Class decorator: make an importer known under `cls.name` (and name its options)."""
    _REGISTRY[cls.name] = cls
    cls.Options.what = cls.name
    if cls.WriteOptions is not None:
        cls.WriteOptions.what = f"the {cls.name} writer"
    return cls


def read_options(
    importer: AnyImporter, given: ImportOptions | FormatOptions | None
) -> FormatOptions:
    """The importer's typed options from what the user gave: parsed here, once. A `-O` key
    the format does not have, or a flag (--scan-topic) it does not take, is an error."""
    if isinstance(given, importer.Options):
        return cast(FormatOptions, given)
    if isinstance(given, FormatOptions):
        raise ToolkitError(f"{type(given).__name__} given to the {importer.name} importer")
    given = given or ImportOptions()
    values: dict[str, object] = dict(given.extra)
    known = [f for f in _fields(importer.Options)]
    for name, flag in FLAGS.items():
        value = getattr(given, name)
        if value is None:
            continue
        if name not in known:
            raise ToolkitError(
                f"{flag} does not apply to {importer.name}; its options: {', '.join(known)}"
            )
        if name in values:
            raise ToolkitError(f"{flag} and -O {name}= both given; give one")
        values[name] = value
    return cast(FormatOptions, importer.Options.parse(values))


def write_options(
    importer: AnyImporter, given: Mapping[str, object] | FormatOptions | None
) -> FormatOptions:
    """The writer's typed options from `KEY=VALUE` text or plain values (unknown keys: error)."""
    if importer.WriteOptions is None:
        raise ToolkitError(f"format {importer.name!r} has no writer")
    if isinstance(given, importer.WriteOptions):
        return cast(FormatOptions, given)
    if isinstance(given, FormatOptions):
        raise ToolkitError(f"{type(given).__name__} given to the {importer.name} writer")
    return cast(FormatOptions, importer.WriteOptions.parse(given or {}))


def _fields(cls: type[FormatOptions]) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def _load_all() -> None:
    global _loaded
    if _loaded:
        return
    for module in pkgutil.iter_modules(__path__):
        if module.name != "base" and not module.name.startswith("_"):
            try:
                importlib.import_module(f"{__name__}.{module.name}")
            except Exception as e:  # one broken format must not take the others down
                _BROKEN[module.name] = f"{type(e).__name__}: {e}"
    _loaded = True


def names() -> list[str]:
    """Registered format names, sorted."""
    _load_all()
    return sorted(_REGISTRY)


def get(name: str) -> AnyImporter:
    _load_all()
    try:
        return _REGISTRY[name]()
    except KeyError:
        if name in _BROKEN:
            raise ToolkitError(f"format {name!r} failed to load: {_BROKEN[name]}") from None
        known = ", ".join(["auto", *names()])
        raise ToolkitError(f"unknown format {name!r}; known: {known}") from None


def _claims(path: Path) -> list[AnyImporter]:
    return [imp for cls in _REGISTRY.values() if (imp := cls()).sniff(path)]


def _logs_in(directory: Path, importer: AnyImporter | None) -> list[tuple[AnyImporter, Path]]:
    """The files directly in `directory` that an importer (the given one, or any) claims."""
    candidates = [importer] if importer else [cls() for cls in _REGISTRY.values()]
    files = [
        c
        for c in sorted(directory.iterdir())
        if c.is_file() and not c.name.startswith(".") and not not_a_log(c)
    ]
    return [(imp, f) for f in files for imp in candidates if imp.sniff(f)]


def resolve(fmt: str, sources: Sequence[Path]) -> tuple[AnyImporter, list[Path]]:
    """The importer for `sources` ('auto' detects it from the first) and the sources to give it.

    A directory that the format does not read as a whole (a Rawseeds session is read whole)
    stands for the one log of that format inside it, e.g. a `toolkit simulate` output."""
    _load_all()
    first = Path(sources[0])
    if not first.exists():
        raise ToolkitError("no such file or directory", file=first)
    importer = get(fmt) if fmt != "auto" else None
    if importer is None:
        if why := not_a_log(first):
            raise ToolkitError(f"{why}, not a laser log; nothing to import", file=first)
        hits = _claims(first)
        if len(hits) > 1:
            raise ToolkitError(
                f"ambiguous format ({', '.join(h.name for h in hits)}); name it", file=first
            )
        importer = hits[0] if hits else None
    if importer is not None and (not first.is_dir() or importer.sniff(first)):
        return importer, list(sources)
    if first.is_dir() and fmt == "auto" and (first / "meta.json").is_file():
        raise ToolkitError(
            "a dataset directory (already imported: `toolkit info`, `toolkit map` read it), "
            "not a laser log; nothing to import",
            file=first,
        )
    if not first.is_dir():  # a file no importer claims
        raise ToolkitError(
            f"cannot tell the format; name it (one of {', '.join(names())})", file=first
        )
    inside = _logs_in(first, importer)
    if len(inside) == 1 and len(sources) == 1:
        return inside[0][0], [inside[0][1]]
    if not inside:
        what = (
            f"{importer.name} log" if importer else f"log of a known format ({', '.join(names())})"
        )
        raise ToolkitError(f"no {what} in this directory", file=first)
    listed = ", ".join(f"{p.name} ({imp.name})" for imp, p in inside)
    raise ToolkitError(f"{len(inside)} candidates ({listed}); name the file", file=first)


def detect(sources: Sequence[Path]) -> AnyImporter:
    """The importer that `toolkit import auto` would use for `sources`."""
    return resolve("auto", sources)[0]


def import_log(
    fmt: str,
    sources: Sequence[str | Path],
    out: str | Path,
    options: ImportOptions | FormatOptions | None = None,
    force: bool = False,
) -> Path:
    """Import `sources` of format `fmt` ('auto' to detect) into the dataset directory `out`.

    `options`: what the user gave (ImportOptions, parsed here into the format's options), or
    the format's own options object."""
    paths = [Path(s) for s in sources]
    if not paths:
        raise ToolkitError("no source given")
    for p in paths:
        check_readable(p)
    if fmt != "auto":  # the options before the sources: a typo fails fast
        read_options(get(fmt), options)
    importer, paths = resolve(fmt, paths)
    typed = read_options(importer, options)
    return importer.import_to(paths, Path(out), typed, force=force)
