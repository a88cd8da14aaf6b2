"""The README stays short and current, and the site's pages stay short and speak of the software, not its history."""

from __future__ import annotations

import re

from clods_bench.docsgen.__main__ import stale_pages
from clods_bench.docsgen.blocks import fill
from tests.docs.pages import DOCS, ROOT, links, site_pages

HISTORY = re.compile(
    r"\bissue \d+|\bissues? \d+|\bsessions? \d+|\b(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|next) visit\b|"
    r"\bGPU visits?\b|\bvisit\d|\bthe visit's\b|\bafter the visit\b|\bthis machine\b|\bthe development machine\b|"
    r"\blater that day\b|\ba slower hour\b|\bengineers?\b|/work/",
    re.I,
)
"""Words of a lab notebook that no user page may contain: tracker numbers, work sessions, machine visits, people."""
RUN_LOG = re.compile(r"\bpins version \d", re.I)
"""A run log by deterministic mode's internal version: the CHANGELOG's and the studies' business, not a user page's."""


def test_the_readme_is_short() -> None:
    assert len((ROOT / "README.md").read_text().splitlines()) <= 300


REFERENCE_PAGES = ("reference/cli.md",)
"""Generated line for line from `--help` (one row per option): as long as the command line is wide."""


def test_no_page_of_the_site_is_long() -> None:
    long = {page: len(text.splitlines()) for page, text in site_pages().items() if len(text.splitlines()) > 400 and page not in REFERENCE_PAGES}
    assert not long, f"pages over 400 lines: {long}"


def test_the_readme_blocks_are_current() -> None:
    stale = stale_pages(ROOT)
    assert not stale, f"{stale}: generated blocks out of date; run `python -m clods_bench.docsgen refresh`"


def test_a_stale_block_is_found(tmp_path) -> None:
    readme = (ROOT / "README.md").read_text()
    start = readme.index("<!-- generated:presets")
    body = readme.index("\n", start) + 1
    (tmp_path / "README.md").write_text(readme[:body] + "| stale |\n" + readme[readme.index("<!-- end generated:presets -->"):])
    for sub in ("docs", "results", "clods_bench"):
        (tmp_path / sub).symlink_to(ROOT / sub)
    assert stale_pages(tmp_path) == [tmp_path / "README.md"]
    fixed = fill((tmp_path / "README.md").read_text(), tmp_path, "README.md")
    assert fixed == readme


def test_the_readme_reaches_the_three_questions_in_one_click() -> None:
    targets = {target for _, target in links((ROOT / "README.md").read_text())}
    assert {"docs/plugins/simulator.md", "docs/gpu.md", "docs/results/claims.md"} <= targets


def _found(pages: dict[str, str], pattern: re.Pattern[str]) -> list[str]:
    return [f"{page}:{n}: {m.group(0)!r}" for page, text in pages.items() for n, line in enumerate(text.splitlines(), 1)
            for m in pattern.finditer(line)]  # fmt: skip


def test_user_pages_speak_of_the_software_not_its_history() -> None:
    pages = {f"docs/{p}": t for p, t in site_pages().items()}
    pages["README.md"] = (ROOT / "README.md").read_text()
    found = _found(pages, HISTORY) + _found(pages, RUN_LOG)
    assert not found, "\n".join(found)
    assert (DOCS / "changelog.md").read_text().strip() == '--8<-- "CHANGELOG.md"'


def test_results_readmes_name_cpu_gpu_and_date_not_visits_or_issues() -> None:
    """The READMEs beside the committed results; the studies' may log runs by deterministic mode's version."""
    readmes = {str(p.relative_to(ROOT)): p.read_text() for p in sorted((ROOT / "results").rglob("README.md"))}
    assert "results/gpu_h200/README.md" in readmes and "results/small-partial/README.md" in readmes
    found = _found(readmes, HISTORY) + _found({k: v for k, v in readmes.items() if not k.startswith("results/studies/")}, RUN_LOG)
    assert not found, "\n".join(found)
    folders = [p.name for p in (ROOT / "results/gpu_h200").iterdir() if p.is_dir()]
    assert folders and all(re.fullmatch(r"\d{4}-\d\d-\d\d-[a-z0-9-]+", f) for f in folders), folders  # date and purpose


def test_the_history_patterns_catch_a_lab_notebook() -> None:
    notebook = ["the fifth visit's defaults", "2026-11-27-visit7/", "issue 14, item 1", "on the development machine",
                "later that day", "in a slower hour", "under pins version 4"]  # fmt: skip
    assert all(HISTORY.search(line) or RUN_LOG.search(line) for line in notebook)
    assert not HISTORY.search("compositing visits only the chord of each Gaussian")  # a word of the software
