"""The report's "Watch" section: rollout videos and 3D views (CDG, stability), labelled frame animations (NVS, DVC).

Rows of one table (task, scene, preset) that show the same trajectory (same name, same true frames) are watched
together: a CDG or stability group gives one video (truth and every method side by side, coloured by edge strain,
divergence marked; `rollout_video`) and one 3D page (`rollout_view3d`); an NVS or DVC group gives one animation of
true above predicted frames (`film_video`). Each record contributes its first seed. A record without what it needs
(a run saved before these files existed, a deleted file, a renderer-only run asked for a 3D view) is one warning
line naming it, and the rest of the report is still written.
"""

from __future__ import annotations

import hashlib
import html
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from clods_bench.benchmark.outputs.film_video import write_film_video
from clods_bench.benchmark.outputs.films import FILM_SUFFIX, Film, load_film
from clods_bench.benchmark.outputs.rollout_samples import ROLLOUT_FILE, RolloutSample, load_rollout_sample
from clods_bench.benchmark.outputs.rollout_strain import STRAIN_MAX, face_strain, rollout_divergence, strain_model
from clods_bench.benchmark.outputs.rollout_video import Panel, write_rollout_video
from clods_bench.benchmark.outputs.rollout_view3d import write_view3d
from clods_bench.benchmark.running.records import load_seed_result
from clods_bench.errors import ClodsError

WATCH_DIR = "watch"
WATCH_ANCHOR = "watch"
TASK_ORDER = ("cdg", "nvs", "dvc", "dvc_multi", "stability")
"""The order of the Watch section: the paper's tables, then stability (as the report's sections)."""
ROLLOUT_TASKS = ("cdg", "stability")
FILM_TASKS = ("nvs", "dvc", "dvc_multi")
TABLE_NAMES = {"cdg": "Table 2 (CDG)", "nvs": "Table 3 (NVS)", "dvc": "Table 4 (DVC)", "dvc_multi": "DVC, several trajectories", "stability": "stability"}
PHASE_AFTER = {"cdg": "extrapolation", "stability": "past the stored frames"}

Records = dict[str, dict[tuple[str, str], list[tuple[Path, dict[str, Any]]]]]
"""task -> (scene, preset) -> [(record folder, record)], as the HTML report groups them."""


@dataclass
class WatchItem:
    """One entry of the Watch section: a video (MP4 or WebP), and for rollouts the 3D page, with their captions."""

    title: str
    video: Path
    caption: str
    view3d: Path | None = None
    jumps: list[tuple[str, int]] = field(default_factory=list)


def selected(rdir: Path, rec: dict[str, Any], select: Sequence[str] | None) -> bool:
    """Whether `--watch` names this record: by its label or its folder (None: every record is watched)."""
    if not select:
        return True
    return any(s == rec.get("label") or Path(s).resolve() == rdir.resolve() for s in select)


def first_seed_dir(rdir: Path, rec: dict[str, Any]) -> tuple[int, Path] | None:
    """(seed, folder) of the record's lowest finished seed that has a folder, or None."""
    for seed in sorted(int(s) for s in rec.get("seeds", [])):
        if (rdir / f"seed_{seed}").is_dir():
            return seed, rdir / f"seed_{seed}"
    return None


def _name(rdir: Path, rec: dict[str, Any]) -> str:
    return f"{rec['task']} record {rdir} ({rec.get('label')})"


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:8]


def _slug(*parts: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", "_".join(parts)).strip("_")


def build_watch(groups: Records, out_dir: Path, registry: Any, select: Sequence[str] | None = None, warn: Callable[[str], None] = print,
                fmt: str | None = None) -> tuple[list[WatchItem], list[str]]:  # fmt: skip
    """Write the videos and 3D pages of every watched record under `out_dir/watch`; returns (items, warnings)."""
    warnings: list[str] = []

    def note(line: str) -> None:
        warnings.append(line)
        warn(line)

    rollouts: dict[tuple, list[tuple[str, int, dict[str, Any] | None, RolloutSample]]] = {}
    films: dict[tuple, list[tuple[str, Film]]] = {}
    named = {(Path(s).resolve() if Path(s).exists() else s) for s in select or []}
    matched: set[Any] = set()
    for task in groups:
        for (scene, preset), items in sorted(groups[task].items()):
            for rdir, rec in items:
                if not selected(rdir, rec, select):
                    continue
                matched |= {rec.get("label"), rdir.resolve()}
                first = first_seed_dir(rdir, rec)
                if first is None:
                    note(f"{_name(rdir, rec)}: no seed folder, nothing to watch")
                    continue
                seed, sdir = first
                if task in ROLLOUT_TASKS:
                    try:
                        sample = load_rollout_sample(sdir / ROLLOUT_FILE)
                    except ClodsError as exc:
                        note(f"{_name(rdir, rec)}: {exc.message}; no rollout video or 3D view for it")
                        continue
                    truth_key = _digest(sample.truth) if sample.truth is not None else _digest(sample.cells, np.asarray(sample.num_frames))
                    key = (task, rec["scene"], preset, sample.trajectory, sample.num_frames, truth_key)
                    rollouts.setdefault(key, []).append((rec["label"], seed, load_seed_result(rdir, seed), sample))
                elif task in FILM_TASKS:
                    if select:
                        note(f"{_name(rdir, rec)}: no rollouts to view in 3D (the {task} task scores rendered or predicted frames); its frames are animated")
                    paths = sorted(sdir.glob(f"*{FILM_SUFFIX}"))
                    if not paths:
                        note(f"{_name(rdir, rec)}: no saved frames (*{FILM_SUFFIX}) in {sdir}; no animation for it")
                    for path in paths:
                        try:
                            film = load_film(path)
                        except ClodsError as exc:
                            note(f"{_name(rdir, rec)}: {exc.message}; no animation for it")
                            continue
                        key = (task, rec["scene"], preset, film.trajectory, tuple(film.views), tuple(film.frames), _digest(film.truth))
                        films.setdefault(key, []).append((rec["label"], film))
                elif select:
                    note(f"{_name(rdir, rec)}: the {task} task saves no rollouts or predicted frames to watch")
    for name in sorted(str(n) for n in named - matched):
        note(f"--watch {name}: no record of that label or folder under the runs folder")
    out = Path(out_dir) / WATCH_DIR
    views3d = plotly_available()
    if rollouts and not views3d:
        note("plotly is not installed (pip install plotly): rollout videos only, no 3D views")
    made = [(key, _rollout_item(key, rows, out, registry, fmt, views3d)) for key, rows in rollouts.items()]
    made += [(key, _film_item(key, rows, out, fmt)) for key, rows in films.items()]
    made.sort(key=lambda kv: (TASK_ORDER.index(kv[0][0]) if kv[0][0] in TASK_ORDER else len(TASK_ORDER), tuple(map(str, kv[0]))))
    return [item for _, item in made], warnings


def plotly_available() -> bool:
    """True when plotly (a base dependency) imports: the 3D views need it."""
    try:
        import plotly  # noqa: F401
    except ImportError:
        return False
    return True


def _rollout_item(key: tuple, rows: list[tuple[str, int, dict[str, Any] | None, RolloutSample]], out: Path, registry: Any,
                  fmt: str | None, view3d: bool = True) -> WatchItem:  # fmt: skip
    """The video and 3D page of one group of rollouts of the same trajectory."""
    task, scene_name, preset, trajectory, num_frames, digest = key
    try:
        scene = registry.get("scene", scene_name)
    except ClodsError:
        scene = None  # a scene whose plugin is not installed here: the flat rest shape of the mesh coordinates
    rows = sorted(rows, key=lambda r: r[0])
    panels: list[Panel] = []
    sources: set[str] = set()
    truth = next((s for *_, s in rows if s.truth is not None), None)
    obstacle: np.ndarray | None = None
    for label, seed, result, sample in rows:
        model = strain_model(sample, scene)
        sources.add(model.rest_source)
        obstacle = (model.face_edges < 0).any(axis=1) if obstacle is None else obstacle
        if not panels and truth is not None:
            panels.append(Panel("ground truth", truth.truth, face_strain(model, truth.truth)))
        panels.append(Panel(f"{label} (seed {seed})", sample.pred, face_strain(model, sample.pred), rollout_divergence(sample, model, task, result)))
    ref = rows[0][3]
    mark = (int(max(ref.marks)), PHASE_AFTER.get(task, "after the mark")) if ref.marks else None
    view = truth.truth if truth is not None else ref.pred[: _finite_prefix(ref.pred)]
    title = f"{TABLE_NAMES.get(task, task)} · {scene_name} · preset {preset} · {trajectory}"
    stem = out / _slug(task, scene_name, preset, trajectory, digest)
    video = write_rollout_video(stem, ref.cells, panels, title, mark, view, fmt=fmt)
    summary = (f"{title}: {', '.join(p.label for p in panels)}; {num_frames} frames; faces coloured by their largest edge strain "
               f"|l/l0 - 1| (0 to {STRAIN_MAX:g}+), rest shape: {'; '.join(sorted(sources))}.")  # fmt: skip
    diverged = " ".join(f"{p.label}: {p.divergence.caption()} ({p.divergence.source})." for p in panels if p.divergence)
    caption = summary + (" " + diverged if diverged else " No rollout diverged.")
    page = None
    if view3d:
        page, _ = write_view3d(stem.with_name(stem.name + "_3d.html"), ref.cells, panels, title, summary, mark, view, obstacle=obstacle)
    jumps = [(p.label, p.divergence.frame) for p in panels if p.divergence is not None]
    return WatchItem(title, video, caption, page, jumps)


def _finite_prefix(frames: np.ndarray) -> int:
    """Frames before the first non-finite one (at least 1)."""
    bad = ~np.isfinite(frames).all(axis=(1, 2))
    return max(1, int(np.argmax(bad)) if bad.any() else len(frames))


def _film_item(key: tuple, rows: list[tuple[str, Film]], out: Path, fmt: str | None) -> WatchItem:
    """The animation of one group of films of the same trajectory, views and frames."""
    task, scene, preset, trajectory, views, frames, digest = key
    rows = sorted(rows, key=lambda r: r[0])
    title = f"{TABLE_NAMES.get(task, task)} · {scene} · preset {preset} · {trajectory}"
    video = write_film_video(out / _slug(task, scene, preset, trajectory, digest), rows, title, fmt)
    caption = (f"{title}: ground truth above {', '.join(label for label, _ in rows)}, views {', '.join(map(str, views))}, "
               f"{len(frames)} frames ({frames[0]} to {frames[-1]})")  # fmt: skip
    return WatchItem(title, video, caption)


def watch_html(items: list[WatchItem], warnings: list[str], out_dir: Path, media_html: Callable[[Path, str], str]) -> str:
    """The Watch section of the report page: every video embedded with its caption and a link to its 3D view."""
    fmt = "MP4 (H.264, PyAV)" if any(i.video.suffix == ".mp4" for i in items) else "animated WebP (PyAV is not installed: pip install clods-bench[video] for MP4)"
    parts = [f"<h2 id='{WATCH_ANCHOR}'>Watch: rollouts and predicted frames</h2>"]
    if items:
        parts.append(f"<p class='caption'>Videos written as {html.escape(fmt)} under <code>{html.escape(WATCH_DIR)}/</code>. A 3D view "
                     "(play, pause, scrub, orbit, click a legend entry to hide a method) opens from its link, offline.</p>")  # fmt: skip
    parts.append("<ul>" + "".join(f"<li><a href='#watch-{k}'>{html.escape(i.title)}</a></li>" for k, i in enumerate(items)) + "</ul>")
    for k, item in enumerate(items):
        parts.append(f"<h3 id='watch-{k}'>{html.escape(item.title)}</h3>")
        parts.append(media_html(item.video, item.caption))
        if item.view3d is not None:
            rel = item.view3d.relative_to(out_dir).as_posix()
            jumps = "".join(f" · <a href='{html.escape(rel)}#frame={f}'>{html.escape(label)} at its divergence (frame {f})</a>" for label, f in item.jumps)
            parts.append(f"<p><a href='{html.escape(rel)}'>open the 3D view</a>{jumps}</p>")
    if warnings:
        parts.append("<p class='caption'>Not watched:</p><ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul>")
    if not items and not warnings:
        parts.append("<p class='caption'>No run saved rollouts or predicted frames.</p>")
    return "".join(parts)
