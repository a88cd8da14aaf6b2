"""A pytest plugin that runs a test session the way the CLI runs a command: `-p clods_bench.numerics.pytest_plugin`.

The pins are set when pytest registers this plugin, which `-p` does before the plugins installed through entry points
load (zarr's and jaxtyping's import numpy), and the whole session runs inside `numerics.exact()`. With
CLODS_BENCH_DETERMINISTIC=0 it does neither: the session runs on the host's own paths. Importing this module does
nothing; pytest's calls do.
"""

from __future__ import annotations

import contextlib
from typing import Any

import clods_bench.numerics.pinning as pins
import clods_bench.numerics.scope as scope

_session = contextlib.ExitStack()


def pytest_addoption(parser: Any, pluginmanager: Any) -> None:
    """Called once as pytest registers this plugin, before any entry-point plugin loads: the pins go in first."""
    if pins.requested():
        pins.pin_environment()


def pytest_sessionstart(session: Any) -> None:
    """The session enters the exact scope (where the CPU can hold it; a CPU without AVX2 runs on host paths, and the
    tests of the pinned bits skip there)."""
    if pins.requested() and not scope.cpu.missing_cpu_features():
        _session.enter_context(scope.exact())


def pytest_sessionfinish(session: Any, exitstatus: Any) -> None:
    _session.close()
