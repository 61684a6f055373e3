"""Table 2 and Fig. 4-5: Gaussian alignment against ICP on random point clouds.

The protocol (cloud, shift, noise, trials, timing) is toolkit.align.protocol, the one
`make bench` runs too, at the paper's five sizes; the times are measured in the run that
writes the report.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from reports.base import Figure, Section, new_figure, save_figure, save_table
from reports.context import Context
from toolkit.align.protocol import SIZES, TRIALS, random_cloud_trials, summarize

KEY = "table2"
TITLE = "Table 2 and Fig. 4-5: random point clouds"
INTRO = (
    "Random 3D clouds of 100 to 10,000 points, shifted and with noise added; the Gaussian "
    "alignment knows the correspondence by index, ICP finds it by nearest neighbours. Mean "
    "translation error over the trials and median time per alignment, measured in this run."
)

LABELS = {"gaussian": "Gaussian (text Eq. 6)", "gaussian-paper": "Gaussian (printed Eq. 6)"}


QUICK_TRIALS = 2


def cloud_rows(ctx: Context) -> pd.DataFrame:
    """The protocol's summary at the paper's sizes: one row per method and size."""
    ctx.step("random clouds")
    return summarize(random_cloud_trials(SIZES, QUICK_TRIALS if ctx.quick else TRIALS))


def generate(ctx: Context, section: Section) -> None:
    frame = cloud_rows(ctx)
    table = pd.DataFrame(
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
    section.data["table2"] = table
    section.tables.append(
        save_table(
            table,
            ctx.out,
            "table2_clouds",
            "Table 2: random clouds, Gaussian alignment against ICP",
            "Translation error (mean over trials) and median time per alignment, by cloud size.",
            {"error (mm)": "{:.3f}", "error std (mm)": "{:.3f}", "time (ms)": "{:.3f}"},
        )
    )
    section.figures.append(_time_figure(ctx, table, ours_only=False))
    section.figures.append(_time_figure(ctx, table, ours_only=True))


def _time_figure(ctx: Context, table: pd.DataFrame, ours_only: bool) -> Figure:
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
        caption = "Median time per alignment of the Gaussian alignment alone (linear in N)."
        # a straight line through the origin is what O(N) predicts
        for values in data.values():
            x, y = np.array(values["points"]), np.array(values["time_ms"])
            values["slope_ms_per_point"] = [float(np.dot(x, y) / np.dot(x, x))]
    else:
        name, title = "fig4_time_both", "Fig. 4: run time against size, both methods"
        caption = "Median time per alignment, Gaussian alignment and ICP (log-log)."
    return save_figure(fig, ctx.out, name, title, caption, data)
