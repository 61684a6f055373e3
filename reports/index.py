"""index.html: the report a reader opens in a browser, offline.

Self-contained: the CSS is inline and every PNG is embedded as a data URI, so the page alone
shows everything; it also links each figure's PNG and SVG and each table's CSV, Markdown and
LaTeX file, all relative to the report folder. Every file it names exists (tests check it).
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from reports.base import Figure, Section, Table, cell

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
h3{font-size:1.05em;margin-bottom:.3em}
.meta{color:#555;font-size:.9em}
.badge{font-size:.7em;padding:.15em .5em;border-radius:.6em;vertical-align:middle;margin-left:.5em}
.ok{background:#d8f0d8}.partial{background:#fff0c0}.na{background:#f0d8d8}.failed{background:#f4b0b0}
table{border-collapse:collapse;margin:.5em 0;font-size:.88em}
th,td{border:1px solid #ccc;padding:.2em .55em}th{background:#f2f2f2}td.n{text-align:right;
font-variant-numeric:tabular-nums}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption,.caption{font-size:.9em;color:#333}
.files{font-size:.85em}.files a{margin-right:.6em}
.unavailable{color:#8a1c1c}
nav ol{columns:2;font-size:.92em}
code{background:#f4f4f4;padding:0 .2em}
"""

STATUS_CLASS = {"ok": "ok", "partial": "partial", "not available": "na", "failed": "failed"}


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _links(files: Sequence[str]) -> str:
    return (
        '<div class="files">'
        + "".join(f'<a href="{_e(f)}">{_e(Path(f).suffix.lstrip(".").upper())}</a>' for f in files)
        + "</div>"
    )


def _figure(fig: Figure, root: Path) -> str:
    png = next((f for f in fig.files if f.endswith(".png")), None)
    img = ""
    if png is not None:
        data = base64.b64encode((root / png).read_bytes()).decode("ascii")
        img = f'<img alt="{_e(fig.title)}" src="data:image/png;base64,{data}">'
    return (
        f'<figure id="fig-{_e(fig.name)}"><h3>{_e(fig.title)}</h3>{img}'
        f"<figcaption>{_e(fig.caption)}</figcaption>{_links(fig.files)}</figure>"
    )


def html_table(table: Table) -> str:
    frame = table.frame
    numeric = [frame[c].dtype.kind in "iuf" for c in frame.columns]
    head = "".join(f"<th>{_e(c)}</th>" for c in frame.columns)
    rows = []
    for row in frame.itertuples(index=False, name=None):
        tds = "".join(
            f'<td class="n">{_e(cell(v, table.formats.get(str(c))))}</td>'
            if n
            else f"<td>{_e(cell(v, table.formats.get(str(c))))}</td>"
            for c, v, n in zip(frame.columns, row, numeric, strict=True)
        )
        rows.append(f"<tr>{tds}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"


def _table(table: Table) -> str:
    return (
        f'<div id="table-{_e(table.name)}"><h3>{_e(table.title)}</h3>'
        f'<p class="caption">{_e(table.caption)}</p>{html_table(table)}{_links(table.files)}</div>'
    )


def _section(section: Section, root: Path) -> str:
    status = section.status
    parts = [
        f'<section id="{_e(section.key)}"><h2>{_e(section.title)}'
        f'<span class="badge {STATUS_CLASS[status]}">{_e(status)}</span></h2>'
    ]
    if section.intro:
        parts.append(f"<p>{_e(section.intro)}</p>")
    if section.error:
        parts.append(f'<p class="unavailable">Failed: {_e(section.error)}</p>')
    for what in section.unavailable:
        parts.append(f'<p class="unavailable">Not available: {_e(what)}</p>')
    parts += [_table(t) for t in section.tables]
    parts += [_figure(f, root) for f in section.figures]
    if section.notes:
        parts.append("<ul>" + "".join(f"<li>{_e(n)}</li>" for n in section.notes) + "</ul>")
    if section.links:
        parts.append(
            '<p class="files">Files: '
            + " ".join(f'<a href="{_e(p)}">{_e(label)}</a>' for label, p in section.links)
            + "</p>"
        )
    parts.append(f'<p class="meta">Generated in {section.seconds:.1f} s.</p></section>')
    return "".join(parts)


def write_index(root: Path, sections: Sequence[Section], header: Mapping[str, Any]) -> Path:
    """Write root/index.html for `sections`; `header` holds title, command, date, seconds."""
    title = str(header.get("title", "Report"))
    toc = "".join(
        f'<li><a href="#{_e(s.key)}">{_e(s.title)}</a> '
        f'<span class="badge {STATUS_CLASS[s.status]}">{_e(s.status)}</span></li>'
        for s in sections
    )
    meta = " · ".join(
        f"{_e(k)}: {_e(v)}" for k, v in header.items() if k != "title" and v is not None
    )
    body = "".join(_section(s, root) for s in sections)
    page = (
        "<!DOCTYPE html>\n"
        f'<html lang="en"><head><meta charset="utf-8"><title>{_e(title)}</title>'
        f'<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<style>{CSS}</style></head><body>"
        f'<h1>{_e(title)}</h1><p class="meta">{meta}</p>'
        f"<nav><ol>{toc}</ol></nav>{body}</body></html>\n"
    )
    path = root / "index.html"
    path.write_text(page, encoding="utf-8")
    return path
