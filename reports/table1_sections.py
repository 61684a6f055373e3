"""Table 1: per corridor section, the alignment error, its standard deviation and the
computing time of the Gaussian alignment against ICP.

The corridor is the simulator's (8 sections of 250 scans, as in the paper). Each section is
matched on its own by each method, timed in this run (after a warm-up, so no timing includes
compiling a kernel). The alignment error of a scan pair is the translation error of the
estimated motion between the two scans against the true motion (the RPE of one step).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pandas as pd

from reports.base import Figure, NotAvailable, Section, new_figure, save_figure, save_table
from reports.context import CORRIDOR, Context
from reports.runs import safe_name, slice_scans, warm_up
from toolkit.metrics import RPE
from toolkit.poses import build, truth_poses

SECTIONS = 8  # the paper's

KEY = "table1"
TITLE = "Table 1: alignment per section"
INTRO = (
    "The simulated corridor section by section (and the Intel lab with drift added, in 8 "
    "equal parts): mean and standard deviation of the "
    "translation error of each scan pair's estimated motion against the true motion, and the "
    "time spent aligning the section's pairs, for the Gaussian alignment, ICP point-to-line "
    "and ICP point-to-point (Open3D); odometry's own error for reference."
)


def sections_of(ctx: Context, name: str) -> np.ndarray:
    """Section per scan: the simulator's for the corridor, else 8 equal consecutive parts."""
    if name == CORRIDOR:
        return np.asarray(ctx.corridor().sections)
    n = ctx.dataset(name).n_scans
    return (np.arange(n) * SECTIONS) // max(n, 1)


def section_rows(ctx: Context, name: str = CORRIDOR) -> pd.DataFrame:
    """Long table: section, method, pairs, error mean/std (m), rotation error, seconds."""
    ds = ctx.dataset(name)
    if ds.groundtruth is None:
        raise NotAvailable(f"{name} has no ground truth")
    sections = sections_of(ctx, name)
    rows: list[dict[str, Any]] = []
    for method in ctx.matchers:
        warm_up(ds, method)
    for k in sorted(set(sections[sections >= 0].tolist())):
        index = np.flatnonzero(sections == k)
        part = slice_scans(ds, index)
        truth = truth_poses(part)
        assert truth is not None  # the log has ground truth (checked above)
        for method in ("odometry", *ctx.matchers):
            ctx.step(f"{name} section {k + 1}, {method}")
            t0 = time.perf_counter()
            result = build(part, method)
            wall = time.perf_counter() - t0
            err_t, err_r = RPE.step_errors(result.poses, truth)
            rows.append(
                {
                    "section": k + 1,
                    "method": method,
                    "pairs": len(err_t),
                    "error_m": float(err_t.mean()),
                    "std_m": float(err_t.std(ddof=1)),
                    "rotation_error_deg": float(np.rad2deg(err_r.mean())),
                    "seconds": float(result.seconds) if method != "odometry" else float("nan"),
                    "wall_seconds": wall,
                }
            )
    return pd.DataFrame(rows)


def wide(rows: pd.DataFrame, methods: tuple[str, ...]) -> pd.DataFrame:
    """The paper's layout: one row per section, error / std / time side by side per method."""
    out = rows.loc[rows["method"] == "odometry", ["section", "pairs"]].reset_index(drop=True)
    out["odometry error (cm)"] = 100 * rows.loc[rows["method"] == "odometry", "error_m"].to_numpy()
    for method in methods:
        part = rows.loc[rows["method"] == method].reset_index(drop=True)
        out[f"{method} error (cm)"] = 100 * part["error_m"]
        out[f"{method} std (cm)"] = 100 * part["std_m"]
        out[f"{method} time (ms)"] = 1000 * part["seconds"]
    return out


def generate(ctx: Context, section: Section) -> None:
    for name in ctx.sectioned_logs():
        with ctx.part(section, f"Table 1 on {name}"):
            section.data[name] = _table1(ctx, section, name)


def _table1(ctx: Context, section: Section, name: str) -> dict[str, Any]:
    rows = section_rows(ctx, name)
    table = wide(rows, ctx.matchers)
    fmt = {c: "{:.2f}" for c in table.columns if "(cm)" in c}
    fmt.update({c: "{:.1f}" for c in table.columns if "(ms)" in c})
    n = ctx.dataset(name).n_scans
    if name == CORRIDOR:
        what = "the simulated corridor" + (f", {n} scans in all (quick mode)" if ctx.quick else "")
    else:
        source = ctx.sources.get(name)
        what = f"{name} ({source.note if source else ''}), {n} scans cut in 8 equal parts"
    suffix = "" if name == CORRIDOR else "_" + safe_name(name)
    section.tables.append(
        save_table(
            table,
            ctx.out,
            f"table1_sections{suffix}",
            f"Table 1 ({name}): alignment error and time per section",
            f"Per section of {what}: mean and standard deviation of the per-pair translation "
            "error against the truth (cm), and the time spent aligning the section's pairs "
            "(ms), measured now.",
            fmt,
        )
    )
    figure = _figure(ctx, rows, ctx.matchers, name, suffix)
    section.figures.append(figure)
    return {"rows": rows, "table1": table, "figure": figure.data}


def _figure(
    ctx: Context, rows: pd.DataFrame, matchers: tuple[str, ...], name: str, suffix: str
) -> Figure:
    fig = new_figure(7.5, 3.8)
    ax = fig.add_subplot()
    methods = ["odometry", *matchers]
    width = 0.8 / len(methods)
    data = {}
    for j, method in enumerate(methods):
        part = rows.loc[rows["method"] == method]
        x = part["section"].to_numpy() + (j - (len(methods) - 1) / 2) * width
        y, e = 100 * part["error_m"].to_numpy(), 100 * part["std_m"].to_numpy()
        ax.bar(x, y, width, yerr=e, capsize=2, label=method)
        data[method] = {"section": part["section"].tolist(), "error_cm": y, "std_cm": e}
    ax.set_xlabel(f"section of {name}")
    ax.set_ylabel("per-pair translation error (cm)")
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)
    return save_figure(
        fig,
        ctx.out,
        f"table1_sections{suffix}",
        f"Table 1 ({name}) as a chart",
        "Mean per-pair translation error per section, with one standard deviation.",
        data,
    )
