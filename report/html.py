"""A self-contained HTML page from the report's Markdown (the small subset the report writes).

Images referenced as ``![alt](file.png)`` are embedded as base64 data URIs, so the page can be mailed or archived
alone; links ``[text](file)`` stay links (the videos, too large to embed). Supported: ``#`` headings, pipe tables,
fenced code, ``**bold**``, ```code```, ``- `` lists and paragraphs.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

_STYLE = """
body { font-family: sans-serif; max-width: 1400px; margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: right; }
th:first-child, td:first-child { text-align: left; }
pre { background: #f5f5f5; padding: 0.5em; overflow-x: auto; font-size: 0.8em; max-height: 30em; }
img { max-width: 100%; }
"""


def _inline(text: str, base: Path) -> str:
    """Escapes ``text`` and applies images, bold and code spans."""

    def image(m: re.Match[str]) -> str:
        path = base / m.group(2)
        if not path.is_file():
            return html.escape(m.group(0))
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        return f'<img alt="{html.escape(m.group(1))}" src="data:image/png;base64,{data}">'

    parts = re.split(r"(!?\[[^\]]*\]\([^)]+\))", text)
    out = []
    for part in parts:
        m = re.fullmatch(r"!\[([^\]]*)\]\(([^)]+)\)", part)
        if m:
            out.append(image(m))
            continue
        m = re.fullmatch(r"\[([^\]]*)\]\(([^)]+)\)", part)
        if m:  # a link to a file beside the page (the videos): not embedded
            out.append(f'<a href="{html.escape(m.group(2))}">{html.escape(m.group(1))}</a>')
            continue
        s = html.escape(part)
        s = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", s)
        s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
        out.append(s)
    return "".join(out)


def _table(lines: list[str], base: Path) -> str:
    cells = [[c.strip() for c in line.strip().strip("|").split("|")] for line in lines]
    head, body = cells[0], cells[2:]  # cells[1] is the |---| separator
    rows = ["<tr>" + "".join(f"<th>{_inline(c, base)}</th>" for c in head) + "</tr>"]
    rows += ["<tr>" + "".join(f"<td>{_inline(c, base)}</td>" for c in row) + "</tr>" for row in body]
    return "<table>" + "\n".join(rows) + "</table>"


def markdown_to_html(markdown: str, base: Path, title: str) -> str:
    """Converts the report's Markdown to one standalone page; images are read relative to ``base``."""
    lines = markdown.splitlines()
    out: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("```"):
            end = next((j for j in range(i + 1, len(lines)) if lines[j].startswith("```")), len(lines))
            out.append("<pre>" + html.escape("\n".join(lines[i + 1 : end])) + "</pre>")
            i = end + 1
        elif line.startswith("|"):
            end = i
            while end < len(lines) and lines[end].startswith("|"):
                end += 1
            out.append(_table(lines[i:end], base))
            i = end
        elif m := re.match(r"(#{1,6}) (.*)", line):
            level = len(m.group(1))
            out.append(f"<h{level}>{_inline(m.group(2), base)}</h{level}>")
            i += 1
        elif line.startswith("- "):
            end = i
            while end < len(lines) and lines[end].startswith("- "):
                end += 1
            out.append("<ul>" + "".join(f"<li>{_inline(x[2:], base)}</li>" for x in lines[i:end]) + "</ul>")
            i = end
        elif line.strip():
            out.append(f"<p>{_inline(line, base)}</p>")
            i += 1
        else:
            i += 1
    body = "\n".join(out)
    return (f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head>\n<body>\n{body}\n</body></html>\n")  # fmt: skip
