"""`toolkit report`: bad input is one line and exit 1, before any work; nothing half written."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from toolkit.cli import main


def run_cli(monkeypatch: pytest.MonkeyPatch, *args: str) -> int:
    monkeypatch.setattr(sys, "argv", ["toolkit", *args])
    with pytest.raises(SystemExit) as done:
        main()
    return int(done.value.code or 0)


def test_bad_dataset_path_is_one_line_and_exit_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out = tmp_path / "report"
    code = run_cli(monkeypatch, "report", str(tmp_path / "nope"), "--out", str(out), "--quick")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err == [f"error: {tmp_path / 'nope'}: not a dataset directory"]
    assert not out.exists()
    assert not list(tmp_path.glob(".report*"))


def test_folder_that_is_not_a_dataset(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    (tmp_path / "empty").mkdir()
    code = run_cli(monkeypatch, "report", str(tmp_path / "empty"), "--out", str(tmp_path / "r"))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "meta.json, scans.parquet missing" in err[0]


def test_existing_report_needs_force(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out = tmp_path / "report"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code = run_cli(monkeypatch, "report", "--out", str(out))
    assert code == 1
    assert "exists; pass --force" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "mine"


def test_missing_regions_file(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    code = run_cli(
        monkeypatch, "report", "--regions", str(tmp_path / "r.csv"), "--out", str(tmp_path / "o")
    )
    assert code == 1
    assert "no such regions file" in capsys.readouterr().err


def test_a_failing_section_is_shown_and_exits_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    import reports
    from reports import machine

    def broken(ctx: object, section: object) -> None:
        raise ValueError("boom")

    monkeypatch.setattr(machine, "generate", broken)
    monkeypatch.setattr(reports, "GENERATORS", ("machine",))
    out = tmp_path / "report"
    code = run_cli(monkeypatch, "report", "--out", str(out), "--no-real")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err[-1] == f"error: {out}: sections failed: machine (the report says why)"
    html = (out / "index.html").read_text()
    assert "Failed: ValueError: boom" in html


def test_an_interrupted_report_leaves_nothing(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    import reports
    from reports import machine

    def interrupted(ctx: object, section: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(machine, "generate", interrupted)
    monkeypatch.setattr(reports, "GENERATORS", ("machine",))
    code = run_cli(monkeypatch, "report", "--out", str(tmp_path / "report"), "--no-real")
    assert code == 130
    assert list(tmp_path.iterdir()) == []
