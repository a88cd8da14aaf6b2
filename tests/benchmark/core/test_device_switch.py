"""The run's device switch: `device` written into the options of every plugin and stage that can use it, the user's own
settings kept, refusals named, the CPU leaving records as they were. No test computes on CUDA: a GPU is pretended
(`torch.cuda.is_available`, `device_count`) and the resolved configs are checked."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import pytest
import torch

from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.device_switch import device_report, device_use, option_fields
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.core.resolve import resolve_plugins
from clods_bench.benchmark.running.executors import SeedJob, job_uses_gpu
from clods_bench.benchmark.running.records import record_dir
from clods_bench.devices import resolve_device
from clods_bench.errors import ClodsError
from clods_bench.plugins.simulators.learned.config import MgnConfig

RECONSTRUCTED = "task_config.clods.initial_mesh=reconstructed"


@pytest.fixture
def gpus(monkeypatch: pytest.MonkeyPatch):
    """Pretend torch sees `n` CUDA GPUs (nothing is computed on them)."""

    def pretend(n: int = 1) -> None:
        monkeypatch.setattr(torch.cuda, "is_available", lambda: n > 0)
        monkeypatch.setattr(torch.cuda, "device_count", lambda: n)

    return pretend


def resolved(*sets: str, **fields: str):
    return resolve_plugins(load_config("ci", overrides=list(sets), **fields), default_registry())


def test_cuda_reaches_every_plugin_and_stage_that_can_use_it(gpus) -> None:
    gpus(1)
    cfg = resolved("device=cuda", RECONSTRUCTED, task="cdg", sim="mgn", renderer="smgs")
    assert cfg.device == "cuda"
    assert cfg.sim_config["mgn"]["device"] == "cuda"
    assert (cfg.renderer_config["smgs"]["backend"], cfg.renderer_config["smgs"]["device"]) == ("gsplat", "cuda")
    assert cfg.task_config["clods"]["stage0"] == {"backend": "gsplat"}  # stage 0's surfels: gsplat's 2DGS kernels
    assert cfg.task_config["clods"]["initial_mesh"] == "reconstructed" and "iterations" in cfg.task_config["clods"]  # the rest kept
    assert resolve_plugins(cfg, default_registry()) == cfg  # idempotent: a worker resolving it again changes nothing
    for renderer in ("games", "gs3d"):
        opts = resolved("device=cuda:0", task="nvs", renderer=renderer).renderer_config[renderer]
        assert (opts["backend"], opts["device"]) == ("gsplat", "cuda:0")
    for predictor in ("simvp", "tau", "mau", "mmvp"):
        assert resolved("device=cuda", task="dvc", predictor=predictor).video_config[predictor]["device"] == "cuda"
    for sim in ("bsms", "hcmt", "dhmp", "lip"):
        assert resolved("device=cuda", task="cdg", sim=sim).sim_config[sim]["device"] == "cuda"
    assert resolved("device=cuda", task="initial_mesh").task_config["initial_mesh"] == {"backend": "gsplat"}
    # stage 0 is reached only where it runs: CloDS rows from a reconstructed mesh, not a mesh-trained simulator's row
    assert "stage0" not in resolved("device=cuda", task="cdg", sim="mgn", renderer="smgs").task_config.get("clods", {})
    assert "stage0" not in resolved("device=cuda", RECONSTRUCTED, task="cdg", sim="mgn").task_config["clods"]
    # Ray gives a GPU share to exactly these jobs
    assert job_uses_gpu(SeedJob(config=cfg.to_dict(), seed=0, name="x"))
    assert not job_uses_gpu(SeedJob(config=resolved("device=cuda", task="cdg", sim="physics").to_dict(), seed=0, name="x"))


def test_options_set_by_hand_win(gpus) -> None:
    gpus(2)
    cfg = resolved("device=cuda", "sim_config.mgn.device=cuda:1", "renderer_config.smgs.device=cpu", task="cdg", sim="mgn", renderer="smgs")
    assert cfg.sim_config["mgn"]["device"] == "cuda:1"
    assert (cfg.renderer_config["smgs"]["backend"], cfg.renderer_config["smgs"]["device"]) == ("cpu", "cpu")  # kept whole on the CPU
    cfg = resolved("device=cuda", "renderer_config.smgs.backend=reference", task="nvs", renderer="smgs")
    assert (cfg.renderer_config["smgs"]["backend"], cfg.renderer_config["smgs"]["device"]) == ("reference", "cpu")
    cfg = resolved("device=cuda", "renderer_config.smgs.backend=gsplat", task="nvs", renderer="smgs")
    assert cfg.renderer_config["smgs"]["device"] == "cuda"  # the backend set by hand, the device from the switch
    cfg = resolved("device=cuda", "task_config.initial_mesh.backend=cpu", task="initial_mesh")
    assert cfg.task_config["initial_mesh"] == {"backend": "cpu"}
    on_device, on_cpu = device_use(resolved("device=cuda", "renderer_config.smgs.device=cpu", task="cdg", sim="mgn", renderer="smgs"),
                                   default_registry())  # fmt: skip
    assert on_device == ["simulator 'mgn'"] and on_cpu == ["renderer 'smgs': renderer_config.smgs has backend=cpu, device=cpu"]


def test_auto_takes_a_gpu_only_where_torch_sees_one(gpus) -> None:
    gpus(0)
    cfg = resolved("device=auto", task="cdg", sim="mgn", renderer="smgs")
    assert cfg.device == "cpu" and cfg == resolved(task="cdg", sim="mgn", renderer="smgs")
    gpus(1)
    assert resolved("device=auto", task="cdg", sim="mgn").sim_config["mgn"]["device"] == "cuda"


def test_the_cpu_keeps_every_record_folder_and_a_gpu_names_its_own(gpus) -> None:
    """`device` is not in the record's identity; the options it reaches are."""
    reg = default_registry()

    def rdir(*sets: str):
        return record_dir(resolved(*sets, task="cdg", sim="mgn", renderer="smgs"), reg)

    base = rdir()
    gpus(0)
    assert rdir("device=cpu") == base and rdir("device=auto") == base
    gpus(1)
    gpu = rdir("device=cuda")
    assert gpu != base and gpu.parent == base.parent  # the same row's folder, another digest
    assert rdir("sim_config.mgn.device=cuda", "renderer_config.smgs.device=cuda", "renderer_config.smgs.backend=gsplat") == gpu
    # a run the device does not reach computes on the CPU as before, and reads the CPU's record
    physics = resolved("device=cuda", task="cdg", sim="physics")
    assert record_dir(physics, reg) == record_dir(resolved(task="cdg", sim="physics"), reg)


def test_what_the_run_says_about_the_device(gpus) -> None:
    gpus(1)
    reg = default_registry()
    clods = resolved("device=cuda", RECONSTRUCTED, task="cdg", sim="mgn", renderer="smgs")
    physics = resolved("device=cuda", task="cdg", sim="physics")
    assert device_report([clods], reg, explicit=True) == [
        "device cuda: simulator 'mgn', renderer 'smgs' (backend gsplat), task_config.clods.stage0 (backend gsplat)"]
    assert device_report([physics], reg, explicit=True) == [
        "warning: device cuda asked for, but nothing in this run can use it; it runs on the CPU (simulator 'physics': it has no device option)"]
    note = "note: device cuda does not reach simulator 'physics': it has no device option; it runs on the CPU"
    assert device_report([physics], reg, explicit=False) == [note]  # 'auto': a note
    assert device_report([clods, physics, physics], reg, explicit=True)[1:] == [note]  # a plan: each note once
    assert device_report([resolved(task="cdg", sim="physics")], reg, explicit=True) == []  # the CPU: nothing to say
    gpus(2)
    stage0 = device_use(resolved("device=cuda:1", task="initial_mesh"), reg)[0]
    assert stage0 == ["task_config.initial_mesh (backend gsplat, the current CUDA device (CUDA_VISIBLE_DEVICES chooses it))"]


@dataclass(frozen=True)
class CpuOnlyConfig:
    device: str = "cpu"


def test_a_plugin_that_refuses_the_device_is_named(gpus) -> None:
    gpus(1)
    reg = default_registry()
    spec = PluginSpec(name="cpuonly", description="refuses CUDA", build=lambda c, ctx: None, config_cls=CpuOnlyConfig, devices=("cpu",))
    reg = dataclasses.replace(reg, simulators={**reg.simulators, "cpuonly": spec})
    cfg = resolve_plugins(load_config("ci", overrides=["device=cuda"], task="cdg", sim="cpuonly", renderer="smgs"), reg)
    assert cfg.sim_config["cpuonly"] == {"device": "cpu"} and cfg.renderer_config["smgs"]["device"] == "cuda"
    assert device_report([cfg], reg, explicit=True) == [
        "device cuda: renderer 'smgs' (backend gsplat)",
        "note: device cuda does not reach simulator 'cpuonly': it runs on cpu only (its PluginSpec.devices); it runs on the CPU"]
    with pytest.raises(ClodsError) as e:
        resolve_plugins(load_config("ci", overrides=["sim_config.cpuonly.device=cuda"], task="cdg", sim="cpuonly"), reg)
    assert e.value.message == ("sim_config.cpuonly.device: simulator 'cpuonly' runs on cpu only (its PluginSpec.devices), not on cuda "
                               "(leave the option out, or set a device it runs on)")  # fmt: skip


def test_the_device_names_and_the_gpus_that_exist(gpus, monkeypatch: pytest.MonkeyPatch) -> None:
    gpus(0)
    monkeypatch.setattr(torch.version, "cuda", None)
    with pytest.raises(ClodsError) as e:
        resolve_device("cuda", "--device")
    assert e.value.message == f"--device cuda: no CUDA device is available (torch {torch.__version__} is a CPU build)"
    monkeypatch.setattr(torch.version, "cuda", "12.8")
    with pytest.raises(ClodsError, match=r"^--device cuda:0: no CUDA device is available \(torch .* \(CUDA 12.8\) sees no GPU\)$"):
        resolve_device("cuda:0", "--device")
    assert resolve_device("cuda", "--device", check=False) == "cuda"  # Ray: the workers hold the GPUs
    for n, exist in ((1, "only cuda:0 exists"), (2, "only cuda:0 and cuda:1 exist"), (4, "only cuda:0 to cuda:3 exist")):
        gpus(n)
        with pytest.raises(ClodsError) as e:
            resolve_device("cuda:7", "--device")
        assert e.value.message == f"--device cuda:7: {exist}"
        assert resolve_device(f"cuda:{n - 1}", "--device") == f"cuda:{n - 1}"
    for bad in ("gpu", "cuda:x", "CUDA", "", 1):
        with pytest.raises(ClodsError) as e:
            resolve_device(bad, "device")
        assert e.value.message == f"device: must be auto, cpu, cuda or cuda:N, got {bad!r}"
    with pytest.raises(ClodsError, match=r"^device: must be auto, cpu, cuda or cuda:N, got 'gpu'$"):
        resolved("device=gpu", task="cdg", sim="mgn")


def test_which_options_take_the_device() -> None:
    from clods_bench.benchmark.clods.stage0 import Stage0Config
    from clods_bench.plugins.renderers.smgs import SmgsConfig

    assert option_fields(MgnConfig) == (True, False)
    assert option_fields(SmgsConfig) == (True, True)
    assert option_fields(Stage0Config) == (False, True)
    assert option_fields(CpuOnlyConfig) == (True, False) and option_fields(int) == (False, False)
