"""Table 2 and Fig. 4-5: Gaussian alignment against ICP on random point clouds.

Two protocols (toolkit.align.protocol, the ones `make bench` runs too), at the paper's five
sizes: the paper's own first (coordinates 0-100 m, shift up to 1 m, 5 cm noise), then the
project's dense cube (1 m, 1 cm noise). The methods are timed interleaved in one process,
in the run that writes the report.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from reports.base import Figure, Section, new_figure, save_figure, save_table
from reports.context import Context
from toolkit.align.protocol import (
    DENSE,
    PAPER,
    SIZES,
    TRIALS,
    Protocol,
    random_cloud_trials,
    summarize,
)

KEY = "table2"
TITLE = "Table 2 and Fig. 4-5: random point clouds"
INTRO = (
    "Random 3D clouds of 100 to 10,000 points, shifted and with noise added; the Gaussian "
    "alignment knows the correspondence by index, ICP (Open3D) finds it by nearest neighbours. "
    "First the paper's protocol (coordinates between 0 and 100 m, shift up to 1 m per axis, "
    "5 cm noise), then a dense cube (1 m, shift up to 5 cm, 1 cm noise) where ICP's "
    "neighbours are often wrong. Mean translation error over the trials and median time per "
    "alignment, the methods timed in turn, trial by trial, in this run."
)

LABELS = {"gaussian": "Gaussian (text Eq. 6)", "gaussian-paper": "Gaussian (printed Eq. 6)"}


QUICK_TRIALS = 2


def cloud_rows(ctx: Context, protocol: Protocol = PAPER) -> pd.DataFrame:
    """The protocol's summary at the paper's sizes: one row per method and size."""
    ctx.step(f"random clouds, {protocol.name} protocol")
    trials = QUICK_TRIALS if ctx.quick else TRIALS
    return summarize(random_cloud_trials(SIZES, trials, protocol=protocol))


def generate(ctx: Context, section: Section) -> None:
    for protocol in (PAPER, DENSE):
        table = _table(cloud_rows(ctx, protocol))
        paper = protocol is PAPER
        key = "table2" if paper else f"table2_{protocol.name}"
        section.data[key] = table
        section.tables.append(
            save_table(
                table,
                ctx.out,
                "table2_clouds" if paper else f"table2_clouds_{protocol.name}",
                f"Table 2{'' if paper else ' (second protocol)'}: random clouds, {protocol.title}",
                "Translation error (mean over trials) and median time per alignment, by cloud "
                f"size; {protocol.title}.",
                {"error (mm)": "{:.3f}", "error std (mm)": "{:.3f}", "time (ms)": "{:.3f}"},
            )
        )
        suffix = "" if paper else f"_{protocol.name}"
        section.figures.append(_time_figure(ctx, table, False, protocol, suffix))
        if paper:
            section.figures.append(_time_figure(ctx, table, True, protocol, suffix))


def _table(frame: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "points": frame["points"].astype(int),
            "method": frame["method"].astype(str),
            "trials": frame["trials"].astype(int),
            "error (mm)": 1000.0 * frame["error_m"].astype(float),
            "error std (mm)": 1000.0 * frame["error_std_m"].astype(float),
            "time (ms)": 1000.0 * frame["seconds"].astype(float),
            "speed-up vs ICP": frame["speedup_vs_icp"].astype(float),
        }
    )  # summarize's rows come sorted by points, then method


def _time_figure(
    ctx: Context, table: pd.DataFrame, ours_only: bool, protocol: Protocol, suffix: str
) -> Figure:
    fig = new_figure(6.0, 4.0)
    ax = fig.add_subplot()
    data: dict[str, dict[str, list[float]]] = {}
    for method, rows in table.groupby("method", sort=True):
        name = str(method)
        if ours_only and not name.startswith("gaussian"):
            continue
        rows = rows.sort_values("points")
        x = rows["points"].to_numpy(dtype=float)
        y = rows["time (ms)"].to_numpy(dtype=float)
        data[name] = {"points": x.tolist(), "time_ms": y.tolist()}
        ax.plot(x, y, marker="o", label=LABELS.get(name, name.upper()))
    ax.set_xscale("log")
    if not ours_only:
        ax.set_yscale("log")
    ax.set_xlabel("points")
    ax.set_ylabel("time per alignment (ms)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    if ours_only:
        name, title = "fig5_time_gaussian", "Fig. 5: run time against size, Gaussian alignment"
        caption = (
            "Median time per alignment of the Gaussian alignment alone (linear in N); "
            f"{protocol.title}."
        )
        # a straight line through the origin is what O(N) predicts
        for values in data.values():
            x, y = np.array(values["points"]), np.array(values["time_ms"])
            values["slope_ms_per_point"] = [float(np.dot(x, y) / np.dot(x, x))]
    else:
        name, title = "fig4_time_both", "Fig. 4: run time against size, both methods"
        caption = (
            f"Median time per alignment, Gaussian alignment and ICP (log-log); {protocol.title}."
        )
    if suffix:
        name, title = name + suffix, f"{title} ({protocol.name} protocol)"
    return save_figure(fig, ctx.out, name, title, caption, data)
