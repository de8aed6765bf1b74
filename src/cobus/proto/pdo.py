"""PDO: mapping codec, COB-ID and transmission types, TPDO trigger, RPDO watchdog (CiA 301).

A mapping entry (1600h/1A00h sub n) is ``index << 16 | subindex << 8 | bit length``. The
mapped objects are laid out from bit 0 of byte 0 upwards, each little-endian, without gaps;
entries with a data-type index 0001h..0007h are dummies that only take room. :class:`PdoMap`
compiles a mapping once and packs/unpacks values fast; it does not know the object
dictionary: the caller gives each entry a :class:`Kind` or a :class:`FieldCodec`.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any, Final, NamedTuple, Protocol, TypeVar

from cobus.errors import CobusError
from cobus.od import DataType  # (od is below proto: the data types, no protocol)
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto._cobid import split_cob_id
from cobus.proto.connection_set import PDO_STEP, RPDO_BASE, TPDO_BASE
from cobus.proto.frame import Frame

__all__ = [
    "MAX_PDO_BITS",
    "MAX_PDO_ENTRIES",
    "REMAP_ORDER",
    "FieldCodec",
    "Kind",
    "MappingEntry",
    "PdoCobId",
    "PdoError",
    "PdoLengthError",
    "PdoMap",
    "RemapStep",
    "RpdoResumed",
    "RpdoTimeout",
    "RpdoTooLong",
    "RpdoTooShort",
    "RpdoWatchdog",
    "TpdoDue",
    "TpdoReason",
    "TpdoSample",
    "TpdoTrigger",
    "TransmissionType",
    "in_remap_order",
    "is_restricted_can_id",
    "kind_of_type",
    "rpdo_default_can_id",
    "tpdo_default_can_id",
]

MAX_PDO_BITS = 64
MAX_PDO_ENTRIES = 64
_INVALID = 1 << 31
_NO_RTR = 1 << 30
_EXTENDED = 1 << 29


class PdoError(CobusError, ValueError):
    """A PDO mapping, setting or value that cannot be used."""


class PdoLengthError(PdoError):
    """A received PDO shorter than its mapping (CiA 301: not processed, EMCY 8210h)."""

    def __init__(self, expected: int, received: int) -> None:
        super().__init__(
            f"PDO carries {received} bytes but its mapping needs {expected}: the producer's "
            "mapping and this one differ; align them (EMCY 8210h)"
        )
        self.expected = expected
        self.received = received


# --- mapping entries --------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class MappingEntry:
    """One mapped object: ``index:subindex`` with ``bit_length`` bits."""

    index: int
    subindex: int
    bit_length: int

    def __post_init__(self) -> None:
        if not isinstance(self.index, int) or not 0 <= self.index <= 0xFFFF:
            raise PdoError(f"mapping entry index {self.index!r} is not 0000h..FFFFh")
        if not isinstance(self.subindex, int) or not 0 <= self.subindex <= 0xFF:
            raise PdoError(f"mapping entry sub-index {self.subindex!r} is not 00h..FFh")
        if not isinstance(self.bit_length, int) or not 0 <= self.bit_length <= 0xFF:
            raise PdoError(f"mapping entry bit length {self.bit_length!r} is not 0..255")

    @property
    def is_dummy(self) -> bool:
        """Whether this is a dummy entry (a data-type index 0001h..0007h)."""
        return 0x0001 <= self.index <= 0x0007

    def to_u32(self) -> int:
        """The mapping entry as the UNSIGNED32 of 1600h/1A00h: index, sub-index, bits."""
        return self.index << 16 | self.subindex << 8 | self.bit_length

    @classmethod
    def from_u32(cls, value: int) -> MappingEntry:
        if not isinstance(value, int) or not 0 <= value <= 0xFFFFFFFF:
            raise PdoError(f"mapping entry {value!r} is not an UNSIGNED32")
        return cls(value >> 16, (value >> 8) & 0xFF, value & 0xFF)

    def __repr__(self) -> str:
        return f"MappingEntry({self.index:04X}h:{self.subindex:02X}h, {self.bit_length} bits)"


class Kind(Enum):
    """How a mapped value is represented in python."""

    SIGNED = "signed int"
    UNSIGNED = "unsigned int"
    BOOL = "bool"
    REAL32 = "real32"
    REAL64 = "real64"
    BYTES = "bytes"


def kind_of_type(data_type: DataType) -> Kind | None:
    """The :class:`Kind` a mapped object of ``data_type`` is carried as: integers (a
    truncated mapping too) signed or unsigned, BOOLEAN a bool, REAL32/REAL64 floats (at
    their own length: :class:`PdoMap` refuses another), OCTET_STRING and DOMAIN bytes.

    None: no Kind carries the type (the strings, TIME_OF_DAY, TIME_DIFFERENCE...); the caller
    says how: a remote node's PDOs and a device decode it with its type (a
    :class:`FieldCodec`), the master's process image keeps its bytes. The one rule of remote
    PDOs, the device's PDOs and the network file."""
    if data_type is DataType.BOOLEAN:
        return Kind.BOOL
    if data_type.is_integer:
        return Kind.SIGNED if data_type.is_signed else Kind.UNSIGNED
    return _KIND_OF_TYPE.get(data_type)


_KIND_OF_TYPE: Final = {
    DataType.REAL32: Kind.REAL32,
    DataType.REAL64: Kind.REAL64,
    DataType.OCTET_STRING: Kind.BYTES,
    DataType.DOMAIN: Kind.BYTES,
}


class RemapStep(Enum):
    """One kind of write of the CiA 301 procedure that (re)configures a PDO over SDO."""

    #: COB-ID with bit 31 set: the PDO no longer exists, its parameters may change.
    DISABLE = "disable"
    #: Mapping sub-index 0 = 0: the entries may change.
    CLEAR_MAPPING = "clear mapping"
    #: The mapping entries, sub-index 1 on.
    MAP = "map"
    #: Mapping sub-index 0 = the number of entries: the mapping is valid again.
    COUNT = "mapped objects"
    #: Transmission type, inhibit time, event timer, SYNC start value (while disabled).
    COMMUNICATION = "communication"
    #: COB-ID with bit 31 clear: the PDO exists again.
    ENABLE = "enable"


#: The order the writes of a PDO (re)configuration go in: disable, clear the mapping, map,
#: count, communication parameters, enable (CiA 301 7.5.2.35/36: the mapping changes only
#: while the PDO is disabled and its count is 0).
REMAP_ORDER: Final[tuple[RemapStep, ...]] = (
    RemapStep.DISABLE,
    RemapStep.CLEAR_MAPPING,
    RemapStep.MAP,
    RemapStep.COUNT,
    RemapStep.COMMUNICATION,
    RemapStep.ENABLE,
)
_RANK: Final = {step: rank for rank, step in enumerate(REMAP_ORDER)}
_T = TypeVar("_T")


def in_remap_order(steps: Sequence[tuple[RemapStep, _T]]) -> list[_T]:
    """The writes of ``steps`` in :data:`REMAP_ORDER` (writes of one step keep their order)."""
    return [write for _, write in sorted(steps, key=lambda step: _RANK[step[0]])]


class FieldCodec(Protocol):
    """A custom value codec: python value <-> the raw unsigned bits of the field."""

    def encode(self, value: Any, bits: int) -> int:
        """The raw bits (0 <= raw < 2**bits) of ``value``."""
        ...

    def decode(self, raw: int, bits: int) -> Any:
        """The python value of the raw bits."""
        ...


_F32 = struct.Struct("<f")
_U32 = struct.Struct("<I")
_F64 = struct.Struct("<d")
_U64 = struct.Struct("<Q")
_STRUCT_CODES: dict[Kind, dict[int, str]] = {
    Kind.SIGNED: {8: "b", 16: "h", 32: "i", 64: "q"},
    Kind.UNSIGNED: {8: "B", 16: "H", 32: "I", 64: "Q"},
    Kind.BOOL: {8: "?"},
    Kind.REAL32: {32: "f"},
    Kind.REAL64: {64: "d"},
}

_Encoder = Callable[[Any], int]
_Decoder = Callable[[int], Any] | None


def _make_codec(entry: MappingEntry, kind: Kind | FieldCodec) -> tuple[_Encoder, _Decoder]:
    bits = entry.bit_length
    mask = (1 << bits) - 1
    where = repr(entry)

    if not isinstance(kind, Kind):
        codec = kind

        def enc_custom(value: Any) -> int:
            raw = codec.encode(value, bits)
            if not isinstance(raw, int) or not 0 <= raw <= mask:
                raise PdoError(
                    f"{where}: the codec encoded {value!r} as {raw!r}, not {bits} raw bits"
                )
            return raw

        def dec_custom(raw: int) -> Any:
            return codec.decode(raw, bits)

        return enc_custom, dec_custom

    if kind is Kind.UNSIGNED:

        def enc_unsigned(value: Any) -> int:
            if not isinstance(value, int) or not 0 <= value <= mask:
                raise PdoError(f"{where}: {value!r} is not an unsigned {bits}-bit integer")
            return value

        return enc_unsigned, None

    if kind is Kind.SIGNED:
        low, high, sign = -(1 << (bits - 1)), (1 << (bits - 1)) - 1, 1 << (bits - 1)

        def enc_signed(value: Any) -> int:
            if not isinstance(value, int) or not low <= value <= high:
                raise PdoError(f"{where}: {value!r} is not a signed {bits}-bit integer")
            return value & mask

        def dec_signed(raw: int) -> int:
            return raw - (sign << 1) if raw & sign else raw

        return enc_signed, dec_signed

    if kind is Kind.BOOL:

        def enc_bool(value: Any) -> int:
            return 1 if value else 0

        return enc_bool, bool

    if kind is Kind.BYTES:
        if bits % 8:
            raise PdoError(f"{where}: a bytes value needs a multiple of 8 bits, not {bits}")
        size = bits // 8

        def enc_bytes(value: Any) -> int:
            if not isinstance(value, bytes | bytearray) or len(value) > size:
                raise PdoError(f"{where}: {value!r} is not bytes of at most {size}")
            return int.from_bytes(value, "little")

        def dec_bytes(raw: int) -> bytes:
            return raw.to_bytes(size, "little")

        return enc_bytes, dec_bytes

    real, raw_struct, need = (_F32, _U32, 32) if kind is Kind.REAL32 else (_F64, _U64, 64)
    if bits != need:
        raise PdoError(f"{where}: a {kind.value} value takes {need} bits, not {bits}")

    def enc_real(value: Any) -> int:
        try:
            packed = real.pack(value)
        except (struct.error, OverflowError) as exc:
            raise PdoError(f"{where}: {value!r} is not a {kind.value}: {exc}") from None
        result: int = raw_struct.unpack(packed)[0]
        return result

    def dec_real(raw: int) -> float:
        result: float = real.unpack(raw_struct.pack(raw))[0]
        return result

    return enc_real, dec_real


class PdoMap:
    """A compiled PDO mapping: ``pack(values) -> bytes`` and ``unpack(data) -> values``.

    ``fields`` pairs each :class:`MappingEntry` with a :class:`Kind` or a
    :class:`FieldCodec`; dummy entries take ``None`` (any kind given is ignored). Values are
    those of the non-dummy entries, in mapping order. At most 64 entries and 64 bits.
    """

    __slots__ = (
        "_bytes_checks",
        "_decoders",
        "_encoders",
        "_struct",
        "bit_length",
        "entries",
        "length",
        "value_count",
    )

    def __init__(self, fields: Sequence[tuple[MappingEntry, Kind | FieldCodec | None]]) -> None:
        if len(fields) > MAX_PDO_ENTRIES:
            raise PdoError(
                f"a PDO maps at most {MAX_PDO_ENTRIES} objects, this mapping has {len(fields)}"
            )
        self.entries = tuple(entry for entry, _ in fields)
        total = sum(e.bit_length for e in self.entries)
        if total > MAX_PDO_BITS:
            listing = ", ".join(
                f"{e.index:04X}h:{e.subindex:02X}h={e.bit_length}" for e in self.entries
            )
            raise PdoError(
                f"the mapping takes {total} bits but a PDO carries at most {MAX_PDO_BITS} "
                f"({listing}); remove or shorten entries (CiA 301: abort 06040042)"
            )
        self.bit_length = total
        self.length = (total + 7) // 8
        encoders: list[tuple[int, _Encoder]] = []
        decoders: list[tuple[int, int, _Decoder]] = []
        codes = ["<"]
        aligned = True
        bytes_checks: list[tuple[int, int, MappingEntry]] = []
        offset = 0
        for entry, kind in fields:
            bits = entry.bit_length
            if bits == 0:
                raise PdoError(f"{entry!r}: a mapped object needs at least 1 bit")
            if entry.is_dummy:
                if bits % 8:
                    aligned = False
                else:
                    codes.append(f"{bits // 8}x")
            else:
                if kind is None:
                    raise PdoError(f"{entry!r} needs a Kind or a codec to turn bits into values")
                enc, dec = _make_codec(entry, kind)
                encoders.append((offset, enc))
                decoders.append((offset, (1 << bits) - 1, dec))
                code: str | None = None
                if isinstance(kind, Kind):
                    if kind is Kind.BYTES:
                        code = f"{bits // 8}s"
                        bytes_checks.append((len(encoders) - 1, bits // 8, entry))
                    else:
                        code = _STRUCT_CODES[kind].get(bits)
                if code is None:
                    aligned = False
                else:
                    codes.append(code)
            offset += bits
        self.value_count = len(encoders)
        self._encoders = tuple(encoders)
        self._decoders = tuple(decoders)
        self._bytes_checks = tuple(bytes_checks)
        self._struct = struct.Struct("".join(codes)) if aligned else None

    @property
    def byte_aligned(self) -> bool:
        """Whether packing uses the single-struct fast path; then :meth:`unpack` cannot fail
        on data of the mapping's length (no value has a decoder that could refuse it), which
        a receiver may rely on to decode only when asked."""
        return self._struct is not None

    def pack(self, values: Sequence[Any]) -> bytes:
        """The PDO data bytes of ``values`` (one per non-dummy entry, in order)."""
        if len(values) != self.value_count:
            raise PdoError(
                f"the mapping has {self.value_count} values (dummies excluded), got {len(values)}"
            )
        st = self._struct
        if st is not None:
            for i, size, entry in self._bytes_checks:
                v = values[i]
                if not isinstance(v, bytes | bytearray) or len(v) > size:
                    raise PdoError(f"{entry!r}: {v!r} is not bytes of at most {size}")
            try:
                return st.pack(*values)
            except (struct.error, OverflowError, TypeError) as exc:
                for (_, enc), v in zip(self._encoders, values, strict=True):
                    enc(v)  # raises the precise error
                raise PdoError(f"cannot pack {values!r}: {exc}") from exc
        raw = 0
        for (shift, enc), v in zip(self._encoders, values, strict=True):
            raw |= enc(v) << shift
        return raw.to_bytes(self.length, "little")

    def unpack(self, data: bytes) -> tuple[Any, ...]:
        """The values in ``data``; extra bytes beyond the mapping are ignored (CiA 301)."""
        if len(data) < self.length:
            raise PdoLengthError(self.length, len(data))
        st = self._struct
        if st is not None:
            return st.unpack_from(data)
        raw = int.from_bytes(data, "little")
        out: list[Any] = []
        for shift, mask, dec in self._decoders:
            v = (raw >> shift) & mask
            out.append(v if dec is None else dec(v))
        return tuple(out)


# --- COB-IDs ------------------------------------------------------------------------------


class PdoCobId(NamedTuple):
    """1400h/1800h sub 1: identifier, valid (bit 31 clear), RTR allowed (bit 30 clear),
    29-bit identifier (bit 29)."""

    can_id: int
    valid: bool = True
    rtr_allowed: bool = True
    extended: bool = False

    @classmethod
    def from_u32(cls, value: int) -> PdoCobId:
        can_id, extended = split_cob_id(value, "PDO COB-ID", PdoError)
        return cls(can_id, not value & _INVALID, not value & _NO_RTR, extended)

    def to_u32(self) -> int:
        """The 1400h/1800h sub 1 value: identifier and flags."""
        return (
            self.can_id
            | (0 if self.valid else _INVALID)
            | (0 if self.rtr_allowed else _NO_RTR)
            | (_EXTENDED if self.extended else 0)
        )

    def __str__(self) -> str:
        flags = [
            "valid" if self.valid else "invalid",
            "RTR" if self.rtr_allowed else "no RTR",
            "29-bit" if self.extended else "11-bit",
        ]
        width = 8 if self.extended else 3
        return f"{self.can_id:0{width}X}h ({', '.join(flags)})"


_RESTRICTED = (
    (0x000, 0x000),
    (0x001, 0x07F),
    (0x101, 0x180),
    (0x581, 0x5FF),
    (0x601, 0x67F),
    (0x6E0, 0x6FF),
    (0x701, 0x77F),
    (0x780, 0x7FF),
)


def is_restricted_can_id(can_id: int) -> bool:
    """Whether an 11-bit identifier is restricted by CiA 301 (NMT, SDO, error control,
    reserved) and so cannot be a PDO's."""
    return any(low <= can_id <= high for low, high in _RESTRICTED)


def _default_can_id(base: int, number: int, node_id: int) -> int:
    if not isinstance(number, int) or not 1 <= number <= 4:
        raise PdoError(f"the pre-defined connection set covers PDO 1..4, not {number!r}")
    if not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise PdoError(f"node-ID {node_id!r} is out of range: use 1..127")
    return base + PDO_STEP * (number - 1) + node_id


def tpdo_default_can_id(number: int, node_id: int) -> int:
    """The pre-defined identifier of TPDO ``number`` (1..4): 180h/280h/380h/480h + id."""
    return _default_can_id(TPDO_BASE, number, node_id)


def rpdo_default_can_id(number: int, node_id: int) -> int:
    """The pre-defined identifier of RPDO ``number`` (1..4): 200h/300h/400h/500h + id."""
    return _default_can_id(RPDO_BASE, number, node_id)


# --- transmission types -------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TransmissionType:
    """1400h/1800h sub 2. 0 acyclic synchronous, 1-240 every n-th SYNC, 241-251 reserved,
    252 RTR-only synchronous, 253 RTR-only event-driven, 254 manufacturer event,
    255 profile event."""

    value: int

    def __post_init__(self) -> None:
        v = self.value
        if not isinstance(v, int) or not 0 <= v <= 255:
            raise PdoError(f"PDO transmission type {v!r} is not 0..255")
        if 241 <= v <= 251:
            raise PdoError(
                f"PDO transmission type {v} is reserved: use 0, 1..240, 252, 253, 254 or 255"
            )

    @property
    def acyclic(self) -> bool:
        """Type 0: synchronous, sent at SYNC only when the data changed."""
        return self.value == 0

    @property
    def cyclic(self) -> bool:
        """Types 1..240: sent every n-th SYNC."""
        return 1 <= self.value <= 240

    @property
    def every(self) -> int | None:
        """n of a cyclic type (every n-th SYNC)."""
        return self.value if 1 <= self.value <= 240 else None

    @property
    def synchronous(self) -> bool:
        """Types 0..240 and 252: tied to SYNC."""
        return self.value <= 240 or self.value == 252

    @property
    def rtr_only(self) -> bool:
        """Types 252 and 253: sent only on a remote request."""
        return self.value in (252, 253)

    @property
    def event_driven(self) -> bool:
        """Types 254 and 255: sent on an event (change, event timer)."""
        return self.value >= 254

    @property
    def valid_for_rpdo(self) -> bool:
        """RPDOs use 0..240 (apply at the next SYNC) and 254/255 (apply at once)."""
        return self.value <= 240 or self.value >= 254


# --- TPDO trigger --------------------------------------------------------------------------


class TpdoReason(Enum):
    """Why a TPDO is due."""

    SYNC = "SYNC"
    EVENT = "event"
    TIMER = "event timer"
    RTR = "remote request"


@dataclass(frozen=True, slots=True)
class TpdoDue(Event):
    """Send the TPDO now (sample the mapped values, except for type 252: send the sample)."""

    reason: TpdoReason


@dataclass(frozen=True, slots=True)
class TpdoSample(Event):
    """Type 252: sample the mapped values now (this SYNC); send them on the next RTR."""


_DUE: dict[TpdoReason, Out] = {r: Out((), (TpdoDue(r),)) for r in TpdoReason}
_SAMPLE = Out((), (TpdoSample(),))


def _check_u16(value: int, what: str) -> int:
    if not isinstance(value, int) or not 0 <= value <= 0xFFFF:
        raise PdoError(f"{what} {value!r} is out of range: use 0..65535")
    return value


class TpdoTrigger:
    """When a TPDO must be sent, from its communication parameters (1800h subs 2, 3, 5, 6).

    Inputs: :meth:`on_sync`, :meth:`on_change` (a mapped value changed), :meth:`on_rtr` and
    timers; output: :class:`TpdoDue` (and :class:`TpdoSample` for type 252). Inhibit time
    and event timer apply to the event-driven types 254/255: a send requested within the
    inhibit time happens at its end, and the event timer restarts with each send. A cyclic
    type with a SYNC start value waits for the SYNC whose counter equals it. Inputs are
    ignored until :meth:`start` (the PDO is valid and the node operational).
    """

    __slots__ = (
        "_active",
        "_changed",
        "_count",
        "_event_timer",
        "_inhibit",
        "_next_free",
        "_pending",
        "_timer_at",
        "_waiting_start",
        "event_timer_ms",
        "inhibit_time_100us",
        "sync_start_value",
        "transmission_type",
    )

    def __init__(
        self,
        transmission_type: int | TransmissionType,
        inhibit_time_100us: int = 0,
        event_timer_ms: int = 0,
        sync_start_value: int = 0,
    ) -> None:
        if not isinstance(transmission_type, TransmissionType):
            transmission_type = TransmissionType(transmission_type)
        self.transmission_type = transmission_type
        self.inhibit_time_100us = _check_u16(inhibit_time_100us, "TPDO inhibit time (100 µs)")
        self.event_timer_ms = _check_u16(event_timer_ms, "TPDO event timer (ms)")
        if not isinstance(sync_start_value, int) or not 0 <= sync_start_value <= 240:
            raise PdoError(f"SYNC start value {sync_start_value!r} is out of range: use 0..240")
        self.sync_start_value = sync_start_value
        self._inhibit = inhibit_time_100us / 10_000
        self._event_timer = event_timer_ms / 1000
        self._active = False
        self._changed = False
        self._count = 0
        self._waiting_start = False
        self._next_free = float("-inf")
        self._pending: TpdoReason | None = None
        self._timer_at: float | None = None

    @property
    def active(self) -> bool:
        """Whether the trigger runs (the device is OPERATIONAL)."""
        return self._active

    @property
    def deadline(self) -> float | None:
        """When the event timer or the end of the inhibit time fires next (None: nothing armed)."""
        if not self._active:
            return None
        timer_at = self._timer_at
        if self._pending is not None and (timer_at is None or self._next_free < timer_at):
            return self._next_free
        return timer_at

    def start(self, now: float) -> None:
        """Start (PDO valid, node operational): counters restart, the event timer runs."""
        tt = self.transmission_type
        self._active = True
        self._changed = False
        self._count = tt.value if tt.cyclic else 0
        self._waiting_start = tt.cyclic and self.sync_start_value != 0
        self._next_free = float("-inf")
        self._pending = None
        self._timer_at = now + self._event_timer if tt.event_driven and self._event_timer else None

    def stop(self) -> None:
        """Stop: no sends until :meth:`start`."""
        self._active = False
        self._pending = None
        self._timer_at = None

    def on_sync(self, counter: int | None, now: float) -> Out:
        """A SYNC with ``counter`` arrived: :class:`TpdoDue` when the transmission type says so."""
        if not self._active:
            return NOTHING
        tt = self.transmission_type.value
        if tt == 0:
            if self._changed:
                self._changed = False
                return _DUE[TpdoReason.SYNC]
            return NOTHING
        if tt <= 240:
            if self._waiting_start:
                if counter is not None:
                    if counter != self.sync_start_value:
                        return NOTHING
                    self._waiting_start = False
                    self._count = tt
                    return _DUE[TpdoReason.SYNC]
                # a SYNC without counter: the start value does not apply
                self._waiting_start = False
            self._count -= 1
            if self._count <= 0:
                self._count = tt
                return _DUE[TpdoReason.SYNC]
            return NOTHING
        if tt == 252:
            return _SAMPLE
        return NOTHING

    def on_change(self, now: float) -> Out:
        """A mapped value changed (type 0: send at the next SYNC; 254/255: send now)."""
        if not self._active:
            return NOTHING
        tt = self.transmission_type
        if tt.event_driven:
            return self._request(now, TpdoReason.EVENT)
        if tt.acyclic:
            self._changed = True
        return NOTHING

    def on_rtr(self, now: float) -> Out:
        """A remote request for this TPDO arrived (allowed by its COB-ID bit 30)."""
        if not self._active:
            return NOTHING
        if self.transmission_type.event_driven:
            return self._request(now, TpdoReason.RTR)
        return _DUE[TpdoReason.RTR]

    def _request(self, now: float, reason: TpdoReason) -> Out:
        if now >= self._next_free:
            return self._send(now, reason)
        if self._pending is None:
            self._pending = reason
        return NOTHING

    def _send(self, now: float, reason: TpdoReason) -> Out:
        self._pending = None
        self._next_free = now + self._inhibit
        if self._event_timer:
            self._timer_at = now + self._event_timer
        return _DUE[reason]

    def on_timer(self, now: float) -> Out:
        """The event timer or the end of the inhibit time: :class:`TpdoDue` when due."""
        if not self._active:
            return NOTHING
        if now < self._next_free:
            if self._timer_at is not None and now >= self._timer_at:
                self._timer_at = None
                if self._pending is None:
                    self._pending = TpdoReason.TIMER
            return NOTHING
        if self._pending is not None:
            return self._send(now, self._pending)
        if self._timer_at is not None and now >= self._timer_at:
            return self._send(now, TpdoReason.TIMER)
        return NOTHING


# --- RPDO watchdog -------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RpdoTimeout(Event):
    """RPDO ``cob_id`` did not arrive within its event timer (once per loss; EMCY 8250h)."""

    cob_id: int


@dataclass(frozen=True, slots=True)
class RpdoResumed(Event):
    """RPDO ``cob_id`` arrives again after :class:`RpdoTimeout`."""

    cob_id: int


@dataclass(frozen=True, slots=True)
class RpdoTooShort(Event):
    """RPDO ``cob_id`` is shorter than its mapping: not processed (EMCY 8210h)."""

    cob_id: int
    expected: int
    received: int


@dataclass(frozen=True, slots=True)
class RpdoTooLong(Event):
    """RPDO ``cob_id`` is longer than its mapping: processed, but reported (EMCY 8220h)."""

    cob_id: int
    expected: int
    received: int


class RpdoWatchdog:
    """Watches one RPDO: its arrival (event timer 1400h sub 5, ms; 0 = off) and its length.

    The watchdog arms with the first RPDO received. ``length`` is the mapping's length in
    bytes (None: not checked); a too short RPDO does not count as an arrival.
    """

    __slots__ = ("_expiry", "_lost", "_timer", "cob_id", "event_timer_ms", "extended", "length")

    def __init__(
        self,
        cob_id: int,
        event_timer_ms: int = 0,
        *,
        extended: bool = False,
        length: int | None = None,
    ) -> None:
        limit = 0x1FFFFFFF if extended else 0x7FF
        if not isinstance(cob_id, int) or not 0 <= cob_id <= limit:
            kind = "29-bit" if extended else "11-bit"
            raise PdoError(f"RPDO identifier {cob_id!r} does not fit an {kind} identifier")
        if length is not None and (not isinstance(length, int) or not 0 <= length <= 8):
            raise PdoError(f"RPDO length {length!r} must be 0..8 bytes")
        self.cob_id = cob_id
        self.extended = extended
        self.length = length
        self.event_timer_ms = 0
        self._timer = 0.0
        self._expiry: float | None = None
        self._lost = False
        self.set_event_timer(event_timer_ms, 0.0)

    @property
    def deadline(self) -> float | None:
        return self._expiry

    @property
    def lost(self) -> bool:
        """Whether the RPDO missed its event-timer deadline and has not arrived since."""
        return self._lost

    def set_event_timer(self, ms: int, now: float) -> None:
        """Write 1400h sub 5: 0 turns the watchdog off; a running one restarts at ``now``."""
        self.event_timer_ms = _check_u16(ms, "RPDO event timer (ms)")
        self._timer = ms / 1000
        if not ms:
            self._expiry = None
            self._lost = False
        elif self._expiry is not None:
            self._expiry = now + self._timer

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.cob_id != self.cob_id or frame.rtr or frame.extended != self.extended:
            return NOTHING
        n = len(frame.data)
        length = self.length
        if length is not None and n < length:
            return Out((), (RpdoTooShort(self.cob_id, length, n),))
        if self._timer:
            self._expiry = now + self._timer
        if not self._lost and (length is None or n == length):
            return NOTHING
        events: list[Event] = []
        if self._lost:
            self._lost = False
            events.append(RpdoResumed(self.cob_id))
        if length is not None and n > length:
            events.append(RpdoTooLong(self.cob_id, length, n))
        return Out((), tuple(events))

    def on_timer(self, now: float) -> Out:
        expiry = self._expiry
        if expiry is None or now < expiry:
            return NOTHING
        self._expiry = None
        self._lost = True
        return Out((), (RpdoTimeout(self.cob_id),))
