"""`toolkit map`: the run directory (trajectory, TUM, cloud, map, metrics, config), written
atomically, and one-line errors; checked on a simulated log whose truth is known."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import toolkit
from tests.conftest import toolkit_process
from toolkit import mapping, raster
from toolkit.sim import simulate


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("data") / "corridor"
    toolkit.save(simulate("corridor", seed=4, scans=300).dataset, out)
    return out


@pytest.mark.slow
def test_map_writes_every_output(dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = toolkit_process("map", dataset, "--out", out, "--no-loops")  # scan-to-keyframe
    assert result.returncode == 0, result.stderr
    assert "ATE" in result.stdout
    names = {p.name for p in out.iterdir()}
    assert {
        "config.json",
        "trajectory.parquet",
        "trajectory.tum",
        "groundtruth.tum",
        "cloud.ply",
        "cloud.pcd",
        "map.png",
        "metrics.json",
    } <= names
    ds = toolkit.load(dataset)
    traj = pd.read_parquet(out / "trajectory.parquet")
    assert list(traj.columns) == ["t", "x", "y", "theta"]
    assert np.allclose(traj.to_numpy(), toolkit.trajectory(ds, method="gaussian").to_numpy())

    # TUM: t x y z qx qy qz qw, yaw-only unit quaternions giving back theta
    tum = np.loadtxt(out / "trajectory.tum")
    assert tum.shape == (300, 8)
    assert np.allclose(tum[:, 0], ds.t, atol=1e-6) and np.allclose(tum[:, 1:3], traj[["x", "y"]])
    assert np.allclose(np.linalg.norm(tum[:, 4:], axis=1), 1)
    yaw = 2 * np.arctan2(tum[:, 6], tum[:, 7])
    assert np.allclose(np.angle(np.exp(1j * (yaw - traj["theta"]))), 0, atol=1e-6)

    # the 3D map: every return once, at the laser's height, coloured from early to late
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(out / "cloud.ply"))
    pts = np.asarray(cloud.points)
    assert len(pts) == int(np.isfinite(ds.ranges).sum())
    assert np.allclose(pts[:, 2], ds.laser.z)
    colours = np.asarray(cloud.colors)
    assert not np.allclose(colours[:100].mean(0), colours[-100:].mean(0), atol=0.1)
    first = mapping.world_points(ds.ranges[:1], traj[["x", "y", "theta"]].to_numpy()[:1], ds.laser)
    assert np.allclose(pts[: len(first[0]), :2], first[0], atol=1e-4)
    # every vertex carries its scan's index and time, in the PLY and the PCD alike
    scan_of_return = np.nonzero(np.isfinite(ds.ranges))[0]
    for name in ("cloud.ply", "cloud.pcd"):
        tcloud = o3d.t.io.read_point_cloud(str(out / name)).point
        assert np.array_equal(tcloud["scan"].numpy().ravel(), scan_of_return), name
        assert np.array_equal(tcloud["t"].numpy().ravel(), ds.t[scan_of_return]), name
        assert np.allclose(tcloud["positions"].numpy(), pts, atol=1e-4), name
    pcd = o3d.io.read_point_cloud(str(out / "cloud.pcd"))
    assert np.allclose(np.asarray(pcd.colors), colours)

    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["groundtruth"] and metrics["pairs"] == 299
    assert metrics["ate"]["rmse"] < metrics["odometry"]["ate"]["rmse"]
    assert metrics["seconds_aligning"] > 0 and metrics["pairs_per_second"] > 0
    assert {"translation", "rotation", "rotation_deg"} <= set(metrics["rpe"])
    assert metrics["failures"]["count"] == 0
    stages = {"read", "prepare", "compile", "match", "compose", "cloud.ply+pcd", "map.png"}
    assert stages <= set(metrics["seconds"]) and metrics["seconds"]["match"] > 0
    assert metrics["seconds"]["match"] == pytest.approx(metrics["seconds_aligning"], abs=1e-4)
    config = json.loads((out / "config.json").read_text())
    assert config["method"] == "gaussian" and config["matcher"]["iterations"] >= 1
    assert (out / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_voxel_and_odometry_method(dataset: Path, tmp_path: Path) -> None:
    ds = toolkit.load(dataset)
    out = mapping.map_run(ds, tmp_path / "odo", method="odometry", voxel=0.2).path
    import open3d as o3d

    pts = np.asarray(o3d.io.read_point_cloud(str(out / "cloud.ply")).points)
    assert 0 < len(pts) < np.isfinite(ds.ranges).sum() / 5
    cells = np.unique(np.floor(pts[:, :2] / 0.2), axis=0)
    assert len(cells) > 0.8 * len(pts)  # about one point per voxel
    traj = pd.read_parquet(out / "trajectory.parquet")
    assert np.allclose(traj[["x", "y", "theta"]], ds.odometry[["x", "y", "theta"]])
    assert json.loads((out / "metrics.json").read_text())["pairs"] == 0


@pytest.mark.slow
def test_errors_are_one_line_and_leave_nothing(dataset: Path, tmp_path: Path) -> None:
    for args, needle in [
        (("map", tmp_path / "missing", "--out", tmp_path / "r1"), "not a dataset directory"),
        (("map", dataset, "--out", tmp_path / "r2", "--method", "magic"), "unknown method"),
        (("map", dataset, "--out", tmp_path / "r3", "--voxel", "-1"), "--voxel"),
    ]:
        result = toolkit_process(*args)
        assert result.returncode == 1, result
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and needle in lines[0] and "Traceback" not in result.stderr
    assert not any(tmp_path.glob("r*"))
    (tmp_path / "taken").mkdir()
    result = toolkit_process("map", dataset, "--out", tmp_path / "taken")
    assert result.returncode == 1 and "--force" in result.stderr


def test_an_interrupted_map_writes_nothing(
    dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(mapping, "write_clouds", broken)
    with pytest.raises(KeyboardInterrupt):
        mapping.map_run(dataset, tmp_path / "run")
    assert list(tmp_path.iterdir()) == []


def test_a_log_without_ground_truth_or_odometry_still_maps(dataset: Path, tmp_path: Path) -> None:
    full = toolkit.load(dataset)
    bare = toolkit.Dataset(t=full.t, ranges=full.ranges, laser=full.laser)
    out = mapping.map_run(bare, tmp_path / "bare").path
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["groundtruth"] is False and "ate" not in metrics
    assert metrics["pairs"] == full.n_scans - 1
    assert not (out / "groundtruth.tum").exists()
    assert len(pd.read_parquet(out / "trajectory.parquet")) == full.n_scans


def test_map_png_is_the_returns_rasterised_with_the_trajectory(
    dataset: Path, tmp_path: Path
) -> None:
    from PIL import Image

    ds = toolkit.load(dataset)
    robot = toolkit.trajectory(ds, method="odometry")[["x", "y", "theta"]].to_numpy()
    path = tmp_path / "map.png"
    mapping.write_map_png(path, ds, robot, title="corridor")
    with Image.open(path) as png:
        image = np.asarray(png.convert("RGB"))
        info = dict(png.info)
    cell = float(info["resolution"])
    x0, y0 = (float(v) for v in info["origin"].split())
    height = image.shape[0]

    def pixel(x: float, y: float) -> np.ndarray:
        return image[height - 1 - int((y - y0) / cell), int((x - x0) / cell)]

    assert info["Title"] == "corridor"
    mid = robot[len(robot) // 2]
    assert tuple(pixel(mid[0], mid[1])) == raster.TRAJECTORY_RGB
    # the returns: dark where walls were seen (the first scan's returns), white elsewhere
    xy, _ = mapping.world_points(ds.ranges[:1], robot[:1], ds.laser)
    seen = np.array([pixel(x, y) for x, y in xy])
    assert (seen.max(axis=1) < 200).mean() > 0.9
    assert (image == 255).all(axis=2).mean() > 0.5
