"""The built-in plan's row labels say what runs at every preset: a number in a label ("MGN (4 steps)", "3 cameras",
"10 per face", "gamma = 0.001", "Physics (2 dt)") must equal the resolved config's value at ci, small and paper, not
only at the preset the row was written for (a row relying on a preset default is mislabelled where that default
differs, e.g. MGN's message-passing steps: 4 at ci, 10 at small, 15 at paper)."""

from __future__ import annotations

import re
from typing import Any, Callable

import pytest

from clods_bench.benchmark.clods.config import clods_config
from clods_bench.benchmark.core.config import RunConfig
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.reproduction.reproduce import PlanRun, build_configs, load_plan, run_name

PRESETS = ("ci", "small", "paper")
# Names whose digits are not settings (checked against nothing): the method names 2DGS and 3DGS, CloDS's stage 0.
NUMBERLESS = re.compile(r"\b[23]DGS\b|\bStage 0\b")


def _training_cameras(cfg: RunConfig) -> int:
    n = clods_config(cfg).num_cameras
    return int(n) if n is not None else cfg.data.num_cameras - cfg.data.num_views_test


# (pattern, what the label claims, the resolved value): every pattern's group 1 is the claimed number (empty: 1).
CLAIMS: list[tuple[re.Pattern[str], str, Callable[[RunConfig], Any]]] = [
    (re.compile(r"\((\d+) steps\)"), "message-passing steps", lambda c: c.sim_config[c.sim]["message_passing_steps"]),
    (re.compile(r"^(\d+) cameras$"), "training cameras of stages 1-2", _training_cameras),
    (re.compile(r"^(\d+) per face$"), "Gaussians per face", lambda c: c.renderer_config[c.renderer]["gaussians_per_face"]),
    (re.compile(r"gamma = ([0-9.]+)"), "edge-loss weight", lambda c: clods_config(c).gamma),
    (re.compile(r"\((\d*) ?dt\)"), "solver time-step factor", lambda c: c.sim_config[c.sim]["dt_factor"]),  # "(dt)": 1
]


def label_claims(run: PlanRun, cfg: RunConfig) -> list[tuple[str, float, float]]:
    """(what, claimed, resolved) for every number the row's label names; a digit no pattern explains is an error."""
    label, out = run.label, []
    rest = NUMBERLESS.sub("", label)
    for pattern, what, value in CLAIMS:
        for m in pattern.finditer(label):
            out.append((what, float(m.group(1) or 1), float(value(cfg))))
            rest = rest.replace(m.group(0), "")
    if re.search(r"\d", rest):
        raise AssertionError(f"{run_name(run)}: label names a number this test does not check: {rest!r} (add a pattern)")
    return out


@pytest.fixture(scope="module")
def resolved() -> dict[str, list[tuple[PlanRun, RunConfig]]]:
    registry, plan = default_registry(), load_plan()
    return {preset: build_configs(plan, preset, registry) for preset in PRESETS}


@pytest.mark.parametrize("preset", PRESETS)
def test_every_number_in_a_label_holds_at_the_preset(resolved: dict, preset: str) -> None:
    wrong, checked = [], 0
    for run, cfg in resolved[preset]:
        for what, claimed, value in label_claims(run, cfg):
            checked += 1
            if abs(claimed - value) > 1e-12:
                wrong.append(f"{run_name(run)}: label says {claimed:g} {what}, the {preset} config runs {value:g}")
    assert not wrong, "\n".join(wrong)
    assert checked >= 14  # the steps, cameras, density, gamma and dt rows were all found


def test_the_check_catches_a_row_relying_on_a_preset_default() -> None:
    """The row this test was written for: 'MGN (4 steps)' without an override is right at ci and wrong at small."""
    registry = default_registry()
    plan = load_plan()
    plan.tables = [t for t in plan.tables if t.id == "error_vs_time"]
    plan.runs = [PlanRun(table="error_vs_time", task="cdg", label="MGN (4 steps)", sim="mgn")]
    [(ci_run, ci_cfg)] = build_configs(plan, "ci", registry)
    [(small_run, small_cfg)] = build_configs(plan, "small", registry)
    assert label_claims(ci_run, ci_cfg) == [("message-passing steps", 4.0, 4.0)]
    assert label_claims(small_run, small_cfg) == [("message-passing steps", 4.0, 10.0)]


def test_an_unchecked_number_in_a_label_fails() -> None:
    run = PlanRun(table="t", task="cdg", label="MGN (7 layers)", sim="mgn")
    with pytest.raises(AssertionError, match="does not check"):
        label_claims(run, None)  # type: ignore[arg-type]
