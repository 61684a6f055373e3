"""Private numba copies of `toolkit.se2`'s arithmetic for the matcher's kernels and the pose
composition (`toolkit.poses`), one pose at a time; tests/test_se2.py holds them equal to the
numpy originals. The keyframe rule lives here too, so the batch (`keyframes`) and the
streaming (`StreamMatcher.push`) forms share it."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def wrap(theta: float) -> float:
    """`toolkit.se2.wrap` for one angle: to (-pi, pi]."""
    w = math.atan2(math.sin(theta), math.cos(theta))
    return math.pi if w == -math.pi else w


@nb.njit(cache=True, nogil=True)
def compose_into(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """out = a ∘ b for single poses (3,) (`toolkit.se2.compose`); `out` may be `a`."""
    x, y, th = a[0], a[1], a[2]
    c, s = math.cos(th), math.sin(th)
    out[0] = x + c * b[0] - s * b[1]
    out[1] = y + s * b[0] + c * b[1]
    out[2] = wrap(th + b[2])


@nb.njit(cache=True, nogil=True)
def is_keyframe(odometry: np.ndarray, key: np.ndarray, distance: float, angle: float) -> bool:
    """Whether a scan whose odometry is `odometry` (3,) becomes the next keyframe after the
    one at `key` (3,): it moved `distance` or turned `angle` since."""
    dx = odometry[0] - key[0]
    dy = odometry[1] - key[1]
    turn = abs(wrap(odometry[2] - key[2]))
    return dx * dx + dy * dy >= distance * distance or turn >= angle
