"""Table text (Markdown, LaTeX), figure files and the not-available guard."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from reports.base import cell, save_figure, save_table, to_latex, to_markdown


def frame() -> pd.DataFrame:
    return pd.DataFrame(
        {"method": ["gaussian", "icp_p2p"], "error (m)": [0.012345, np.nan], "n": [10, 3]}
    )


def test_markdown_aligns_numbers_and_formats_cells() -> None:
    text = to_markdown(frame(), {"error (m)": "{:.3f}"}, title="T")
    lines = text.splitlines()
    assert lines[0] == "**T**"
    assert lines[2] == "| method | error (m) | n |"
    assert lines[3] == "| --- | ---: | ---: |"
    assert lines[4] == "| gaussian | 0.012 | 10 |"
    assert lines[5] == "| icp_p2p | – | 3 |"


def test_latex_escapes_and_uses_booktabs() -> None:
    text = to_latex(frame(), caption="50% of x_1")
    assert r"\caption{50\% of x\_1}" in text
    assert r"\begin{tabular}{lrr}" in text
    assert r"icp\_p2p & – & 3 \\" in text
    assert text.index(r"\toprule") < text.index(r"\midrule") < text.index(r"\bottomrule")


def test_cell() -> None:
    assert cell(np.float32(1.23456)) == "1.235"
    assert cell(np.int64(7)) == "7"
    assert cell(float("nan")) == "–"
    assert cell(True) == "True"


def test_save_table_and_figure_write_every_format(tmp_path: Path) -> None:
    from reports.base import new_figure

    table = save_table(frame(), tmp_path, "t1", "T", "caption")
    assert table.files == ["tables/t1.csv", "tables/t1.md", "tables/t1.tex"]
    back = pd.read_csv(tmp_path / "tables/t1.csv")
    assert back["error (m)"].iloc[0] == pytest.approx(0.012345)
    fig = new_figure()
    fig.add_subplot().plot([0, 1], [1, 0])
    figure = save_figure(fig, tmp_path, "f1", "F", "caption", data={"x": [0, 1]})
    assert figure.files == ["figures/f1.png", "figures/f1.svg"]
    assert (tmp_path / "figures/f1.png").read_bytes()[:4] == b"\x89PNG"
    assert "<svg" in (tmp_path / "figures/f1.svg").read_text()


def test_markdown_table_escapes_html_pipes_and_newlines(tmp_path: Path) -> None:
    """A feature name is user text (the regions CSV): it must not become markup or columns."""
    hostile = pd.DataFrame(
        {"feature": ["<script>alert('x')</script>", "a|b & c\nd"], "scans": [1, 2]}
    )
    save_table(hostile, tmp_path, "f", "T <b>", "caption")
    text = (tmp_path / "tables/f.md").read_text()
    assert "<script>" not in text and "<b>" not in text
    assert "&lt;script&gt;alert('x')&lt;/script&gt;" in text
    lines = text.splitlines()
    assert lines[0] == "**T &lt;b&gt;**"
    assert lines[-1] == "| a\\|b &amp; c d | 2 |"
    assert all(line.count(" | ") == 1 for line in lines[2:])  # two columns, no more


def test_csv_cells_that_look_like_formulas_are_quoted(tmp_path: Path) -> None:
    """OWASP CSV injection: a text cell starting with = + - @ is prefixed with ' so that a
    spreadsheet shows it as text; numbers, negative ones too, stay numbers."""
    cells = ['=HYPERLINK("http://x","y")', "+1", "-2+3", "@SUM(A1)", "corridor"]
    frame = pd.DataFrame({"feature": cells, "error": [-1.5, 0.0, 1.0, 2.0, 3.0]})
    save_table(frame, tmp_path, "c", "T", "caption")
    back = pd.read_csv(tmp_path / "tables/c.csv")
    assert list(back["feature"]) == ["'" + c for c in cells[:4]] + ["corridor"]
    assert list(back["error"]) == [-1.5, 0.0, 1.0, 2.0, 3.0]
    assert not any(str(v).startswith(("=", "+", "-", "@")) for v in back["feature"])
    assert list(frame["feature"]) == cells  # the table's data is not changed
