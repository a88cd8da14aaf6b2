"""clods-bench-example-sim: a third-party simulator plugin for clods-bench (a worked example)."""

__version__ = "0.1.0"
