"""Mesh pictures (the paper's prediction figure): ground truth beside extracted or predicted cloth, per-node error as colour.

Tasks save one sample trajectory per seed as `*_meshes.npz` (cells, the true frames when known, and one or more
named mesh sequences over the same frames); the HTML report draws each into a PNG grid: one row per chosen frame,
one column per sequence, faces coloured by the mean of their nodes' distance to the truth.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from clods_bench.atomic import atomic_path, write_npz
from clods_bench.errors import ClodsError

__all__ = ["MESH_SUFFIX", "choose_frames", "face_errors", "load_mesh_sample", "node_errors", "plot_mesh_sample", "save_mesh_sample"]

MESH_SUFFIX = "_meshes.npz"
"""Seed-directory files ending so are mesh samples the report draws."""
_PREFIX = "mesh__"
INFO_PREFIX = "info__"
"""Prefix of a sample's `extra` arrays (`save_mesh_sample(extra=...)`)."""


def node_errors(truth: np.ndarray, meshes: np.ndarray) -> np.ndarray:
    """(T, V) Euclidean distance of every node to its true position (NaN where a prediction is not finite)."""
    d = np.linalg.norm(np.asarray(meshes, np.float64) - np.asarray(truth, np.float64), axis=-1)
    return np.where(np.isfinite(d), d, np.nan)


def face_errors(cells: np.ndarray, node_err: np.ndarray) -> np.ndarray:
    """(..., F) mean of each triangle's three node errors: the colour of a face."""
    return np.asarray(node_err)[..., np.asarray(cells)].mean(axis=-1)


def choose_frames(num_frames: int, marks: Sequence[int] = ()) -> list[int]:
    """Up to four frames to show: 1, the `marks` (e.g. the end of interpolation) and the last, sorted, in range."""
    last = num_frames - 1
    picks = sorted({min(1, last), last, *(int(m) for m in marks if 0 <= int(m) <= last)})
    return picks if len(picks) <= 4 else [*picks[:3], last]


def save_mesh_sample(path: Path, cells: np.ndarray, meshes: Mapping[str, np.ndarray], truth: np.ndarray | None = None,
                     marks: Sequence[int] = (), title: str = "", extra: Mapping[str, np.ndarray] | None = None) -> Path:  # fmt: skip
    """Write one sample (atomically): `meshes` maps a column name to (T, V, 3) frames over the same frames as `truth`;
    `extra` arrays are stored beside them as `info__<name>` (what a reader needs more, e.g. a rollout's topology)."""
    if not meshes:
        raise ClodsError("no mesh sequence to save", where=str(path))
    shapes = {name: np.shape(m) for name, m in meshes.items()}
    first = next(iter(shapes.values()))
    if truth is not None:
        first = np.shape(truth)
    for name, shape in shapes.items():
        if len(shape) != 3 or shape[2] != 3 or shape[1:] != tuple(first[1:]) or shape[0] > first[0]:
            raise ClodsError(f"mesh sequence '{name}' has shape {shape}, expected (T<={first[0]}, {first[1]}, 3)", where=str(path))
    arrays = {f"{_PREFIX}{name}": np.asarray(m, np.float32) for name, m in meshes.items()}
    if truth is not None:
        arrays["truth"] = np.asarray(truth, np.float32)
    arrays.update({f"{INFO_PREFIX}{name}": np.asarray(value) for name, value in (extra or {}).items()})
    write_npz(path, cells=np.asarray(cells, np.int32), marks=np.asarray(list(marks), np.int64), title=np.asarray(title), **arrays)
    return path


def load_mesh_sample(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray | None, list[int], str]:
    """(cells, named sequences, truth or None, marks, title) of a sample written by `save_mesh_sample`."""
    with np.load(path) as z:
        meshes = {k[len(_PREFIX) :]: z[k] for k in z.files if k.startswith(_PREFIX)}
        truth = z["truth"] if "truth" in z.files else None
        return z["cells"], meshes, truth, [int(m) for m in z["marks"]], str(z["title"])


def plot_mesh_sample(sample: Path, path: Path, frames: Sequence[int] | None = None) -> Path:
    """PNG grid of a mesh sample: rows are frames, columns the truth (grey) then each sequence coloured by its
    per-face error (one colour scale for the whole picture, in metres); without truth, sequences are grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import cm, colors

    cells, meshes, truth, marks, title = load_mesh_sample(sample)
    length = min([len(m) for m in meshes.values()] + ([len(truth)] if truth is not None else []))
    frames = list(frames) if frames is not None else choose_frames(length, marks)
    columns = ([("ground truth", truth)] if truth is not None else []) + list(meshes.items())
    errors = {n: face_errors(cells, node_errors(truth[:length], m[:length])) for n, m in meshes.items()} if truth is not None else {}
    finite = np.concatenate([e[frames].ravel() for e in errors.values()]) if errors else np.zeros(0)
    finite = finite[np.isfinite(finite)]
    norm = colors.Normalize(0.0, float(np.percentile(finite, 99)) if finite.size else 1.0)
    cmap = matplotlib.colormaps["viridis"]
    ref = truth if truth is not None else next(iter(meshes.values()))
    pts = np.asarray(ref[:length], np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, half = (lo + hi) / 2.0, max(float((hi - lo).max()) / 2.0, 1e-6) * 1.1

    fig = plt.figure(figsize=(2.6 * len(columns) + 0.8, 2.5 * len(frames)))
    for r, t in enumerate(frames):
        for c, (name, seq) in enumerate(columns):
            ax = fig.add_subplot(len(frames), len(columns), r * len(columns) + c + 1, projection="3d")
            x = np.asarray(seq[t], np.float64)
            if np.isfinite(x).all():
                face = errors[name][t] if name in errors else None
                surf = ax.plot_trisurf(x[:, 0], x[:, 1], x[:, 2], triangles=cells, linewidth=0.1, edgecolor=(0, 0, 0, 0.15), antialiased=True)
                surf.set_facecolor(cmap(norm(np.nan_to_num(face, nan=norm.vmax))) if face is not None else (0.75, 0.75, 0.78, 1.0))
            else:
                ax.text2D(0.5, 0.5, "not finite", ha="center", transform=ax.transAxes)
            for set_lim, k in ((ax.set_xlim, 0), (ax.set_ylim, 1), (ax.set_zlim, 2)):
                set_lim(centre[k] - half, centre[k] + half)
            ax.set_box_aspect((1, 1, 1))
            ax.view_init(elev=20, azim=-60)
            ax.set_xticks([]), ax.set_yticks([]), ax.set_zticks([])
            if r == 0:
                ax.set_title(name, fontsize=9)
            if c == 0:
                ax.text2D(-0.05, 0.5, f"t={t}", rotation=90, va="center", transform=ax.transAxes, fontsize=9)
    if errors:
        fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=fig.axes, shrink=0.6, label="node error (m)")
    if title:
        import textwrap

        width = fig.get_size_inches()[0]
        fig.suptitle(textwrap.fill(title, max(20, int(width * 13))), fontsize=10)  # ~13 characters per inch at 10 pt: one column fits
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)
    return path
