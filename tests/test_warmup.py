"""`toolkit.warmup` reaches the kernels a real log's first `toolkit map` needs."""

from __future__ import annotations

import numpy as np

from toolkit.sim import simulate
from toolkit.slam import grid
from toolkit.slam.scanmap import scan_to_map
from toolkit.warmup import slipped


def test_a_heading_slip_reaches_the_front_ends_search_kernels() -> None:
    """The real laserazos log loses the front end's fit twice and its first map after the
    warm-up compiled grid._likelihood_t and a non-contiguous float32 grid._lookup (0.7 s); a
    clean simulated building reaches neither, its slipped copy (as the warm-up maps it) both."""
    ds = simulate("building", seed=0, scans=600).dataset
    moved = slipped(ds)
    odo, turned = ds.odometry, moved.odometry
    assert odo is not None and turned is not None
    k = len(odo) // 2
    np.testing.assert_allclose(turned["theta"].to_numpy()[k:] - odo["theta"].to_numpy()[k:], 0.5)
    np.testing.assert_array_equal(turned.to_numpy()[:k], odo.to_numpy()[:k])
    step = np.hypot(*np.diff(odo[["x", "y"]].to_numpy(), axis=0).T)
    turned_step = np.hypot(*np.diff(turned[["x", "y"]].to_numpy(), axis=0).T)
    np.testing.assert_allclose(turned_step, step, atol=1e-9)  # the path's steps kept

    def searched() -> tuple[int, bool]:
        layouts = {sig[0].layout for sig in grid._lookup.signatures}
        return len(grid._likelihood_t.signatures), "A" in layouts

    scan_to_map(ds)
    assert searched() == (0, False)
    scan_to_map(moved)
    assert searched() == (1, True)
