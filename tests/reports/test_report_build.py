"""The whole report in quick mode, built once: every section's content (the data behind each
figure and table, not pixels), and an index.html whose every link and image exists."""

from __future__ import annotations

import json
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

import reports
from reports import Report
from toolkit.sim import Simulation, simulate

pytestmark = pytest.mark.slow  # the report built end to end (~75 s loaded)

GIVEN_SCANS = 300


@pytest.fixture(scope="module")
def given(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset given on the command line: the simulated building, with its regions.csv and
    truth.parquet inside, as `toolkit simulate` writes them."""
    from toolkit.dataset import save
    from toolkit.sim import simulate

    sim = simulate("building", seed=1, scans=GIVEN_SCANS)
    path = save(sim.dataset, tmp_path_factory.mktemp("given") / "building")
    sim.regions.to_csv(path / "regions.csv", index=False, float_format="%.6f")
    sim.truth().to_parquet(path / "truth.parquet")
    return path


@pytest.fixture(scope="module")
def quick_corridor() -> Simulation:
    """The corridor as the quick report simulates it (seed 0, QUICK_CORRIDOR_SCANS), once."""
    from reports.context import QUICK_CORRIDOR_SCANS

    return simulate("corridor", seed=0, scans=QUICK_CORRIDOR_SCANS)


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory, real: Path, given: Path) -> Report:
    out = tmp_path_factory.mktemp("rep") / "report"
    return reports.build(out, [given], quick=True, real=real, command="test")


class Refs(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.refs: list[str] = []
        self.data_images = 0

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for key, value in attrs:
            if key in ("href", "src") and value is not None:
                if value.startswith("data:image/png;base64,"):
                    self.data_images += 1
                elif not value.startswith("#"):
                    self.refs.append(value)


def test_index_links_every_file_and_every_file_it_names_exists(report: Report) -> None:
    root = report.path
    parser = Refs()
    parser.feed((root / "index.html").read_text())
    assert parser.refs, "the index links no file"
    for ref in parser.refs:
        assert "://" not in ref and not ref.startswith("/"), f"not a relative link: {ref}"
        assert (root / ref).is_file(), f"index.html names {ref}, which does not exist"
    files = {f for s in report.sections for a in [*s.figures, *s.tables] for f in a.files}
    assert files <= set(parser.refs), f"not linked: {files - set(parser.refs)}"
    figures = [f for s in report.sections for f in s.figures]
    assert parser.data_images == len(figures)  # every figure embedded: the page works alone
    for fig in figures:
        assert {Path(f).suffix for f in fig.files} == {".png", ".svg"}
    for table in [t for s in report.sections for t in s.tables]:
        assert {Path(f).suffix for f in table.files} == {".csv", ".md", ".tex"}


def test_every_section_is_there_and_says_what_is_not_available(report: Report) -> None:
    summary = json.loads((report.path / "report.json").read_text())
    keys = [s["key"] for s in summary["sections"]]
    assert keys == [m.KEY for m in reports.generators()]
    html = (report.path / "index.html").read_text()
    for s in report.sections:
        assert s.status != "failed", f"{s.key}: {s.error}"
        for what in s.unavailable:
            assert "Not available: " + what.replace("'", "&#x27;") in html
    assert not list(report.path.parent.glob(".report*")), "temporary folder left behind"


def test_table2_sizes_methods_and_finite_figures(report: Report) -> None:
    from toolkit.align.protocol import DENSE, PAPER

    section = report.section("table2")
    for key, protocol in (("table2", PAPER), ("table2_dense", DENSE)):
        table = section.data[key]
        assert sorted(set(table["points"])) == [100, 500, 1000, 5000, 10_000]
        assert {"gaussian", "icp"} <= set(table["method"])
        assert len(table) == 5 * table["method"].nunique()
        assert np.isfinite(table["error (mm)"]).all() and (table["error (mm)"] >= 0).all()
        assert (table["time (ms)"] > 0).all()
        assert (table["trials"] >= 2).all() and (table["error std (mm)"] >= 0).all()
        # the Gaussian alignment finds the shift (up to 1 m or 5 cm per axis) to within a few
        # standard errors of the mean of N noisy points; on the paper's sparse clouds ICP too
        checked = table if protocol is PAPER else table[table["method"] == "gaussian"]
        bound = 1000 * 6 * protocol.noise / np.sqrt(checked["points"])
        assert (checked["error (mm)"] < bound).all(), checked
    names = [t.name for t in section.tables]
    assert names == ["table2_clouds", "table2_clouds_dense"]  # the paper's protocol first
    fig4 = section.figure("fig4_time_both").data
    assert set(fig4) >= {"gaussian", "icp"}
    assert fig4["icp"]["points"] == [100, 500, 1000, 5000, 10_000]
    assert section.figure("fig4_time_both_dense").data["icp"]["points"][-1] == 10_000
    fig5 = section.figure("fig5_time_gaussian").data
    assert "icp" not in fig5


def test_features_probabilities_and_training_positions(report: Report) -> None:
    section = report.section("features")
    data = section.data["corridor"]
    assert len(data["features"]) >= 3
    n = len(data["label"])
    fig8 = section.figure("fig8_probability_corridor").data
    for f in data["features"]:
        p = fig8["probability"][f]
        assert p.shape == (n,) and np.all((p >= 0) & (p <= 1))
        train = fig8["training"][f]
        assert 5 <= len(train) <= 20 and train.max() < n
        # the model recognises its own training scans
        assert p[train].mean() > 0.5
    fig9 = section.figure("fig9_found_corridor").data
    for f in data["features"]:
        assert np.array_equal(fig9["found"][f], data["label"] == f)
    table = data["table"]
    assert list(table["feature"]) == data["features"]
    assert (table["recall"] >= 0).all() and (table["recall"] <= 1).all()
    assert data["balanced_accuracy"] > 1 / (len(data["features"]) + 1)  # better than chance
    import pandas as pd

    saved = pd.read_parquet(report.path / "runs/corridor/labels/labels.parquet")
    assert list(saved["label"]) == list(data["label"])
    assert np.allclose(saved[f"p_{data['features'][0]}"], fig8["probability"][data["features"][0]])


def test_machine_section(report: Report) -> None:
    info = report.section("machine").data["machine"]
    assert info["cpus (logical)"] >= 1
    assert info["numpy"] == np.__version__
    assert info["python"].count(".") == 2


def test_table1_has_eight_sections_and_each_method(report: Report) -> None:
    from reports.context import QUICK_MATCHERS

    section = report.section("table1")
    rows = section.data["corridor"]["rows"]
    assert sorted(set(rows["section"])) == list(range(1, 9))
    assert set(rows["method"]) == {"odometry", *QUICK_MATCHERS}
    assert len(rows) == 8 * (1 + len(QUICK_MATCHERS))
    assert (rows["pairs"] >= 40).all()  # quick mode: 8 sections of 50 scans
    assert np.isfinite(rows[["error_m", "std_m"]].to_numpy()).all()
    assert (rows["error_m"] >= 0).all() and (rows["std_m"] >= 0).all()
    timed = rows[rows["method"] != "odometry"]
    assert (timed["seconds"] > 0).all()
    table = section.data["corridor"]["table1"]
    assert list(table["section"]) == list(range(1, 9))
    gauss = rows[rows["method"] == "gaussian"].reset_index(drop=True)
    assert np.allclose(table["gaussian error (cm)"], 100 * gauss["error_m"])
    chart = section.figure("table1_sections").data
    assert np.allclose(chart["gaussian"]["error_cm"], 100 * gauss["error_m"])
    assert np.allclose(chart["gaussian"]["std_cm"], 100 * gauss["std_m"])


@pytest.mark.real
def test_table1_and_fig3_on_the_intel_log_with_drift(report: Report) -> None:
    rows = report.section("table1").data["intel+drift"]["rows"]
    assert sorted(set(rows["section"])) == list(range(1, 9))
    gauss = rows[rows["method"] == "gaussian"]
    assert gauss["pairs"].sum() == report.section("maps").data["intel+drift"]["scans"] - 8
    assert np.isfinite(rows["error_m"]).all()
    pairs = report.section("pairs").data["intel+drift"]
    assert pairs["close"]["median_range_m"] < pairs["distant"]["median_range_m"]
    assert "fig3_pairs_intel_drift" in {f.name for f in report.section("pairs").figures}


def test_table1_errors_are_the_metric_of_the_runs(
    report: Report, quick_corridor: Simulation
) -> None:
    """Recompute one section's error from scratch with the toolkit and compare."""
    from reports.runs import slice_scans
    from toolkit.metrics import RPE
    from toolkit.poses import build, truth_poses

    sim = quick_corridor
    part = slice_scans(sim.dataset, np.flatnonzero(sim.sections == 3))
    err, _ = RPE.step_errors(build(part, "gaussian").poses, truth_poses(part))
    rows = report.section("table1").data["corridor"]["rows"]
    row = rows[(rows["section"] == 4) & (rows["method"] == "gaussian")].iloc[0]
    assert row["error_m"] == pytest.approx(err.mean())
    assert row["std_m"] == pytest.approx(err.std(ddof=1))


def test_fig3_pairs_close_and_distant(report: Report) -> None:
    data = report.section("pairs").data["corridor"]
    assert set(data) == {"close", "distant"}
    assert data["close"]["median_range_m"] < data["distant"]["median_range_m"]
    for pair in data.values():
        assert set(pair["estimate"]) >= {"odometry", "gaussian", "icp"}
        for method, pose in pair["estimate"].items():
            assert pose.shape == (3,)
            err = 100 * np.hypot(*(pose[:2] - pair["truth"][:2]))
            assert pair["error_cm"][method] == pytest.approx(err)
        # consecutive scans 0.08 m apart: every method is within 10 cm of the truth
        assert max(pair["error_cm"].values()) < 10


def test_fig6_odometry_map_against_corrected(report: Report, quick_corridor: Simulation) -> None:
    from toolkit.metrics import ATE
    from toolkit.poses import truth_poses

    section = report.section("maps")
    data = section.data["corridor"]
    assert data["methods"][0] == "odometry"
    ds = quick_corridor.dataset
    gt = truth_poses(ds)
    for method in data["methods"]:
        poses = data["trajectories"][method]
        assert poses.shape == (ds.n_scans, 3)
        assert data["ate"][method] == pytest.approx(ATE.compute(poses, gt).rmse)
        assert data["points"][method] > 1000
    odo = data["trajectories"]["odometry"]
    assert np.allclose(odo, ds.odometry[["x", "y", "theta"]].to_numpy())
    # the paper's claim, measured: the Gaussian-corrected map beats odometry alone
    assert data["ate"]["gaussian"] < data["ate"]["odometry"]
    assert section.figure("fig6_maps_corridor").files


@pytest.mark.real
def test_fig7_real_logs(report: Report) -> None:
    from reports.context import QUICK_REAL_SCANS

    section = report.section("maps")
    loop5, intel = section.data["dpslam_loop5"], section.data["intel+drift"]
    assert all(v is None for v in loop5["ate"].values())  # no ground truth: no ATE claimed
    assert loop5["scans"] == intel["scans"] == QUICK_REAL_SCANS  # quick mode: the first scans
    for data in (loop5, intel):
        for poses in data["trajectories"].values():
            assert poses.shape == (data["scans"], 3)
    assert intel["ate"]["odometry"] > 1.0  # the drift added is visible
    assert all(np.isfinite(v) for v in intel["ate"].values())
    names = {f.name for f in section.figures}
    assert {"fig7_maps_dpslam_loop5", "fig7_maps_intel_drift"} <= names


def test_accuracy_every_method_and_log(report: Report) -> None:
    from reports.context import QUICK_MATCHERS

    table = report.section("accuracy").data["accuracy"]
    logs = list(dict.fromkeys(table["log"]))
    assert logs == ["corridor", "dpslam_loop5", "intel+drift", "building"]
    for log in logs:
        assert list(table.loc[table["log"] == log, "method"]) == ["odometry", *QUICK_MATCHERS]
    with_truth = table[table["log"] != "dpslam_loop5"]
    assert np.isfinite(with_truth[["ATE (m)", "RPE (cm)", "RPE (deg)"]].to_numpy()).all()
    assert table.loc[table["log"] == "dpslam_loop5", "ATE (m)"].isna().all()
    matched = table[table["method"] != "odometry"]
    assert (matched["aligning (s)"] > 0).all() and (matched["pairs/s"] > 0).all()
    for log, method in zip(table["log"], table["method"], strict=True):
        folder = report.path / "runs" / log.replace("+", "_") / method
        metrics = json.loads((folder / "metrics.json").read_text())
        row = table[(table["log"] == log) & (table["method"] == method)].iloc[0]
        assert metrics.get("ate", {}).get("rmse", np.nan) == pytest.approx(
            row["ATE (m)"], nan_ok=True
        )
        tum = np.loadtxt(folder / "trajectory.tum")
        assert tum.shape == (row["scans"], 8)
        if log != "dpslam_loop5":  # what evo needs side by side: `evo_ape tum groundtruth.tum
            truth = np.loadtxt(folder / "groundtruth.tum")  # trajectory.tum -a` in the folder
            assert truth.shape == tum.shape and np.array_equal(truth[:, 0], tum[:, 0])
    maps = report.section("maps").data["corridor"]["ate"]
    corridor = table[table["log"] == "corridor"].set_index("method")["ATE (m)"]
    assert corridor.to_dict() == pytest.approx(maps)  # one run per log and method, shared


def test_dataset_given_is_mapped_labelled_and_scored(report: Report, given: Path) -> None:
    import pandas as pd

    maps = report.section("maps").data["building"]
    assert maps["scans"] == GIVEN_SCANS
    assert all(np.isfinite(v) for v in maps["ate"].values())
    assert "fig7_maps_building" in {f.name for f in report.section("maps").figures}
    features = report.section("features").data["building"]
    assert set(features["features"]) == set(pd.read_csv(given / "regions.csv")["feature"])
    assert "recall" in features["table"]  # truth.parquet beside the data gives the truth
    for f in features["features"]:
        p = features["probability"][f]
        assert p.shape == (GIVEN_SCANS,) and np.all((p >= 0) & (p <= 1))
    names = {f.name for f in report.section("features").figures}
    assert {"fig8_probability_building", "fig9_found_building", "fig10_map3d_building"} <= names


def test_html_ids_are_unique(report: Report) -> None:
    import re

    ids = re.findall(r'\bid="([^"]+)"', (report.path / "index.html").read_text())
    assert len(ids) == len(set(ids))


@pytest.mark.real
def test_features_on_the_real_intel_log(report: Report) -> None:
    data = report.section("features").data["intel"]
    assert set(data["features"]) == {"corridor", "room"}
    for f in data["features"]:
        p = data["probability"][f]
        assert np.all((p >= 0) & (p <= 1))
        assert p[data["training"][f]].mean() > 0.5


def test_bundled_catalog_is_read_and_imported(tmp_path: Path) -> None:
    from reports.context import CATALOG, Context, catalog_sources

    sources = catalog_sources()
    if not CATALOG.is_file():
        assert sources == {}
        return
    assert sources, "the catalog names no log"
    for source in sources.values():
        assert source.origin == "bundled" and source.native is not None
        assert all(p.exists() for p in source.native[1])
        assert source.regions is None or source.regions.is_file()

    def size(name: str) -> int:
        paths = sources[name].native[1]  # type: ignore[index]
        files = [f for p in paths for f in ([p] if p.is_file() else p.rglob("*"))]
        return sum(f.stat().st_size for f in files)

    smallest = min(sources, key=size)
    short = catalog_sources(max_scans=1000)  # what quick mode takes
    assert set(short) < set(sources)
    ctx = Context(tmp_path / "out", tmp_path / "work", quick=True, sources=sources)
    ds = ctx.dataset(smallest)
    assert ds.n_scans > 100 and sources[smallest].path is not None
    if sources[smallest].truth is not None:  # the simulator's truth is the ground truth
        import pandas as pd

        truth = pd.read_parquet(sources[smallest].truth)
        assert ds.groundtruth is not None and len(ds.groundtruth) == len(truth)


def test_logs_table_names_every_log(report: Report) -> None:
    logs = report.section("accuracy").data["logs"].set_index("log")
    assert set(logs.index) == {"corridor", "dpslam_loop5", "intel+drift", "building", "intel"}
    assert logs.loc["corridor", "scans"] == 400  # quick mode
    assert logs.loc["dpslam_loop5", "ground truth"] == "no"
    assert logs.loc["intel+drift", "ground truth"] == "yes"
    assert logs.loc["building", "origin"] == "command line"
    assert logs.loc["building", "regions"] == "regions.csv"


def test_fig10_map3d_every_return_at_the_laser_height(
    report: Report, quick_corridor: Simulation
) -> None:
    ds = quick_corridor.dataset
    data = report.section("features").figure("fig10_map3d_corridor").data
    assert data["points"] == int(np.isfinite(ds.ranges).sum())  # every return, none invented
    assert np.allclose(data["z"], [ds.laser.z])
    assert sum(data["label_counts"].values()) == data["points"]


def test_log_without_odometry_is_matched_from_standstill(tmp_path: Path) -> None:
    """A raw laser capture has no odometry: no odometry map or row, the matchers still run."""
    from dataclasses import replace

    from reports import accuracy, fig6_maps
    from reports.base import Section
    from reports.context import Context, Source
    from toolkit.dataset import save
    from toolkit.sim import simulate

    ds = replace(simulate("corridor", seed=2, scans=120).dataset, odometry=None)
    path = save(ds, tmp_path / "capture")
    ctx = Context(tmp_path / "out", tmp_path / "work", quick=True)
    ctx.sources["capture"] = Source("capture", path, "command line")
    section = Section("maps", "maps")
    data = fig6_maps._maps(ctx, section, "capture")
    assert data["methods"] == ["gaussian", "icp"]
    assert all(np.isfinite(v) for v in data["ate"].values())
    assert any("no odometry" in n for n in section.notes)
    table = Section("accuracy", "accuracy")
    ctx.map_logs = lambda: ["capture"]  # type: ignore[method-assign]
    accuracy.generate(ctx, table)
    assert list(table.data["accuracy"]["method"]) == ["gaussian", "icp"]
