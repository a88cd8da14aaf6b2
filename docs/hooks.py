"""MkDocs hooks of the clods-bench site: the generated pages and blocks (`clods_bench.docsgen`).

- `on_files`: adds the CLI reference (from the parser), the results pages and their CSV, LaTeX and picture files
  (from `results/`; figures drawn from committed data are drawn here), and puts the table pages into the navigation;
- `on_page_markdown`: rewrites every `<!-- generated:NAME -->` block, so a page built from a checkout whose
  committed blocks are stale still shows the current numbers (the docs tests fail on the stale copy).
A missing table file, a picture without its command or a stale claim stops the build with one error naming the
file and line (mkdocs reports it as an aborted build).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files

from clods_bench.docsgen.blocks import fill
from clods_bench.docsgen.cli_reference import cli_reference
from clods_bench.docsgen.results_pages import nav_entries, results_pages
from clods_bench.errors import ClodsError

def _root(config: Any) -> Path:
    return Path(config.config_file_path).resolve().parent


def _section(nav: list[Any], title: str) -> list[Any] | None:
    for item in nav:
        if isinstance(item, dict) and title in item and isinstance(item[title], list):
            return item[title]
    return None


def on_files(files: Files, config: Any) -> Files:
    """Add the generated pages and files; extend the navigation with them."""
    root = _root(config)
    try:
        generated = results_pages(root)
        tables = nav_entries(root)
    except ClodsError as exc:
        raise PluginError(f"results pages: {exc.message}") from None
    files.append(File.generated(config, "reference/cli.md", content=cli_reference()))
    for g in generated:
        if g.text is not None:
            files.append(File.generated(config, g.path, content=g.text))
        elif g.draw is not None:
            try:
                files.append(File.generated(config, g.path, content=g.draw()))
            except ClodsError as exc:
                raise PluginError(f"results pages: {exc.message}") from None
        else:
            files.append(File.generated(config, g.path, abs_src_path=str(g.source)))
    nav = config.nav or []
    results = _section(nav, "Results")
    if results is not None:  # `mkdocs serve` may build twice from one config: replace, never append twice
        results[:] = [item for item in results if not (isinstance(item, dict) and ("Tables" in item or "Plots" in item))]
        results += [{"Tables": tables}, {"Plots": "results/plots.md"}]
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    """Fill the generated blocks of a hand-written page with what the generators write now."""
    try:
        return fill(markdown, _root(config), page.file.src_uri)
    except ClodsError as exc:
        raise PluginError(f"{page.file.src_uri}: {exc.message}") from None
