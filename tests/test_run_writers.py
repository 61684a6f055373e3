"""A map run's outputs: map.png's return counts (a numba kernel) equal numpy's histogram of
`world_points`, and the writers that run side by side in threads report every failure and
leave no run behind."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import toolkit
from toolkit import mapping, raster, writers
from toolkit.errors import ToolkitError
from toolkit.poses import truth_poses
from toolkit.sim import simulate
from toolkit.slam import render


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> toolkit.Dataset:
    path = tmp_path_factory.mktemp("raster") / "corridor"
    toolkit.save(simulate("corridor", seed=3, scans=150).dataset, path)
    return toolkit.load(path)


def _numpy_counts(
    ds: toolkit.Dataset, robot: np.ndarray, lo: np.ndarray, cell: float, size: tuple[int, int]
) -> np.ndarray:
    """The returns per pixel by numpy: world_points, floor, bincount (the former map_image)."""
    width, height = size
    xy, _ = raster.world_points(ds.ranges, robot, ds.laser)
    i, j = np.floor((xy - lo) / cell).astype(np.int64).T
    inside = (i >= 0) & (i < width) & (j >= 0) & (j < height)
    return np.bincount(j[inside] * width + i[inside], minlength=width * height)


@pytest.mark.parametrize("cells", [1500, 90])  # fine, and coarse with returns off the grid
def test_map_counts_equal_numpys_histogram_of_world_points(
    dataset: toolkit.Dataset, cells: int
) -> None:
    ds = dataset
    robot = truth_poses(ds)
    assert robot is not None
    lo, cell, size = raster.grid_for(ds, robot, cells)
    if cells == 90:  # a grid inside the returns: some fall off it on every side
        lo, size = lo + 4 * cell, (size[0] - 8, size[1] - 8)
    expected = _numpy_counts(ds, robot, lo, cell, size)
    counts = np.zeros(size[0] * size[1], np.int64)
    for part in raster.scan_chunks(ds.n_scans, 40):
        frame = raster.beam_frame(robot[part], ds.laser)
        raster._count_returns(ds.ranges[part], frame, lo, cell, size[0], counts)
    returns = np.isfinite(ds.ranges).sum()
    assert np.array_equal(counts, expected)
    if cells == 90:
        assert 0.1 * returns < counts.sum() < returns  # some returns were off the grid
    else:
        assert counts.sum() > 0.95 * returns


def test_every_writer_reports_its_time_and_the_outputs_wall(
    dataset: toolkit.Dataset, tmp_path: Path
) -> None:
    run = mapping.map_run(dataset, tmp_path / "run", loops=False)
    seconds = run.metrics["seconds"]
    written = {"cloud.ply+pcd", "map.png", "map.pgm+yaml", "trajectory.parquet", "trajectory.tum"}
    assert written <= set(seconds) and seconds["outputs"] > 0
    for name in ("cloud.ply", "cloud.pcd", "map.png", "map.pgm", "map.yaml", "metrics.json"):
        assert (run.path / name).stat().st_size > 0, name
    traj = pd.read_parquet(run.path / "trajectory.parquet")
    assert len(traj) == dataset.n_scans


def test_a_failing_writer_fails_the_run_and_leaves_nothing(
    dataset: toolkit.Dataset, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise ToolkitError("disk full (simulated)")

    monkeypatch.setattr(mapping, "write_occupancy", broken)
    with pytest.raises(ToolkitError, match="disk full"):
        mapping.map_run(dataset, tmp_path / "run", loops=False)
    assert not (tmp_path / "run").exists()
    assert [p.name for p in tmp_path.iterdir()] == []  # no temporary left either


def _numpy_cloud(
    ds: toolkit.Dataset, robot: np.ndarray, part: slice, span: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """PLY and PCD rows by numpy (the former cloud_rows and pcd_rows)."""
    xy, scan = raster.world_points(ds.ranges[part], robot[part], ds.laser)
    rows = np.empty(len(xy), writers.CLOUD)
    rows["x"], rows["y"], rows["z"] = xy[:, 0], xy[:, 1], ds.laser.z
    t = ds.t[part][scan]
    rgb = writers.viridis((t - span[0]) / (span[1] - span[0] if span[1] > span[0] else 1.0))
    rows["red"], rows["green"], rows["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    rows["t"], rows["scan"] = t, scan + (part.start or 0)
    return rows, writers.pcd_rows(rows)


@pytest.mark.parametrize("part", [slice(0, 150), slice(40, 97)])
def test_cloud_vertices_are_the_bytes_numpy_gives(dataset: toolkit.Dataset, part: slice) -> None:
    ds = dataset
    robot = truth_poses(ds)
    assert robot is not None
    span = (float(ds.t[10]), float(ds.t[120]))  # times before and after: clipped colours
    ply, pcd = mapping.cloud_chunk(ds, robot, part, span)
    want_ply, want_pcd = _numpy_cloud(ds, robot, part, span)
    assert len(ply) == np.isfinite(ds.ranges[part]).sum() > 0
    assert ply.tobytes() == want_ply.tobytes()
    assert pcd.tobytes() == want_pcd.tobytes()
    assert mapping.cloud_rows(ds, robot, part, span).tobytes() == want_ply.tobytes()


def _trace_reference(
    lp: np.ndarray, ranges: np.ndarray, angles: np.ndarray, lo: np.ndarray, res: float,
    reach: float, free_range: float, hits: np.ndarray, seen: np.ndarray,
) -> None:  # fmt: skip
    """The occupancy grid's beam tracing in plain Python (Bresenham, every cell checked)."""
    h, w = hits.shape
    for k in range(len(lp)):
        x0, y0 = (lp[k, 0] - lo[0]) / res, (lp[k, 1] - lo[1]) / res
        for b in range(len(angles)):
            r = float(ranges[k, b])
            hit = r == r and r <= reach
            length = r if hit else free_range
            if not length > 0:
                continue
            th = lp[k, 2] + angles[b]
            i0, j0 = math.floor(x0), math.floor(y0)
            i1 = math.floor(x0 + length * math.cos(th) / res)
            j1 = math.floor(y0 + length * math.sin(th) / res)
            di, dj = abs(i1 - i0), abs(j1 - j0)
            si, sj = (1 if i1 > i0 else -1), (1 if j1 > j0 else -1)
            err, i, j = di - dj, i0, j0
            while (i, j) != (i1, j1):
                if 0 <= i < w and 0 <= j < h:
                    seen[j, i] += 1
                e2 = 2 * err
                if e2 > -dj:
                    err, i = err - dj, i + si
                if e2 < di:
                    err, j = err + di, j + sj
            if hit and 0 <= i1 < w and 0 <= j1 < h:
                hits[j1, i1] += 1
                seen[j1, i1] += 1


@pytest.mark.parametrize("crop", [0, 25])  # the whole grid; a grid that cuts beams off
def test_occupancy_tracing_equals_plain_bresenham(dataset: toolkit.Dataset, crop: int) -> None:
    ds = dataset
    robot = truth_poses(ds)
    assert robot is not None
    part = slice(0, 150, 10)
    lp = toolkit.se2.laser_poses(robot[part], ds.laser)
    res = 0.1
    lo, hi = render._bounds(ds, robot, 30.0)
    lo = np.floor(lo / res) * res + crop * res
    w, h = (np.ceil((hi - lo) / res).astype(np.int64) + 1 - crop).tolist()
    grids = [np.zeros((h, w), np.int32) for _ in range(4)]
    angles = ds.laser.angles.astype(np.float64)
    args = (lp, ds.ranges[part], angles, lo, res, 30.0, 2.0)
    render._trace(*args, grids[0], grids[1])
    _trace_reference(*args, grids[2], grids[3])
    assert grids[1].sum() > 1000
    xy, _ = raster.world_points(ds.ranges[part], robot[part], ds.laser)
    off = (np.floor((xy - lo) / res) < 0) | (np.floor((xy - lo) / res) >= [w, h])
    assert off.any() == (crop > 0)  # beams that leave the grid, or none
    assert np.array_equal(grids[0], grids[2]) and np.array_equal(grids[1], grids[3])


def test_occupancy_in_two_threads_counts_as_one(
    dataset: toolkit.Dataset, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two threads, each into its own grid, then added: the same counts as one pass."""
    robot = truth_poses(dataset)
    assert robot is not None
    monkeypatch.setattr(render, "SPLIT_BYTES", 0)  # one pass
    hits, seen, lo = render.occupancy(dataset, robot, 0.05)
    monkeypatch.setattr(render, "SPLIT_BYTES", 2**40)
    monkeypatch.setattr(render, "CHUNK", 37)  # several chunks per thread, odd and even
    split = render.occupancy(dataset, robot, 0.05)
    assert seen.sum() > 10_000 and hits.sum() > 1_000
    assert np.array_equal(split[0], hits) and np.array_equal(split[1], seen)
    assert np.array_equal(split[2], lo)


@pytest.mark.parametrize("reach", [np.inf, 2.5])
def test_returns_box_is_world_points_extent(dataset: toolkit.Dataset, reach: float) -> None:
    ds = dataset
    robot = truth_poses(ds)
    assert robot is not None
    near = np.where(ds.ranges <= reach, ds.ranges, np.nan)
    xy, _ = raster.world_points(near, robot, ds.laser)
    assert 0 < len(xy) < (np.isfinite(ds.ranges).sum() if reach < np.inf else len(xy) + 1)
    box = raster.returns_box(ds.ranges, robot, ds.laser, reach)
    assert box is not None
    assert np.array_equal(box[0], xy.min(axis=0)) and np.array_equal(box[1], xy.max(axis=0))
    assert raster.returns_box(ds.ranges, robot, ds.laser, 0.01) is None  # no return that near


def test_tum_is_numpy_savetxt_byte_for_byte(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`write_tum` formats blocks of rows at once: the same bytes as np.savetxt's row loop,
    across block boundaries, also for NaN, infinities, -0.0 and large times."""
    monkeypatch.setattr(mapping, "TUM_BLOCK", 64)  # 500 rows: 8 blocks, the last one short
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0, 2e9, 500))
    poses = rng.normal(0, 1e3, (500, 3))
    poses[:4] = [[np.nan, 1.0, 0.5], [np.inf, -np.inf, 1.0], [-0.0, 0.0, -0.0], [1, 2, np.nan]]
    mapping.write_tum(tmp_path / "a.tum", t, poses)
    half, zero = poses[:, 2] / 2, np.zeros(len(t))
    table = np.column_stack([t, poses[:, :2], zero, zero, zero, np.sin(half), np.cos(half)])
    np.savetxt(tmp_path / "b.tum", table, fmt=["%.6f"] + ["%.9f"] * 7, delimiter=" ")
    assert (tmp_path / "a.tum").read_bytes() == (tmp_path / "b.tum").read_bytes()


def test_occupancy_tracing_equals_plain_bresenham_in_every_direction() -> None:
    """The tracing's fast path (both ends on the grid: the major axis counted, the minor
    step's test alone) against plain Bresenham on beams in every direction: steep and
    shallow, both signs, diagonal, along the axes, within one cell, off the grid."""
    rng = np.random.default_rng(15)
    res, reach = 0.1, 6.0
    angles = np.concatenate([np.linspace(-np.pi, np.pi, 73), [0.0, np.pi / 4, -np.pi / 2]])
    for trial in range(30):
        lp = np.column_stack(
            [rng.uniform(0.5, 6.5, 8), rng.uniform(0.5, 5.5, 8), rng.uniform(-np.pi, np.pi, 8)]
        )
        lp[0, 2] = 0.0  # beams along the axes and the diagonals exactly
        ranges = rng.uniform(0.0, 7.0, (8, len(angles))).astype(np.float32)
        ranges[:, :3] = [0.0, 0.04, np.inf]  # no length, one cell, no return
        args = (lp, ranges, angles, np.zeros(2), res, reach, 2.5 if trial % 2 else 0.0)
        grids = [np.zeros((61, 71), np.int32) for _ in range(4)]
        render._trace(*args, grids[0], grids[1])
        _trace_reference(*args, grids[2], grids[3])
        assert np.array_equal(grids[0], grids[2]) and np.array_equal(grids[1], grids[3])
    assert grids[1].sum() > 1000


def test_clouds_in_chunks_are_the_same_bytes(dataset: toolkit.Dataset, tmp_path: Path) -> None:
    """write_clouds fills one pair of buffers chunk after chunk: the files are the header
    and every chunk's vertices, whatever the chunk size."""
    robot = truth_poses(dataset)
    assert robot is not None
    files = {}
    for chunk in (37, 10**6):
        paths = [tmp_path / f"{chunk}.ply", tmp_path / f"{chunk}.pcd"]
        n = mapping.write_clouds(paths, dataset, robot, chunk=chunk)
        files[chunk] = [p.read_bytes() for p in paths]
    span = (float(dataset.t[0]), float(dataset.t[-1]))
    ply, pcd = mapping.cloud_chunk(dataset, robot, slice(0, dataset.n_scans), span)
    assert n == len(ply) > 1000
    assert files[37] == files[10**6]
    assert files[37] == [
        writers.ply_header(n) + ply.tobytes(),
        writers.pcd_header(n) + pcd.tobytes(),
    ]
