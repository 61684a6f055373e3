"""`SlamConfig.excursion_mend`: a stretch the front end placed turned after the odometry
slipped at a weak fit, turned back where a later scan finds the map again, re-derived from
its two ends when the scans after the return confirm it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.slam.conftest import drifted_carmen
from toolkit import se2
from toolkit.dataset import Dataset
from toolkit.poses import odometry_poses, truth_poses
from toolkit.slam.pipeline import SlamConfig, mend_excursions
from toolkit.slam.scanmap import scan_to_map

ON = SlamConfig()  # the default: excursion_mend 0.2


def _front(real: Path, name: str, seed: int) -> tuple[Dataset, np.ndarray, np.ndarray, np.ndarray]:
    ds = drifted_carmen(real, name, seed=seed)
    odometry, front = odometry_poses(ds), scan_to_map(ds)
    assert odometry is not None and front.matches is not None
    return ds, front.poses, front.matches.agreement, odometry


def test_an_excursion_is_mended_and_nothing_else_moves(real: Path) -> None:
    """intel drift seed 1: the odometry slips 0.45 rad at scan 795 (fit 0.64), the front end
    follows, and scan 811 turns 0.54 rad back against the odometry: scans 795-810 lie 0.6 rad
    off the truth relative to scan 794 (1.4 m); mended, under 0.1 rad (0.3 m), and no other
    scan moves."""
    ds, before, fit, odometry = _front(real, "intel", 1)
    truth = truth_poses(ds)
    assert truth is not None
    mended = mend_excursions(ds.ranges, ds.laser, fit, before, odometry, ON)

    def off(p: np.ndarray) -> float:
        rel = se2.wrap(p[795:811, 2] - p[794, 2] - (truth[795:811, 2] - truth[794, 2]))
        return float(np.abs(rel).max())

    def away(p: np.ndarray) -> float:
        rel = se2.between(np.repeat(p[794:795], 16, 0), p[795:811])
        true = se2.between(np.repeat(truth[794:795], 16, 0), truth[795:811])
        return float(np.hypot(*(rel[:, :2] - true[:, :2]).T).max())

    assert off(before) > 0.5 and off(mended) < 0.1
    assert away(before) > 1.0 and away(mended) < 0.3  # m, relative to scan 794
    moved = np.flatnonzero(np.any(mended != before, axis=1))
    assert moved.tolist() == list(range(795, 811))
    off = SlamConfig(excursion_mend=0.0)
    assert mend_excursions(ds.ranges, ds.laser, fit, before, odometry, off) is before


def test_a_corrected_odometry_slip_is_left_alone(real: Path) -> None:
    """orebro drift seed 3: the odometry slips 1.2 rad into scan 51, which the front end fits
    right, three steps after a weak fit (scan 48, 0.63): a candidate, but the scans after it fit the
    stretch as placed better than mended, so nothing moves."""
    ds, before, fit, odometry = _front(real, "orebro", 3)
    d = se2.wrap(
        se2.between(before[:-1], before[1:])[:, 2] - se2.between(odometry[:-1], odometry[1:])[:, 2]
    )
    weak = fit < ON.scan_map.min_inliers
    assert abs(d[50]) > 1.0 and weak[47]  # a return and an entry: a candidate
    assert mend_excursions(ds.ranges, ds.laser, fit, before, odometry, ON) is before
