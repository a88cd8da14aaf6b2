"""`python -m clods_bench.docsgen refresh [--check]`: rewrite (or check) the generated blocks of README.md;
`python -m clods_bench.docsgen redraw`: rewrite the committed pictures drawn from committed data.

The README's blocks hold numbers read from `results/` (headline results, the paper's claims) and the presets table;
the claims page (`docs/results/claims.md`) holds every claim with its numbers, committed filled so that it reads the
same in the repository as on the site. Run `refresh` after regenerating the committed tables. `--check` writes nothing and exits 1 when a block is out of
date (a test does the same). `redraw` draws every `plots` entry of `docs/results_sources.yaml` that has both a
committed `file` and a drawing (`draw` + `from`) into that file, as the site draws it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from clods_bench.docsgen.blocks import BLOCK, fill
from clods_bench.errors import ClodsError


COMMITTED_FILLED = ("README.md", "docs/results/claims.md")
"""The pages whose generated blocks are committed filled (linked from the README, read in the repository's web view)."""


def pages_with_blocks(root: Path) -> list[Path]:
    """The committed pages whose generated blocks must be current (`COMMITTED_FILLED`)."""
    return [p for p in (root / name for name in COMMITTED_FILLED) if p.is_file() and BLOCK.search(p.read_text())]


def stale_pages(root: Path) -> list[Path]:
    """The pages whose generated blocks differ from what the generators write now."""
    return [p for p in pages_with_blocks(root) if fill(p.read_text(), root, str(p)) != p.read_text()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m clods_bench.docsgen", description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("refresh", "redraw"), help="refresh: the generated blocks of README.md and the claims page; redraw: the committed figures drawn from committed data")
    parser.add_argument("--check", action="store_true", help="exit 1, writing nothing, when a block is out of date")
    parser.add_argument("--root", type=Path, default=Path("."), help="the checkout (default: the current directory)")
    args = parser.parse_args(argv)
    if args.what == "redraw":
        return _redraw(args.root)
    try:
        stale = stale_pages(args.root)
        if args.check:
            for path in stale:
                print(f"{path}: generated blocks out of date; run `python -m clods_bench.docsgen refresh`", file=sys.stderr)
            return 1 if stale else 0
        for path in stale:
            path.write_text(fill(path.read_text(), args.root, str(path)))
            print(f"{path}: generated blocks rewritten")
    except (OSError, ClodsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not stale:
        print("generated blocks up to date")
    return 0


def _redraw(root: Path) -> int:
    from clods_bench.docsgen.figures import redraw
    from clods_bench.docsgen.results_pages import plots

    try:
        for path in redraw(plots(root)):
            print(f"{path}: redrawn")
    except (OSError, ClodsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
