"""The `clods-bench` command line: one module per command group, the parser built from them, and `main()`."""

from clods_bench.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
