"""Helpers shared by the tests."""

from __future__ import annotations

import time
from collections.abc import Callable, Coroutine
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


def until(check: Callable[[], object], timeout: float = 2.0) -> None:
    """Wait in real time (polling every 5 ms) until ``check()`` holds; AssertionError after
    ``timeout`` seconds. For tests with python-canopen, which runs its own threads."""
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.005)
