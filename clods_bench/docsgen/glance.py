"""Committed markdown tables as the results pages show them: the Avg. columns at a glance, every column behind a toggle.

A table whose header names `... / Avg.` columns (Table 2's layout: per group the d_avg, d(t=end) and Avg. columns) is
shown with its label column, its Avg. columns and the columns of groups that have no Avg. (strain, times); the whole
table follows in a `<details>` block. A column of numbers is right-aligned (a text column, such as a divergence note,
stays left-aligned and wraps), and `mean ± std` never wraps (the spaces around `±` become non-breaking). The
numbers themselves are the committed file's, cell for cell.
"""

from __future__ import annotations

import re

NBSP = "\u00a0"
AVG = "Avg."
WRAPPER = "clods-table"
"""CSS class of the block around every results table (docs/stylesheets/results.css styles it)."""

_SPLIT = re.compile(r"(?<!\\)\|")
_NUMBER = r"[-+]?(?:\d[\d,]*(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?%?|nan|inf|-inf"
_NUMERIC = re.compile(rf"(?:{_NUMBER})(?:\s*±\s*(?:{_NUMBER}))?\S{{0,2}}", re.I)
"""A number, or `mean ± std`, with at most a footnote mark after it."""
_PLACEHOLDER = re.compile(r"|-|n/a|—|(?:diverged|unavailable|not run)\S{0,2}", re.I)
"""A cell that holds no number in a number column (an empty cell, a diverged row, LPIPS without its weights)."""


def split_row(line: str) -> list[str]:
    """The cells of one markdown table row (`| a | b |`), stripped; an escaped `\\|` stays inside its cell."""
    inner = line.strip()
    inner = inner[1:] if inner.startswith("|") else inner
    inner = inner[:-1] if inner.endswith("|") and not inner.endswith("\\|") else inner
    return [c.strip() for c in _SPLIT.split(inner)]


def is_table_line(line: str) -> bool:
    """A line of a markdown table (starts with `|`)."""
    return line.lstrip().startswith("|")


def _cell(text: str) -> str:
    """A number cell: `mean ± std` kept on one line."""
    return text.replace(" ± ", f"{NBSP}±{NBSP}")


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _group(header: str) -> str:
    return header.split(" / ")[0].strip() if " / " in header else ""


def glance_columns(header: list[str]) -> list[int] | None:
    """Indices of the columns shown at a glance, or None when the table has no Avg. columns (it is shown whole)."""
    avg_groups = {_group(h) for h in header[1:] if h.endswith(AVG) and _group(h)}
    if not avg_groups:
        return None
    keep = [0] + [i for i, h in enumerate(header) if i > 0 and (h.endswith(AVG) or _group(h) not in avg_groups)]
    return keep if len(keep) < len(header) else None


def numeric_columns(rows: list[list[str]]) -> set[int]:
    """Indices of the columns (past the label column) whose every filled cell is a number or `mean ± std`."""
    out = set()
    for i in range(1, max((len(r) for r in rows), default=0)):
        cells = [r[i].strip() for r in rows if i < len(r) and not _PLACEHOLDER.fullmatch(r[i].strip())]
        if cells and all(_NUMERIC.fullmatch(c) for c in cells):
            out.add(i)
    return out


def _render(header: list[str], rows: list[list[str]], columns: list[int]) -> list[str]:
    numbers = numeric_columns(rows)
    lines = [_row([header[i] for i in columns]), _row(["---:" if i in numbers else ":---" for i in columns])]
    lines += [_row([r[i] if i == 0 else _cell(r[i]) for i in columns]) for r in rows]
    return lines


def glance_table(table_lines: list[str]) -> list[str]:
    """Markdown of one committed table as a results page shows it (see the module's docstring)."""
    rows = [split_row(line) for line in table_lines if line.strip()]
    if len(rows) < 2:
        return [f'<div class="{WRAPPER}" markdown>', "", *table_lines, "", "</div>"]
    header, body = rows[0], [r + [""] * (len(rows[0]) - len(r)) for r in rows[2:]]
    every = list(range(len(header)))
    columns = glance_columns(header)
    out = [f'<div class="{WRAPPER}" markdown>', ""]
    if columns is None:
        out += _render(header, body, every)
    else:
        out += _render(header, body, columns)
        out += ["", f'<details class="{WRAPPER}-all" markdown>', f"<summary>All {len(header) - 1} columns</summary>", ""]
        out += _render(header, body, every)
        out += ["", "</details>"]
    return out + ["", "</div>"]


def glance(lines: list[str]) -> list[str]:
    """`lines` of markdown with every table replaced by its at-a-glance form; other lines unchanged."""
    out: list[str] = []
    i = 0
    while i < len(lines):
        if not is_table_line(lines[i]):
            out.append(lines[i])
            i += 1
            continue
        j = i
        while j < len(lines) and is_table_line(lines[j]):
            j += 1
        out += glance_table(lines[i:j])
        i = j
    return out
