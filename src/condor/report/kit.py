"""The HTML kit any report is built of: `figure`, `table`, `paragraph`, `folded`, `verdict`,
`side_by_side`, `Section`, `render` and `write_report`. PNGs are embedded as base64 data URIs,
tables come from CSV files or DataFrames, every figure and table has a caption, long
galleries fold away (<details>), and a table of contents links the sections. A missing or
empty input raises ReportError instead of showing a placeholder."""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

CSS = """
body{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;padding:0 1em;color:#222}
h1{font-size:1.5em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
figure{margin:1.2em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption,caption{font-size:.9em;color:#444;text-align:left;margin:.3em 0}
table{border-collapse:collapse;font-size:.85em;margin:.8em 0}
td,th{border:1px solid #ddd;padding:.2em .5em;text-align:right}th{background:#f4f4f4}
td:first-child,th:first-child{text-align:left}nav li{margin:.15em 0}
.scroll{overflow-x:auto}
.meta{color:#666;font-size:.85em}
details{margin:.8em 0;border:1px solid #e4e4e4;border-radius:4px;padding:.3em .7em}
summary{cursor:pointer;font-weight:600;color:#08519c}
.verdict{background:#f5f9ff;border-left:4px solid #08519c;padding:.5em .9em;margin:1em 0}
.headline{font-size:1em;margin:.6em 0}.headline th{text-align:left;white-space:nowrap}
.headline td{text-align:left}nav{font-size:.9em;margin:.3em 0}h1{margin:.4em 0}
section#summary h2{margin-top:.6em}
.grid{display:flex;flex-wrap:wrap;gap:1.5em;align-items:flex-start}.grid>div{flex:1 1 420px}
"""


class ReportError(ValueError):
    """A report input is missing or empty; the message names it."""


@dataclass
class Section:
    """One section: an anchor id, a title and HTML blocks (figures, tables, paragraphs)."""

    id: str
    title: str
    blocks: list[str] = field(default_factory=list)


def existing_file(path, what: str) -> Path:
    path = Path(path)
    if not path.is_file() or path.stat().st_size == 0:
        raise ReportError(f"{what}: {str(path)!r} is missing or empty")
    return path


def paragraph(text: str) -> str:
    """A paragraph of plain text (escaped)."""
    return f"<p>{html.escape(text)}</p>"


def figure(path, caption: str, alt: str | None = None) -> str:
    """A PNG embedded as a base64 data URI, with its caption."""
    path = existing_file(path, "figure")
    if path.suffix.lower() != ".png":
        raise ReportError(f"figure {str(path)!r} must be a .png")
    data = base64.b64encode(_compact_png(path)).decode("ascii")
    alt = html.escape(alt or path.stem)
    return (f'<figure><img alt="{alt}" src="data:image/png;base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


# A PNG larger than this is embedded with its colours quantised to a 256-colour palette
# (matplotlib's figures hold few colours; the page stays small), when that is smaller.
COMPACT_PNG_BYTES = 20_000


def _compact_png(path: Path) -> bytes:
    """The PNG's bytes, or those of its 256-colour quantised copy when it is larger than
    COMPACT_PNG_BYTES and the copy is smaller."""
    raw = path.read_bytes()
    if len(raw) <= COMPACT_PNG_BYTES:
        return raw
    import io

    from PIL import Image

    with Image.open(io.BytesIO(raw)) as image:
        small = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
        out = io.BytesIO()
        small.save(out, format="PNG", optimize=True)
    return out.getvalue() if out.tell() < len(raw) else raw


def _format(value, digits: int) -> str:
    if isinstance(value, (float, np.floating)):
        if not np.isfinite(value):
            return "" if np.isnan(value) else str(value)
        if float(value).is_integer() and abs(value) >= 10 ** digits:
            return f"{int(value):,}"  # a count (cells, evaluations), not 4.57e+03
        return f"{value:.{digits}g}"
    return html.escape(str(value))


def folded(title: str, blocks: list[str], open_: bool = False) -> str:
    """Blocks folded under a one-line summary (HTML <details>)."""
    flag = " open" if open_ else ""
    return (f"<details{flag}><summary>{html.escape(title)}</summary>" + "".join(blocks)
            + "</details>")


def verdict(text: str) -> str:
    """A highlighted paragraph: what the numbers mean, in plain words."""
    return f'<p class="verdict">{html.escape(text)}</p>'


def side_by_side(*blocks: str) -> str:
    return '<div class="grid">' + "".join(f"<div>{b}</div>" for b in blocks) + "</div>"


def table(data, caption: str, columns=None, digits: int = 4, index: bool = False,
          max_rows: int = 60) -> str:
    """An HTML table from a DataFrame or a CSV path (floats to `digits` significant digits);
    `columns` picks and orders columns; at most `max_rows` rows (the rest are counted)."""
    if not isinstance(data, pd.DataFrame):
        data = pd.read_csv(existing_file(data, "table"))
    if index:
        data = data.reset_index()
    if columns is not None:
        missing = [c for c in columns if c not in data.columns]
        if missing:
            raise ReportError(f"table {caption!r}: no column(s) {missing} in {list(data.columns)}")
        data = data[list(columns)]
    if data.empty:
        raise ReportError(f"table {caption!r} has no rows")
    shown = data.head(max_rows)
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in shown.columns)
    body = "".join("<tr>" + "".join(f"<td>{_format(v, digits)}</td>" for v in row) + "</tr>"
                   for row in shown.itertuples(index=False))
    more = len(data) - len(shown)
    note = f" ({more} more rows in the CSV)" if more > 0 else ""
    return (f'<div class="scroll"><table><caption>{html.escape(caption)}{note}</caption>'
            f"<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>")


def render(title: str, sections: list[Section], meta: str = "") -> str:
    """The whole HTML document: title, table of contents, sections. A section without
    blocks raises ReportError (no placeholders)."""
    for s in sections:
        if not s.blocks:
            raise ReportError(f"section {s.title!r} has no content")
    ids = [s.id for s in sections]
    if len(set(ids)) != len(ids):
        raise ReportError(f"section ids repeat: {ids}")
    toc = " · ".join(f'<a href="#{html.escape(s.id)}">{html.escape(s.title)}</a>'
                     for s in sections)
    body = "".join(f'<section id="{html.escape(s.id)}"><h2>{html.escape(s.title)}</h2>'
                   + "".join(s.blocks) + "</section>" for s in sections)
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{CSS}</style></head><body>"
            f"<h1>{html.escape(title)}</h1><p class=\"meta\">{html.escape(meta)}</p>"
            f"<nav>Contents: {toc}</nav>{body}</body></html>")


def write_report(path, title: str, sections: list[Section], meta: str = "") -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(render(title, sections, meta), encoding="utf-8")
    return path
