"""Records: one JSON object per line on stdout (NaN -> null), or a table / markdown for people."""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Iterable, Mapping
from itertools import groupby
from typing import IO, Any

import numpy as np

from lesscli.errors import DataError


def to_jsonable(value: Any) -> Any:
    """Plain JSON types: numpy scalars/arrays unwrapped, NaN/inf -> None (written as null)."""
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def dumps(record: Mapping) -> str:
    """One record as a single JSON line (allow_nan=False: NaN was already turned into null)."""
    return json.dumps(to_jsonable(record), allow_nan=False, separators=(", ", ": "))


# a table's list or mapping cell is cut to its first items within this many characters
CELL_ITEMS_WIDTH = 60
TABLE_WIDTH = 120        # a one-record table wider than this is written as one "key  value" line per column


def _rounded(value: Any) -> Any:
    """``value`` (plain JSON) with its floats to the 4 significant digits a table's number cells show."""
    if isinstance(value, float):
        return float(f"{value:.4g}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def _short(value: Any, width: int) -> str:
    """``value`` (plain JSON) as JSON in about ``width`` characters: a list or mapping cut after the items
    that fit, saying how many there are in all, each item itself cut to the room left (the first to nearly all
    of it); a string cut with "...". A table is read by people, and a split's hundred insert names would
    make every row a screen wide; JSON lines and JSON keep every item."""
    whole = json.dumps(value)
    if len(whole) <= width:
        return whole
    if isinstance(value, str):
        return json.dumps(value[:max(width - 5, 8)] + "...")
    if not isinstance(value, (list, dict)):
        return whole
    pairs = isinstance(value, dict)
    items = value.items() if pairs else ((None, v) for v in value)
    tail = f", ... ({len(value)} in all)" if len(value) > 1 else ""
    shown: list[str] = []
    for key, item in items:
        room = width - 2 - len(tail) - len(", ".join(shown)) - (2 if shown else 0)
        prefix = f"{json.dumps(key)}: " if pairs else ""
        part = prefix + _short(item, max(room - len(prefix), 8))
        if shown and len(part) > room:
            break
        shown.append(part)
    if len(shown) == len(value):
        tail = ""
    return ("{" if pairs else "[") + ", ".join(shown) + tail + ("}" if pairs else "]")


def _cell(value: Any, width: int = CELL_ITEMS_WIDTH) -> str:
    value = to_jsonable(value)
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, dict)):
        return _short(_rounded(value), width)
    return str(value)


def _columns(rows: list[Mapping], columns: list[str] | None) -> list[str]:
    if columns:
        return columns
    seen: dict[str, None] = {}
    for row in rows:
        seen.update(dict.fromkeys(row))
    return list(seen)


def format_table(rows: list[Mapping], columns: list[str] | None = None, markdown: bool = False) -> str:
    """Aligned text table (or GitHub markdown table) of ``rows``, long lists and mappings cut
    (:func:`_short`). One record wider than ``TABLE_WIDTH`` is written down the page instead, left-aligned: a
    column "key" of its keys and one "value" of their cells, as wide as the keys leave (``less info`` of a
    scan set). A
    markdown table keeps its columns: a document's tables are read across, and its viewer scrolls."""
    cols = _columns(rows, columns)
    cells = [[_cell(row.get(c)) for c in cols] for row in rows]
    widths = [max([len(c)] + [len(r[i]) for r in cells]) for i, c in enumerate(cols)]
    down = not markdown and len(rows) == 1 and sum(widths) + 2 * len(widths) > TABLE_WIDTH
    if down:                                    # the value column takes the width the keys leave
        width = max(CELL_ITEMS_WIDTH, TABLE_WIDTH - 2 - max(map(len, cols)))
        cols, cells = ["key", "value"], [[c, _cell(rows[0].get(c), width)] for c in cols]
        widths = [max([len(c)] + [len(r[i]) for r in cells]) for i, c in enumerate(cols)]
    if markdown:
        def line(vals: list[str]) -> str:
            return "| " + " | ".join(v.ljust(w) for v, w in zip(vals, widths)) + " |"

        sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
        return "\n".join([line(cols), sep, *(line(r) for r in cells)])

    def row(vals: list[str]) -> str:
        return "  ".join(v.ljust(w) if down else v.rjust(w) for v, w in zip(vals, widths)).rstrip()

    return "\n".join([row(cols), row(["-" * w for w in widths]), *(row(r) for r in cells)])


def resolve_format(fmt: str | None, stream: IO | None = None) -> str:
    """Default format: table on a terminal, JSON lines otherwise."""
    if fmt:
        return fmt
    stream = sys.stdout if stream is None else stream
    return "table" if getattr(stream, "isatty", lambda: False)() else "jsonl"


def emit_records(
    rows: Iterable[Mapping], fmt: str | None = None, stream: IO | None = None,
    columns: list[str] | None = None
) -> None:
    """Write records to ``stream`` (stdout) as JSON lines, a JSON array, a table or markdown.

    JSON lines are streamed one by one (a long sweep shows progress through a pipe); tables are
    collected first to align columns. Records of several kinds (their ``row`` key: a report's contrast,
    classes and inclusions) make one table per run of a kind, each with its own columns, unless
    ``columns`` are given.
    """
    stream = stream or sys.stdout
    fmt = resolve_format(fmt, stream)
    if fmt == "jsonl":
        for row in rows:
            stream.write(dumps(row) + "\n")
            stream.flush()
        return
    rows = list(rows)
    if fmt == "json":
        stream.write(json.dumps(to_jsonable(rows), allow_nan=False, indent=1) + "\n")
    elif rows:
        kinds = [list(run) for _kind, run in groupby(rows, key=lambda r: r.get("row"))]
        if columns is not None or len(kinds) == 1:
            kinds = [rows]
        stream.write("\n\n".join(format_table(run, columns, markdown=fmt == "markdown") for run in kinds)
                     + "\n")
    stream.flush()


def _parse_jsonl(lines: Iterable[str], path: str) -> list[dict]:
    rows = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError as exc:
            raise DataError(f"{path}: line {number} is not valid JSON ({exc.msg})") from None
    return rows


def read_jsonl(path: str, stream: IO | None = None) -> list[dict]:
    """Read JSON lines from ``path`` ('-' = stdin); blank lines are skipped, bad lines name their number."""
    if stream is not None:
        return _parse_jsonl(stream, path)
    if path == "-":
        return _parse_jsonl(sys.stdin, path)
    if not os.path.isfile(path):
        raise DataError(f"{path}: no such file")
    with open(path, encoding="utf-8") as fh:
        return _parse_jsonl(fh, path)
