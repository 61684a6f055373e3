"""Trajectory accuracy against ground truth: ATE, RPE and failures.

- `ATE`: absolute trajectory error, the RMS position error after the best SE(2) alignment
  of the estimate onto the truth (rotation and translation, no scale: Umeyama/Kabsch).
- `RPE`: relative pose error per scan step: the error of each estimated motion between
  consecutive scans, in translation (m) and rotation (rad); RMS over the steps.
- `Failures`: steps whose motion is off by more than 0.2 m or 5°.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from toolkit.se2 import between, compose, wrap

FAIL_TRANSLATION = 0.2  # m
FAIL_ROTATION = float(np.deg2rad(5.0))  # rad


def align_se2(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The SE(2) transform (x, y, theta) that best moves `est` positions onto `truth`'s."""
    a = est[:, :2] - est[:, :2].mean(axis=0)
    b = truth[:, :2] - truth[:, :2].mean(axis=0)
    cross = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    dot = float(np.sum(a * b))
    theta = np.arctan2(cross, dot)
    c, s = np.cos(theta), np.sin(theta)
    centre = est[:, :2].mean(axis=0)
    rotated = np.array([c * centre[0] - s * centre[1], s * centre[0] + c * centre[1]])
    shift = truth[:, :2].mean(axis=0) - rotated
    return np.array([shift[0], shift[1], theta])


def _check(est: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    est = np.asarray(est, dtype=np.float64).reshape(-1, 3)
    truth = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    if est.shape != truth.shape:
        raise ValueError(f"estimate {est.shape} and truth {truth.shape} differ")
    return est, truth


@dataclass(frozen=True)
class ATE:
    """Absolute trajectory error after SE(2) alignment (m)."""

    rmse: float
    mean: float
    median: float
    max: float
    poses: int

    @classmethod
    def compute(cls, est: np.ndarray, truth: np.ndarray) -> ATE:
        est, truth = _check(est, truth)
        if len(est) == 0:
            return cls(0.0, 0.0, 0.0, 0.0, 0)
        moved = compose(np.broadcast_to(align_se2(est, truth), est.shape), est)
        err = np.hypot(*(moved[:, :2] - truth[:, :2]).T)
        return cls(
            float(np.sqrt(np.mean(err**2))),
            float(err.mean()),
            float(np.median(err)),
            float(err.max()),
            len(err),
        )


@dataclass(frozen=True)
class RPE:
    """Relative pose error per scan step: RMS translation (m) and rotation (rad) errors."""

    translation: float
    rotation: float
    translation_median: float
    rotation_median: float
    steps: int

    @staticmethod
    def step_errors(est: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per step: translation (m) and absolute rotation (rad) error of the motion."""
        est, truth = _check(est, truth)
        e = between(between(truth[:-1], truth[1:]), between(est[:-1], est[1:]))
        return np.hypot(e[:, 0], e[:, 1]), np.abs(wrap(e[:, 2]))

    @classmethod
    def compute(cls, est: np.ndarray, truth: np.ndarray) -> RPE:
        et, er = cls.step_errors(est, truth)
        if len(et) == 0:
            return cls(0.0, 0.0, 0.0, 0.0, 0)
        return cls(
            float(np.sqrt(np.mean(et**2))),
            float(np.sqrt(np.mean(er**2))),
            float(np.median(et)),
            float(np.median(er)),
            len(et),
        )


@dataclass(frozen=True)
class Failures:
    """Steps whose estimated motion is off by more than 0.2 m or 5° (the thresholds)."""

    count: int
    steps: int
    translation_limit: float = FAIL_TRANSLATION
    rotation_limit: float = FAIL_ROTATION

    @classmethod
    def compute(cls, est: np.ndarray, truth: np.ndarray) -> Failures:
        et, er = RPE.step_errors(est, truth)
        bad = (et > FAIL_TRANSLATION) | (er > FAIL_ROTATION)
        return cls(int(bad.sum()), len(et))

    @property
    def fraction(self) -> float:
        return self.count / self.steps if self.steps else 0.0


def evaluate(est: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    """ATE, RPE and failures of `est` against `truth` (both S x 3), as a JSON-ready dict."""
    rpe = RPE.compute(est, truth)
    return {
        "ate": asdict(ATE.compute(est, truth)),
        "rpe": {**asdict(rpe), "rotation_deg": float(np.rad2deg(rpe.rotation))},
        "failures": asdict(Failures.compute(est, truth)),
    }


def truth_relations(
    truth: np.ndarray, step: float = 1.0, loop_radius: float = 1.0, loop_gap: float = 10.0
) -> np.ndarray:
    """Index pairs (R x 2) to measure relation error on, derived from the truth as in Kümmerle
    et al. (2009): each pose with the first one `step` metres further along the path, and one
    "loop" relation per revisit (a pose within `loop_radius` m of an earlier one that lies more
    than `loop_gap` m back along the path; one every `step` metres of path)."""
    truth = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    n = len(truth)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth[:, :2], axis=0).T))])
    later = np.searchsorted(along, along + step)
    keep = later < n
    seq = np.column_stack([np.nonzero(keep)[0], later[keep]])
    # loop relations on poses one `step` apart along the path (bounded: O(M^2) on M poses)
    marks = np.unique(np.searchsorted(along, np.arange(0.0, along[-1], step)))
    xy, a = truth[marks, :2], along[marks]
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    near = (d < loop_radius) & (a[:, None] - a[None, :] > loop_gap)
    i, j = np.nonzero(near)
    first = np.unique(i, return_index=True)[1]  # one per later pose: the earliest match
    loops = np.column_stack([marks[j[first]], marks[i[first]]])
    return np.concatenate([seq, loops]).astype(np.int64)


def relation_error(est: np.ndarray, truth: np.ndarray, pairs: np.ndarray) -> dict[str, float]:
    """Kümmerle et al.'s relation error over index pairs (i, j): the error of the estimated
    motion from pose i to pose j against the true one; mean and std of its translation (m) and
    absolute rotation (deg), and the number of relations."""
    est, truth = _check(est, truth)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) == 0:
        return {"relations": 0}
    i, j = pairs[:, 0], pairs[:, 1]
    return relation_error_motions(between(est[i], est[j]), between(truth[i], truth[j]))


def relation_error_motions(est_motion: np.ndarray, true_motion: np.ndarray) -> dict[str, float]:
    """Relation error of estimated motions (R x 3) against given ones (e.g. a Rawseeds
    `.relations` file)."""
    e = between(true_motion, est_motion)
    et, er = np.hypot(e[:, 0], e[:, 1]), np.rad2deg(np.abs(wrap(e[:, 2])))
    return {
        "relations": len(e),
        "translation_mean": float(et.mean()),
        "translation_std": float(et.std()),
        "rotation_mean_deg": float(er.mean()),
        "rotation_std_deg": float(er.std()),
    }


@dataclass(frozen=True)
class SharedError:
    """Repeated runs' error of relative motion over `distance` m of the truth's path, split
    into the part every run has (`common`: the truth's own error, or a bias of the method no
    run escapes) and each run's own (`own`: run-to-run noise). RMS over the pose pairs and
    runs; total^2 = own^2 + common^2. Translation in m, rotation in rad."""

    distance: float
    translation: float
    translation_own: float
    translation_common: float
    rotation: float
    rotation_own: float
    rotation_common: float
    pairs: int
    runs: int


def shared_error(runs: list[np.ndarray], truth: np.ndarray, distance: float) -> SharedError:
    """The error of each run's motion from every pose i to the first pose `distance` m of the
    truth's path later, against the truth's, split by the runs' agreement: the own part from
    the differences of the runs' errors (pairwise, halved), the common part the rest. Why: the
    corrected poses real logs give as truth are a SLAM output themselves; a part of the error
    that drift seeds, starting poses and other matchers all share is no run's own
    (docs/journal/maps.md, session 27). Needs two runs or more."""
    if len(runs) < 2:
        raise ValueError("the split needs two runs or more")
    checked = [_check(run, truth) for run in runs]
    truth = checked[0][1]
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth[:, :2], axis=0).T))])
    later = np.searchsorted(along, along + distance)
    i = np.nonzero(later < len(truth))[0]
    j = later[i]
    true_motion = between(truth[i], truth[j])
    errors = []
    for est, _ in checked:
        e = between(true_motion, between(est[i], est[j]))
        e[:, 2] = wrap(e[:, 2])
        errors.append(e)
    err = np.stack(errors)  # runs x pairs x 3
    if err.shape[1] == 0:
        return SharedError(distance, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, len(runs))
    a, b = np.triu_indices(len(runs), k=1)
    diff = err[a] - err[b]
    diff[..., 2] = wrap(diff[..., 2])
    total_t = float(np.mean(np.sum(err[..., :2] ** 2, axis=-1)))
    total_r = float(np.mean(err[..., 2] ** 2))
    own_t = float(np.mean(np.sum(diff[..., :2] ** 2, axis=-1))) / 2.0
    own_r = float(np.mean(diff[..., 2] ** 2)) / 2.0
    return SharedError(
        distance,
        float(np.sqrt(total_t)),
        float(np.sqrt(own_t)),
        float(np.sqrt(max(total_t - own_t, 0.0))),
        float(np.sqrt(total_r)),
        float(np.sqrt(own_r)),
        float(np.sqrt(max(total_r - own_r, 0.0))),
        len(i),
        len(runs),
    )
