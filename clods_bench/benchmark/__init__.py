"""The benchmark, in layers (each imports only those below it): `scoring` <- `core` (plugin contract, registry,
config, builders) <- `running` <- `outputs` <- `reproduction`; then `clods` (the CloDS pipeline) beside the plugins,
and `tasks` and `speed` (the speed benchmarks) on top."""
