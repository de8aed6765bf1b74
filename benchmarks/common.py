"""Helpers shared by the benchmark scripts: timing and a uniform table of figures."""

from __future__ import annotations

import time
from collections.abc import Callable


def best_of(fn: Callable[[], object], repeat: int = 5) -> float:
    """The fastest of ``repeat`` runs of ``fn``, in seconds."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def row(label: str, cobus: float, other: float | None, unit: str, higher_is_better: bool) -> str:
    """One line: the figure of cobus, of python-canopen, and how many times better cobus is."""
    if other is None or other == 0 or cobus == 0:
        return f"  {label:<44} {cobus:>12,.0f} {unit:<8} {'-':>12}"
    ratio = cobus / other if higher_is_better else other / cobus
    return f"  {label:<44} {cobus:>12,.0f} {unit:<8} {other:>12,.0f} {unit:<8} x{ratio:5.1f}"


def header(title: str) -> str:
    return f"\n{title}\n  {'':<44} {'cobus':>12} {'':<8} {'canopen':>12}"
