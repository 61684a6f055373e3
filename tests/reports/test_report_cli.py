"""`toolkit report`: bad input is one line and exit 1, before any work; nothing half written."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import Cli


def test_bad_dataset_path_is_one_line_and_exit_1(tmp_path: Path, cli: Cli) -> None:
    out = tmp_path / "report"
    code, _, err_text = cli("report", str(tmp_path / "nope"), "--out", str(out), "--quick")
    err = err_text.strip().splitlines()
    assert code == 1
    assert err == [f"error: {tmp_path / 'nope'}: not a dataset directory"]
    assert not out.exists()
    assert not list(tmp_path.glob(".report*"))


def test_folder_that_is_not_a_dataset(tmp_path: Path, cli: Cli) -> None:
    (tmp_path / "empty").mkdir()
    code, _, err_text = cli("report", str(tmp_path / "empty"), "--out", str(tmp_path / "r"))
    err = err_text.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "meta.json, scans.parquet missing" in err[0]


def test_existing_report_needs_force(tmp_path: Path, cli: Cli) -> None:
    out = tmp_path / "report"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, _, err_text = cli("report", "--out", str(out))
    assert code == 1
    assert "exists; pass --force" in err_text
    assert (out / "keep.txt").read_text() == "mine"


def test_missing_regions_file(tmp_path: Path, cli: Cli) -> None:
    code, _, err_text = cli(
        "report", "--regions", str(tmp_path / "r.csv"), "--out", str(tmp_path / "o")
    )
    assert code == 1
    assert "no such regions file" in err_text


def test_a_failing_section_is_shown_and_exits_1(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, cli: Cli
) -> None:
    import reports
    from reports import machine

    def broken(ctx: object, section: object) -> None:
        raise ValueError("boom")

    monkeypatch.setattr(machine, "generate", broken)
    monkeypatch.setattr(reports, "GENERATORS", (machine,))
    out = tmp_path / "report"
    code, _, err_text = cli("report", "--out", str(out), "--no-real")
    err = err_text.strip().splitlines()
    assert code == 1
    assert err[-1] == f"error: {out}: sections failed: machine (the report says why)"
    html = (out / "index.html").read_text()
    assert "Failed: ValueError: boom" in html


def test_an_interrupted_report_leaves_nothing(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, cli: Cli
) -> None:
    import reports
    from reports import machine

    def interrupted(ctx: object, section: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(machine, "generate", interrupted)
    monkeypatch.setattr(reports, "GENERATORS", (machine,))
    code, _, _ = cli("report", "--out", str(tmp_path / "report"), "--no-real")
    assert code == 130
    assert list(tmp_path.iterdir()) == []


def test_each_section_is_reported_as_it_finishes(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, cli: Cli
) -> None:
    """Not on a terminal (a pipe, CI, `make demo | tee`): one line per section the moment it
    is done, not all of them after the whole report."""
    import types

    import reports
    from reports import machine

    def slow(ctx: object, section: object) -> None:
        print("second section starts")

    second = types.SimpleNamespace(KEY="second", TITLE="Second", INTRO="", generate=slow)
    monkeypatch.setattr(reports, "GENERATORS", (machine, second))
    code, out, _ = cli("report", "--out", str(tmp_path / "report"), "--no-real")
    assert code == 0
    lines = out.splitlines()
    first = next(i for i, line in enumerate(lines) if machine.TITLE in line)
    assert lines[first].startswith("ok ")
    assert first < lines.index("second section starts")  # printed before the next one began
    assert sum(machine.TITLE in line for line in lines) == 1  # and not again at the end
    assert lines[-1].startswith(f"report in {tmp_path / 'report'}/index.html")
