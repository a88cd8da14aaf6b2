"""Helpers of the docs tests: the site's pages as the build sees them, and their code blocks, links and anchors."""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Iterator

from markdown.extensions.toc import slugify

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

FENCE = re.compile(r"^(\s*)(```+|~~~+)\s*([\w+-]*)")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")


@dataclass(frozen=True)
class CodeBlock:
    """A fenced code block: its language, the line its first content line is on, and its lines."""

    lang: str
    line: int
    lines: tuple[str, ...]


def code_blocks(text: str) -> list[CodeBlock]:
    """Every fenced code block of a markdown text (indented fences inside list items included)."""
    out, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, lang = m.groups()
        body, j = [], i + 1
        while j < len(lines) and not lines[j].strip().startswith(fence):
            body.append(lines[j][len(indent):] if lines[j].startswith(indent) else lines[j])
            j += 1
        out.append(CodeBlock(lang, i + 2, tuple(body)))
        i = j + 1
    return out


def prose_lines(text: str) -> Iterator[tuple[int, str]]:
    """(line number, line) of the lines outside code blocks, inline code removed."""
    inside, fence = False, ""
    for n, line in enumerate(text.splitlines(), 1):
        m = FENCE.match(line)
        if m and (not inside or line.strip().startswith(fence)):
            inside, fence = (not inside), m.group(2)
            continue
        if not inside:
            yield n, re.sub(r"`[^`]*`", "``", line)


def links(text: str) -> list[tuple[int, str]]:
    """(line, target) of every markdown link and image outside code."""
    return [(n, m.group(1)) for n, line in prose_lines(text) for m in LINK.finditer(line)]


@lru_cache(maxsize=1)
def site_pages() -> dict[str, str]:
    """Every page of the site as the build sees it: docs/**/*.md with their generated blocks filled, and the
    generated pages (CLI reference, results). Keys are paths relative to docs/."""
    from clods_bench.docsgen.blocks import fill
    from clods_bench.docsgen.cli_reference import cli_reference
    from clods_bench.docsgen.results_pages import results_pages

    pages = {str(p.relative_to(DOCS)): fill(p.read_text(), ROOT, str(p)) for p in sorted(DOCS.rglob("*.md"))}
    pages["reference/cli.md"] = cli_reference()
    pages.update({g.path: g.text for g in results_pages(ROOT) if g.text is not None})
    return pages


@lru_cache(maxsize=1)
def site_files() -> set[str]:
    """Every file of the site that is not a page (pictures, CSV and LaTeX copies), relative to docs/."""
    from clods_bench.docsgen.results_pages import results_pages

    own = {str(p.relative_to(DOCS)) for p in DOCS.rglob("*") if p.is_file() and p.suffix not in (".md", ".py", ".yaml")}
    return own | {g.path for g in results_pages(ROOT) if g.text is None}


def heading_ids(text: str) -> set[str]:
    """The ids MkDocs gives the headings of a page (Python-Markdown's toc slugify; inline code kept as words,
    duplicates numbered)."""
    seen: dict[str, int] = {}
    out = set()
    inside, fence = False, ""
    for line in text.splitlines():
        m = FENCE.match(line)
        if m and (not inside or line.strip().startswith(fence)):
            inside, fence = (not inside), m.group(2)
            continue
        h = HEADING.match(line) if not inside else None
        if not h:
            continue
        words = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", h.group(2)).replace("`", "").replace("\\*", "*").replace("*", "")
        slug = slugify(words, "-")
        n = seen.get(slug)
        seen[slug] = 0 if n is None else n + 1
        out.add(slug if n is None else f"{slug}_{n + 1}")
    return out
