"""The report's document model and its two formats: a list of blocks (headings, paragraphs,
bullets, code, tables, figures) written as Markdown (`to_markdown`) or as a self-contained HTML
page (`to_html`, figures embedded as data URIs); and the number formats its tables use."""

from __future__ import annotations

import base64
import html
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from nerfaug.statistics import markdown_table


@dataclass
class Heading:
    text: str
    level: int = 2


@dataclass
class Paragraph:
    text: str


@dataclass
class Bullets:
    items: list[str]


@dataclass
class Code:
    text: str
    summary: str | None = None
    """If given, the block is collapsed behind this summary."""


@dataclass
class Table:
    headers: list[str]
    rows: list[list[str]]
    notes: list[str] = field(default_factory=list)


@dataclass
class Figure:
    path: Path
    caption: str


Block = Heading | Paragraph | Bullets | Code | Table | Figure


def to_markdown(blocks: list[Block], root: Path) -> str:
    parts = []
    for block in blocks:
        if isinstance(block, Heading):
            parts.append("#" * block.level + " " + block.text)
        elif isinstance(block, Paragraph):
            parts.append(block.text)
        elif isinstance(block, Bullets):
            parts.append("\n".join(f"- {item}" for item in block.items))
        elif isinstance(block, Code):
            code = f"```\n{block.text}\n```"
            if block.summary is not None:
                code = f"<details><summary>{block.summary}</summary>\n\n{code}\n\n</details>"
            parts.append(code)
        elif isinstance(block, Table):
            rows = [dict(enumerate(row)) for row in block.rows]
            table = markdown_table(rows, [(i, h) for i, h in enumerate(block.headers)]).rstrip()
            parts.append("\n\n".join([table, *block.notes]))
        elif isinstance(block, Figure):
            parts.append(f"![{block.caption}]({block.path.relative_to(root).as_posix()})\n\n*{block.caption}*")
    return "\n\n".join(parts) + "\n"


def _inline_html(text: str) -> str:
    """Escape, then the two Markdown inline marks this report uses: **bold** and `code`."""
    text = html.escape(text, quote=False)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", text)


def _data_uri(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


_NUMBER = re.compile(r"^[-+*]*[0-9.]")


def _html_table(table: Table) -> str:
    head = "".join(f"<th>{_inline_html(h)}</th>" for h in table.headers)
    body = []
    for row in table.rows:
        cells = "".join(
            f'<td class="num">{_inline_html(c)}</td>' if _NUMBER.match(c) else f"<td>{_inline_html(c)}</td>"
            for c in row
        )
        body.append(f"<tr>{cells}</tr>")
    notes = "".join(f'<p class="note">{_inline_html(n)}</p>' for n in table.notes)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>{notes}"


def _html_block(block: Block) -> str:
    if isinstance(block, Heading):
        return f"<h{block.level}>{_inline_html(block.text)}</h{block.level}>"
    if isinstance(block, Paragraph):
        return f"<p>{_inline_html(block.text)}</p>"
    if isinstance(block, Bullets):
        return "<ul>" + "".join(f"<li>{_inline_html(i)}</li>" for i in block.items) + "</ul>"
    if isinstance(block, Code):
        code = f"<pre>{html.escape(block.text)}</pre>"
        if block.summary is None:
            return code
        return f"<details><summary>{html.escape(block.summary)}</summary>{code}</details>"
    if isinstance(block, Table):
        return _html_table(block)
    alt = html.escape(block.caption)
    return f'<figure><img src="{_data_uri(block.path)}" alt="{alt}"><figcaption>{alt}</figcaption></figure>'


# Inline so the file is self-contained: it must open from an e-mail or an offline machine.
_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;max-width:1200px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:2em}
table{border-collapse:collapse;margin:0.8em 0;font-size:0.9em}
th,td{border:1px solid #ccc;padding:3px 8px}th{background:#eee}td.num{text-align:right;
font-variant-numeric:tabular-nums}tr:nth-child(even) td{background:#fafafa}
pre{background:#f4f4f4;padding:0.6em;overflow-x:auto;font-size:0.85em}
code{background:#f4f4f4;padding:0 3px}p.note{font-size:0.85em;color:#555;margin:0.2em 0}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{font-size:0.9em;color:#444}details{margin:0.5em 0}summary{cursor:pointer}
"""


def to_html(blocks: list[Block], title: str) -> str:
    body = "\n".join(_html_block(b) for b in blocks)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n<body>\n{body}\n</body></html>\n"
    )


# Number formats shared by the sections.


def number(value: float | None, decimals: int) -> str:
    if value is None:
        return "n/a"
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return f"{value:.{decimals}f}"


def percent(fraction: float | None) -> str:
    if fraction is None or math.isnan(fraction):
        return "n/a"
    return f"{fraction * 100:+.1f}%"


def p_value(value: float | None) -> str:
    if value is None:
        return "n/a"
    return f"{value:.1e}" if value < 1e-3 else f"{value:.3f}"


def seconds(value: float | None) -> str:
    if value is None or math.isnan(value):
        return "n/a"
    if value < 60:
        return f"{value:.1f} s"
    minutes, rest = divmod(round(value), 60)
    if minutes < 60:
        return f"{minutes}m {rest:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h {minutes:02d}m"


def slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def bold_best(cells: list[str], values: list[float | None], lower_is_better: bool) -> list[str]:
    """Bold the best value (the paper highlights the best method per column). Ties are judged on
    the cells as shown, so values equal to the shown precision are all bold; if all are, none is."""
    finite = [(v, c) for v, c in zip(values, cells) if v is not None and math.isfinite(v)]
    if len({c for _, c in finite}) < 2:
        return cells
    best = (min if lower_is_better else max)(finite)[1]
    return [f"**{c}**" if c == best else c for c in cells]


__all__ = [
    "Block",
    "Bullets",
    "Code",
    "Figure",
    "Heading",
    "Paragraph",
    "Table",
    "bold_best",
    "number",
    "p_value",
    "percent",
    "seconds",
    "slug",
    "to_html",
    "to_markdown",
]
