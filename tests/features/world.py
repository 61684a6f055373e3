"""A small ray-cast world for the feature tests: a corridor with a side room and a hall,
scanned by a 181-beam 180° laser with range noise and no-returns beyond the maximum range."""

from __future__ import annotations

import numpy as np

from toolkit.dataset import LaserGeometry

LASER = LaserGeometry.sick_180(181, range_max=8.0)


def walls() -> np.ndarray:
    """Wall segments (N, 4): x0, y0, x1, y1. A 2 m corridor (x 0..12) with a room opening
    above (x 12..16), a 5 m wide lobby (x 16..26), an 8 m hall (x 26..34), and the corridor
    again (x 34..40)."""
    w = [
        (0, -1, 0, 1), (0, -1, 16, -1), (0, 1, 12, 1), (5, -1, 5, -0.8),  # corridor, a pillar
        (12, 1, 12, 5), (12, 5, 16, 5), (16, 5, 16, 2.5),  # room above
        (16, -1, 16, -2.5), (16, -2.5, 26, -2.5), (16, 2.5, 26, 2.5), (20, -2.5, 20, -2),  # lobby
        (26, 2.5, 26, 4), (26, -2.5, 26, -4), (26, -4, 34, -4), (26, 4, 34, 4),  # hall
        (34, 4, 34, 1), (34, -4, 34, -1), (34, -1, 40, -1), (34, 1, 40, 1), (40, -1, 40, 1),
    ]  # fmt: skip
    return np.array(w, dtype=np.float64)


def cast(
    poses: np.ndarray, laser: LaserGeometry = LASER, seed: int = 0, sigma: float = 0.01
) -> np.ndarray:
    """Ranges (S, B) float32 seen from poses (S, 3); NaN where nothing is within range_max."""
    rng = np.random.default_rng(seed)
    seg = walls()
    ang = poses[:, 2:3] + laser.angles[None, :]  # (S, B)
    dx, dy = np.cos(ang)[..., None], np.sin(ang)[..., None]  # (S, B, 1)
    px, py = poses[:, 0, None, None], poses[:, 1, None, None]
    ex, ey = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]  # (N,)
    wx, wy = seg[:, 0] - px, seg[:, 1] - py  # (S, 1, N)
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wx * ey - wy * ex) / den
        u = (wx * dy - wy * dx) / den
    hit = (t > 1e-9) & (u >= 0) & (u <= 1)
    r = np.where(hit, t, np.inf).min(axis=2)
    r = r + rng.normal(0, sigma, r.shape)
    r[r >= laser.range_max] = np.nan
    return r.astype(np.float32)


def drive(step: float = 0.1, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A run along the centre line with a little sway and heading wobble: t (S,), poses
    (S, 3), and the true place per scan: corridor (x < 12 and x >= 34), room (12..16), none
    (the lobby, 16..26, never taught), hall (26..34)."""
    rng = np.random.default_rng(seed + 1)
    x = np.arange(1.0, 38.0, step)
    y = rng.normal(0, 0.03, len(x))
    theta = rng.normal(0, 0.01, len(x))
    poses = np.column_stack([x, y, theta])
    label = np.full(len(x), "corridor", dtype=object)
    label[(x >= 12) & (x < 16)] = "room"
    label[(x >= 16) & (x < 26)] = "none"
    label[(x >= 26) & (x < 34)] = "hall"
    return np.arange(len(x)) * 0.2, poses, label.astype(str)
