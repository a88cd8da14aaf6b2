"""`clods-bench report`: one self-contained HTML page with every task's table, the plots and the runs' media embedded."""

from __future__ import annotations

import base64
import re
import shutil
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.animation_files import read_animation
from clods_bench.benchmark.outputs.html_report import build_html_report
from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, load_rollout_sample
from clods_bench.benchmark.outputs.rollout_view3d import read_view3d_figure
from clods_bench.benchmark.running.run_data import ensure_complete_dataset
from clods_bench.benchmark.running.runner import run_task
from clods_bench.benchmark.tasks.nvs import GRID_FILE
from clods_bench.cli import main
from clods_bench.errors import ClodsError
from tests.benchmark.tasks.test_nvs import _run
from tests.conftest import tiny_config


def _embedded(page: str, mime: str) -> list[bytes]:
    return [base64.b64decode(m) for m in re.findall(rf'src="data:{re.escape(mime)};base64,([A-Za-z0-9+/=]+)"', page)]


def test_report_embeds_tables_plots_grids_and_videos(tiny_root: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    reg = default_registry()
    cdg_dirs = [run_task(tiny_config(tiny_root, f"runs_dir={runs}", sim=sim), reg, ensure_data=ensure_complete_dataset) for sim in ("constvel", "frozen")]
    _, nvs_dir, _ = _run(tiny_root, tmp_path, "constant", "task_config.nvs.lpips=false")
    video = np.zeros((4, 8, 8, 3), np.uint8)
    video[:, :, :4] = 255
    iio.imwrite(cdg_dirs[0] / "seed_0" / "rollout.gif", video)  # what a DVC run leaves in its seed directory

    out = tmp_path / "report"
    paths = build_html_report(runs, out)
    assert out / "index.html" in paths and (out / "error_vs_time_flag_ci.png").is_file() and (out / "rollout_rmse_flag_ci.csv").is_file()
    page = (out / "index.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "http" not in page.split("<body>")[1].split("Records under")[0]
    for label in ("Const. velocity", "Frozen", "constant"):
        assert f">{label}</th>" in page
    assert "PSNR (dB)" in page and "Unviewed" in page  # the NVS and CDG layouts
    pngs = _embedded(page, "image/png")
    assert (nvs_dir / "seed_0" / GRID_FILE).read_bytes() in pngs
    assert (out / "error_vs_time_flag_ci.png").read_bytes() in pngs and (out / "rollout_rmse_flag_ci.png").read_bytes() in pngs
    assert _embedded(page, "image/gif") == [(cdg_dirs[0] / "seed_0" / "rollout.gif").read_bytes()]
    pictures = sorted((out / "meshes").glob("*rollout_meshes.png"))  # one mesh picture per CDG run (truth beside rollout)
    assert len(pictures) == 2 and all(p.read_bytes() in pngs for p in pictures) and "per-node error as colour" in page
    # Watch: one video and one 3D view for the two CDG rows (same trajectory), one animation of the NVS frames
    videos = sorted(p.name for p in (out / "watch").iterdir() if p.suffix in (".mp4", ".webp"))
    assert [v.split("_")[0] for v in videos] == ["cdg", "nvs"] and len(list((out / "watch").glob("*_3d.html"))) == 1
    assert "<h2 id='watch'>Watch: rollouts and predicted frames</h2>" in page and "Watch: 2 videos, 1 3D view</a>" in page
    view = next((out / "watch").glob("*_3d.html"))
    assert f"<a href='watch/{view.name}'>open the 3D view</a>" in page and "Const. velocity (seed 0), Frozen (seed 0)" in page
    sample = load_rollout_sample(cdg_dirs[0] / "seed_0" / ROLLOUT_FILE)
    assert len(read_view3d_figure(view)["frames"]) == sample.num_frames == len(read_animation(out / "watch" / videos[0]))
    # through the CLI, with an NVS-only runs folder (no CDG plots to make)
    nvs_only = tmp_path / "nvs_only"
    shutil.copytree(nvs_dir, nvs_only / nvs_dir.relative_to(runs))
    assert main(["report", "--runs", str(nvs_only), "--out", str(tmp_path / "r2")]) == 0
    assert sorted(p.name for p in (tmp_path / "r2").iterdir()) == ["index.html", "watch"]
    assert [p.name.split("_")[0] for p in (tmp_path / "r2" / "watch").iterdir()] == ["nvs"]  # the NVS frames animated; no 3D view
    assert (nvs_dir / "seed_0" / GRID_FILE).read_bytes() in _embedded((tmp_path / "r2" / "index.html").read_text(), "image/png")
    assert main(["report", "--runs", str(tmp_path / "missing"), "--out", str(tmp_path / "r3")]) == 2


def test_report_without_records_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(ClodsError, match="no run records found"):
        build_html_report(tmp_path / "empty", tmp_path / "out")
