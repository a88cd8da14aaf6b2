"""Built-in video predictors (pixel-space baselines of the DVC forward task): copy-last-frame and SimVP."""
