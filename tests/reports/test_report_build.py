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


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Report:
    out = tmp_path_factory.mktemp("rep") / "report"
    return reports.build(out, quick=True, real=False, command="test")


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
    table = report.section("table2").data["table2"]
    assert sorted(set(table["points"])) == [100, 500, 1000, 5000, 10_000]
    assert {"gaussian", "icp"} <= set(table["method"])
    assert len(table) == 5 * table["method"].nunique()
    assert np.isfinite(table["error (mm)"]).all() and (table["error (mm)"] >= 0).all()
    assert (table["time (ms)"] > 0).all()
    # the error is small against the shift (up to 50 mm per axis) for both methods
    assert table.loc[table["method"] == "gaussian", "error (mm)"].max() < 10
    fig4 = report.section("table2").figure("fig4_time_both").data
    assert set(fig4) >= {"gaussian", "icp"}
    assert fig4["icp"]["points"] == [100, 500, 1000, 5000, 10_000]
    fig5 = report.section("table2").figure("fig5_time_gaussian").data
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


def test_machine_section(report: Report) -> None:
    info = report.section("machine").data["machine"]
    assert info["cpus (logical)"] >= 1
    assert info["numpy"] == np.__version__
    assert info["python"].count(".") == 2
