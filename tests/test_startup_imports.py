"""Each command loads only the libraries it uses, checked in a new process as a user runs it:
`map` reads and writes its tables without pandas (Arrow straight into numpy and back),
`map` without loops (or by odometry) needs neither GTSAM nor scipy.ndimage nor the simulator,
`map` with loops needs GTSAM, scipy.ndimage only when a grid needs its distance transform,
scipy.spatial and scipy.sparse only when there are keyframes to compare or loops to check,
nothing loads a plotting or 3D library, and rich only for a progress bar on a terminal; typer
coerces these commands' plain values without pydantic (`toolkit.app.cli._PlainValues`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import toolkit
from toolkit.sim import simulate

WATCHED = (
    "pandas", "numba", "scipy.ndimage", "gtsam", "toolkit.sim", "toolkit.slam.pipeline",
    "matplotlib", "open3d", "sklearn", "distributed", "rich", "pydantic", "scipy.spatial",
    "scipy.sparse",
)  # fmt: skip

RUN = (
    "import json, sys\n"
    "from toolkit.app.cli import main\n"
    "watched = json.loads(sys.argv[1])\n"
    "sys.argv = ['toolkit', *sys.argv[2:]]\n"
    "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
    "print(json.dumps(sorted(m for m in watched if m in sys.modules)))\n"
)


def loaded(*args: object) -> set[str]:
    """Which of WATCHED `toolkit ARGS` has imported when it ends, in a new process."""
    env = {**os.environ, "TOOLKIT_NO_PROGRESS": "1"}
    out = subprocess.run(
        [sys.executable, "-c", RUN, json.dumps(WATCHED), *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
    )
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("startup") / "corridor"
    toolkit.save(simulate("corridor", seed=2, scans=60).dataset, path)
    return path


@pytest.mark.parametrize("method", [["--no-loops"], ["--method", "odometry"]])
def test_map_without_loops_loads_neither_gtsam_nor_scipy_ndimage(
    dataset: Path, tmp_path: Path, method: list[str]
) -> None:
    mods = loaded("map", dataset, "--out", tmp_path / "run", "-q", *method)
    assert (tmp_path / "run" / "map.pgm").is_file()  # it ran: every output written
    assert mods == {"numba"}


def test_map_with_loops_loads_the_pose_graph_and_nothing_to_plot(
    dataset: Path, tmp_path: Path
) -> None:
    mods = loaded("map", dataset, "--out", tmp_path / "run", "-q")
    assert (tmp_path / "run" / "graph.g2o").is_file()
    # this log's grids are all stamped (`_disc_field`): no distance transform, no scipy.ndimage;
    # no two keyframes within the drift gate and no loop to check: no k-d tree, no sparse
    # graph (scipy.spatial and scipy.sparse, 0.3-0.5 s to import)
    assert mods == {"numba", "gtsam", "toolkit.slam.pipeline"}


def test_scipy_ndimage_loads_when_a_grid_needs_the_distance_transform() -> None:
    """A grid whose cap is wider than the stamped discs is scipy's transform: imported then,
    and the distances are scipy's own."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from toolkit.slam.grid import LikelihoodGrid\n"
        "assert 'scipy.ndimage' not in sys.modules\n"
        "pts = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 2.0]])\n"
        "grid = LikelihoodGrid.build(pts, 0.05, 0.1, cap=2.0)\n"
        "assert 'scipy.ndimage' in sys.modules\n"
        "print(float(grid.distance.max()), float(grid.distance.min()))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    top, bottom = map(float, out.stdout.split())
    assert bottom == 0.0 and top == pytest.approx(2.0)  # zero on the points, capped far away


def test_info_loads_numpy_and_pyarrow_only(dataset: Path) -> None:
    assert loaded("info", dataset) == set()


def test_the_command_ends_with_its_output_and_exit_code_after_freezing_the_gc(
    dataset: Path, tmp_path: Path
) -> None:
    """`toolkit` freezes the garbage collector when the command is done (a fast shutdown):
    what it printed is all there, and failures still exit 1 with one line."""
    env = {**os.environ, "TOOLKIT_NO_PROGRESS": "1"}
    ok = subprocess.run(
        [sys.executable, "-m", "toolkit", "info", str(dataset), "--json"],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert ok.returncode == 0, ok.stderr
    assert json.loads(ok.stdout)["scans"] == 60
    bad = subprocess.run(
        [sys.executable, "-m", "toolkit", "info", str(tmp_path / "missing")],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert bad.returncode == 1 and bad.stderr.startswith("error: ")
    assert len(bad.stderr.strip().splitlines()) == 1


def test_numbas_tables_are_built_with_the_imports_and_frozen() -> None:
    """`toolkit map` builds numba's typing and lowering tables inside its imports' block
    (`numba_tables`): what numba's first kernel load would otherwise make in the run (about
    48,000 objects, a collection) is frozen, and the load's own refresh makes nothing new."""
    code = (
        "import gc\n"
        "from toolkit.app.startup import imports_kept, numba_tables\n"
        "with imports_kept():\n    numba_tables()\n"
        "from numba.core.registry import cpu_target\n"
        "before = len(gc.get_objects())\n"
        "cpu_target.target_context.refresh()\n"
        "print(len(gc.get_objects()) - before)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) < 1_000
    unbuilt = code.replace("    numba_tables()\n", "    import numba\n")
    out = subprocess.run([sys.executable, "-c", unbuilt], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.strip()) > 20_000  # what the test above would catch
