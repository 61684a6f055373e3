"""The simulator against real logs: the building robot drives like the real Bicocca robot
(its ground truth read in place from ../shared/data/real)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from toolkit.sim import Simulation


def _speeds(
    t: np.ndarray, x: np.ndarray, y: np.ndarray, theta: np.ndarray
) -> tuple[float, float, float]:
    """Median speed while moving (m/s); median and 90th percentile turn rate while turning."""
    dt = np.diff(t)
    v = np.hypot(np.diff(x), np.diff(y)) / dt
    w = np.abs(np.diff(np.unwrap(theta))) / dt
    turning = w[w > 0.1]
    return float(np.median(v[v > 0.05])), *np.percentile(turning, [50, 90]).tolist()


@pytest.mark.real
def test_building_robot_drives_like_the_real_bicocca_robot(
    real: Path, building_sim: Simulation
) -> None:
    sessions = sorted((real / "rawseeds_bicocca_groundtruth").glob("*/*-GT-extended.csv"))
    assert len(sessions) == 5
    stats = np.array(
        [
            _speeds(*pd.read_csv(p, header=None, skipinitialspace=True).to_numpy().T[:4])
            for p in sessions
        ]
    )
    sim = building_sim
    gt = sim.dataset.groundtruth
    assert gt is not None
    v, w, _ = _speeds(sim.dataset.t, gt.x.to_numpy(), gt.y.to_numpy(), gt.theta.to_numpy())
    assert 0.9 * stats[:, 0].min() <= v <= 1.1 * stats[:, 0].max()  # real: 0.58..0.63 m/s
    # turning: between the real sessions' median (0.19..0.24) and 90th percentile (0.37..0.45)
    assert stats[:, 1].min() <= w <= stats[:, 2].max()
