"""The built-in scenes' plugin: registers the scenes of `clods_bench.datasets.scenes` through the entry-point group."""
