"""Report pages from sections: a self-contained HTML file (images inlined as base64 data URIs) and Markdown
(images referenced as PNG files next to it). Sections hold plain text, tables and figures only."""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Table:
    headers: list[str]
    rows: list[list[str]]
    caption: str = ""


@dataclass(frozen=True)
class FigureRef:
    path: Path          # a PNG written by the section
    caption: str


@dataclass
class Section:
    """One part of the report. ``data`` goes to report.json under "sections"/<key>."""

    key: str
    title: str
    paragraphs: list[str] = field(default_factory=list)
    tables: list[Table] = field(default_factory=list)
    figures: list[FigureRef] = field(default_factory=list)
    data: dict[str, Any] = field(default_factory=dict)


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1180px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #1f77b4;padding-bottom:.2em}h2{margin-top:2em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:1em 0;font-size:.92em}th,td{border:1px solid #ccc;padding:.3em .6em;
text-align:right}th{background:#f3f6fa}td:first-child,th:first-child{text-align:left}
caption{caption-side:top;text-align:left;font-weight:600;padding-bottom:.3em}
figure{margin:1.2em 0}figure img{max-width:100%;border:1px solid #eee}figcaption{font-size:.9em;color:#555}
nav a{margin-right:1em}code{background:#f4f4f4;padding:0 .2em}p.note{color:#8a4b00}
"""


def _md_table(t: Table) -> str:
    lines = []
    if t.caption:
        lines.append(f"**{t.caption}**\n")
    lines.append("| " + " | ".join(t.headers) + " |")
    lines.append("|" + "|".join(["---"] + ["---:"] * (len(t.headers) - 1)) + "|")
    lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |" for row in t.rows]
    return "\n".join(lines)


def render_markdown(title: str, sections: list[Section], root: Path) -> str:
    out = [f"# {title}", ""]
    for s in sections:
        out += [f"## {s.title}", ""]
        for p in s.paragraphs:
            out += [p, ""]
        for t in s.tables:
            out += [_md_table(t), ""]
        for f in s.figures:
            rel = f.path.relative_to(root) if f.path.is_relative_to(root) else f.path
            out += [f"![{f.caption}]({rel.as_posix()})", "", f"*{f.caption}*", ""]
    return "\n".join(out)


def _html_table(t: Table) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in t.headers)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in t.rows)
    cap = f"<caption>{html.escape(t.caption)}</caption>" if t.caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def data_uri(png: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")


def render_html(title: str, sections: list[Section]) -> str:
    parts = ["<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\">",
             f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>",
             "<nav>" + "".join(f"<a href=\"#{html.escape(s.key)}\">{html.escape(s.title)}</a>" for s in sections)
             + "</nav>"]
    for s in sections:
        parts.append(f"<section id=\"{html.escape(s.key)}\"><h2>{html.escape(s.title)}</h2>")
        for p in s.paragraphs:
            cls = " class=\"note\"" if p.startswith("Note:") or p.startswith("**") else ""
            parts.append(f"<p{cls}>{_inline(p)}</p>")
        parts += [_html_table(t) for t in s.tables]
        for f in s.figures:
            parts.append(f"<figure><img alt=\"{html.escape(f.caption)}\" src=\"{data_uri(f.path)}\">"
                         f"<figcaption>{html.escape(f.caption)}</figcaption></figure>")
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _inline(text: str) -> str:
    """Escape, then render `code` spans and **bold** (the only Markdown the sections use)."""
    esc = html.escape(text)
    out = []
    for i, piece in enumerate(esc.split("`")):
        out.append(f"<code>{piece}</code>" if i % 2 else piece)
    joined = "".join(out)
    bold = joined.split("**")
    return "".join(f"<strong>{p}</strong>" if i % 2 else p for i, p in enumerate(bold))
