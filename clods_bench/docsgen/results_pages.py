"""The site's results pages, generated from the files under `results/` (never copied by hand).

One page per table of the reproduce plan, holding the committed `ci` table and every `small` file of that table,
each with the command that made it; a page of the plots; an index with the manifest's provenance and the cost of
each table. `docs/results_sources.yaml` says what each file is and how it was made.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Callable

from clods_bench.docsgen.figures import Plot, plot_entry, rendered
from clods_bench.docsgen.glance import glance
from clods_bench.benchmark.outputs.table_sources import field, load_yaml, where
from clods_bench.errors import ClodsError

PLAN_FILE = Path("clods_bench/benchmark/reproduction/plans/reproduce.yaml")
SOURCES_FILE = Path("docs/results_sources.yaml")
TASK_PAGES = {
    "cdg": "tasks/cdg.md", "nvs": "tasks/nvs.md", "dvc": "tasks/dvc.md", "dvc_multi": "tasks/dvc.md",
    "extract": "tasks/extract.md", "stability": "tasks/stability.md", "initial_mesh": "tasks/initial-mesh.md",
}  # fmt: skip
"""The hand-written page that explains each task's metrics."""


WIDE_PAGE = "---\nhide:\n  - toc\n---\n\n"
"""Front matter of the table and plot pages: no table of contents beside them, so their tables get its width."""


@dataclass(frozen=True)
class Generated:
    """A file of the site: markdown `text`, a copy of `source` (a CSV, LaTeX table or picture), or a picture that
    `draw()` makes from committed data when the site is built."""

    path: str
    text: str | None = None
    source: Path | None = None
    draw: Callable[[], bytes] | None = None


@dataclass(frozen=True)
class TableEntry:
    """A table of the plan: id, title, task and the line it is declared on."""

    id: str
    title: str
    task: str
    where: str


def plan_tables(root: Path) -> list[TableEntry]:
    """The tables of the built-in reproduce plan, in its order."""
    path = root / PLAN_FILE
    plan = load_yaml(path)
    return [TableEntry(field(t, "id", path), field(t, "title", path), field(t, "task", path), where(path, t)) for t in field(plan, "tables", path, list)]


def _table_body(md: Path) -> list[str]:
    """A committed markdown table: its caption line in italics, then the table."""
    lines = md.read_text().strip().splitlines()
    caption = lines[0].strip() if lines and not lines[0].startswith("|") else ""
    body = lines[1:] if caption else lines
    return ([f"*{caption}*", ""] if caption else []) + glance([line for line in body if line.strip() or not body])


def _code(command: str) -> list[str]:
    return ["```bash", command.rstrip(), "```"]


def _downloads(files: list[tuple[Path, str]]) -> str:
    return "Files: " + ", ".join(f"[`{src.name}`]({dst})" for src, dst in files) + "."


def _copies(stem: Path, folder: str, name: str) -> list[tuple[Path, str]]:
    """(source, site path) of a table's CSV and LaTeX files that exist; `name` keeps its subfolders (`a/t` and `t` differ)."""
    return [(stem.with_suffix(ext), f"files/{folder}/{name}{ext}") for ext in (".csv", ".tex") if stem.with_suffix(ext).is_file()]


def _manifest_rows(manifest: dict[str, Any], table: str) -> list[str]:
    runs = [r for r in manifest.get("runs", []) if r.get("table") == table]
    if not runs:
        return []
    lines = ["| row | simulator | renderer | seeds | seconds of its seed jobs | same run as |", "| --- | --- | --- | --- | --- | --- |"]
    for r in runs:
        secs = r.get("compute_seconds")
        lines.append(f"| {r.get('label')} | {r.get('sim') or '-'} | {r.get('renderer') or '-'} | {len(r.get('seeds', []))} | "
                     f"{'-' if secs is None else f'{secs:.1f}'} | {r.get('same_as') or '-'} |")  # fmt: skip
    return lines


def small_entries(root: Path) -> list[dict[str, Any]]:
    """The `small` entries of the sources file, checked against the table files that exist (both ways)."""
    path = root / SOURCES_FILE
    doc = load_yaml(path)
    small = field(doc, "small", path, dict)
    folder = root / field(small, "folder", path)
    entries = field(small, "tables", path, list)
    listed = set()
    for e in entries:
        stem = field(e, "file", path)
        field(e, "table", path)
        field(e, "made_by", path)
        if not (folder / f"{stem}.md").is_file():
            raise ClodsError(f"table file {folder.relative_to(root) / stem}.md is missing", where=where(path, e))
        listed.add(stem)
    found = {str(p.relative_to(folder).with_suffix("")) for p in folder.rglob("*.md") if p.name != "README.md"}
    unlisted = sorted(found - listed)
    if unlisted:
        raise ClodsError(f"no entry for {', '.join(f'{folder.relative_to(root)}/{u}.md' for u in unlisted)}", where=f"{path}: small.tables",
                         hint="say which table each file is and the command that made it")  # fmt: skip
    return entries


def _figure(plot: Plot, link: str) -> list[str]:
    """A picture that opens at full size when clicked (docs/javascripts/results.js zooms it in place)."""
    return ['<div class="clods-figure" markdown>', "", f"[![{plot.title}]({link})]({link})", "", "</div>", ""]


def _plot_section(plot: Plot, link: str, level: str) -> list[str]:
    return [f"{level} {plot.title}", "", *_figure(plot, link), plot.caption, "", *_code(plot.made_by), ""]


def plots(root: Path) -> list[Plot]:
    """Every picture of the sources file, checked; a PNG under `results/` that is neither shown nor drawn from is an error."""
    path = root / SOURCES_FILE
    entries = [plot_entry(root, path, p) for p in field(load_yaml(path), "plots", path, list)]
    listed = {p.file for p in entries if p.file} | {f for p in entries for f in p.inputs}
    unlisted = sorted(str(p.relative_to(root)) for p in (root / "results").rglob("*.png") if p not in listed)
    if unlisted:
        raise ClodsError(f"no entry for {', '.join(unlisted)}", where=f"{path}: plots", hint="say what each picture shows and the command that made it")
    return entries


def _picture(plot: Plot) -> Generated:
    if plot.draw is None:
        return Generated(f"results/{plot.site}", source=plot.file)
    return Generated(f"results/{plot.site}", draw=partial(rendered, plot))


def table_pages(root: Path) -> list[Generated]:
    """One page per table of the plan: the `small` tables (evidence) first, then the `ci` table (the regression
    fixture, which must exist), then the table's plots."""
    path = root / SOURCES_FILE
    doc = load_yaml(path)
    ci = field(doc, "ci", path, dict)
    ci_dir = root / field(ci, "folder", path)
    manifest_file = ci_dir / "manifest.json"
    manifest = json.loads(manifest_file.read_text()) if manifest_file.is_file() else {}
    small = small_entries(root)
    small_dir = root / doc["small"]["folder"]
    all_plots = plots(root)
    out: list[Generated] = []
    for t in plan_tables(root):
        md = ci_dir / f"{t.id}.md"
        if not md.is_file():
            raise ClodsError(f"table '{t.id}' has no committed file {md.relative_to(root)}", where=t.where,
                             hint=f"make it with `{ci['one_table'].format(table=t.id)}`")  # fmt: skip
        lines = [f"# {t.title}", "", f"Task `{t.task}`: what it measures and how each metric is computed is on [its page](../{TASK_PAGES.get(t.task, 'tasks/index.md')}). "
                 "Tables show their Avg. columns; *All columns* opens the whole table. Click a plot to zoom.", ""]  # fmt: skip
        copies = _copies(ci_dir / t.id, "ci", t.id)
        fixture = ["## At `ci`: a regression fixture", "", *_table_body(md), "", "Made by (the whole plan, or this table alone):", ""]
        fixture += [*_code(f"{ci['made_by']}\n{ci['one_table'].format(table=t.id)}"), "", _downloads(copies), ""]
        rows = _manifest_rows(manifest, t.id)
        if rows:
            fixture += ["The rows in `results/ci/manifest.json` (seconds as recorded by the run that made the table; work shared through "
                        "the caches counts where it was done first):", "", *rows, ""]  # fmt: skip
        mine = [e for e in small if e["table"] == t.id]
        evidence = ["## At `small`: evidence, in part (each table says over how many seeds)", ""] if mine else []
        for e in mine:
            stem = small_dir / e["file"]
            files = _copies(stem, "small", e["file"])
            evidence += [f"### `{e['file']}`", ""] + ([e["note"], ""] if e.get("note") else [])
            evidence += [*_table_body(stem.with_suffix(".md")), "", "Made by:", "", *_code(e["made_by"]), ""] + ([_downloads(files), ""] if files else [])
            copies += files
        lines += evidence + fixture  # the evidence first, the regression fixture after it (as on the claims page)
        mine_plots = [p for p in all_plots if p.table == t.id]
        if mine_plots:
            lines += ["## Plots", ""]
        for plot in mine_plots:
            lines += _plot_section(plot, plot.site, "###")
        out.append(Generated(f"results/{t.id}.md", WIDE_PAGE + "\n".join(lines).rstrip() + "\n"))
        out += [Generated(f"results/{dst}", source=src) for src, dst in copies]
    return out


def plot_pages(root: Path) -> list[Generated]:
    """The page of every picture under `results/` (and every figure drawn from them), each with its command, and the
    pictures themselves; a picture without an entry is an error."""
    entries = plots(root)
    lines = ["# Plots", "", "Every picture committed under `results/` or drawn from its files when the site is built, with the command "
             "that made it; click a plot to zoom. A plot of a table is also on that table's page.", ""]  # fmt: skip
    for plot in entries:
        lines += _plot_section(plot, plot.site, "##")
    return [Generated("results/plots.md", WIDE_PAGE + "\n".join(lines).rstrip() + "\n"), *(_picture(p) for p in entries)]


def nav_entries(root: Path) -> list[dict[str, str]]:
    """Sidebar entries of the table pages, in the plan's order: each title up to its colon or parenthesis."""
    out, seen = [], set()
    for t in plan_tables(root):
        name = t.title.split(":")[0].split(" (")[0].strip()
        if name in seen:
            name = f"{name} ({t.task})"
        seen.add(name)
        out.append({name: f"results/{t.id}.md"})
    return out


def _manifest(root: Path) -> dict[str, Any]:
    """`results/ci/manifest.json` (empty when absent: a checkout before the first reproduce)."""
    doc = load_yaml(root / SOURCES_FILE)
    path = root / doc["ci"]["folder"] / "manifest.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def table_seconds(manifest: dict[str, Any], table: str) -> float:
    """Seconds of the seed jobs a table runs itself (rows shared with an earlier table count there)."""
    return sum(float(r.get("compute_seconds") or 0.0) for r in manifest.get("runs", []) if r.get("table") == table and not r.get("same_as"))


def table_costs(root: Path, link_prefix: str = "results/") -> str:
    """Per table of the plan: its rows and the seconds of its seed jobs in `results/ci/manifest.json`, and the total."""
    manifest = _manifest(root)
    lines = ["| table | rows | seeds | seconds of its seed jobs |", "| --- | --- | --- | --- |"]
    total = 0.0
    for t in plan_tables(root):
        runs = [r for r in manifest.get("runs", []) if r.get("table") == t.id]
        secs = table_seconds(manifest, t.id)
        total += secs
        seeds = max((len(r.get("seeds", [])) for r in runs), default=0)
        lines.append(f"| [`{t.id}`]({link_prefix}{t.id}.md) | {len(runs)} | {seeds} | {secs:.0f} |")
    lines.append(f"| all | | | {total:.0f} |")
    return "\n".join(lines) + "\n"


def index_page(root: Path) -> Generated:
    """The results index: what the two sizes mean, every table with its pages, the manifest's provenance and costs."""
    path = root / SOURCES_FILE
    doc = load_yaml(path)
    ci_dir = root / doc["ci"]["folder"]
    manifest_file = ci_dir / "manifest.json"
    manifest = json.loads(manifest_file.read_text()) if manifest_file.is_file() else {}
    small = small_entries(root)
    lines = [
        "# Results", "",
        "Every page of this section is generated from the files under `results/` when the site is built.", "",
        "- **`ci`** (`results/ci/`) is a **regression fixture**: every table of the paper at a size that runs on 2 CPU cores. "
        "CI regenerates it and compares it with the committed files, exactly (`results/ci/tolerance.yaml`; "
        "[exact numbers](../reproducibility.md)). Its learned rows carry no scientific weight.",
        "- **`small`** (`results/small-partial/`) is **evidence** for the paper's questions: the `small` preset, seed 0, the "
        "tables and rows that have run so far.",
        "- GPU measurements (`results/gpu_h200/`) and studies (`results/studies/`) name their GPU, CPU and date.", "",
        "[The paper's claims here](claims.md) decides each claim of the paper on these tables.", "",
        "| table | task | `ci` | `small` files | seconds of the `ci` seed jobs |", "| --- | --- | --- | --- | --- |",
    ]  # fmt: skip
    for t in plan_tables(root):
        n_small = sum(1 for e in small if e["table"] == t.id)
        secs = table_seconds(manifest, t.id)
        lines.append(f"| [{t.title}]({t.id}.md) | `{t.task}` | {'yes' if (ci_dir / f'{t.id}.md').is_file() else 'no'} | {n_small or '-'} | {secs:.0f} |")
    lines += ["", "The seconds are the seed jobs recorded in `results/ci/manifest.json` for the rows a table runs itself (a row "
              "shared with an earlier table counts there; fits and extractions loaded from a cache count where they were made).", ""]  # fmt: skip
    if manifest:
        versions = ", ".join(f"{k} {v}" for k, v in sorted((manifest.get("versions") or {}).items()))
        lines += ["## Provenance of `results/ci`", "", f"- written {manifest.get('written', '?')} from commit `{manifest.get('commit', '?')}`, "
                  f"preset `{manifest.get('preset', '?')}`, executor `{manifest.get('executor', '?')}` with {manifest.get('jobs', '?')} jobs",
                  f"- versions: {versions}", f"- plan `{manifest.get('plan', '?')}` (sha256 {manifest.get('plan_sha256', '?')})"]  # fmt: skip
        for s in manifest.get("spliced", []) or []:
            lines.append(f"- table `{s.get('table')}`: rows appended from commit `{str(s.get('commit'))[:12]}` ({s.get('written')})")
        lines.append("")
    lines += ["## Regenerating", "", *_code(f"{doc['ci']['made_by']}\n{doc['ci']['check']}"), "",
              "See [Development](../development.md#regenerating-the-tables) for when to regenerate and how the check decides.", ""]  # fmt: skip
    return Generated("results/index.md", "\n".join(lines).rstrip() + "\n")


def results_pages(root: Path) -> list[Generated]:
    """Every generated page and file of the results section."""
    return [index_page(root), *table_pages(root), *plot_pages(root)]
