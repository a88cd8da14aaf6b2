"""The results pages hold every committed table with its command, and a missing or unlisted file fails naming it."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from clods_bench.docsgen.results_pages import nav_entries, plan_tables, plot_pages, plots, results_pages, table_pages
from clods_bench.errors import ClodsError
from tests.docs.pages import ROOT


def test_every_plan_table_has_a_page_with_its_ci_rows_and_command() -> None:
    pages = {g.path: g for g in results_pages(ROOT)}
    for t in plan_tables(ROOT):
        text = pages[f"results/{t.id}.md"].text
        with (ROOT / "results/ci" / f"{t.id}.csv").open(newline="") as fh:
            labels = [row[next(iter(row))] for row in csv.DictReader(fh)]
        for label in labels:
            assert f"| {label} " in text, f"{t.id}: row {label!r} of the committed CSV is not on its page"
        assert f"clods-bench reproduce --preset ci --jobs 2 --only {t.id}" in text
        assert pages[f"results/files/ci/{t.id}.csv"].source == ROOT / "results/ci" / f"{t.id}.csv"
    assert [next(iter(e.values())) for e in nav_entries(ROOT)] == [f"results/{t.id}.md" for t in plan_tables(ROOT)]


def test_every_small_table_and_picture_is_on_a_page() -> None:
    text = "\n".join(g.text for g in results_pages(ROOT) if g.text)
    for md in (ROOT / "results/small-partial").rglob("*.md"):
        if md.name != "README.md":
            assert f"`{md.relative_to(ROOT / 'results/small-partial').with_suffix('')}`" in text, md
    shown = {p.file for p in plots(ROOT) if p.file} | {f for p in plots(ROOT) for f in p.inputs if f.suffix == ".png"}
    assert shown == set((ROOT / "results").rglob("*.png"))
    pictures = {g.path: g for g in plot_pages(ROOT) if g.text is None}
    assert {g.source for g in pictures.values() if g.source} == {p.file for p in plots(ROOT) if p.file and p.draw is None}
    for g in pictures.values():
        if g.draw is not None:  # a figure drawn from committed files: a real PNG
            png = g.draw()
            assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000, g.path


def test_each_table_page_holds_its_plots_and_every_plot_is_on_the_plots_page() -> None:
    pages = {g.path: g.text for g in results_pages(ROOT) if g.text}
    tables = {t.id for t in plan_tables(ROOT)}
    by_table: dict[str, list[str]] = {}
    for p in plots(ROOT):
        assert f"[![{p.title}]({p.site})]({p.site})" in pages["results/plots.md"], p.title  # a click opens the full size
        if p.table is not None:
            assert p.table in tables, p.table
            by_table.setdefault(p.table, []).append(p.site)
    assert {"error_vs_time", "stability", "table4_dvc"} <= set(by_table)
    for table, sites in by_table.items():
        page = pages[f"results/{table}.md"]
        assert "## Plots" in page and all(f"]({site})" in page for site in sites), table


def test_table_pages_show_the_avg_columns_with_every_column_behind_a_toggle() -> None:
    page = {g.path: g.text for g in results_pages(ROOT) if g.text}["results/table2_cdg.md"]
    assert page.startswith("---\nhide:\n  - toc\n---\n")  # the table gets the table of contents' width
    glance_header = ("| Method | Viewed / Interpolation / Avg. | Viewed / Extrapolation / Avg. | Unviewed / Interpolation / Avg. | "
                     "Unviewed / Extrapolation / Avg. | Stability / max edge strain | Time / infer ms/step | Time / fit s |")  # fmt: skip
    assert glance_header in page
    assert '<details class="clods-table-all" markdown>\n<summary>All 15 columns</summary>' in page
    with (ROOT / "results/ci/table2_cdg.csv").open(newline="") as fh:
        physics = next(r for r in csv.DictReader(fh) if r["method"] == "Physics")
    avg = f"{float(physics['viewed/interp/avg/mean']):.4f}\u00a0±\u00a0{float(physics['viewed/interp/avg/std']):.4f}"
    assert page.count(avg) == 2  # at a glance and in the whole table: the committed number, on one line
    assert not [line for line in page.splitlines() if line.startswith("|") and " ± " in line]


def test_each_small_file_is_copied_to_its_own_place_on_the_site() -> None:
    """Two tables with one name in different folders (a rerun beside the original) keep both downloads."""
    generated = results_pages(ROOT)
    paths = [g.path for g in generated]
    assert len(paths) == len(set(paths)), sorted(p for p in paths if paths.count(p) > 1)
    sources = {g.path: g.source for g in generated if g.source}
    for rel in ("cdg_flag_small.csv", "ported_simulators/cdg_flag_small.csv"):
        assert sources[f"results/files/small/{rel}"] == ROOT / "results/small-partial" / rel


def _fake_root(tmp_path: Path) -> Path:
    """A checkout with a two-table plan, its ci tables, one small table and one picture, all listed."""
    (tmp_path / "clods_bench/benchmark/reproduction/plans").mkdir(parents=True)
    (tmp_path / "clods_bench/benchmark/reproduction/plans/reproduce.yaml").write_text(
        "version: 1\ntables:\n  - {id: t1, task: cdg, title: 'Table 1: one'}\n  - {id: t2, task: nvs, title: 'Table 2: two'}\nruns: []\n"
    )
    for folder in ("results/ci", "results/small-partial", "results/plots", "docs"):
        (tmp_path / folder).mkdir(parents=True)
    for t in ("t1", "t2"):
        (tmp_path / f"results/ci/{t}.md").write_text(f"caption of {t}\n\n| Method | x |\n|:--|--:|\n| A | 1 |\n")
        (tmp_path / f"results/ci/{t}.csv").write_text("method,x\nA,1\n")
    (tmp_path / "results/small-partial/t1_small.md").write_text("| Method | x |\n|:--|--:|\n| A | 2 |\n")
    (tmp_path / "results/plots/p.png").write_bytes(b"\x89PNG")
    (tmp_path / "docs/results_sources.yaml").write_text(
        "ci:\n  folder: results/ci\n  made_by: make ci\n  one_table: make {table}\n  check: check ci\n"
        "small:\n  folder: results/small-partial\n  tables:\n    - file: t1_small\n      table: t1\n      made_by: make small\n"
        "plots:\n  - file: results/plots/p.png\n    title: P\n    caption: a plot\n    made_by: make p\n"
    )  # fmt: skip
    return tmp_path


def test_a_missing_or_unlisted_result_file_fails_naming_where(tmp_path: Path) -> None:
    root = _fake_root(tmp_path)
    pages = {g.path: g for g in results_pages(root)}
    assert "| A | 2 |" in pages["results/t1.md"].text and "make small" in pages["results/t1.md"].text
    assert "make t2" in pages["results/t2.md"].text and "## At `small`" not in pages["results/t2.md"].text
    t1 = pages["results/t1.md"].text
    assert t1.index("## At `small`: evidence") < t1.index("## At `ci`: a regression fixture")  # the evidence first

    (root / "results/ci/t2.md").unlink()
    with pytest.raises(ClodsError, match=r"reproduce\.yaml:4: table 't2' has no committed file results/ci/t2\.md"):
        table_pages(root)
    (root / "results/ci/t2.md").write_text("| Method |\n|--|\n| A |\n")

    (root / "results/small-partial/extra_small.md").write_text("| Method |\n")
    with pytest.raises(ClodsError, match=r"results_sources\.yaml: small\.tables: no entry for results/small-partial/extra_small\.md"):
        table_pages(root)
    (root / "results/small-partial/extra_small.md").unlink()

    (root / "results/small-partial/t1_small.md").unlink()
    with pytest.raises(ClodsError, match=r"results_sources\.yaml:9: table file results/small-partial/t1_small\.md is missing"):
        table_pages(root)
    (root / "results/small-partial/t1_small.md").write_text("| Method |\n")

    (root / "results/plots/q.png").write_bytes(b"\x89PNG")
    with pytest.raises(ClodsError, match=r"no entry for results/plots/q\.png"):
        plot_pages(root)
