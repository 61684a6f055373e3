"""What a report section is made of, and how its figures and tables are written.

A generator returns a `Section`: its figures (PNG + SVG), its tables (CSV, Markdown, LaTeX),
the data behind each of them (so tests check content, not pixels), and what it could not
show and why. A section that lacks a log (or a piece of one: ground truth, odometry, training
regions) says "not available"; it never shows a stand-in.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from matplotlib.figure import Figure as MplFigure

FIGURES = "figures"
TABLES = "tables"


class NotAvailable(Exception):
    """A piece a section needs (a toolkit module, a log) is missing: the report says so."""


# ---------------------------------------------------------------- artifacts


@dataclass
class Figure:
    """One figure: its files (relative to the report), caption and the data it plots."""

    name: str
    title: str
    caption: str
    files: list[str]
    data: Any = None


@dataclass
class Table:
    """One table: the frame, its files (CSV, Markdown, LaTeX) and caption."""

    name: str
    title: str
    caption: str
    frame: pd.DataFrame
    files: list[str]
    formats: dict[str, str] = field(default_factory=dict)


@dataclass
class Section:
    """One result of the report: figures, tables, notes, and what is not available."""

    key: str
    title: str
    intro: str = ""
    figures: list[Figure] = field(default_factory=list)
    tables: list[Table] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    unavailable: list[str] = field(default_factory=list)
    links: list[tuple[str, str]] = field(default_factory=list)  # (label, relative path)
    data: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    seconds: float = 0.0

    @property
    def status(self) -> str:
        if self.error is not None:
            return "failed"
        if self.figures or self.tables or self.data:
            return "partial" if self.unavailable else "ok"
        return "not available"

    def figure(self, name: str) -> Figure:
        return next(f for f in self.figures if f.name == name)

    def table(self, name: str) -> Table:
        return next(t for t in self.tables if t.name == name)


# ---------------------------------------------------------------- writing


def save_figure(
    fig: MplFigure, out: Path, name: str, title: str, caption: str, data: object = None
) -> Figure:
    """Write `fig` as figures/NAME.png and figures/NAME.svg and close it. The tight bounding
    box is found once for both files (`bbox_inches="tight"` lays the figure out again for
    each: a quarter of the report's time in figures)."""
    folder = out / FIGURES
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    fig.draw_without_rendering()
    bbox = fig.get_tightbbox().padded(matplotlib.rcParams["savefig.pad_inches"])
    for ext, extra in (("png", {"dpi": 110}), ("svg", {"metadata": {"Date": None}})):
        path = folder / f"{name}.{ext}"
        fig.savefig(path, bbox_inches=bbox, **extra)
        files.append(f"{FIGURES}/{path.name}")
    plt.close(fig)
    return Figure(name, title, caption, files, data)


def save_table(
    frame: pd.DataFrame,
    out: Path,
    name: str,
    title: str,
    caption: str,
    formats: Mapping[str, str] | None = None,
) -> Table:
    """Write `frame` as tables/NAME.csv (full precision), NAME.md and NAME.tex (formatted)."""
    folder = out / TABLES
    folder.mkdir(parents=True, exist_ok=True)
    formats = dict(formats or {})
    csv_safe(frame).to_csv(folder / f"{name}.csv", index=False)
    (folder / f"{name}.md").write_text(to_markdown(frame, formats, title))
    (folder / f"{name}.tex").write_text(to_latex(frame, formats, caption))
    files = [f"{TABLES}/{name}.{ext}" for ext in ("csv", "md", "tex")]
    return Table(name, title, caption, frame, files, formats)


def new_figure(width: float = 7.0, height: float = 4.0) -> MplFigure:
    """A matplotlib figure on the Agg backend (no display needed)."""
    matplotlib.use("Agg", force=False)
    return plt.figure(figsize=(width, height))


# ---------------------------------------------------------------- table text


def cell(value: object, fmt: str | None = None) -> str:
    """A value as table text: numbers by `fmt` (default 4 significant digits), NaN as '–'."""
    if value is None:
        return "–"
    if isinstance(value, float | np.floating):
        if math.isnan(value):
            return "–"
        return (fmt or "{:.4g}").format(value)
    if isinstance(value, np.integer | int) and not isinstance(value, bool):
        return (fmt or "{:d}").format(int(value))
    return str(value)


def _rows(frame: pd.DataFrame, formats: Mapping[str, str]) -> list[list[str]]:
    columns = [str(c) for c in frame.columns]
    return [
        [cell(v, formats.get(c)) for c, v in zip(columns, row, strict=True)]
        for row in frame.itertuples(index=False, name=None)
    ]


def _numeric(frame: pd.DataFrame) -> list[bool]:
    return [
        pd.api.types.is_numeric_dtype(frame[c]) and not pd.api.types.is_bool_dtype(frame[c])
        for c in frame.columns
    ]


_MARKDOWN_SPECIAL = str.maketrans(
    {"&": "&amp;", "<": "&lt;", ">": "&gt;", "|": "\\|", "\n": " ", "\r": " "}
)


def markdown_escape(text: str) -> str:
    """Text safe in a Markdown table cell: HTML's &, <, > as entities (a name like
    `<script>` shows as text, not markup), | escaped (no extra column), newlines as spaces."""
    return text.translate(_MARKDOWN_SPECIAL)


FORMULA_START = ("=", "+", "-", "@", "\t", "\r")  # what a spreadsheet may read as a formula


def csv_cell(value: object) -> object:
    """A text cell a spreadsheet will not evaluate: one that starts like a formula gets a
    leading ' (OWASP's CSV injection advice); numbers and other text are kept as they are."""
    if isinstance(value, str) and value.startswith(FORMULA_START):
        return "'" + value
    return value


def csv_safe(frame: pd.DataFrame) -> pd.DataFrame:
    """`frame` with every text cell and column name through `csv_cell` (numbers untouched)."""
    out = frame.rename(columns=lambda c: csv_cell(c) if isinstance(c, str) else c)
    for column in out.columns:
        if not pd.api.types.is_numeric_dtype(out[column]):
            out[column] = out[column].map(csv_cell)
    return out


def to_markdown(
    frame: pd.DataFrame, formats: Mapping[str, str] | None = None, title: str = ""
) -> str:
    """A GitHub-flavoured Markdown table (numbers right-aligned), every cell escaped."""
    esc = markdown_escape
    columns = [esc(str(c)) for c in frame.columns]
    lines = [f"**{esc(title)}**", ""] if title else []
    lines.append("| " + " | ".join(columns) + " |")
    lines.append("| " + " | ".join("---:" if n else "---" for n in _numeric(frame)) + " |")
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in _rows(frame, formats or {})]
    return "\n".join(lines) + "\n"


_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}


def latex_escape(text: str) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in text)


def to_latex(
    frame: pd.DataFrame, formats: Mapping[str, str] | None = None, caption: str = ""
) -> str:
    """A booktabs `table` environment (needs \\usepackage{booktabs})."""
    align = "".join("r" if n else "l" for n in _numeric(frame))
    head = " & ".join(latex_escape(str(c)) for c in frame.columns) + r" \\"
    body = [
        " & ".join(latex_escape(c) for c in row) + r" \\" for row in _rows(frame, formats or {})
    ]
    lines = [r"\begin{table}[ht]", r"\centering"]
    if caption:
        lines.append(r"\caption{" + latex_escape(caption) + "}")
    lines += [rf"\begin{{tabular}}{{{align}}}", r"\toprule", head, r"\midrule", *body]
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"
