"""The page "The paper's claims here": each claim of `docs/claims.yaml` decided on the committed tables, per size."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clods_bench.docsgen.claim_rules import Columns, MissingRows, Verdict, evaluate, rule_columns
from clods_bench.docsgen.sources import CsvTable, as_list, load_yaml, where
from clods_bench.docsgen.sources import field as required
from clods_bench.errors import ClodsError

CLAIMS_FILE = Path("docs/claims.yaml")
HOLDS, FAILS, NOT_RUN = "holds", "does not hold", "not run"


@dataclass
class Outcome:
    """One claim at one size: the verdict and the numbers it was decided on."""

    size: str
    kind: str
    status: str
    ours: str
    seeds: int | None = None
    files: list[Path] = field(default_factory=list)


@dataclass
class Claim:
    """A claim of the paper with its outcome at every size it is evaluated at."""

    id: str
    title: str
    claim: str
    where: str
    paper: str
    rule_text: str
    outcomes: list[Outcome]


def _columns(spec: dict[str, Any], path: Path) -> dict[str, Columns]:
    out = {}
    for name, entry in spec.items():
        if name.startswith("__"):
            continue
        better = required(entry, "better", path)
        if better not in ("lower", "higher"):
            raise ClodsError(f"columns '{name}': better must be lower or higher, got {better!r}", where=where(path, entry))
        out[name] = Columns(name, required(entry, "label", path), tuple(required(entry, "columns", path, list)), better == "higher")
    return out


def _fmt(x: float) -> str:
    return "n/a" if x != x else f"{x:.4g}"


def _ours(table: CsvTable, verdict: Verdict, groups: list[Columns]) -> str:
    parts = []
    for cols in groups:
        values = "; ".join(f"{row} {' / '.join(_fmt(table.value(row, c)) for c in cols.columns)}" for row in verdict.rows
                           if all(c in table.rows[row] for c in cols.columns))  # fmt: skip
        parts.append(f"{cols.label}: {values}")
    return "<br>".join(parts) + f"<br>({verdict.passed} of {verdict.total} comparisons hold)"


def rule_text(rule: dict[str, Any], columns: dict[str, Columns]) -> str:
    """The rule in words."""
    if "all" in rule:
        return "; and ".join(rule_text(sub, columns) for sub in rule["all"])
    (kind, spec), = [(k, v) for k, v in rule.items() if not k.startswith("__")]
    cols = columns[spec["columns"]]
    better = "higher" if cols.higher_is_better else "lower"
    if kind == "better":
        by = f" by a factor {spec['by']}" if float(spec.get("by", 1.0)) != 1.0 else ""
        return f"{spec['row']} is {better}{by} than {', '.join(as_list(spec['than']))} in every column of {cols.label}"
    if kind == "within":
        return f"{', '.join(as_list(spec['rows']))} within {spec['factor']}x of {spec['of']} in every column of {cols.label}"
    return f"{' > '.join(as_list(spec['rows']))} (best first) in every column of {cols.label}"


def _sources(claim: dict[str, Any], sizes: dict[str, Any], root: Path, path: Path) -> list[tuple[str, str, list[Path], bool, dict]]:
    """(size label, kind, files, partial, aliases) for every size the claim is evaluated at."""
    if "sources" in claim:
        return [(label, "measurement", [root / f for f in as_list(files)], False, {})
                for label, files in claim["sources"].items() if not label.startswith("__")]  # fmt: skip
    table = required(claim, "table", path)
    out = []
    for name in as_list(claim.get("sizes", [s for s in sizes if not s.startswith("__")])):
        if name not in sizes:
            raise ClodsError(f"unknown size '{name}'; known: {', '.join(s for s in sizes if not s.startswith('__'))}", where=where(path, claim))
        size = sizes[name]
        files = (size.get("files") or {}).get(table, size["file"].format(table=table))
        aliases = (size.get("aliases") or {}).get(table, {})
        out.append((size["label"], size["kind"], [root / size["folder"] / f for f in as_list(files)], bool(size.get("partial")), aliases))
    return out


def evaluate_claims(root: Path, claims_file: Path | None = None) -> list[Claim]:
    """Every claim of the claims file (relative to `root`) decided on the tables under `root`."""
    path = root / (claims_file or CLAIMS_FILE)
    doc = load_yaml(path)
    if not isinstance(doc, dict):
        raise ClodsError("expected a mapping with sizes, columns and claims", where=str(path))
    sizes, columns = required(doc, "sizes", path, dict), _columns(required(doc, "columns", path, dict), path)
    out = []
    for entry in required(doc, "claims", path, list):
        rule = required(entry, "rule", path, dict)
        try:
            groups = [columns[name] for name in rule_columns(rule)]
            text = rule_text(rule, columns)
        except KeyError as exc:
            raise ClodsError(f"unknown column group {exc}; known: {', '.join(columns)}", where=where(path, entry)) from None
        outcomes = []
        for label, kind, files, partial, aliases in _sources(entry, sizes, root, path):
            present = [f for f in files if f.is_file()]
            if len(present) < len(files):
                gone = ", ".join(str(f.relative_to(root)) for f in files if not f.is_file())
                if not partial:
                    raise ClodsError(f"claim '{entry.get('id')}': table file {gone} is missing", where=where(path, entry))
                if not present:
                    outcomes.append(Outcome(label, kind, NOT_RUN, "table not made at this size"))
                    continue
            table = CsvTable(present, as_list(entry.get("key", [])), aliases)
            try:
                verdict = evaluate(rule, table, lambda name: columns[name])
            except MissingRows as exc:
                if not partial:
                    raise ClodsError(f"claim '{entry.get('id')}': {', '.join(str(p.relative_to(root)) for p in present)} has no "
                                     f"{', '.join(exc.missing)}", where=where(path, entry)) from None  # fmt: skip
                outcomes.append(Outcome(label, kind, NOT_RUN, f"rows not run at this size: {', '.join(exc.missing)}", files=present))
                continue
            except ValueError as exc:
                raise ClodsError(f"claim '{entry.get('id')}': {exc}", where=where(path, entry)) from None
            status = HOLDS if verdict.holds else FAILS
            outcomes.append(Outcome(label, kind, status, _ours(table, verdict, groups), table.seeds(verdict.rows), present))
        out.append(Claim(required(entry, "id", path), required(entry, "title", path), required(entry, "claim", path),
                         required(entry, "where", path), required(entry, "paper", path), text, outcomes))  # fmt: skip
    return out
