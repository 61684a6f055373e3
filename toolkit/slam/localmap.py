"""The sequential part of the mapper, with a motion model: odometry when the log has it,
constant velocity when it has none.

With odometry every scan pair is independent given its seed, so the batch matcher matches all
pairs at once (`toolkit.poses.build`). Without, each scan's seed is the previous motion
carried on (constant velocity, as KISS-ICP predicts), so scans are matched one after another
through the streaming matcher (`MotionMatcher`, a `StreamMatcher` whose odometry may be
missing): a log without odometry is no longer matched "from standstill"."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from toolkit import se2
from toolkit.align import scan as sc
from toolkit.dataset import Dataset, LaserGeometry, pose_frame
from toolkit.poses import Method, TrajectoryResult, build, odometry_poses

STREAM_STEP = 256  # scans the streaming matcher runs between two progress calls


class MotionMatcher(sc.StreamMatcher):
    """`StreamMatcher` whose `push` takes odometry or None; with None, the pose predicted by
    constant velocity (the last motion repeated) plays the odometry's part."""

    def __init__(self, laser: LaserGeometry, config: sc.MatchConfig | None = None) -> None:
        super().__init__(laser, config)
        self._last = np.zeros(3)
        self._step = np.zeros(3)
        self._dt = 0.0
        self._t: float | None = None

    def push_predicted(self, ranges: np.ndarray, t: float | None = None) -> np.ndarray:
        """Take the next scan of a log without odometry (at time `t`, to scale the motion to
        uneven scan intervals); return the robot pose."""
        step = self._step
        if t is not None and self._t is not None and self._dt > 0:
            scale = min((t - self._t) / self._dt, 3.0)
            step = step * scale
        predicted = se2.compose(self._last[None], step[None])[0]
        if not self._started:
            predicted = np.zeros(3)
        else:  # the "odometry" is the corrected frame: the keyframe's pose is its own odometry
            self._key_odometry[:] = self._key_pose
        pose = self.push(ranges, predicted)
        if self._started and t is not None and self._t is not None:
            self._dt = t - self._t
        self._step = se2.between(self._last[None], pose[None])[0]
        self._last = pose
        self._t = t
        return pose


def sequential(
    ds: Dataset,
    config: sc.MatchConfig | None = None,
    progress: Callable[[int], object] | None = None,
) -> TrajectoryResult:
    """The sequential trajectory of `ds`: the batch matcher seeded by odometry, or the streaming
    matcher seeded by constant velocity when the log has no odometry. `progress(m)`: m more
    scan pairs matched (S - 1 in all)."""
    if odometry_poses(ds) is not None:
        return build(ds, "gaussian", config, progress=progress)
    config = config or sc.MatchConfig()
    matcher = MotionMatcher(ds.laser, config)
    poses = np.zeros((ds.n_scans, 3))
    matches = sc.PairMatches.empty(max(ds.n_scans - 1, 0))
    t0 = time.perf_counter()
    for k in range(ds.n_scans):
        poses[k] = matcher.push_predicted(ds.ranges[k], float(ds.t[k]))
        if k > 0:  # the pair just matched: its pose, covariance and diagnostics
            sigma, n_used, degenerate, agreement = matcher.stats
            matches.pose[k - 1] = matcher.pose
            matches.covariance[k - 1] = matcher.covariance
            matches.sigma[k - 1], matches.used[k - 1] = sigma, n_used
            matches.degenerate[k - 1], matches.agreement[k - 1] = degenerate, agreement
            if progress is not None and (k % STREAM_STEP == 0 or k == ds.n_scans - 1):
                progress(k % STREAM_STEP or STREAM_STEP)
    seconds = time.perf_counter() - t0
    frame = pose_frame(ds.t, poses)
    used = config.to_dict()
    return TrajectoryResult(frame, Method.GAUSSIAN, matches, seconds, used)


__all__ = ["MotionMatcher", "sequential"]
