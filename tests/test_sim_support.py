"""Shared set-up of the simulation tests: a simulated network with a cobus AsyncRemoteNode as the
master of a simulated device, a log of every frame, and waiting on the virtual clock."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

from cobus.device import export_eds
from cobus.od import loads
from cobus.proto import Event, Frame
from cobus.runtime import AsyncNetwork, SimulatedEventLoop
from cobus.runtime.remote import AsyncRemoteNode
from cobus.sim.generic import CanopenSimDevice

T = TypeVar("T")


def simulate(coro: Coroutine[Any, Any, T]) -> T:
    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(coro)
    finally:
        loop.close()


class SimBench:
    """A simulated device, a master for it, and what happened on the network."""

    def __init__(self, net: AsyncNetwork, sim: CanopenSimDevice, master: AsyncRemoteNode) -> None:
        self.net = net
        #: the simulated device (typed loosely: each test knows which kind it made)
        self.sim: Any = sim
        self.master = master
        self.sdo = master.sdo
        self.node = sim.node_id
        self.frames: list[tuple[float, Frame]] = []
        self.events: list[Event] = []
        net.subscribe_all(lambda frame, now: self.frames.append((now, frame)))
        net.add_listener(self.events.append)

    def on(self, cob_id: int, *, since: float = -1.0) -> list[tuple[float, Frame]]:
        return [(t, f) for t, f in self.frames if f.cob_id == cob_id and t >= since]

    def data(self, cob_id: int, *, since: float = -1.0) -> list[bytes]:
        return [f.data for _, f in self.on(cob_id, since=since) if not f.rtr]

    def of(self, kind: type[Any]) -> list[Any]:
        return [e for e in self.events if isinstance(e, kind)]

    def send(self, cob_id: int, data: bytes = b"") -> None:
        self.net.send(Frame(cob_id, data))

    async def settle(self) -> None:
        """Let every frame sent so far be delivered (no virtual time passes)."""
        for _ in range(4):
            await asyncio.sleep(0)

    async def sync(self) -> None:
        self.send(0x80)
        await self.settle()

    async def until(self, check: Callable[[], Any], timeout: float, step=0.001) -> float:
        """Wait (virtual time) until ``check()`` holds; the time it took."""
        start = self.net.time()
        while True:
            result = check()
            if asyncio.iscoroutine(result):
                result = await result
            if result:
                return self.net.time() - start
            if self.net.time() - start > timeout:
                raise AssertionError(f"not reached within {timeout} s of simulated time")
            await self.net.sleep(step)


def run_sim(
    make: Callable[[AsyncNetwork], CanopenSimDevice],
    scenario: Callable[[SimBench], Coroutine[Any, Any, T]],
    *,
    sdo_timeout: float = 1.0,
) -> T:
    """Start ``make(net)``'s device on a simulated network and run ``scenario`` against it,
    with a master that knows the device from its exported EDS."""

    async def main() -> T:
        async with AsyncNetwork() as net:
            sim = make(net)
            master = net.add_remote(
                sim.node_id, loads(export_eds(sim.od), sim.node_id), sdo_timeout=sdo_timeout
            )
            bench = SimBench(net, sim, master)
            sim.start()
            try:
                return await scenario(bench)
            finally:
                sim.close()

    return simulate(main())
