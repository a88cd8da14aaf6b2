"""The benchmark's core: the plugin contract (descriptors, interfaces, hookspecs), the registry, run configuration and
presets, and what every task builds from a config (builders, fit cache, stage digests)."""
