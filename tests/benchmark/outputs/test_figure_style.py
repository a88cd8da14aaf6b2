"""Report figures are drawn for a web page: legible text, plain tick labels that never overlap, axis titles in words."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import pandas as pd
import pytest

from clods_bench.benchmark.outputs.figure_style import DPI, FONT_PT, WIDTH_IN, log_ticks, metric_words, plain_number, pyplot
from clods_bench.benchmark.outputs.report import plot_error_vs_time


def test_metric_keys_read_as_words() -> None:
    assert metric_words("unviewed/extrap/d_avg") == "Rollout RMSE (m), unviewed trajectories, extrapolation, average"
    assert metric_words("viewed/interp/d_end") == "Rollout RMSE (m), viewed trajectories, interpolation, last frame"
    assert metric_words("max_strain") == "Largest edge strain |l/l0 - 1|"
    assert metric_words("psnr") == "psnr"  # an unknown key stays as it is


@pytest.mark.parametrize(("value", "text"), [(0.1, "0.1"), (0.05, "0.05"), (2.0, "2"), (20.0, "20"), (1000.0, "1,000"), (2e7, "2e+07")])
def test_tick_numbers_are_plain(value: float, text: str) -> None:
    assert plain_number(value) == text


def _labels(lo: float, hi: float) -> list[str]:
    plt = pyplot()
    fig, ax = plt.subplots()
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    log_ticks(ax.xaxis, lo, hi)
    fig.canvas.draw()
    inside = lambda ticks: [t.get_text() for t in ticks if lo <= t.get_position()[0] <= hi and t.get_text()]  # noqa: E731
    major, minor = inside(ax.get_xticklabels()), inside(ax.xaxis.get_minorticklabels())
    plt.close(fig)
    assert minor == []  # never the `3×10⁰4×10⁰` of labelled minor ticks
    return major


def test_log_axes_carry_plain_labels_on_few_ticks() -> None:
    assert _labels(2.6, 33.0) == ["5", "10", "20"]  # within a decade or two: 1-2-5
    assert _labels(0.1, 4000.0) == ["0.1", "1", "10", "100", "1,000"]  # beyond: decades


def test_the_error_against_time_figure_is_drawn_for_a_page(tmp_path: Path) -> None:
    points = pd.DataFrame({"label": ["A", "B", "C"], "metric": "unviewed/extrap/d_avg", "rmse": [0.09, 0.12, 0.15], "rmse_std": 0.0,
                           "infer_ms_per_step": [2.6, 10.0, 33.0], "fit_seconds": [0.1, 100.0, 4000.0],
                           "pareto_infer_ms_per_step": [True, False, False], "pareto_fit_seconds": [True, False, False]})  # fmt: skip
    plot_error_vs_time(points, "Error against run time", tmp_path / "e.png")
    height, width = iio.imread(tmp_path / "e.png").shape[:2]
    assert 0.9 * WIDTH_IN * DPI <= width <= 1.05 * WIDTH_IN * DPI and height < width
    # shown 700 px wide (a page's column), FONT_PT-point text is at least 10.5 px high
    assert FONT_PT * DPI / 72 * 700 / width >= 10.5


def test_figures_are_drawn_with_the_report_style_only_inside_it() -> None:
    plt = pyplot()
    before = plt.rcParams["font.size"]
    from clods_bench.benchmark.outputs.figure_style import page_style

    with page_style():
        assert plt.rcParams["font.size"] == FONT_PT
    assert plt.rcParams["font.size"] == before
