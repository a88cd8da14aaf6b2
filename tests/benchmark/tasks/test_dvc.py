"""The DVC forward task end to end on the tiny dataset: scores checked against values computed here independently."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
import pandas as pd
import pytest

from clods_bench.benchmark.core.descriptors import PluginSpec
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.registry import Registry, default_registry, make_plugin_manager
from clods_bench.benchmark.outputs.films import load_film
from clods_bench.benchmark.outputs.image_tables import dvc_frame
from clods_bench.benchmark.outputs.mesh_pictures import load_mesh_sample
from clods_bench.benchmark.outputs.tables import write_tables
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.benchmark.scoring.image_metrics import psnr, ssim
from clods_bench.benchmark.tasks.dvc import FILM_FILE, GRID_FILE
from clods_bench.datasets.rasterizer import render_views
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import NORMAL
from clods_bench.errors import ClodsError
from tests.benchmark.tasks.test_nvs import Doubles, RasterDouble, _gt_render_args
from tests.conftest import tiny_config

# tiny: trajectories 0,1 are training ones (scored), frames 0..8 observed, 9..11 predicted; camera 2 held out
FUTURE = [9, 10, 11]


class WrongShape:
    """A predictor returning one frame too few."""

    def fit(self, videos, ctx) -> dict[str, float]:
        return {}

    def predict(self, context, num_frames, cameras):
        return np.zeros((context.shape[0], num_frames - 1, *context.shape[2:]), np.float32)


class BadPredictors:
    @hookimpl
    def clods_bench_video_predictors(self) -> list[PluginSpec]:
        return [PluginSpec(name="wrongshape", description="bad", build=lambda cfg, ctx: WrongShape())]


def _run(root: Path, tmp_path: Path, *extra: str, registry: Registry | None = None, **fields: Any) -> tuple[dict[str, Any], Path, Any]:
    cfg = tiny_config(root, f"runs_dir={tmp_path / 'runs'}", "task_config.dvc.lpips=false", *extra, task="dvc", **fields)
    rdir = run_task(cfg, registry or default_registry())
    return json.loads((rdir / RECORD_FILE).read_text()), rdir, cfg


def _unit(frames: np.ndarray) -> np.ndarray:
    return np.asarray(frames, np.float64) / 255.0


def test_copylast_scores_equal_the_hand_computed_ones(tiny_root: Path, tmp_path: Path) -> None:
    rec, rdir, cfg = _run(tiny_root, tmp_path, predictor="copylast")
    store = DatasetStore.open(cfg.data.dataset_dir())
    p, s, r = [], [], []
    for i in (0, 1):
        video = _unit(store.load_frames(i)[:, 2])  # held-out camera
        for t in FUTURE:
            p.append(psnr(video[8], video[t]))
            s.append(ssim(video[8], video[t]))
            r.append(np.sqrt(np.mean((video[8] - video[t]) ** 2)))
    m = rec["metrics"]
    assert m["psnr"]["mean"] == pytest.approx(np.mean(p), rel=1e-5)
    assert m["ssim"]["mean"] == pytest.approx(np.mean(s), rel=1e-5)
    assert m["rmse"]["mean"] == pytest.approx(np.mean(r), rel=1e-5)
    assert "lpips" not in m and rec["label"] == "Copy last"
    extra = rec["per_seed"]["0"]["extra"]
    assert extra["scored_frames"] == FUTURE and extra["views"] == [2] and extra["trajectories"] == [0, 1]
    seed_dir = rdir / "seed_0"
    gif = iio.imread(seed_dir / "dvc_traj0.gif", index=None)
    assert gif.shape[0] == len(FUTURE)  # one GIF frame per predicted frame
    film = load_film(seed_dir / FILM_FILE)  # the report's animation: trajectory 0, truth and the copied last frame
    assert film.frames == FUTURE and film.views == [2] and film.trajectory == "traj 0"
    np.testing.assert_array_equal(film.truth[0], store.load_frames(0)[FUTURE, 2])
    np.testing.assert_array_equal(film.pred[0], np.repeat(store.load_frames(0)[8:9, 2], len(FUTURE), axis=0))
    grid = iio.imread(seed_dir / GRID_FILE)
    assert grid.ndim == 3 and grid.shape[0] > grid.shape[1] / 4  # truth row above prediction row
    # The table: PSNR as is, SSIM x10, RMSE x100; LPIPS marked unavailable with the reason.
    paths = write_tables(tmp_path / "runs", tmp_path / "tables", task="dvc")
    csv = pd.read_csv([q for q in paths if q.suffix == ".csv"][0])
    assert csv.loc[0, "psnr/mean"] == pytest.approx(np.mean(p), rel=1e-5)
    assert csv.loc[0, "ssim_x10/mean"] == pytest.approx(10 * np.mean(s), rel=1e-5)
    assert csv.loc[0, "rmse_x100/mean"] == pytest.approx(100 * np.mean(r), rel=1e-5)
    md = [q for q in paths if q.suffix == ".md"][0].read_text()
    assert "SSIM×10" in md and "LPIPS×100" in md and "RMSE×100" in md and "unavailable [1]" in md


def test_table_scales_the_paper_values() -> None:
    # The paper's SimVP row: SSIM 0.9801, LPIPS 0.01020, RMSE 0.0557 print as 9.801, 1.020, 5.57.
    rec = {
        "label": "simvp", "seeds": [0, 1],
        "metrics": {"psnr": {"mean": 25.477, "std": 2.04}, "ssim": {"mean": 0.9801, "std": 0.007},
                    "lpips": {"mean": 0.0102, "std": 0.0009}, "rmse": {"mean": 0.0557, "std": 0.0045}},
        "timings": {"predict_ms_per_frame": {"mean": 2.0, "std": 0.0}, "fit_seconds": {"mean": 10.0, "std": 0.0}},
    }  # fmt: skip
    display, numeric, notes = dvc_frame([rec])
    row = display.loc["simvp"]
    assert row[("Quality", "SSIM×10 ↑")] == "9.801 ± 0.070"
    assert row[("Quality", "LPIPS×100 ↓")] == "1.020 ± 0.090"
    assert row[("Quality", "RMSE×100 ↓")] == "5.57 ± 0.45"
    assert row[("Quality", "PSNR (dB) ↑")] == "25.4770 ± 2.0400"
    assert numeric.loc[0, "lpips_x100/mean"] == pytest.approx(1.02) and notes == []


def test_simulator_and_renderer_follow_algorithm_s2(tiny_root: Path, tmp_path: Path) -> None:
    """A frozen cloth rendered by the ground-truth rasterizer: the expected images are computed here directly."""
    cfg0 = tiny_config(tiny_root)
    uv, texture, settings = _gt_render_args(cfg0)
    reg = Registry.from_plugin_manager(make_plugin_manager([Doubles(RasterDouble(uv, texture, settings))]))
    rec, rdir, cfg = _run(tiny_root, tmp_path, "task_config.dvc.sim_training=mesh", registry=reg, sim="frozen", renderer="raster")
    store = DatasetStore.open(cfg.data.dataset_dir())
    cam = store.cameras()[2]
    future, every = [], []
    for i in (0, 1):
        traj = store.load_trajectory(i)
        video = _unit(store.load_frames(i)[:, 2])
        for t in range(1, 12):
            mesh = traj.world_pos[t].copy()
            free = traj.node_type == NORMAL
            mesh[free] = traj.world_pos[1][free]  # frozen: NORMAL nodes stay at frame 1, handles follow the truth
            img = render_views(mesh, traj.cells, uv, texture, [cam], settings)[0]
            every.append(psnr(img, video[t]))
            if t in FUTURE:
                future.append(psnr(img, video[t]))
    m = rec["metrics"]
    assert m["psnr"]["mean"] == pytest.approx(np.mean(future), rel=1e-5)
    assert m["all/psnr"]["mean"] == pytest.approx(np.mean(every), rel=1e-5)
    assert m["all/psnr"]["mean"] > m["psnr"]["mean"]  # early frames are still close to frame 1
    t = rec["per_seed"]["0"]["timings"]
    assert t["render_ms_per_frame"] > 0 and t["rollout_ms_per_step"] >= 0 and t["predict_ms_per_frame"] > 0
    assert rec["per_seed"]["0"]["extra"]["sim_training"] == "mesh" and rec["label"] == "frozen+raster"
    assert (rdir / "seed_0" / "dvc_traj1.gif").is_file()


def test_bad_input_is_a_clear_error(tiny_root: Path, tmp_path: Path) -> None:
    with pytest.raises(ClodsError, match="did you mean 'copylast'"):
        _run(tiny_root, tmp_path, predictor="copylas")
    with pytest.raises(ClodsError, match="either --predictor or --sim"):
        _run(tiny_root, tmp_path, predictor="copylast", sim="frozen", renderer="games")
    with pytest.raises(ClodsError, match="needs a video predictor or a simulator and a renderer"):
        _run(tiny_root, tmp_path, sim="frozen")
    with pytest.raises(ClodsError, match=r"unknown config key 'dvc.view'"):
        _run(tiny_root, tmp_path, "task_config.dvc.view=all", predictor="copylast")
    reg = Registry.from_plugin_manager(make_plugin_manager([BadPredictors()]))
    with pytest.raises(ClodsError, match=r"video predictor 'wrongshape'.*expected \(1, 3, 24, 24, 3\)"):
        _run(tiny_root, tmp_path, registry=reg, predictor="wrongshape")


def test_start_from_the_last_observed_frames(tiny_root: Path, tmp_path: Path) -> None:
    """start=observed: frames 0..interp are the meshes stage 2 recovered, the rollout continues from the last two.
    With the frozen simulator every later frame is the recovered mesh of frame interp; images recomputed here."""
    import torch

    fast = ["renderer_config.games.iterations=10", "renderer_config.games.gaussians_per_face=1",
            "task_config.clods.iterations=2", "task_config.clods.min_iterations=2", "task_config.dvc.sim_training=video"]  # fmt: skip
    rec, rdir, cfg = _run(tiny_root, tmp_path, *fast, "task_config.dvc.start=observed", sim="frozen", renderer="games")
    assert rec["per_seed"]["0"]["extra"]["start"] == "observed"
    store = DatasetStore.open(cfg.data.dataset_dir())
    cam = store.cameras()[2]
    (renderer_file,) = (tmp_path / "runs" / "clods_cache").glob("stage1-*.pt")  # one fit: pipeline and DVC share it
    renderer = torch.load(renderer_file, weights_only=False)
    interp = cfg.data.interp_steps
    future, every = [], []
    for i in (0, 1):
        (ext_file,) = (tmp_path / "runs" / "clods_cache").glob(f"*/traj_{i:04d}.npz")
        with np.load(ext_file) as z:
            recovered = z["world_pos"]
        traj, video = store.load_trajectory(i), _unit(store.load_frames(i)[:, 2])
        if i == 0:  # the report's picture sample: training video 0's recovered meshes beside their truth
            _, meshes, truth, _, _ = load_mesh_sample(rdir / "seed_0" / "extraction_meshes.npz")
            np.testing.assert_allclose(meshes["extracted (stage 2)"], recovered, atol=1e-6)
            np.testing.assert_allclose(truth, traj.world_pos[: interp + 1], atol=1e-6)
        for t in range(1, 12):
            mesh = recovered[min(t, interp)].copy()
            mesh[traj.node_type != NORMAL] = traj.world_pos[t][traj.node_type != NORMAL]  # handles follow the truth
            with torch.no_grad():
                img = renderer.render(torch.from_numpy(mesh), [cam]).numpy()[0]
            every.append(psnr(img, video[t]))
            if t in FUTURE:
                future.append(psnr(img, video[t]))
    assert rec["metrics"]["psnr"]["mean"] == pytest.approx(np.mean(future), rel=1e-4)
    assert rec["metrics"]["all/psnr"]["mean"] == pytest.approx(np.mean(every), rel=1e-4)
    with pytest.raises(ClodsError, match="start=observed needs the meshes stage 2 recovered"):
        _run(tiny_root, tmp_path / "mesh", "task_config.dvc.sim_training=mesh", "task_config.dvc.start=observed", sim="frozen", renderer="games")


def test_a_dataset_with_frames_on_demand_scores_the_same(tiny_root: Path, tmp_path: Path) -> None:
    """The task reads frames through the store's interface only: rendered on demand they give the same scores."""
    stored, _, _ = _run(tiny_root, tmp_path / "a", predictor="copylast")
    rendered, _, cfg = _run(tiny_root, tmp_path / "b", "data.frames=on_demand", predictor="copylast")
    assert DatasetStore.open(cfg.data.dataset_dir()).frames_on_demand
    for key in ("psnr", "ssim", "rmse"):
        assert rendered["metrics"][key]["mean"] == stored["metrics"][key]["mean"]
