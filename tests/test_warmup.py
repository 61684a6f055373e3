"""`toolkit.warmup` reaches the kernels a real log's first `toolkit map` needs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from toolkit.sim import simulate
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

    # which kernels a front end run reaches, each in a fresh process (a test run before this
    # one in the same process may have reached them already)
    code = (
        "import sys\n"
        "from toolkit.sim import simulate\n"
        "from toolkit.slam import grid\n"
        "from toolkit.slam.scanmap import scan_to_map\n"
        "from toolkit.warmup import slipped\n"
        "ds = simulate('building', seed=0, scans=600).dataset\n"
        "scan_to_map(slipped(ds) if sys.argv[1] == 'slip' else ds)\n"
        "layouts = {sig[0].layout for sig in grid._lookup.signatures}\n"
        "print(len(grid._likelihood_t.signatures), 'A' in layouts)\n"
    )

    def searched(case: str) -> str:
        out = subprocess.run([sys.executable, "-c", code, case], capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    assert searched("clean") == "0 False"
    assert searched("slip") == "1 True"
