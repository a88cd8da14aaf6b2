"""The multi-trajectory video-prediction task: the split against a hand-made one, windows that never span two
trajectories, copy-last and a frozen simulator scored against values computed here, resume, bad input."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch
from torch import nn

from clods_bench.benchmark.core.interfaces import FitContext
from clods_bench.benchmark.core.registry import Registry, default_registry, make_plugin_manager
from clods_bench.benchmark.outputs.films import load_film
from clods_bench.benchmark.outputs.image_tables import dvc_multi_frame
from clods_bench.benchmark.outputs.tables import write_tables
from clods_bench.benchmark.running.records import RECORD_FILE
from clods_bench.benchmark.running.runner import run_task
from clods_bench.benchmark.scoring.image_metrics import psnr, ssim
from clods_bench.benchmark.tasks.dvc_multi import DvcMultiConfig, MultiSplit, multi_split, training_videos
from clods_bench.datasets.rasterizer import render_views
from clods_bench.datasets.splits import SplitSpec
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.types import NORMAL
from clods_bench.errors import ClodsError
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig
from tests.benchmark.tasks.test_nvs import Doubles, RasterDouble, _gt_render_args
from tests.conftest import tiny_config

# tiny: training trajectories 0, 1 (frames 0..8 observed, 9..11 Extrapolation), test trajectory 2; camera 2 held out.
# gen_context=3: frames 0..2 of trajectory 2 given, 3..5 scored (as many as Extrapolation).
EXTRAP, GEN = [9, 10, 11], [3, 4, 5]
FAST = ["task_config.dvc_multi.lpips=false", "task_config.dvc_multi.gen_context=3"]
SIMVP = [  # a tiny SimVP: 3 -> 3 frames, 6 steps, a checkpoint every 3
    "video_config.simvp.context_frames=3", "video_config.simvp.hid_s=8", "video_config.simvp.hid_t=16",
    "video_config.simvp.enc_layers=2", "video_config.simvp.trans_layers=2", "video_config.simvp.kernels=[3]",
    "video_config.simvp.groups=2", "video_config.simvp.train_steps=6", "video_config.simvp.batch_size=4",
    "video_config.simvp.checkpoint_every=3", "video_config.simvp.num_threads=1",
]  # fmt: skip


def _run(root: Path, runs: Path, *extra: str, registry: Registry | None = None, **fields: Any) -> tuple[dict[str, Any], Path, Any]:
    cfg = tiny_config(root, f"runs_dir={runs}", *FAST, *extra, task="dvc_multi", **fields)
    rdir = run_task(cfg, registry or default_registry())
    return json.loads((rdir / RECORD_FILE).read_text()), rdir, cfg


def _unit(frames: np.ndarray) -> np.ndarray:
    return np.asarray(frames, np.float64) / 255.0


def test_split_matches_a_hand_made_one() -> None:
    splits = SplitSpec(num_train=4, num_test=3, num_steps=12, interp_steps=8, num_views_train=2, num_views_test=1)
    got = multi_split(splits, DvcMultiConfig(num_train_trajectories=3, num_test_trajectories=2, gen_context=2))
    assert got == MultiSplit(train_ids=[0, 1, 2], observed=9, extrap_frames=[9, 10, 11], test_ids=[4, 5], gen_context=2, gen_frames=[2, 3, 4])
    assert got.scored("extrap") == ([0, 1, 2], 9, [9, 10, 11]) and got.scored("gen") == ([4, 5], 2, [2, 3, 4])
    more = multi_split(splits, DvcMultiConfig(num_train_trajectories=10, num_test_trajectories=10, gen_context=6, gen_frames=3))
    assert more.train_ids == [0, 1, 2, 3] and more.test_ids == [4, 5, 6] and more.gen_frames == [6, 7, 8]  # ends on frame interp
    assert multi_split(splits, DvcMultiConfig(gen_context=1, gen_frames=8)).gen_frames == list(range(1, 9))
    with pytest.raises(ClodsError, match=r"task_config\.dvc_multi\.gen_context: Generalization gives frames 0\.\.6 and scores 3 more"):
        multi_split(splits, DvcMultiConfig(gen_context=7))
    with pytest.raises(ClodsError, match=r"gen_context.*past the interpolation phase"):
        multi_split(splits, DvcMultiConfig(gen_context=1, gen_frames=9))


class RecorderConfig(WindowTrainConfig):
    def validate(self) -> None:
        self.validate_training("recorder")


class Recorder(WindowPredictor[RecorderConfig]):
    """Trains nothing useful: records the value of every frame of every window it is given."""

    name = "recorder"
    label = "Recorder"

    def __init__(self, cfg: RecorderConfig) -> None:
        super().__init__(cfg, seed=0, progress=False)
        self.windows: list[np.ndarray] = []

    def build_model(self) -> nn.Module:
        return nn.Linear(1, 1)

    def downsample_factor(self) -> int:
        return 1

    def loss(self, model: nn.Module, window: torch.Tensor, step: int, rng: np.random.Generator) -> torch.Tensor:
        self.windows += [w.numpy().reshape(w.shape[0], -1) for w in window]  # (2C, pixels) per window
        return model.weight.sum() * 0.0 + model.bias.sum() ** 2


def test_windows_never_span_two_trajectories(tmp_path: Path) -> None:
    """Each trajectory's frames hold one distinct constant: a window spanning two trajectories holds two values."""
    clips = {i: np.full((2, 12, 4, 4, 3), 0.1 * (i + 1), np.float32) for i in range(4)}  # (views, T, H, W, 3)
    for i, clip in clips.items():
        clip[1] += 0.05  # the second view differs too: a window spanning two views is caught as well
    videos = training_videos(clips, observed=9)
    assert len(videos) == 8 and all(v.shape == (9, 4, 4, 3) for v in videos)  # frames 0..8 only, never 9..11
    rec = Recorder(RecorderConfig(context_frames=2, train_steps=50, batch_size=8, checkpoint_every=0))
    stats = rec.fit(videos, FitContext(tmp_path, 0, False))
    assert stats["train_windows"] == 8 * (9 - 4 + 1)
    values = set()
    for w in rec.windows:
        assert w.shape[0] == 4 and np.ptp(w) == 0.0  # one value in every frame of the window
        values.add(round(float(w[0, 0]), 4))
    assert values == {round(0.1 * (i + 1) + d, 4) for i in range(4) for d in (0.0, 0.05)}  # every trajectory and view drawn


def test_copylast_scores_equal_the_hand_computed_ones(tiny_root: Path, tmp_path: Path) -> None:
    rec, rdir, cfg = _run(tiny_root, tmp_path / "runs", predictor="copylast")
    store = DatasetStore.open(cfg.data.dataset_dir())
    expected: dict[str, dict[str, list[float]]] = {s: {"psnr": [], "ssim": [], "rmse": []} for s in ("extrap", "gen")}
    for s, ids, last, frames in (("extrap", (0, 1), 8, EXTRAP), ("gen", (2,), 2, GEN)):
        for i in ids:
            video = _unit(store.load_frames(i)[:, 2])  # the held-out camera
            for t in frames:
                expected[s]["psnr"].append(psnr(video[last], video[t]))
                expected[s]["ssim"].append(ssim(video[last], video[t]))
                expected[s]["rmse"].append(float(np.sqrt(np.mean((video[last] - video[t]) ** 2))))
    m = rec["metrics"]
    for s, cols in expected.items():
        for k, v in cols.items():
            assert m[f"{s}/{k}"]["mean"] == pytest.approx(np.mean(v), rel=1e-5), (s, k)
    assert "extrap/lpips" not in m and m["gen/psnr"]["mean"] != pytest.approx(m["extrap/psnr"]["mean"])
    extra = rec["per_seed"]["0"]["extra"]
    assert extra["train_trajectories"] == [0, 1] and extra["test_trajectories"] == [2] and extra["views"] == [2]
    assert extra["extrap_frames"] == EXTRAP and extra["gen_frames"] == GEN and extra["images"] == {"extrap": 6, "gen": 3}
    assert (rdir / "seed_0" / "dvc_multi_extrap_traj0.gif").is_file() and (rdir / "seed_0" / "dvc_multi_gen_traj2.gif").is_file()
    films = {s: load_film(rdir / "seed_0" / f"dvc_multi_{s}_frames.npz") for s in ("extrap", "gen")}
    assert (films["extrap"].frames, films["extrap"].trajectory) == (EXTRAP, "extrapolation, traj 0")
    assert (films["gen"].frames, films["gen"].trajectory, films["gen"].views) == (GEN, "generalization, traj 2", [2])
    # The table: two column groups, the paper's unscaled SSIM/LPIPS/RMSE.
    paths = write_tables(tmp_path / "runs", tmp_path / "tables", task="dvc_multi")
    csv = pd.read_csv([q for q in paths if q.suffix == ".csv"][0])
    assert csv.loc[0, "extrap/ssim/mean"] == pytest.approx(np.mean(expected["extrap"]["ssim"]), rel=1e-5)
    assert csv.loc[0, "gen/rmse/mean"] == pytest.approx(np.mean(expected["gen"]["rmse"]), rel=1e-5)
    md = [q for q in paths if q.suffix == ".md"][0].read_text()
    assert "Extrapolation / PSNR (dB) ↑" in md and "Generalization / RMSE ↓" in md and "unavailable [1]" in md


def test_table_prints_the_paper_layout() -> None:
    # The paper's SimVP row: Extrapolation 18.9722, 0.9557, 0.03246, 0.12704; Generalization 14.2391, 0.9438, 0.04593, 0.14028.
    values = {"extrap": (18.9722, 0.9557, 0.03246, 0.12704), "gen": (14.2391, 0.9438, 0.04593, 0.14028)}
    metrics = {f"{s}/{k}": {"mean": v, "std": 0.0} for s, vs in values.items() for k, v in zip(("psnr", "ssim", "lpips", "rmse"), vs)}
    rec = {"label": "SimVP", "seeds": [0, 1], "metrics": metrics,
           "timings": {"predict_ms_per_frame": {"mean": 2.0, "std": 0.0}, "fit_seconds": {"mean": 10.0, "std": 0.0}}}  # fmt: skip
    display, numeric, notes = dvc_multi_frame([rec])
    row = display.loc["SimVP"]
    assert [row[("Extrapolation", c)] for c in ("PSNR (dB) ↑", "SSIM ↑", "LPIPS ↓", "RMSE ↓")] == [
        "18.9722 ± 0.0000", "0.9557 ± 0.0000", "0.03246 ± 0.00000", "0.12704 ± 0.00000"]  # fmt: skip
    assert row[("Generalization", "LPIPS ↓")] == "0.04593 ± 0.00000" and notes == []
    assert numeric.loc[0, "gen/psnr/mean"] == pytest.approx(14.2391) and numeric.loc[0, "extrap/rmse/mean"] == pytest.approx(0.12704)


def test_frozen_simulator_rendered_on_both_splits(tiny_root: Path, tmp_path: Path) -> None:
    """A frozen cloth rendered by the ground-truth rasterizer, rolled out from each trajectory's initial mesh."""
    uv, texture, settings = _gt_render_args(tiny_config(tiny_root))
    reg = Registry.from_plugin_manager(make_plugin_manager([Doubles(RasterDouble(uv, texture, settings))]))
    rec, _, cfg = _run(tiny_root, tmp_path / "runs", "task_config.dvc_multi.sim_training=mesh", registry=reg, sim="frozen", renderer="raster")
    store = DatasetStore.open(cfg.data.dataset_dir())
    cam = store.cameras()[2]
    for s, ids, frames in (("extrap", (0, 1), EXTRAP), ("gen", (2,), GEN)):
        want = []
        for i in ids:
            traj, video = store.load_trajectory(i), _unit(store.load_frames(i)[:, 2])
            for t in frames:
                mesh = traj.world_pos[t].copy()
                free = traj.node_type == NORMAL
                mesh[free] = traj.world_pos[1][free]  # frozen: NORMAL nodes stay at frame 1, handles follow the truth
                want.append(psnr(render_views(mesh, traj.cells, uv, texture, [cam], settings)[0], video[t]))
        assert rec["metrics"][f"{s}/psnr"]["mean"] == pytest.approx(np.mean(want), rel=1e-5), s
    seed = rec["per_seed"]["0"]
    assert seed["extra"]["sim_training"] == "mesh" and seed["timings"]["render_ms_per_frame"] > 0


class Interrupt(KeyboardInterrupt):
    """Raised by the patched checkpoint writer to stop a run after its first checkpoint, as Ctrl-C or SIGTERM would (an
    interruption, not a plugin's error: it passes the plugin-call wrapper unchanged)."""


def test_resumed_run_ends_with_the_uninterrupted_weights(tiny_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    whole, _, _ = _run(tiny_root, tmp_path / "whole", *SIMVP, predictor="simvp")
    save = WindowPredictor._save

    def save_then_stop(self: WindowPredictor[Any], path: Path, digest: str, step: int, *rest: Any) -> None:
        save(self, path, digest, step, *rest)
        raise Interrupt(step)

    with monkeypatch.context() as patch:
        patch.setattr(WindowPredictor, "_save", save_then_stop)
        with pytest.raises(Interrupt, match="3"):
            _run(tiny_root, tmp_path / "cut", *SIMVP, predictor="simvp")
    resumed, _, _ = _run(tiny_root, tmp_path / "cut", *SIMVP, predictor="simvp")
    (whole_ckpt,) = (tmp_path / "whole" / "fit_cache").glob("simvp-*/simvp.pt")
    (cut_ckpt,) = (tmp_path / "cut" / "fit_cache").glob("simvp-*/simvp.pt")
    a, b = torch.load(whole_ckpt, weights_only=True), torch.load(cut_ckpt, weights_only=True)
    assert a["step"] == b["step"] == 6 and a["digest"] == b["digest"]
    for key in a["model"]:
        assert torch.equal(a["model"][key], b["model"][key]), key
    assert resumed["metrics"] == whole["metrics"]
    assert whole["per_seed"]["0"]["timings"]["fit/train_windows"] == 2 * (9 - 6 + 1)  # 2 trajectories x 1 view


def test_table4_and_multi_rows_on_the_same_videos_share_one_fit(tiny_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """At these sizes Table 4's DVC row and this task train SimVP on the same videos (trajectories 0-1, camera 2,
    frames 0..8): the second run loads the first's checkpoint, trains no step, and counts its recorded cost."""
    runs = tmp_path / "runs"
    cfg = tiny_config(tiny_root, f"runs_dir={runs}", "task_config.dvc.lpips=false", *SIMVP, task="dvc", predictor="simvp")
    table4 = json.loads((run_task(cfg, default_registry()) / RECORD_FILE).read_text())["per_seed"]["0"]["timings"]
    monkeypatch.setattr(WindowPredictor, "loss", lambda *a: pytest.fail("trained again"))
    multi = _run(tiny_root, runs, *SIMVP, predictor="simvp")[0]["per_seed"]["0"]["timings"]
    assert len(list((runs / "fit_cache").glob("simvp-*"))) == 1
    assert multi["fit/train_seconds"] == table4["fit/train_seconds"] > 0  # the recorded training time, not the load's
    assert multi["fit_seconds"] == pytest.approx(table4["fit/train_seconds"]) and multi["fit_wall_seconds"] < multi["fit_seconds"]


def test_bad_input_is_one_clear_error(tiny_root: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    with pytest.raises(ClodsError, match=r"task_config\.dvc_multi\.num_train_trajectories: no training trajectories"):
        _run(tiny_root, runs, "task_config.dvc_multi.num_train_trajectories=0", predictor="copylast")
    with pytest.raises(ClodsError, match=r"task_config\.dvc_multi\.num_test_trajectories: no unseen test trajectories for the Generalization split"):
        _run(tiny_root, runs, "task_config.dvc_multi.num_test_trajectories=0", predictor="copylast")
    with pytest.raises(ClodsError, match=r"task_config\.dvc_multi\.gen_context: Generalization gives frames 0\.\.7"):
        _run(tiny_root, runs, "task_config.dvc_multi.gen_context=8", predictor="copylast")
    # more context frames than the interpolation phase has (frames 0..8): caught before any training
    with pytest.raises(ClodsError, match=r"video_config\.simvp\.context_frames: 5 context frames need training windows of 2 x 5 = 10 frames; "
                                         r"the interpolation phase has 9"):  # fmt: skip
        _run(tiny_root, runs, *SIMVP, "video_config.simvp.context_frames=5", predictor="simvp")
    with pytest.raises(ClodsError, match=r"video_config\.simvp\.context_frames: 4 context frames, but Generalization gives 3"):
        _run(tiny_root, runs, *SIMVP, "video_config.simvp.context_frames=4", predictor="simvp")
    assert not list(runs.rglob("simvp.pt"))
    with pytest.raises(ClodsError, match="either --predictor or --sim"):
        _run(tiny_root, runs, predictor="copylast", sim="frozen", renderer="games")
    with pytest.raises(ClodsError, match=r"unknown config key 'dvc_multi.num_trajectories'"):
        _run(tiny_root, runs, "task_config.dvc_multi.num_trajectories=3", predictor="copylast")
