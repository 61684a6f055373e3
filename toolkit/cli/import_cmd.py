"""`toolkit import FORMAT SOURCE... --out DATASET`"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from toolkit.cli import app
from toolkit.cli.options import key_values


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
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no summary")] = False,
) -> None:
    """Import a log into a dataset directory (Parquet + meta.json), atomically."""
    import importers
    from toolkit.cli.info_cmd import print_summary
    from toolkit.dataset import load
    from toolkit.info import summary

    options = importers.ImportOptions(
        rate=rate,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        laser=laser,
        extra=key_values(option, "-O"),
    )
    written = importers.import_log(fmt, sources, out, options, force=force)
    if not quiet:
        print_summary(summary(load(written)))


@app.command("formats")
def formats_command() -> None:
    """List the source formats, what auto-detection looks for, and their options."""
    import importers

    for name in importers.names():
        imp = importers.get(name)
        typer.echo(f"{name:10s} {imp.summary}")
        for key, help_ in imp.options.items():
            typer.echo(f"{'':10s}   -O {key}=...  {help_}")
