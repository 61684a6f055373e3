"""Option parsing and outcome reports shared by the commands."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import typer

from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    from toolkit.app.fleet import Outcome


def key_values(pairs: list[str] | None, flag: str) -> dict[str, str]:
    """Repeated `FLAG KEY=VALUE` options as a dict (text: the format or the simulator converts
    each to its type); a malformed or repeated one is a one-line error."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ToolkitError(f"{flag} {pair!r} is not KEY=VALUE")
        if key.strip() in out:
            raise ToolkitError(f"{flag} {key.strip()}= given twice; give it once")
        out[key.strip()] = value.strip()
    return out


def report_outcomes(outcomes: list[Outcome], out: Path, noun: str, quiet: bool) -> None:
    """A line per failure on stderr (`failed: INPUT: why`), a count line, exit 1 if any failed."""
    failed = [o for o in outcomes if o.status == "failed"]
    for o in failed:
        typer.echo(f"failed: {o.source}: {o.error}", err=True)
    if not quiet:
        counts = {s: sum(o.status == s for o in outcomes) for s in ("written", "skipped")}
        typer.echo(
            f"{out}: {counts['written']} written, {counts['skipped']} skipped (complete), "
            f"{len(failed)} failed, of {len(outcomes)} {noun}"
        )
    if failed:
        raise typer.Exit(1)
