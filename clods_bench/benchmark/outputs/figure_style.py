"""How the report's figures look: sized for a web page, text legible at display size, ticks that never overlap.

A figure is drawn `WIDTH_IN` inches wide at `DPI`; a page shows it about 1000 px wide (the results pages) or 700 px
(the others), so `FONT_PT` points of text come out at 11-16 px. Log axes carry plain numbers (`0.1`, `20`, `1,000`)
on 1-2-5 ticks when they span few decades and on decades otherwise, never matplotlib's `3×10⁰4×10⁰` minor labels.
Metric keys (`unviewed/extrap/d_avg`) are written out in words for axis titles.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from typing import Any, Iterator

from clods_bench.atomic import atomic_path

WIDTH_IN = 10.0
"""Width of a figure in inches (a row of panels shares it)."""
DPI = 150
"""Dots per inch of the PNG files: a 10-inch figure is 1500 px, sharp when a page shrinks it and when zoomed."""
FONT_PT = 11.0
"""Base font size: about 11 px on a 700-px page column, 15 px on a 1000-px one."""

_GROUPS = {"viewed": "viewed trajectories", "unviewed": "unviewed trajectories"}
_PARTS = {"interp": "interpolation", "extrap": "extrapolation"}
_STATS = {"d_avg": "average", "d_end": "last frame", "avg": "mean of average and last frame"}
_PLAIN = {"max_strain": "largest edge strain |l/l0 - 1|", "rmse": "rollout RMSE (m)"}


def metric_words(key: str) -> str:
    """`unviewed/extrap/d_avg` -> 'Rollout RMSE (m), unviewed trajectories, extrapolation, average'; an unknown key as is."""
    if key in _PLAIN:
        return _PLAIN[key][0].upper() + _PLAIN[key][1:]
    parts = key.split("/")
    if len(parts) == 3 and parts[0] in _GROUPS and parts[1] in _PARTS and parts[2] in _STATS:
        return f"Rollout RMSE (m), {_GROUPS[parts[0]]}, {_PARTS[parts[1]]}, {_STATS[parts[2]]}"
    return key


def plain_number(value: float) -> str:
    """A tick label without exponents: 0.001, 0.05, 2, 20, 1,000 (scientific only beyond 1e6 or below 1e-4)."""
    if value == 0 or not math.isfinite(value):
        return "0" if value == 0 else str(value)
    if abs(value) >= 1e6 or abs(value) < 1e-4:
        return f"{value:.0e}"
    if abs(value) >= 1000:
        return f"{value:,.0f}"
    return f"{value:g}"


def log_ticks(axis: Any, lo: float, hi: float) -> None:
    """Plain-number major ticks on a log `axis` whose data span [lo, hi]: 1-2-5 within 2.5 decades, decades beyond;
    minor ticks unlabelled."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    decades = math.log10(hi / lo) if lo > 0 and hi > 0 and math.isfinite(hi / lo) else 10.0
    subs = (1.0, 2.0, 5.0) if decades <= 2.5 else (1.0,)
    axis.set_major_locator(LogLocator(base=10.0, subs=subs))
    axis.set_major_formatter(FuncFormatter(lambda v, _pos: plain_number(v)))
    axis.set_minor_formatter(NullFormatter())


def value_axis(ax: Any, which: str, values: Any) -> None:
    """Log scale with plain ticks on `which` ('x' or 'y') when the positive `values` span more than a decade, else a
    linear axis with plain ticks: RMSEs between 0.09 and 0.15 read as 0.10, 0.12, 0.14, not 1.2×10⁻¹."""
    import numpy as np
    from matplotlib.ticker import FuncFormatter

    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    axis = ax.xaxis if which == "x" else ax.yaxis
    if len(v) and (v > 0).all() and v.max() / v.min() > 10.0:
        (ax.set_xscale if which == "x" else ax.set_yscale)("log")
        log_ticks(axis, float(v.min()), float(v.max()))
    else:
        axis.set_major_formatter(FuncFormatter(lambda x, _pos: plain_number(round(x, 10))))


def pyplot() -> Any:
    """matplotlib.pyplot on the file-only Agg backend (no display is needed to draw a report)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


@contextmanager
def page_style() -> Iterator[None]:
    """Matplotlib settings of every report figure (font sizes, line widths), undone on exit."""
    plt = pyplot()

    params = {
        "font.size": FONT_PT, "axes.titlesize": FONT_PT + 1, "axes.labelsize": FONT_PT, "xtick.labelsize": FONT_PT - 1,
        "ytick.labelsize": FONT_PT - 1, "legend.fontsize": FONT_PT - 1, "figure.titlesize": FONT_PT + 2,
        "lines.linewidth": 1.8, "lines.markersize": 5, "savefig.dpi": DPI,
    }  # fmt: skip
    with plt.rc_context(params):
        yield


def save_png(fig: Any, path: Any) -> None:
    """Write `fig` as PNG at `DPI` (atomically: a reader never sees half a file)."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI, bbox_inches="tight")
