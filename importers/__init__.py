"""Importers: one module per source format, found by a registry.

A module in this package that defines an `Importer` subclass decorated with `@register`
is picked up by `toolkit import` and by format auto-detection; nothing else to edit.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Sequence
from pathlib import Path

from importers.base import Importer, ImportOptions, check_readable
from toolkit.errors import ToolkitError

__all__ = [
    "ImportOptions",
    "Importer",
    "detect",
    "get",
    "import_log",
    "names",
    "register",
    "resolve",
]

_REGISTRY: dict[str, type[Importer]] = {}
_BROKEN: dict[str, str] = {}  # module name -> why it failed to import
_loaded = False


def register(cls: type[Importer]) -> type[Importer]:
    """Class decorator: make an importer known under `cls.name`."""
    _REGISTRY[cls.name] = cls
    return cls


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


def get(name: str) -> Importer:
    _load_all()
    try:
        return _REGISTRY[name]()
    except KeyError:
        if name in _BROKEN:
            raise ToolkitError(f"format {name!r} failed to load: {_BROKEN[name]}") from None
        known = ", ".join(["auto", *names()])
        raise ToolkitError(f"unknown format {name!r}; known: {known}") from None


def _claims(path: Path) -> list[Importer]:
    return [imp for cls in _REGISTRY.values() if (imp := cls()).sniff(path)]


def _logs_in(directory: Path, importer: Importer | None) -> list[tuple[Importer, Path]]:
    """The files directly in `directory` that an importer (the given one, or any) claims."""
    candidates = [importer] if importer else [cls() for cls in _REGISTRY.values()]
    files = [c for c in sorted(directory.iterdir()) if c.is_file() and not c.name.startswith(".")]
    return [(imp, f) for f in files for imp in candidates if imp.sniff(f)]


def resolve(fmt: str, sources: Sequence[Path]) -> tuple[Importer, list[Path]]:
    """The importer for `sources` ('auto' detects it from the first) and the sources to give it.

    A directory that the format does not read as a whole (a Rawseeds session is read whole)
    stands for the one log of that format inside it, e.g. a `toolkit simulate` output."""
    _load_all()
    first = Path(sources[0])
    if not first.exists():
        raise ToolkitError("no such file or directory", file=first)
    importer = get(fmt) if fmt != "auto" else None
    if importer is None:
        hits = _claims(first)
        if len(hits) > 1:
            raise ToolkitError(
                f"ambiguous format ({', '.join(h.name for h in hits)}); name it", file=first
            )
        importer = hits[0] if hits else None
    if importer is not None and (not first.is_dir() or importer.sniff(first)):
        return importer, list(sources)
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


def detect(sources: Sequence[Path]) -> Importer:
    """The importer that `toolkit import auto` would use for `sources`."""
    return resolve("auto", sources)[0]


def import_log(
    fmt: str,
    sources: Sequence[str | Path],
    out: str | Path,
    options: ImportOptions | None = None,
    force: bool = False,
) -> Path:
    """Import `sources` of format `fmt` ('auto' to detect) into the dataset directory `out`."""
    paths = [Path(s) for s in sources]
    if not paths:
        raise ToolkitError("no source given")
    for p in paths:
        check_readable(p)
    importer, paths = resolve(fmt, paths)
    return importer.import_to(paths, Path(out), options or ImportOptions(), force=force)
