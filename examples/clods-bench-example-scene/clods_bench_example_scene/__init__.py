"""clods-bench-example-scene: a third-party scene plugin for clods-bench (a worked example: a swaying swallowtail banner)."""

__version__ = "0.1.0"
