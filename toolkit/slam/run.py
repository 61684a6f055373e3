"""The mapper's part of a run directory (`toolkit map`, loops on by default).

RUN/ gains:
    graph.g2o     the pose graph (VERTEX_SE2 per keyframe, its scan index as id; EDGE_SE2
                  sequential and loop edges with their information), optimised poses
    loops.csv     every verified loop candidate: scans a, b, relative pose, score, inliers,
                  ambiguity, accepted, reason (why not kept; "(coarse level)": refused
                  as ambiguous by the coarse search alone, its pose and score the coarse
                  winner's, no inliers; with ground truth, its residual and `false`)
    map.png       odometry / before loops / after loops side by side
    map.pgm/.yaml the occupancy grid (ROS map_server)
and metrics.json the loops, the time of each stage, the sequential estimate's errors and the
relation error (Kümmerle et al.); `toolkit.mapping` adds the grid's consistency.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from toolkit.align import scan as sc
from toolkit.dataset import Dataset, PoseStream, write_csv
from toolkit.metrics import evaluate
from toolkit.poses import TrajectoryResult, build, odometry_poses, truth_poses
from toolkit.slam import graph as pg
from toolkit.slam.localmap import sequential
from toolkit.slam.loops import Loop, is_false_loop
from toolkit.slam.motion import scan_clock
from toolkit.slam.pipeline import (
    SlamConfig,
    SlamResult,
    close_loops,
    mend_blind,
    mend_excursions,
)
from toolkit.slam.relations import RELATIONS, relation_metrics
from toolkit.slam.render import write_occupancy, write_side_by_side
from toolkit.slam.scanmap import scan_to_map


@dataclass
class SlamRun:
    """The loop-closing stage's results, beside the sequential TrajectoryResult."""

    before: np.ndarray
    keys: np.ndarray
    edges: list[pg.Edge]
    loops: list[Loop]
    timings: dict[str, float]
    config: SlamConfig

    def write(
        self, out: Path, ds: Dataset, poses: np.ndarray, title: str, maps: bool = True
    ) -> None:
        """graph.g2o and loops.csv; with `maps`, map.png (odometry / before / after loops
        side by side) and the occupancy grid map.pgm + map.yaml."""
        graph, values = pg.factor_graph(self.keys, poses[self.keys], self.edges, robust=0.0)
        pg.write_g2o(out / "graph.g2o", graph, values)
        truth = truth_poses(ds)
        table = SlamResult(
            poses, self.before, self.keys, self.edges, self.loops, 0.0, {}, {}
        ).loop_table(truth)
        columns = [
            "a",
            "b",
            "x",
            "y",
            "theta",
            "score",
            "inliers",
            "ambiguity",
            "accepted",
            "reason",
            "corridor",
            "axis_x",
            "axis_y",
        ]
        write_csv(out / "loops.csv", table, columns)
        if not maps:
            return
        panels = []
        odo = odometry_poses(ds)
        if odo is not None:
            panels.append(("odometry", odo))
        panels += [("before loops", self.before), ("after loops", poses)]
        write_side_by_side(out / "map.png", ds, panels, truth, title)
        write_occupancy(out, ds, poses)

    def metrics(self, ds: Dataset) -> dict[str, Any]:
        accepted = [lp for lp in self.loops if lp.accepted]
        out: dict[str, Any] = {
            "motion_model": "odometry" if odometry_poses(ds) is not None else "constant velocity",
            "loops": len(accepted),
            "loop_candidates": len(self.loops),
            "graph": {"nodes": len(self.keys), "edges": len(self.edges)},
            "seconds": {**self.timings, "total": sum(self.timings.values())},
        }
        if odometry_poses(ds) is None:  # the times the constant velocity read
            out["scan_clock"] = scan_clock(ds.t)
        truth = truth_poses(ds)
        if truth is not None:
            out["false_loops"] = sum(is_false_loop(lp, truth) for lp in accepted)
            out["before_loops"] = evaluate(self.before, truth)
        return out


def slam_trajectory(
    ds: Dataset,
    method: str = "gaussian",
    config: sc.MatchConfig | None = None,
    matcher: Callable[..., sc.PairMatches] | None = None,
    slam: SlamConfig | None = None,
    progress: Callable[[int], object] | None = None,
    velocity: np.ndarray | None = None,
) -> tuple[TrajectoryResult, SlamRun]:
    """The sequential trajectory by `method` (gaussian: odometry or constant velocity as the
    motion model), then loops and the pose graph; the result's frame holds the final poses.
    `progress(m)`: m more scan pairs matched (`toolkit.poses.build`). `velocity`: without
    odometry, the motion per scan the log starts with (None: measured, `sequential`)."""
    slam = slam or SlamConfig()
    t0 = time.perf_counter()
    wheels = odometry_poses(ds)
    if slam.maps_scan_to_map(method, wheels is not None):
        # sequential by nature: runs here even when a cluster `matcher` is given (which
        # matches independent scan pairs), so a run gives the same poses on a cluster or not
        result = scan_to_map(ds, slam.scan_map, progress)
    elif method == "gaussian" and matcher is None:
        result = sequential(ds, config, progress, velocity)
        slam = replace(slam, front_end="keyframe")  # no odometry: the keyframe front end
    else:
        result = build(ds, method, config, matcher, progress)
        slam = replace(slam, front_end="keyframe")
    matching = time.perf_counter() - t0 - result.timings.get("compile", 0.0)
    before = result.poses
    step_cov = None
    if slam.front_end == "map" and result.matches is not None:
        step_cov = result.matches.covariance  # scan-to-map: world frame, per scan step
    odometry = wheels if slam.odometry_along > 0 else None
    step_fit = step_doubt = None
    if slam.front_end == "map" and slam.blind_turn > 0 and result.matches is not None:
        step_fit = result.matches.agreement  # the inlier share of each scan's fit
        step_doubt = result.matches.doubt
    if slam.front_end == "map" and wheels is not None and result.matches is not None:
        before = mend_blind(ds.ranges, result.matches.agreement, before, wheels, slam)
        before = mend_excursions(
            ds.ranges, ds.laser, result.matches.agreement, before, wheels, slam
        )
    poses, keys, edges, loops, timings, before = close_loops(
        ds, before, slam, step_cov, odometry, step_fit, step_doubt
    )
    out = replace(result, stream=PoseStream(result.stream.t, poses))
    run = SlamRun(before, keys, edges, loops, {"matching": matching, **timings}, slam)
    return out, run


__all__ = ["RELATIONS", "SlamRun", "relation_metrics", "slam_trajectory"]
