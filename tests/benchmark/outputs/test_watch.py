"""The report's Watch section: strain and divergence of saved rollouts, the videos (frame count, size, the red
divergence marking), the 3D view's figure, the NVS/DVC animations, and one warning per run that cannot be watched."""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pytest

from clods_bench.benchmark.core.registry import default_registry
from clods_bench.benchmark.outputs.animation_files import CONTROLS_PAD, mp4_available, read_animation, write_animation
from clods_bench.benchmark.outputs.film_video import LABEL_W, MIN_TILE, TOP_H, film_video_frames
from clods_bench.benchmark.outputs.films import FILM_MAX_FRAMES, load_film, save_film
from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, load_rollout_sample
from clods_bench.benchmark.outputs.rollout_strain import ENERGY_FACTOR, TEAR_STRAIN, face_strain, rollout_divergence, strain_model
from clods_bench.benchmark.outputs.rollout_video import DIVERGED_RGB, FOOTER_H, HEADER_H, PANEL_H, PANEL_W, SCALE_H, TITLE_H
from clods_bench.benchmark.outputs.rollout_view3d import read_view3d_figure
from clods_bench.benchmark.outputs.watch import build_watch
from clods_bench.benchmark.tasks.stability import StabilityConfig
from clods_bench.errors import ClodsError
from tests.benchmark.outputs.watch_data import FRAMES, MESH, NAN_AT, TEAR_AT, exploding, tearing, truth_frames, write_record


def _red(frame: np.ndarray) -> np.ndarray:
    """Pixels of the divergence red (viridis, the grey bars and the text hold none)."""
    f = frame.astype(np.int64)
    return (np.abs(f - np.array(DIVERGED_RGB)).sum(axis=-1) < 60)


def _groups(*records: tuple[Path, dict]) -> dict:
    out: dict = {}
    for rdir, rec in records:
        out.setdefault(rec["task"], {}).setdefault((rec["scene"], rec["preset"]), []).append((rdir, rec))
    return out


def test_thresholds_are_the_stability_tasks_defaults() -> None:
    assert (TEAR_STRAIN, ENERGY_FACTOR) == (StabilityConfig().strain_threshold, StabilityConfig().energy_factor)


def test_face_strain_by_hand(tmp_path: Path) -> None:
    rdir, _ = write_record(tmp_path, "cdg", "m", truth_frames(), truth_frames())
    sample = load_rollout_sample(rdir / "seed_0" / ROLLOUT_FILE)
    model = strain_model(sample, None)  # no scene: the flat rest shape (u, 0, v) of the mesh coordinates, the flag's own
    rest = MESH.rest_pos[None].astype(np.float64)
    assert np.abs(face_strain(model, rest)).max() < 1e-6  # the sample keeps mesh_pos in float32
    stretched = rest * np.array([1.2, 1.0, 1.0])  # x edges 20 % longer, vertical ones unchanged, diagonals in between
    assert face_strain(model, stretched)[0] == pytest.approx(np.full(len(MESH.cells), 0.2), abs=1e-6)
    broken = rest.copy()
    broken[0, 0] = np.nan
    faces = face_strain(model, broken)[0]
    touching = (MESH.cells == 0).any(axis=1)
    assert np.isnan(faces[touching]).all() and np.isfinite(faces[~touching]).all()


def test_divergence_is_the_runs_own(tmp_path: Path) -> None:
    scene = default_registry().get("scene", "flag")
    # CDG: the stability monitors find the tear; a recorded non-finite frame earlier than any tear wins
    rdir, _ = write_record(tmp_path, "cdg", "tear", tearing(), truth_frames())
    sample = load_rollout_sample(rdir / "seed_0" / ROLLOUT_FILE)
    model = strain_model(sample, scene)
    assert model.rest_source == "the scene's rest mesh" or model.rest_source.startswith("the flat")
    div = rollout_divergence(sample, model, "cdg", None)
    assert div is not None and div.frame == TEAR_AT and div.reason.startswith("edge strain") and "> 0.5" in div.reason
    div = rollout_divergence(sample, model, "cdg", {"extra": {"diverged": {"unviewed/4": 3}}})
    assert (div.frame, div.reason, div.source) == (3, "non-finite positions (NaN/Inf)", "the CDG run")
    rdir, _ = write_record(tmp_path, "cdg", "nan", exploding(), truth_frames())
    sample = load_rollout_sample(rdir / "seed_0" / ROLLOUT_FILE)
    assert rollout_divergence(sample, strain_model(sample, scene), "cdg", None).frame == NAN_AT
    # stability: the recorded failure frame and reason, or none when the run recorded none for this trajectory
    result = {"extra": {"diverged": {"unviewed/4": 7}, "reasons": {"unviewed/4": "kinetic energy 9 J > 1 J"}}}
    div = rollout_divergence(sample, strain_model(sample, scene), "stability", result)
    assert (div.frame, div.reason) == (7, "kinetic energy 9 J > 1 J")
    assert rollout_divergence(sample, strain_model(sample, scene), "stability", {"extra": {"diverged": {}}}) is None


@pytest.mark.parametrize("fmt", ["webp", "mp4"])
def test_rollout_video_frames_size_and_divergence_marking(tmp_path: Path, fmt: str) -> None:
    if fmt == "mp4" and not mp4_available():
        pytest.skip("PyAV is not installed (the video extra): MP4 cannot be written")
    runs = tmp_path / "runs"
    records = [write_record(runs, "cdg", "tear", tearing(), truth_frames()), write_record(runs, "cdg", "steady", truth_frames() + 0.001, truth_frames())]
    lines: list[str] = []
    items, warnings = build_watch(_groups(*records), tmp_path / "out", default_registry(), warn=lines.append, fmt=fmt)
    assert warnings == lines == []
    assert len(items) == 1 and items[0].video.suffix == f".{fmt}" and items[0].view3d is not None
    assert "ground truth, steady (seed 0), tear (seed 0)" in items[0].caption and f"diverged at frame {TEAR_AT}" in items[0].caption
    video = read_animation(items[0].video)
    cell_h = HEADER_H + PANEL_H + FOOTER_H
    assert video.shape == (FRAMES, TITLE_H + cell_h + SCALE_H + CONTROLS_PAD, 3 * PANEL_W, 3)  # truth, steady, tear in one row
    footer = slice(TITLE_H + HEADER_H + PANEL_H, TITLE_H + cell_h)
    for t, frame in enumerate(video):
        red = _red(frame)
        tear_footer = red[footer, 2 * PANEL_W :].mean()
        assert (tear_footer > 0.5) == (t >= TEAR_AT), (t, tear_footer)  # the diverged panel's counter bar is red from the frame on
        assert red[:, : 2 * PANEL_W].sum() < 20  # never under the truth or the steady rollout
        if t < TEAR_AT:
            assert red.sum() < 20


def test_view3d_figure_holds_every_frame_and_method(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    records = [write_record(runs, "stability", "nan", exploding(), truth_frames(), result={"extra": {"diverged": {"unviewed/4": NAN_AT},
               "reasons": {"unviewed/4": "non-finite positions (NaN/Inf)"}}}), write_record(runs, "stability", "tear", tearing(), truth_frames())]  # fmt: skip
    items, _ = build_watch(_groups(*records), tmp_path / "out", default_registry(), warn=lambda line: None, fmt="webp")
    page = items[0].view3d
    text = page.read_text()
    assert '<script src="plotly.min.js">' in text and (page.parent / "plotly.min.js").stat().st_size > 10**6
    assert "://" not in text.split("<script", 1)[1].split("application/json")[0]  # nothing fetched at view time
    fig = read_view3d_figure(page)
    meshes = [t for t in fig["data"] if t["type"] == "mesh3d"]
    assert [t["name"] for t in meshes] == ["ground truth", "nan (seed 0)", "tear (seed 0)"]
    assert [f["name"] for f in fig["frames"]] == [str(t) for t in range(FRAMES)]
    assert items[0].jumps == [("nan (seed 0)", NAN_AT), ("tear (seed 0)", TEAR_AT)]  # stability without a result: the monitors

    def decoded(spec: dict) -> np.ndarray:
        return np.frombuffer(base64.b64decode(spec["bdata"]), np.dtype(spec["dtype"]))

    frame = fig["frames"][NAN_AT + 1]
    shown = decoded(frame["data"][1]["z"])  # the non-finite rollout holds its last finite frame
    np.testing.assert_allclose(shown, exploding()[NAN_AT - 1, :, 2], atol=1e-6)
    assert "diverged: nan (seed 0) at frame 9, tear (seed 0) at frame 6" in frame["layout"]["title"]["text"]
    assert "diverged" not in fig["frames"][TEAR_AT - 1]["layout"]["title"]["text"]
    truth_x = decoded(fig["frames"][3]["data"][0]["x"])
    np.testing.assert_allclose(truth_x, truth_frames()[3, :, 0], atol=1e-6)  # the truth's slot has no offset


def test_view3d_thins_frames_to_its_budget(tmp_path: Path) -> None:
    from clods_bench.benchmark.outputs.rollout_video import Panel
    from clods_bench.benchmark.outputs.rollout_view3d import view3d_figure

    frames = truth_frames(200)
    strain = np.zeros((200, len(MESH.cells)))
    fig, picks = view3d_figure(MESH.cells, [Panel("a", frames, strain), Panel("b", frames, strain, None)], "t", budget=40_000)
    assert picks[0] == 0 and picks[-1] == 199 and 5 < len(picks) < 200 and [f["name"] for f in fig["frames"]] == [str(p) for p in picks]


def test_film_animation_labels_rows_and_frames(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    truth = rng.random((2, 5, 16, 24, 3))
    films = []
    for label in ("b", "a"):
        path = save_film(tmp_path / f"{label}_frames.npz", truth, np.clip(truth + 0.1, 0, 1), [3, 5], [10, 11, 12, 13, 14], "traj 0", label)
        films.append((label, load_film(path)))
    assert films[0][1].truth.dtype == np.uint8 and films[0][1].frames == [10, 11, 12, 13, 14]
    video = film_video_frames(films, "Table 3")
    k = MIN_TILE // 24 + 1  # tiles enlarged to at least 128 px a side
    assert video.shape[0] == 5 and video.shape[2] == LABEL_W + 2 * (24 * k + 4) + 4 and video.shape[1] == TOP_H + 3 * (16 * k + 4) + 4 + CONTROLS_PAD
    tile = video[2, TOP_H + 4 : TOP_H + 4 + 16 * k : k, LABEL_W + 4 : LABEL_W + 4 + 24 * k : k]
    np.testing.assert_array_equal(tile, films[0][1].truth[0, 2])  # row 0, view 0, frame 2: the truth
    long = save_film(tmp_path / "long_frames.npz", np.zeros((1, 300, 4, 4, 3)), np.zeros((1, 300, 4, 4, 3)), [0], list(range(300)), "traj 0")
    assert len(load_film(long).frames) == FILM_MAX_FRAMES and load_film(long).frames[-1] == 299
    with pytest.raises(ClodsError, match="must both be"):
        save_film(tmp_path / "x_frames.npz", truth, truth[:, :2], [3, 5], [10, 11, 12, 13, 14], "traj 0")


def test_runs_that_cannot_be_watched_are_one_line_each(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    good = write_record(runs, "cdg", "good", truth_frames() + 0.001, truth_frames())
    missing = write_record(runs, "cdg", "gone", truth_frames(), truth_frames())
    (missing[0] / "seed_0" / ROLLOUT_FILE).unlink()
    broken = write_record(runs, "stability", "broken", truth_frames(), truth_frames())
    (broken[0] / "seed_0" / ROLLOUT_FILE).write_bytes(b"not a zip")
    nvs_dir = runs / "nvs" / "games" / "flag-ci-0000"
    (nvs_dir / "seed_0").mkdir(parents=True)
    nvs = (nvs_dir, {"task": "nvs", "label": "GaMeS", "scene": "flag", "preset": "ci", "seeds": [0]})
    save_film(nvs_dir / "seed_0" / "nvs_frames.npz", np.zeros((1, 2, 8, 8, 3)), np.ones((1, 2, 8, 8, 3)), [4], [0, 10], "traj 0")
    lines: list[str] = []
    items, warnings = build_watch(_groups(good, missing, broken, nvs), tmp_path / "out", default_registry(), warn=lines.append, fmt="webp")
    assert lines == warnings and len(lines) == 2
    assert lines[0].startswith(f"cdg record {missing[0]} (gone): ") and "rollout_meshes.npz" in lines[0] and "missing" in lines[0]
    assert lines[1] == (f"stability record {broken[0]} (broken): {broken[0] / 'seed_0' / ROLLOUT_FILE}: not a readable rollout sample "
                        "(not an .npz archive); no rollout video or 3D view for it")
    assert [i.video.suffix for i in items] == [".webp", ".webp"] and items[1].view3d is None  # the cdg rollout, the NVS frames
    # asked for by name: the renderer-only NVS run has no rollouts to view in 3D; an unknown name is said too
    lines.clear()
    items, _ = build_watch(_groups(good, nvs), tmp_path / "out2", default_registry(), select=["GaMeS", str(good[0]), "nothing"], warn=lines.append, fmt="webp")
    assert len(items) == 2 and len(lines) == 2
    assert lines[0] == f"nvs record {nvs_dir} (GaMeS): no rollouts to view in 3D (the nvs task scores rendered or predicted frames); its frames are animated"
    assert lines[1] == "--watch nothing: no record of that label or folder under the runs folder"


def test_write_animation_refuses_bad_frames(tmp_path: Path) -> None:
    with pytest.raises(ClodsError, match="expected"):
        write_animation(np.zeros((3, 4, 4), np.uint8), tmp_path / "a", 10.0)
    frames = np.zeros((3, 5, 7, 3), np.uint8)
    frames[1] = 255
    path = write_animation(frames, tmp_path / "b", 10.0, fmt="webp")
    np.testing.assert_array_equal(read_animation(path), frames)  # lossless


def test_report_command_prints_one_warning_per_run_and_writes_the_rest(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from clods_bench.cli import main

    runs = tmp_path / "runs"
    write_record(runs, "stability", "good", tearing(), truth_frames())
    gone, _ = write_record(runs, "stability", "gone", truth_frames(), truth_frames())
    (gone / "seed_0" / ROLLOUT_FILE).unlink()
    out = tmp_path / "report"
    assert main(["report", "--runs", str(runs), "--out", str(out), "--bench", str(tmp_path / "no-bench")]) == 0
    err = " ".join(capsys.readouterr().err.split())  # rich wraps long lines
    assert err.count("warning:") == 1 and f"stability record {gone} (gone):" in err and "the rollout sample is missing" in err
    page = (out / "index.html").read_text()
    assert "Watch: 1 video, 1 3D view (1 run not watched)" in page and "<h2 id='stability-all_scenes-ci'>" in page
    assert len(list((out / "watch").glob("stability_*"))) == 2
    assert main(["report", "--runs", str(runs), "--out", str(tmp_path / "quiet"), "--bench", str(tmp_path / "no-bench"), "--no-watch"]) == 0
    assert "Watch" not in (tmp_path / "quiet" / "index.html").read_text() and not (tmp_path / "quiet" / "watch").exists()
