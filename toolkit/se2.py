"""SE(2) poses (x, y, theta) in plain numpy: the one home of pose arithmetic.

Every function takes (..., 3) float arrays (one pose or N x 3) and broadcasts; angles in rad,
headings wrapped to (-pi, pi]. Numpy only, so that modules that must not load numba (the
importers, the features, the reports) share it; the numba matcher keeps private copies in its
kernels, tested equal to these (tests/test_se2.py).

    p = compose(a, b)             # a ∘ b: b given in a's frame, in a's parent frame
    d = between(a, b)             # a^-1 ∘ b: b seen from a
    xyt = interpolate(t, xyt, ts) # poses at times ts, heading on the circle

A timed stream of poses (odometry, ground truth, a trajectory) is `toolkit.dataset.PoseStream`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Mount(Protocol):
    """Where a sensor sits on the robot (`toolkit.dataset.LaserGeometry` is one)."""

    @property
    def x(self) -> float: ...
    @property
    def y(self) -> float: ...
    @property
    def yaw(self) -> float: ...


def wrap(theta: np.ndarray | float) -> np.ndarray:
    """Angles (any shape) wrapped to (-pi, pi], as atan2(sin, cos) (the kernels' form)."""
    theta = np.asarray(theta, dtype=np.float64)
    w = np.arctan2(np.sin(theta), np.cos(theta))
    return np.where(w == -np.pi, np.pi, w)


def rotation(theta: float) -> np.ndarray:
    """The 2 x 2 matrix turning a vector by `theta` (rad)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _stacked(x: np.ndarray, y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """`np.stack([x, y, t], axis=-1)` of three arrays of one shape (the same values and
    dtype): a quarter of its cost, in the thousands of one-pose calls of a map run."""
    out = np.empty((*np.shape(x), 3), dtype=np.result_type(x, y, t))
    out[..., 0], out[..., 1], out[..., 2] = x, y, t
    return out


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ∘ b for (..., 3) poses: b, given in a's frame, in a's parent frame."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return _stacked(x, y, wrap(a[..., 2] + b[..., 2]))


def inverse(a: np.ndarray) -> np.ndarray:
    """a^-1 for (..., 3) poses (the heading negated, not wrapped)."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return _stacked(x, y, -a[..., 2])


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 ∘ b: b seen from a."""
    return compose(inverse(a), b)


def mount_pose(mount: Mount) -> np.ndarray:
    """The laser's pose in the robot frame (3,): its x, y, yaw."""
    return np.array([mount.x, mount.y, mount.yaw], dtype=np.float64)


def laser_poses(robot: np.ndarray, mount: Mount) -> np.ndarray:
    """Robot poses (N x 3) as the poses of the laser mounted at `mount`: robot ∘ M."""
    return compose(robot, np.broadcast_to(mount_pose(mount), robot.shape))


def laser_motion(robot_steps: np.ndarray, mount: Mount) -> np.ndarray:
    """Relative robot motions (N x 3) as motions of the laser: M^-1 ∘ step ∘ M."""
    m = np.broadcast_to(mount_pose(mount), robot_steps.shape)
    return compose(compose(inverse(m), robot_steps), m)


def robot_motion(laser_steps: np.ndarray, mount: Mount) -> np.ndarray:
    """Relative laser motions (N x 3) as motions of the robot: M ∘ step ∘ M^-1."""
    m = np.broadcast_to(mount_pose(mount), laser_steps.shape)
    return compose(compose(m, laser_steps), inverse(m))


def interpolate(t: np.ndarray, xyt: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Poses (len(at) x 3) of the stream (t, xyt), linear between its samples, the heading
    along the shorter arc (unwrapped, interpolated, wrapped); times outside the stream take
    its first or last pose. `t` need not be sorted (ties keep their order)."""
    t = np.asarray(t, dtype=np.float64)
    xyt = np.asarray(xyt, dtype=np.float64).reshape(-1, 3)
    at = np.asarray(at, dtype=np.float64)
    if len(t) == 0:
        raise ValueError("pose stream is empty")
    order = np.argsort(t, kind="stable")
    t, xyt = t[order], xyt[order]
    theta = np.unwrap(xyt[:, 2])
    out = np.column_stack(
        [np.interp(at, t, xyt[:, 0]), np.interp(at, t, xyt[:, 1]), np.interp(at, t, theta)]
    )
    out[:, 2] = wrap(out[:, 2])
    return out
