"""Running tasks on an imported dataset (`data.path`): the same numbers as on the original where the task needs no
meshes, the visual-hull proxy for per-frame 3DGS, and one clear refusal from every task that needs meshes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.config import load_config
from clods_bench.benchmark.records import RECORD_FILE, record_dir
from clods_bench.benchmark.registry import default_registry
from clods_bench.benchmark.runner import run_task
from clods_bench.datasets.generate import ensure_dataset, generate
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
    rdir = record_dir(cfg)
    d = cfg.to_dict()
    d["data"].pop("path")
    assert "path" not in json.dumps(d["data"]) and rdir == record_dir(cfg)


def test_dvc_copylast_gives_the_same_numbers(imported: dict[str, Path], tiny_root: Path, tmp_path: Path) -> None:
    extra = ["task_config.dvc.lpips=false", f"runs_dir={tmp_path}"]
    a = _metrics(tiny_config(tiny_root, *extra, task="dvc", predictor="copylast"))
    b = _metrics(tiny_config(tiny_root, *extra, f"data.path={imported['plain']}", task="dvc", predictor="copylast"))
    assert a == b and set(a) == {"psnr", "ssim", "rmse"}


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
    ("task", "fields", "what"),
    [
        ("cdg", {"sim": "constvel"}, "task cdg"),
        ("stability", {"sim": "constvel"}, "task stability"),
        ("extract", {"renderer": "games"}, "task extract"),
        ("nvs", {"renderer": "smgs"}, "renderer 'smgs'"),
        ("nvs", {"renderer": "games"}, "renderer 'games'"),
        ("dvc", {"sim": "frozen", "renderer": "games"}, "dvc with a simulator and renderer"),
    ],
)
def test_tasks_that_need_meshes_refuse_in_one_line(imported, tiny_root: Path, tmp_path: Path, task, fields, what) -> None:
    cfg = tiny_config(tiny_root, f"runs_dir={tmp_path}", f"data.path={imported['plain']}", task=task, **fields)
    with pytest.raises(ClodsError, match="the dataset has no meshes") as info:
        run_task(cfg, default_registry())
    assert what in info.value.message and "\n" not in info.value.message
