"""`--device` on `run` and `reproduce`: one line and exit 2 before any work when the device does not exist, the resolved
configs carry it into every plugin that can use it (a GPU pretended; nothing runs on CUDA)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from clods_bench.benchmark.running import runner
from clods_bench.cli import main


def pretend_gpus(monkeypatch: pytest.MonkeyPatch, n: int) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: n > 0)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: n)


@pytest.fixture
def caught(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> list:
    """`run`'s runner replaced: the config it was handed is kept, a one-metric record returned (nothing computes)."""
    seen: list = []

    def fake_run_task(cfg, registry, console=None, ensure_data=None):
        from clods_bench.benchmark.core.resolve import resolve_plugins

        seen.append(resolve_plugins(cfg, registry))
        (tmp_path / "record.json").write_text(json.dumps({"task": cfg.task, "label": "x", "scene": "flag", "preset": "ci", "seeds": [0],
                                                          "metrics": {"rmse": {"mean": 1.0, "std": 0.0}}, "timings": {}}))  # fmt: skip
        return tmp_path

    monkeypatch.setattr(runner, "run_task", fake_run_task)
    monkeypatch.chdir(tmp_path)
    return seen


@pytest.mark.parametrize(
    "argv, gpus, line",
    [
        (["run", "cdg", "--sim", "mgn", "--device", "cuda"], 0, "--device cuda: no CUDA device is available (torch {v} is a CPU build)"),
        (["run", "nvs", "--renderer", "smgs", "--set", "device=cuda:0"], 0, "device cuda:0: no CUDA device is available (torch {v} is a CPU build)"),
        (["run", "cdg", "--sim", "mgn", "--device", "cuda:3"], 1, "--device cuda:3: only cuda:0 exists"),
        (["reproduce", "--preset", "small", "--device", "cuda"], 0, "--device cuda: no CUDA device is available (torch {v} is a CPU build)"),
        (["reproduce", "--device", "cuda:2", "--only", "table3_nvs"], 2, "--device cuda:2: only cuda:0 and cuda:1 exist"),
        (["run", "cdg", "--sim", "mgn", "--device", "gpu"], 0, "--device: must be auto, cpu, cuda or cuda:N, got 'gpu'"),
    ],
)
def test_a_device_that_is_not_there_is_one_line_before_any_work(argv, gpus, line, caught, monkeypatch, capsys, tmp_path) -> None:
    pretend_gpus(monkeypatch, gpus)
    monkeypatch.setattr(torch.version, "cuda", None)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == f"error: {line.format(v=torch.__version__)}\n"
    assert caught == [] and list(tmp_path.iterdir()) == []  # nothing ran, nothing written


def test_run_device_cuda_reaches_the_run_config_and_set_wins(caught, monkeypatch, capsys) -> None:
    pretend_gpus(monkeypatch, 1)
    assert main(["run", "cdg", "--sim", "mgn", "--renderer", "smgs", "--jobs", "1", "--device", "cuda",
                 "--set", "renderer_config.smgs.backend=cpu", "--set", "task_config.clods.initial_mesh=reconstructed"]) == 0  # fmt: skip
    (cfg,) = caught
    assert cfg.device == "cuda" and cfg.sim_config["mgn"]["device"] == "cuda"
    assert (cfg.renderer_config["smgs"]["backend"], cfg.renderer_config["smgs"]["device"]) == ("cpu", "cpu")  # --set wins
    assert cfg.task_config["clods"]["stage0"] == {"backend": "gsplat"}
    assert capsys.readouterr().err.splitlines()[:2] == [
        "device cuda: simulator 'mgn', task_config.clods.stage0 (backend gsplat)",
        "note: device cuda does not reach renderer 'smgs': renderer_config.smgs has backend=cpu, device=cpu; it runs on the CPU",
    ]


def test_run_on_the_cpu_and_auto_without_a_gpu_say_nothing_of_devices(caught, monkeypatch, capsys) -> None:
    pretend_gpus(monkeypatch, 0)
    for extra in ([], ["--device", "auto"], ["--device", "cpu"]):
        assert main(["run", "cdg", "--sim", "mgn", "--jobs", "1", *extra]) == 0
        assert "device" not in capsys.readouterr().err
    assert [c.device for c in caught] == ["cpu"] * 3 and caught[0] == caught[1] == caught[2]
    assert caught[0].sim_config["mgn"]["device"] == "cpu"


def test_cuda_that_nothing_can_use_is_a_warning(caught, monkeypatch, capsys) -> None:
    pretend_gpus(monkeypatch, 1)
    assert main(["run", "cdg", "--sim", "physics", "--jobs", "1", "--device", "cuda"]) == 0
    assert capsys.readouterr().err.splitlines()[0] == (
        "warning: device cuda asked for, but nothing in this run can use it; it runs on the CPU (simulator 'physics': it has no device option)")
    assert main(["run", "cdg", "--sim", "physics", "--jobs", "1", "--device", "auto"]) == 0
    assert capsys.readouterr().err.splitlines()[0] == "note: device cuda does not reach simulator 'physics': it has no device option; it runs on the CPU"


def test_reproduce_device_cuda_reaches_every_run_of_the_plan(monkeypatch, capsys, tmp_path) -> None:
    pretend_gpus(monkeypatch, 1)
    assert main(["reproduce", "--dry-run", "--device", "cuda", "--only", "table3_nvs", "initial_mesh", "--set", f"runs_dir={tmp_path}"]) == 0
    err = capsys.readouterr().err
    assert err.splitlines() == ["device cuda: renderer 'games' (backend gsplat), renderer 'smgs' (backend gsplat), renderer 'gs3d' (backend gsplat), "
                                "task_config.initial_mesh (backend gsplat)"]  # fmt: skip
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.benchmark.reproduction.reproduce import build_configs, load_plan

    plan = load_plan()
    plan.runs = [r for r in plan.runs if r.table in ("table3_nvs", "table2_cdg")]
    plan.tables = [t for t in plan.tables if t.id in ("table3_nvs", "table2_cdg")]
    for run, cfg in build_configs(plan, "ci", default_registry(), ["device=cuda"]):
        for section, name in (("renderer_config", cfg.renderer), ("sim_config", cfg.sim)):
            options = getattr(cfg, section).get(name, {}) if name else {}
            assert options.get("device", "cuda") == "cuda", (run.label, section)  # every plugin with the option has it
        if cfg.renderer:
            assert cfg.renderer_config[cfg.renderer]["backend"] == "gsplat", run.label
        if cfg.sim in ("physics", "constvel", "frozen"):
            assert "device" not in cfg.sim_config.get(cfg.sim, {}), run.label


def test_every_committed_ci_record_keeps_its_folder_under_the_default_device_and_auto_on_a_cpu(monkeypatch, capsys, tmp_path) -> None:
    """The device is not in any record's identity on the CPU: the whole ci plan's record keys are the committed ones."""
    pretend_gpus(monkeypatch, 0)
    committed = Path(__file__).resolve().parents[2] / "results" / "ci"
    for extra in ([], ["--device", "auto"]):
        assert main(["reproduce", "--dry-run", "--check", str(committed), "--out", str(tmp_path / "out"), "--set", f"runs_dir={tmp_path}", *extra]) == 0
        assert f"every row's config is the one {committed} was made with" in capsys.readouterr().out.replace("\n", "")
