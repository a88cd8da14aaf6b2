"""A clock the fakes advance by hand, so timing code is checked against exact, known durations."""

from __future__ import annotations


class FakeClock:
    """Returns `now`; a fake plugin adds its cost to `now` instead of spending it."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now
