"""ICP baselines the paper compares against: Open3D point-to-point, and a 2D point-to-line.

This module holds the Open3D and scipy imports (about 1 s of start-up between them), so only
what runs ICP loads them: `toolkit.align.icp` and `match_pairs_icp` load it on first use.

Both search nearest neighbours (a KD-tree) every iteration, which is what the Gaussian
alignment avoids. Point-to-plane ICP on z = 0 clouds is degenerate (every normal is
(0, 0, 1)), so the 2D variant uses in-plane normals taken from neighbouring beams.

`register_*(source, target)` return the rigid transform T with T(source) ~ target;
`icp(cur, prev)` aligns prev onto cur, so its `.shift` is comparable to `gaussian(cur, prev)`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from toolkit.align.scan import PairMatches, pair_refs, scan_points
from toolkit.dataset import LaserGeometry
from toolkit.se2 import rotation

ICP_STEP = 256  # pairs between two progress calls (ICP runs one pair at a time)

Method = Literal["point_to_point", "point_to_line"]


@dataclass(frozen=True)
class IcpResult:
    """Homogeneous transform ((D+1) x (D+1)) taking prev onto cur, its translation and fit."""

    transform: np.ndarray
    fitness: float
    rmse: float

    @property
    def shift(self) -> np.ndarray:
        d = self.transform.shape[0] - 1
        return self.transform[:d, d].copy()


def icp(
    cur: np.ndarray,
    prev: np.ndarray,
    init: np.ndarray | None = None,
    max_distance: float = 1.0,
    iterations: int = 30,
    method: Method = "point_to_point",
) -> IcpResult:
    """Align `prev` onto `cur` (K x 2 or K x 3 points, no correspondence needed) by ICP.

    `method="point_to_point"` is Open3D's ICP (2D points are lifted to z = 0 and the
    transform returned is 3 x 3 for 2D input); `"point_to_line"` is the 2D variant, with
    normals of `cur` from its point order (a scan's beam order).
    """
    cur = np.asarray(cur, dtype=np.float64)
    prev = np.asarray(prev, dtype=np.float64)
    dim = cur.shape[1]
    if method == "point_to_line":
        if dim != 2:
            raise ValueError("point-to-line ICP is 2D; give K x 2 points")
        T, fit, rmse = register_point_to_line(
            prev, cur, ordered_normals(cur), _pose(init), max_distance, iterations
        )
        return IcpResult(T, fit, rmse)
    T4, fit, rmse = register_point_to_point(prev, cur, init, max_distance, iterations)
    if dim == 2:
        T = np.eye(3)
        T[:2, :2] = T4[:2, :2]
        T[:2, 2] = T4[:2, 3]
        return IcpResult(T, fit, rmse)
    return IcpResult(T4, fit, rmse)


def _lift(points: np.ndarray) -> np.ndarray:
    if points.shape[1] == 3:
        return points
    return np.column_stack([points[:, :2], np.zeros(len(points))])


def _pose(init: np.ndarray | None) -> np.ndarray:
    """(x, y, theta) from a 3 x 3 homogeneous transform or a pose vector."""
    if init is None:
        return np.zeros(3)
    init = np.asarray(init, dtype=np.float64)
    if init.shape == (3, 3):
        return np.array([init[0, 2], init[1, 2], np.arctan2(init[1, 0], init[0, 0])])
    return init.reshape(3)


def one_openmp_thread() -> threadpool_limits:
    """A context in which Open3D runs on one OpenMP thread (Open3D is loaded by this module:
    a limit reaches only the OpenMP runtimes already loaded). One small registration (a scan pair, a
    random cloud) gains nothing from more threads; on busy cores they spin (measured: 1,000
    points, 12-38 ms of CPU per ICP with two threads on two loaded cores, 1.2 ms with one)."""
    return threadpool_limits(1, user_api="openmp")


def register_point_to_point(
    source: np.ndarray,
    target: np.ndarray,
    init: np.ndarray | None = None,
    max_distance: float = 1.0,
    iterations: int = 30,
) -> tuple[np.ndarray, float, float]:
    """Open3D point-to-point ICP: 4 x 4 T with T(source) ~ target, fitness, inlier RMSE."""
    reg = o3d.pipelines.registration
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_lift(source)))
    dst = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_lift(target)))
    T0 = np.eye(4)
    if init is not None:
        init = np.asarray(init, dtype=np.float64)
        if init.shape == (4, 4):
            T0 = init
        else:
            x, y, th = _pose(init)
            T0[:2, :2] = rotation(th)
            T0[:2, 3] = (x, y)
    result = reg.registration_icp(
        src,
        dst,
        max_distance,
        T0,
        reg.TransformationEstimationPointToPoint(),
        reg.ICPConvergenceCriteria(max_iteration=iterations),
    )
    return np.asarray(result.transformation), float(result.fitness), float(result.inlier_rmse)


def ordered_normals(points: np.ndarray, max_gap: float = 0.5) -> np.ndarray:
    """In-plane unit normals of K x 2 points in scan order, from the neighbouring beams.

    NaN where a neighbour is missing or further than `max_gap` (a depth jump, no surface).
    """
    p = np.asarray(points, dtype=np.float64)
    ahead = np.full_like(p, np.nan)
    behind = np.full_like(p, np.nan)
    ahead[:-1] = p[1:]
    behind[1:] = p[:-1]
    with np.errstate(invalid="ignore"):
        gap_a = np.linalg.norm(ahead - p, axis=1)
        gap_b = np.linalg.norm(p - behind, axis=1)
        ahead[~(gap_a <= max_gap)] = p[~(gap_a <= max_gap)]
        behind[~(gap_b <= max_gap)] = p[~(gap_b <= max_gap)]
        tangent = ahead - behind
        length = np.linalg.norm(tangent, axis=1)
        normal = np.column_stack([-tangent[:, 1], tangent[:, 0]]) / length[:, None]
    normal[~(length > 1e-9)] = np.nan
    return np.asarray(normal)


def register_point_to_line(
    source: np.ndarray,
    target: np.ndarray,
    target_normals: np.ndarray,
    init: np.ndarray | None = None,
    max_distance: float = 1.0,
    iterations: int = 30,
    tolerance: float = 1e-6,
) -> tuple[np.ndarray, float, float]:
    """2D point-to-line ICP (Gauss-Newton on (x, y, theta), KD-tree correspondences).

    Returns the 3 x 3 T with T(source) ~ target, the fraction of source points matched and
    the RMS point-to-line distance of the matches.
    """
    src = np.asarray(source, dtype=np.float64)
    src = src[np.isfinite(src).all(axis=1)]
    keep = np.isfinite(target).all(axis=1) & np.isfinite(target_normals).all(axis=1)
    dst = np.asarray(target, dtype=np.float64)[keep]
    nrm = np.asarray(target_normals, dtype=np.float64)[keep]
    pose = _pose(init).copy()
    fit = rmse = 0.0
    if len(src) < 3 or len(dst) < 3:
        return _matrix(pose), fit, rmse
    tree = cKDTree(dst)
    for _ in range(iterations):
        p = src @ rotation(pose[2]).T + pose[:2]
        dist, idx = tree.query(p, distance_upper_bound=max_distance)
        ok = np.isfinite(dist)
        if ok.sum() < 3:
            break
        pm, n = p[ok], nrm[idx[ok]]
        e = np.einsum("ij,ij->i", n, pm - dst[idx[ok]])
        arm = pm - pose[:2]
        J = np.column_stack([n, n[:, 1] * arm[:, 0] - n[:, 0] * arm[:, 1]])
        H = J.T @ J + 1e-9 * np.eye(3)
        step = -np.linalg.solve(H, J.T @ e)
        pose += step
        fit, rmse = float(ok.mean()), float(np.sqrt(np.mean(e * e)))
        if np.abs(step).max() < tolerance:
            break
    return _matrix(pose), fit, rmse


def _matrix(pose: np.ndarray) -> np.ndarray:
    T = np.eye(3)
    T[:2, :2] = rotation(pose[2])
    T[:2, 2] = pose[:2]
    return T


def match_pairs_icp(
    ranges: np.ndarray,
    seeds: np.ndarray,
    laser: LaserGeometry,
    method: Literal["point_to_point", "point_to_line"] = "point_to_line",
    max_distance: float = 0.5,
    iterations: int = 30,
    ref: np.ndarray | None = None,
    progress: Callable[[int], object] | None = None,
) -> PairMatches:
    """The ICP baseline on the same pairs as `match_pairs`, seeded the same way (one pair at a
    time: ICP builds a KD-tree of each reference scan); `progress(m)` after every m pairs.
    Open3D runs on one OpenMP thread here:
    a pair is a few hundred points, and more threads only wait on each other, spinning when
    the cores are busy (300 corridor pairs on 2 loaded cores: 13.2 s of CPU and 125 s wall
    with its 2 threads, 0.25 s of CPU and 1.9 s wall with one)."""
    with one_openmp_thread():
        n = max(len(ranges) - 1, 0)
        refs = pair_refs(ref, len(ranges))
        out = PairMatches.empty(n)
        key, prev, normals = -1, np.zeros((0, 2)), np.zeros((0, 2))
        for k in range(n):
            if refs[k + 1] != key:
                key = int(refs[k + 1])
                prev = scan_points(ranges[key], laser)
                normals = ordered_normals(prev)
            cur = scan_points(ranges[k + 1], laser)
            src = cur[np.isfinite(cur).all(axis=1)]
            if method == "point_to_line":
                T, fit, rmse = register_point_to_line(
                    src, prev, normals, seeds[k], max_distance, iterations
                )
                pose = np.array([T[0, 2], T[1, 2], np.arctan2(T[1, 0], T[0, 0])])
            else:
                dst = prev[np.isfinite(prev).all(axis=1)]
                T4, fit, rmse = register_point_to_point(
                    src, dst, seeds[k], max_distance, iterations
                )
                pose = np.array([T4[0, 3], T4[1, 3], np.arctan2(T4[1, 0], T4[0, 0])])
            out.pose[k] = pose
            out.sigma[k] = rmse
            out.used[k] = round(fit * len(src))
            if progress is not None and ((k + 1) % ICP_STEP == 0 or k + 1 == n):
                progress((k + 1) % ICP_STEP or ICP_STEP)
        return out
