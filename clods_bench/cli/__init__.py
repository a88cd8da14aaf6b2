"""The `clods-bench` command line: one module per command group (`info`, `data`, `run`, `outputs`, `reproduce`,
`bench`), the parser built from them and `main()` in `app` (the console script `clods_bench.cli:main`)."""

from clods_bench.cli.app import build_parser, main

__all__ = ["build_parser", "main"]
