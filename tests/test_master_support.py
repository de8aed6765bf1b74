"""Shared set-up of the master tests: device dictionaries, their EDS files, network files, and a
simulated network with the master, the devices and a log of frames and events."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any, TypeVar

from cobus.device import BlockingDevice, Device, DictionaryBuilder, add_device, export_eds
from cobus.master import (
    BlockingMaster,
    Diagnostic,
    Leds,
    ManagedNode,
    Master,
    MasterEvent,
    MasterState,
    MasterStatus,
    NetworkConfig,
    NodeState,
    loads_network,
)
from cobus.od import DataType, ObjectDictionary
from cobus.proto import Frame
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork, SimulatedEventLoop

T = TypeVar("T")

VENDOR = 0x00C0B05
PRODUCT = 0x401


def simulate(coro: Coroutine[Any, Any, T]) -> T:
    loop = SimulatedEventLoop()
    try:
        return loop.run_until_complete(coro)
    finally:
        loop.close()


def io_od(*, device_type: int = 0x191, vendor_id: int = VENDOR, **profile: Any) -> ObjectDictionary:
    """The dictionary of the simulated I/O device most tests use."""
    b = DictionaryBuilder(
        device_name="test io",
        device_type=device_type,
        vendor_id=vendor_id,
        product_code=PRODUCT,
        revision=0x10001,
        serial=0xABCD,
        **profile,
    )
    b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
    b.variable(
        0x2001, "Setpoint", DataType.INTEGER16, access="rww", mappable=True, low=-1000, high=1000
    )
    b.variable(0x2002, "Flags", DataType.UNSIGNED8, access="rww", mappable=True)
    b.variable(0x2003, "Temperature", DataType.REAL32, access="ro", mappable=True)
    b.variable(0x2004, "Ready", DataType.BOOLEAN, access="ro", mappable=True)
    b.variable(0x200A, "Parameter", DataType.UNSIGNED32, default=7)
    b.array(0x6000, "Digital inputs", DataType.UNSIGNED8, 2, access="ro", mappable=True)
    return b.build()


def write_eds(folder: Path, name: str = "io.eds", od: ObjectDictionary | None = None) -> Path:
    path = folder / name
    path.write_text(export_eds(od if od is not None else io_od()), encoding="utf-8")
    return path


def network(folder: Path, text: str, eds: str = "io.eds") -> NetworkConfig:
    """A network description from YAML text; writes the I/O device's EDS next to it."""
    if not (folder / eds).exists():
        write_eds(folder, eds)
    return loads_network(text, base_dir=folder, path=str(folder / "net.yml"))


# Read state through functions: mypy narrows a property after one assertion and would call a
# second assertion on the same property unreachable.
def state(node: ManagedNode) -> NodeState:
    return node.state


def diagnostic(node: ManagedNode) -> Diagnostic:
    return node.diagnostic


def nmt(device: Device | BlockingDevice) -> NmtState:
    return device.state


def master_state(master: Master | BlockingMaster) -> MasterState:
    return master.state


def status(master: Master | BlockingMaster) -> MasterStatus:
    return master.status


def leds(node: ManagedNode) -> Leds:
    return node.led


class Rig:
    """A master and devices on one simulated network, with every frame and event logged."""

    def __init__(self, net: AsyncNetwork, config: NetworkConfig) -> None:
        self.net = net
        self.config = config
        self.frames: list[tuple[float, Frame]] = []
        self.events: list[tuple[float, MasterEvent]] = []
        self.devices: dict[int, Device] = {}
        net.subscribe_all(lambda frame, now: self.frames.append((now, frame)))
        self.master = Master(net, config)
        self.master.add_listener(lambda e: self.events.append((net.time(), e)))

    def add(self, node_id: int, od: ObjectDictionary | None = None, **options: Any) -> Device:
        """Power on a device (each gets a dictionary of its own)."""
        device = add_device(self.net, node_id, od if od is not None else io_od(), **options)
        self.devices[node_id] = device
        return device

    def of(self, kind: type[T]) -> list[T]:
        return [e for _, e in self.events if isinstance(e, kind)]

    def on(self, cob_id: int, *, since: float = -1.0) -> list[tuple[float, Frame]]:
        return [(t, f) for t, f in self.frames if f.cob_id == cob_id and t >= since]

    def data(self, cob_id: int, *, since: float = -1.0) -> list[bytes]:
        return [f.data for _, f in self.on(cob_id, since=since) if not f.rtr]

    def send(self, cob_id: int, data: bytes = b"", *, rtr: bool = False) -> None:
        self.net.send(Frame(cob_id, data, rtr=rtr))

    async def settle(self) -> None:
        for _ in range(4):
            await asyncio.sleep(0)

    async def run(self, seconds: float) -> None:
        await asyncio.sleep(seconds)


def rig_test(config: NetworkConfig, scenario: Callable[[Rig], Coroutine[Any, Any, T]]) -> T:
    """Run ``scenario`` on a fresh simulated network with a master for ``config``."""

    async def main() -> T:
        async with AsyncNetwork() as net:
            rig = Rig(net, config)
            try:
                return await scenario(rig)
            finally:
                await rig.master.stop()

    return simulate(main())
