"""Shared set-up of the device tests: a test dictionary, a simulated network with the device
and a cobus AsyncRemoteNode as the master, and a log of every frame on the bus."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

from cobus.device import Device, DeviceEvent, DictionaryBuilder, add_device, export_eds
from cobus.od import DataType, ObjectDictionary, loads
from cobus.proto import Event, Frame
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork, SimulatedEventLoop
from cobus.runtime.remote import AsyncRemoteNode

T = TypeVar("T")
NODE = 5


def simulate(coro: Coroutine[Any, Any, T]) -> T:
    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(coro)
    finally:
        loop.close()


def test_od(**profile: Any) -> ObjectDictionary:
    """The device dictionary most tests use."""
    b = DictionaryBuilder(device_name="test device", **profile)
    b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
    b.variable(
        0x2001, "Setpoint", DataType.INTEGER16, access="rww", mappable=True, low=-1000, high=1000
    )
    b.variable(0x2002, "Flags", DataType.UNSIGNED8, mappable=True)
    b.variable(0x2003, "Name", DataType.VISIBLE_STRING, default="pump")
    b.variable(0x2004, "Secret", DataType.UNSIGNED32, access="wo")
    b.variable(0x2005, "Constant", DataType.UNSIGNED32, access="const", default=42)
    b.variable(0x2006, "Temperature", DataType.REAL32, access="ro", mappable=True)
    b.variable(0x2007, "Enable", DataType.BOOLEAN, mappable=True)
    b.variable(0x2008, "Blob", DataType.DOMAIN)
    b.variable(0x2009, "Wide", DataType.UNSIGNED64, mappable=True)
    b.variable(0x200A, "Parameter", DataType.UNSIGNED32, default=7)
    b.array(0x6000, "Digital inputs", DataType.UNSIGNED8, 2, access="ro", mappable=True)
    b.array(0x6200, "Digital outputs", DataType.UNSIGNED8, 2, access="rww", mappable=True)
    return b.build()


# not a test: pytest collects names starting with "test"
test_od.__test__ = False  # type: ignore[attr-defined]


class Bench:
    """A device and a master on one simulated network, with the frames and events seen."""

    def __init__(
        self,
        net: AsyncNetwork,
        device: Device,
        master: AsyncRemoteNode,
        frames: list[tuple[float, Frame]],
        events: list[Event],
    ) -> None:
        self.net = net
        self.device = device
        self.master = master
        self.sdo = master.sdo
        self.frames = frames
        self.events = events

    def on(self, cob_id: int, *, since: float = -1.0) -> list[tuple[float, Frame]]:
        """The frames on ``cob_id`` (sent at or after ``since``)."""
        return [(t, f) for t, f in self.frames if f.cob_id == cob_id and t >= since]

    def data(self, cob_id: int, *, since: float = -1.0) -> list[bytes]:
        return [f.data for _, f in self.on(cob_id, since=since) if not f.rtr]

    def times(self, cob_id: int, *, since: float = -1.0) -> list[float]:
        return [round(t, 6) for t, f in self.on(cob_id, since=since) if not f.rtr]

    def state(self) -> NmtState:
        return self.device.state

    def of(self, kind: type[DeviceEvent]) -> list[Any]:
        return [e for e in self.events if isinstance(e, kind)]

    def send(self, cob_id: int, data: bytes = b"", *, rtr: bool = False) -> None:
        self.net.send(Frame(cob_id, data, rtr=rtr))

    async def settle(self) -> None:
        """Let every frame sent so far be delivered (no virtual time passes)."""
        await asyncio.sleep(0)
        await asyncio.sleep(0)

    async def start(self) -> None:
        """NMT start of the device, delivered."""
        self.net.nmt.start(self.device.node_id)
        await self.settle()

    async def sync(self, counter: int | None = None) -> None:
        self.send(0x80, b"" if counter is None else bytes((counter,)))
        await self.settle()


def bench(
    net: AsyncNetwork,
    od: ObjectDictionary | None = None,
    node_id: int = NODE,
    **options: Any,
) -> Bench:
    """Start a device on ``net`` (before the log starts, so the boot-up is logged too)."""
    dictionary = od if od is not None else test_od()
    # the master knows the device from its exported EDS
    master = net.add_remote(node_id, loads(export_eds(dictionary), node_id))
    frames: list[tuple[float, Frame]] = []
    events: list[Event] = []
    net.subscribe_all(lambda frame, now: frames.append((now, frame)))
    net.add_listener(events.append)
    device = add_device(net, node_id, dictionary, **options)
    return Bench(net, device, master, frames, events)


def run_bench(
    scenario: Callable[[Bench], Coroutine[Any, Any, T]],
    od: ObjectDictionary | None = None,
    node_id: int = NODE,
    **options: Any,
) -> T:
    """Run ``scenario(bench)`` on a fresh simulated network."""

    async def main() -> T:
        async with AsyncNetwork() as net:
            b = bench(net, od, node_id, **options)
            await b.settle()
            return await scenario(b)

    return simulate(main())
