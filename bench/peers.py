"""The peers the benchmarks measure the toolkit against, set up once for all of them."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from toolkit import se2
from toolkit.poses import odometry_poses

if TYPE_CHECKING:
    from toolkit.dataset import Dataset


def kiss_icp(ds: Dataset, voxel: float) -> tuple[Any, list[np.ndarray], np.ndarray | None]:
    """KISS-ICP as a 2D laser user runs it: each scan's returns as 3D points at z = 0 in the
    laser frame, deskew off, one thread, voxel `voxel` m. Returns the pipeline, the points of
    every scan (made before any clock starts, as the toolkit's scans are), and the seed of
    each step k -> k+1 (the odometry's laser motion as 4 x 4 matrices; None without
    odometry: then KISS-ICP's own constant-velocity model)."""
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP

    config = KISSConfig()
    config.data.deskew = False
    config.data.max_range = float(ds.laser.range_max or 80.0)
    config.data.min_range = 0.0
    config.mapping.voxel_size = voxel
    config.registration.max_num_threads = 1
    c, s = np.cos(ds.laser.angles), np.sin(ds.laser.angles)
    frames = []
    for r in ds.ranges.astype(np.float64):
        ok = np.isfinite(r)
        frames.append(np.column_stack([r[ok] * c[ok], r[ok] * s[ok], np.zeros(ok.sum())]))
    odo = odometry_poses(ds)
    if odo is None:
        return KissICP(config), frames, None
    laser = se2.compose(odo, np.broadcast_to(se2.mount_pose(ds.laser), odo.shape))
    steps = se2.between(laser[:-1], laser[1:])
    seeds = np.repeat(np.eye(4)[None], len(steps), axis=0)
    seeds[:, 0, 0] = seeds[:, 1, 1] = np.cos(steps[:, 2])
    seeds[:, 1, 0] = np.sin(steps[:, 2])
    seeds[:, 0, 1] = -seeds[:, 1, 0]
    seeds[:, :2, 3] = steps[:, :2]
    return KissICP(config), frames, seeds


def register(kiss: Any, frames: list[np.ndarray], seeds: np.ndarray | None) -> np.ndarray:  # noqa: ANN401
    """Register every frame, seeding each step by `seeds`; the laser poses (S x 3) relative to
    the first scan."""
    out = np.zeros((len(frames), 3))
    for k, pts in enumerate(frames):
        if seeds is not None and k > 0:
            kiss.last_delta = seeds[k - 1]
        kiss.register_frame(pts, np.zeros(len(pts)))
        p = kiss.last_pose
        out[k] = p[0, 3], p[1, 3], np.arctan2(p[1, 0], p[0, 0])
    return out
