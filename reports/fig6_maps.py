"""Fig. 6-7: the map from odometry alone beside the maps from the corrected trajectories.

Fig. 6 is the simulator's corridor; Fig. 7 the real logs: the DP-SLAM loop (raw odometry, no
ground truth) and the Intel lab, whose SLAM-corrected poses serve as ground truth and whose
odometry is replaced by drifting wheel odometry simulated along them. Then every dataset
given on the command line.
"""

from __future__ import annotations

from typing import Any

from reports.base import Section, new_figure, save_figure
from reports.context import CORRIDOR, Context
from reports.runs import safe_name, world_points
from toolkit.poses import truth_poses

KEY = "maps"
TITLE = "Fig. 6-7: odometry against corrected maps"
INTRO = (
    "Each log's map (every return placed at its pose) from odometry alone, beside the maps "
    "from the trajectories the scan matchers correct; ATE against ground truth in the "
    "titles where the log has one."
)

MAX_POINTS = 80_000


def generate(ctx: Context, section: Section) -> None:
    for name in ctx.map_logs():
        with ctx.part(section, f"maps of {name}"):
            section.data[name] = _maps(ctx, section, name)


def _maps(ctx: Context, section: Section, name: str) -> dict[str, Any]:
    ds = ctx.dataset(name)
    methods = list(ctx.methods(name))
    if ds.odometry is None:
        section.notes.append(f"{name} has no odometry: its scans are matched from standstill.")
    runs = {m: ctx.run(name, m) for m in methods}
    truth = ds.groundtruth is not None
    every = max(1, ds.n_scans * ds.n_beams // (2 * MAX_POINTS))
    data: dict[str, Any] = {"methods": methods, "scans": ds.n_scans}
    data.update(trajectories={}, ate={}, points={})
    fig = new_figure(4.6 * len(methods), 4.8)
    axes = fig.subplots(1, len(methods), squeeze=False)[0]
    gt = None
    if truth:
        gt = truth_poses(ds)
    for ax, method in zip(axes, methods, strict=True):
        run = runs[method]
        poses = run.trajectory[["x", "y", "theta"]].to_numpy()
        points, _ = world_points(ds, poses, every=every)
        data["trajectories"][method] = poses
        data["points"][method] = len(points)
        ate = run.metrics.get("ate", {}).get("rmse") if truth else None
        data["ate"][method] = ate
        ax.plot(points[:, 0], points[:, 1], ",", color="0.2", alpha=0.5, rasterized=True)
        if gt is not None:
            ax.plot(gt[:, 0], gt[:, 1], "--", color="tab:green", lw=0.9, label="ground truth")
        ax.plot(poses[:, 0], poses[:, 1], color="tab:red", lw=0.9, label="trajectory")
        ax.set_title(method + (f": ATE {ate:.2f} m" if ate is not None else ""), fontsize=10)
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7, loc="best")
    fig_no = "6" if name == CORRIDOR else "7"
    source = ctx.sources.get(name)
    note = f" ({source.note})" if source is not None and source.note else ""
    caption = (
        f"{name}{note}: the map from odometry alone (left, when the log has odometry) and from "
        "the trajectories corrected "
        "by "
        + ", ".join(ctx.matchers)
        + "; red the trajectory"
        + (", dashed green the ground truth" if gt is not None else "; the log has no ground truth")
        + (f"; every {every}th scan drawn." if every > 1 else ".")
    )
    section.figures.append(
        save_figure(
            fig,
            ctx.out,
            f"fig{fig_no}_maps_{safe_name(name)}",
            f"Fig. {fig_no} ({name}): odometry against corrected maps",
            caption,
            data,
        )
    )
    if gt is not None and "odometry" in methods:
        odo, best = data["ate"]["odometry"], min(data["ate"][m] for m in ctx.matchers)
        section.notes.append(f"{name}: ATE from odometry {odo:.3f} m, best corrected {best:.3f} m.")
    return data
