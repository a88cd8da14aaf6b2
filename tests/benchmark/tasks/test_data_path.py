"""Running tasks on an imported dataset (`data.path`): the same numbers as on the original where the task needs no
meshes, the visual-hull proxy for per-frame 3DGS, and one clear refusal from every task that needs meshes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.config import load_config
from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.running.records import RECORD_FILE, record_dir
from clods_bench.benchmark.running.run_data import ensure_dataset
from clods_bench.benchmark.running.runner import run_task
from clods_bench.datasets.generate import generate
from clods_bench.datasets.nerf import export_nerf
from clods_bench.datasets.store import DatasetStore
from clods_bench.datasets.video_import import import_video
from clods_bench.datasets.visual_hull import box_mesh, foreground, hull_box
from clods_bench.errors import ClodsError
from tests.conftest import tiny_config

GS3D = ["renderer_config.gs3d.iterations=3", "renderer_config.gs3d.num_gaussians=200", "task_config.nvs.num_trajectories=1",
        "task_config.nvs.frame_stride=4", "task_config.nvs.lpips=false", "task_config.nvs.grid_frames=0"]  # fmt: skip


@pytest.fixture(scope="module")
def imported(tiny_root: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The tiny dataset exported and imported twice: without meshes and with the PLY meshes re-attached."""
    original = DatasetStore.open(tiny_config(tiny_root).data.dataset_dir())
    tmp = tmp_path_factory.mktemp("imported")
    export_nerf(original, tmp / "nerf", "ply", None, original.config["num_views_test"], original.config["interp_steps"])
    caps = sorted((tmp / "nerf").glob("traj_*/transforms.json"))
    return {"plain": import_video(caps, tmp / "plain").root, "meshes": import_video(caps, tmp / "meshes", meshes="meshes").root}


def _metrics(cfg) -> dict[str, float]:
    rdir = run_task(cfg, default_registry())
    rec = json.loads((rdir / RECORD_FILE).read_text())
    return {k: v["mean"] for k, v in rec["metrics"].items()}


def test_data_path_takes_the_sizes_from_the_dataset(imported: dict[str, Path], tiny_root: Path) -> None:
    cfg = load_config("ci", overrides=[f"data.path={imported['plain']}"])  # ci sizes differ from the tiny dataset's
    tiny = tiny_config(tiny_root).data
    for key in ("num_train", "num_test", "num_steps", "interp_steps", "num_cameras", "num_views_test", "image_size"):
        assert getattr(cfg.data, key) == getattr(tiny, key), key
    assert cfg.data.dataset_dir() == imported["plain"].resolve()
    assert "path" in cfg.data.identity()
    assert ensure_dataset(cfg, default_registry(), False).root == imported["plain"].resolve()
    with pytest.raises(ClodsError, match="nothing to generate"):
        generate(cfg.data, default_registry().get("scene", "flag"), progress=False)
    with pytest.raises(ClodsError, match="manifest.json missing"):
        load_config("ci", overrides=[f"data.path={tiny_root}"])


def test_unset_path_keeps_dataset_and_record_names(tiny_root: Path) -> None:
    cfg = tiny_config(tiny_root)
    assert "path" not in cfg.data.identity()  # so generated datasets keep the directory names they had
    rdir = record_dir(cfg, default_registry())
    d = cfg.to_dict()
    d["data"].pop("path")
    assert "path" not in json.dumps(d["data"]) and rdir == record_dir(cfg, default_registry())


def test_dvc_copylast_gives_the_same_numbers(imported: dict[str, Path], tiny_root: Path, tmp_path: Path) -> None:
    extra = ["task_config.dvc.lpips=false", f"runs_dir={tmp_path}"]
    a = _metrics(tiny_config(tiny_root, *extra, task="dvc", predictor="copylast"))
    b = _metrics(tiny_config(tiny_root, *extra, f"data.path={imported['plain']}", task="dvc", predictor="copylast"))
    assert a == b and set(a) == {"psnr", "ssim", "rmse"}


@pytest.mark.parametrize("sim", ["constvel", "mgn"])
def test_cdg_on_reattached_meshes_gives_the_same_numbers(imported: dict[str, Path], tiny_root: Path, tmp_path: Path, sim: str) -> None:
    """The round trip keeps what CDG reads: frames, cells, mesh space, node types and dt. The baseline needs no
    training; MGN (30 steps) trains on the imported meshes and must end with the same weights, so the same scores."""
    tiny_mgn = ["sim_config.mgn.train_steps=30", "sim_config.mgn.warmup_steps=5", "sim_config.mgn.latent_size=16",
                "sim_config.mgn.message_passing_steps=2"]  # fmt: skip
    a = _metrics(tiny_config(tiny_root, *tiny_mgn, f"runs_dir={tmp_path / 'a'}", task="cdg", sim=sim))
    b = _metrics(tiny_config(tiny_root, *tiny_mgn, f"runs_dir={tmp_path / 'b'}", f"data.path={imported['meshes']}", task="cdg", sim=sim))
    assert a.keys() == b.keys() and len(a) >= 12
    assert all(a[k] == b[k] for k in a), {k: (a[k], b[k]) for k in a if a[k] != b[k]}


def test_nvs_gs3d_on_reattached_meshes_gives_the_same_numbers(imported: dict[str, Path], tiny_root: Path, tmp_path: Path) -> None:
    a = _metrics(tiny_config(tiny_root, *GS3D, f"runs_dir={tmp_path}", task="nvs", renderer="gs3d"))
    b = _metrics(tiny_config(tiny_root, *GS3D, f"runs_dir={tmp_path}", f"data.path={imported['meshes']}", task="nvs", renderer="gs3d"))
    assert a.keys() == b.keys() and all(abs(a[k] - b[k]) < 1e-6 for k in a), (a, b)


def test_nvs_gs3d_without_meshes_fits_in_the_visual_hull_box(imported: dict[str, Path], tiny_root: Path, tmp_path: Path) -> None:
    cfg = tiny_config(tiny_root, *GS3D, f"runs_dir={tmp_path}", f"data.path={imported['plain']}", "renderer_config.gs3d.init=random",
                      task="nvs", renderer="gs3d")  # fmt: skip
    rdir = run_task(cfg, default_registry())
    res = json.loads((rdir / "seed_0" / "result.json").read_text())
    assert res["extra"]["geometry"].startswith("visual-hull box") and res["extra"]["fits"] == len(res["extra"]["frames"])
    assert np.isfinite(res["metrics"]["psnr"])


def test_hull_box_contains_the_true_mesh(tiny_root: Path) -> None:
    """The box from the training views' silhouettes holds every vertex of the ground-truth mesh (to one grid cell)."""
    store = DatasetStore.open(tiny_config(tiny_root).data.dataset_dir())
    cams, traj, frames = store.cameras(), store.load_trajectory(0), store.load_frames(0)
    for t in (0, 6, 11):
        lo, hi = hull_box(frames[t], cams)
        verts = traj.world_pos[t]
        assert (verts >= lo).all() and (verts <= hi).all()
        span = verts.max(0) - verts.min(0)
        # not much larger than the cloth: 3 cameras carve a thin sheet loosely across its plane, but within its size
        assert (hi - lo).max() < 1.5 * np.linalg.norm(span)
    v, cells, _ = box_mesh(lo, hi)
    assert v.shape == (8, 3) and cells.shape == (12, 3)
    # outward normals: each face normal points away from the box centre
    n = np.cross(v[cells[:, 1]] - v[cells[:, 0]], v[cells[:, 2]] - v[cells[:, 0]])
    assert (np.einsum("fi,fi->f", n, v[cells].mean(1) - v.mean(0)) > 0).all()
    with pytest.raises(ClodsError, match="no foreground"):
        hull_box(np.full_like(frames[0], 255), cams)
    assert not foreground(np.full((1, 4, 4, 3), 250, np.uint8)).any() and foreground(np.zeros((1, 4, 4, 3), np.uint8)).all()


@pytest.mark.parametrize(
    ("task", "fields", "extra", "what"),
    [
        ("cdg", {"sim": "constvel"}, [], "task cdg"),
        ("stability", {"sim": "constvel"}, [], "task stability"),
        ("nvs", {"renderer": "smgs"}, [], "renderer 'smgs'"),
        ("nvs", {"renderer": "games"}, [], "renderer 'games'"),
        ("dvc_multi", {"sim": "frozen", "renderer": "games"}, ["task_config.dvc_multi.gen_context=3"], "initial_mesh=truth starts stage 2 from the true frame-0 mesh"),
        ("dvc_multi", {"sim": "frozen", "renderer": "games"}, ["task_config.dvc_multi.gen_context=3", "task_config.dvc_multi.sim_training=mesh"], "task_config.dvc_multi.sim_training=mesh (it trains the simulator on ground-truth meshes)"),
        # the CloDS stages on video alone need the initial mesh from the images, and its node count
        ("extract", {"renderer": "games"}, [], "initial_mesh=truth starts stage 2 from the true frame-0 mesh"),
        ("dvc", {"sim": "frozen", "renderer": "games"}, [], "initial_mesh=truth starts stage 2 from the true frame-0 mesh"),
        ("dvc", {"sim": "frozen", "renderer": "games"}, ["task_config.dvc.sim_training=mesh"], "task_config.dvc.sim_training=mesh (it trains the simulator on ground-truth meshes)"),
        ("extract", {"renderer": "games"}, ["task_config.clods.initial_mesh=reconstructed"], "no meshes to take the node count"),
        ("initial_mesh", {}, [], "no meshes to take the node count"),
    ],
)
def test_tasks_that_need_meshes_refuse_in_one_line(imported, tiny_root: Path, tmp_path: Path, task, fields, extra, what) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path}", f"data.path={imported['plain']}", *extra, task=task, **fields)
    with pytest.raises(ClodsError, match="has no meshes") as info:
        run_task(cfg, default_registry())
    assert what in info.value.message and "\n" not in info.value.message


# CloDS on video alone, shrunk to seconds: stage 0 (the mesh from frame 0's images), stage 1, stage 2, stage 3
VIDEO_ONLY = ["task_config.clods.initial_mesh=reconstructed", "task_config.clods.stage0.iterations=30",
              "task_config.clods.stage0.num_surfels=300", "task_config.clods.stage0.refine_iterations=10",
              "task_config.clods.stage0.num_nodes=24", "renderer_config.games.iterations=10",
              "renderer_config.games.gaussians_per_face=1", "task_config.clods.iterations=2", "task_config.clods.min_iterations=2"]  # fmt: skip


def _recovered(runs: Path, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, object]:
    """(frames, cells, mesh_pos, renderer) of one video from the pipeline's caches alone: stage 2's tracked frames, the
    stage-0 mesh they start from (its rest shape is their frame 0), the stage-1 renderer fitted on that mesh."""
    import torch

    (tracked,) = (runs / "clods_cache").glob(f"*/traj_{index:04d}.npz")
    with np.load(tracked) as z:
        frames = z["world_pos"].astype(np.float64)
    for f in (runs / "clods_cache").glob("stage0-*.npz"):
        with np.load(f) as z:
            if z["rest_pos"].shape == frames[0].shape and np.abs(z["rest_pos"] - frames[0]).max() < 1e-6:
                cells, mesh_pos = z["cells"], z["mesh_pos"]
                break
    else:
        raise AssertionError(f"no stage-0 mesh starts video {index}")
    renderers = [torch.load(f, weights_only=False) for f in (runs / "clods_cache").glob("stage1-*.pt")]
    (renderer,) = [r for r in renderers if np.array_equal(np.asarray(r.cells), cells)]
    return frames, cells, mesh_pos, renderer


def test_dvc_from_video_alone_equals_the_meshed_run_and_its_images(imported, tiny_root: Path, tmp_path: Path) -> None:
    """`dvc --sim --renderer` with a reconstructed initial mesh reads nothing of the truth: the dataset without meshes
    gives the original's numbers. With the frozen simulator each video's own mesh stays at its recovered frame 1 with
    the handles found in its motion held at frame 0: the scores are recomputed here from the pipeline's caches."""
    import torch

    from clods_bench.benchmark.clods.reconstructed import detect_handles
    from clods_bench.benchmark.outputs.mesh_pictures import load_mesh_sample
    from clods_bench.benchmark.scoring.image_metrics import psnr

    fields = {"task": "dvc", "sim": "frozen", "renderer": "games"}
    extra = [*VIDEO_ONLY, "task_config.dvc.lpips=false", "task_config.dvc.sim_training=video"]
    meshed = _metrics(tiny_config(tiny_root, *extra, f"runs_dir={tmp_path / 'a'}", **fields))
    cfg = tiny_config(tiny_root, *extra, f"runs_dir={tmp_path / 'b'}", f"data.path={imported['plain']}", **fields)
    rdir = run_task(cfg, default_registry())
    rec = json.loads((rdir / RECORD_FILE).read_text())
    alone = {k: v["mean"] for k, v in rec["metrics"].items()}
    assert alone.keys() == meshed.keys() and all(alone[k] == pytest.approx(meshed[k], rel=1e-6) for k in alone), (alone, meshed)
    assert rec["per_seed"]["0"]["extra"]["mesh"] == "reconstructed (per video)"
    store = DatasetStore.open(imported["plain"])
    cam = store.cameras()[2]  # the held-out camera
    future, every = [], []
    for i in (0, 1):
        frames, cells, mesh_pos, renderer = _recovered(tmp_path / "b", i)
        pinned = np.zeros(len(mesh_pos), bool)
        pinned[detect_handles(frames, mesh_pos, cells)] = True
        video = np.asarray(store.frames(i)[:, [2]], np.float64)[:, 0] / 255.0
        for t in range(1, 12):
            mesh = frames[1].copy()
            if t >= 2:
                mesh[pinned] = frames[0][pinned]
            with torch.no_grad():
                img = renderer.render(torch.from_numpy(mesh.astype(np.float32)), [cam]).numpy()[0]
            every.append(psnr(img, video[t]))
            if t in (9, 10, 11):
                future.append(psnr(img, video[t]))
        if i == 0:  # the predicted cloth on its own mesh, for the report and `data export-meshes`
            saved_cells, saved, truth, _, _ = load_mesh_sample(rdir / "seed_0" / "rollout_meshes.npz")
            assert truth is None and np.array_equal(saved_cells, cells)
            np.testing.assert_allclose(next(iter(saved.values()))[5], np.where(pinned[:, None], frames[0], frames[1]), atol=1e-6)
    assert alone["psnr"] == pytest.approx(np.mean(future), rel=1e-5)
    assert alone["all/psnr"] == pytest.approx(np.mean(every), rel=1e-5)


def test_dvc_multi_from_video_alone_equals_the_meshed_run(imported, tiny_root: Path, tmp_path: Path) -> None:
    """The multi-trajectory row from video alone: the training videos roll out on their own meshes, each unseen
    Generalization video on the mesh stages 0-2 recover from its 3 given frames alone; the dataset without meshes
    gives the original's numbers, and the unseen videos' extraction used only the given frames."""
    fields = {"task": "dvc_multi", "sim": "frozen", "renderer": "games"}
    extra = [*VIDEO_ONLY, "task_config.dvc_multi.lpips=false", "task_config.dvc_multi.gen_context=3", "task_config.dvc_multi.sim_training=video"]
    meshed = _metrics(tiny_config(tiny_root, *extra, f"runs_dir={tmp_path / 'a'}", **fields))
    cfg = tiny_config(tiny_root, *extra, f"runs_dir={tmp_path / 'b'}", f"data.path={imported['plain']}", **fields)
    rdir = run_task(cfg, default_registry())
    rec = json.loads((rdir / RECORD_FILE).read_text())
    alone = {k: v["mean"] for k, v in rec["metrics"].items()}
    assert alone.keys() == meshed.keys() and {"extrap/psnr", "gen/psnr"} <= alone.keys()
    assert all(alone[k] == pytest.approx(meshed[k], rel=1e-6) for k in alone), (alone, meshed)
    assert rec["per_seed"]["0"]["extra"]["mesh"] == "reconstructed (per video)"
    tracked = sorted((tmp_path / "b" / "clods_cache").glob("*/traj_*.npz"))
    lengths = {p.stem: np.load(p)["world_pos"].shape[0] for p in tracked}
    assert lengths == {"traj_0000": 9, "traj_0001": 9, "traj_0002": 3}  # training videos 0..interp, the unseen one 0..2


def test_extract_from_video_alone_is_scored_in_images(imported, tiny_root: Path, tmp_path: Path) -> None:
    """Stages 0-2 on a dataset without meshes: the extracted meshes rendered by their stage-1 renderer against the
    held-out camera's frames (recomputed here from the caches) and the training cameras'; E-GT where meshes exist."""
    import torch

    from clods_bench.benchmark.scoring.image_metrics import psnr

    extra = [*VIDEO_ONLY, "task_config.extract.lpips=false"]
    meshed = _metrics(tiny_config(tiny_root, *extra, f"runs_dir={tmp_path / 'a'}", task="extract", renderer="games"))
    alone = _metrics(tiny_config(tiny_root, *extra, f"runs_dir={tmp_path / 'b'}", f"data.path={imported['plain']}", task="extract", renderer="games"))
    assert {"egt_avg", "edge_strain_max"} <= meshed.keys() and "psnr" not in meshed
    assert set(alone) == {"psnr", "ssim", "rmse", "train/psnr", "train/ssim", "train/rmse", "edge_strain_max"}
    assert alone["edge_strain_max"] == pytest.approx(meshed["edge_strain_max"], rel=1e-6)  # the same extraction
    store = DatasetStore.open(imported["plain"])
    held = []
    for i in (0, 1):
        frames, cells, _, renderer = _recovered(tmp_path / 'b', i)
        video = np.asarray(store.frames(i)[:, [2]], np.float64)[:, 0] / 255.0
        for t in range(1, len(frames)):
            with torch.no_grad():
                held.append(psnr(renderer.render(torch.from_numpy(frames[t].astype(np.float32)), [store.cameras()[2]]).numpy()[0], video[t]))
    assert alone["psnr"] == pytest.approx(np.mean(held), rel=1e-5)
    assert alone["train/psnr"] > alone["psnr"]  # stage 2 fitted the training cameras
    from clods_bench.benchmark.outputs.tables import write_tables

    md = next(p for p in write_tables(tmp_path / "b", tmp_path / "tables", task="extract") if p.suffix == ".md").read_text()
    assert "held-out PSNR (dB)" in md and f"{alone['psnr']:.4f}" in md and "E-GT" not in md
    from clods_bench.benchmark.outputs.html_report import build_html_report

    written = build_html_report(tmp_path / "b", tmp_path / "report")
    html = (tmp_path / "report" / "index.html").read_text()
    assert "re-rendered in the held-out cameras" in html and any(p.name.startswith("extraction_egt") for p in written)


def test_initial_mesh_from_video_alone_is_scored_by_its_held_out_silhouette(imported, tiny_root: Path, tmp_path: Path) -> None:
    im = ["task_config.initial_mesh.iterations=30", "task_config.initial_mesh.num_surfels=300",
          "task_config.initial_mesh.refine_iterations=10", "task_config.initial_mesh.num_nodes=24", f"runs_dir={tmp_path}"]  # fmt: skip
    meshed = _metrics(tiny_config(tiny_root, *im, task="initial_mesh"))
    alone = _metrics(tiny_config(tiny_root, *im, f"data.path={imported['plain']}", task="initial_mesh"))
    assert "attached_rmse" in meshed and set(alone) == {"heldout_iou", "nodes"} and alone["nodes"] == meshed["nodes"] == 24
    assert 0.0 < alone["heldout_iou"] <= 1.0


def test_silhouette_iou_is_one_for_the_true_mesh_and_drops_as_it_moves(tiny_root: Path) -> None:
    """The held-out silhouette score against the rendered frames of a 48 px rig: the true mesh covers the cloth's
    pixels (up to the anti-aliased rim), a mesh shifted by a fifth of its size much less, one moved away not at all."""
    from clods_bench.benchmark.tasks.initial_mesh import silhouette_iou
    from clods_bench.datasets.cameras import camera_rig
    from clods_bench.datasets.rasterizer import RasterSettings, render_views
    from clods_bench.datasets.types import ClothMesh

    traj = DatasetStore.open(tiny_config(tiny_root).data.dataset_dir()).load_trajectory(0)
    x0 = traj.world_pos[0].astype(np.float64)
    size = float(np.ptp(x0, axis=0).max())
    cams = camera_rig(3, x0.mean(axis=0), 3.0 * size, 48, 48, fov_deg=40.0)
    uv = (traj.mesh_pos - traj.mesh_pos.min(0)) / np.ptp(traj.mesh_pos, axis=0).max()
    images = render_views(x0, traj.cells, uv.astype(np.float32), np.zeros((4, 4, 3), np.float32), cams, RasterSettings())
    images = np.clip(np.rint(images * 255.0), 0, 255).astype(np.uint8)

    def iou(shift: float) -> float:
        pos = x0 + np.array([shift * size, 0.0, 0.0])
        return silhouette_iou(ClothMesh(traj.cells, traj.mesh_pos, traj.node_type, pos), images, cams, 0.08)

    assert iou(0.0) > 0.9
    assert iou(0.2) < iou(0.0) - 0.1
    assert iou(5.0) == 0.0
