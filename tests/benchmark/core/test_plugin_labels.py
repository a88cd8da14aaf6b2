"""Row labels come from one place (`PluginSpec.label` / `variant`): tables, the plan and the claims agree with it.

A plugin whose description calls it a variant must declare how it differs, and then no committed table row, plan
row or claim may print its published name without that qualifier.
"""

from __future__ import annotations

import csv
import re
from pathlib import Path

import pytest
import yaml

from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.claims_check import rule_rows
from clods_bench.benchmark.reproduction.reproduce import PlanRun, default_plan_path, load_plan, settle_label

ROOT = Path(__file__).resolve().parents[3]
KINDS = ("simulator", "renderer", "video_predictor")
CHECKED_TABLES = [ROOT / "results" / "ci", ROOT / "results" / "small-partial" / "2026-12-07-table2-rerun"]  # tables made with the labels of this release


def builtin_specs() -> list[PluginSpec]:
    registry = default_registry()
    return [registry.get(kind, name) for kind in KINDS for name in registry.names(kind)
            if registry.sources[registry.origins[(kind, name)]].builtin]  # fmt: skip


def variants() -> list[PluginSpec]:
    return [spec for spec in builtin_specs() if spec.variant]


def names_published(label: str, spec: PluginSpec) -> bool:
    """Whether `label` names the published model `spec.label` (as a word: 'BSMS*' does, 'BSMSX' does not)."""
    return re.search(rf"(?<![A-Za-z]){re.escape(spec.label or spec.name)}(?![A-Za-z])", label) is not None


def test_every_builtin_plugin_declares_its_label_and_a_variant_says_how_it_differs():
    specs = builtin_specs()
    assert specs and all(spec.label for spec in specs)
    for spec in specs:
        called_variant = "variant" in spec.description.lower()
        assert called_variant == bool(spec.variant), f"{spec.name}: description and `variant` disagree"
    assert {spec.name for spec in variants()} == {"bsms", "hcmt", "dhmp"}


def test_row_label_puts_the_star_before_the_qualifier():
    spec = PluginSpec(name="x", description="a variant", build=lambda c, ctx: None, label="X", variant="other frame")
    assert spec.row_label() == "X (other frame)" and spec.row_label(first_half=True) == "X* (other frame)"
    assert PluginSpec(name="y", description="", build=lambda c, ctx: None).row_label(True) == "y*"


def committed_labels() -> list[tuple[Path, str]]:
    rows = []
    for folder in CHECKED_TABLES:
        for path in sorted(folder.rglob("*.csv")):
            with open(path, newline="") as f:
                reader = csv.DictReader(f)
                if reader.fieldnames and reader.fieldnames[0] == "method":
                    rows += [(path, row["method"]) for row in reader]
    return rows


def test_no_committed_table_row_prints_a_variant_under_its_published_name():
    rows = committed_labels()
    assert len(rows) > 50  # the ci tables are there to be checked
    bad = [(p.relative_to(ROOT), label) for p, label in rows for spec in variants() if names_published(label, spec) and spec.variant not in label]
    assert not bad, bad


def test_no_plan_row_or_claim_names_a_variant_without_its_qualifier():
    registry = default_registry()
    plan = load_plan(default_plan_path())
    for run in plan.runs:
        assert settle_label(run, registry) is None, run
    claims = yaml.safe_load((ROOT / "docs" / "claims.yaml").read_text())
    named = [(claim["id"], row) for claim in claims["claims"] for row in rule_rows(claim.get("rule", {}))]
    assert len(named) > 50
    bad = [(cid, row) for cid, row in named for spec in variants() if names_published(row, spec) and spec.variant not in row]
    assert not bad, bad


def test_a_plan_row_naming_a_variant_bare_is_refused_and_a_row_without_label_takes_the_plugins():
    registry = default_registry()
    bare = PlanRun(table="table2_cdg", task="cdg", label="BSMS", sim="bsms")
    problem = settle_label(bare, registry)
    assert problem and "BSMS" in problem and "MGN cloth frame" in problem
    derived = PlanRun(table="table2_cdg", task="cdg", sim="dhmp", train_subset="first_half")
    assert settle_label(derived, registry) is None and derived.label == "DHMP* (MGN cloth frame)"
    two = PlanRun(table="table2_cdg", task="cdg", sim="mgn", renderer="smgs")
    assert "give the row a `label:`" in (settle_label(two, registry) or "")


@pytest.mark.parametrize("label", ["", "  "])
def test_an_empty_label_is_refused_at_registration(label):
    from clods_bench.benchmark.core.plugin_checks import check_hook_result
    from clods_bench.errors import ClodsError

    spec = PluginSpec(name="z", description="", build=lambda c, ctx: None, label=label)
    with pytest.raises(ClodsError, match="label"):
        check_hook_result("simulator", "clods_bench_simulators", [spec])
