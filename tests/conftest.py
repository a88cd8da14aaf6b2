"""Shared fixtures: a tiny generated dataset (meshes and frames) reused across tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from clods_bench.benchmark.core.config import RunConfig, load_config

TINY = [
    "data.resolution=[6,4]",
    "data.num_train=2",
    "data.num_test=1",
    "data.num_steps=12",
    "data.interp_steps=8",
    "data.num_cameras=3",
    "data.num_views_test=1",
    "data.image_size=24",
    "seeds=[0]",
    "progress=false",
    "task_config.nvs.num_trajectories=5",  # the task's defaults, not the ci preset's trimmed ones
    "task_config.nvs.frame_stride=1",
]


def tiny_config(root: Path, *extra: str, **fields) -> RunConfig:
    """A ci-preset config shrunk to seconds, writing under `root`."""
    return load_config("ci", overrides=[*TINY, f"data.root={root / 'data'}", f"runs_dir={root / 'runs'}", *extra], **fields)


@pytest.fixture(scope="session")
def tiny_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A directory holding the tiny dataset, generated once per test session."""
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.datasets.generate import generate

    root = tmp_path_factory.mktemp("tiny")
    cfg = tiny_config(root)
    generate(cfg.data, default_registry().get("scene", cfg.data.scene), progress=False)
    return root
