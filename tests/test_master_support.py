"""Shared set-up of the master tests: device dictionaries, their EDS files, network files."""

from __future__ import annotations

from collections.abc import Coroutine
from pathlib import Path
from typing import Any, TypeVar

from cobus.device import DictionaryBuilder, export_eds
from cobus.master import NetworkConfig, loads_network
from cobus.od import DataType, ObjectDictionary
from cobus.runtime import SimulatedEventLoop

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
