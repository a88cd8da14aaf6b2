"""Fixtures of the docs tests: the plugin guide's example plugins, registered in memory once per session."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import pytest

from tests.docs.pages import ROOT

EXAMPLE_PACKAGES = {"clods_bench_example_sim.plugin": "examples/clods-bench-example-sim",
                    "clods_bench_example_scene.plugin": "examples/clods-bench-example-scene"}  # fmt: skip
"""The guide's installable examples: entry-point module -> package folder."""
EXAMPLE_MODULES = {"docs_example_vertex_splat": "docs/plugins/examples/vertex_splat.py",
                   "docs_example_momentum_predictor": "docs/plugins/examples/momentum_predictor.py"}  # fmt: skip
"""The guide's single-module examples: module name -> file."""


def load_module(path: Path, name: str) -> Any:
    """Import a single-file plugin module from its path."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    return module


@dataclass(frozen=True)
class Guide:
    """The example modules by name and a registry of the built-ins plus all of them."""

    modules: dict[str, Any]
    registry: Any


@pytest.fixture(scope="session")
def guide() -> Iterator[Guide]:
    """The built-in plugins plus the plugin guide's four examples, registered in memory (nothing installed)."""
    from clods_bench.benchmark.core.registry import Registry, make_plugin_manager

    with pytest.MonkeyPatch.context() as mp:
        for folder in EXAMPLE_PACKAGES.values():
            mp.syspath_prepend(str(ROOT / folder))
        modules = {name: importlib.import_module(name) for name in EXAMPLE_PACKAGES}
        modules.update({name: load_module(ROOT / path, name) for name, path in EXAMPLE_MODULES.items()})
        try:
            yield Guide(modules, Registry.from_plugin_manager(make_plugin_manager(list(modules.values()))))
        finally:
            for name in [m for m in sys.modules if m.startswith(("clods_bench_example_", "docs_example_"))]:
                sys.modules.pop(name)
