"""Seed every random number generator a task may use, so one config and seed give the same numbers twice."""

from __future__ import annotations

import os
import random

import numpy as np

# The runner sets these before each seed; a seed's numbers then depend only on (config, seed, machine, thread count).
SEED_ENV = "CLODS_BENCH_SEED"


def seed_everything(seed: int, torch_threads: int | None = None) -> None:
    """Seed Python's `random`, NumPy's global RNG and torch (CPU and CUDA); optionally fix torch's CPU threads.

    Plugins should still draw from their own generators (`np.random.default_rng(seed)`,
    `torch.Generator().manual_seed(seed)`); this covers code that uses the global ones.
    cuDNN is switched to deterministic kernels (no autotuning), which matters on GPU machines only.
    """
    seed = int(seed)
    os.environ[SEED_ENV] = str(seed)
    random.seed(seed)
    np.random.seed(seed % 2**32)
    try:
        import torch
    except ImportError:  # torch is a dependency, but a plugin-only environment may lack it
        return
    torch.manual_seed(seed)
    if torch_threads is not None:
        torch.set_num_threads(int(torch_threads))
    if torch.backends.cudnn.is_available():
        torch.backends.cudnn.deterministic = True
        torch.backends.cudnn.benchmark = False
