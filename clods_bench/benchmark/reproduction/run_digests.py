"""`digests.json`: every plan row's exact per-seed numbers and stage digests, and the comparison that names where two
runs part.

`reproduce` writes one beside its tables: per row (run once, rows sharing a run point to it) its record key (the
digest of its resolved config), and per seed the stage digests (`stage_digests`) and the metrics. Comparing a fresh
file with a committed one names, for each row that moved, the first stage that differs (data, renderer fit,
extraction, fit, rollout, score) and the metrics that moved; a row whose record key changed was run with another
config. Files of another format, or made under other numeric paths (host paths against deterministic mode, other
pins, another thread count), cannot match bit for bit: they are refused with one line.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any, Iterable, Mapping

from clods_bench import __version__
from clods_bench.atomic import write_json
from clods_bench.benchmark.core.stage_digests import STAGES
from clods_bench.errors import ClodsError
from clods_bench.numerics import cpu_model

DIGESTS_FILE = "digests.json"
DIGESTS_FORMAT = 1


def numerics_key(numerics: Mapping[str, Any] | None) -> dict[str, Any]:
    """The part of a record's `numerics` that decides its bits: mode, pins version, threads (not the CPU)."""
    n = dict(numerics or {})
    return {k: n.get(k) for k in ("mode", "pins_version", "threads")}


def row_entry(table: str, label: str, record_key: str, record: Mapping[str, Any] | None, same_as: str | None) -> dict[str, Any]:
    """One row of the file: its table, label and record key, and (for the row that ran) each seed's stages and metrics."""
    entry: dict[str, Any] = {"table": table, "label": label, "record": record_key}
    if same_as is not None:
        entry["same_as"] = same_as
        return entry
    seeds = {}
    for seed, result in sorted((record or {}).get("per_seed", {}).items(), key=lambda kv: int(kv[0])):
        seeds[str(seed)] = {"stages": dict(result.get("extra", {}).get("stage_digests", {})), "metrics": dict(result.get("metrics", {}))}
    entry["seeds"] = seeds
    return entry


def build(preset: str, rows: dict[str, dict[str, Any]], numerics: Mapping[str, Any]) -> dict[str, Any]:
    """The whole file: format, version, preset, numeric paths, where and when it was made, the rows in plan order."""
    return {
        "format": DIGESTS_FORMAT,
        "clods_bench": __version__,
        "preset": preset,
        "numerics": numerics_key(numerics),
        "made_on": {"cpu": cpu_model(), "date": time.strftime("%Y-%m-%d")},
        "rows": rows,
    }


def write(path: Path, digests: dict[str, Any], merge_into_existing: bool = False) -> None:
    """Write `digests` atomically; with `merge_into_existing`, rows of a readable file of the same preset and numerics
    that `digests` does not hold are kept (a `reproduce --only` that regenerates some tables)."""
    if merge_into_existing and Path(path).is_file():
        try:
            old = load(path)
        except ClodsError:
            old = None
        if old is not None and old.get("preset") == digests["preset"] and old.get("numerics") == digests["numerics"]:
            tables = {r["table"] for r in digests["rows"].values()}
            kept = {k: v for k, v in old["rows"].items() if v.get("table") not in tables}
            digests = {**digests, "rows": {**kept, **digests["rows"]}}
    write_json(Path(path), digests)


def load(path: Path) -> dict[str, Any]:
    """Read a digests file; one ClodsError naming the file for anything unreadable or of another format."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ClodsError("no digests file", where=str(path), hint="it is written by `clods-bench reproduce`") from None
    except (OSError, ValueError) as exc:
        raise ClodsError(f"unreadable digests file ({exc})", where=str(path)) from None
    if not isinstance(data, dict) or data.get("format") != DIGESTS_FORMAT:
        got = data.get("format") if isinstance(data, dict) else None
        raise ClodsError(f"digests format {got!r} (written by clods-bench {data.get('clods_bench', '?') if isinstance(data, dict) else '?'}); "
                         f"this release reads format {DIGESTS_FORMAT}", where=str(path),
                         hint="regenerate it with this release's `clods-bench reproduce`")  # fmt: skip
    if not isinstance(data.get("rows"), dict):
        raise ClodsError("digests file without 'rows'", where=str(path))
    return data


def check_comparable(committed: Mapping[str, Any], fresh: Mapping[str, Any], committed_name: str, fresh_name: str) -> None:
    """Refuse, in one line, two files whose numbers cannot match bit for bit (other numeric paths or preset)."""
    a, b = committed.get("numerics") or {}, fresh.get("numerics") or {}
    if a.get("mode") != b.get("mode"):
        raise ClodsError(
            f"{committed_name} was made in {a.get('mode')} mode and {fresh_name} in {b.get('mode')} mode: their numbers cannot match bit for bit",
            where=fresh_name, hint="rerun without --no-deterministic (and without CLODS_BENCH_DETERMINISTIC=0)",
        )  # fmt: skip
    if a != b:
        raise ClodsError(f"{committed_name} was made with pins {a.get('pins_version')} and {a.get('threads')} thread(s) per job, {fresh_name} "
                         f"with pins {b.get('pins_version')} and {b.get('threads')}: their numbers cannot match bit for bit", where=fresh_name,
                         hint="use the committed file's release and CLODS_BENCH_THREADS")  # fmt: skip
    if committed.get("preset") != fresh.get("preset"):
        raise ClodsError(f"preset {fresh.get('preset')!r} against the committed {committed.get('preset')!r}", where=fresh_name)


def compare(committed: Mapping[str, Any], fresh: Mapping[str, Any], tolerance: Any = None) -> list[tuple[str, str]]:
    """(row, line) per row and seed that differs, the line naming the first stage that differs and the metrics that moved.

    Only seeds present in both are compared (a `--first-seeds` run holds fewer). `tolerance` (a `ToleranceSpec`)
    may let a metric move, matched as the column '<metric>/mean' of '<table>.csv'; a row whose every moved metric is
    within it is not reported. Rows of `committed` absent from `fresh` are skipped (not run)."""
    lines: list[tuple[str, str]] = []
    fresh_rows = fresh.get("rows", {})
    for name, row in committed.get("rows", {}).items():
        if name not in fresh_rows or "seeds" not in row:
            continue
        new = fresh_rows[name]
        if "seeds" not in new:
            new = fresh_rows.get(new.get("same_as", ""), {})
        for seed, old_seed in row["seeds"].items():
            new_seed = new.get("seeds", {}).get(seed)
            if new_seed is None:
                continue
            line = _seed_difference(name, row, seed, old_seed, new_seed, new.get("record"), tolerance)
            if line:
                lines.append((name, line))
    return lines


def _seed_difference(name: str, row: Mapping[str, Any], seed: str, old: Mapping[str, Any], new: Mapping[str, Any], new_record: Any,
                     tolerance: Any) -> str | None:  # fmt: skip
    moved = _moved_metrics(row.get("table", ""), row.get("label", ""), old.get("metrics", {}), new.get("metrics", {}), tolerance)
    stage = first_stage_differing(old.get("stages", {}), new.get("stages", {}))
    if not moved:
        return None
    where = f"differs from stage '{stage}' on" if stage else "stage digests equal"
    equal = [s for s in STAGES if s != stage and s in old.get("stages", {}) and STAGES.index(s) < STAGES.index(stage or "score")]
    config = "" if row.get("record") == new_record else f"; its config changed (record {row.get('record')} -> {new_record})"
    shown = "; ".join(moved[:4]) + (f"; {len(moved) - 4} more" if len(moved) > 4 else "")
    return f"{name} seed {seed}: {where}" + (f" (equal: {', '.join(equal)})" if equal else "") + f"{config}: {shown}"


def first_stage_differing(old: Mapping[str, str], new: Mapping[str, str]) -> str | None:
    """The first stage, in pipeline order, whose digest differs or exists in only one of the two (None: all equal)."""
    for stage in STAGES:
        if old.get(stage) != new.get(stage):
            return stage
    return None


def _moved_metrics(table: str, label: str, old: Mapping[str, Any], new: Mapping[str, Any], tolerance: Any) -> list[str]:
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = _num(old.get(key)), _num(new.get(key))
        if _same(a, b):
            continue
        if tolerance is not None:
            tol = tolerance.for_cell(f"{table}.csv", label, f"{key}/mean")
            if tol is None or tol.allows(a, b):
                continue
        out.append(f"{key} {a:.6g} -> {b:.6g}" + (f" (rel {abs(b - a) / abs(a):.2g})" if math.isfinite(a) and math.isfinite(b) and a else ""))
    return out


def _num(value: Any) -> float:
    try:
        return float("nan") if value is None else float(value)
    except (TypeError, ValueError):
        return float("nan")


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


def tables_of(names: Iterable[str], digests: Mapping[str, Any]) -> list[str]:
    """The tables holding rows `names` or rows that share their run (`same_as`), in file order."""
    rows = digests.get("rows", {})
    wanted = set(names)
    hit = {r["table"] for n, r in rows.items() if n in wanted or r.get("same_as") in wanted}
    return [t for t in dict.fromkeys(r["table"] for r in rows.values()) if t in hit]


def changed_configs(committed: Mapping[str, Any], current: Mapping[str, str]) -> list[tuple[str, str]]:
    """(row, line) for each row whose record key (resolved-config digest) differs from the committed one."""
    out = []
    for name, key in current.items():
        row = committed.get("rows", {}).get(name)
        if row is None:
            out.append((name, f"{name}: not in the committed digests (a new row)"))
        elif row.get("record") != key:
            out.append((name, f"{name}: config changed (record {row.get('record')} -> {key})"))
    return out
