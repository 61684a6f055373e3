"""Trajectories and metrics: composition, interpolation, and the accuracy targets on the
simulator's corridor and building and on a real CARMEN log with added odometry drift."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import toolkit
from toolkit import se2
from toolkit.align import scan as sc
from toolkit.metrics import ATE, RPE, Failures, align_se2, evaluate, shared_error
from toolkit.poses import build, compose_refs, compose_steps, poses_at, truth_poses, with_drift
from toolkit.sim import simulate


def random_walk(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = np.column_stack([rng.uniform(0, 0.5, n), rng.normal(0, 0.05, n), rng.normal(0, 0.2, n)])
    return compose_steps(np.array([1.0, 2.0, 0.3]), steps)


def drifted_radish(real: Path, tmp_path: Path, name: str) -> tuple[toolkit.Dataset, np.ndarray]:
    """A corrected Radish log imported with its poses as ground truth, odometry drifted from
    them (`with_drift`, seed 0); and the true poses at the scans."""
    import importers
    from importers.carmen import CarmenOptions

    out = importers.import_log(
        "carmen",
        [real / "carmen_radish_corrected" / f"{name}-corrected.log.gz"],
        tmp_path / name,
        CarmenOptions(poses="groundtruth"),
    )
    ds = with_drift(toolkit.load(out), seed=0)
    truth = truth_poses(ds)
    assert truth is not None
    return ds, truth


def test_compose_steps_matches_pose_by_pose_composition() -> None:
    rng = np.random.default_rng(0)
    steps = rng.normal(0, 0.3, (50, 3))
    start = np.array([1.0, -2.0, 0.5])
    poses = compose_steps(start, steps)
    slow = [start]
    for s in steps:
        slow.append(se2.compose(slow[-1], s))
    assert np.allclose(poses, np.array(slow), atol=1e-9)
    ref = sc.keyframes(poses, 0.6, 0.5)
    rel = se2.between(poses[ref[1:]], poses[1:])
    assert np.allclose(compose_refs(start, ref, rel), poses, atol=1e-9)


def test_poses_at_interpolates_across_the_heading_wrap() -> None:
    frame = pd.DataFrame({"t": [0.0, 1.0], "x": [0.0, 2.0], "y": [0.0, 0.0], "theta": [3.1, -3.1]})
    p = poses_at(frame, np.array([0.5, 2.0]))
    assert p[0, 0] == pytest.approx(1.0)
    assert abs(se2.wrap(p[0, 2] - np.pi)) < 1e-9  # through pi, not through 0
    assert p[1, 0] == pytest.approx(2.0)


def test_metrics_on_known_errors() -> None:
    truth = random_walk(200, 1)
    # a rigidly moved copy: ATE 0 after SE(2) alignment, RPE 0
    moved = se2.compose(np.broadcast_to([3.0, -1.0, 0.7], truth.shape), truth)
    assert np.allclose(align_se2(moved, truth), se2.inverse(np.array([3.0, -1.0, 0.7])))
    assert ATE.compute(moved, truth).rmse < 1e-9
    assert RPE.compute(moved, truth).translation < 1e-9
    # one step 0.3 m off and one 6° off: two failures, and the RPE counts them
    steps = se2.between(truth[:-1], truth[1:])
    steps[10, 0] += 0.3
    steps[50, 2] += np.deg2rad(6)
    bad = compose_steps(truth[0], steps)
    f = Failures.compute(bad, truth)
    assert (f.count, f.steps) == (2, 200)
    rpe = RPE.compute(bad, truth)
    assert rpe.translation == pytest.approx(np.sqrt(0.3**2 / 200), rel=1e-6)
    assert rpe.rotation == pytest.approx(np.sqrt(np.deg2rad(6) ** 2 / 200), rel=1e-6)
    assert evaluate(bad, truth)["ate"]["rmse"] > 0.1


def _headings_noised(truth: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """`truth` rebuilt from its steps with N(0, sigma) rad added to each step's turn."""
    steps = se2.between(truth[:-1], truth[1:])
    steps[:, 2] += rng.normal(0.0, sigma, len(steps))
    return compose_steps(truth[0], steps)


def test_shared_error_splits_a_common_error_from_each_runs_own() -> None:
    """Runs that all inherit one heading error per step (a truth off by it) plus their own:
    the split recovers both over 10 steps (sigma * sqrt(10)); runs with no common error show
    (nearly) none; identical runs have no own part."""
    rng = np.random.default_rng(3)
    steps = np.column_stack([np.full(2000, 0.5), np.zeros(2000), rng.normal(0, 0.05, 2000)])
    truth = compose_steps(np.zeros(3), steps)  # 0.5 m apart: 4.9 m of path is 10 steps
    common, own = 0.004, 0.002
    shared = _headings_noised(truth, common, rng)
    runs = [_headings_noised(shared, own, rng) for _ in range(6)]
    got = shared_error(runs, truth, 4.9)
    assert got.runs == 6 and got.pairs == len(truth) - 10
    assert got.rotation_common == pytest.approx(common * np.sqrt(10), rel=0.1)
    assert got.rotation_own == pytest.approx(own * np.sqrt(10), rel=0.1)
    assert got.rotation**2 == pytest.approx(got.rotation_own**2 + got.rotation_common**2)
    alone = shared_error([_headings_noised(truth, own, rng) for _ in range(6)], truth, 4.9)
    assert alone.rotation_common < 0.3 * alone.rotation_own
    assert alone.rotation_own == pytest.approx(own * np.sqrt(10), rel=0.1)
    same = shared_error([shared, shared.copy()], truth, 4.9)
    assert same.rotation_own == 0.0 and same.translation_own == 0.0
    assert same.rotation_common == pytest.approx(common * np.sqrt(10), rel=0.1)
    assert same.translation_common > 0.0
    with pytest.raises(ValueError, match="two runs"):
        shared_error([shared], truth, 4.9)


@pytest.mark.parametrize("scenario", ["corridor", "building"])
def test_simulated_logs_meet_the_accuracy_targets(scenario: str) -> None:
    ds = simulate(scenario, seed=1).dataset
    truth = truth_poses(ds)
    assert truth is not None
    odo = evaluate(build(ds, "odometry").poses, truth)
    result = build(ds, "gaussian")
    got = evaluate(result.poses, truth)
    assert got["ate"]["rmse"] <= odo["ate"]["rmse"] / 5
    assert got["failures"]["count"] == 0
    assert got["rpe"]["rotation"] < odo["rpe"]["rotation"]
    assert got["rpe"]["translation"] < 0.02
    frame = toolkit.trajectory(ds, method="gaussian")
    assert list(frame.columns) == ["t", "x", "y", "theta"] and len(frame) == ds.n_scans
    assert np.allclose(frame[["x", "y", "theta"]].to_numpy(), result.poses)


@pytest.mark.real
def test_real_intel_log_with_drift_beats_odometry_and_icp(real: Path, tmp_path: Path) -> None:
    ds, truth = drifted_radish(real, tmp_path, "intel")
    odo = evaluate(build(ds, "odometry").poses, truth)
    gauss = evaluate(build(ds, "gaussian").poses, truth)
    icp = evaluate(build(ds, "icp").poses, truth)
    assert odo["ate"]["rmse"] > 5.0  # the drift is real
    assert gauss["ate"]["rmse"] <= odo["ate"]["rmse"] / 5
    assert gauss["rpe"]["translation"] <= 1.25 * icp["rpe"]["translation"]
    assert gauss["rpe"]["rotation"] <= 1.25 * icp["rpe"]["rotation"]
    assert gauss["failures"]["count"] <= icp["failures"]["count"]


def test_methods_and_errors() -> None:
    ds = simulate("corridor", seed=2, scans=50).dataset
    assert np.allclose(build(ds, "odometry").poses, ds.odometry[["x", "y", "theta"]].to_numpy())
    with pytest.raises(toolkit.ToolkitError, match="unknown method"):
        build(ds, "magic")
    bare = toolkit.Dataset(t=ds.t, ranges=ds.ranges, laser=ds.laser)
    with pytest.raises(toolkit.ToolkitError, match="needs odometry"):
        build(bare, "odometry")
    with pytest.raises(toolkit.ToolkitError, match="ground truth"):
        with_drift(bare)
    assert len(build(bare, "gaussian").frame) == 50  # no odometry: seeded with no motion


@pytest.mark.real
def test_real_acapulco_hall_heading_does_not_lean_on_the_odometry(
    real: Path, tmp_path: Path
) -> None:
    # A convention hall, scans ~1 m apart: a tenth of the seed's heading error used to survive
    # each match, and the drift's bias piled up (ATE 14 m against odometry's 31 m).
    ds, truth = drifted_radish(real, tmp_path, "acapulco")
    steps = se2.laser_motion(se2.between(truth[:-1], truth[1:]), ds.laser)
    off = np.deg2rad(0.8)

    def pull(config: sc.MatchConfig) -> float:
        """How far the mean heading follows a +-0.8° seed error (0: not at all, 1: fully)."""
        lean = [
            se2.wrap(
                sc.match_pairs(ds.ranges, steps + np.array([0, 0, s]), ds.laser, config).pose[:, 2]
                - steps[:, 2]
            ).mean()
            for s in (off, -off)
        ]
        return float(lean[0] - lean[1]) / (2 * off)

    assert pull(sc.MatchConfig(restart_turn=-1)) > 0.08  # without the restart
    assert pull(sc.MatchConfig()) < 0.5 * pull(sc.MatchConfig(restart_turn=-1))
    odo = evaluate(build(ds, "odometry").poses, truth)
    gauss = evaluate(build(ds, "gaussian").poses, truth)
    assert odo["ate"]["rmse"] > 20.0  # the drift is real
    assert gauss["ate"]["rmse"] <= odo["ate"]["rmse"] / 5
