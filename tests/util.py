"""Helpers shared by the tests."""

from __future__ import annotations

from collections.abc import Coroutine
from typing import Any, TypeVar

from cobus.runtime import SimulatedEventLoop

T = TypeVar("T")


def simulate(coro: Coroutine[Any, Any, T]) -> T:
    """Run ``coro`` to the end on a fresh simulated-clock loop (time starts at 0.0)."""
    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(coro)
    finally:
        loop.close()
