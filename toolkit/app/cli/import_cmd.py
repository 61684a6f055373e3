"""`toolkit import FORMAT SOURCE... --out DATASET [--each [--scheduler none|local:N|ADDRESS]]`"""

from __future__ import annotations

import shutil
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from toolkit.app.cli import app
from toolkit.app.cli.options import key_values, report_outcomes
from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    from importers.base import ImportOptions, OptionSpec


@app.command("import", short_help="Import a log (or, with --each, many) into a dataset.")
def import_command(
    fmt: Annotated[
        str,
        typer.Argument(
            metavar="FORMAT", help="auto, or one of the formats `toolkit formats` lists"
        ),
    ],
    sources: Annotated[
        list[Path],
        typer.Argument(
            metavar="SOURCE", help="log files or a session directory", show_default=False
        ),
    ],
    out: Annotated[Path, typer.Option("--out", metavar="DIR", help="dataset directory to write")],
    force: Annotated[bool, typer.Option("--force", help="replace an existing dataset")] = False,
    rate: Annotated[
        float | None,
        typer.Option(
            metavar="HZ",
            help="scans per second, for logs without a clock (carmen, aria, lms200, table)",
        ),
    ] = None,
    scan_topic: Annotated[
        str | None, typer.Option(metavar="TOPIC", help="rosbag: the LaserScan topic")
    ] = None,
    odom_topic: Annotated[
        str | None, typer.Option(metavar="TOPIC", help="rosbag: the odometry topic")
    ] = None,
    laser: Annotated[
        str | None,
        typer.Option(metavar="NAME", help="carmen, rawseeds: which laser is the primary one"),
    ] = None,
    option: Annotated[
        list[str] | None,
        typer.Option(
            "--option",
            "-O",
            metavar="KEY=VALUE",
            help="a format option, repeatable; `toolkit formats` lists each format's; an "
            "option or flag the format does not have is an error",
        ),
    ] = None,
    each: Annotated[
        bool,
        typer.Option(
            "--each",
            help="many logs: every SOURCE file, quoted glob pattern, or log found in a "
            "directory tree becomes its own dataset OUT/dataset=<name> (a hive-partitioned "
            "fleet); complete ones are skipped",
        ),
    ] = False,
    scheduler: Annotated[
        str,
        typer.Option(
            metavar="WHERE",
            help="with --each: where the imports run: none (this process), local or local:N "
            "(a Dask LocalCluster of N workers) or a Dask scheduler's address",
        ),
    ] = "none",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no summary")] = False,
) -> None:
    """Import a log into a dataset directory (Parquet + meta.json), atomically; or, with
    --each, many logs into one dataset each."""
    # on use: the importers and their format libraries load for `import` alone
    import importers
    from toolkit.app.cli.info_cmd import print_summary
    from toolkit.info import summary_of

    options = importers.ImportOptions(
        rate=rate,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        laser=laser,
        extra=key_values(option, "-O"),
    )
    if fmt != "auto":  # a bad option fails once, up front, not once per log
        importers.read_options(importers.get(fmt), options)
    if each or scheduler != "none":
        _import_each(fmt, sources, out, options, force, scheduler, quiet)
        return
    written = importers.import_log(fmt, sources, out, options, force=force)
    if not quiet:
        print_summary(summary_of(written))


def _import_each(
    fmt: str,
    sources: list[Path],
    out: Path,
    options: ImportOptions,
    force: bool,
    scheduler: str,
    quiet: bool,
) -> None:
    """One dataset per log; a line per failure on stderr and exit 1 if any failed."""
    from toolkit.app.fleet import client_for, find_logs, import_many  # Dask, on use

    logs = find_logs(fmt, sources)
    if not logs:
        raise ToolkitError(f"no {'' if fmt == 'auto' else fmt + ' '}log found in the sources")
    with client_for(scheduler) as client:
        outcomes = import_many(client, fmt, logs, out, options, force)
    report_outcomes(outcomes, out, "logs", quiet)


@app.command("formats", short_help="List the formats: read/write, sources, options.")
def formats_command(
    name: Annotated[
        str | None, typer.Argument(metavar="FORMAT", help="one format only (default: all)")
    ] = None,
) -> None:
    """List the log formats: which the toolkit reads and writes, what each reads, and each
    format's options: `-O KEY=VALUE` of `toolkit import` (reading) and of `toolkit simulate`
    (writing), with type, default and meaning."""
    import importers  # on use: every format's module

    chosen = [importers.get(name)] if name else [importers.get(n) for n in importers.names()]
    width = _width()
    typer.echo(f"{'FORMAT':9s} {'READ':5s} {'WRITE':5s} SOURCES")
    for imp in chosen:
        row = f"{imp.name:9s} {'yes':5s} {'yes' if imp.writes else 'no':5s} {imp.summary}"
        typer.echo(textwrap.fill(row, width, subsequent_indent=" " * 22))
    for imp in chosen:
        typer.echo(f"\n{imp.name}: toolkit import {imp.name} SOURCE --out DIR -O KEY=VALUE ...")
        _print_options(imp.Options.specs())
        if imp.WriteOptions is not None:
            typer.echo(f"{imp.name} writer: toolkit simulate ... -f {imp.name} -O KEY=VALUE ...")
            _print_options(imp.WriteOptions.specs(flags=False))


def _print_options(specs: list[OptionSpec]) -> None:
    """Per option: KEY=TYPE (default), the flag that sets it too, then its help, wrapped."""
    width = _width()
    for s in specs:
        flag = f"; also {s.flag}" if s.flag else ""
        typer.echo(f"  {s.name}={s.type}  (default {s.default}{flag})")
        typer.echo(textwrap.fill(s.help, width, initial_indent=" " * 6, subsequent_indent=" " * 6))


def _width() -> int:
    """The terminal's width for wrapped listings, within 60-100 columns."""
    return max(60, min(shutil.get_terminal_size().columns, 100))
