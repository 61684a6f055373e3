"""The pose graph: keyframe poses, sequential edges with the matcher's covariances, loop edges
with a robust (Cauchy) kernel; optimised by GTSAM's Levenberg-Marquardt and written as g2o.

Vertex ids are scan indices, so `graph.g2o` names the scans it constrains."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from toolkit.se2 import between


@dataclass
class Edge:
    """A relative pose measurement: pose of scan `b` in the frame of scan `a`."""

    a: int
    b: int
    pose: np.ndarray  # (3,)
    covariance: np.ndarray  # 3 x 3
    loop: bool = False


def _pose(p: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


def factor_graph(
    nodes: np.ndarray, poses: np.ndarray, edges: list[Edge], robust: float = 1.0
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """GTSAM graph and initial values: a prior on the first node, one BetweenFactorPose2 per
    edge (loop edges wrapped in a Cauchy kernel of width `robust` sigmas; 0: none, as g2o's
    file format has no kernels)."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for node, pose in zip(nodes, poses, strict=True):
        values.insert(int(node), _pose(pose))
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    graph.add(gtsam.PriorFactorPose2(int(nodes[0]), _pose(poses[0]), prior))
    for e in edges:
        # GTSAM's Pose2 tangent order is (x, y, theta), as ours
        noise: Any = gtsam.noiseModel.Gaussian.Covariance(np.asarray(e.covariance, np.float64))
        if e.loop and robust > 0:
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Cauchy.Create(robust), noise
            )
        graph.add(gtsam.BetweenFactorPose2(int(e.a), int(e.b), _pose(e.pose), noise))
    return graph, values


def optimise(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, nodes: np.ndarray
) -> np.ndarray:
    """Levenberg-Marquardt from `values`; the optimised poses of `nodes` (K x 3)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-6)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    out = np.empty((len(nodes), 3))
    for k, node in enumerate(nodes):
        p = result.atPose2(int(node))
        out[k] = p.x(), p.y(), p.theta()
    return out


def residuals(poses: np.ndarray, nodes: np.ndarray, edges: list[Edge]) -> np.ndarray:
    """Per edge: the measurement's error against `poses` (K x 3, in `nodes` order) as
    (translation m, |rotation| rad, Mahalanobis distance squared)."""
    index = {int(n): k for k, n in enumerate(nodes)}
    p = np.asarray(poses)
    out = np.zeros((len(edges), 3))
    for m, e in enumerate(edges):
        rel = between(p[index[e.a]], p[index[e.b]])
        err = between(e.pose, rel)
        err[2] = (err[2] + np.pi) % (2 * np.pi) - np.pi
        out[m] = np.hypot(err[0], err[1]), abs(err[2]), err @ np.linalg.solve(e.covariance, err)
    return out


def write_g2o(path: Path, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """The graph in g2o's text format (VERTEX_SE2 / EDGE_SE2), as `gtsam.readG2o` reads it."""
    gtsam.writeG2o(graph, values, str(path))
