"""Importers: one module per source format, found by a registry.

A module in this package that defines an `Importer` subclass decorated with `@register`
is picked up by `toolkit import` and by format auto-detection; nothing else to edit.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Sequence
from pathlib import Path

from importers.base import Importer, ImportOptions
from toolkit.errors import ToolkitError

__all__ = ["ImportOptions", "Importer", "detect", "get", "import_log", "names", "register"]

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


def detect(sources: Sequence[Path]) -> Importer:
    """The one importer whose sniffer accepts the first source."""
    _load_all()
    first = Path(sources[0])
    if not first.exists():
        raise ToolkitError("no such file or directory", file=first)
    hits = [cls() for cls in _REGISTRY.values() if cls().sniff(first)]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        raise ToolkitError(
            f"cannot tell the format; name it (one of {', '.join(names())})", file=first
        )
    raise ToolkitError(f"ambiguous format ({', '.join(h.name for h in hits)}); name it", file=first)


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
        if not p.exists():
            raise ToolkitError("no such file or directory", file=p)
    importer = detect(paths) if fmt == "auto" else get(fmt)
    return importer.import_to(paths, Path(out), options or ImportOptions(), force=force)
