"""`reproduce`: a plan (YAML) runs into tables + manifest; bad plans fail before any work; reruns are identical."""

from __future__ import annotations

import dataclasses
import json
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from rich.console import Console

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.reproduction.reproduce import build_configs, default_plan_path, load_plan, reproduce
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.run_data import ensure_complete_dataset
from clods_bench.benchmark.running.runner import run_task
from clods_bench.cli import main
from clods_bench.errors import ClodsError
from tests.conftest import TINY, tiny_config

PLAN = textwrap.dedent(
    """\
    version: 1
    description: tiny test plan
    tables:
      - {id: t_cdg, task: cdg, title: "CDG baselines"}
      - {id: t_damp, task: cdg, title: "the same baseline under two labels"}
    runs:
      - {table: t_cdg, task: cdg, label: Const. velocity, sim: constvel}
      - {table: t_cdg, task: cdg, label: Frozen, sim: frozen}
      - {table: t_damp, task: cdg, label: frozen again, sim: frozen}
    """
)


def _overrides(root: Path, runs: Path) -> list[str]:
    return [*TINY, f"data.root={root / 'data'}", f"runs_dir={runs}", "seeds=[0, 1]"]


def _plan(tmp_path: Path, text: str = PLAN) -> Path:
    path = tmp_path / "plan.yaml"
    path.write_text(text)
    return path


def test_builtin_plan_loads_and_every_enabled_run_is_installed() -> None:
    plan = load_plan(default_plan_path())
    runs = build_configs(plan, "ci", default_registry())
    tables = {t.id for t in plan.tables}
    assert {"table2_cdg", "table3_nvs", "stability"} <= tables
    assert len(runs) == len(plan.runs) and all(len(cfg.seeds) >= 2 for _, cfg in runs)


def test_backbone_ablation_has_every_learned_backbone_and_reuses_table2_for_mgn() -> None:
    """Paper Fig. 6a: X* and CloDS (X) per backbone; MGN's two rows resolve to Table 2's MGN* and CloDS configs (run once)."""
    from clods_bench.benchmark.reproduction.reproduce import config_identity

    runs = build_configs(load_plan(default_plan_path()), "ci", default_registry())
    rows = {(run.table, run.label): cfg for run, cfg in runs}
    variant = {"mgn": "", "bsms": " (MGN cloth frame)", "hcmt": " (MGN cloth frame)", "dhmp": " (MGN cloth frame)"}
    for sim in ("mgn", "bsms", "hcmt", "dhmp"):
        name, qualifier = sim.upper(), variant[sim]
        star = rows[("ablation_backbone", f"{name}*{qualifier}")]
        clods = rows[("ablation_backbone", f"CloDS ({name}{qualifier.replace(' (', ', ').rstrip(')')})")]
        assert (star.sim, star.renderer, star.train_subset) == (sim, None, "first_half")
        assert (clods.sim, clods.renderer) == (sim, "smgs") and clods.task_config["clods"]["variant"] == "finetune"
    assert config_identity(rows[("ablation_backbone", "MGN*")]) == config_identity(rows[("table2_cdg", "MGN*")])
    assert config_identity(rows[("ablation_backbone", "CloDS (MGN)")]) == config_identity(rows[("table2_cdg", "CloDS")])
    assert config_identity(rows[("ablation_backbone", "CloDS (BSMS, MGN cloth frame)")]) != config_identity(rows[("table2_cdg", "CloDS")])
    assert rows[("table2_cdg", "DHMP (MGN cloth frame)")].sim == "dhmp"


def test_lighting_table_differs_from_table2_clods_only_in_the_scene() -> None:
    """Paper lighting table: 'w/o light' is Table 2's CloDS** run (run once), 'light' the same config on flag-lit."""
    from clods_bench.benchmark.reproduction.reproduce import config_identity

    runs = build_configs(load_plan(default_plan_path()), "ci", default_registry())
    rows = {(run.table, run.label): cfg for run, cfg in runs}
    lit, unlit, clods2 = rows[("lighting_cdg", "light")], rows[("lighting_cdg", "w/o light")], rows[("table2_cdg", "CloDS**")]
    assert config_identity(unlit) == config_identity(clods2) and unlit.data.scene == "flag"
    assert lit.data.scene == "flag-lit" and default_registry().get("scene", "flag-lit").has_lighting
    assert config_identity(dataclasses.replace(lit, data=dataclasses.replace(lit.data, scene="flag"))) == config_identity(clods2)


def test_reproduce_writes_tables_and_manifest_matching_the_records(tmp_path: Path, tiny_root: Path) -> None:
    out = tmp_path / "results"
    manifest = reproduce("ci", out, default_registry(), Console(quiet=True), plan_path=_plan(tmp_path), overrides=_overrides(tiny_root, tmp_path / "runs"))
    for stem in ("t_cdg", "t_damp"):
        for suffix in (".md", ".tex", ".csv"):
            assert (out / f"{stem}{suffix}").is_file()
    on_disk = json.loads((out / "manifest.json").read_text())
    assert on_disk["tables"] == ["t_cdg", "t_damp"] and "numpy" in on_disk["versions"] and "commit" in on_disk
    assert on_disk["wall_seconds_total"] > 0 and len(on_disk["runs"]) == 3
    # the duplicate row ran once and points at its twin
    dup = next(r for r in manifest["runs"] if r["label"] == "frozen again")
    assert dup["same_as"] == "t_cdg/Frozen" and dup["seeds_run"] == []
    first = next(r for r in manifest["runs"] if r["label"] == "Frozen")
    assert first["seeds_run"] == [0, 1] and first["wall_seconds"] > 0

    csv = pd.read_csv(out / "t_cdg.csv").set_index("method")
    for run in manifest["runs"][:2]:
        rec = json.loads((Path(run["record_dir"]) / RECORD_FILE).read_text())
        assert rec["seeds"] == [0, 1]
        for key in ("viewed/interp/d_avg", "unviewed/extrap/d_end"):
            assert csv.loc[run["label"], f"{key}/mean"] == pytest.approx(rec["metrics"][key]["mean"], rel=1e-12)
            per_seed = [rec["per_seed"][s]["metrics"][key] for s in ("0", "1")]
            assert rec["metrics"][key]["mean"] == pytest.approx(np.mean(per_seed), rel=1e-12)
    damp = pd.read_csv(out / "t_damp.csv").set_index("method")
    assert damp.loc["frozen again", "unviewed/extrap/d_avg/mean"] == csv.loc["Frozen", "unviewed/extrap/d_avg/mean"]
    assert "Const. velocity" in (out / "t_cdg.md").read_text()

    # resumable: a second call reruns no seed and writes the same CSVs
    before = (out / "t_cdg.csv").read_text()
    again = reproduce("ci", out, default_registry(), Console(quiet=True), plan_path=_plan(tmp_path), overrides=_overrides(tiny_root, tmp_path / "runs"))
    assert all(r["seeds_run"] == [] for r in again["runs"])
    assert (out / "t_cdg.csv").read_text() == before


def test_unregistered_plugins_and_tasks_fail_listing_every_problem(tmp_path: Path, tiny_root: Path) -> None:
    bad = PLAN + (
        "  - {table: t_cdg, task: cdg, label: typo, sim: constvl}\n"
        "  - {table: t_cdg, task: nosuchtask, label: nope, sim: constvel}\n"
        "  - {table: t_missing, task: cdg, label: orphan, sim: frozen}\n"
        '  - {table: t_cdg, task: cdg, label: Frozen, sim: frozen, overrides: ["data.num_trian=3"]}\n'
    )
    runs = tmp_path / "runs"
    with pytest.raises(ClodsError) as err:
        reproduce("ci", tmp_path / "out", default_registry(), Console(quiet=True), plan_path=_plan(tmp_path, bad), overrides=_overrides(tiny_root, runs))
    msg = err.value.message
    assert "sim: unknown simulator 'constvl'" in msg and "did you mean 'constvel'" in msg  # names the row's option
    assert "task 'nosuchtask' but table 't_cdg' holds 'cdg' rows" in msg and "task 'nosuchtask' is not registered" in msg
    assert "unknown table 't_missing'" in msg
    assert "label 'Frozen' appears twice" in msg and "data.num_trian" in msg
    assert not runs.exists() and not (tmp_path / "out").exists()  # nothing ran


def test_one_seed_is_refused(tmp_path: Path, tiny_root: Path) -> None:
    with pytest.raises(ClodsError, match="reproduce needs at least 2"):
        build_configs(load_plan(_plan(tmp_path)), "ci", default_registry(), [*_overrides(tiny_root, tmp_path), "seeds=[3]"])


def test_first_seeds_keeps_the_first_seeds_and_lifts_the_two_seed_rule(tmp_path: Path, tiny_root: Path) -> None:
    plan = load_plan(_plan(tmp_path))
    runs = build_configs(plan, "ci", default_registry(), [*_overrides(tiny_root, tmp_path), "seeds=[3, 5, 7]"], first_seeds=2)
    assert runs and all(cfg.seeds == [3, 5] for _, cfg in runs)
    runs = build_configs(plan, "ci", default_registry(), [*_overrides(tiny_root, tmp_path), "seeds=[3]"], first_seeds=1)
    assert all(cfg.seeds == [3] for _, cfg in runs)
    with pytest.raises(ClodsError, match="first_seeds must be >= 1"):
        build_configs(plan, "ci", default_registry(), _overrides(tiny_root, tmp_path), first_seeds=0)


def test_cli_check_on_the_first_seed_compares_with_the_first_seed_tables(tmp_path: Path, tiny_root: Path) -> None:
    plan = _plan(tmp_path)
    sets = [arg for o in _overrides(tiny_root, tmp_path / "runs") for arg in ("--set", o)]
    committed = tmp_path / "committed"
    assert main(["reproduce", "--plan", str(plan), "--out", str(committed), *sets]) == 0
    (committed / "tolerance.yaml").write_text("default: {rel: 0.0, abs: 0.0}\nexclude: ['*_ms_per_*', '*seconds*']\n")
    table = pd.read_csv(committed / "t_cdg.csv")
    table.loc[0, "viewed/interp/d_avg/mean"] *= 1.5  # the two-seed table: a first-seed check does not read it
    table.to_csv(committed / "t_cdg.csv", index=False)
    assert set(pd.read_csv(committed / "first_seed" / "t_cdg.csv")["seeds"]) == {1}
    fresh = tmp_path / "fresh"
    assert main(["reproduce", "--plan", str(plan), "--out", str(fresh), "--first-seeds", "1", "--check", str(committed), *sets]) == 0
    assert set(pd.read_csv(fresh / "t_cdg.csv")["seeds"]) == {1}
    assert json.loads((fresh / "manifest.json").read_text())["first_seeds"] == 1
    first = pd.read_csv(committed / "first_seed" / "t_cdg.csv")
    first.loc[0, "viewed/interp/d_avg/mean"] = np.nextafter(first.loc[0, "viewed/interp/d_avg/mean"], 1.0)  # one ulp in the first seed's
    first.to_csv(committed / "first_seed" / "t_cdg.csv", index=False)
    assert main(["reproduce", "--plan", str(plan), "--out", str(fresh), "--first-seeds", "1", "--check", str(committed), *sets]) == 1


def test_cli_reproduce_check_passes_then_fails_when_a_committed_number_differs(tmp_path: Path, tiny_root: Path) -> None:
    plan = _plan(tmp_path)
    sets = [arg for o in _overrides(tiny_root, tmp_path / "runs") for arg in ("--set", o)]
    committed = tmp_path / "committed"
    assert main(["reproduce", "--plan", str(plan), "--out", str(committed), *sets]) == 0
    (committed / "tolerance.yaml").write_text("default: {rel: 1.0e-6, abs: 1.0e-9}\nexclude: ['*_ms_per_*', '*seconds*']\n")
    fresh = tmp_path / "fresh"
    assert main(["reproduce", "--plan", str(plan), "--out", str(fresh), "--check", str(committed), *sets]) == 0
    table = pd.read_csv(committed / "t_cdg.csv")
    table.loc[0, "viewed/interp/d_avg/mean"] *= 1.01
    table.to_csv(committed / "t_cdg.csv", index=False)
    assert main(["reproduce", "--plan", str(plan), "--out", str(fresh), "--check", str(committed), *sets]) == 1
    assert main(["reproduce", "--plan", str(plan), "--out", str(committed), "--check", str(committed), *sets]) == 2  # would compare with itself


def test_same_learned_config_twice_gives_identical_metrics(tmp_path: Path, tiny_root: Path) -> None:
    """The runner seeds every RNG: two fresh runs of a trained MGN (separate record dirs) agree bit for bit."""
    extra = ["sim_config.mgn.train_steps=15", "sim_config.mgn.latent_size=16", "sim_config.mgn.message_passing_steps=2", "sim_config.mgn.warmup_steps=2"]
    recs = []
    for name in ("a", "b"):
        cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / name}", *extra, sim="mgn")
        recs.append(json.loads((run_task(cfg, default_registry(), ensure_data=ensure_complete_dataset) / RECORD_FILE).read_text()))
    assert recs[0]["per_seed"]["0"]["metrics"] == recs[1]["per_seed"]["0"]["metrics"]
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'c'}", *extra, "seeds=[1]", sim="mgn")
    other = json.loads((run_task(cfg, default_registry(), ensure_data=ensure_complete_dataset) / RECORD_FILE).read_text())
    assert other["per_seed"]["1"]["metrics"] != recs[0]["per_seed"]["0"]["metrics"]  # the seed does matter


def test_override_order_plan_then_table_then_run_then_command_line(tmp_path: Path) -> None:
    text = (
        "version: 1\noverrides: [data.num_test=5, data.num_train=6]\n"
        "tables:\n  - {id: t, task: cdg, title: T, overrides: [data.num_test=4, data.interp_steps=20]}\n"
        "runs:\n  - {table: t, task: cdg, label: a, sim: frozen, overrides: [data.num_test=3]}\n"
        "  - {table: t, task: cdg, label: b, sim: frozen}\n"
    )
    runs = build_configs(load_plan(_plan(tmp_path, text)), "ci", default_registry(), ["data.interp_steps=25"])
    (_, a), (_, b) = runs
    assert (a.data.num_train, a.data.num_test, a.data.interp_steps) == (6, 3, 25)
    assert (b.data.num_train, b.data.num_test, b.data.interp_steps) == (6, 4, 25)
    assert a.label == "a" and a.seeds == [0, 1]  # the ci preset's seeds


def test_a_label_may_repeat_across_scenes_and_each_scene_gets_its_row(tmp_path: Path, tiny_root: Path) -> None:
    """The stability table's layout: one row per (simulator, scene); a row's `scene:` picks its dataset."""
    text = (
        "version: 1\ntables:\n  - {id: stab, task: stability, title: S, overrides: [task_config.stability.horizon_factor=1.5]}\n"
        "runs:\n  - {table: stab, task: stability, label: Const. velocity, sim: constvel}\n"
        "  - {table: stab, task: stability, label: Const. velocity, sim: constvel, scene: flag-stiff, overrides: [data.render_frames=false]}\n"
    )
    out = tmp_path / "out"
    manifest = reproduce("ci", out, default_registry(), Console(quiet=True), plan_path=_plan(tmp_path, text), overrides=_overrides(tiny_root, tmp_path / "runs"))
    assert [r["same_as"] for r in manifest["runs"]] == [None, None]  # two scenes: two runs, not one run twice
    table = pd.read_csv(out / "stab.csv").set_index(["method", "scene"])
    assert sorted(table.index) == [("Const. velocity", "flag"), ("Const. velocity", "flag-stiff")]
    # different data: the stiff flag moves differently, so the same baseline scores differently on it
    assert table.loc[("Const. velocity", "flag"), "rmse/mean"] != table.loc[("Const. velocity", "flag-stiff"), "rmse/mean"]
    stiff_dir = Path(manifest["runs"][1]["record_dir"])
    assert "flag-stiff" in stiff_dir.name
    rec = json.loads((stiff_dir / RECORD_FILE).read_text())
    assert rec["scene"] == "flag-stiff"

    twice = text + "  - {table: stab, task: stability, label: Const. velocity, sim: frozen, scene: flag-stiff}\n"
    with pytest.raises(ClodsError, match=r"label 'Const. velocity' appears twice in table 'stab' \(flag-stiff\)"):
        build_configs(load_plan(_plan(tmp_path, twice)), "ci", default_registry(), _overrides(tiny_root, tmp_path / "runs"))


def test_shape_generalisation_rows_share_table2_and_score_the_cylinder_trained_rows_data() -> None:
    """A -> B rows: flag -> flag is Table 2's run; flag -> cylinder trains as Table 2 does (same data and simulator
    options, so the same cached fit) and scores the very dataset the cylinder -> cylinder row trains and scores on."""
    from clods_bench.benchmark.core.eval_data import scored_data
    from clods_bench.benchmark.reproduction.reproduce import config_identity

    reg = default_registry()
    rows = {(run.table, run.label): cfg for run, cfg in build_configs(load_plan(default_plan_path()), "ci", reg)}
    for name, t2 in (("CloDS**", "CloDS**"), ("MGN", "MGN")):
        same, cross, home = (rows[("shape_generalisation", f"{name} {a} -> {b}")] for a, b in (("flag", "flag"), ("flag", "cylinder"), ("cylinder", "cylinder")))
        assert config_identity(same) == config_identity(rows[("table2_cdg", t2)])
        assert cross.data == same.data and cross.sim_config == same.sim_config and cross.task_config.get("clods") == same.task_config.get("clods")
        assert scored_data(cross, reg) == scored_data(home, reg) == home.data and home.data.scene == "cylinder"
        assert scored_data(cross, reg).dataset_dir() != cross.data.dataset_dir()


def test_dry_run_lists_the_seeds_already_recorded(tmp_path: Path, tiny_root: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--dry-run` says which (run, seed) jobs a resumed `reproduce` would skip; a row reusing another's config counts once."""
    plan = _plan(tmp_path)
    sets = [arg for o in _overrides(tiny_root, tmp_path / "runs") for arg in ("--set", o)]
    assert main(["reproduce", "--plan", str(plan), "--dry-run", *sets]) == 0
    assert "0 of 4 seed jobs have records" in capsys.readouterr().out and not (tmp_path / "runs").exists()
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path / 'runs'}", "seeds=[1]", label="Frozen", sim="frozen")  # one seed of one row, run directly
    run_task(cfg, default_registry(), ensure_data=ensure_complete_dataset)
    assert main(["reproduce", "--plan", str(plan), "--dry-run", *sets]) == 0
    out = capsys.readouterr().out
    assert "1 of 4 seed jobs have records" in out and "3 to run" in out
    assert main(["reproduce", "--plan", str(plan), "--out", str(tmp_path / "out"), *sets]) == 0
    capsys.readouterr()
    assert main(["reproduce", "--plan", str(plan), "--dry-run", *sets]) == 0
    assert "4 of 4 seed jobs have records" in capsys.readouterr().out


BUDGET_PLAN = textwrap.dedent(
    """\
    version: 1
    description: two tables for the time budget
    tables:
      - {id: t_first, task: cdg, title: "first"}
      - {id: t_second, task: cdg, title: "second"}
    runs:
      - {table: t_second, task: cdg, label: Frozen, sim: frozen}
      - {table: t_first, task: cdg, label: Const. velocity, sim: constvel}
    """
)  # runs listed against the tables' order: jobs still start table by table, t_first's first


def _deadline_after(monkeypatch: pytest.MonkeyPatch, jobs_allowed: int) -> None:
    """Make the executor's deadline pass once `jobs_allowed` jobs have started (the serial executor asks before each)."""
    import clods_bench.benchmark.running.executors as executors

    asked = []

    def past(deadline: float | None) -> bool:
        asked.append(deadline)
        return deadline is not None and len(asked) > jobs_allowed

    monkeypatch.setattr(executors, "_past", past)


def test_a_time_budget_writes_the_finished_tables_and_the_next_run_resumes(tmp_path: Path, tiny_root: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    plan = _plan(tmp_path, BUDGET_PLAN)
    over = _overrides(tiny_root, tmp_path / "runs")
    _deadline_after(monkeypatch, 1)
    first = reproduce("ci", tmp_path / "out", default_registry(), Console(quiet=True), "local", plan, over, first_seeds=1, budget_seconds=100)
    assert first["unfinished"] == {"t_second": ["Frozen"]} and first["budget_seconds"] == 100
    assert (tmp_path / "out" / "t_first.csv").is_file() and not (tmp_path / "out" / "t_second.csv").exists()
    assert [r["label"] for r in first["runs"]] == ["Const. velocity"]
    monkeypatch.undo()
    again = reproduce("ci", tmp_path / "out", default_registry(), Console(quiet=True), "local", plan, over, first_seeds=1)
    assert again["unfinished"] == {} and (tmp_path / "out" / "t_second.csv").is_file()
    seeds_run = {r["label"]: r["seeds_run"] for r in again["runs"]}
    assert seeds_run == {"Const. velocity": [], "Frozen": [0]}  # the finished row is resumed, not rerun
    fresh = reproduce("ci", tmp_path / "fresh", default_registry(), Console(quiet=True), "local", plan, _overrides(tiny_root, tmp_path / "runs2"), first_seeds=1)
    a, b = (pd.read_csv(tmp_path / d / "t_first.csv") for d in ("out", "fresh"))
    metrics = [c for c in a.columns if c.endswith("/mean")]
    assert len(metrics) > 4 and a[metrics].equals(b[metrics])  # the budgeted run's table holds the unbudgeted numbers
    with pytest.raises(ClodsError, match="--budget"):
        reproduce("ci", tmp_path / "x", default_registry(), Console(quiet=True), "local", plan, over, first_seeds=1, budget_seconds=0)
    with pytest.raises(ClodsError, match="local executor"):
        reproduce("ci", tmp_path / "x", default_registry(), Console(quiet=True), "ray", plan, over, first_seeds=1, budget_seconds=10)
    assert fresh["unfinished"] == {}


def test_cli_check_under_a_budget_names_the_tables_it_did_not_check(
    tmp_path: Path, tiny_root: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = _plan(tmp_path, BUDGET_PLAN)
    sets = [arg for o in _overrides(tiny_root, tmp_path / "runs") for arg in ("--set", o)]
    committed = tmp_path / "committed"
    assert main(["reproduce", "--plan", str(plan), "--out", str(committed), "--first-seeds", "1", *sets]) == 0
    (committed / "tolerance.yaml").write_text("default: {rel: 1.0e-6, abs: 1.0e-9}\nexclude: ['*_ms_per_*', '*seconds*']\n")
    frozen = pd.read_csv(committed / "t_second.csv")
    frozen.loc[0, "viewed/interp/d_avg/mean"] *= 1.5  # a moved number in the table the budget leaves out
    frozen.to_csv(committed / "t_second.csv", index=False)
    fresh = tmp_path / "fresh"
    check = ["reproduce", "--plan", str(plan), "--out", str(fresh), "--first-seeds", "1", "--check", str(committed), *sets]
    capsys.readouterr()
    _deadline_after(monkeypatch, 0)  # everything recorded already: the runs resume, so give the fresh tables a new runs_dir
    sets2 = [arg for o in _overrides(tiny_root, tmp_path / "runs_fresh") for arg in ("--set", o)]
    check = [*check[: -len(sets)], *sets2]
    assert main([*check, "--budget", "5"]) == 2  # nothing could start: nothing was checked, an error
    assert "left no table to check" in capsys.readouterr().err
    _deadline_after(monkeypatch, 1)
    assert main([*check, "--budget", "5"]) == 0  # t_first checked and equal; t_second not run, so not compared
    out = capsys.readouterr().out
    assert "not checked (left by the time budget): t_second" in out and "1 of 2 tables finished" in out
    monkeypatch.undo()
    assert main(check) == 1  # without a budget the moved number in t_second is found
