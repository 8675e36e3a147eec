"""report.html: the report's markdown as one self-contained HTML page (tables as HTML, plots embedded as data URIs)."""

from __future__ import annotations

import base64
import html as _html
import re
from pathlib import Path

from .files import PLOTS_PREFIX

_INLINE_CODE = re.compile(r"`([^`]*)`")


def _inline(text: str) -> str:
    """Escaped text with `code` spans."""
    return _INLINE_CODE.sub(lambda m: f"<code>{m.group(1)}</code>", _html.escape(text, quote=False))


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _is_rule(line: str) -> bool:
    """A table's header rule: only |, -, : and spaces."""
    return "-" in line and not line.strip().strip("|-: ")


def _table(rows: list[str]) -> str:
    """A markdown pipe table (header, ``|---|`` rule, body) as an HTML table."""
    head, body = rows[0], rows[2:] if len(rows) > 1 and _is_rule(rows[1]) else rows[1:]
    out = ["<table>", "<thead><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in _cells(head)) + "</tr></thead>",
           "<tbody>"]
    out += ["<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in _cells(r)) + "</tr>" for r in body]
    return "\n".join(out + ["</tbody>", "</table>"])


def _figures(images: dict[str, str]) -> str:
    return "\n".join(f'<figure><img alt="{name}" src="{uri}"><figcaption>{name}</figcaption></figure>'
                     for name, uri in images.items())


def markdown_to_html(text: str, images: dict[str, str] | None = None) -> str:
    """The subset of markdown :func:`.document.markdown` writes (# / ## headings, pipe tables, paragraphs, `code`) as
    HTML body
    elements; the ``Plots:`` paragraph becomes the embedded ``images`` (name -> data URI) when given."""
    blocks: list[str] = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
        elif line.startswith("#"):
            level = min(len(line) - len(line.lstrip("#")), 6)
            blocks.append(f"<h{level}>{_inline(line[level:].strip())}</h{level}>")
            i += 1
        elif line.lstrip().startswith("|"):
            j = i
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                j += 1
            blocks.append(_table(lines[i:j]))
            i = j
        else:
            j = i
            while (j < len(lines) and lines[j].strip() and not lines[j].startswith("#")
                   and not lines[j].lstrip().startswith("|")):
                j += 1
            para = " ".join(s.strip() for s in lines[i:j])
            blocks.append(_figures(images) if images and para.startswith(PLOTS_PREFIX) else f"<p>{_inline(para)}</p>")
            i = j
    return "\n".join(blocks)


_CSS = ("body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;line-height:1.45}"
        "table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #bbb;padding:.25em .6em;text-align:left}"
        "th{background:#eee}code{background:#f4f4f4;padding:0 .2em}figure{margin:1em 0}img{max-width:100%}")



def html_page(env_id: str, markdown_text: str, images: dict[str, str] | None = None) -> str:
    """report.html: one self-contained page (no external resources) of the report's markdown."""
    title = _html.escape(f"Mismatch report: {env_id}")
    return (f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{title}</title>\n"
            f"<style>{_CSS}</style>\n</head>\n<body>\n{markdown_to_html(markdown_text, images)}\n</body>\n</html>\n")


def data_uri(path: Path) -> str:
    """A PNG file as a data URI (embedded in report.html)."""
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")

