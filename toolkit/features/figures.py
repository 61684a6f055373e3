"""Figures and the labelled cloud: membership along the map (the paper's Fig. 8-10) and the
3D cloud coloured by label."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import open3d as o3d

from toolkit.atomic import atomic_file
from toolkit.dataset import Dataset, LaserGeometry
from toolkit.features.classify import Labels

NONE_GREY = (0.75, 0.75, 0.75)


def world_points(
    ranges: np.ndarray, poses: np.ndarray, laser: LaserGeometry, every: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """World (x, y) of every return (N, 2) and the scan index of each, scans subsampled."""
    idx = np.arange(0, len(ranges), max(every, 1))
    r = ranges[idx].astype(np.float64)
    ok = np.isfinite(r)
    ang = laser.angles[None, :] + laser.yaw
    lx = laser.x + r * np.cos(ang)
    ly = laser.y + r * np.sin(ang)
    th = poses[idx, 2:3]
    c, s = np.cos(th), np.sin(th)
    wx = poses[idx, 0:1] + c * lx - s * ly
    wy = poses[idx, 1:2] + s * lx + c * ly
    scan = np.broadcast_to(idx[:, None], r.shape)
    return np.column_stack([wx[ok], wy[ok]]), scan[ok]


def membership_figure(
    path: Path,
    ranges: np.ndarray,
    poses: np.ndarray,
    laser: LaserGeometry,
    labels: Labels,
    training: dict[str, np.ndarray],
    title: str = "",
) -> None:
    """One panel per feature: the map in grey, trajectory points coloured by the feature's
    probability, training positions marked; and a found/not-found panel per feature
    (red: labelled as the feature, blue: not), as in the paper's Fig. 9/10."""
    matplotlib.use("Agg")
    features = [c for c in labels.classes if c != "none"]
    pts, _ = world_points(ranges, poses, laser, every=max(1, len(ranges) // 400))
    n = len(features)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 8.4), squeeze=False)
    lo, hi = np.percentile(poses[:, :2], [0, 100], axis=0)
    pad = 0.1 * max(float((hi - lo).max()), 1.0)
    for k, feature in enumerate(features):
        col = labels.classes.index(feature)
        for row, ax in enumerate(axes[:, k]):
            ax.scatter(pts[:, 0], pts[:, 1], s=0.2, c="0.8", linewidths=0, rasterized=True)
            if row == 0:
                sc = ax.scatter(
                    poses[:, 0], poses[:, 1], c=labels.prob[:, col], cmap="viridis",
                    vmin=0, vmax=1, s=4, linewidths=0,
                )  # fmt: skip
                ax.set_title(f"P({feature})")
            else:
                found = labels.label == feature
                ax.scatter(poses[~found, 0], poses[~found, 1], c="tab:blue", s=3, linewidths=0)
                ax.scatter(poses[found, 0], poses[found, 1], c="tab:red", s=4, linewidths=0)
                ax.set_title(f"{feature}: found (red) / not (blue)")
            idx = training.get(feature, np.array([], dtype=int))
            ax.scatter(
                poses[idx, 0], poses[idx, 1], marker="x", c="black", s=18, linewidths=0.8,
                label="training",
            )  # fmt: skip
            ax.set_aspect("equal")
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            ax.tick_params(labelsize=7)
        axes[0, k].legend(loc="upper right", fontsize=7)
    fig.colorbar(sc, ax=axes[0, :].tolist(), shrink=0.8, label="probability")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110, format="png")
    plt.close(fig)


def label_colours(classes: list[str]) -> np.ndarray:
    """An RGB colour per class (tab10), grey for "none"."""
    cmap = matplotlib.colormaps["tab10"]
    out = []
    k = 0
    for c in classes:
        if c == "none":
            out.append(NONE_GREY)
        else:
            out.append(cmap(k % 10)[:3])
            k += 1
    return np.array(out)


def write_cloud(
    path: Path, ranges: np.ndarray, poses: np.ndarray, laser: LaserGeometry, labels: Labels
) -> int:
    """The 3D cloud: every return at its world position and the laser's mounting height,
    coloured by its scan's label; written with Open3D. Returns the number of points."""
    pts, scan = world_points(ranges, poses, laser)
    colours = label_colours(labels.classes)
    which = {c: k for k, c in enumerate(labels.classes)}
    cls = np.array([which[c] for c in labels.label])[scan]
    xyz = np.column_stack([pts, np.full(len(pts), laser.z)])
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    cloud.colors = o3d.utility.Vector3dVector(colours[cls])
    named = path.with_name(path.name + ".ply")  # Open3D picks the writer by extension
    try:
        if not o3d.io.write_point_cloud(str(named), cloud):
            raise OSError(f"open3d could not write {named}")
        named.replace(path)
    finally:
        named.unlink(missing_ok=True)
    return len(xyz)


def write_figures(
    folder: Path,
    ds: Dataset,
    name: str,
    labels: Labels,
    poses: np.ndarray,
    pose_source: str,
    training: dict[str, np.ndarray],
    metrics: dict[str, Any],
) -> None:
    """membership.png and labels-cloud.ply of a label run into `folder` (each atomically),
    the cloud's point count into `metrics`: the `figures` that `toolkit label` passes to
    `toolkit.features.run.label_run`."""
    with atomic_file(folder / "membership.png") as png:
        membership_figure(
            png, ds.ranges, poses, ds.laser, labels, training,
            title=f"{name}: feature membership ({pose_source})",
        )  # fmt: skip
    with atomic_file(folder / "labels-cloud.ply") as ply:
        metrics["cloud_points"] = write_cloud(ply, ds.ranges, poses, ds.laser, labels)
