"""The report's 3D view opened in headless Chromium: it draws the meshes in their strain colours, jumps to a frame,
and the figure it draws holds the run's frames and methods. Skipped where `chromium` is not installed."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.html_report import build_html_report
from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, load_rollout_sample
from clods_bench.benchmark.outputs.rollout_view3d import read_view3d_figure
from clods_bench.benchmark.outputs.watch import build_watch
from clods_bench.benchmark.running.run_data import ensure_complete_dataset
from clods_bench.benchmark.running.runner import run_task
from tests.benchmark.outputs.watch_data import TEAR_AT, tearing, truth_frames, write_record
from tests.conftest import tiny_config

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not on PATH (Debian: apt-get install chromium): the 3D view is not opened in a browser")


def _screenshot(page: Path, tmp: Path, name: str, fragment: str = "") -> np.ndarray:
    """(900, 1400, 3) uint8 screenshot of `page` (with `#fragment`) after 5 s of virtual time."""
    from PIL import Image

    png = tmp / f"{name}.png"
    cmd = [str(CHROMIUM), "--headless", "--disable-gpu", "--no-sandbox", f"--user-data-dir={tmp / 'profile'}", f"--screenshot={png}",
           "--window-size=1400,900", "--virtual-time-budget=5000", page.as_uri() + fragment]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert png.is_file(), f"chromium wrote no screenshot (exit {done.returncode}): {done.stderr[-2000:]}"
    with Image.open(png) as img:
        return np.asarray(img.convert("RGB"))


def _plot_area(shot: np.ndarray) -> np.ndarray:
    """The scene: below the captions and the title, left of the legend and colour bar, above the slider."""
    return shot[200:640, 0:1180]


def _coloured(area: np.ndarray) -> int:
    """Pixels with a clear hue (the strain colours; white, greys and black text have none)."""
    a = area.astype(np.int64)
    return int(((a.max(axis=-1) - a.min(axis=-1)) > 40).sum())


def test_3d_view_of_real_runs_draws_their_frames_and_methods(tiny_root: Path, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    reg = default_registry()
    dirs = [run_task(tiny_config(tiny_root, f"runs_dir={runs}", sim=sim), reg, ensure_data=ensure_complete_dataset) for sim in ("constvel", "frozen")]
    out = tmp_path / "report"
    build_html_report(runs, out, warn=lambda line: pytest.fail(f"unexpected warning: {line}"))
    (page,) = sorted((out / "watch").glob("*_3d.html"))
    fig = read_view3d_figure(page)
    sample = load_rollout_sample(dirs[0] / "seed_0" / ROLLOUT_FILE)
    assert [f["name"] for f in fig["frames"]] == [str(t) for t in range(sample.num_frames)]
    assert [t["name"] for t in fig["data"] if t["type"] == "mesh3d"] == ["ground truth", "Const. velocity (seed 0)", "Frozen (seed 0)"]
    shot = _screenshot(page, tmp_path, "view")
    area = _plot_area(shot)
    assert len(np.unique(area.reshape(-1, 3), axis=0)) > 200, "the scene looks blank"
    assert _coloured(area) > 1500, "no strain-coloured meshes in the scene"
    legend = shot[150:400, 1180:]
    assert _coloured(legend) > 50  # the legend's swatches and the colour bar


def test_3d_view_jumps_to_the_divergence_frame(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    records = [write_record(runs, "cdg", "tear", tearing(), truth_frames())]
    groups = {"cdg": {("flag", "ci"): records}}
    items, _ = build_watch(groups, tmp_path / "out", default_registry(), warn=lambda line: None, fmt="webp")
    page = items[0].view3d
    before = _screenshot(page, tmp_path, "first")
    after = _screenshot(page, tmp_path, "diverged", f"#frame={TEAR_AT}")

    def red(img: np.ndarray) -> int:
        a = img[:220].astype(np.int64)  # the captions (their red "jump to" links in both), the title and its frame line
        return int(((a[..., 0] > 150) & (a[..., 1] < 90) & (a[..., 2] < 90)).sum())

    assert red(after) - red(before) > 30  # the frame line adds "diverged: tear (seed 0) at frame 6" in red
    assert np.abs(_plot_area(after).astype(int) - _plot_area(before).astype(int)).sum(axis=-1).astype(bool).sum() > 2000  # the cloth moved
