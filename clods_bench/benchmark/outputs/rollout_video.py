"""Rollout videos: the ground truth and each method's rollout of one trajectory side by side, coloured by edge strain.

Every panel is drawn by the project's ground-truth mesh rasterizer (`datasets.rasterizer`, flat per-face colours,
one soft light) from one common camera fitted to the truth, so the panels compare directly. Faces take the
viridis colour of their most strained edge on a fixed scale (0 to `STRAIN_MAX`, drawn with its label under the
panels; grey: obstacles); viridis holds no red, which is kept for divergence: from a method's divergence frame on,
its frame counter turns red and names the frame and the reason. A non-finite frame shows the method's last
finite one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clods_bench.benchmark.outputs.animation_files import CONTROLS_PAD, label_font, write_animation
from clods_bench.benchmark.outputs.rollout_strain import STRAIN_MAX, Divergence
from clods_bench.datasets.cameras import Camera, intrinsics_from_fov, look_at

PANEL_W, PANEL_H = 320, 240
HEADER_H, FOOTER_H, TITLE_H, SCALE_H = 22, 36, 26, 44
MAX_VIDEO_FRAMES = 400
"""Longer rollouts are shown at every k-th frame (the counter keeps the true frame numbers)."""
DIVERGED_RGB = (200, 20, 20)
OBSTACLE_RGB = (0.62, 0.62, 0.66)
FOV_DEG = 35.0
AZIMUTH_DEG, ELEVATION_DEG = -60.0, 20.0  # as the report's still mesh pictures


@dataclass(frozen=True)
class Panel:
    """One column of the video: a label, frames (T,V,3) (NaN allowed), per-face strain (T,F), a divergence or None."""

    label: str
    frames: np.ndarray
    strain: np.ndarray
    divergence: Divergence | None = None


def fitted_view(points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre, radius) of the finite points' bounding box: what the common camera frames."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return np.zeros(3), 1.0
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    return (lo + hi) / 2.0, max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)


def watch_camera(centre: np.ndarray, radius: float, width: int = PANEL_W, height: int = PANEL_H) -> Camera:
    """A camera at azimuth -60 deg, elevation 20 deg (z up) whose view holds the sphere (centre, radius)."""
    az, el = math.radians(AZIMUTH_DEG), math.radians(ELEVATION_DEG)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    half = math.radians(FOV_DEG) / 2.0 * min(1.0, height / width)
    distance = radius / math.sin(half) * 1.05
    R, t = look_at(np.asarray(centre) + distance * direction, np.asarray(centre))
    return Camera(intrinsics_from_fov(FOV_DEG, width, height), R, t, width, height)


def strain_colours(strain: np.ndarray) -> np.ndarray:
    """(F,3) colours in [0, 1]: viridis of strain / STRAIN_MAX (clipped), OBSTACLE_RGB where NaN."""
    import matplotlib

    s = np.asarray(strain, np.float64)
    rgb = matplotlib.colormaps["viridis"](np.clip(np.nan_to_num(s, nan=0.0) / STRAIN_MAX, 0.0, 1.0))[:, :3]
    rgb[~np.isfinite(s)] = OBSTACLE_RGB
    return rgb


def last_finite(frames: np.ndarray) -> np.ndarray:
    """(T,) index of the frame shown at each t: t itself when finite, else the last finite frame before it (0 if none)."""
    finite = np.isfinite(np.asarray(frames)).all(axis=(1, 2))
    shown = np.zeros(len(finite), np.int64)
    last = 0
    for t, ok in enumerate(finite):
        last = t if ok else last
        shown[t] = last
    return shown


def render_panel(cells: np.ndarray, verts: np.ndarray, strain: np.ndarray, camera: Camera, centre: np.ndarray, radius: float) -> np.ndarray:
    """(H,W,3) float32 image of one mesh frame, faces coloured by strain, lit softly from the camera's side."""
    from clods_bench.datasets.rasterizer import DirectionalLight, RasterSettings, render

    x = np.clip(np.asarray(verts, np.float64), centre - 50.0 * radius, centre + 50.0 * radius)  # a blown-up mesh stays drawable
    forward = np.asarray(camera.R)[2]
    light = DirectionalLight(tuple(forward + np.array([0.0, 0.0, -0.6])), ambient=0.62, diffuse=0.38)
    uv, texture = np.zeros((len(x), 2)), np.ones((1, 1, 3), np.float32)
    return render(x, cells, uv, texture, camera, RasterSettings(supersample=2, light=light), face_colors=strain_colours(strain))


def video_frame_indices(num_frames: int) -> list[int]:
    """The rollout frames the video shows: all of them up to MAX_VIDEO_FRAMES, else every k-th (the last kept)."""
    step = max(1, math.ceil(num_frames / MAX_VIDEO_FRAMES))
    picks = list(range(0, num_frames, step))
    return picks if picks[-1] == num_frames - 1 else [*picks, num_frames - 1]


def grid_shape(panels: int) -> tuple[int, int]:
    """(rows, columns): one row up to four panels, else two or more rows of at most four."""
    cols = panels if panels <= 4 else min(4, math.ceil(panels / math.ceil(panels / 4)))
    return math.ceil(panels / cols), cols


def rollout_video_frames(cells: np.ndarray, panels: list[Panel], title: str, mark: tuple[int, str] | None = None,
                         view: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """(F,H,W,3) uint8 video frames: a title, the panels in a grid (label above, frame counter below), the strain scale.
    Frames after `mark` = (frame, phase name) say the phase; the camera frames `view` (points; default the first
    panel's frames: the truth's)."""
    from PIL import Image, ImageDraw

    centre, radius = fitted_view(panels[0].frames if view is None else view)
    camera = watch_camera(centre, radius)
    rows, cols = grid_shape(len(panels))
    cell_h = HEADER_H + PANEL_H + FOOTER_H
    width, height = cols * PANEL_W, TITLE_H + rows * cell_h + SCALE_H + CONTROLS_PAD
    num_frames = max(len(p.frames) for p in panels)
    shown = [last_finite(p.frames) for p in panels]
    base = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(base)
    draw.text((8, 5), title, fill=(20, 20, 20), font=label_font(14))
    _draw_scale(draw, width, height - SCALE_H - CONTROLS_PAD)
    for k, panel in enumerate(panels):
        x0, y0 = (k % cols) * PANEL_W, TITLE_H + (k // cols) * cell_h
        draw.rectangle([x0, y0, x0 + PANEL_W - 1, y0 + HEADER_H - 1], fill=(235, 235, 240))
        draw.text((x0 + 6, y0 + 4), panel.label, fill=(0, 0, 0), font=label_font(13))
    out = []
    for t in video_frame_indices(num_frames):
        frame = base.copy()
        draw = ImageDraw.Draw(frame)
        for k, panel in enumerate(panels):
            x0, y0 = (k % cols) * PANEL_W, TITLE_H + (k // cols) * cell_h
            s = shown[k][min(t, len(panel.frames) - 1)]
            img = render_panel(cells, panel.frames[s], panel.strain[s], camera, centre, radius)
            frame.paste(Image.fromarray(np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)), (x0, y0 + HEADER_H))
            _draw_counter(draw, x0, y0 + HEADER_H + PANEL_H, t, num_frames, panel.divergence, s != t, mark)
        out.append(np.asarray(frame))
    return np.stack(out)


def _draw_counter(draw, x0: int, y0: int, t: int, num_frames: int, div: Divergence | None, held: bool, mark: tuple[int, str] | None) -> None:  # noqa: ANN001
    """The footer under a panel: 'frame t / T-1' on grey, on red with the reason from the divergence frame on."""
    diverged = div is not None and t >= div.frame
    draw.rectangle([x0, y0, x0 + PANEL_W - 1, y0 + FOOTER_H - 1], fill=DIVERGED_RGB if diverged else (60, 60, 66))
    phase = f" ({mark[1]})" if mark is not None and t > mark[0] else ""
    line = f"frame {t} / {num_frames - 1}{phase}" + (f"  diverged at frame {div.frame}" if diverged else "")  # type: ignore[union-attr]
    draw.text((x0 + 6, y0 + 2), line, fill=(255, 255, 255), font=label_font(13))
    if diverged or held:
        reason = (div.reason if diverged else "") + ("; last finite frame shown" if held else "")  # type: ignore[union-attr]
        draw.text((x0 + 6, y0 + 19), reason if len(reason) <= 54 else reason[:51] + "...", fill=(255, 255, 255), font=label_font(11))


def _draw_scale(draw, width: int, y0: int) -> None:  # noqa: ANN001
    """The fixed strain colour scale, 0 to STRAIN_MAX, with ticks and its label."""
    import matplotlib

    x0, x1, bar_h = 40, min(width - 40, 440), 12
    cmap = matplotlib.colormaps["viridis"]
    for x in range(x0, x1):
        r, g, b, _ = cmap((x - x0) / max(x1 - x0 - 1, 1))
        draw.line([(x, y0 + 6), (x, y0 + 6 + bar_h)], fill=(int(r * 255), int(g * 255), int(b * 255)))
    for k in range(6):
        value = STRAIN_MAX * k / 5
        x = x0 + (x1 - x0 - 1) * k / 5
        draw.line([(x, y0 + 6 + bar_h), (x, y0 + 9 + bar_h)], fill=(0, 0, 0))
        draw.text((x - 8, y0 + 10 + bar_h), f"{value:.1f}" + ("+" if k == 5 else ""), fill=(0, 0, 0), font=label_font(10))
    draw.text((x1 + 10, y0 + 4), "edge strain |l/l0 - 1| (grey: obstacle)", fill=(0, 0, 0), font=label_font(11))


def write_rollout_video(stem: Path, cells: np.ndarray, panels: list[Panel], title: str, mark: tuple[int, str] | None = None,
                        view: np.ndarray | None = None, fps: float = 10.0, fmt: str | None = None) -> Path:  # fmt: skip
    """Write the panels' video to `stem`.mp4 (PyAV) or .webp (Pillow); returns the path written."""
    return write_animation(rollout_video_frames(cells, panels, title, mark, view), stem, fps, fmt)
