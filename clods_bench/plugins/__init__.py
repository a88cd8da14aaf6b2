"""Built-in plugins (simulators, renderers, video predictors, scenes), registered through entry points exactly as a
third-party package registers its own."""
