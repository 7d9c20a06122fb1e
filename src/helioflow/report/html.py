"""HTML building blocks of the self-contained report (report/page.py).

Everything is escaped, and nothing refers to a file: images and downloads are embedded as
``data:`` URIs, style sheets inline. Nested JSON (field metrics, PAINT centroids) is shown as
tables by `nested_tables`, so a writer may add keys without touching the report.
"""

from __future__ import annotations

import base64
import html
import json
import os
import re
from collections import Counter
from pathlib import Path

from helioflow.errors import DataError

DASH = "–"
MAX_ROWS = 40  # rows shown of one generic table; the file holds all
MAX_LIST = 8  # a longer list of numbers in a cell is shown as its count and range
MAX_COLUMNS = 12  # a generic table wider than this (and longer than wide) is shown transposed
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

STYLE = """
body { font-family: system-ui, sans-serif; max-width: 78em; margin: 1em auto; padding: 0 1em;
       color: #222; line-height: 1.4; }
h1 { border-bottom: 2px solid #444; } h2 { border-bottom: 1px solid #aaa; margin-top: 2em; }
nav ol { columns: 2; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; } th { background: #f0f0f0; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.total td { font-weight: bold; border-top: 2px solid #444; }
.scroll { overflow-x: auto; }
figure { display: inline-block; margin: 0.5em; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 0.9em; color: #555; }
p.absent { color: #777; font-style: italic; }
p.verdict { background: #f6f6e8; border-left: 4px solid #b8b840; padding: 0.5em 1em; }
"""


def esc(text) -> str:
    """HTML-escaped text of any value."""
    return html.escape(str(text))


def read_bytes(path: str | os.PathLike) -> bytes:
    """A file's bytes; a missing or unreadable file raises DataError naming it."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read report input: {exc}") from None


def read_json(path: str | os.PathLike):
    """A JSON file's content; DataError naming the file if it is missing or not JSON."""
    try:
        return json.loads(read_bytes(path))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: not a JSON file: {exc}") from None


def png_uri(data: bytes) -> str:
    """A data: URI of PNG bytes."""
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def figure(path: str | os.PathLike, caption: str) -> str:
    """A PNG file inline as <figure> with a caption; DataError if the file is not a PNG."""
    data = read_bytes(path)
    if not data.startswith(PNG_SIGNATURE):
        raise DataError(f"{path}: not a PNG image")
    return figure_bytes(data, caption)


def figure_bytes(data: bytes, caption: str) -> str:
    """PNG bytes inline as <figure> with a caption."""
    return (f'<figure><img src="{png_uri(data)}" alt="{esc(caption)}">'
            f"<figcaption>{esc(caption)}</figcaption></figure>")


def download(path: str | os.PathLike, mime: str = "text/csv") -> str:
    """A link that saves the file's content, embedded as a data: URI, under its name."""
    data = base64.b64encode(read_bytes(path)).decode("ascii")
    name = Path(path).name
    return f'<a download="{esc(name)}" href="data:{mime};base64,{data}">{esc(name)}</a>'


def fmt(value) -> str:
    """A table cell: floats to 4 significant digits, None as a dash, a list of more than
    MAX_LIST items by its count and range (numbers) or counts (text), a shorter one item by item,
    nested lists and dicts as JSON."""
    if isinstance(value, list) and len(value) > MAX_LIST:
        return _summary(value)
    if value is None:
        return DASH
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if value != 0 and not 1e-3 <= abs(value) < 1e5:
            return f"{value:.3e}"
        return f"{value:.4g}"
    if isinstance(value, list) and all(map(_is_scalar, value)):
        return "[" + ", ".join(map(fmt, value)) + "]"
    if isinstance(value, (list, dict)):
        return json.dumps(value, separators=(", ", ": "))
    return str(value)


def _summary(values: list) -> str:
    """'200 values, 0.1 … 4.3' for numbers, '200 values: train 150, interpolation 50' for text."""
    numbers = [v for v in values if _reads_as_number(v)]
    if len(numbers) == len(values):
        return f"{len(values)} values, {fmt(float(min(numbers)))} … {fmt(float(max(numbers)))}"
    counts = Counter(map(str, values))
    if len(counts) > MAX_LIST:
        return f"{len(values)} values"
    return f"{len(values)} values: " + ", ".join(f"{k} {n}" for k, n in counts.items())


def _reads_as_number(value) -> bool:
    """A number, or text that reads as one (pre-formatted cells such as '2.50' or '80 %')."""
    if isinstance(value, str):
        return re.fullmatch(r"-?\d[\d.,]*( %)?", value) is not None
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def table(header: list[str], rows: list[list], total: list | None = None) -> str:
    """An HTML table; numbers (and text that reads as one) right-aligned; `total` is an
    emphasised last row."""
    def row(cells, cls=""):
        tds = "".join(f'<td class="num">{esc(fmt(c))}</td>' if _reads_as_number(c) else f"<td>{esc(fmt(c))}</td>"
                      for c in cells)
        return f"<tr{cls}>{tds}</tr>"

    body = "".join(row(r) for r in rows) + (row(total, ' class="total"') if total else "")
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    return f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'


def _inline(text: str) -> str:
    """Escaped text with Markdown **bold** and `code`."""
    text = esc(text)
    text = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", text)
    return re.sub(r"`(.+?)`", r"<code>\1</code>", text)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def markdown(text: str) -> str:
    """The Markdown the pipeline writes (paragraphs, pipe tables, **bold**, `code`) as HTML."""
    parts = []
    for block in re.split(r"\n\s*\n", text.strip()):
        lines = block.strip().splitlines()
        if len(lines) >= 2 and all(line.lstrip().startswith("|") for line in lines):
            right = [c.endswith(":") for c in _cells(lines[1])]
            head = "".join(f"<th>{_inline(c)}</th>" for c in _cells(lines[0]))
            body = "".join(
                "<tr>" + "".join(f'<td class="num">{_inline(c)}</td>' if i < len(right) and right[i]
                                 else f"<td>{_inline(c)}</td>" for i, c in enumerate(_cells(line))) + "</tr>"
                for line in lines[2:])
            parts.append(f'<div class="scroll"><table><thead><tr>{head}</tr></thead>'
                         f"<tbody>{body}</tbody></table></div>")
        else:
            parts.append(f"<p>{_inline(' '.join(lines))}</p>")
    return "\n".join(parts)


def fixed(value, digits: int):
    """A number as text with `digits` decimals (a column reads evenly); anything else as it is."""
    return f"{value:.{digits}f}" if _reads_as_number(value) and not isinstance(value, str) else value


def figures_by_name(paths: list[str]) -> dict[str, str]:
    """{file name: path} of figure files, to pick a section's figures by name."""
    return {Path(p).name: str(p) for p in paths}


def _is_scalar(value) -> bool:
    return value is None or isinstance(value, (str, int, float, bool)) or (
        isinstance(value, list) and all(isinstance(v, (str, int, float, bool)) or v is None for v in value))


def _rows(data, path: tuple[str, ...], out: list[tuple[tuple[str, ...], dict]]) -> None:
    """Collect (path, {column: scalar}) rows: a dict's scalar entries form one row, its nested
    dicts and lists of dicts rows of their own below it."""
    if isinstance(data, dict):
        scalars = {str(k): v for k, v in data.items() if _is_scalar(v)}
        if scalars:
            out.append((path, scalars))
        for key, value in data.items():
            if not _is_scalar(value):
                _rows(value, (*path, str(key)), out)
    elif isinstance(data, list):
        for i, value in enumerate(data):
            _rows(value, (*path, str(i)), out)
    else:
        out.append((path[:-1], {path[-1] if path else "value": data}))


def nested_tables(data) -> str:
    """Any nested JSON as tables: rows are the dicts (labelled by their path), columns their
    scalar keys; rows with the same columns share one table, in order of first appearance.
    A table shows at most MAX_ROWS rows; one much wider than long is transposed."""
    rows: list[tuple[tuple[str, ...], dict]] = []
    _rows(data, (), rows)
    groups: dict[tuple[str, ...], list[tuple[str, dict]]] = {}
    for path, values in rows:
        groups.setdefault(tuple(values), []).append((" / ".join(path), values))
    parts = []
    for columns, members in groups.items():
        header, body = ["", *columns], [[label, *(v[c] for c in columns)] for label, v in members]
        if len(columns) > MAX_COLUMNS and len(columns) > len(members):
            header = ["", *(label for label, _ in members)]
            body = [[c, *(v[c] for _, v in members)] for c in columns]
        note = f"<p>first {MAX_ROWS} of {len(body)} rows (all in the file)</p>" * (len(body) > MAX_ROWS)
        parts.append(table(header, body[:MAX_ROWS]) + note)
    return "\n".join(parts)


def page(title: str, sections: list[tuple[str, str, str]]) -> str:
    """A complete HTML document: title, contents list, then the (id, heading, body) sections."""
    nav = "".join(f'<li><a href="#{sid}">{esc(heading)}</a></li>' for sid, heading, _ in sections)
    body = "\n".join(f'<section id="{sid}">\n<h2>{esc(heading)}</h2>\n{content}\n</section>'
                     for sid, heading, content in sections)
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f"<title>{esc(title)}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n<h1>{esc(title)}</h1>\n"
            f"<nav><ol>{nav}</ol></nav>\n{body}\n</body>\n</html>\n")
