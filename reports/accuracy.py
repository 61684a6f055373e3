"""Accuracy against ground truth, which the paper does not give: ATE and RPE of every method
on every log that has ground truth, with the time spent aligning, measured in this run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from reports.base import Section, save_table
from reports.context import CORRIDOR, Context

KEY = "accuracy"
TITLE = "Accuracy against ground truth (ATE, RPE)"
INTRO = (
    "Absolute trajectory error (RMS position error after the best rigid alignment) and "
    "relative pose error per scan step, for odometry alone and every scan matcher, on every "
    "log; a failure is a step off by more than 0.2 m or 5°. Logs without ground truth show "
    "only the time. Every run's trajectory (TUM format, for evo) and metrics.json are in runs/."
)


def generate(ctx: Context, section: Section) -> None:
    rows: list[dict[str, Any]] = []
    for name in ctx.map_logs():
        with ctx.part(section, f"accuracy on {name}"):
            ds = ctx.dataset(name)
            for method in ctx.methods(name):
                run = ctx.run(name, method)
                rows.append(_row(name, ds.n_scans, method, run.metrics))
                section.links += [(f"{name} {method} {Path(f).name}", f) for f in run.files]
            if ds.groundtruth is None:
                section.notes.append(f"{name} has no ground truth: ATE and RPE are not computable.")
    logs = _logs(ctx)
    if not logs.empty:
        section.data["logs"] = logs
        section.tables.append(
            save_table(
                logs,
                ctx.out,
                "logs",
                "The logs of this report",
                "Every log mapped or labelled: where it comes from, its scans, whether it has "
                "ground truth and training regions.",
            )
        )
    if not rows:
        return
    table = pd.DataFrame(rows)
    section.data["accuracy"] = table
    section.tables.append(
        save_table(
            table,
            ctx.out,
            "accuracy",
            "Accuracy of every method on every log",
            "ATE RMSE (m), RPE per step (translation cm, rotation deg, RMS), failed steps, time "
            "spent aligning (s) and pairs aligned per second, measured in this run.",
            {
                "ATE (m)": "{:.3f}",
                "RPE (cm)": "{:.2f}",
                "RPE (deg)": "{:.3f}",
                "failures (%)": "{:.1f}",
                "aligning (s)": "{:.2f}",
                "pairs/s": "{:.0f}",
            },
        )
    )


def _logs(ctx: Context) -> pd.DataFrame:
    rows = []
    for name in dict.fromkeys([*ctx.map_logs(), *ctx.labelled_logs()]):
        source = ctx.sources.get(name)
        ds = ctx.loaded(name)
        if source is None or ds is None:
            continue  # never loaded: its sections say why
        rows.append(
            {
                "log": name,
                "origin": source.origin,
                "scans": ds.n_scans,
                "beams": ds.n_beams,
                "ground truth": "yes" if ds.groundtruth is not None else "no",
                "regions": source.regions.name
                if source.regions is not None
                else ("the simulator's" if name == CORRIDOR else ""),
                "about": source.note,
            }
        )
    return pd.DataFrame(rows)


def _row(name: str, scans: int, method: str, metrics: dict[str, Any]) -> dict[str, Any]:
    nan = float("nan")
    ate = metrics.get("ate", {})
    rpe = metrics.get("rpe", {})
    fails = metrics.get("failures", {})
    steps = fails.get("steps") or 0
    aligning = metrics.get("seconds_aligning") if method != "odometry" else None
    pairs_per_s = metrics.get("pairs_per_second") if method != "odometry" else None
    return {
        "log": name,
        "scans": scans,
        "method": method,
        "ATE (m)": ate.get("rmse", nan),
        "RPE (cm)": 100 * rpe["translation"] if "translation" in rpe else nan,
        "RPE (deg)": rpe.get("rotation_deg", nan),
        "failures (%)": 100 * fails["count"] / steps if steps else nan,
        "aligning (s)": nan if aligning is None else float(aligning),
        "pairs/s": nan if pairs_per_s is None else float(pairs_per_s),
    }
