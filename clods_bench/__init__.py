"""clods-bench: a plugin-based benchmark for learning cloth dynamics from multi-view video."""

from clods_bench import deterministic_mode as _deterministic_mode

__version__ = "0.2.0"

# Before anything imports numpy, torch or numba: pin their floating-point paths (see `deterministic_mode`).
_deterministic_mode.apply()
