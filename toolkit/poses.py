"""Trajectories: the robot's pose at every scan, from odometry alone or corrected by scan matching.

    traj = toolkit.trajectory(ds, method="gaussian")     # DataFrame t, x, y, theta

Every consecutive pair of scans is matched independently given odometry (all pairs at once,
`toolkit.align.scan`), each against the last keyframe (chosen from odometry, so the pairs are
known before matching), and the relative motions are composed into poses: for consecutive
pairs a cumulative SE(2) sum (headings a cumulative sum, positions a cumulative sum of rotated
steps), with keyframes one pass per scan. The trajectory starts at the odometry's first pose
(the origin without odometry).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from enum import StrEnum
from functools import cached_property
from typing import TYPE_CHECKING, Literal

import numba as nb
import numpy as np

from toolkit import align, se2
from toolkit.align import scan as sc
from toolkit.align import se2_jit
from toolkit.dataset import Dataset, PoseStream
from toolkit.errors import ToolkitError

if TYPE_CHECKING:
    import pandas as pd

    from toolkit.sim.odometry import OdometryModel


class Method(StrEnum):
    """How a trajectory is obtained; the values are the CLI's `--method` names."""

    GAUSSIAN = "gaussian"  # the paper's scan matcher
    ICP = "icp"  # 2D point-to-line ICP
    ICP_POINT = "icp-point"  # Open3D point-to-point ICP
    ODOMETRY = "odometry"  # no matching

    @classmethod
    def parse(cls, name: str) -> Method:
        """The method called `name`; a ToolkitError naming the known ones otherwise."""
        try:
            return cls(name)
        except ValueError:
            known = ", ".join(m.value for m in cls)
            raise ToolkitError(f"unknown method {name!r}; known: {known}") from None


METHODS: tuple[str, ...] = tuple(m.value for m in Method)


@dataclass
class TrajectoryResult:
    """Poses per scan and how they were obtained: `stream` (numpy), `frame` its DataFrame
    (pandas loaded then, on use: `toolkit map` does without)."""

    stream: PoseStream  # t, x, y, theta
    method: Method
    matches: sc.PairMatches | None = None  # per pair, for the matching methods
    seconds: float = 0.0  # time spent aligning scan pairs (compilation kept out)
    config: dict[str, object] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)  # s: prepare, compile, match, compose

    @cached_property
    def frame(self) -> pd.DataFrame:
        """DataFrame t, x, y, theta (made on first use)."""
        return self.stream.frame()

    @property
    def poses(self) -> np.ndarray:
        """The poses (S x 3), a new array each time, in Fortran order as the DataFrame's
        `[["x", "y", "theta"]].to_numpy()` gave them (the numba kernels that take them
        were compiled, and cached, for that layout)."""
        return np.array(self.stream.xyt, order="F")

    @property
    def pairs_per_second(self) -> float | None:
        if self.matches is None or self.seconds <= 0:
            return None
        return len(self.matches) / self.seconds


def poses_at(frame: pd.DataFrame, t: np.ndarray) -> np.ndarray:
    """A pose stream (t, x, y, theta) at times `t` (S x 3): `PoseStream.at`."""
    return PoseStream.from_frame(frame).at(t)


def compose_steps(start: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Poses (P+1 x 3) from a start pose and P relative motions, each in the previous frame."""
    start = np.asarray(start, dtype=np.float64).reshape(3)
    steps = np.asarray(steps, dtype=np.float64).reshape(-1, 3)
    theta = start[2] + np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    moves = np.column_stack([c * steps[:, 0] - s * steps[:, 1], s * steps[:, 0] + c * steps[:, 1]])
    xy = start[:2] + np.concatenate([np.zeros((1, 2)), np.cumsum(moves, axis=0)])
    return np.column_stack([xy, se2.wrap(theta)])


def compose_refs(start: np.ndarray, ref: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Poses (S x 3): scan 0 at `start`, scan k at pose[ref[k]] ∘ steps[k-1] (ref[k] < k)."""
    ref = np.asarray(ref, dtype=np.int64)
    if np.array_equal(ref[1:], np.arange(len(ref) - 1)):
        return compose_steps(start, steps)
    return _compose_refs(np.asarray(start, np.float64), ref, np.asarray(steps, np.float64))


@nb.njit(cache=True)
def _compose_refs(start: np.ndarray, ref: np.ndarray, steps: np.ndarray) -> np.ndarray:
    poses = np.empty((len(ref), 3))
    poses[0] = start
    for k in range(1, len(ref)):  # truly sequential: each pose hangs from an earlier one
        se2_jit.compose_into(poses[ref[k]], steps[k - 1], poses[k])
    return poses


def odometry_poses(ds: Dataset) -> np.ndarray | None:
    """The odometry at every scan time (S x 3), or None when the log has no odometry."""
    stream = ds.stream("odometry")
    return stream.at(ds.t) if stream is not None and len(stream) else None


def truth_poses(ds: Dataset) -> np.ndarray | None:
    """The ground truth at every scan time (S x 3), or None."""
    stream = ds.stream("groundtruth")
    return stream.at(ds.t) if stream is not None and len(stream) else None


#: Scan pairs the default matcher runs at once between two progress steps: large enough that
#: the parallel batch keeps both cores busy (the chunks do not change the result).
PAIRS_PER_STEP = 4096


#: The methods matched by ICP (`toolkit.align`), which records its own parameters.
ICP_METHODS = (Method.ICP, Method.ICP_POINT)


def icp_settings(method: Method, config: sc.MatchConfig) -> dict[str, object]:
    """What an ICP run records as its matcher's parameters (config.json's `matcher`): the
    variant, its fixed distance and iterations, and the keyframes of `config` it used."""
    icp = "point_to_line" if method == Method.ICP else "point_to_point"
    used: dict[str, object] = {"icp": icp, "max_distance": 0.5, "iterations": 30}
    return used | {k: getattr(config, k) for k in ("keyframe_distance", "keyframe_angle")}


def build(
    ds: Dataset,
    method: Method | str = Method.GAUSSIAN,
    config: sc.MatchConfig | None = None,
    matcher: Callable[..., sc.PairMatches] | None = None,
    progress: Callable[[int], object] | None = None,
) -> TrajectoryResult:
    """The trajectory of `ds` by `method`: gaussian (the paper's matcher), icp (2D
    point-to-line), icp-point (Open3D point-to-point) or odometry (no matching).

    `matcher` replaces `match_pairs` for gaussian (same arguments and result), e.g. one that
    runs the pairs on a Dask cluster (`toolkit.app.fleet_map.matcher_for`). `progress(m)` is told
    of every m scan pairs matched (S - 1 in all; per `PAIRS_PER_STEP` by the default matcher,
    all at once by a given one)."""
    method = Method.parse(method)
    t_start = time.perf_counter()
    odo = odometry_poses(ds)
    n = ds.n_scans
    if method == Method.ODOMETRY:
        if odo is None:
            raise ToolkitError("method odometry needs odometry; the dataset has none", file=ds.path)
        prepare = {"prepare": time.perf_counter() - t_start}
        return TrajectoryResult(PoseStream(ds.t, odo), method, timings=prepare)
    start = odo[0] if odo is not None else np.zeros(3)
    if n < 2:
        return TrajectoryResult(PoseStream(ds.t, np.tile(start, (n, 1))), method)
    config = config or sc.MatchConfig()
    if odo is not None:
        ref = sc.keyframes(odo, config.keyframe_distance, config.keyframe_angle)
        robot_seed = se2.between(odo[ref[1:]], odo[1:])
    else:  # no odometry: consecutive scans, seeded with "no motion" (the motion model bounds it)
        ref = np.maximum(np.arange(n) - 1, 0)
        robot_seed = np.zeros((n - 1, 3))
    seeds = se2.laser_motion(robot_seed, ds.laser)
    t_compile = time.perf_counter()
    if method == Method.GAUSSIAN and matcher is None:
        # the kernels' first call of a session compiles them, or loads numba's cache (0.1-1 s;
        # 10 s and more when nothing is cached): done on the first pair alone, so that the
        # matching time (and pairs/s) is the matching's
        sc.match_pairs(ds.ranges[:2], seeds[:1], ds.laser, config, ref[:2])
    t0 = time.perf_counter()
    if method == Method.GAUSSIAN and matcher is None:
        matches = sc.match_pairs(
            ds.ranges, seeds, ds.laser, config, ref, chunk=PAIRS_PER_STEP, progress=progress
        )
        used: dict[str, object] = config.to_dict()
    elif method == Method.GAUSSIAN and matcher is not None:
        matches = matcher(ds.ranges, seeds, ds.laser, config, ref)
        used = config.to_dict()
        if progress is not None:
            progress(n - 1)
    else:
        icp_method: Literal["point_to_line", "point_to_point"] = (
            "point_to_line" if method == Method.ICP else "point_to_point"
        )
        matches = align.match_pairs_icp(
            ds.ranges, seeds, ds.laser, icp_method, ref=ref, progress=progress
        )
        used = icp_settings(method, config)
    seconds = time.perf_counter() - t0
    poses = compose_refs(start, ref, se2.robot_motion(matches.pose, ds.laser))
    timings = {
        "prepare": t_compile - t_start,
        "compile": t0 - t_compile,
        "match": seconds,
        "compose": time.perf_counter() - t0 - seconds,
    }
    return TrajectoryResult(PoseStream(ds.t, poses), method, matches, seconds, used, timings)


def trajectory(
    ds: Dataset, method: Method | str = Method.GAUSSIAN, config: sc.MatchConfig | None = None
) -> pd.DataFrame:
    """DataFrame t, x, y, theta: the robot's pose at every scan by `method`."""
    return build(ds, method, config).frame


#: The one default drift (`with_drift`), used by the tests, the bench and the report alike:
#: wheel-odometry errors added to real logs whose poses are corrected (no raw odometry):
#: 2% scale error, 0.5% wheel-diameter difference (a heading drift of ~0.9°/m on a Pioneer),
#: 0.005 m/sqrt(m) encoder noise per wheel and a slip in one step of 200 (toolkit.sim.odometry).
REAL_LOG_DRIFT: dict[str, float] = {
    "scale_error": 0.02,
    "wheel_diff": 0.005,
    "wheel_noise": 0.005,
    "slip_prob": 0.005,
}


def with_drift(ds: Dataset, seed: int = 0, **params: float) -> Dataset:
    """A copy of `ds` whose odometry is its ground truth at the scan times run through the
    simulator's differential-drive odometry model (REAL_LOG_DRIFT, overridden by `params`),
    seeded: for real logs whose only poses are SLAM-corrected ones."""
    truth = truth_poses(ds)
    if truth is None:
        raise ToolkitError("adding drift needs ground truth; the dataset has none", file=ds.path)
    # on use: importing toolkit.sim.odometry loads the whole simulator (the package)
    odometry_model: type[OdometryModel] = importlib.import_module(
        "toolkit.sim.odometry"
    ).OdometryModel
    model = odometry_model(**{**REAL_LOG_DRIFT, **params})
    odo = model.integrate(truth, np.random.default_rng(seed))
    meta = {**ds.meta, "odometry": "simulated wheel odometry along the ground truth (drift added)"}
    return replace(
        ds, odometry=PoseStream(ds.t, odo), groundtruth=PoseStream(ds.t, truth), meta=meta
    )
