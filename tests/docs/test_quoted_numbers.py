"""Every time or cost the user pages quote is tied to the file it comes from: the page says it, the file says the same.

A quote is a piece of a page's text (with its CPU or GPU and date) and either a piece of text the source file holds
verbatim, or a function that reads the number from the source (a CSV cell, a column of a benchmark's printed
table) and returns it as the page writes it. A number that changes in its source, or a page edited away from its
source, fails here naming both.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pytest

from tests.docs.pages import ROOT

CHANGELOG = "CHANGELOG.md"
VIDEO_CPU = "results/small-partial/bench_video_small.txt"
VIDEO_GPU = "results/gpu_h200/2026-11-27-paper-trajectory-and-video-bench/call2_resume/bench_video_small_cuda.txt"
SMALL_CDG = "results/small-partial/cdg_flag_small.csv"


@dataclass(frozen=True)
class Quote:
    """`text` on `page`; `source` holds `found` verbatim, or `found(source path)` is the number as `text` writes it."""

    page: str
    text: str
    source: str
    found: str | Callable[[Path], str]


def fit_seconds(row: str) -> Callable[[Path], str]:
    """A row's training seconds in a committed table CSV, rounded as the pages quote them."""

    def read(path: Path) -> str:
        with path.open(newline="") as fh:
            return f"{float(next(r for r in csv.DictReader(fh) if r['method'] == row)['fit_seconds']):.0f} s"

    return read


def step_range(path: Path) -> str:
    """'lo-hi' of the seconds per training step column of a `bench video` table (the first number column)."""
    values = []
    for line in path.read_text().splitlines():
        cells = [c.strip() for c in line.split("│")[1:-1]]
        if len(cells) > 1 and cells[1]:
            try:
                values.append(float(cells[1]))
            except ValueError:
                continue
    lo, hi = min(values), max(values)
    return f"{lo:g}-{hi:g} s"


QUOTES = [
    # README: the cost of the ci plan, small and paper, and of deterministic mode
    Quote("README.md", "took 1188 s with `--jobs 2` on a 2-core AMD EPYC", CHANGELOG, "--first-seeds 1 --check results/ci`, 1188 s)"),
    Quote("README.md", "and 1485 s on a 2-core Intel Xeon (Sapphire Rapids), 2026-11-29", CHANGELOG, "inside `.ci/run` from a fresh clone | the same host model, later that day (the test suite took 367 s against 234 s in the morning) | 1485 s |"),
    Quote("README.md", "MGN's 20,000 steps: 3544 s on a 2-core", SMALL_CDG, fit_seconds("mgn")),
    Quote("README.md", "(0.0708-0.331 s a training step on one NVIDIA H200", VIDEO_GPU, step_range),
    Quote("README.md", "against\n  9.06-45.2 s on 2 cores of an Intel Xeon, 2026-11-27", VIDEO_CPU, step_range),
    Quote("README.md", "(300 frames in\n  365.5 s, 2026-11-27)", "results/gpu_h200/README.md", "354.7 s; 365.5 s wall"),
    Quote("README.md", "MGN's training step 1.13-1.14x on an Intel Xeon (Sapphire Rapids, 2026-11-29)", CHANGELOG, "training step costs 1.13-1.14x its host-path time"),
    Quote("README.md", "0.97-1.01x on an AMD EPYC (Zen\n4, 2026-12-06", CHANGELOG, "mode costs 0.97-1.01x on that CPU's MGN training step"),
    Quote("README.md", "the renderer 0.98-1.06x", "docs/reproducibility.md", "| 69.2 ms | 67.8 ms | 0.98x |"),
    Quote("README.md", "the renderer 0.98-1.06x", "docs/reproducibility.md", "1.13x, 1.12x, 1.02x and 1.06x"),
    # presets: the measured plan
    Quote("docs/presets.md", "nothing else running, 2026-12-06 | 1188 s |", CHANGELOG, "nothing else running, 2026-12-06 | 1188 s |"),
    Quote("docs/presets.md", "the same AMD host, 2026-12-06 | 1183 s |", CHANGELOG, "the same AMD host, 2026-12-06 | 1183 s |"),
    Quote("docs/presets.md", "nothing else running, 2026-12-06 | 1234 s |", CHANGELOG, "the plan in 1234 s"),
    Quote("docs/presets.md", "nothing else running, 2026-11-29 | 1485 s |", CHANGELOG, "the plan in 1485 s"),
    Quote("docs/presets.md", "3544 s on one core of a 2-core Intel Xeon, 2026-11-26", SMALL_CDG, fit_seconds("mgn")),
    Quote("docs/presets.md", "(9.06-45.2 s a step on 2 cores of an Intel Xeon", VIDEO_CPU, step_range),
    Quote("docs/presets.md", "0.0708-0.331 s on one NVIDIA H200", VIDEO_GPU, step_range),
    # development: CI's cost and the test suite's
    Quote("docs/development.md", "took 1695 s (28.3 minutes) on a 2-core AMD EPYC", CHANGELOG, "1695 s on\n  the AMD EPYC (2026-12-06: 1180 tests in 353 s, the plan in 1234 s)"),
    Quote("docs/development.md", "1180 tests in 353 s, the site, and the seed-0 plan in 1234 s", CHANGELOG, "1180 tests in 353 s, the plan in 1234 s"),
    Quote("docs/development.md", "it took 1975 s:\n1178 tests in 367 s and the seed-0 plan in 1485 s", CHANGELOG, "1975 s on the Xeon"),
    Quote("docs/development.md", "1178 tests in 367 s and the seed-0 plan in 1485 s", CHANGELOG, "1178 tests in 367 s, the plan in 1485 s"),
    Quote("docs/development.md", "took 353 s on a 2-core AMD EPYC (Zen 4), 2026-12-06, and 367 s on a 2-core Intel Xeon", CHANGELOG, "1180 tests in 353 s"),
]  # fmt: skip


@pytest.mark.parametrize("quote", QUOTES, ids=lambda q: f"{q.page}: {q.text[:40]}")
def test_each_quoted_number_is_on_its_page_and_in_its_source(quote: Quote) -> None:
    page = (ROOT / quote.page).read_text()
    assert quote.text in page, f"{quote.page} no longer says {quote.text!r}"
    source = ROOT / quote.source
    if callable(quote.found):
        number = quote.found(source)
        assert number in quote.text.replace("\n  ", " ").replace("\n", " "), f"{quote.source} gives {number!r}; {quote.page} says {quote.text!r}"
    else:
        assert quote.found in source.read_text(), f"{quote.source} no longer says {quote.found!r} (quoted by {quote.page})"


def test_the_ci_plan_times_quoted_are_todays() -> None:
    """The first seed's time under an earlier deterministic mode (886 s, pins version 3) is history, not a quote."""
    for page in ("README.md", "docs/presets.md", "docs/development.md", "docs/getting-started.md"):
        assert "886 s" not in (ROOT / page).read_text(), page
    assert "886 s" in (ROOT / CHANGELOG).read_text()
