"""Reading the docs' data files: YAML that remembers line numbers, and the committed CSV tables.

Every error names the file and line it comes from (`docs/claims.yaml:42: ...`), so a stale entry is found at once.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Sequence

import yaml

from clods_bench.errors import ClodsError

LINE = "__line__"
"""Key under which `load_yaml` stores a mapping's 1-based line number."""


class _LineLoader(yaml.SafeLoader):
    """A safe loader whose mappings carry the line they start on."""


def _mapping_with_line(loader: _LineLoader, node: yaml.MappingNode) -> dict[str, Any]:
    mapping = loader.construct_mapping(node, deep=True)
    mapping[LINE] = node.start_mark.line + 1
    return mapping


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping_with_line)


def load_yaml(path: Path) -> Any:
    """The YAML document at `path`, each mapping with its line under `LINE`; a missing or malformed file is one error."""
    try:
        return yaml.load(path.read_text(), Loader=_LineLoader)  # noqa: S506 - a SafeLoader subclass
    except OSError as exc:
        raise ClodsError(f"cannot read: {exc.strerror}", where=str(path)) from None
    except yaml.YAMLError as exc:
        raise ClodsError(f"not valid YAML: {exc}", where=str(path)) from None


def where(path: Path, entry: Any) -> str:
    """'path:line' of a mapping read by `load_yaml` (the path alone when it has no line)."""
    line = entry.get(LINE) if isinstance(entry, dict) else None
    return f"{path}:{line}" if line else str(path)


def field(entry: dict[str, Any], key: str, path: Path, kind: type | tuple[type, ...] = str) -> Any:
    """`entry[key]`, which must exist and be of `kind`; else one error naming the file, line and field."""
    if key not in entry:
        raise ClodsError(f"missing field '{key}'", where=where(path, entry))
    value = entry[key]
    if not isinstance(value, kind):
        names = " or ".join(k.__name__ for k in (kind if isinstance(kind, tuple) else (kind,)))
        raise ClodsError(f"field '{key}' must be {names}, got {value!r}", where=where(path, entry))
    return value


def as_list(value: Any) -> list[Any]:
    """A scalar as a one-item list; a list unchanged."""
    return list(value) if isinstance(value, (list, tuple)) else [value]


class CsvTable:
    """A committed results table: its rows by label (the first column, or `key` columns joined with '/')."""

    def __init__(self, paths: Sequence[Path], key: Sequence[str] = (), aliases: dict[str, str] | None = None) -> None:
        self.paths = list(paths)
        self.rows: dict[str, dict[str, str]] = {}
        for path in self.paths:
            with path.open(newline="") as fh:
                reader = csv.DictReader(fh)
                names = list(reader.fieldnames or [])
                for row in reader:
                    label = "/".join(row[k] for k in key) if key else row[names[0]]
                    self.rows.setdefault(label, row)
        for canonical, label in (aliases or {}).items():
            if label in self.rows and canonical not in self.rows:
                self.rows[canonical] = self.rows[label]

    def value(self, row: str, column: str) -> float:
        """The number in `row`, `column`: NaN for an empty cell or a text cell ('diverged')."""
        cell = self.rows[row].get(column)
        if cell is None:
            raise KeyError(column)
        try:
            return float(cell)
        except ValueError:
            return float("nan")

    def seeds(self, rows: Sequence[str]) -> int | None:
        """The smallest seed count among `rows`, when the table records one."""
        counts = [int(float(self.rows[r]["seeds"])) for r in rows if self.rows[r].get("seeds") not in (None, "")]
        return min(counts) if counts else None
