"""Fig. 3: two scan pairs of the corridor aligned by each method, overlaid.

One pair where the walls are close (the section with the shortest median range) and one
where they are distant (the longest); the middle pair of each section. Each panel draws the
previous scan and the current scan moved into the previous laser's frame by the method's
estimate; the error is the estimate's distance from the true motion.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np

from reports.base import NotAvailable, Section, new_figure, save_figure
from reports.context import CORRIDOR, Context
from reports.runs import safe_name
from reports.table1_sections import sections_of
from toolkit import se2
from toolkit.align import scan as sc
from toolkit.align.baselines import match_pairs_icp
from toolkit.dataset import Dataset
from toolkit.poses import odometry_poses, truth_poses

VIEW = 6.0  # m: the panels show the returns within this range of the laser

KEY = "pairs"
TITLE = "Fig. 3: scan pairs aligned by each method"
INTRO = (
    "A pair of consecutive scans where the walls are close and one where they are distant "
    "(the corridor; the Intel lab with drift added), the current scan moved onto the previous one by odometry, by the Gaussian "
    "alignment and by ICP, beside the truth."
)


def pick_pairs(ranges: np.ndarray, sections: np.ndarray) -> dict[str, int]:
    """Index k of the pair (k-1, k) in the middle of the sections with the shortest and the
    longest median range."""
    ids = sorted(set(sections[sections >= 0].tolist()))
    med = [float(np.nanmedian(ranges[sections == s])) for s in ids]
    out = {}
    for what, s in (("close", ids[int(np.argmin(med))]), ("distant", ids[int(np.argmax(med))])):
        index = np.flatnonzero(sections == s)
        out[what] = int(index[len(index) // 2])
    return out


def align_pair(ds: Dataset, k: int, methods: tuple[str, ...]) -> dict[str, Any]:
    """Relative laser pose (x, y, theta) of scan k in scan k-1's frame by each method."""
    odo_all, gt_all = odometry_poses(ds), truth_poses(ds)
    if odo_all is None or gt_all is None:
        raise NotAvailable("a scan pair needs odometry (the seed) and ground truth (the error)")
    odo, gt = odo_all[k - 1 : k + 1], gt_all[k - 1 : k + 1]
    seed = se2.laser_motion(se2.between(odo[:1], odo[1:]), ds.laser)
    truth = se2.laser_motion(se2.between(gt[:1], gt[1:]), ds.laser)[0]
    ranges = ds.ranges[k - 1 : k + 1]
    est = {"odometry": seed[0]}
    for method in methods:
        if method == "gaussian":
            est[method] = sc.match_pairs(ranges, seed, ds.laser).pose[0]
        else:
            kind: Literal["point_to_line", "point_to_point"] = (
                "point_to_line" if method == "icp" else "point_to_point"
            )
            est[method] = match_pairs_icp(ranges, seed, ds.laser, kind).pose[0]
    error_cm = {m: 100 * float(np.hypot(*(p[:2] - truth[:2]))) for m, p in est.items()}
    error_deg = {m: float(np.rad2deg(abs(se2.wrap(p[2] - truth[2])))) for m, p in est.items()}
    return {"k": k, "truth": truth, "estimate": est, "error_cm": error_cm, "error_deg": error_deg}


def _moved(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.column_stack(
        [
            pose[0] + c * points[:, 0] - s * points[:, 1],
            pose[1] + s * points[:, 0] + c * points[:, 1],
        ]
    )


def generate(ctx: Context, section: Section) -> None:
    for name in ctx.sectioned_logs():
        with ctx.part(section, f"scan pairs of {name}"):
            ds = ctx.dataset(name)
            if ds.groundtruth is None:
                raise NotAvailable(f"{name} has no ground truth")
            pairs = pick_pairs(ds.ranges, sections_of(ctx, name))
            section.data[name] = _pairs(ctx, section, name, ds, pairs)


def _pairs(
    ctx: Context, section: Section, name: str, ds: Dataset, pairs: dict[str, int]
) -> dict[str, Any]:
    methods = ("odometry", *ctx.matchers, "truth")
    fig = new_figure(3.6 * len(methods), 3.6 * len(pairs))
    axes = fig.subplots(len(pairs), len(methods), squeeze=False)
    data: dict[str, Any] = {}
    for row, (what, k) in enumerate(pairs.items()):
        ctx.step(f"{name}: {what} pair")
        result = align_pair(ds, k, ctx.matchers)
        result["median_range_m"] = float(np.nanmedian(ds.ranges[k - 1 : k + 1]))
        data[what] = result
        prev = sc.scan_points(ds.ranges[k - 1], ds.laser)
        cur = sc.scan_points(ds.ranges[k], ds.laser)
        near = prev[np.hypot(*prev.T) < VIEW]  # zoom on the returns near the laser
        lo, hi = np.nanmin(near, axis=0) - 0.3, np.nanmax(near, axis=0) + 0.3
        view = list(zip(lo, hi, strict=True))
        for col, method in enumerate(methods):
            ax = axes[row, col]
            pose = result["truth"] if method == "truth" else result["estimate"][method]
            ax.plot(*prev.T, ".", ms=2, color="0.2", label=f"scan {k - 1}", rasterized=True)
            ax.plot(
                *_moved(cur, pose).T,
                ".",
                ms=2,
                color="tab:red",
                label=f"scan {k} moved",
                rasterized=True,
            )
            title = (
                method if method == "truth" else f"{method}: {result['error_cm'][method]:.1f} cm"
            )
            ax.set_title(f"{what} walls, {title}", fontsize=9)
            ax.set_xlim(*view[0])
            ax.set_ylim(*view[1])
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
        section.notes.append(
            f"{name}, {what} walls (pair {k - 1}-{k}, median range {result['median_range_m']:.1f} m): "
            + ", ".join(f"{m} {result['error_cm'][m]:.2f} cm" for m in ("odometry", *ctx.matchers))
            + " from the true motion."
        )
    axes[0, 0].legend(fontsize=7, markerscale=3)
    suffix = "" if name == CORRIDOR else "_" + safe_name(name)
    section.figures.append(
        save_figure(
            fig,
            ctx.out,
            f"fig3_pairs{suffix}",
            f"Fig. 3 ({name}): scan pairs aligned by each method",
            "Previous scan (black) and current scan (red) moved into the previous laser frame by "
            "each method's estimate of the motion, within 6 m of the laser; titles give the "
            "translation error against the true motion. 'Close' and 'distant' are read as the "
            "sections whose walls are nearest and furthest (median range).",
            data,
        )
    )
    return data
