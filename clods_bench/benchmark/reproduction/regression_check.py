"""`reproduce --check`: a fresh reproduction against the committed one, exact where the numbers are exact.

Two comparisons, both under the committed `tolerance.yaml` (whose default is exact):
- the digests (`run_digests`): per row and seed, the first stage that differs and the metrics that moved;
- the tables: every fresh CSV against the committed one, or, for a `--first-seeds 1` run, against the committed
  first seed's tables (`first_seed/`), cell by cell.
The report names the tables a regeneration must rewrite and the command that does it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from clods_bench.benchmark.reproduction import run_digests
from clods_bench.benchmark.reproduction.compare import TOLERANCE_FILE, compare_dirs, load_tolerance
from clods_bench.benchmark.reproduction.reproduce import FIRST_SEED_DIR
from clods_bench.errors import ClodsError


@dataclass
class CheckReport:
    """What moved: digest lines (row, seed, first stage), table lines (file, row, column), the tables to regenerate."""

    digest_lines: list[str] = field(default_factory=list)
    table_lines: list[str] = field(default_factory=list)
    tables: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.digest_lines and not self.table_lines


def check_reproduction(committed: Path, fresh: Path, tables: Sequence[str], first_seeds: int | None, tolerance: Path | None = None) -> CheckReport:
    """Compare the fresh output folder with the committed one for `tables` (the ones the fresh run wrote)."""
    committed, fresh = Path(committed), Path(fresh)
    report = CheckReport()
    tol_path = Path(tolerance) if tolerance is not None else committed / TOLERANCE_FILE
    spec = load_tolerance(tol_path)
    digests_path = committed / run_digests.DIGESTS_FILE
    moved_rows: list[str] = []
    if digests_path.is_file():
        old = run_digests.load(digests_path)
        new = run_digests.load(fresh / run_digests.DIGESTS_FILE)
        run_digests.check_comparable(old, new, str(digests_path), str(fresh / run_digests.DIGESTS_FILE))
        for row, line in run_digests.compare(old, new, spec):
            moved_rows.append(row)
            report.digest_lines.append(line)
        report.tables += run_digests.tables_of(moved_rows, old)
    else:
        report.notes.append(f"{digests_path} not found: tables compared, no stage digests")

    table_dir = committed
    if first_seeds is not None and (committed / FIRST_SEED_DIR).is_dir():
        table_dir = committed / FIRST_SEED_DIR
    elif first_seeds is not None and not _single_seed(committed):
        raise ClodsError("no first-seed tables to check a --first-seeds run against", where=str(committed / FIRST_SEED_DIR),
                         hint="regenerate the committed tables with this release's `clods-bench reproduce` (it writes them)")  # fmt: skip
    known = {p.stem for p in table_dir.glob("*.csv")}
    skip = sorted(known - set(tables))
    missing = [t for t in tables if t not in known]
    if missing:
        report.notes.append(f"not in {table_dir}: {', '.join(missing)} (new tables: nothing to compare with)")
    if set(tables) & known:
        report.table_lines = compare_dirs(table_dir, fresh, tol_path, skip_tables=skip)
    report.tables += [line.split(".csv:", 1)[0] for line in report.table_lines if ".csv:" in line]
    report.tables = list(dict.fromkeys(report.tables))
    return report


def _single_seed(folder: Path) -> bool:
    """Whether a committed folder's tables were made from one seed (its manifest says so): they are first-seed tables."""
    import json

    try:
        manifest = json.loads((folder / "manifest.json").read_text())
    except (OSError, ValueError):
        return False
    return manifest.get("first_seeds") == 1 or all(len(r.get("seeds", [])) == 1 for r in manifest.get("runs", [{}]))


def regenerate_command(preset: str, tables: Sequence[str], out: str) -> str:
    """The command that regenerates `tables` into the committed folder `out` (the other tables' files are kept)."""
    return f"clods-bench reproduce --preset {preset} --jobs 2 --only {' '.join(tables)} --out {out}"
