"""The compiled kernels that score a log equal their plain numpy references, on a simulated
log with a model learnt the default way (speed: bench/bench_features.py; docs/places.md)."""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
import pytest

from toolkit.features import Config, FeatureModel, fit
from toolkit.features import descriptors as d
from toolkit.features.descriptors import (
    chosen_columns,
    context_windows,
    describe,
    features,
    path_length,
    with_context,
)
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import simulate

SUMS, CELL, SECTORS = d._SUMS, d.CELL, d.SECTORS


@pytest.fixture(scope="module")
def learnt() -> tuple[FeatureModel, np.ndarray]:
    """The default model learnt on a random world's regions, and its log's classifier input."""
    world = simulate("random", seed=3)
    ds = world.dataset
    spans = spans_from_frame(world.regions, ds.t)
    model = fit(ds.ranges, ds.laser, training_indices(spans), Config(), spans)
    assert model.places is not None and model.places.forest is not None
    cfg = model.config
    assert ds.groundtruth is not None
    poses = ds.groundtruth[["x", "y", "theta"]].to_numpy()
    along = path_length(ds.n_scans, poses)
    x = features(ds.ranges, ds.laser, chosen_columns(), along, cfg.context, None, cfg.beside)
    return model, x


def leaves_reference(forest, x, columns, mean, scale) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Every tree walked in numpy on standardised descriptors: (S, T) each scan's leaf."""
    z = (x[:, columns] - mean) / scale
    out = np.empty((len(x), len(forest.roots)), dtype=np.int64)
    rows = np.arange(len(x))
    for t, root in enumerate(forest.roots):
        node = np.full(len(x), root)
        while (inner := forest.left[node] >= 0).any():
            at = node[inner]
            go_left = z[rows[inner], forest.feature[at]] <= forest.threshold[at]
            node[inner] = np.where(go_left, forest.left[at], forest.right[at])
        out[:, t] = node
    return out


def forest_reference(forest, x, columns, mean, scale) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The leaves' class shares (`leaves_reference`) summed over the trees in their order,
    each divided by the tree count."""
    out = np.zeros((len(x), forest.value.shape[1]))
    for node in leaves_reference(forest, x, columns, mean, scale).T:
        out += forest.value[node] / len(forest.roots)
    return out


def test_forest_kernel_equals_the_numpy_walk(learnt) -> None:  # type: ignore[no-untyped-def]
    model, x = learnt
    p = model.places
    fast = p.forest.predict_proba(x, p.columns, p.mean, p.scale)
    ref = forest_reference(p.forest, x, p.columns, p.mean, p.scale)
    # the kernel tests raw descriptors against thresholds mapped back from the standardised
    # ones: a scan on a threshold could go the other way; none of the log's does
    assert np.array_equal(fast, ref)
    assert np.allclose(fast.sum(axis=1), 1.0) and len(np.unique(fast.argmax(axis=1))) > 2
    # a tile's last scans (a log not a multiple of the tile) and a single scan
    for n in (1, 33, 77):
        assert np.array_equal(p.forest.predict_proba(x[:n], p.columns, p.mean, p.scale), fast[:n])


def test_the_walks_leaves_give_the_resemblance_checks_proximity(learnt) -> None:  # type: ignore[no-untyped-def]
    """The leaves `predict_proba` writes on its walk are every tree's leaf (the numpy walk's)
    and leave its probabilities as they are; the proximity counted from them for some rows
    (`which`) is the share of trees putting a scan in one leaf with a support scan, the mean
    over its closest `SUPPORT_NEIGHBOURS` per checked place (numpy), 0 for the others."""
    from toolkit.features.places import SUPPORT_NEIGHBOURS

    model, x = learnt
    p = model.places
    trees = len(p.forest.roots)
    leaves = np.full((len(x), trees), -1, dtype=np.int32)
    proba = p.forest.predict_proba(x, p.columns, p.mean, p.scale, leaves)
    assert np.array_equal(proba, p.forest.predict_proba(x, p.columns, p.mean, p.scale))
    ref = leaves_reference(p.forest, x, p.columns, p.mean, p.scale)
    assert np.array_equal(leaves, ref)
    assert np.array_equal(p.forest.leaves(x, p.columns, p.mean, p.scale), ref)
    check = np.array([p.classes.index(k) for k in ("door", "window") if k in p.classes])
    assert len(check) and p.support_leaves is not None and p.support_place is not None
    which = np.arange(1, len(x), 7)
    got = p.proximity_of_leaves(leaves, check, which)
    shared = (ref[which][:, None, :] == p.support_leaves[None, :, :]).mean(axis=2)
    for j in range(len(p.classes)):
        mine = shared[:, p.support_place == j]
        want = np.sort(mine, axis=1)[:, -SUPPORT_NEIGHBOURS:].mean(axis=1)
        assert np.allclose(got[:, j], want if j in check else 0.0)
    assert got[:, check].max() > 0.5  # some scans share most leaves with a checked place
    assert np.array_equal(p.proximity(x[which], check), got)  # the walk of its own


def log_distance_reference(places, x) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The gate in numpy (S x D temporaries): the compiled pass's reference."""
    g = places.centres.shape[1]
    z = (x[:, places.columns[:g]] - places.mean[:g]) / places.scale[:g]
    zp = z @ places.precision
    quad = np.einsum("sd,sd->s", zp, z)[:, None] - 2 * zp @ places.centres.T
    quad += np.einsum("kd,kd->k", places.centres @ places.precision, places.centres)[None, :]
    return np.asarray(0.5 * np.log(np.maximum(quad.min(axis=1), 1e-12)))


def test_log_distance_kernel_equals_numpy(learnt) -> None:  # type: ignore[no-untyped-def]
    model, x = learnt
    fast, ref = model.places.log_distance(x), log_distance_reference(model.places, x)
    assert fast.shape == ref.shape == (len(x),) and fast.std() > 0.1
    assert np.allclose(fast, ref, rtol=0, atol=1e-9)


@numba.njit(cache=True)
def accumulate_reference(
    ranges: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    sector: np.ndarray,
    log_of: np.ndarray,
    bin_of: np.ndarray,
    gaps: np.ndarray,
    cap: float,
    near: float,
    sums: np.ndarray,
    per_sector: np.ndarray,
    beside: np.ndarray,
) -> None:
    """The descriptors' sums as first written: a scan's sums in arrays of their own."""
    s_count, nb = ranges.shape
    n_gaps, n_bins = len(gaps), int(bin_of.max()) + 1
    inv_cell = 1.0 / CELL
    last = len(log_of) - 1
    for s in range(s_count):
        acc = np.zeros(SUMS)
        sec = np.zeros((4, SECTORS))  # count, sum log, sum log^2, no-returns
        side = np.zeros((2, 3))  # per side (right, left): nearest, farthest |y|, count
        side[:, 0] = cap
        px, py, prev = 0.0, 0.0, 0.0
        for b in range(nb):
            r = ranges[s, b]
            ok = np.isfinite(r) and r < cap
            rc = r if ok else cap
            cell = min(int(rc * inv_cell), last)
            lr = log_of[cell]
            acc[0] += ok
            acc[1] += rc
            acc[2] += rc * rc
            acc[3] += lr
            acc[4] += lr * lr
            x, y = rc * cos[b], rc * sin[b]
            acc[9] += x
            acc[10] += y
            acc[11] += x * x
            acc[12] += y * y
            acc[13] += x * y
            if b > 0:
                d = abs(rc - prev)
                acc[5] += d
                acc[6] += d * d
                acc[7] += 0.5 * (px * y - x * py)  # area: fan of triangles from the origin
                acc[8] += np.sqrt((x - px) ** 2 + (y - py) ** 2)  # perimeter
                for g in range(n_gaps):
                    if d > gaps[g]:
                        acc[14 + g] += 1.0
            else:
                acc[8] += rc  # from the origin to the first end point
            if ok:
                acc[14 + n_gaps + bin_of[cell]] += 1.0
            else:
                acc[14 + n_gaps + n_bins] += 1.0
            if abs(x) < near:  # beside the laser: how far the space reaches sideways
                k = 1 if y > 0 else 0
                ay = abs(y)
                side[k, 0] = min(side[k, 0], ay)
                side[k, 1] = max(side[k, 1], ay)
                side[k, 2] += 1.0
            j = sector[b]
            sec[0, j] += 1.0
            sec[1, j] += lr
            sec[2, j] += lr * lr
            sec[3, j] += not ok
            px, py, prev = x, y, rc
        acc[8] += prev  # back to the origin
        for i in range(SUMS):
            sums[s, i] = acc[i]
        for i in range(4):
            for j in range(SECTORS):
                per_sector[s, i, j] = sec[i, j]
        for i in range(2):
            for j in range(3):
                beside[s, i, j] = side[i, j]


def test_describe_kernel_equals_the_first_written(learnt) -> None:  # type: ignore[no-untyped-def]
    """The sums in registers, the gaps counted once: the very same descriptors."""
    model, _ = learnt
    world = simulate("random", seed=4)
    ranges = world.dataset.ranges
    assert np.isnan(ranges).any() and np.nanmax(ranges) > d.CAP  # no-returns and far ones
    seen: dict[str, Any] = {}
    accumulate: Any = d._accumulate

    def keep(*args):  # type: ignore[no-untyped-def]
        accumulate(*args)
        seen["args"] = args

    d._accumulate = keep  # type: ignore[assignment]
    try:
        fast = describe(ranges, model.laser)
    finally:
        d._accumulate = accumulate
    args: Any = seen["args"]
    reference: Any = accumulate_reference
    finish: Any = d._finish_compiled
    outs = [np.full_like(a, np.nan) for a in args[-3:]]
    reference(*args[:-3], *outs)
    for ours, ref in zip(args[-3:], outs, strict=True):
        assert np.array_equal(ours, ref)
    assert args[-3][:, 14:17].sum() > 0  # gaps over 0.5, 1.5 and 3 m counted
    out = np.empty_like(fast)
    finish(*outs, ranges.shape[1], out)
    assert np.array_equal(fast, out)


def test_context_running_sums_equal_numpy_cumsum(learnt) -> None:  # type: ignore[no-untyped-def]
    _, x = learnt
    own = x[:, : x.shape[1] // 3]
    along = np.cumsum(np.full(len(own), 0.05))
    lo, hi = context_windows(along, 1.0)
    centre = own.mean(axis=0)
    c1 = np.zeros((len(own) + 1, own.shape[1]))
    c2 = np.zeros_like(c1)
    np.cumsum(own - centre, axis=0, out=c1[1:])
    np.cumsum((own - centre) ** 2, axis=0, out=c2[1:])
    ref = np.empty((len(own), 3 * own.shape[1]))
    d._window_moments(own, c1, c2, lo, hi, np.arange(len(own)), centre, ref)
    assert np.array_equal(with_context(own, lo, hi), ref)
