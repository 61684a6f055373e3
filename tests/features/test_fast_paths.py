"""The compiled kernels that score a log equal their plain numpy references, on a simulated
log with a model learnt the default way (speed: bench/bench_features.py; docs/places.md)."""

from __future__ import annotations

import numpy as np
import pytest

from toolkit.features import Config, FeatureModel, fit
from toolkit.features.descriptors import chosen_columns, features, path_length
from toolkit.features.regions import spans_from_frame, training_indices
from toolkit.sim import simulate


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


def forest_reference(forest, x, columns, mean, scale) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Every tree walked in numpy on standardised descriptors; the leaves' class shares
    summed over the trees in their order, each divided by the tree count."""
    z = (x[:, columns] - mean) / scale
    out = np.zeros((len(x), forest.value.shape[1]))
    rows = np.arange(len(x))
    for root in forest.roots:
        node = np.full(len(x), root)
        while (inner := forest.left[node] >= 0).any():
            at = node[inner]
            go_left = z[rows[inner], forest.feature[at]] <= forest.threshold[at]
            node[inner] = np.where(go_left, forest.left[at], forest.right[at])
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


def test_log_distance_kernel_equals_numpy(learnt) -> None:  # type: ignore[no-untyped-def]
    model, x = learnt
    fast, ref = model.places.log_distance(x), model.places.log_distance_reference(x)
    assert fast.shape == ref.shape == (len(x),) and fast.std() > 0.1
    assert np.allclose(fast, ref, rtol=0, atol=1e-9)
