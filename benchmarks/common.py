"""Helpers shared by the benchmark scripts: timing and a uniform table of figures."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence

import can
import canopen

from cobus.runtime import AsyncNetwork, SimulatedEventLoop


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


def cobus_receive_rate(
    setup: Callable[[AsyncNetwork], object], msgs: Sequence[can.Message]
) -> float:
    """Frames per second through a cobus network's receive path (messages already read, in
    batches as its reader takes them), after ``setup(network)`` subscribed what it measures."""
    loop = SimulatedEventLoop()

    async def connect() -> AsyncNetwork:
        net = await AsyncNetwork().connect()
        setup(net)
        await asyncio.sleep(0)  # what setup sent is delivered before the timing starts
        return net

    net = loop.run_until_complete(connect())
    batches = [msgs[i : i + 64] for i in range(0, len(msgs), 64)]

    def run() -> None:
        for batch in batches:
            net._on_messages(batch)

    elapsed = best_of(run)
    loop.run_until_complete(net.disconnect())
    loop.close()
    return len(msgs) / elapsed


def canopen_device_type_od() -> canopen.ObjectDictionary:
    """A python-canopen dictionary holding only 1000h (device type 191h), for a LocalNode
    that answers expedited reads."""
    od = canopen.ObjectDictionary()
    var = canopen.objectdictionary.ODVariable("Device type", 0x1000, 0)
    var.data_type = canopen.objectdictionary.datatypes.UNSIGNED32
    var.access_type = "ro"
    var.default = 0x191
    od.add_object(var)
    return od
