"""Generators of the documentation site's pages that must not be written by hand.

The CLI reference comes from the argument parser, the results pages and the README's results block from the
files under `results/`, and the paper-claims page from `docs/claims.yaml` evaluated on those files, so that the
site cannot drift from the code or the committed tables. `docs/hooks.py` calls them while MkDocs builds;
`python -m clods_bench.docsgen readme [--check]` rewrites (or checks) the README's generated blocks.
"""
