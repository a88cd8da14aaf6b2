"""clods-bench: a plugin-based benchmark for learning cloth dynamics from multi-view video.

Importing it changes nothing in the process: exact numerics are a scope (`clods_bench.numerics.exact()`) that the
CLI, the runner and its workers enter.
"""

__version__ = "0.2.0"
