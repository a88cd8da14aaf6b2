"""Small plugin distributions for the isolation tests, installed the cheap way: a module plus a `*.dist-info` folder
(METADATA, entry_points.txt) in a directory put on sys.path, which `importlib.metadata` finds as `pip install` would.

Each one exercises one way an installed plugin can go wrong; GOOD works, to show the rest keeps loading.
"""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
import textwrap
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, Sequence

import pytest

from clods_bench.benchmark.core import plugin_loading, registry
from clods_bench.benchmark.core.plugin_loading import PluginSource

ROOT = Path(__file__).resolve().parents[1]

BROKEN_IMPORT = '''
import clods_bench_missing_dependency  # not installed: the import fails
'''

HOOK_RAISES = '''
from clods_bench.api import hookimpl

@hookimpl
def clods_bench_scenes():
    raise RuntimeError("scene server unreachable")
'''

NEWER_API = '''
from clods_bench.api import PluginSpec, hookimpl

CLODS_BENCH_API = "2.0"

@hookimpl
def clods_bench_simulators():
    return [PluginSpec(name="future-sim", description="needs a newer API", build=lambda cfg, ctx: None)]
'''

DEPRECATED_SCENE = '''
"""A scene written for the pre-1.0 form: SceneSpec(kind=...) with a build_mesh override."""
from clods_bench.api import hookimpl
from clods_bench.datasets.cloth_solver import SolverParams
from clods_bench.datasets.meshes import make_flag_mesh
from clods_bench.datasets.scenes import SceneSpec


class NarrowFlag(SceneSpec):
    def build_mesh(self, resolution=None):
        res = self.default_resolution if resolution is None else resolution
        return make_flag_mesh(int(res[0]), int(res[1]), *self.size)


@hookimpl
def clods_bench_scenes():
    return [NarrowFlag(name="narrow-flag", description="a narrow flag (pre-1.0 form)", kind="flag",
                       params=SolverParams(air_drag=0.02, damping_stiffness=1e-3), size=(1.0, 0.4),
                       default_resolution=(8, 4))]
'''

WRONG_TYPE = '''
from clods_bench.api import PluginSpec, hookimpl

@hookimpl
def clods_bench_simulators():
    return {"name": "dict-sim"}

@hookimpl
def clods_bench_renderers():
    return [PluginSpec(name="fine-renderer", description="left out with its plugin", build=lambda cfg, ctx: None)]
'''

CONFIG_NO_DEFAULT = '''
from dataclasses import dataclass
from clods_bench.api import PluginSpec, hookimpl

@dataclass(frozen=True)
class StepsConfig:
    steps: int

@hookimpl
def clods_bench_simulators():
    return [PluginSpec(name="steps-sim", description="config field without default", build=lambda c, x: None,
                       config_cls=StepsConfig)]
'''

CONFIG_NO_TYPE = '''
from dataclasses import dataclass
from clods_bench.api import PluginSpec, hookimpl

@dataclass(frozen=True)
class DampingConfig:
    damping = 0.5

@hookimpl
def clods_bench_simulators():
    return [PluginSpec(name="untyped-sim", description="config attribute without a type", build=lambda c, x: None,
                       config_cls=DampingConfig)]
'''


def twin(who: str) -> str:
    """A plugin providing simulator 'twin' (so does the other twin), its own one and, twin a, 'constvel' (a built-in name)."""
    return f'''
from clods_bench.api import PluginSpec, hookimpl

@hookimpl
def clods_bench_simulators():
    return [PluginSpec(name="twin", description="{who}", build=lambda c, x: None),
            PluginSpec(name="{who}-only", description="{who}", build=lambda c, x: None)]{' + [PluginSpec(name="constvel", description="a", build=lambda c, x: None)]' if who == "a" else ""}
'''


GOOD = '''
import numpy as np
from clods_bench.api import PluginSpec, hookimpl

CLODS_BENCH_API = "1.0"


class Still:
    """Holds the cloth where frame 1 has it (kinematic nodes follow their path)."""

    def fit(self, train, ctx):
        return {}

    def rollout(self, inp):
        x = np.repeat(inp.init_pos[1:2], inp.num_frames, axis=0)
        x[:2] = inp.init_pos
        kin = inp.kinematic_mask
        x[2:, kin] = inp.kinematic_pos[2:, kin]
        return x


@hookimpl
def clods_bench_simulators():
    return [PluginSpec(name="good-sim", description="works", build=lambda cfg, ctx: Still())]
'''

TASKS = '''
"""Two third-party tasks: one declares its table layout and row label, the other neither."""
import pandas as pd
from clods_bench.api import TableLayout, TaskResult, TaskSpec, hookimpl

CLODS_BENCH_API = "1.2"


def run(ctx):
    return TaskResult(metrics={"score": 0.25 + ctx.seed}, timings={"fit_seconds": 0.0})


def frame(records):
    display = pd.DataFrame([{"Score": f"{r['metrics']['score']['mean']:.2f}"} for r in records],
                           index=pd.Index([r["label"] for r in records], name="Coin"))
    numeric = pd.DataFrame([{"method": r["label"], "score": r["metrics"]["score"]["mean"]} for r in records])
    return display, numeric, ["one coin per seed"]


def caption(scene, preset, records, notes):
    return f"Coin flips ({scene}, preset {preset}): {'; '.join(notes)}."


@hookimpl
def clods_bench_tasks():
    return [TaskSpec(name="coin-flip", description="declares its table", run=run,
                     table=TableLayout(frame=frame, caption=caption), row_label=lambda cfg: "coin"),
            TaskSpec(name="no-table", description="declares no table", run=run)]
'''
"""A distribution of its own (not in PACKAGES): tasks, for the table tests."""

PACKAGES: dict[str, str] = {
    "broken-import": BROKEN_IMPORT,
    "hook-raises": HOOK_RAISES,
    "newer-api": NEWER_API,
    "deprecated-scene": DEPRECATED_SCENE,
    "wrong-type": WRONG_TYPE,
    "config-no-default": CONFIG_NO_DEFAULT,
    "config-no-type": CONFIG_NO_TYPE,
    "twin-a": twin("a"),
    "twin-b": twin("b"),
    "good": GOOD,
}
"""Distribution name -> the source of its one module (named after it, dashes as underscores, prefixed `cbt_`)."""


def module_name(dist: str) -> str:
    return "cbt_" + dist.replace("-", "_")


def install(site: Path, dist: str, source: str, version: str = "0.1.0", entry_point: str | None = None) -> None:
    """Write `source` as a module and a dist-info declaring it as the `clods_bench` entry point `entry_point` (`dist`)."""
    site.mkdir(parents=True, exist_ok=True)
    module = module_name(dist)
    (site / f"{module}.py").write_text(textwrap.dedent(source))
    info = site / f"{module}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(f"[clods_bench]\n{entry_point or dist} = {module}\n")


def install_all(site: Path, names: list[str] | None = None) -> None:
    for dist in names or list(PACKAGES):
        install(site, dist, PACKAGES[dist])


DISCOVER = plugin_loading.installed_entry_points
"""The registry's real entry-point lookup, kept before any test replaces it."""


def own_entry_points(sites: Sequence[Path]) -> Callable[[str], list[importlib.metadata.EntryPoint]]:
    """The registry's lookup narrowed to clods-bench's own entry points and those of distributions in `sites` (the
    ones a test installs): a plugin installed in the environment for other reasons then cannot change its outcome."""
    mine = {Path(site).resolve() for site in sites}

    def lookup(group: str) -> list[importlib.metadata.EntryPoint]:
        def kept(ep: importlib.metadata.EntryPoint) -> bool:
            dist = getattr(ep, "dist", None)
            if dist is None:
                return False
            if PluginSource(ep.name, dist.metadata["Name"] or "").builtin:
                return True
            return Path(dist.locate_file("")).resolve() in mine  # the folder holding its *.dist-info

        return [ep for ep in DISCOVER(group) if kept(ep)]

    return lookup


@contextmanager
def only_own_plugins(*sites: Path) -> Iterator[pytest.MonkeyPatch]:
    """`sites` on sys.path and the registry seeing only their plugins and the built-ins; default_registry's cached
    registry is put back as it was on exit, so nothing a test loads outlives it."""
    with pytest.MonkeyPatch.context() as mp:
        for site in sites:
            mp.syspath_prepend(str(site))
        mp.setattr(plugin_loading, "installed_entry_points", own_entry_points(sites))
        mp.setattr(registry, "_DEFAULT", None)
        yield mp


def run_cli(site: Path, *args: str, env: dict[str, str] | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """`clods-bench ARGS` in a fresh interpreter with `site` on its path (as if the plugins were pip-installed)."""
    import os

    full = {k: v for k, v in os.environ.items() if k != "CLODS_BENCH_STRICT_PLUGINS"}
    full["PYTHONPATH"] = os.pathsep.join([str(site), str(ROOT)])
    full.update(env or {})
    cmd = [sys.executable, "-m", "clods_bench.cli", *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=full, cwd=cwd or ROOT, timeout=300)
