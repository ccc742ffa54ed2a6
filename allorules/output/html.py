"""A single self-contained HTML report: summary, tables and pictures in one file.

The file opens offline in any browser and can be mailed around: pictures are embedded as
base64 ``data:`` URIs, the style sheet is inline, nothing is fetched from the network. It is
written atomically. Used by ``allorules demo``.
"""
from __future__ import annotations

import base64
import html
import math
import mimetypes
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

from allorules.files import atomic_write

_STYLE = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; color: #222;
       max-width: 1100px; margin: 2em auto; padding: 0 1em; line-height: 1.45; }
h1 { font-weight: 600; margin-bottom: 0.2em; }
h2 { font-weight: 600; margin-top: 1.8em; border-bottom: 1px solid #ddd; padding-bottom: 0.2em; }
.meta { color: #777; font-size: 0.9em; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em; font-size: 0.95em; }
th, td { border: 1px solid #ddd; padding: 0.3em 0.7em; text-align: left; vertical-align: top; }
th { background: #f4f4f4; font-weight: 600; }
td.number { text-align: right; font-variant-numeric: tabular-nums; }
table.summary th { width: 16em; }
figure { margin: 1em 0 2em; }
figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { color: #555; font-size: 0.9em; margin-top: 0.3em; }
.missing { color: #a33; }
"""


@dataclass
class Table:
    """A titled table: ``rows`` are sequences of cells in ``columns`` order."""

    title: str
    columns: Sequence[str]
    rows: Sequence[Sequence[Any]] = field(default_factory=list)
    note: str | None = None


def _format(value: Any) -> tuple[str, bool]:
    """(escaped text, is a number) of a table cell."""
    if isinstance(value, bool):
        return ("yes" if value else "no"), False
    if isinstance(value, int):
        return f"{value:,}", True
    if isinstance(value, float):
        if math.isnan(value):
            return "—", True
        magnitude = abs(value)
        text = f"{value:.4g}" if magnitude == 0 or 1e-3 <= magnitude < 1e6 else f"{value:.3e}"
        return text, True
    try:  # numpy scalars
        import numpy as np

        if isinstance(value, np.generic):
            return _format(value.item())
    except ImportError:  # pragma: no cover
        pass
    if value is None:
        return "—", False
    return html.escape(str(value)), False


def _as_table(item: Any, number: int) -> Table:
    """Accept a :class:`Table`, a mapping with title/columns/rows, or a list of records."""
    if isinstance(item, Table):
        return item
    if isinstance(item, Mapping) and "rows" in item:
        rows = list(item["rows"])
        columns = item.get("columns")
        if columns is None and rows and isinstance(rows[0], Mapping):
            columns = list(rows[0])
        if rows and isinstance(rows[0], Mapping):
            rows = [[row.get(column) for column in columns] for row in rows]
        return Table(str(item.get("title", f"Table {number}")), list(columns or []), rows, item.get("note"))
    if isinstance(item, Sequence) and item and all(isinstance(row, Mapping) for row in item):
        columns: list[str] = []
        for row in item:
            columns += [key for key in row if key not in columns]
        return Table(f"Table {number}", columns, [[row.get(column) for column in columns] for row in item])
    raise TypeError(
        f"table {number}: give a report_html.Table, a dict with 'title', 'columns', 'rows', or a list of dicts"
    )


def _image_html(item: Any) -> str:
    """A <figure> with the picture embedded; ``item`` is a path or (path, caption)."""
    if isinstance(item, (tuple, list)):
        path, caption = Path(item[0]), str(item[1])
    else:
        path = Path(item)
        caption = path.stem.replace("_", " ")
    if not path.is_file():
        return f'<figure><p class="missing">picture missing: {html.escape(str(path))}</p></figure>'
    mime = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (
        f'<figure><img src="data:{mime};base64,{data}" alt="{html.escape(caption)}">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


def render_html(
    *,
    title: str,
    summary: Mapping[str, Any],
    tables: Sequence[Any] = (),
    images: Sequence[Any] = (),
    notes: Sequence[str] = (),
) -> str:
    """The report's HTML text (see :func:`write_html_report`)."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f'<p class="meta">written by allorules, {datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")}</p>',
    ]
    if summary:
        parts.append('<h2>Summary</h2><table class="summary">')
        for key, value in summary.items():
            text, is_number = _format(value)
            parts.append(f'<tr><th>{html.escape(str(key))}</th><td{" class=number" if is_number else ""}>{text}</td></tr>')
        parts.append("</table>")
    if notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(note)}</li>" for note in notes) + "</ul>")
    for number, item in enumerate(tables, start=1):
        table = _as_table(item, number)
        parts.append(f"<h2>{html.escape(table.title)}</h2><table><tr>")
        parts.extend(f"<th>{html.escape(str(column))}</th>" for column in table.columns)
        parts.append("</tr>")
        for row in table.rows:
            cells = []
            for value in row:
                text, is_number = _format(value)
                cells.append(f'<td{" class=number" if is_number else ""}>{text}</td>')
            parts.append("<tr>" + "".join(cells) + "</tr>")
        parts.append("</table>")
        if table.note:
            parts.append(f'<p class="meta">{html.escape(table.note)}</p>')
    if images:
        parts.append("<h2>Pictures</h2>")
        parts.extend(_image_html(item) for item in images)
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def write_html_report(
    path: str | Path,
    *,
    title: str,
    summary: Mapping[str, Any],
    tables: Sequence[Any] = (),
    images: Sequence[Any] = (),
    notes: Sequence[str] = (),
) -> Path:
    """Write one self-contained HTML file (atomically) and return its path.

    ``summary``: {label: value} shown first. ``tables``: :class:`Table` objects, dicts with
    ``title``/``columns``/``rows`` (rows may be dicts), or lists of dicts. ``images``: paths to
    PNG/JPEG/SVG files, or (path, caption) pairs; they are embedded, so the report still works
    after the pictures are deleted. A missing picture is named in red, not fatal.
    """
    path = Path(path)
    atomic_write(path, render_html(title=title, summary=summary, tables=tables, images=images, notes=notes))
    return path
