"""Interactive 3D view of rollouts: a static HTML page (plotly) to play, pause, scrub, orbit and toggle methods.

Why plotly: its `Mesh3d` draws a triangle mesh with one colour value per face (`intensitymode="cell"`: the edge
strain), animation `frames` with a slider and play/pause buttons give play, pause and scrub, the 3D scene orbits
with the mouse, and a click on a legend entry hides a method. The page needs no server: the figure is JSON inside
the page and plotly.js (`plotly.min.js`, written once beside the pages from the installed `plotly` package) is read
from the same folder, so it opens from `file://` with nothing fetched. viser and rerun were ruled out: both view
through a running server (rerun's web viewer needs its wasm served).

All methods stand in one scene side by side (truth first), offset along x by the truth's width, so one camera
orbits them together; each mesh keeps its own coordinates otherwise. A method's non-finite frames show its last
finite one, and vertices that fly off are clamped near its slot, so a blown-up rollout cannot hide the others.
The page's address may end in `#frame=K` to open at frame K (the report links each divergence frame so).
"""

from __future__ import annotations

import html
import json
import math
from pathlib import Path

import numpy as np

from clods_bench.atomic import write_text
from clods_bench.benchmark.outputs.rollout_strain import STRAIN_MAX
from clods_bench.benchmark.outputs.rollout_video import Panel, fitted_view, last_finite

PLOTLY_JS = "plotly.min.js"
MAX_PAGE_BYTES = 8 * 2**20
"""Frame data per page stays under about this: longer or finer rollouts are shown at every k-th frame."""
FIGURE_ID = "clods-figure"


def view_frame_indices(num_frames: int, bytes_per_frame: int, keep: list[int], budget: int = MAX_PAGE_BYTES) -> list[int]:
    """Frames the page animates: every k-th with k the smallest that fits `budget`, plus the last and the `keep`
    frames (divergence frames: the red label appears at the very frame)."""
    step = max(1, math.ceil(num_frames * bytes_per_frame / max(budget, 1)))
    return sorted({*range(0, num_frames, step), num_frames - 1, *(k for k in keep if 0 <= k < num_frames)})


def _slot_offsets(truth_like: np.ndarray, panels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(per-panel x offsets, scene box lo, hi) for panels in a row along x, one truth-width and a gap apart."""
    pts = np.asarray(truth_like, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(3), np.ones(3))
    ext = np.maximum(hi - lo, 1e-6)
    pitch = ext[0] + 0.3 * float(ext.max())
    offsets = np.array([k * pitch for k in range(panels)])
    pad = 0.15 * float(ext.max())
    box_lo = lo - pad
    box_hi = hi + pad + np.array([offsets[-1], 0.0, 0.25 * float(ext.max())])  # room above for the labels
    return offsets, box_lo, box_hi


def view3d_figure(cells: np.ndarray, panels: list[Panel], title: str, mark: tuple[int, str] | None = None, view: np.ndarray | None = None,
                  budget: int = MAX_PAGE_BYTES, fps: float = 10.0, obstacle: np.ndarray | None = None) -> tuple[dict, list[int]]:  # fmt: skip
    """(plotly figure as a dict, frames shown): one Mesh3d per panel coloured by face strain (`obstacle` (F,) bool faces
    grey, in a trace of their own), one text label above each, animation frames with a slider and play/pause buttons."""
    import plotly.graph_objects as go

    cells = np.asarray(cells, np.int64)
    cloth = np.ones(len(cells), bool) if obstacle is None else ~np.asarray(obstacle, bool)
    obstacle_faces, cloth_faces = cells[~cloth], cells[cloth]
    ref = panels[0].frames if view is None else view
    offsets, box_lo, box_hi = _slot_offsets(ref, len(panels))
    centre, radius = fitted_view(ref)
    num_frames = max(len(p.frames) for p in panels)
    per_frame = len(panels) * (panels[0].frames.shape[1] * 3 * 4 + len(cloth_faces) * 4) * 4 // 3 + 200 * len(panels)
    picks = view_frame_indices(num_frames, per_frame, [p.divergence.frame for p in panels if p.divergence is not None], budget)
    shown = [last_finite(p.frames) for p in panels]
    label_z = float(box_hi[2]) - 0.1 * (float(box_hi[2]) - float(box_lo[2]))
    label_x = [float(offsets[k] + (box_lo[0] + box_hi[0] - offsets[-1]) / 2.0) for k in range(len(panels))]
    label_y = float(centre[1])

    def verts(k: int, t: int) -> np.ndarray:
        s = shown[k][min(t, len(panels[k].frames) - 1)]
        x = np.clip(panels[k].frames[s], centre - 3.0 * radius, centre + 3.0 * radius)
        return (x + np.array([offsets[k], 0.0, 0.0])).astype(np.float32)

    def strain(k: int, t: int) -> np.ndarray:
        s = shown[k][min(t, len(panels[k].frames) - 1)]
        return np.nan_to_num(panels[k].strain[s][cloth], nan=0.0).astype(np.float32)

    def traces(t: int) -> list:
        out = []
        for k in range(len(panels)):
            x = verts(k, t)
            out.append(go.Mesh3d(x=x[:, 0], y=x[:, 1], z=x[:, 2], intensity=strain(k, t)))
            if len(obstacle_faces):
                out.append(go.Mesh3d(x=x[:, 0], y=x[:, 1], z=x[:, 2]))
        return out

    data = []
    for k, panel in enumerate(panels):
        x = verts(k, picks[0])
        data.append(go.Mesh3d(
            x=x[:, 0], y=x[:, 1], z=x[:, 2], i=cloth_faces[:, 0].astype(np.int32), j=cloth_faces[:, 1].astype(np.int32),
            k=cloth_faces[:, 2].astype(np.int32), intensity=strain(k, picks[0]), intensitymode="cell", colorscale="Viridis", cmin=0.0,
            cmax=STRAIN_MAX, showscale=k == 0, name=panel.label, legendgroup=panel.label, showlegend=True, flatshading=True,
            lighting={"ambient": 0.65, "diffuse": 0.4, "specular": 0.05}, hovertemplate=f"{html.escape(panel.label)}<br>strain %{{intensity:.3f}}<extra></extra>",
            colorbar={"title": {"text": "edge strain<br>|l/l0 - 1|"}, "tickvals": [STRAIN_MAX * i / 5 for i in range(6)],
                      "ticktext": [f"{STRAIN_MAX * i / 5:.1f}" + ("+" if i == 5 else "") for i in range(6)], "len": 0.5,
                      "y": 0.05, "yanchor": "bottom"},
        ))  # fmt: skip
        if len(obstacle_faces):
            data.append(go.Mesh3d(x=x[:, 0], y=x[:, 1], z=x[:, 2], i=obstacle_faces[:, 0].astype(np.int32), j=obstacle_faces[:, 1].astype(np.int32),
                                  k=obstacle_faces[:, 2].astype(np.int32), color="rgb(158,158,168)", legendgroup=panel.label, showlegend=False,
                                  name=f"{panel.label} (obstacle)", hoverinfo="skip"))  # fmt: skip
    moving = list(range(len(data)))  # the meshes; the labels after them stay put (plotly.js redraws animated 3D text smaller)
    for k, panel in enumerate(panels):
        data.append(go.Scatter3d(x=[label_x[k]], y=[label_y], z=[label_z], mode="text", text=[panel.label], textfont={"color": "#111111", "size": 14},
                                 legendgroup=panel.label, showlegend=False, hoverinfo="skip"))  # fmt: skip

    def heading(t: int) -> str:
        phase = f" ({mark[1]})" if mark is not None and t > mark[0] else ""
        gone = [f"{html.escape(p.label)} at frame {p.divergence.frame}" for p in panels if p.divergence is not None and t >= p.divergence.frame]
        red = f" <span style='color:#c81414'>diverged: {', '.join(gone)}</span>" if gone else ""
        return f"{html.escape(title)}<br><sub>frame {t} / {num_frames - 1}{phase}{red}</sub>"

    frames = [go.Frame(name=str(t), data=traces(t), traces=moving, layout={"title": {"text": heading(t)}}) for t in picks]
    step_args = {"frame": {"duration": 0, "redraw": True}, "mode": "immediate", "transition": {"duration": 0}}
    sliders = [{"active": 0, "currentvalue": {"prefix": "frame "}, "pad": {"t": 30}, "x": 0.12, "len": 0.88,
                "steps": [{"label": str(t), "method": "animate", "args": [[str(t)], step_args]} for t in picks]}]  # fmt: skip
    play = {"frame": {"duration": int(1000 / fps), "redraw": True}, "fromcurrent": True, "transition": {"duration": 0}, "mode": "immediate"}
    buttons = [{"label": "Play", "method": "animate", "args": [None, play]}, {"label": "Pause", "method": "animate", "args": [[None], step_args]}]
    span = np.maximum(box_hi - box_lo, 1e-9)
    ratio = span / span.max()
    axis = {"showbackground": False, "showgrid": True, "zeroline": False, "title": {"text": ""}}
    layout = {
        "template": "plotly_white", "title": {"text": heading(picks[0]), "x": 0.02},
        "scene": {"xaxis": {**axis, "range": [box_lo[0], box_hi[0]]}, "yaxis": {**axis, "range": [box_lo[1], box_hi[1]]},
                  "zaxis": {**axis, "range": [box_lo[2], box_hi[2]]}, "aspectmode": "manual",
                  "aspectratio": {"x": ratio[0], "y": ratio[1], "z": ratio[2]}, "camera": {"eye": {"x": 0.12, "y": -0.72, "z": 0.32}}},
        "uirevision": "keep", "legend": {"title": {"text": "click to hide / show"}, "x": 1.0, "y": 1.0, "yanchor": "top", "itemsizing": "constant"},
        "margin": {"l": 0, "r": 0, "t": 70, "b": 0},
        "updatemenus": [{"type": "buttons", "direction": "left", "x": 0.0, "y": 0.0, "xanchor": "left", "yanchor": "top", "pad": {"t": 40}, "buttons": buttons}],
        "sliders": sliders,
    }  # fmt: skip
    fig = go.Figure(data=data, layout=layout, frames=frames)
    return json.loads(fig.to_json()), picks


PAGE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{title}</title><script src="{js}"></script>
<style>body {{ font-family: system-ui, sans-serif; margin: 0.6em 1em; color: #222; }} #view {{ width: 100%; height: 82vh; }}
p {{ margin: 0.2em 0; font-size: 0.9em; color: #444; }} .div {{ color: #c81414; }}</style></head>
<body><p>{caption}</p><p>Play / Pause and the slider scrub the frames; drag to orbit, scroll to zoom; click a legend entry to hide or
show a method.{divergences}</p>
<div id="view"></div>
<script type="application/json" id="{fid}">{figure}</script>
<script>
const fig = JSON.parse(document.getElementById("{fid}").textContent);
const view = document.getElementById("view");
function jump() {{
  const m = location.hash.match(/frame=(\\d+)/);
  if (!m) return;
  const names = fig.frames.map(f => Number(f.name));
  const want = Number(m[1]);
  const best = names.reduce((a, b) => Math.abs(b - want) < Math.abs(a - want) ? b : a, names[0]);
  Plotly.animate(view, [String(best)], {{frame: {{duration: 0, redraw: true}}, mode: "immediate", transition: {{duration: 0}}}});
}}
Plotly.newPlot(view, fig.data, fig.layout, {{responsive: true, displaylogo: false}})
  .then(() => Plotly.addFrames(view, fig.frames)).then(() => {{ view.dataset.ready = "1"; jump(); }});
window.addEventListener("hashchange", jump);
</script></body></html>
"""


def write_view3d(path: Path, cells: np.ndarray, panels: list[Panel], title: str, caption: str, mark: tuple[int, str] | None = None,
                 view: np.ndarray | None = None, budget: int = MAX_PAGE_BYTES, obstacle: np.ndarray | None = None) -> tuple[Path, list[int]]:  # fmt: skip
    """Write the 3D view page at `path` (and plotly.min.js beside it when missing); returns (page, frames shown)."""
    from plotly.offline import get_plotlyjs

    figure, picks = view3d_figure(cells, panels, title, mark, view, budget, obstacle=obstacle)
    js, code = Path(path).parent / PLOTLY_JS, get_plotlyjs()
    if not js.is_file() or js.stat().st_size != len(code.encode()):  # once per folder, again when plotly changed
        write_text(js, code)
    links = [f" <a class='div' href='#frame={p.divergence.frame}'>{html.escape(p.label)}: {html.escape(p.divergence.caption())}</a>"
             for p in panels if p.divergence is not None]  # fmt: skip
    page = PAGE.format(title=html.escape(title), js=PLOTLY_JS, caption=html.escape(caption), fid=FIGURE_ID,
                       divergences=("<br>Jump to" + ";".join(links)) if links else "",
                       figure=json.dumps(figure, separators=(",", ":")).replace("</", "<\\/"))  # fmt: skip
    write_text(path, page)
    return Path(path), picks


def read_view3d_figure(path: Path) -> dict:
    """The figure (data, layout, frames) embedded in a 3D view page: what the page draws."""
    text = Path(path).read_text()
    start = text.index(f'id="{FIGURE_ID}">') + len(f'id="{FIGURE_ID}">')
    return json.loads(text[start : text.index("</script>", start)])
