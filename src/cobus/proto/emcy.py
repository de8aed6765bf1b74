"""EMCY: emergency codes, the error register, producer and consumer (CiA 301).

Frame: ``80h+id [8]`` emergency error code U16 LE, error register 1001h U8, 5 bytes of
manufacturer-specific data. The producer honours the COB-ID 1014h (bit 31 = not valid, bit 29
= 29-bit identifier) and the inhibit time 1015h (100 µs units), and keeps the pre-defined error
field 1003h (newest first).
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import NamedTuple

from cobus.errors import CobusError
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto._cobid import split_cob_id
from cobus.proto.connection_set import EMCY_BASE
from cobus.proto.frame import Frame

__all__ = [
    "EMCY_BASE",
    "EmcyCobId",
    "EmcyCode",
    "EmcyConsumer",
    "EmcyError",
    "EmcyProducer",
    "EmcyQueueOverflow",
    "EmcyReceived",
    "Emergency",
    "ErrorRegister",
    "MalformedEmcy",
    "describe",
    "emcy_frame_data",
    "parse_emcy",
]

_INVALID = 1 << 31
_EXTENDED = 1 << 29
_FRAME = struct.Struct("<HB5s")


class EmcyError(CobusError, ValueError):
    """An emergency that cannot be built or an EMCY setting out of its range."""


class EmcyCode(IntEnum):
    """The emergency error codes CiA 301 defines; :attr:`text` is the standard's wording."""

    NO_ERROR = 0x0000
    GENERIC = 0x1000
    CURRENT = 0x2000
    CURRENT_INPUT = 0x2100
    CURRENT_INSIDE = 0x2200
    CURRENT_OUTPUT = 0x2300
    VOLTAGE = 0x3000
    MAINS_VOLTAGE = 0x3100
    VOLTAGE_INSIDE = 0x3200
    OUTPUT_VOLTAGE = 0x3300
    TEMPERATURE = 0x4000
    AMBIENT_TEMPERATURE = 0x4100
    DEVICE_TEMPERATURE = 0x4200
    HARDWARE = 0x5000
    SOFTWARE = 0x6000
    INTERNAL_SOFTWARE = 0x6100
    USER_SOFTWARE = 0x6200
    DATA_SET = 0x6300
    ADDITIONAL_MODULES = 0x7000
    MONITORING = 0x8000
    COMMUNICATION = 0x8100
    CAN_OVERRUN = 0x8110
    CAN_ERROR_PASSIVE = 0x8120
    LIFE_GUARD_OR_HEARTBEAT = 0x8130
    BUS_OFF_RECOVERED = 0x8140
    CAN_ID_COLLISION = 0x8150
    PROTOCOL = 0x8200
    PDO_LENGTH_ERROR = 0x8210
    PDO_LENGTH_EXCEEDED = 0x8220
    DAM_MPDO_NOT_PROCESSED = 0x8230
    UNEXPECTED_SYNC_LENGTH = 0x8240
    RPDO_TIMEOUT = 0x8250
    EXTERNAL = 0x9000
    ADDITIONAL_FUNCTIONS = 0xF000
    DEVICE_SPECIFIC = 0xFF00

    @property
    def text(self) -> str:
        """The meaning of the code as CiA 301 words it."""
        return _TEXTS[self]

    def __str__(self) -> str:
        return f"0x{self.value:04X} {_TEXTS[self]}"


def _load_codes() -> tuple[dict[int, str], dict[int, str], dict[int, str]]:
    """The code and class texts from the data file beside this module."""
    from importlib import resources

    import yaml

    text = (resources.files("cobus.proto") / "emcy_codes.yaml").read_text("utf-8")
    data = yaml.safe_load(text)
    return dict(data["codes"]), dict(data["subclasses"]), dict(data["classes"])


_TEXTS, _SUBCLASSES, _CLASSES = _load_codes()


def describe(code: int) -> str:
    """The text of an emergency error code: the CiA 301 wording of a defined code, else
    its class (``"Temperature (4310h)"``); codes of no class say so."""
    text = _TEXTS.get(code)
    if text is not None:
        return text
    if not isinstance(code, int) or not 0 <= code <= 0xFFFF:
        raise EmcyError(f"emergency error code {code!r} is not an UNSIGNED16")
    if code >> 8 == 0:
        return _SUBCLASSES[0]
    name = _SUBCLASSES.get(code >> 8) or _CLASSES.get(code >> 12)
    if name is None:
        return f"Error code {code:04X}h of no CiA 301 class (reserved)"
    return f"{name} ({code:04X}h)"


class ErrorRegister(IntFlag):
    """The error register 1001h."""

    GENERIC = 0x01
    CURRENT = 0x02
    VOLTAGE = 0x04
    TEMPERATURE = 0x08
    COMMUNICATION = 0x10
    DEVICE_PROFILE = 0x20
    RESERVED = 0x40
    MANUFACTURER = 0x80


_REGISTERS: tuple[ErrorRegister, ...] = tuple(ErrorRegister(i) for i in range(256))


class EmcyCobId(NamedTuple):
    """The 1014h value: identifier, validity (bit 31 clear) and identifier format (bit 29)."""

    can_id: int
    valid: bool = True
    extended: bool = False

    @classmethod
    def from_u32(cls, value: int) -> EmcyCobId:
        can_id, extended = split_cob_id(value, "1014h value", EmcyError)
        if value & (1 << 30):
            raise EmcyError(f"1014h value 0x{value:08X} sets reserved bit 30; it must be 0")
        return cls(can_id, not value & _INVALID, extended)

    def to_u32(self) -> int:
        """The 1014h value: identifier and flags."""
        return self.can_id | (0 if self.valid else _INVALID) | (_EXTENDED if self.extended else 0)


def emcy_frame_data(code: int, register: int, manufacturer: bytes = b"") -> bytes:
    """The 8 data bytes of an emergency."""
    if not isinstance(code, int) or not 0 <= code <= 0xFFFF:
        raise EmcyError(f"emergency error code {code!r} is not an UNSIGNED16 (0000h..FFFFh)")
    if not isinstance(register, int) or not 0 <= register <= 0xFF:
        raise EmcyError(f"error register {register!r} is not an UNSIGNED8 (00h..FFh)")
    if len(manufacturer) > 5:
        raise EmcyError(
            f"manufacturer-specific data has {len(manufacturer)} bytes; an EMCY carries at most 5"
        )
    return _FRAME.pack(code, register, bytes(manufacturer))


@dataclass(frozen=True, slots=True)
class EmcyReceived(Event):
    """An emergency from ``node_id``; ``text`` describes ``code`` (see :func:`describe`)."""

    node_id: int
    code: int
    register: ErrorRegister
    manufacturer_data: bytes
    text: str

    @property
    def is_reset(self) -> bool:
        """Whether this is an 'error reset or no error' emergency (00xxh)."""
        return self.code >> 8 == 0


@dataclass(frozen=True, slots=True)
class Emergency:
    """One emergency a node sent, as every part of cobus keeps it (a remote node's
    ``emcy``, the master's nodes' histories): ``str()`` gives ``"0x8130 Life guard error
    or heartbeat error (register 0x11)"``."""

    node_id: int
    time: float
    code: int
    register: ErrorRegister
    manufacturer_data: bytes
    text: str

    @classmethod
    def received(cls, event: EmcyReceived, time: float) -> Emergency:
        """The emergency an :class:`EmcyReceived` event reports, heard at ``time``."""
        return cls(
            event.node_id, time, event.code, event.register, event.manufacturer_data, event.text
        )

    @property
    def is_reset(self) -> bool:
        """Whether this is an "error reset or no error" emergency (00xxh)."""
        return self.code >> 8 == 0

    def __str__(self) -> str:
        return f"0x{self.code:04X} {self.text} (register 0x{int(self.register):02X})"

    def __repr__(self) -> str:
        return (
            f"<Emergency of node {self.node_id} at {self.time:.3f} s: {self}"
            f"{', data ' + self.manufacturer_data.hex(' ') if any(self.manufacturer_data) else ''}>"
        )


@dataclass(frozen=True, slots=True)
class MalformedEmcy(Event):
    """A frame on the EMCY identifier of ``node_id`` that is no emergency."""

    node_id: int
    data: bytes
    reason: str


@dataclass(frozen=True, slots=True)
class EmcyQueueOverflow(Event):
    """The inhibit-time queue was full: the emergency ``code`` was not sent (it is still in
    the 1003h history)."""

    code: int


def parse_emcy(frame: Frame, node_id: int) -> EmcyReceived | MalformedEmcy:
    """Decode an emergency frame of ``node_id`` (DLC must be 8)."""
    data = frame.data
    if frame.rtr:
        return MalformedEmcy(node_id, b"", "remote frame on an EMCY identifier")
    if len(data) != 8:
        reason = f"emergency with {len(data)} data bytes; CiA 301 emergencies carry 8"
        return MalformedEmcy(node_id, data, reason)
    code, register, manufacturer = _FRAME.unpack(data)
    return EmcyReceived(node_id, code, _REGISTERS[register], manufacturer, describe(code))


class EmcyConsumer:
    """Receives emergencies of many nodes: by default on the pre-defined 81h..FFh; other
    identifiers can be assigned per node with :meth:`set_cob_id`."""

    __slots__ = ("_ext", "_std")

    def __init__(self) -> None:
        self._std: dict[int, int] = {EMCY_BASE + n: n for n in range(1, 128)}
        self._ext: dict[int, int] = {}

    @property
    def deadline(self) -> float | None:
        return None

    def set_cob_id(self, node_id: int, can_id: int, *, extended: bool = False) -> None:
        """Receive the emergencies of ``node_id`` on ``can_id`` instead of 80h+id.

        The identifier may be the pre-defined one of another node (that node then has no
        identifier until it gets one); one assigned with this method cannot be shared."""
        _check_node(node_id)
        limit = 0x1FFFFFFF if extended else 0x7FF
        if not isinstance(can_id, int) or not 0 <= can_id <= limit:
            kind = "29-bit" if extended else "11-bit"
            raise EmcyError(f"EMCY identifier {can_id!r} does not fit an {kind} identifier")
        table = self._ext if extended else self._std
        other = table.get(can_id)
        if other is not None and other != node_id and (extended or can_id != EMCY_BASE + other):
            raise EmcyError(
                f"EMCY identifier 0x{can_id:X} is already assigned to node {other}; "
                "assign that node another identifier first"
            )
        for t in (self._std, self._ext):
            for k in [k for k, n in t.items() if n == node_id]:
                del t[k]
        table[can_id] = node_id

    def on_frame(self, frame: Frame, now: float) -> Out:
        node_id = (self._ext if frame.extended else self._std).get(frame.cob_id)
        if node_id is None:
            return NOTHING
        return Out((), (parse_emcy(frame, node_id),))

    def on_timer(self, now: float) -> Out:
        return NOTHING


def _check_node(node_id: int) -> int:
    if not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise EmcyError(f"node-ID {node_id!r} is out of range: use 1..127")
    return node_id


class EmcyProducer:
    """Sends the emergencies of one node and keeps its error register and 1003h history.

    An emergency requested during the inhibit time is queued (up to ``queue_size``) and sent
    when the inhibit time ends. Whether EMCY may be sent in the current NMT state is the
    owner's call: use :meth:`record` instead of :meth:`send` when it may not.
    """

    __slots__ = (
        "_deadline",
        "_history",
        "_inhibit",
        "_next_free",
        "_queue",
        "can_id",
        "depth",
        "error_register",
        "extended",
        "inhibit_100us",
        "node_id",
        "queue_size",
        "valid",
    )

    def __init__(self, node_id: int, *, depth: int = 8, queue_size: int = 16) -> None:
        self.node_id = _check_node(node_id)
        if not isinstance(depth, int) or not 0 <= depth <= 254:
            raise EmcyError(f"1003h depth {depth!r} is out of range: use 0 (no history)..254")
        if not isinstance(queue_size, int) or queue_size < 1:
            raise EmcyError(f"EMCY queue size {queue_size!r} must be at least 1")
        self.depth = depth
        self.queue_size = queue_size
        self.can_id = EMCY_BASE + node_id
        self.valid = True
        self.extended = False
        self.inhibit_100us = 0
        self._inhibit = 0.0
        self._next_free = float("-inf")
        self._queue: deque[bytes] = deque()
        self._deadline: float | None = None
        self._history: deque[int] = deque(maxlen=depth or 1)
        self.error_register = ErrorRegister(0)

    @property
    def deadline(self) -> float | None:
        return self._deadline

    @property
    def cob_id(self) -> int:
        """The 1014h value."""
        return EmcyCobId(self.can_id, self.valid, self.extended).to_u32()

    def set_cob_id(self, value: int) -> None:
        """Write 1014h (bit 31 set = no emergencies are sent)."""
        new = EmcyCobId.from_u32(value)
        self.can_id, self.valid, self.extended = new
        if not self.valid:
            self._queue.clear()
            self._deadline = None

    def set_inhibit_time(self, units_100us: int, now: float) -> None:
        """Write 1015h: the minimum gap between emergencies in 100 µs units (0 = none)."""
        if not isinstance(units_100us, int) or not 0 <= units_100us <= 0xFFFF:
            raise EmcyError(
                f"EMCY inhibit time (1015h) {units_100us!r} is out of range: use 0..65535 x 100 µs"
            )
        if self._inhibit and self._next_free > now:
            # the running inhibit period keeps its start; only its length changes
            self._next_free += units_100us / 10_000 - self._inhibit
            if self._queue:
                self._deadline = self._next_free
        self.inhibit_100us = units_100us
        self._inhibit = units_100us / 10_000

    @property
    def history(self) -> tuple[int, ...]:
        """1003h sub 1.. : the errors recorded, newest first (code | info << 16)."""
        return tuple(self._history) if self.depth else ()

    def error_field(self, sub: int) -> int:
        """Read 1003h sub ``sub`` (0 = number of errors recorded)."""
        if sub == 0:
            return len(self.history)
        if not isinstance(sub, int) or not 1 <= sub <= max(self.depth, 1) or not self.depth:
            raise EmcyError(f"1003h has sub-indexes 0..{self.depth}, not {sub!r}")
        history = self.history
        if sub > len(history):
            raise EmcyError(
                f"1003h sub {sub} holds no error: only {len(history)} are recorded (sub 0)"
            )
        return history[sub - 1]

    def write_error_count(self, value: int) -> None:
        """Write 1003h sub 0: only 0 is allowed, and it clears the history."""
        if value != 0:
            raise EmcyError(
                f"1003h sub 0 accepts only 0 (clear the history), not {value!r} "
                "(CiA 301: abort 06090030)"
            )
        self._history.clear()

    def record(self, code: int, info: int = 0) -> None:
        """Put an error into the 1003h history without sending it."""
        if not isinstance(info, int) or not 0 <= info <= 0xFFFF:
            raise EmcyError(f"1003h additional information {info!r} is not an UNSIGNED16")
        if not isinstance(code, int) or not 0 <= code <= 0xFFFF:
            raise EmcyError(f"emergency error code {code!r} is not an UNSIGNED16 (0000h..FFFFh)")
        if code and self.depth:
            self._history.appendleft(code | info << 16)

    def send(
        self,
        code: int,
        register: ErrorRegister | int,
        manufacturer: bytes,
        now: float,
        *,
        info: int = 0,
    ) -> Out:
        """Report an error: record it in 1003h (``info`` = the 16-bit additional
        information there), set the error register and send, now or when the inhibit time
        ends."""
        data = emcy_frame_data(code, register, manufacturer)
        self.record(code, info)
        self.error_register = ErrorRegister(register)
        return self._emit(data, now)

    def reset(
        self, now: float, register: ErrorRegister | int = 0, manufacturer: bytes = b""
    ) -> Out:
        """Send the 'error reset' emergency (0000h) with the error register after reset."""
        data = emcy_frame_data(0, register, manufacturer)
        self.error_register = ErrorRegister(register)
        return self._emit(data, now)

    def _emit(self, data: bytes, now: float) -> Out:
        if not self.valid:
            return NOTHING
        if self._queue or now < self._next_free:
            if len(self._queue) >= self.queue_size:
                code = data[0] | data[1] << 8
                return Out((), (EmcyQueueOverflow(code),))
            self._queue.append(data)
            self._deadline = self._next_free
            return NOTHING
        self._next_free = now + self._inhibit
        return Out((Frame(self.can_id, data, extended=self.extended),), ())

    def on_frame(self, frame: Frame, now: float) -> Out:
        return NOTHING

    def on_timer(self, now: float) -> Out:
        if not self._queue or now < self._next_free:
            return NOTHING
        data = self._queue.popleft()
        self._next_free = now + self._inhibit
        self._deadline = self._next_free if self._queue else None
        return Out((Frame(self.can_id, data, extended=self.extended),), ())
