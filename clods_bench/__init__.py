"""clods-bench: a plugin-based benchmark for learning cloth dynamics from multi-view video."""

__version__ = "0.1.0"
