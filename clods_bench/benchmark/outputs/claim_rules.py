"""The rules of `docs/claims.yaml`, evaluated on one results table: does a claim of the paper hold in our numbers?

Each rule compares rows of one table on a named group of columns (`better`, `within`, `order`, `all`; the file's
header defines them). A comparison with a NaN (a diverged rollout) does not hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

from clods_bench.benchmark.outputs.table_sources import CsvTable, as_list


@dataclass(frozen=True)
class Columns:
    """A named group of CSV columns and which direction is better."""

    name: str
    label: str
    columns: tuple[str, ...]
    higher_is_better: bool


@dataclass
class Verdict:
    """The outcome of a rule on one table: holds, how many comparisons held, the rows it read, and each
    comparison's margin (column group, by how much it holds: positive when it holds, in the columns' units;
    -inf when a value is NaN)."""

    holds: bool
    passed: int
    total: int
    rows: list[str]
    missing: list[str]
    margins: list[tuple[str, float]] = field(default_factory=list)


class MissingRows(Exception):
    """Rows (or columns) a rule needs that the table lacks."""

    def __init__(self, missing: list[str]) -> None:
        super().__init__(", ".join(missing))
        self.missing = missing


def _values(table: CsvTable, row: str, cols: Columns) -> list[float]:
    if row not in table.rows:
        raise MissingRows([row])
    try:
        return [table.value(row, c) for c in cols.columns]
    except KeyError as exc:
        raise MissingRows([f"column {exc.args[0]}"]) from None


def _beats(a: float, b: float, higher: bool, by: float = 1.0) -> bool:
    """a is better than b (by the factor `by`); False when either is NaN."""
    return _margin(a, b, higher, by) > 0


def _margin(a: float, b: float, higher: bool, by: float = 1.0) -> float:
    """By how much a beats b (by the factor `by`), in the values' units: positive when it does; -inf with a NaN."""
    if math.isnan(a) or math.isnan(b):
        return -math.inf
    return a - b * by if higher else b - a * by


def rule_better(table: CsvTable, spec: dict[str, Any], columns: Callable[[str], Columns]) -> Verdict:
    """`row` beats every row of `than` on every column (by the factor `by`)."""
    cols, by = columns(spec["columns"]), float(spec.get("by", 1.0))
    others = as_list(spec["than"])
    rows = [spec["row"], *others]
    missing = [r for r in rows if r not in table.rows]
    if missing:
        raise MissingRows(missing)
    mine = _values(table, spec["row"], cols)
    margins = [_margin(m, o, cols.higher_is_better, by) for other in others for m, o in zip(mine, _values(table, other, cols))]
    return _verdict(margins, rows, cols)


def _verdict(margins: list[float], rows: list[str], cols: Columns) -> Verdict:
    checks = [m > 0 for m in margins]
    return Verdict(all(checks), sum(checks), len(checks), rows, [], [(cols.name, m) for m in margins])


def rule_within(table: CsvTable, spec: dict[str, Any], columns: Callable[[str], Columns]) -> Verdict:
    """Each of `rows` is at most `factor` times `of` (lower is better) or at least 1/factor times it (higher)."""
    cols, factor = columns(spec["columns"]), float(spec["factor"])
    subjects = as_list(spec["rows"])
    rows = [*subjects, spec["of"]]
    missing = [r for r in rows if r not in table.rows]
    if missing:
        raise MissingRows(missing)
    ref = _values(table, spec["of"], cols)
    margins = []
    for row in subjects:
        for v, r in zip(_values(table, row, cols), ref):
            if math.isnan(v) or math.isnan(r):
                margins.append(-math.inf)
            else:  # holding at the boundary counts: the smallest positive margin stands for 0
                m = v * factor - r if cols.higher_is_better else r * factor - v
                margins.append(m if m != 0 else math.ulp(0.0))
    return _verdict(margins, rows, cols)


def rule_order(table: CsvTable, spec: dict[str, Any], columns: Callable[[str], Columns]) -> Verdict:
    """`rows`, listed best first, are strictly in that order on every column."""
    cols = columns(spec["columns"])
    rows = as_list(spec["rows"])
    missing = [r for r in rows if r not in table.rows]
    if missing:
        raise MissingRows(missing)
    values = [_values(table, r, cols) for r in rows]
    margins = [_margin(a[i], b[i], cols.higher_is_better) for a, b in zip(values, values[1:]) for i in range(len(cols.columns))]
    return _verdict(margins, rows, cols)


RULES: dict[str, Callable[[CsvTable, dict[str, Any], Callable[[str], Columns]], Verdict]] = {
    "better": rule_better,
    "within": rule_within,
    "order": rule_order,
}


def evaluate(rule: dict[str, Any], table: CsvTable, columns: Callable[[str], Columns]) -> Verdict:
    """Evaluate a rule mapping ({kind: spec}, or {all: [rules]}); rows missing from the table raise MissingRows."""
    kinds = [k for k in rule if not k.startswith("__")]
    if len(kinds) != 1:
        raise ValueError(f"a rule has exactly one of {', '.join([*RULES, 'all'])}; got {', '.join(kinds) or 'none'}")
    kind = kinds[0]
    if kind == "all":
        parts, missing = [], []
        for sub in rule["all"]:
            try:
                parts.append(evaluate(sub, table, columns))
            except MissingRows as exc:
                missing += exc.missing
        if missing:
            raise MissingRows(sorted(set(missing)))
        rows = list(dict.fromkeys(r for p in parts for r in p.rows))
        margins = [m for p in parts for m in p.margins]
        return Verdict(all(p.holds for p in parts), sum(p.passed for p in parts), sum(p.total for p in parts), rows, [], margins)
    if kind not in RULES:
        raise ValueError(f"unknown rule '{kind}'; known: {', '.join([*RULES, 'all'])}")
    return RULES[kind](table, rule[kind], columns)


def rule_columns(rule: dict[str, Any]) -> list[str]:
    """The column-group names a rule reads, in order of first use."""
    if "all" in rule:
        return list(dict.fromkeys(c for sub in rule["all"] for c in rule_columns(sub)))
    return [spec["columns"] for kind, spec in rule.items() if not kind.startswith("__")]
