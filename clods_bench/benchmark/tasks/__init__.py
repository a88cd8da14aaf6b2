"""The benchmark tasks; `builtin` registers them through the entry-point group."""
