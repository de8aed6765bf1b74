"""The EC motor of seed 002 from the master side: its own SDO dialect as a client, its
objects by name with their unit classes, its modes, the status poll and its emergencies.

The motor is "based on CANopen" but speaks a dialect: expedited SDO only, a read answered
with command byte 40h and a shortened frame, no abort (a refused request shows as an
emergency), a status poll by a DLC 0 frame on 200h+a answered on 180h+a, and an NMT reset
``000: 82 a`` without boot-up. A CiA 301 SDO client cannot talk to it;
:class:`AsyncEcMotorDrive` (blocking: :class:`EcMotorDrive`) can::

    motor = EcMotorDrive(net, 3)
    motor.write("p_ven", 1234)            # 603 [8] 22 24 20 00 D2 04 00 00
    motor.set_mode("VEL")                 # 2042h
    print(motor.read_value("h_vel"), "rpm")
"""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from cobus.errors import CobusError
from cobus.profiles._tables import table
from cobus.proto import Frame
from cobus.proto.connection_set import EMCY_BASE, RPDO_BASE, SDO_RX_BASE, SDO_TX_BASE, TPDO_BASE
from cobus.runtime._service import Callbacks
from cobus.runtime.twin import BlockingTwin

__all__ = [
    "COMMANDS",
    "MODES",
    "OBJECTS",
    "UNITS",
    "AsyncEcMotorDrive",
    "EcEmergency",
    "EcMotorDrive",
    "EcMotorError",
    "EcRefusedError",
    "EcStatus",
    "EcTimeoutError",
]

#: Unit classes: (name, factor to the physical unit, unit).
UNITS: Mapping[str, tuple[str, float, str]] = {
    "V": ("velocity", 0.1875, "rpm"),
    "A": ("acceleration", 0.0146484375, "rpm/ms"),
    "D": ("deceleration", 0.0146484375, "rpm/ms"),
    "P": ("position", 0.1171875, "deg"),
    "M": ("torque", 0.000135, "Nm"),
    "C": ("current", 0.000135, "A"),
    "U": ("voltage", 0.01, "V"),
    "T": ("temperature", 0.01, "degC"),
    "K": ("time", 0.8, "ms"),
}

#: T_MOD: the working modes (2042h; m_ssm bits 4-0).
MODES: Mapping[int, str] = {
    0: "MON",
    1: "OFF",
    2: "STP",
    3: "PON",
    4: "MOM",
    5: "VEL",
    6: "POZ",
    15: "VELP",
    16: "ARRP",
    17: "ETY1",
    18: "ETY2",
    19: "VYSR",
    20: "VYSL",
    28: "M24",
    29: "ERR",
    30: "JMP",
    31: "RES",
}
_MODE_NUMBERS = {name: number for number, name in MODES.items()}


@dataclass(frozen=True)
class EcObject:
    """One object of the motor: index, sub-index (0 16-bit access, 1 32-bit), type, unit
    class (None: none)."""

    name: str
    index: int
    subindex: int
    type: str  # I16, U16, B16, I32, U32
    unit: str | None = None
    writable: bool = True

    @property
    def size(self) -> int:
        """Bytes: 4 for the 32-bit types, else 2."""
        return 4 if self.type.endswith("32") else 2

    @property
    def signed(self) -> bool:
        """Whether the value is signed (I16, I32)."""
        return self.type.startswith("I")


def _objects() -> dict[str, EcObject]:
    table = [
        ("m_eci", 0x200A, 0, "B16", None, True),
        ("S_err", 0x200B, 0, "B16", None, True),
        ("c_sss", 0x200C, 0, "B16", None, False),
        ("m_set", 0x200D, 0, "B16", None, True),
        ("m_sss", 0x200E, 0, "B16", None, False),
        ("m_ssm", 0x200F, 0, "B16", None, False),
        ("p_pox", 0x2010, 1, "I32", "P", False),
        ("p_vex", 0x2011, 0, "I16", "V", False),
        ("h_poz", 0x2012, 1, "I32", "P", False),
        ("h_tet", 0x2013, 1, "I32", "P", False),
        ("h_vel", 0x2014, 0, "I16", "V", False),
        ("iq_ref", 0x2015, 0, "I16", "M", False),
        ("udc", 0x2016, 0, "U16", "U", False),
        ("tsn", 0x2017, 0, "U16", "T", False),
        ("tcu", 0x2018, 0, "U16", None, False),
        ("p_err", 0x2019, 0, "I16", "P", False),
        ("u_tim", 0x2020, 1, "U32", "K", True),
        ("P_lil", 0x2021, 1, "I32", "P", True),
        ("P_lih", 0x2022, 1, "I32", "P", True),
        ("p_pon", 0x2023, 1, "I32", "P", True),
        ("p_ven", 0x2024, 0, "I16", "V", True),
        ("p_acc", 0x2025, 0, "U16", "A", True),
        ("p_dec", 0x2026, 0, "U16", "D", True),
        ("p_mon", 0x2027, 0, "I16", "M", True),
        ("c_set", 0x202F, 0, "U16", None, True),
        ("sw_version", 0x2041, 0, "U16", None, False),
        ("mode", 0x2042, 0, "U16", None, True),
    ]
    return {name: EcObject(name, i, s, t, u, w) for name, i, s, t, u, w in table}


#: The motor's objects by their names in the document.
OBJECTS: Mapping[str, EcObject] = _objects()
_BY_INDEX = {obj.index: obj for obj in OBJECTS.values()}

#: The objects whose write makes the motor act (index → why): a parameter set never holds
#: them unless allowed (:class:`~cobus.od.CommandObjects` with this table).
COMMANDS: Mapping[int, str] = {
    0x200A: "m_eci, the motor's I/O bits: it switches its outputs",
    0x200D: "m_set, the motor control word: it enables the power stage and sets the direction",
    0x2023: "p_pon, the target position",
    0x2024: "p_ven, the target velocity",
    0x2042: "the working mode (T_MOD): it starts and stops the motor",
    0x2045: "a motor command (clear errors, zero the position)",
}

#: m_sss (200Eh) error and warning bits, by name.
M_SSS_BITS: Mapping[int, str] = dict(table("ecmotor_status")["m_sss"])
_BAD_COMMAND, _FRAME_ERROR = 1 << 14, 1 << 15
#: c_sss (200Ch) communication status bits, by name.
C_SSS_BITS: Mapping[int, str] = dict(table("ecmotor_status")["c_sss"])


def _bits(value: int, names: Mapping[int, str]) -> list[str]:
    return [text for bit, text in names.items() if value >> bit & 1]


class EcMotorError(CobusError):
    """The EC motor did not do what it was asked."""


class EcTimeoutError(EcMotorError, TimeoutError):
    """No answer within the timeout (the motor answers a refused request with an emergency
    only; a motor that is off answers nothing)."""


@dataclass(frozen=True)
class EcEmergency:
    """The motor's emergency ``080+a [8] 10 00 m_sss c_sss m_ssm``, decoded."""

    address: int
    time: float
    m_sss: int
    c_sss: int
    m_ssm: int

    @property
    def errors(self) -> list[str]:
        """The m_sss bits set, in words."""
        return _bits(self.m_sss, M_SSS_BITS)

    @property
    def communication(self) -> list[str]:
        """The c_sss bits set, in words (``"bad command"`` for a refused request)."""
        return _bits(self.c_sss, C_SSS_BITS)

    @property
    def mode(self) -> str:
        """The mode m_ssm shows."""
        number = self.m_ssm & 0x1F
        return MODES.get(number, str(number))

    def __str__(self) -> str:
        parts = self.errors + self.communication
        return (
            f"EC motor {self.address} emergency: {', '.join(parts) or 'no bits'} (mode {self.mode})"
        )


class EcRefusedError(EcMotorError):
    """The motor refused a request: it sent an emergency instead of the SDO answer
    (``emergency`` says which bits it set)."""

    def __init__(self, what: str, emergency: EcEmergency) -> None:
        super().__init__(f"{what}: refused — {emergency}")
        self.emergency = emergency


@dataclass(frozen=True)
class EcStatus:
    """The status poll's answer: ``position`` (h_poz, P units), ``io`` (m_eci), ``status``
    (m_ssm), with the mode and flags decoded."""

    position: int
    io: int
    status: int

    @property
    def mode(self) -> str:
        """The working mode (m_ssm bits 4-0) by name."""
        number = self.status & 0x1F
        return MODES.get(number, str(number))

    @property
    def error(self) -> bool:
        """m_ssm bit 15: the motor is in error."""
        return bool(self.status & 0x8000)

    @property
    def power_stage_on(self) -> bool:
        """m_ssm bit 11."""
        return bool(self.status & 0x0800)

    @property
    def rotating(self) -> bool:
        """m_ssm bit 10."""
        return bool(self.status & 0x0400)

    @property
    def in_position(self) -> bool:
        """m_ssm bit 9."""
        return bool(self.status & 0x0200)


class AsyncEcMotorDrive:
    """The EC motor at ``address`` (1-15) on ``network`` (see the module docstring).

    Reads and writes go one at a time, each within ``timeout`` seconds. Objects are named as
    in the document (:data:`OBJECTS`: ``"p_ven"``, ``"h_vel"``...) or given as an index
    (then ``subindex`` 0 is a 16-bit access, 1 a 32-bit one)."""

    #: The motor's address, 1..15.
    address: int
    #: Seconds to wait for each answer.
    timeout: float

    def __init__(self, network: Any, address: int, *, timeout: float = 0.5) -> None:
        if isinstance(address, bool) or not isinstance(address, int) or not 1 <= address <= 15:
            raise ValueError(f"EC motor address {address!r}: 1..15 (c_set.adr0)")
        self._network = getattr(network, "aio", network)
        self.address = address
        self.timeout = timeout
        self._lock = asyncio.Lock()
        self._pending: tuple[bytes, asyncio.Future[Frame | EcEmergency]] | None = None
        self._status: asyncio.Future[EcStatus] | None = None
        self._emergencies: list[EcEmergency] = []
        self._callbacks: Callbacks[EcEmergency] = Callbacks(
            self._network, f"EC motor {address} emergencies"
        )
        self._subscriptions = [
            self._network.subscribe(SDO_TX_BASE + address, self._on_answer),
            self._network.subscribe(TPDO_BASE + address, self._on_status),
            self._network.subscribe(EMCY_BASE + address, self._on_emcy),
        ]

    def __repr__(self) -> str:
        return f"<EcMotorDrive address {self.address}>"

    # ------------------------------------------------------------------ frames in
    def _on_answer(self, frame: Frame, now: float) -> None:
        pending = self._pending
        if pending is None or pending[1].done() or len(frame.data) < 4:
            return
        head, future = pending
        if bytes(frame.data[1:4]) == head[1:4] and frame.data[0] in (0x40, 0x60):
            future.set_result(frame)

    def _on_status(self, frame: Frame, now: float) -> None:
        if self._status is not None and not self._status.done() and len(frame.data) >= 8:
            position, io, status = struct.unpack_from("<iHH", frame.data)
            self._status.set_result(EcStatus(position, io, status))

    def _on_emcy(self, frame: Frame, now: float) -> None:
        if len(frame.data) < 8:
            return
        m_sss, c_sss, m_ssm = struct.unpack_from("<HHH", frame.data, 2)
        emergency = EcEmergency(self.address, now, m_sss, c_sss, m_ssm)
        self._emergencies.append(emergency)
        del self._emergencies[:-32]
        pending = self._pending
        refused = c_sss & (_BAD_COMMAND | _FRAME_ERROR)
        if refused and pending is not None and not pending[1].done():
            pending[1].set_result(emergency)  # the motor's answer to a refused request
        self._callbacks(emergency)

    # ------------------------------------------------------------------ transfers
    def _object(self, key: str | int, subindex: int | None) -> EcObject:
        if isinstance(key, str):
            obj = OBJECTS.get(key) or next(
                (o for n, o in OBJECTS.items() if n.lower() == key.lower()), None
            )
            if obj is None:
                raise KeyError(
                    f"the EC motor has no object {key!r}; its objects: {', '.join(OBJECTS)}"
                )
            return obj
        if isinstance(key, bool) or not isinstance(key, int) or not 0x2000 <= key <= 0x2FFF:
            raise ValueError(f"EC motor index {key!r}: its objects are 2000h..20FFh")
        known = _BY_INDEX.get(key)
        sub = subindex if subindex is not None else (known.subindex if known else 0)
        if not 0 <= sub <= 4:
            raise ValueError(f"sub-index {sub}: 0 16-bit, 1 32-bit, 2 SET, 3 CLR, 4 NEG")
        kind = known.type if known and sub in (0, 1) else ("U32" if sub == 1 else "U16")
        name = known.name if known else f"0x{key:04X}"
        return EcObject(name, key, sub, kind, known.unit if known else None)

    async def _transfer(self, request: bytes, what: str) -> Frame:
        async with self._lock:
            future: asyncio.Future[Frame | EcEmergency] = self._network.loop.create_future()
            self._pending = (request, future)
            try:
                self._network.send(Frame(SDO_RX_BASE + self.address, request))
                answer = await asyncio.wait_for(future, self.timeout)
            except TimeoutError:
                raise EcTimeoutError(
                    f"EC motor {self.address}: no answer to {what} within {self.timeout:g} s"
                ) from None
            finally:
                self._pending = None
        if isinstance(answer, EcEmergency):
            raise EcRefusedError(f"EC motor {self.address}: {what}", answer)
        return answer

    async def read(self, key: str | int, subindex: int | None = None) -> int:
        """Read an object (raw value, signed as its type)."""
        obj = self._object(key, subindex)
        request = struct.pack("<BHB", 0x40, obj.index, obj.subindex) + bytes(4)
        answer = await self._transfer(request, f"read {obj.name}")
        data = bytes(answer.data[4:])
        if len(data) < 2:
            raise EcMotorError(f"EC motor {self.address}: read {obj.name}: answer {answer}")
        size = 4 if len(data) >= 4 and obj.size == 4 else 2
        return int.from_bytes(data[:size], "little", signed=obj.signed)

    async def write(self, key: str | int, value: int, subindex: int | None = None) -> None:
        """Write an object (raw value), checked against its type first."""
        obj = self._object(key, subindex)
        if not obj.writable:
            raise EcMotorError(f"EC motor object {obj.name} is read-only")
        if isinstance(value, bool) or not isinstance(value, int):
            raise TypeError(f"{obj.name}: a raw value is an integer, not {value!r}")
        bits = obj.size * 8
        low, high = (-(1 << bits - 1), (1 << bits - 1) - 1) if obj.signed else (0, (1 << bits) - 1)
        if not low <= value <= high:
            raise ValueError(f"{obj.name} ({obj.type}): {value} is outside {low}..{high}")
        data = (value & (1 << bits) - 1).to_bytes(4, "little")
        await self._transfer(
            struct.pack("<BHB", 0x22, obj.index, obj.subindex) + data, f"write {obj.name}"
        )

    async def read_value(self, name: str) -> float:
        """Read an object in its physical unit (raw x the unit class's factor)."""
        obj = self._object(name, None)
        factor = UNITS[obj.unit][1] if obj.unit else 1.0
        return await self.read(name) * factor

    async def write_value(self, name: str, value: float) -> None:
        """Write an object given in its physical unit (rounded to raw units)."""
        obj = self._object(name, None)
        factor = UNITS[obj.unit][1] if obj.unit else 1.0
        await self.write(name, round(value / factor))

    async def set_bits(self, name: str | int, mask: int) -> None:
        """SET the ``mask`` bits of a bit-field object (sub 2)."""
        await self.write(self._object(name, None).index, mask, 2)

    async def clear_bits(self, name: str | int, mask: int) -> None:
        """CLR the ``mask`` bits of a bit-field object (sub 3)."""
        await self.write(self._object(name, None).index, mask, 3)

    async def toggle_bits(self, name: str | int, mask: int) -> None:
        """NEG the ``mask`` bits of a bit-field object (sub 4)."""
        await self.write(self._object(name, None).index, mask, 4)

    async def set_mode(self, mode: str | int) -> None:
        """Switch the working mode (2042h): ``"VEL"``, ``"POZ"``, ``"OFF"``... or its number."""
        number = _MODE_NUMBERS.get(mode.upper()) if isinstance(mode, str) else mode
        if number is None or number not in MODES or number >= 28:
            names = ", ".join(f"{n} {m}" for n, m in MODES.items() if n < 28)
            raise ValueError(f"mode {mode!r}: the modes a master sets are {names}")
        await self.write("mode", number)

    async def clear_errors(self) -> None:
        """Clear the latched errors of m_sss (2045h sub 0)."""
        await self.write(0x2045, 0, 0)

    async def poll_status(self) -> EcStatus:
        """The status poll (``200+a`` with DLC 0): position, I/O and status bits."""
        async with self._lock:
            self._status = self._network.loop.create_future()
            try:
                self._network.send(Frame(RPDO_BASE + self.address, b""))
                return await asyncio.wait_for(self._status, self.timeout)
            except TimeoutError:
                raise EcTimeoutError(
                    f"EC motor {self.address}: no status within {self.timeout:g} s"
                ) from None
            finally:
                self._status = None

    def reset(self) -> None:
        """Reset the motor (``000: 82 a``); it answers nothing and sends no boot-up."""
        self._network.send(Frame(0x000, bytes((0x82, self.address))))

    @property
    def emergencies(self) -> list[EcEmergency]:
        """The last emergencies received, oldest first."""
        return list(self._emergencies)

    def add_callback(self, callback: Callable[[EcEmergency], object]) -> None:
        """Call ``callback(emergency)`` for each emergency of the motor."""
        self._callbacks.add(callback)

    def remove_callback(self, callback: Callable[[EcEmergency], object]) -> None:
        """Stop calling ``callback``."""
        self._callbacks.remove(callback)

    def close(self) -> None:
        """Stop listening to the motor; a transfer under way fails at once."""
        for subscription in self._subscriptions:
            subscription.cancel()
        pending = self._pending
        if pending is not None and not pending[1].done():
            pending[1].set_exception(EcMotorError(f"EC motor {self.address}: closed"))


class EcMotorDrive(BlockingTwin, twin_of=AsyncEcMotorDrive):
    """The EC motor client for blocking code: ``EcMotorDrive(net, 3)`` on a blocking
    :class:`~cobus.runtime.Network`."""

    def __init__(self, network: Any, address: Any, **options: Any) -> None:
        if isinstance(network, AsyncEcMotorDrive):  # a twin made for an async client
            super().__init__(network, address)
            return
        runner = getattr(network, "_runner", None)
        if runner is None:
            raise TypeError("EcMotorDrive takes a blocking Network; use AsyncEcMotorDrive")
        aio = runner.call(lambda: AsyncEcMotorDrive(network.aio, address, **options))
        super().__init__(aio, runner)
