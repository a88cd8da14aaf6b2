"""Scenes, the ground-truth cloth solver and mesh rasterizer, cameras, splits and the on-disk store."""
