"""The `clods-bench bench` speed benchmarks and the deterministic-mode probe fits."""
