"""Built-in plugins (simulators, renderers, the CloDS pipeline), registered through entry points."""
