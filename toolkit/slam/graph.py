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


# the first node's prior: held where it is (a graph's gauge)
_HOLD = np.array([1e-3, 1e-3, 1e-4])


def _pose(p: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


def factor_graph(
    nodes: np.ndarray,
    poses: np.ndarray,
    edges: list[Edge],
    robust: float = 1.0,
    base: gtsam.NonlinearFactorGraph | None = None,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """GTSAM graph and initial values: a prior on the first node, one BetweenFactorPose2 per
    edge (loop edges wrapped in a Cauchy kernel of width `robust` sigmas; 0: none, as g2o's
    file format has no kernels). `base` (`edge_factors`' graph) goes in after the prior and
    before `edges`: the factors of edges that many optimisations share, built once (the
    same graph, factor for factor, as those edges given first in `edges`)."""
    graph = gtsam.NonlinearFactorGraph()
    values = initial_values(nodes, poses)
    prior = gtsam.noiseModel.Diagonal.Sigmas(_HOLD)
    graph.add(gtsam.PriorFactorPose2(int(nodes[0]), _pose(poses[0]), prior))
    if base is not None:
        graph.push_back(base)
    _add_edges(graph, edges, robust)
    return graph, values


def initial_values(nodes: np.ndarray, poses: np.ndarray) -> gtsam.Values:
    """GTSAM values: each node's pose (K x 3, in `nodes` order)."""
    values = gtsam.Values()
    for node, pose in zip(nodes, poses, strict=True):
        values.insert(int(node), _pose(pose))
    return values


def error(graph: gtsam.NonlinearFactorGraph, nodes: np.ndarray, poses: np.ndarray) -> float:
    """The graph's total error (half the sum of squared whitened residuals, kernels applied)
    at `poses`."""
    return float(graph.error(initial_values(nodes, poses)))


def lago_start(nodes: np.ndarray, edges: list[Edge], first: np.ndarray) -> np.ndarray:
    """The nodes' poses (K x 3) by GTSAM's LAGO (the orientations by linear least squares over
    the graph, then the positions), the first held at `first`: a start for Levenberg-Marquardt
    that takes turns of any size, where the last optimum may sit in the basin of a stretch
    turned a quarter round. LAGO asks for keys 0..K-1 along the sequential chain and diagonal
    noise: the nodes are renumbered and each edge keeps its covariance's diagonal."""
    index = {int(n): k for k, n in enumerate(nodes)}
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(0, _pose(first), gtsam.noiseModel.Diagonal.Sigmas(_HOLD)))
    for e in edges:
        spread = np.sqrt(np.maximum(np.diag(np.asarray(e.covariance, np.float64)), 1e-12))
        noise = gtsam.noiseModel.Diagonal.Sigmas(spread)
        graph.add(gtsam.BetweenFactorPose2(index[e.a], index[e.b], _pose(e.pose), noise))
    start = gtsam.lago.initialize(graph, True)
    out: np.ndarray = np.ascontiguousarray(gtsam.utilities.extractPose2(start))
    return out


def edge_factors(edges: list[Edge], robust: float = 1.0) -> gtsam.NonlinearFactorGraph:
    """A graph of `edges`' factors alone (`factor_graph`'s), to pass as its `base`."""
    graph = gtsam.NonlinearFactorGraph()
    _add_edges(graph, edges, robust)
    return graph


def _add_edges(graph: gtsam.NonlinearFactorGraph, edges: list[Edge], robust: float) -> None:
    """One BetweenFactorPose2 per edge into `graph` (loop edges with the Cauchy kernel)."""
    for e in edges:
        # GTSAM's Pose2 tangent order is (x, y, theta), as ours
        noise: Any = gtsam.noiseModel.Gaussian.Covariance(np.asarray(e.covariance, np.float64))
        if e.loop and robust > 0:
            noise = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Cauchy.Create(robust), noise
            )
        graph.add(gtsam.BetweenFactorPose2(int(e.a), int(e.b), _pose(e.pose), noise))


def optimise(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, nodes: np.ndarray
) -> np.ndarray:
    """Levenberg-Marquardt from `values`; the optimised poses of `nodes` (K x 3): read in
    one call (`extractPose2`, the same doubles as `atPose2` node by node) when `values`
    holds exactly the nodes, ascending (the keys' order)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-6)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    ordered = len(nodes) == result.size() and bool(np.all(np.diff(nodes) > 0))
    if ordered:  # the values are the nodes: GTSAM's (x, y, theta) of each, in key order
        got: np.ndarray = np.ascontiguousarray(gtsam.utilities.extractPose2(result))
        if got.shape == (len(nodes), 3):
            return got
    out = np.empty((len(nodes), 3))
    for k, node in enumerate(nodes):
        p = result.atPose2(int(node))
        out[k] = p.x(), p.y(), p.theta()
    return out


def residuals(poses: np.ndarray, nodes: np.ndarray, edges: list[Edge]) -> np.ndarray:
    """Per edge: the measurement's error against `poses` (K x 3, in `nodes` order) as
    (translation m, |rotation| rad, Mahalanobis distance squared). The errors of all edges
    in one call of `between` (row by row the same numbers), the distances edge by edge."""
    out = np.zeros((len(edges), 3))
    if not edges:
        return out
    index = {int(n): k for k, n in enumerate(nodes)}
    p = np.asarray(poses)
    ia = np.array([index[e.a] for e in edges])
    ib = np.array([index[e.b] for e in edges])
    rel = between(p[ia], p[ib])
    err = between(np.array([e.pose for e in edges], dtype=np.float64), rel)
    err[:, 2] = (err[:, 2] + np.pi) % (2 * np.pi) - np.pi
    out[:, 0] = np.hypot(err[:, 0], err[:, 1])
    out[:, 1] = np.abs(err[:, 2])
    for m, e in enumerate(edges):
        out[m, 2] = err[m] @ np.linalg.solve(e.covariance, err[m])
    return out


def write_g2o(path: Path, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """The graph in g2o's text format (VERTEX_SE2 / EDGE_SE2), as `gtsam.readG2o` reads it."""
    gtsam.writeG2o(graph, values, str(path))
