"""The page "The paper's claims here": each claim of `docs/claims.yaml` decided on the committed tables, per size."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from clods_bench.benchmark.outputs.claim_rules import Columns, MissingRows, Verdict, evaluate, rule_columns
from clods_bench.benchmark.outputs.claims_check import column_groups
from clods_bench.benchmark.outputs.table_sources import CsvTable, as_list, load_yaml, where
from clods_bench.benchmark.outputs.table_sources import field as required
from clods_bench.errors import ClodsError

CLAIMS_FILE = Path("docs/claims.yaml")
HOLDS, FAILS, NOT_RUN, NOISE = "holds", "does not hold", "not run", "within noise"
FIXTURE = "regression fixture"  # a size of this kind is listed after the evidence, apart from it


@dataclass(frozen=True)
class NoiseBand:
    """How far a one-seed number moves between fits on this benchmark, for the column groups it applies to."""

    value: float
    groups: tuple[str, ...]
    what: str


@dataclass
class Outcome:
    """One claim at one size: the verdict and the numbers it was decided on."""

    size: str
    kind: str
    status: str
    ours: str
    seeds: int | None = None
    files: list[Path] = field(default_factory=list)
    counted: bool = True
    """False where the paper scores another quantity: the outcome supports the claim but is not counted."""
    noise: str = ""
    """The noise band a one-seed verdict was read with, in words (empty: none applied)."""


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


def _noise(size: dict[str, Any], columns: dict[str, Columns], path: Path) -> NoiseBand | None:
    entry = size.get("noise")
    if entry is None:
        return None
    groups = tuple(required(entry, "columns", path, list))
    unknown = [g for g in groups if g not in columns]
    if unknown:
        raise ClodsError(f"noise: unknown column group(s) {', '.join(unknown)}; known: {', '.join(columns)}", where=where(path, entry))
    value = float(required(entry, "value", path, (int, float)))
    if not value >= 0:
        raise ClodsError(f"noise: value must be >= 0, got {value!r}", where=where(path, entry))
    return NoiseBand(value, groups, required(entry, "what", path))


def status_of(verdict: Verdict, seeds: int | None, band: NoiseBand | None) -> str:
    """holds / does not hold; a one-seed verdict with a noise band reads 'within noise' when some comparison's
    margin lies inside the band and none fails by more than it."""
    if band is None or seeds != 1:
        return HOLDS if verdict.holds else FAILS
    inside = False
    for group, margin in verdict.margins:
        banded = group in band.groups
        if margin <= 0 and not (banded and margin >= -band.value):
            return FAILS
        inside = inside or (banded and abs(margin) <= band.value)
    return NOISE if inside else HOLDS


def _sources(claim: dict[str, Any], sizes: dict[str, Any], root: Path, path: Path) -> list[tuple[str, str, list[Path], bool, dict, Any]]:
    """(size label, kind, files, partial, aliases, size spec) for every size the claim is evaluated at, the evidence
    first and a regression fixture last."""
    if "sources" in claim:
        return [(label, "measurement", [root / f for f in as_list(files)], False, {}, {})
                for label, files in claim["sources"].items() if not label.startswith("__")]  # fmt: skip
    table = required(claim, "table", path)
    out = []
    for name in as_list(claim.get("sizes", [s for s in sizes if not s.startswith("__")])):
        if name not in sizes:
            raise ClodsError(f"unknown size '{name}'; known: {', '.join(s for s in sizes if not s.startswith('__'))}", where=where(path, claim))
        size = sizes[name]
        files = (size.get("files") or {}).get(table, size["file"].format(table=table))
        aliases = (size.get("aliases") or {}).get(table, {})
        out.append((size["label"], size["kind"], [root / size["folder"] / f for f in as_list(files)], bool(size.get("partial")), aliases, size))
    return sorted(out, key=lambda source: source[1] == FIXTURE)


def evaluate_claims(root: Path, claims_file: Path | None = None) -> list[Claim]:
    """Every claim of the claims file (relative to `root`) decided on the tables under `root`."""
    path = root / (claims_file or CLAIMS_FILE)
    doc = load_yaml(path)
    if not isinstance(doc, dict):
        raise ClodsError("expected a mapping with sizes, columns and claims", where=str(path))
    sizes, columns = required(doc, "sizes", path, dict), column_groups(required(doc, "columns", path, dict), path)
    out = []
    for entry in required(doc, "claims", path, list):
        rule = required(entry, "rule", path, dict)
        try:
            groups = [columns[name] for name in rule_columns(rule)]
            text = rule_text(rule, columns)
        except KeyError as exc:
            raise ClodsError(f"unknown column group {exc}; known: {', '.join(columns)}", where=where(path, entry)) from None
        outcomes = []
        counted = entry.get("counts", True)
        if not isinstance(counted, bool):
            raise ClodsError(f"counts must be true or false, got {counted!r}", where=where(path, entry))
        for label, kind, files, partial, aliases, size in _sources(entry, sizes, root, path):
            band = _noise(size, columns, path)
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
            seeds = table.seeds(verdict.rows)
            status = status_of(verdict, seeds, band)
            banded = band is not None and seeds == 1 and any(g.name in band.groups for g in groups)
            noise = f"one seed: within {band.value:g} counts as noise ({band.what})" if banded else ""
            outcomes.append(Outcome(label, kind, status, _ours(table, verdict, groups), seeds, present, counted, noise))
        out.append(Claim(required(entry, "id", path), required(entry, "title", path), required(entry, "claim", path),
                         required(entry, "where", path), required(entry, "paper", path), text, outcomes))  # fmt: skip
    return out

