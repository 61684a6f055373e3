"""The pose graph's fast paths (session 22) give, to the bit, what they replace: the shared
edges' factors built once (`edge_factors` as `factor_graph`'s base) optimise to the same
poses as the graph built whole, and the residuals of all edges at once equal those of one
edge at a time."""

from __future__ import annotations

import gtsam
import numpy as np

from toolkit.se2 import between, compose
from toolkit.slam import graph as pg
from toolkit.slam.pipeline import SlamConfig, restarted


def _loop_graph(
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, list[pg.Edge], list[pg.Edge]]:
    """A drifted square walked twice: sequential edges (from noisy steps), loop edges
    between its two laps (one of them wrong by a metre), and a start from the odometry."""
    n = 80
    t = np.arange(n) / 40 * 2 * np.pi
    truth = np.c_[10 * np.cos(t), 10 * np.sin(t), t + np.pi / 2]
    nodes = np.arange(n) * 3
    steps = between(truth[:-1], truth[1:]) + rng.normal(size=(n - 1, 3)) * [0.02, 0.02, 0.01]
    cov = np.diag([0.02**2, 0.02**2, 0.01**2])
    sequential = [pg.Edge(int(nodes[k]), int(nodes[k + 1]), steps[k], cov) for k in range(n - 1)]
    start = [truth[0]]
    for s in steps:
        start.append(compose(start[-1], s))
    loops = [
        pg.Edge(int(nodes[k]), int(nodes[k + 40]), between(truth[k], truth[k + 40]), cov, loop=True)
        for k in range(0, 40, 4)
    ]
    loops[3].pose = loops[3].pose + np.array([1.0, 0.0, 0.0])
    return nodes, np.array(start), sequential, loops


def test_base_graph_and_batched_residuals_give_the_plain_numbers() -> None:
    rng = np.random.default_rng(7)
    nodes, start, sequential, loops = _loop_graph(rng)
    whole = pg.optimise(*pg.factor_graph(nodes, start, sequential + loops), nodes)
    base = pg.edge_factors(sequential)
    shared = pg.optimise(*pg.factor_graph(nodes, start, loops, base=base), nodes)
    assert np.array_equal(whole, shared)
    # the base is not changed by the graphs built on it: a second use, from the optimum
    again = pg.optimise(*pg.factor_graph(nodes, whole, loops[:5], base=base), nodes)
    plain = pg.optimise(*pg.factor_graph(nodes, whole, sequential + loops[:5]), nodes)
    assert np.array_equal(again, plain) and base.size() == len(sequential)
    # the loops moved the start (the odometry's drift): the numbers compared are not trivial
    assert np.abs(whole - start).max() > 0.05

    out = pg.residuals(whole, nodes, loops)
    index = {int(n): k for k, n in enumerate(nodes)}
    for e, row in zip(loops, out, strict=True):
        err = between(e.pose, between(whole[index[e.a]], whole[index[e.b]]))
        err[2] = (err[2] + np.pi) % (2 * np.pi) - np.pi
        one = [np.hypot(err[0], err[1]), abs(err[2]), err @ np.linalg.solve(e.covariance, err)]
        assert np.array_equal(row, one)
    assert out[3, 2] > 16 > np.delete(out[:, 2], 3).max()  # the wrong loop stands out
    assert pg.residuals(whole, nodes, []).shape == (0, 3)


def test_the_optimum_read_in_one_call_equals_node_by_node() -> None:
    """`optimise` reads the optimum with `extractPose2` when the values are the nodes in
    order: the same doubles as `atPose2` node by node (the path it replaces, still taken for
    nodes out of order)."""
    rng = np.random.default_rng(11)
    nodes, start, sequential, loops = _loop_graph(rng)
    graph, values = pg.factor_graph(nodes, start, sequential + loops)
    got = pg.optimise(graph, values, nodes)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-6)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    one = np.array([[p.x(), p.y(), p.theta()] for p in map(result.atPose2, nodes.tolist())])
    assert got.tobytes() == one.tobytes() and np.abs(got - start).max() > 0.05
    shuffled = rng.permutation(len(nodes))  # out of order: node by node, in the asked order
    assert np.array_equal(pg.optimise(graph, values, nodes[shuffled]), one[shuffled])


def test_lagos_start_needs_no_guess_and_takes_any_turn() -> None:
    """LAGO places the square walked twice (two full turns, scan-index keys) from its edges
    alone, near the truth; the first node held where it is given."""
    rng = np.random.default_rng(3)
    nodes, start, sequential, loops = _loop_graph(rng)
    right = [e for k, e in enumerate(loops) if k != 3]  # the metre-wrong loop left out
    got = pg.lago_start(nodes, sequential + right, start[0])
    n = len(nodes)
    t = np.arange(n) / 40 * 2 * np.pi
    truth = np.c_[10 * np.cos(t), 10 * np.sin(t), t + np.pi / 2]
    assert got.shape == (n, 3) and np.allclose(got[0], start[0], atol=1e-5)
    assert np.hypot(*(got[:, :2] - truth[:, :2]).T).max() < 0.3
    assert np.abs(np.angle(np.exp(1j * (got[:, 2] - truth[:, 2])))).max() < 0.05


def test_an_optimum_with_a_stretch_turned_a_quarter_is_restarted_from_lago() -> None:
    """`restarted`: a warm start's optimum with the second lap turned 90 deg about its first
    node (a local minimum the graph's error shows) gives way to LAGO's; the right optimum is
    kept as it is (the same array: no other run changes)."""
    rng = np.random.default_rng(5)
    nodes, start, sequential, loops = _loop_graph(rng)
    graph, values = pg.factor_graph(nodes, start, sequential + loops, robust=1.0)
    right = pg.optimise(graph, values, nodes)
    kept = restarted(graph, nodes, sequential + loops, start[0], right, SlamConfig())
    assert kept is right
    turned = right.copy()
    pivot = right[40]
    c, s = np.cos(np.pi / 2), np.sin(np.pi / 2)
    rel = turned[40:, :2] - pivot[:2]
    turned[40:, :2] = pivot[:2] + rel @ np.array([[c, s], [-s, c]])
    turned[40:, 2] += np.pi / 2
    assert pg.error(graph, nodes, turned) > 10 * pg.error(graph, nodes, right)
    mended = restarted(graph, nodes, sequential + loops, start[0], turned, SlamConfig())
    assert np.hypot(*(mended[:, :2] - right[:, :2]).T).max() < 0.05
    assert pg.error(graph, nodes, mended) < 1.01 * pg.error(graph, nodes, right)
