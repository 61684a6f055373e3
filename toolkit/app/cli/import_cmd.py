"""`toolkit import FORMAT SOURCE... --out DATASET [--each [--scheduler none|local:N|ADDRESS]]`"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from toolkit.app.cli import app
from toolkit.app.cli.options import key_values, report_outcomes
from toolkit.errors import ToolkitError


@app.command("import")
def import_command(
    fmt: Annotated[
        str,
        typer.Argument(
            metavar="FORMAT", help="auto, or one of the formats `toolkit formats` lists"
        ),
    ],
    sources: Annotated[list[Path], typer.Argument(help="log files or a session directory")],
    out: Annotated[Path, typer.Option("--out", "-o", help="dataset directory to write")],
    force: Annotated[bool, typer.Option("--force", help="replace an existing dataset")] = False,
    rate: Annotated[
        float | None, typer.Option(help="scans per second, for logs without a clock")
    ] = None,
    scan_topic: Annotated[str | None, typer.Option(help="ROS bags: the LaserScan topic")] = None,
    odom_topic: Annotated[str | None, typer.Option(help="ROS bags: the odometry topic")] = None,
    laser: Annotated[str | None, typer.Option(help="which laser is the primary one")] = None,
    option: Annotated[
        list[str] | None,
        typer.Option("--option", "-O", help="format-specific KEY=VALUE (see `toolkit formats`)"),
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
            help="with --each: where the imports run: none (this process), local or local:N "
            "(a Dask LocalCluster of N workers) or a Dask scheduler's address"
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
    options: object,
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


@app.command("formats")
def formats_command() -> None:
    """List the source formats, what auto-detection looks for, and their options."""
    import importers  # on use: every format's module

    for name in importers.names():
        imp = importers.get(name)
        typer.echo(f"{name:10s} {imp.summary}")
        for key, help_ in imp.options.items():
            typer.echo(f"{'':10s}   -O {key}=...  {help_}")
