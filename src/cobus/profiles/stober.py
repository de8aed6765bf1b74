"""The STÖBER MDS 5000 inverter (seed 004) from the master side: parameters by their names
(``C01``, ``A225.3``), the E82 events decoded (from the emergency or read), its device state
E48, and the device control word.

STÖBER numbers parameters by group and number: ``Gnn.e`` is object ``2000h + 200h x (group -
1) + nn``, sub-index ``e`` (A = 2000h, C01 -> 2401h, E08 -> 2808h ... Z = 5200h). Its
emergencies carry the E82 event in byte 3 and the E39 cause in byte 4. The manual leaves the
application's process data to the vendor's tool; the device control parameter (the simulated
inverter's A180: bit 0 enable, bit 1 quick stop, bit 2 acknowledge) is an option.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cobus.errors import CobusError
from cobus.od import DataType, decode, encode
from cobus.profiles._tables import table
from cobus.runtime.twin import BlockingTwin

__all__ = [
    "EVENTS",
    "STATES",
    "AsyncStoberDrive",
    "StoberDrive",
    "StoberError",
    "StoberEvent",
    "event_of",
    "parameter_index",
]

#: E82 event -> (text, EMCY error code, error register), from the manual's table.
EVENTS: Mapping[int, tuple[str, int, int]] = {
    number: (event["text"], event["emcy"], event["register"])
    for number, event in table("stober_events")["events"].items()
}

#: E48 device states.
STATES: Mapping[int, str] = {
    0: "self test",
    1: "switch-on disabled",
    2: "ready to switch on",
    3: "switched on",
    4: "operation enabled",
    5: "quick stop active",
    6: "fault reaction active",
    7: "fault",
}

GROUPS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"


class StoberError(CobusError, ValueError):
    """A STÖBER parameter name that is not one, or an answer the adapter cannot use."""


def parameter_index(coordinate: str) -> tuple[int, int]:
    """The CANopen index and sub-index of a STÖBER parameter: ``"C01"`` -> (2401h, 0),
    ``"A225.3"`` -> (20E1h, 3), ``"E08"`` -> (2808h, 0); :class:`StoberError` for a name
    that is not one."""
    text = coordinate.strip().upper() if isinstance(coordinate, str) else ""
    group, rest = text[:1], text[1:]
    number_text, _, element_text = rest.partition(".")
    if (
        group not in GROUPS
        or not group
        or not number_text.isdigit()
        or (element_text and not element_text.isdigit())
    ):
        raise StoberError(
            f"{coordinate!r} is not a parameter coordinate: a group A..Z, a number, an optional "
            "element (e.g. C01, A225.3)"
        )
    number = int(number_text)
    element = int(element_text) if element_text else 0
    if not 0 <= number <= 0x1FF or not 0 <= element <= 0xFF:
        raise StoberError(f"{coordinate!r}: the number is 0..511 and the element 0..255")
    return 0x2000 + 0x200 * GROUPS.index(group) + number, element


@dataclass(frozen=True)
class StoberEvent:
    """An E82 event with its E39 ``cause``: ``str()`` gives ``"E82 41 motor temperature
    (cause 0)"``."""

    number: int
    cause: int = 0

    @property
    def text(self) -> str:
        """The manual's name of the event (``"event 99"`` for one the table lacks)."""
        return EVENTS.get(self.number, (f"event {self.number}", 0, 0))[0]

    @property
    def emcy_code(self) -> int | None:
        """The EMCY error code the inverter sends for it (None: not in the table)."""
        known = EVENTS.get(self.number)
        return known[1] if known else None

    @property
    def active(self) -> bool:
        """Whether it is a fault (30 is "no event")."""
        return self.number != 30

    def __str__(self) -> str:
        return f"E82 {self.number} {self.text} (cause {self.cause})"


def event_of(emergency: Any) -> StoberEvent | None:
    """The E82 event and E39 cause an emergency of the inverter carries (bytes 3 and 4, the
    first two of its manufacturer data); None for a frame too short to hold them."""
    data = bytes(getattr(emergency, "manufacturer_data", b""))
    if len(data) < 2:
        return None
    return StoberEvent(data[0], data[1])


class AsyncStoberDrive:
    """A STÖBER MDS 5000 on a remote node (``net.add_remote(1)``, its EDS if there is one).

    ``read("C01")`` / ``write("C01", 2500)`` by SDO; the data type comes from the node's
    EDS, else from ``types`` (name -> :class:`~cobus.od.DataType`), else a read gives the
    unsigned integer of the bytes that came and a write needs the type. ``control``: the
    device control parameter (bit 0 enable, bit 1 quick stop, bit 2 acknowledge).
    """

    #: The node-ID of the inverter.
    node_id: int

    def __init__(
        self,
        node: Any,
        *,
        types: Mapping[str, DataType] | None = None,
        control: str = "A180",
    ) -> None:
        self._node = getattr(node, "aio", node)
        self.node_id = self._node.node_id
        self._types = {parameter_index(k): v for k, v in (types or {}).items()}
        self._control = parameter_index(control)

    def __repr__(self) -> str:
        return f"<StoberDrive node {self.node_id}>"

    def _type(self, key: tuple[int, int]) -> DataType | None:
        od = self._node.od
        var = od.get_variable(*key) if od is not None else None
        return var.data_type if var is not None else self._types.get(key)

    async def read(self, parameter: str) -> Any:
        """Read a parameter by its name (``"C01"``, ``"A225.3"``)."""
        key = parameter_index(parameter)
        data = await self._node.sdo.upload(*key)
        dt = self._type(key)
        if dt is None:
            return int.from_bytes(data, "little")
        return decode(dt, data[: dt.size or len(data)])

    async def write(self, parameter: str, value: Any) -> None:
        """Write a parameter by its name; its data type must be known (EDS or ``types``)."""
        key = parameter_index(parameter)
        dt = self._type(key)
        if dt is None:
            raise StoberError(
                f"{parameter}: its data type is unknown (0x{key[0]:04X}:{key[1]:02X} is not in "
                "the node's EDS): give the EDS, or types={'" + parameter + "': DataType....}"
            )
        await self._node.sdo.download(*key, encode(dt, value))

    async def read_state(self) -> str:
        """The device state E48 in words (``"operation enabled"``)."""
        state = int(await self.read("E48"))
        return STATES.get(state, f"state {state}")

    async def read_event(self) -> StoberEvent:
        """The last event E82 and its cause E39."""
        return StoberEvent(int(await self.read("E82")), int(await self.read("E39")))

    async def _control_bits(self, bits: int) -> None:
        data = encode(DataType.UNSIGNED16, bits)
        await self._node.sdo.download(*self._control, data)

    async def enable(self) -> None:
        """Device control: enable (bit 0)."""
        await self._control_bits(0x01)

    async def disable(self) -> None:
        """Device control: all bits off."""
        await self._control_bits(0x00)

    async def quick_stop(self) -> None:
        """Device control: enable and quick stop (bits 0 and 1)."""
        await self._control_bits(0x03)

    async def acknowledge(self) -> None:
        """Acknowledge a fault: a rising edge of bit 2 (the inverter sends EMCY 0000h)."""
        await self._control_bits(0x00)
        await self._control_bits(0x04)
        await self._control_bits(0x00)


class StoberDrive(BlockingTwin, twin_of=AsyncStoberDrive):
    """The STÖBER adapter for blocking code: ``StoberDrive(net.add_remote(1))``."""

    def __init__(self, node: Any, runner: Any = None, **options: Any) -> None:
        if isinstance(node, AsyncStoberDrive):
            super().__init__(node, runner)
            return
        runner = getattr(node, "_runner", None)
        if runner is None:
            raise TypeError(
                "StoberDrive takes a node of a blocking Network; use AsyncStoberDrive in async code"
            )
        aio = runner.call(lambda: AsyncStoberDrive(node.aio, **options))
        super().__init__(aio, runner)
