"""Odometry model: a differential-drive robot's wheel encoders, integrated at scan times.

Between consecutive true poses the robot moves ds forward and turns dθ; its wheels travel
dL = ds - dθ·b/2 and dR = ds + dθ·b/2 (b = `wheel_base`). The encoders report
dL' = kL·dL + nL and dR' = kR·dR + nR, where

- kR, kL = (1 + `scale_error`)(1 ± `wheel_diff`/2): unequal wheel diameters turn a straight
  run into a steady curve, a heading drift that grows with distance (dθ/ds ≈ wheel_diff/b),
  as in the paper's Fig. 6a; a common scale error stretches every distance;
- nL, nR ~ N(0, (`wheel_noise`)² |d|) per wheel: noise that grows with the distance rolled;
- with probability `slip_prob` per step one wheel slips: it reports `slip_max`·U(0.25, 1)
  more travel than it made.

Odometry then integrates ds' = (dL' + dR')/2, dθ' = (dR' - dL')/b from the true first pose,
so a model with every error set to 0 reproduces the true path exactly.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from toolkit import se2
from toolkit.typed import check_fields


@dataclass
class OdometryModel:
    """Wheel odometry errors of a Pioneer-like robot; every field is a simulator parameter."""

    wheel_base: float = 0.33  # m, Pioneer 3-DX
    wheel_diff: float = 0.001  # relative difference of the wheel diameters (R vs L)
    scale_error: float = 0.01  # common relative error of both wheels
    wheel_noise: float = 0.002  # m per sqrt(m) rolled, per wheel
    slip_prob: float = 0.002  # chance per step that one wheel slips
    slip_max: float = 0.3  # largest slip, as a fraction of the step's travel

    def __post_init__(self) -> None:
        check_fields(self, "the simulator")  # numbers, as `toolkit simulate -p` parses them

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def integrate(self, truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Odometry poses (S x 3) for true robot poses (S x 3), starting at the true first pose."""
        truth = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
        if len(truth) < 2:
            return truth.copy()
        # true increments in the frame of the previous pose
        dxy = np.diff(truth[:, :2], axis=0)
        th = truth[:-1, 2]
        c, s = np.cos(th), np.sin(th)
        fx = c * dxy[:, 0] + s * dxy[:, 1]
        fy = -s * dxy[:, 0] + c * dxy[:, 1]
        dth = np.diff(np.unwrap(truth[:, 2]))
        ds = np.sign(fx) * np.hypot(fx, fy)

        half = 0.5 * self.wheel_base * dth
        d_left, d_right = ds - half, ds + half
        k = 1.0 + self.scale_error
        d_left = k * (1.0 - self.wheel_diff / 2) * d_left
        d_right = k * (1.0 + self.wheel_diff / 2) * d_right
        n = len(ds)
        d_left = d_left + rng.normal(0.0, 1.0, n) * self.wheel_noise * np.sqrt(np.abs(d_left))
        d_right = d_right + rng.normal(0.0, 1.0, n) * self.wheel_noise * np.sqrt(np.abs(d_right))
        slips = rng.random(n) < self.slip_prob
        right_wheel = rng.random(n) < 0.5
        extra = self.slip_max * rng.uniform(0.25, 1.0, n) * np.abs(ds)
        d_left = d_left + np.where(slips & ~right_wheel, extra * np.sign(ds), 0.0)
        d_right = d_right + np.where(slips & right_wheel, extra * np.sign(ds), 0.0)

        ds_odo = 0.5 * (d_left + d_right)
        dth_odo = (d_right - d_left) / self.wheel_base
        with np.errstate(divide="ignore", invalid="ignore"):
            stretch = np.where(ds != 0, ds_odo / ds, 0.0)
        fx_odo, fy_odo = fx * stretch, fy * stretch

        theta = truth[0, 2] + np.concatenate([[0.0], np.cumsum(dth_odo)])
        c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
        steps = np.stack([c * fx_odo - s * fy_odo, s * fx_odo + c * fy_odo], axis=1)
        xy = truth[0, :2] + np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
        return np.column_stack([xy, se2.wrap(theta)])
