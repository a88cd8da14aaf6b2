"""torch CPU thread settings: one context manager, and a cap that parallel workers put on every setting.

Plugins ask for a thread count in their configs (`num_threads`); a parallel executor running k jobs
on c cores sets `CLODS_BENCH_MAX_THREADS` = c // k in each worker, so the jobs together never ask
for more threads than there are cores. A run's numbers depend on its thread count (float rounding
of parallel reductions), so the same command on the same machine reproduces them bit for bit.
"""

from __future__ import annotations

import contextlib
import os
from typing import Iterator

MAX_THREADS_ENV = "CLODS_BENCH_MAX_THREADS"


def thread_cap() -> int | None:
    """The cap from `CLODS_BENCH_MAX_THREADS` (None when unset or not a positive integer)."""
    try:
        value = int(os.environ.get(MAX_THREADS_ENV, ""))
    except ValueError:
        return None
    return value if value >= 1 else None


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Use `n` torch CPU threads inside the block (None: leave the setting alone), never more than the cap."""
    import torch

    cap = thread_cap()
    if n is None and cap is None:
        yield
        return
    want = torch.get_num_threads() if n is None else int(n)
    if cap is not None:
        want = min(want, cap)
    old = torch.get_num_threads()
    torch.set_num_threads(want)
    try:
        yield
    finally:
        torch.set_num_threads(old)
