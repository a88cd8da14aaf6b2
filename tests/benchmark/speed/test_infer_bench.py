"""bench infer: each part's time lands in its own column (fake clock), counts match the preset, caps are reported,
--device cuda without CUDA fails in one line, and the JSON, CSV and plot are written; one real run at a tiny size."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from rich.console import Console

from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.registry import Registry, make_plugin_manager
from clods_bench.benchmark.outputs.infer_output import load_infer_results, result_rows, write_infer_outputs
from clods_bench.benchmark.speed.infer_bench import bench_infer, check_device
from clods_bench.benchmark.speed.infer_console import print_bench_infer
from clods_bench.cli import main
from clods_bench.datasets.scenes import get_scene
from clods_bench.errors import ClodsError
from tests.benchmark.speed.fake_clock import FakeClock

TINY = ["data.resolution=[5,3]", "data.num_cameras=3", "data.num_views_test=1", "data.image_size=16", "sim_config.mgn.latent_size=8",
        "sim_config.mgn.message_passing_steps=1", "sim_config.mgn.num_threads=1", "renderer_config.smgs.gaussians_per_face=2"]  # fmt: skip


CLOCK = FakeClock()


@dataclass(frozen=True)
class LearnedCfg:
    train_steps: int = 1000
    warmup_steps: int = 500


@dataclass(frozen=True)
class RendererCfg:
    iterations: int = 300
    backend: str = "cpu"
    device: str = "cpu"


FITS: list[LearnedCfg] = []


class FakeSim:
    """A rollout costs `ms` per step on the fake clock and repeats the last given frame."""

    def __init__(self, ms: float, cfg: object = None) -> None:
        self.ms, self.cfg = ms, cfg

    def fit(self, train, ctx):
        FITS.append(self.cfg)
        CLOCK.now += 100.0  # set-up: outside every timed region
        return {}

    def rollout(self, inp):
        CLOCK.now += self.ms / 1e3 * (inp.num_frames - 2)
        return np.repeat(inp.init_pos[1:], inp.num_frames, axis=0)


class FakeRenderer:
    """A render of every view costs 20 ms on the fake clock; 4 Gaussians per face."""

    def __init__(self, cfg: RendererCfg) -> None:
        self.cfg = cfg

    def fit(self, verts, cells, mesh_pos, images, cameras):
        self.num_gaussians = 4 * len(cells)
        return {}

    def render(self, verts, cameras):
        CLOCK.now += 0.020
        return torch.zeros(len(cameras), cameras[0].height, cameras[0].width, 3)


class Fakes:
    @hookimpl
    def clods_bench_simulators(self) -> list[PluginSpec]:
        return [PluginSpec("learned", "fake learned", lambda cfg, ctx: FakeSim(10.0, cfg), LearnedCfg, learned=True),
                PluginSpec("physics", "fake solver", lambda cfg, ctx: FakeSim(40.0))]  # fmt: skip

    @hookimpl
    def clods_bench_renderers(self) -> list[PluginSpec]:
        return [PluginSpec("splats", "fake", lambda cfg, ctx: FakeRenderer(cfg), RendererCfg)]

    @hookimpl
    def clods_bench_scenes(self):
        return [get_scene("flag")]


def fake_registry() -> Registry:
    return Registry.from_plugin_manager(make_plugin_manager(extra_plugins=[Fakes()], load_entry_points=False))


def test_each_part_is_timed_in_its_own_column() -> None:
    """Fake simulators and renderer advance a fake clock by known amounts; the real rasterizer advances it by nothing."""
    FITS.clear()
    r = bench_infer(load_config("ci", overrides=TINY), fake_registry(), sim="learned", renderer="splats", frames=4, clock=CLOCK)
    assert r["clods"]["sim_step"]["per_frame_ms"] == pytest.approx([10.0] * 4)
    assert r["clods"]["render"]["per_frame_ms"] == pytest.approx([20.0] * 4)
    assert r["traditional"]["sim_step"]["per_frame_ms"] == pytest.approx([40.0] * 4)
    assert r["traditional"]["render"]["per_frame_ms"] == pytest.approx([0.0] * 4)
    assert r["clods"]["total_ms"] == pytest.approx(30.0) and r["traditional"]["total_ms"] == pytest.approx(40.0)
    assert r["ratio_traditional_over_clods"] == pytest.approx(40.0 / 30.0)
    assert FITS[0] == LearnedCfg(train_steps=1, warmup_steps=0)  # the learned simulator: one optimiser step, no warm-up
    assert r["counts"]["gaussians"] == 4 * 16 and r["counts"]["gaussians_per_face"] == 4  # 5x3 grid: 2 * 4 * 2 = 16 faces
    assert r["caps"] == []


def test_a_simulator_that_is_not_learned_is_refused() -> None:
    with pytest.raises(ClodsError, match="not a learned simulator"):
        bench_infer(load_config("ci", overrides=TINY), fake_registry(), sim="physics", renderer="splats", frames=1, clock=CLOCK)


def test_device_cuda_without_a_gpu_fails_in_one_line(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ClodsError, match="no CUDA GPU"):
        check_device("cuda")
    with pytest.raises(ClodsError, match="unknown device"):
        check_device("gpu")
    assert main(["bench", "infer", "--device", "cuda", "--out", "/nonexistent/never-written"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--device" in err and "no CUDA GPU" in err


def test_real_pipelines_at_a_tiny_size(tmp_path: Path) -> None:
    """Real MGN, physics solver, SMGS and rasterizer: parts, totals and counts; capped views; files and plot."""
    cfg = load_config("ci", overrides=TINY)
    console = Console(record=True, width=220)
    r = print_bench_infer(console, cfg, tmp_path, progress=False, frames=3, views=2)
    for pipeline in ("clods", "traditional"):
        parts = r[pipeline]
        for part in ("sim_step", "render"):
            assert len(parts[part]["per_frame_ms"]) == 3 and min(parts[part]["per_frame_ms"]) > 0
            assert parts[part]["median_ms"] == pytest.approx(float(np.median(parts[part]["per_frame_ms"])))
        assert parts["total_ms"] == pytest.approx(parts["sim_step"]["median_ms"] + parts["render"]["median_ms"])
    assert r["ratio_traditional_over_clods"] == pytest.approx(r["traditional"]["total_ms"] / r["clods"]["total_ms"])
    c = r["counts"]
    assert (c["nodes"], c["faces"], c["views"], c["views_preset"]) == (15, 16, 2, 3)
    assert (c["width"], c["height"], c["pixels"]) == (16, 16, 2 * 16 * 16)
    assert c["gaussians"] == 2 * 16 and c["raster_supersample"] == cfg.data.supersample
    assert len(r["caps"]) == 1 and "2 of the preset's 3" in r["caps"][0]
    text = console.export_text()
    assert "capped" in text and "traditional / CloDS" in text
    saved = json.loads((tmp_path / "infer_ci.json").read_text())
    assert saved["clods"]["total_ms"] == pytest.approx(r["clods"]["total_ms"]) and saved["caps"] == r["caps"]
    rows = pd.read_csv(tmp_path / "infer_ci.csv")
    total = rows[(rows.pipeline == "clods") & (rows.part == "total")].median_ms.item()
    assert total == pytest.approx(rows[(rows.pipeline == "clods") & (rows.part != "total")].median_ms.sum())
    png = (tmp_path / "infer_time.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


def _synthetic(preset: str, sim_ms: float, render_ms: float) -> dict:
    part = lambda ms: {"median_ms": ms, "min_ms": ms, "max_ms": ms, "per_frame_ms": [ms]}  # noqa: E731
    return {"preset": preset, "scene": "flag", "sim": "mgn", "renderer": "smgs", "reference_sim": "physics", "device": "cpu", "frames": 1,
            "counts": {"nodes": 10, "faces": 8, "views": 2, "views_preset": 4, "width": 8, "height": 8, "pixels": 128, "gaussians": 40,
                       "gaussians_per_face": 5, "raster_supersample": 2},
            "caps": ["views: 2 of the preset's 4"], "notes": ["synthetic"],
            "clods": {"sim_step": part(sim_ms), "render": part(render_ms), "total_ms": sim_ms + render_ms},
            "traditional": {"sim_step": part(3.0), "render": part(4.0), "total_ms": 7.0},
            "ratio_traditional_over_clods": 7.0 / (sim_ms + render_ms)}  # fmt: skip


def test_outputs_accumulate_presets_and_the_report_shows_them(tmp_path: Path) -> None:
    from clods_bench.benchmark.outputs.html_report import build_html_report

    bench = tmp_path / "bench"
    write_infer_outputs(_synthetic("small", 1.0, 2.0), bench)
    write_infer_outputs(_synthetic("ci", 0.5, 0.25), bench)
    assert [r["preset"] for r in load_infer_results(bench)] == ["ci", "small"]
    rows = result_rows(_synthetic("ci", 0.5, 0.25))
    assert [(row["pipeline"], row["part"], row["median_ms"]) for row in rows] == [
        ("clods", "sim_step", 0.5), ("clods", "render", 0.25), ("clods", "total", 0.75),
        ("traditional", "sim_step", 3.0), ("traditional", "render", 4.0), ("traditional", "total", 7.0)]  # fmt: skip
    paths = build_html_report(tmp_path / "no-runs", tmp_path / "report", bench_dir=bench)  # bench results alone make a report
    page = (tmp_path / "report" / "index.html").read_text()
    assert tmp_path / "report" / "infer_time.png" in paths
    assert "Inference time: CloDS against the traditional pipeline" in page and "9.33" in page  # 7 / 0.75
    assert "capped: views: 2 of the preset&#x27;s 4" in page and "data:image/png;base64," in page
    with pytest.raises(ClodsError, match="no run records"):
        build_html_report(tmp_path / "report", tmp_path / "report2", bench_dir=tmp_path / "empty")  # a folder without records


def test_on_a_gpu_the_learned_step_is_timed_there_too() -> None:
    """`--device cuda` puts the learned simulator on that device (MGN has a device option), one step and no warm-up
    as on the CPU; on the CPU its config keeps the preset's device."""
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.benchmark.speed.infer_bench import learned_values

    cfg = load_config("ci", None, [])
    spec = default_registry().get("simulator", "mgn")
    gpu = learned_values(cfg, spec, "mgn", "cuda:1")
    assert gpu["device"] == "cuda:1" and gpu["train_steps"] == 1 and gpu["warmup_steps"] == 0
    assert "device" not in learned_values(cfg, spec, "mgn", "cpu") or learned_values(cfg, spec, "mgn", "cpu")["device"] == "cpu"
