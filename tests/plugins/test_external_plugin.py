"""A simulator defined outside the package, registered through the entry-point path, runs CDG."""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import numpy as np

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from tests.conftest import tiny_config

PLUGIN = '''
"""A third-party simulator: damped constant velocity, with a typed config."""
from dataclasses import dataclass
import numpy as np
from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl


@dataclass(frozen=True)
class DampedConfig:
    damping: float = 0.5
    """Fraction of the velocity kept each step."""


class Damped:
    def __init__(self, cfg):
        self.cfg = cfg
        self.fitted_on = 0

    def fit(self, train, ctx):
        self.fitted_on = len(train)
        return {"num_train": float(len(train))}

    def rollout(self, inp):
        x = np.empty(inp.kinematic_pos.shape, np.float64)
        x[:2] = inp.init_pos
        free = ~inp.kinematic_mask
        for t in range(2, inp.num_frames):
            x[t] = inp.kinematic_pos[t]
            x[t, free] = x[t - 1, free] + self.cfg.damping * (x[t - 1, free] - x[t - 2, free])
        return x.astype(np.float32)


@hookimpl
def clods_bench_simulators():
    return [PluginSpec(name="damped", description="damped constant velocity", build=lambda cfg, ctx: Damped(cfg), config_cls=DampedConfig)]
'''


def _install_fake_distribution(site: Path) -> None:
    """Write a module plus a *.dist-info with an entry point, as `pip install` of a plugin would."""
    (site / "my_cloth_plugin.py").write_text(PLUGIN)
    info = site / "my_cloth_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-cloth-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent("[clods_bench]\nmy_cloth_plugin = my_cloth_plugin\n"))


def test_external_simulator_runs_cdg(tmp_path: Path, tiny_root: Path, monkeypatch) -> None:
    site = tmp_path / "site"
    site.mkdir()
    _install_fake_distribution(site)
    monkeypatch.syspath_prepend(str(site))
    try:
        reg = default_registry(refresh=True)
        assert "damped" in reg.names("simulator")
        assert reg.origins[("simulator", "damped")] == "my_cloth_plugin"
        cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", "sim_config.damped.damping=0.0", sim="damped")
        rdir = run_task(cfg, reg)
        rec = json.loads((rdir / RECORD_FILE).read_text())
        assert rec["label"] == "damped"
        assert rec["per_seed"]["0"]["timings"]["fit/num_train"] == 2.0
        for key in ("viewed/interp/d_avg", "unviewed/extrap/d_end"):
            assert np.isfinite(rec["metrics"][key]["mean"])
        assert rec["timings"]["infer_ms_per_step"]["mean"] > 0
    finally:
        sys.modules.pop("my_cloth_plugin", None)
        monkeypatch.undo()
        default_registry(refresh=True)
