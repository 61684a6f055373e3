"""Fig. 8-10: learnt features along the map, the found / not-found view, and the 3D map.

For every log with training regions (the simulated corridor always; the real Intel log with
datasets/real-regions/intel-regions.csv; each given or bundled log with a regions CSV): the
feature model is learnt from the training scans (about ten per feature) with the toolkit's
defaults, and every scan gets a probability per feature.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from reports.base import Figure, NotAvailable, Section, new_figure, save_figure, save_table
from reports.context import Context
from reports.runs import safe_name, world_points
from toolkit.dataset import Dataset, path_distance
from toolkit.features import balanced_accuracy
from toolkit.features.run import LabelRun
from toolkit.poses import poses_at

KEY = "features"
TITLE = "Fig. 8-10: learnt features"
INTRO = (
    "Each feature is learnt from its training scans (one Gaussian per beam); every scan then "
    "gets a probability per feature. Fig. 8 plots it along the path with the training "
    "positions marked, Fig. 9 shows where each feature is found (red) or not (blue), Fig. 10 "
    "the 3D map coloured by the label of the scan that saw each point."
)

MAX_MAP_POINTS = 25_000  # drawn in the 3D view (all are counted)


def map_poses(ctx: Context, name: str) -> tuple[np.ndarray, str]:
    """Poses at the scan times for drawing the map: the Gaussian-corrected trajectory when
    there is one, else odometry (said in the caption)."""
    ds = ctx.dataset(name)
    try:
        run = ctx.run(name, "gaussian")
        return poses_at(run.trajectory, ds.t), "the Gaussian-corrected trajectory"
    except NotAvailable:
        if ds.odometry is None:
            raise NotAvailable(f"{name}: no trajectory and no odometry to draw a map") from None
        return poses_at(ds.odometry, ds.t), "odometry (no corrected trajectory available)"


def generate(ctx: Context, section: Section) -> None:
    for name in ctx.labelled_logs():
        with ctx.part(section, f"features of {name}"):
            labelled = ctx.labels(name)
            ds = ctx.dataset(name)
            poses, how = map_poses(ctx, name)
            section.data[name] = _features(ctx, section, name, labelled.run, ds, poses, how)
            section.links += [(f"{name} {Path(f).name}", f) for f in labelled.files]


def _features(
    ctx: Context,
    section: Section,
    name: str,
    run: LabelRun,
    ds: Dataset,
    poses: np.ndarray,
    how: str,
) -> dict[str, Any]:
    features = list(run.training)
    label = np.asarray(run.labels.label).astype(str)
    distance = path_distance(poses[:, :2])
    data: dict[str, Any] = {"features": features, "label": label, "distance": distance}
    data["probability"] = {f: run.probability(f) for f in features}
    data["training"] = {f: np.asarray(run.training[f]) for f in features}
    data["found"] = {f: label == f for f in features}

    rows = []
    for f in features:
        row: dict[str, Any] = {
            "feature": f,
            "training scans": len(run.training[f]),
            "scans found": int((label == f).sum()),
            "mean p on training scans": float(run.probability(f)[run.training[f]].mean()),
        }
        if run.truth is not None:
            true = run.truth == f
            found = label == f
            row["true scans"] = int(true.sum())
            row["recall"] = float((found & true).sum() / max(true.sum(), 1))
            row["precision"] = float((found & true).sum() / found.sum()) if found.any() else np.nan
        rows.append(row)
    table = pd.DataFrame(rows)
    data["table"] = table
    if run.truth is not None:
        data["balanced_accuracy"] = float(balanced_accuracy(run.truth, label))
        section.notes.append(
            f"{name}: balanced accuracy of the labels against the simulator's truth "
            f"{data['balanced_accuracy']:.3f} over {len(label)} scans (learning and labelling "
            f"took {run.seconds:.2f} s in this run)."
        )
    section.tables.append(
        save_table(
            table,
            ctx.out,
            f"features_{safe_name(name)}",
            f"Features of {name}",
            "Per feature: training scans, scans labelled with it"
            + (
                ", and recall / precision against the simulator's truth"
                if run.truth is not None
                else ""
            ),
            {"mean p on training scans": "{:.3f}", "recall": "{:.3f}", "precision": "{:.3f}"},
        )
    )
    section.figures.append(_fig8(ctx, name, data, run, how))
    section.figures.append(_fig9(ctx, name, data, ds, poses, how))
    with ctx.part(section, f"Fig. 10 ({name}), the 3D map"):
        section.figures.append(_fig10(ctx, name, data, ds, poses, how))
    return data


def _fig8(ctx: Context, name: str, data: dict[str, Any], run: LabelRun, how: str) -> Figure:
    features, distance = data["features"], data["distance"]
    fig = new_figure(8.0, 1.5 + 1.3 * len(features))
    axes = fig.subplots(len(features), 1, sharex=True, squeeze=False)[:, 0]
    for ax, f in zip(axes, features, strict=True):
        p = data["probability"][f]
        ax.plot(distance, p, lw=0.9, color="tab:blue")
        if run.truth is not None:
            ax.fill_between(
                distance,
                0,
                1,
                where=run.truth == f,
                color="tab:green",
                alpha=0.15,
                lw=0,
                label="true place",
            )
        idx = data["training"][f]
        ax.plot(distance[idx], p[idx], "v", color="tab:red", ms=4, label="training scans")
        ax.set_ylim(-0.05, 1.1)
        ax.set_ylabel(f"p({f})", fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel(f"distance along the path (m), from {how}")
    return save_figure(
        fig,
        ctx.out,
        f"fig8_probability_{safe_name(name)}",
        f"Fig. 8 ({name}): probability of each feature along the map",
        "Per feature, its probability at every scan against the distance travelled; red "
        "triangles mark the training scans"
        + (
            "; the green band is where the simulator says the place is."
            if run.truth is not None
            else "."
        ),
        {"distance": distance, "probability": data["probability"], "training": data["training"]},
    )


def _fig9(
    ctx: Context, name: str, data: dict[str, Any], ds: Dataset, poses: np.ndarray, how: str
) -> Figure:
    features = data["features"]
    cols = min(3, len(features))
    rows = int(np.ceil(len(features) / cols))
    fig = new_figure(4.2 * cols, 3.6 * rows)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    try:
        background = world_points(ds, poses, every=max(1, ds.n_scans // 400))[0][:, :2]
    except NotAvailable:
        background = None
    for ax, f in zip(axes, features, strict=False):
        found = data["found"][f]
        if background is not None:
            ax.plot(*background.T, ",", color="0.75", rasterized=True)
        ax.plot(
            *poses[~found, :2].T, ".", ms=2, color="tab:blue", label="not found", rasterized=True
        )
        ax.plot(*poses[found, :2].T, ".", ms=3, color="tab:red", label="found", rasterized=True)
        ax.set_title(f, fontsize=9)
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=7)
    for ax in axes[len(features) :]:
        ax.axis("off")
    axes[0].legend(fontsize=7, markerscale=2)
    return save_figure(
        fig,
        ctx.out,
        f"fig9_found_{safe_name(name)}",
        f"Fig. 9 ({name}): where each feature is found",
        f"Robot positions from {how}: red where the scan is labelled with the feature, blue "
        "where it is not" + ("; grey: the map." if background is not None else "."),
        {"positions": poses[:, :2], "found": data["found"]},
    )


def _fig10(
    ctx: Context, name: str, data: dict[str, Any], ds: Dataset, poses: np.ndarray, how: str
) -> Figure:
    points, scan_of_point = world_points(ds, poses)
    fig = new_figure(8.0, 6.0)
    ax = fig.add_subplot(projection="3d")
    labels = data["label"][scan_of_point]  # each point takes the label of the scan that saw it
    thin = slice(None, None, max(1, len(points) // MAX_MAP_POINTS))
    shown, shown_labels = points[thin], labels[thin]
    counts: dict[str, int] = {}
    for k, cls in enumerate(["none", *data["features"]]):
        counts[cls] = int((labels == cls).sum())
        sel = shown_labels == cls
        if sel.any():
            colour = "0.6" if cls == "none" else f"C{k}"
            ax.plot(*shown[sel].T, ".", ms=0.8, color=colour, label=cls, rasterized=True)
    ax.legend(fontsize=7, markerscale=12, loc="upper left")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_zlim(0.0, max(1.0, 2.0 * float(ds.laser.z)))
    return save_figure(
        fig,
        ctx.out,
        f"fig10_map3d_{safe_name(name)}",
        f"Fig. 10 ({name}): the 3D map",
        f"Every return at its world position and the laser's mounting height, poses from {how}, "
        "coloured by the label of the scan that saw it.",
        {"points": len(points), "z": np.unique(np.round(points[:, 2], 6)), "label_counts": counts},
    )
