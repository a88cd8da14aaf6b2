"""`run cdg --sim ... --renderer ...` end to end on the tiny dataset: the CloDS branch of the CDG task."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.clods.config import clods_config
from clods_bench.benchmark.clods.labels import clods_label
from clods_bench.benchmark.core.hookspecs import hookimpl
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.records import RECORD_FILE, default_label
from clods_bench.benchmark.running.runner import run_task
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config

FAST = [
    "renderer_config.games.iterations=10",
    "renderer_config.games.gaussians_per_face=1",
    "task_config.clods.iterations=2",
    "task_config.clods.min_iterations=2",
]


def _record(rdir: Path) -> dict:
    return json.loads((rdir / RECORD_FILE).read_text())


def test_constvel_from_video_matches_mesh_supervised_rollouts(tiny_root: Path, tmp_path: Path):
    """constvel ignores its training data, so the video-trained row must score exactly like the mesh one,
    while stages 1-2 ran: E-GT recorded per frame (0 at the ground-truth initial mesh), meshes cached per trajectory."""
    runs = tmp_path / "runs"
    video = run_task(tiny_config(tiny_root, f"runs_dir={runs}", *FAST, sim="constvel", renderer="games"), default_registry())
    mesh = run_task(tiny_config(tiny_root, f"runs_dir={runs}", sim="constvel"), default_registry())
    rv, rm = _record(video), _record(mesh)
    assert rv["label"] == "CloDS**[constvel+games]" and rm["label"] == "Const. velocity"
    for key, value in rm["metrics"].items():
        assert rv["metrics"][key]["mean"] == pytest.approx(value["mean"], rel=1e-6), key
    seed = rv["per_seed"]["0"]
    assert seed["extra"]["train_ids"] == [0, 1]
    egt = np.asarray(seed["extra"]["egt_curve"])
    assert egt.shape == (9,) and egt[0] == 0.0 and np.all(egt[1:] > 0)  # frames 0..interp_steps
    t = seed["timings"]
    assert t["fit/stage2_frames"] == 16 and t["fit/stage2_ms_per_frame"] > 0 and t["fit/egt_rmse"] == pytest.approx(egt[1:].mean())
    cached = sorted(p.name for p in (runs / "clods_cache").glob("*/traj_*.npz"))
    assert cached == ["traj_0000.npz", "traj_0001.npz"]


def test_labels_and_variants(tiny_root: Path):
    cfg = tiny_config(tiny_root, sim="mgn", renderer="smgs")
    assert default_label(cfg, default_registry()) == "CloDS**"
    assert clods_label(tiny_config(tiny_root, sim="mgn", renderer="smgs", train_subset="first_half")) == "CloDS*"
    fine = tiny_config(tiny_root, "task_config.clods.variant=finetune", sim="mgn", renderer="smgs")
    assert default_label(fine, default_registry()) == "CloDS" and clods_config(fine).variant == "finetune"
    with pytest.raises(ClodsError, match="task_config.clods"):
        clods_config(tiny_config(tiny_root, "task_config.clods.gama=0.1"))
    with pytest.raises(ClodsError, match="num_cameras"):
        clods_config(tiny_config(tiny_root, "task_config.clods.num_cameras=0"))


def test_stage3_overrides_given_are_laid_over_the_papers_rollout_loss():
    """Setting one stage-3 option on a preset without sim_overrides (as the paper-trajectory script sets train_steps
    on `paper`) keeps the 8-step rollout loss of eq. 8 instead of silently dropping it; `loss: one_step` still
    switches it off."""
    from clods_bench.benchmark.core.config import load_config

    assert clods_config(load_config("paper", None, [])).sim_overrides == {"loss": "rollout", "rollout_length": 8}
    one = clods_config(load_config("paper", None, ["task_config.clods.sim_overrides.train_steps=20"]))
    assert one.sim_overrides == {"loss": "rollout", "rollout_length": 8, "train_steps": 20}
    off = clods_config(load_config("paper", None, ["task_config.clods.sim_overrides.loss=one_step"]))
    assert off.sim_overrides == {"loss": "one_step", "rollout_length": 8}


@pytest.mark.slow
def test_finetune_starts_from_the_mesh_pretrained_model(tiny_root: Path, tmp_path: Path):
    """CloDS: MGN* on the first half's meshes, then fine-tuned on the second half's extracted meshes."""
    tiny_mgn = ["sim_config.mgn.latent_size=8", "sim_config.mgn.message_passing_steps=1", "sim_config.mgn.train_steps=4",
                "sim_config.mgn.warmup_steps=1", "task_config.clods.sim_overrides.train_steps=3", "task_config.clods.sim_overrides.warmup_steps=1",
                "task_config.clods.sim_overrides.rollout_length=2"]  # fmt: skip
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path}", *FAST, *tiny_mgn, "task_config.clods.variant=finetune", sim="mgn", renderer="games")
    rec = _record(run_task(cfg, default_registry()))
    seed = rec["per_seed"]["0"]
    assert rec["label"] == "CloDS[mgn+games]" and seed["extra"]["train_ids"] == [1]  # videos of the second half
    t = seed["timings"]
    assert t["fit/pretrain/train_steps"] == 4 and t["fit/stage3/train_steps"] == 3
    assert np.isfinite(rec["metrics"]["unviewed/interp/avg"]["mean"])


def test_warm_start_hands_over_a_copy_of_the_trained_model():
    import torch

    from clods_bench.benchmark.clods.stage3 import warm_start

    class Learned:
        def __init__(self) -> None:
            self.model = None

        def build_model(self, seed: int) -> torch.nn.Module:
            return torch.nn.Linear(2, 2)

    pre, sim = Learned(), Learned()
    pre.model = torch.nn.Linear(2, 2).eval()
    warm_start(sim, pre, "fake")
    built = sim.build_model(0)
    assert built is not pre.model and built.training
    assert all(torch.equal(a, b) for a, b in zip(built.parameters(), pre.model.parameters()))
    with pytest.raises(ClodsError, match="cannot fine-tune"):
        warm_start(object(), object(), "constvel")


def test_fit_stage1_is_cached_and_reloads_the_same_renderer(tiny_root: Path, tmp_path: Path, monkeypatch):
    import torch

    from clods_bench.benchmark.clods.pipeline import fit_stage1
    from clods_bench.benchmark.core.descriptors import TaskContext
    from clods_bench.datasets.store import DatasetStore
    from clods_bench.plugins.renderers.games import GamesRenderer

    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path}", *FAST, sim="constvel", renderer="games")
    ctx = TaskContext(config=cfg, seed=0, work_dir=tmp_path / "w", registry=default_registry())
    store = DatasetStore.open(cfg.data.dataset_dir())
    trajs = [store.load_trajectory(i) for i in (0, 1)]
    images = np.stack([store.load_frames(i)[0, :2] for i in (0, 1)])
    cams = store.cameras()[:2]
    first, s1 = fit_stage1(ctx, trajs, images, cams)
    moved = []
    monkeypatch.setattr(GamesRenderer, "relocate", lambda self: moved.append(self.device))
    second, s2 = fit_stage1(ctx, trajs, images, cams)
    assert moved == [torch.device("cpu")]  # a cached fit goes back to the device it was fitted on
    assert s1["stage1_cached"] == 0.0 and s1["stage1_seconds"] > 0 and s2["stage1_cached"] == 1.0
    v = torch.from_numpy(trajs[0].world_pos[3])
    with torch.no_grad():
        torch.testing.assert_close(first.render(v, cams), second.render(v, cams), rtol=0, atol=0)
    _, s3 = fit_stage1(ctx, trajs, images, cams, initial_meshes=np.stack([t.world_pos[0] + 0.01 for t in trajs]))
    assert s3["stage1_cached"] == 0.0  # other initial meshes: another representation


class _ThirdPartySim:
    """A third-party plugin (not an entry point of this package): a learned simulator under its own name."""

    @staticmethod
    def _build(cfg, ctx):
        from clods_bench.plugins.simulators.learned.mgn import MgnProcessor
        from clods_bench.plugins.simulators.learned.simulator import LearnedSimulator

        return LearnedSimulator("acme", cfg, ctx.scene, lambda latent, hidden, names: MgnProcessor(latent, hidden, names, cfg.message_passing_steps))

    @hookimpl
    def clods_bench_simulators(self):
        from clods_bench.benchmark.core.descriptors import PluginSpec
        from clods_bench.plugins.simulators.learned.config import MgnConfig

        return [PluginSpec(name="acme", description="third-party MGN", build=self._build, config_cls=MgnConfig, learned=True)]


def test_a_third_party_backbone_is_built_by_name_with_the_stage3_overrides(tiny_root: Path, tmp_path: Path):
    """Fast half of the check below: resolve_plugins accepts the name, stage 3 builds that plugin with its overrides."""
    from clods_bench.benchmark.clods.config import clods_config
    from clods_bench.benchmark.clods.stage3 import stage3_context
    from clods_bench.benchmark.core.builders import build_simulator
    from clods_bench.benchmark.core.descriptors import TaskContext
    from clods_bench.benchmark.core.registry import Registry, make_plugin_manager
    from clods_bench.benchmark.core.resolve import resolve_plugins

    registry = Registry.from_plugin_manager(make_plugin_manager([_ThirdPartySim()]))
    cfg = tiny_config(tiny_root, "task_config.clods.variant=finetune", sim="acme", renderer="smgs")
    resolve_plugins(cfg, registry)
    ctx = TaskContext(config=cfg, seed=0, work_dir=tmp_path, registry=registry)
    sim = build_simulator(stage3_context(ctx, clods_config(cfg)))
    assert sim.name == "acme" and sim.config.loss == "rollout"  # the stage-3 default: eq. 8's rollout loss
    assert build_simulator(ctx).config.loss == "one_step"  # its mesh pre-training (X*) keeps the plugin's own config


@pytest.mark.slow  # ~60 s alone, minutes on a loaded machine: stages 1-3 end to end
def test_any_registered_simulator_is_a_clods_backbone_by_name(tiny_root: Path, tmp_path: Path):
    """The backbone ablation's rows: `sim: <name>` picks the backbone, a third-party plugin included, and it is the
    simulator stage 3 fine-tunes (pre-trained on the first half's meshes, then trained on the second half's videos)."""
    from clods_bench.benchmark.core.registry import Registry, make_plugin_manager

    registry = Registry.from_plugin_manager(make_plugin_manager([_ThirdPartySim()]))
    tiny = ["sim_config.acme.latent_size=8", "sim_config.acme.message_passing_steps=1", "sim_config.acme.train_steps=4",
            "sim_config.acme.warmup_steps=1", "task_config.clods.sim_overrides.train_steps=3", "task_config.clods.sim_overrides.warmup_steps=1",
            "task_config.clods.sim_overrides.rollout_length=2"]  # fmt: skip
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path}", *FAST, *tiny, "task_config.clods.variant=finetune", sim="acme", renderer="games")
    rec = _record(run_task(cfg, registry))
    t = rec["per_seed"]["0"]["timings"]
    assert rec["label"] == "CloDS[acme+games]" and t["fit/pretrain/train_steps"] == 4 and t["fit/stage3/train_steps"] == 3
    assert list(tmp_path.rglob("acme.ckpt"))  # the third-party model was trained, not a built-in one


def test_an_unregistered_backbone_is_one_error_naming_sim(tiny_root: Path, tmp_path: Path):
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path}", "task_config.clods.variant=finetune", sim="mgm", renderer="smgs")
    with pytest.raises(ClodsError) as exc:
        run_task(cfg, default_registry())
    assert exc.value.where == "sim" and "unknown simulator 'mgm'" in exc.value.what and exc.value.hint == "did you mean 'mgn'?"
    assert exc.value.message.startswith("sim: unknown simulator 'mgm'")
    assert not list(tmp_path.rglob("*.npz"))  # failed before any work
