"""The machine and the versions the report's timings were taken on (the paper gives neither)."""

from __future__ import annotations

import datetime as dt
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

import pandas as pd

import toolkit
from reports.base import Section, save_table
from reports.context import Context

KEY = "machine"
TITLE = "Machine and versions"
INTRO = (
    "Every time in this report was measured in the run that wrote it, on this machine, "
    "with these versions. The load average shows whether other work shared the CPUs."
)

PACKAGES = ("numpy", "scipy", "pandas", "pyarrow", "open3d", "numba", "matplotlib", "rosbags")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit(root: Path) -> str | None:
    try:
        done = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() or None if done.returncode == 0 else None


def machine_info() -> dict[str, Any]:
    """CPU, OS, Python and package versions, date, load: plain values."""
    info: dict[str, Any] = {
        "date (UTC)": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M:%S"),
        "cpu": cpu_model(),
        "cpus (logical)": os.cpu_count(),
        "cpus usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "load average (1, 5, 15 min)": " ".join(f"{x:.2f}" for x in os.getloadavg()),
        "os": platform.platform(),
        "python": platform.python_version(),
        "toolkit": toolkit.__version__,
        "git commit": git_commit(Path(__file__).resolve().parents[1]),
    }
    for name in PACKAGES:
        try:
            info[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            info[name] = "not installed"
    return info


def generate(ctx: Context, section: Section) -> None:
    info = machine_info()
    info["load average at the start of the run"] = " ".join(f"{x:.2f}" for x in ctx.load_at_start)
    section.data["machine"] = info
    cpus = os.cpu_count() or 1
    busiest = max(ctx.load_at_start[0], os.getloadavg()[0])
    if busiest > cpus:
        section.notes.append(
            f"The machine was shared during this run (1-minute load up to {busiest:.1f} on "
            f"{cpus} CPUs): the times are inflated and noisy, ICP's (multi-threaded Open3D) "
            "most of all. Rerun on an idle machine for figures to quote."
        )
    frame = pd.DataFrame({"item": list(info), "value": [str(v) for v in info.values()]})
    section.tables.append(
        save_table(
            frame, ctx.out, "machine", "Machine and versions", "Where the timings come from."
        )
    )
