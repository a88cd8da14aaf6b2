"""Every relative link of the site's pages and of the README points at a page, file or heading that exists.

MkDocs' strict build checks the same in CI; this test names the page and line, runs in a second, and covers the
README, whose links must work in the repository (they cannot point at pages generated when the site is built).
"""

from __future__ import annotations

import posixpath
from pathlib import Path

from tests.docs.pages import DOCS, ROOT, heading_ids, links, site_files, site_pages


def _external(target: str) -> bool:
    return target.startswith(("http://", "https://", "mailto:"))


def broken_site_links(pages: dict[str, str], files: set[str]) -> list[str]:
    """'page:line: target: why' for every link of the site's pages that leads nowhere."""
    problems = []
    for page, text in sorted(pages.items()):
        for line, target in links(text):
            if _external(target):
                continue
            path, _, anchor = target.partition("#")
            resolved = posixpath.normpath(posixpath.join(posixpath.dirname(page), path)) if path else page
            if resolved.startswith(".."):
                problems.append(f"docs/{page}:{line}: {target}: leaves the docs folder (the site cannot serve it)")
            elif resolved not in pages and resolved not in files:
                problems.append(f"docs/{page}:{line}: {target}: no such page or file")
            elif anchor and resolved in pages and anchor not in heading_ids(pages[resolved]):
                problems.append(f"docs/{page}:{line}: {target}: no heading '#{anchor}' in {resolved}")
    return problems


def broken_readme_links(readme: Path) -> list[str]:
    """'README.md:line: target: why' for every README link to a missing file or heading of the repository."""
    problems = []
    for line, target in links(readme.read_text()):
        if _external(target):
            continue
        path, _, anchor = target.partition("#")
        file = (readme.parent / path) if path else readme
        if not file.exists():
            problems.append(f"README.md:{line}: {target}: no such file in the repository")
        elif anchor and anchor not in heading_ids(file.read_text()):
            problems.append(f"README.md:{line}: {target}: no heading '#{anchor}' in {path or 'README.md'}")
    return problems


def test_every_link_of_the_site_resolves() -> None:
    problems = broken_site_links(site_pages(), site_files())
    assert not problems, "\n".join(problems)


def test_every_link_of_the_readme_resolves() -> None:
    problems = broken_readme_links(ROOT / "README.md")
    assert not problems, "\n".join(problems)


def test_a_broken_link_is_named_with_its_page_and_line() -> None:
    pages = {
        "a.md": "# Title\n\n## Part one\n\ntext [ok](b.md#second) and [gone](c.md)\n[bad anchor](b.md#nope)\n",
        "b.md": "# B\n\n## Second\n\n```bash\n# not a heading\n```\n[up](../../x.md) [self](#b)\n",
    }
    assert broken_site_links(pages, set()) == [
        "docs/a.md:5: c.md: no such page or file",
        "docs/a.md:6: b.md#nope: no heading '#nope' in b.md",
        "docs/b.md:8: ../../x.md: leaves the docs folder (the site cannot serve it)",
    ]


def test_the_readme_link_check_fails_on_a_missing_file(tmp_path: Path) -> None:
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "gpu.md").write_text("# GPUs\n\n## The run sheet\n")
    readme = tmp_path / "README.md"
    readme.write_text("# X\n\n[gpu](docs/gpu.md#the-run-sheet) [no](docs/gone.md) [anchor](docs/gpu.md#nope)\n")
    assert broken_readme_links(readme) == [
        "README.md:3: docs/gone.md: no such file in the repository",
        "README.md:3: docs/gpu.md#nope: no heading '#nope' in docs/gpu.md",
    ]


def test_the_pages_of_the_navigation_exist() -> None:
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    _Loader.add_multi_constructor("", lambda loader, suffix, node: None)  # mkdocs.yml's !!python tags, if any
    nav = yaml.load((ROOT / "mkdocs.yml").read_text(), Loader=_Loader)["nav"]

    def walk(items: list) -> list[str]:
        out = []
        for item in items:
            value = next(iter(item.values())) if isinstance(item, dict) else item
            out += walk(value) if isinstance(value, list) else [value]
        return out

    missing = [p for p in walk(nav) if p not in site_pages()]
    assert not missing, f"mkdocs.yml names pages that do not exist: {missing}"
    assert (DOCS / "hooks.py").is_file()
