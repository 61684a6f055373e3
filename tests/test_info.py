"""`toolkit info`'s summary read from the files (summary_of, no pandas) equals the summary of
the loaded dataset, on a simulated log with odometry, ground truth and a second pose stream."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

import toolkit
from toolkit.info import summary, summary_of
from toolkit.sim import simulate


def test_summary_of_the_files_equals_the_summary_of_the_dataset(tmp_path: Path) -> None:
    ds = simulate("corridor", seed=1, scans=120).dataset
    ds = replace(ds, poses={"robotGlobal": ds.groundtruth})
    toolkit.save(ds, tmp_path / "d")
    loaded = toolkit.load(tmp_path / "d")
    expected = summary(loaded)
    assert summary_of(tmp_path / "d") == expected
    assert expected["scans"] == 120 and expected["poses"] == {"robotGlobal": 120}
    steps = np.diff(loaded.groundtruth[["x", "y"]].to_numpy(), axis=0)
    assert expected["groundtruth_path_m"] == round(float(np.hypot(*steps.T).sum()), 3)


def test_info_loads_neither_pandas_nor_numba(tmp_path: Path) -> None:
    toolkit.save(simulate("corridor", seed=1, scans=50).dataset, tmp_path / "d")
    code = (
        "import sys; from toolkit.app.cli import main; sys.argv = ['toolkit', 'info', sys.argv[1]]\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in ('pandas', 'numba', 'matplotlib', 'open3d', 'scipy') "
        "if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / "d")], capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    assert "scans      50 x 181 beams" in out.stdout
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_info_prints_the_range_limit_as_the_sensor_gives_it(real: Path, tmp_path: Path) -> None:
    """The real Mines log (5600 mm x 0.001) and the CCNY bag (float32 5.6) both read 5.6 m;
    before, `toolkit info` printed 5.6000000000000005 and 5.599999904632568."""
    import importers
    from importers.base import ImportOptions

    mines = real / "breezyslam_mines_urg04lx" / "exp1.dat"
    bag = real / "ccny_scan_tools_bags" / "laser_scan_matcher" / "demo.bag"
    options = ImportOptions(extra={"preset": "mines"})
    for name, source, opts in (("mines", mines, options), ("bag", bag, None)):
        importers.import_log("auto", [source], tmp_path / name, opts)
        assert summary_of(tmp_path / name)["range_max"] == 5.6
        out = subprocess.run(
            [sys.executable, "-m", "toolkit", "info", str(tmp_path / name)],
            capture_output=True,
            text=True,
        )
        assert out.returncode == 0, out.stderr
        assert ", range_max 5.6 m, " in out.stdout, out.stdout
