"""A claims file (`docs/claims.yaml`) checked against the reproduce plan before any job runs.

Each claim on a plan table must name a table of the plan, rows the plan makes in it and column groups the file
defines: `reproduce --dry-run` reports the first that does not, with the claim's line. The docs' claims page reads
the same file (`clods_bench.docsgen.claims`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from clods_bench.benchmark.outputs.claim_rules import Columns, rule_columns
from clods_bench.benchmark.outputs.table_sources import as_list, load_yaml, where
from clods_bench.benchmark.outputs.table_sources import field as required
from clods_bench.errors import ClodsError


def column_groups(spec: dict[str, Any], path: Path) -> dict[str, Columns]:
    """The `columns` section of a claims file: named column groups with the direction that is better."""
    out = {}
    for name, entry in spec.items():
        if name.startswith("__"):
            continue
        better = required(entry, "better", path)
        if better not in ("lower", "higher"):
            raise ClodsError(f"columns '{name}': better must be lower or higher, got {better!r}", where=where(path, entry))
        out[name] = Columns(name, required(entry, "label", path), tuple(required(entry, "columns", path, list)), better == "higher")
    return out


def rule_rows(rule: dict[str, Any]) -> list[str]:
    """Every row label a rule reads."""
    if "all" in rule:
        return [r for sub in rule["all"] for r in rule_rows(sub)]
    out: list[str] = []
    for kind, spec in rule.items():
        if kind.startswith("__") or not isinstance(spec, dict):
            continue
        for key in ("row", "of", "than", "rows"):
            out += [str(v) for v in as_list(spec.get(key, []))]
    return out


def check_claims_against_plan(path: Path, labels: dict[str, set[str]]) -> None:
    """Every claim on a plan table names a table of the plan, rows the plan makes in it and column groups the file
    defines; else one ClodsError naming the claim's line. `labels`: table id -> the row labels the plan gives it."""
    doc = load_yaml(path)
    columns = column_groups(required(doc, "columns", path, dict), path)
    for entry in required(doc, "claims", path, list):
        if "sources" in entry:
            continue
        table = required(entry, "table", path)
        if table not in labels:
            raise ClodsError(f"claim '{entry.get('id')}': table '{table}' is not a table of the plan (tables: {', '.join(labels)})",
                             where=where(path, entry))  # fmt: skip
        rule = required(entry, "rule", path, dict)
        unknown = [c for c in rule_columns(rule) if c not in columns]
        if unknown:
            raise ClodsError(f"claim '{entry.get('id')}': unknown column group {', '.join(unknown)}; known: {', '.join(columns)}", where=where(path, entry))
        missing = [r for r in dict.fromkeys(rule_rows(rule)) if r not in labels[table]]
        if missing:
            raise ClodsError(f"claim '{entry.get('id')}': the plan makes no row {', '.join(repr(m) for m in missing)} in table '{table}'",
                             where=where(path, entry), hint=f"its rows: {', '.join(sorted(labels[table]))}")  # fmt: skip
