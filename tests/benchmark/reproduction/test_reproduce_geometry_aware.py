"""The plan's geometry-aware table: its CloDS row is Table 2's CloDS run (run once); CS is GaMeS + MGN with the filter start."""

from __future__ import annotations

from clods_bench.benchmark.clods.config import clods_config
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.reproduction.reproduce import build_configs, config_identity, default_plan_path, load_plan


def test_geometry_aware_rows_resolve_to_the_intended_configs() -> None:
    runs = build_configs(load_plan(default_plan_path()), "ci", default_registry())
    rows = {(run.table, run.label): cfg for run, cfg in runs}
    clods, cs = rows[("geometry_aware", "CloDS")], rows[("geometry_aware", "CS-style")]
    assert config_identity(clods) == config_identity(rows[("table2_cdg", "CloDS")])  # shared: no extra CI cost
    assert (cs.sim, cs.renderer, cs.train_subset) == ("mgn", "games", "all")
    opts = clods_config(cs)
    assert (opts.variant, opts.start) == ("finetune", "simulator")
    assert opts.iterations == clods_config(clods).iterations  # the ci preset's stage-2 sizes apply to both rows
