"""Option parsing shared by the commands."""

from __future__ import annotations

from toolkit.errors import ToolkitError


def key_values(pairs: list[str] | None, flag: str) -> dict[str, str]:
    """Repeated `FLAG KEY=VALUE` options as a dict; a malformed one is a one-line error."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ToolkitError(f"{flag} {pair!r} is not KEY=VALUE")
        out[key.strip()] = value.strip()
    return out
