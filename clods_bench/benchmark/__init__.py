"""The core: plugin manager, interfaces, configuration, runner, tasks, metrics and tables."""
