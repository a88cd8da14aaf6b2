"""Regression check of result tables: fresh CSVs against committed ones, error metrics within a tolerance.

The tolerance file (`tolerance.yaml` next to the committed tables) says, per table, row
and column pattern, how far a number may move: |fresh - committed| <= abs + rel * |committed|.
Timing columns are excluded by pattern. Text columns (method, scene, reason) must match
exactly; a NaN must stay NaN ('diverged' stays diverged). `seed_spread` measures the
seed-to-seed variation of run records, the evidence the tolerance is justified by.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from clods_bench.benchmark.core.config import read_yaml
from clods_bench.benchmark.running.records import iter_records
from clods_bench.errors import ClodsError
from clods_bench.typed_config import dataclass_from_dict

TOLERANCE_FILE = "tolerance.yaml"
KEY_COLUMNS = ("method", "scene")


@dataclass
class Tolerance:
    """How far one number may move: |fresh - committed| <= abs + rel * |committed|."""

    rel: float = 0.0
    """Relative part (fraction of the committed value)."""
    abs: float = 0.0
    """Absolute part (units of the column)."""

    def allows(self, committed: float, fresh: float) -> bool:
        """True when `fresh` is within tolerance of `committed` (NaN only matches NaN)."""
        if math.isnan(committed) or math.isnan(fresh):
            return math.isnan(committed) and math.isnan(fresh)
        if math.isinf(committed) or math.isinf(fresh):
            return committed == fresh
        return abs(fresh - committed) <= self.abs + self.rel * abs(committed)


@dataclass
class ToleranceRule:
    """A tolerance for the cells whose table file, row label and column match these fnmatch patterns."""

    rel: float = 0.0
    """Relative part (fraction of the committed value)."""
    abs: float = 0.0
    """Absolute part (units of the column)."""
    table: str = "*"
    """Pattern of the CSV file name, e.g. 'table2_cdg.csv'."""
    row: str = "*"
    """Pattern of the row label (the 'method' column), e.g. 'MGN*'."""
    column: str = "*"
    """Pattern of the column name, e.g. '*/std'."""
    skip: bool = False
    """Do not compare the matched cells at all (e.g. a learned rollout's divergence frame and reason, which a
    different float rounding can move or remove); every use must say why."""
    why: str = ""
    """One line: what this rule covers and why its numbers."""

    def matches(self, table: str, row: str, column: str) -> bool:
        return all(fnmatch.fnmatchcase(v, p) for v, p in ((table, self.table), (row, self.row), (column, self.column)))


@dataclass
class ToleranceSpec:
    """The tolerance file: rules (first match wins), a default, excluded columns, and the justification."""

    default: Tolerance = field(default_factory=Tolerance)
    """Tolerance of every compared cell no rule matches."""
    rules: list[ToleranceRule] = field(default_factory=list)
    """Per table/row/column tolerances, first match wins."""
    exclude: list[str] = field(default_factory=list)
    """fnmatch patterns of columns never compared (timings)."""
    justification: str = ""
    """Why these numbers: the measured seed-to-seed variation (`clods-bench seed-spread`)."""

    def for_cell(self, table: str, row: str, column: str) -> Tolerance | None:
        """The tolerance of one cell, or None when its column is excluded or its first matching rule skips it."""
        if any(fnmatch.fnmatchcase(column, p) for p in self.exclude):
            return None
        for rule in self.rules:
            if rule.matches(table, row, column):
                return None if rule.skip else Tolerance(rel=rule.rel, abs=rule.abs)
        return self.default


def load_tolerance(path: Path) -> ToleranceSpec:
    """Read a tolerance YAML file into a `ToleranceSpec` (unknown keys fail)."""
    spec: ToleranceSpec = dataclass_from_dict(ToleranceSpec, read_yaml(Path(path)), where=str(path))
    for name, tol in [("default", spec.default), *((f"rules[{i}]", r) for i, r in enumerate(spec.rules))]:
        if tol.rel < 0 or tol.abs < 0:
            raise ClodsError(f"tolerance must be >= 0, got rel={tol.rel}, abs={tol.abs}", where=f"{path}: {name}")
    return spec


def _row_key(row: pd.Series, keys: list[str]) -> str:
    return " / ".join(str(row[k]) for k in keys)


def compare_tables(committed: Path, fresh: Path, spec: ToleranceSpec) -> list[str]:
    """Every difference between two CSV tables beyond tolerance, as 'file: row: column: old -> new' lines."""
    name = Path(committed).name
    a = pd.read_csv(committed)
    b = pd.read_csv(fresh)
    problems: list[str] = []
    keys = [k for k in KEY_COLUMNS if k in a.columns]
    if not keys:
        return [f"{name}: no key column ({', '.join(KEY_COLUMNS)}) to match rows by"]
    missing_cols = [c for c in a.columns if c not in b.columns]
    extra_cols = [c for c in b.columns if c not in a.columns]
    problems += [f"{name}: column '{c}' missing from the fresh table" for c in missing_cols]
    problems += [f"{name}: column '{c}' is new (not in the committed table)" for c in extra_cols if spec.for_cell(name, "*", c) is not None]
    rows_a = {_row_key(r, keys): r for _, r in a.iterrows()}
    rows_b = {_row_key(r, [k for k in keys if k in b.columns]): r for _, r in b.iterrows()}
    problems += [f"{name}: row '{k}' missing from the fresh table" for k in rows_a if k not in rows_b]
    problems += [f"{name}: row '{k}' is new (not in the committed table)" for k in rows_b if k not in rows_a]
    for key, ra in rows_a.items():
        rb = rows_b.get(key)
        if rb is None:
            continue
        for col in a.columns:
            if col in keys or col not in b.columns:
                continue
            tol = spec.for_cell(name, str(ra[keys[0]]), col)
            if tol is None:
                continue
            old, new = ra[col], rb[col]
            old_num, new_num = _as_float(old), _as_float(new)
            if old_num is None or new_num is None:  # text (or empty) cells must match exactly
                if _text(old) != _text(new):
                    problems.append(f"{name}: {key}: {col}: {_text(old)!r} -> {_text(new)!r}")
            elif not tol.allows(old_num, new_num):
                allowed = tol.abs + tol.rel * abs(old_num) if math.isfinite(old_num) else 0.0
                problems.append(f"{name}: {key}: {col}: {old_num:.6g} -> {new_num:.6g} (moved {abs(new_num - old_num):.3g}, allowed {allowed:.3g})")
    return problems


def compare_dirs(
    committed: Path, fresh: Path, tolerance: Path | None = None, skip_columns: Sequence[str] = (), skip_tables: Sequence[str] = ()
) -> list[str]:
    """Compare every CSV of `committed` with the same file in `fresh` (tolerance file default: `committed/tolerance.yaml`).

    `skip_columns`: fnmatch patterns of columns left out on top of the tolerance file's `exclude` (e.g. the std
    columns when the fresh tables were made from fewer seeds). `skip_tables`: table ids (CSV stems) not compared,
    e.g. those a time-boxed `reproduce` did not finish (a stale file of that name in `fresh` is ignored too).
    """
    committed, fresh = Path(committed), Path(fresh)
    if not committed.is_dir():
        raise ClodsError("committed results folder not found", where=str(committed))
    if not fresh.is_dir():
        raise ClodsError("fresh results folder not found", where=str(fresh))
    tol_path = Path(tolerance) if tolerance is not None else committed / TOLERANCE_FILE
    spec = load_tolerance(tol_path)
    spec.exclude = [*spec.exclude, *skip_columns]
    csvs = sorted(committed.glob("*.csv"))
    if not csvs:
        raise ClodsError("no CSV tables to compare against", where=str(committed))
    problems: list[str] = []
    for path in csvs:
        if path.stem in skip_tables:
            continue
        other = fresh / path.name
        if not other.is_file():
            problems.append(f"{path.name}: not produced (missing from {fresh})")
            continue
        problems += compare_tables(path, other, spec)
    return problems


def _as_float(value: Any) -> float | None:
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        return float(value)
    return None


def _text(value: Any) -> str:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


# ---------------------------------------------------------------- seed-to-seed variation


def seed_spread(runs_dir: Path, task: str | None = None) -> pd.DataFrame:
    """Per record and metric with >= 2 seeds: mean, std, std/|mean| and max |x_seed - mean| / |mean| over seeds.

    Timings are left out (they are not compared). Deterministic baselines show 0.
    """
    rows = []
    for rdir, rec in iter_records(Path(runs_dir), task):
        per_seed = rec.get("per_seed", {})
        if len(per_seed) < 2:
            continue
        for key in sorted(rec.get("metrics", {})):
            values = np.array([_nan(s["metrics"].get(key)) for s in per_seed.values()], np.float64)
            if not np.all(np.isfinite(values)):
                continue
            mean = float(values.mean())
            std = float(values.std(ddof=1))
            scale = abs(mean) if mean != 0 else float("nan")
            rows.append(
                {
                    "task": rec["task"],
                    "label": rec["label"],
                    "preset": rec["preset"],
                    "metric": key,
                    "seeds": len(values),
                    "mean": mean,
                    "std": std,
                    "rel_std": std / scale,
                    "max_rel_dev": float(np.max(np.abs(values - mean))) / scale,
                    "record": str(rdir),
                }
            )
    return pd.DataFrame(rows, columns=["task", "label", "preset", "metric", "seeds", "mean", "std", "rel_std", "max_rel_dev", "record"])


def _nan(value: Any) -> float:
    return float("nan") if value is None else float(value)
