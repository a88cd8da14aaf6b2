"""The pictures of the results pages: committed PNG files, and figures drawn from committed data when the site is built.

Each entry of `plots` in `docs/results_sources.yaml` is a committed picture (`file`), a figure drawn from committed
data (`draw` + `from`), or both: then `python -m clods_bench.docsgen redraw` rewrites the committed file with the same
drawing, so the repository's copy and the site's agree. Kinds of drawing:

- `error_vs_time`: a `report` points CSV (`error_vs_time_*_points.csv`) or a committed error-vs-time table CSV;
- `training_curves`: a `training_curves_*.csv` of `report`;
- `video_grids`: the DVC task's unlabelled `dvc_grid.png` of several rows (`from` maps row label to file), drawn as
  one figure with the methods beside the rows and the frames above the columns (`frames`, `views`).
No experiment is run: every drawing reads only files under `results/`.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from clods_bench.benchmark.outputs.table_sources import field, where
from clods_bench.errors import ClodsError

KINDS = ("error_vs_time", "training_curves", "video_grids")


@dataclass(frozen=True)
class Plot:
    """A picture of the site: its title, caption, command, site path, the table page it belongs to (or None), and
    either the committed file it copies or how it is drawn."""

    title: str
    caption: str
    made_by: str
    site: str
    table: str | None
    file: Path | None
    draw: Callable[[Path], Path] | None
    inputs: tuple[Path, ...]


def _points_from_table(csv_path: Path, metric: str) -> Any:
    """report_points' frame from a committed error-vs-time table CSV (its metric's mean/std and the two times)."""
    import pandas as pd

    from clods_bench.benchmark.outputs.report import TIME_AXES, pareto_front

    table = pd.read_csv(csv_path)
    first = table.columns[0]
    need = [f"{metric}/mean", f"{metric}/std", *(k for k, _ in TIME_AXES)]
    missing = [c for c in need if c not in table.columns]
    if missing:
        raise ClodsError(f"no column {', '.join(missing)}", where=str(csv_path), hint="an error-vs-time table or report points CSV")
    frame = pd.DataFrame({"label": table[first], "metric": metric, "rmse": table[f"{metric}/mean"], "rmse_std": table[f"{metric}/std"]})
    for key, _ in TIME_AXES:
        frame[key] = table[key]
        frame[f"pareto_{key}"] = pareto_front(frame["rmse"].to_numpy(), frame[key].to_numpy())
    return frame


def draw_error_vs_time(source: Path, title: str) -> Callable[[Path], Path]:
    """Error against inference and training time from a points CSV (`report`'s) or an error-vs-time table CSV."""

    def draw(out: Path) -> Path:
        import pandas as pd

        from clods_bench.benchmark.outputs.report import HEADLINE, plot_error_vs_time

        head = pd.read_csv(source, nrows=0).columns
        points = pd.read_csv(source) if "rmse" in head else _points_from_table(source, HEADLINE)
        plot_error_vs_time(points, title, out)
        return out

    return draw


def draw_training_curves(source: Path, title: str, strain_threshold: float = 0.5) -> Callable[[Path], Path]:
    """The training curves figure from `report`'s training_curves CSV."""

    def draw(out: Path) -> Path:
        import numpy as np
        import pandas as pd

        from clods_bench.benchmark.outputs.training_curves import plot_training_curves

        frame = pd.read_csv(source).replace([np.inf, -np.inf], np.nan)
        plot_training_curves(frame, strain_threshold, title, out)
        return out

    return draw


def draw_video_grids(grids: dict[str, Path], frames: list[int], views: int, title: str) -> Callable[[Path], Path]:
    """The labelled figure of several rows' DVC grids."""

    def draw(out: Path) -> Path:
        from clods_bench.benchmark.outputs.grid_figure import labelled_grids

        return labelled_grids(grids, frames, views, title, out)

    return draw


def _site_name(rel: str) -> str:
    return "plots/" + rel.removeprefix("results/").replace("/", "_")


def plot_entry(root: Path, path: Path, p: dict[str, Any]) -> Plot:
    """One `plots` entry, checked: its files exist, its kind is known, a drawn figure without a committed file has a `name`."""
    title, caption, made_by = field(p, "title", path), field(p, "caption", path), field(p, "made_by", path)
    rel = p.get("file")
    file = root / rel if rel else None
    if file is not None and not file.is_file():
        raise ClodsError(f"picture {rel} is missing", where=where(path, p))
    kind = p.get("draw")
    draw, inputs = None, ()
    if kind is not None:
        if kind not in KINDS:
            raise ClodsError(f"unknown drawing '{kind}'; known: {', '.join(KINDS)}", where=where(path, p))
        if kind == "video_grids":
            grids = {str(k): root / v for k, v in field(p, "from", path, dict).items() if k != "__line__"}
            frames = [int(f) for f in field(p, "frames", path, list)]
            draw = draw_video_grids(grids, frames, int(field(p, "views", path, int)), title)
            inputs = tuple(grids.values())
        else:
            source = root / field(p, "from", path)
            draw = (draw_error_vs_time if kind == "error_vs_time" else draw_training_curves)(source, p.get("figure_title", title))
            inputs = (source,)
        for f in inputs:
            if not f.is_file():
                raise ClodsError(f"file {f.relative_to(root)} of the drawing is missing", where=where(path, p))
    elif file is None:
        raise ClodsError("an entry needs `file` (a committed picture), `draw` (a figure drawn from `from`) or both", where=where(path, p))
    site = _site_name(rel) if rel else f"plots/{field(p, 'name', path)}.png"
    return Plot(title, caption, made_by, site, p.get("table"), file, draw, inputs)


def rendered(plot: Plot) -> bytes:
    """The PNG bytes the site shows: a fresh drawing, or the committed file."""
    if plot.draw is None:
        assert plot.file is not None
        return plot.file.read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        return plot.draw(Path(tmp) / "figure.png").read_bytes()


def redraw(plots: list[Plot]) -> list[Path]:
    """Rewrite every committed picture that is drawn from committed data (atomically); returns the files written."""
    return [plot.draw(plot.file) for plot in plots if plot.draw is not None and plot.file is not None]
