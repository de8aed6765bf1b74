"""The CiA 301 basic data types and their exact little-endian encoding.

``encode``/``decode`` are hot paths (one call per mapped object per PDO frame): every codec is
a closure built once at import over a precompiled :class:`struct.Struct` or ``int`` method, and
the dispatch is one dict lookup. Errors are only assembled on the failure path.
"""

from __future__ import annotations

import datetime as _dt
import math
import operator
import struct
from collections.abc import Callable
from typing import Any, NamedTuple, TypeAlias

from cobus._enum import NamedIntEnum
from cobus.od._errors import DataLengthError, DataTypeError, ValueRangeError

__all__ = [
    "DataType",
    "TimeDifference",
    "TimeOfDay",
    "Value",
    "data_type_named",
    "decode",
    "encode",
    "struct_unpacker",
]


class DataType(NamedIntEnum):
    """CiA 301 basic data types, numbered by their index in the object dictionary."""

    BOOLEAN = 0x01
    INTEGER8 = 0x02
    INTEGER16 = 0x03
    INTEGER32 = 0x04
    UNSIGNED8 = 0x05
    UNSIGNED16 = 0x06
    UNSIGNED32 = 0x07
    REAL32 = 0x08
    VISIBLE_STRING = 0x09
    OCTET_STRING = 0x0A
    UNICODE_STRING = 0x0B
    TIME_OF_DAY = 0x0C
    TIME_DIFFERENCE = 0x0D
    DOMAIN = 0x0F
    INTEGER24 = 0x10
    REAL64 = 0x11
    INTEGER40 = 0x12
    INTEGER48 = 0x13
    INTEGER56 = 0x14
    INTEGER64 = 0x15
    UNSIGNED24 = 0x16
    UNSIGNED40 = 0x18
    UNSIGNED48 = 0x19
    UNSIGNED56 = 0x1A
    UNSIGNED64 = 0x1B

    @property
    def bit_length(self) -> int | None:  # type: ignore[override]
        """Bits the type occupies in a PDO (BOOLEAN: 1); None for variable-length types."""
        return _BIT_LENGTH[self]

    @property
    def size(self) -> int | None:
        """Bytes of an SDO transfer of the value (BOOLEAN: 1); None for variable length."""
        return _SIZE[self]

    @property
    def is_integer(self) -> bool:
        """INTEGERn and UNSIGNEDn (not BOOLEAN)."""
        return self in _INT_RANGE

    @property
    def is_signed(self) -> bool:
        """The signed integer types INTEGERn."""
        return self in _SIGNED

    @property
    def is_real(self) -> bool:
        return self is DataType.REAL32 or self is DataType.REAL64

    @property
    def is_string(self) -> bool:
        """VISIBLE_STRING, OCTET_STRING and UNICODE_STRING."""
        return self in _STRINGS

    @property
    def range(self) -> tuple[int, int] | None:
        """Smallest and largest value of an integer type; None for other types."""
        return _INT_RANGE.get(self)


class TimeOfDay(NamedTuple):
    """TIME_OF_DAY: days since 1984-01-01 and milliseconds after midnight."""

    days: int
    milliseconds: int

    def to_datetime(self) -> _dt.datetime:
        return EPOCH + _dt.timedelta(days=self.days, milliseconds=self.milliseconds)

    @classmethod
    def from_datetime(cls, moment: _dt.datetime) -> TimeOfDay:
        """The time of day of a naive datetime (or of an aware one, in its own zone)."""
        delta = moment.replace(tzinfo=None) - EPOCH
        return cls(delta.days, delta.seconds * 1000 + delta.microseconds // 1000)


class TimeDifference(NamedTuple):
    """TIME_DIFFERENCE: a span of days plus milliseconds."""

    days: int
    milliseconds: int

    def to_timedelta(self) -> _dt.timedelta:
        return _dt.timedelta(days=self.days, milliseconds=self.milliseconds)

    @classmethod
    def from_timedelta(cls, span: _dt.timedelta) -> TimeDifference:
        return cls(span.days, span.seconds * 1000 + span.microseconds // 1000)


#: The CANopen epoch of TIME_OF_DAY.
EPOCH = _dt.datetime(1984, 1, 1)

#: A decoded value of any basic data type.
Value: TypeAlias = bool | int | float | str | bytes | TimeOfDay | TimeDifference

_D = DataType
_INT_WIDTH: dict[DataType, tuple[int, bool]] = {
    _D.INTEGER8: (8, True),
    _D.INTEGER16: (16, True),
    _D.INTEGER24: (24, True),
    _D.INTEGER32: (32, True),
    _D.INTEGER40: (40, True),
    _D.INTEGER48: (48, True),
    _D.INTEGER56: (56, True),
    _D.INTEGER64: (64, True),
    _D.UNSIGNED8: (8, False),
    _D.UNSIGNED16: (16, False),
    _D.UNSIGNED24: (24, False),
    _D.UNSIGNED32: (32, False),
    _D.UNSIGNED40: (40, False),
    _D.UNSIGNED48: (48, False),
    _D.UNSIGNED56: (56, False),
    _D.UNSIGNED64: (64, False),
}
_INT_RANGE: dict[DataType, tuple[int, int]] = {
    dt: ((-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1))
    for dt, (bits, signed) in _INT_WIDTH.items()
}
_SIGNED = frozenset(dt for dt, (_, signed) in _INT_WIDTH.items() if signed)
#: Integer types: (lowest, highest, signed, bits), for hot paths that avoid enum properties.
INT_INFO: dict[DataType, tuple[int, int, bool, int]] = {
    dt: (*_INT_RANGE[dt], signed, bits) for dt, (bits, signed) in _INT_WIDTH.items()
}
_STRINGS = frozenset((_D.VISIBLE_STRING, _D.OCTET_STRING, _D.UNICODE_STRING))
_BIT_LENGTH: dict[DataType, int | None] = {
    **{dt: bits for dt, (bits, _) in _INT_WIDTH.items()},
    _D.BOOLEAN: 1,
    _D.REAL32: 32,
    _D.REAL64: 64,
    _D.TIME_OF_DAY: 48,
    _D.TIME_DIFFERENCE: 48,
    _D.VISIBLE_STRING: None,
    _D.OCTET_STRING: None,
    _D.UNICODE_STRING: None,
    _D.DOMAIN: None,
}
_SIZE: dict[DataType, int | None] = {
    dt: (None if bits is None else max(1, bits // 8)) for dt, bits in _BIT_LENGTH.items()
}

_MS_PER_DAY = 86_400_000
_MS_MASK = 0x0FFFFFFF


# --- failure paths ---------------------------------------------------------------------------


def _describe(value: object) -> str:
    return f"{type(value).__name__} {value!r}"


def _int_error(dt: DataType, value: object) -> ValueRangeError:
    lo, hi = _INT_RANGE[dt]
    try:
        number = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        return ValueRangeError(f"{dt.name} needs an integer in {lo}..{hi}, got {_describe(value)}")
    return ValueRangeError(f"{number} is out of range for {dt.name}: allowed {lo}..{hi}")


def _length_error(dt: DataType, expected: int, data: object) -> DataLengthError:
    try:
        given = len(data)  # type: ignore[arg-type]
    except TypeError:
        return DataLengthError(f"{dt.name} decodes bytes, got {_describe(data)}")
    unit = "byte" if expected == 1 else "bytes"
    return DataLengthError(f"{dt.name} takes {expected} {unit}; got {given}")


# --- codec builders --------------------------------------------------------------------------

_Encoder = Callable[[Any], bytes]
_Decoder = Callable[[Any], Any]


def _struct_int(dt: DataType, fmt: str) -> tuple[_Encoder, _Decoder]:
    st = struct.Struct(fmt)
    pack = st.pack
    unpack = st.unpack
    size = st.size

    def enc(value: Any) -> bytes:
        try:
            return pack(value)
        except (struct.error, OverflowError, TypeError):
            if type(value) is not bool:
                try:
                    number = operator.index(value)
                except TypeError:
                    raise _int_error(dt, value) from None
                lo, hi = _INT_RANGE[dt]
                if lo <= number <= hi:
                    return pack(number)
            raise _int_error(dt, value) from None

    def dec(data: Any) -> int:
        try:
            return unpack(data)[0]  # type: ignore[no-any-return]
        except (struct.error, TypeError):
            raise _length_error(dt, size, data) from None

    return enc, dec


def _odd_int(dt: DataType) -> tuple[_Encoder, _Decoder]:
    bits, signed = _INT_WIDTH[dt]
    size = bits // 8
    lo, hi = _INT_RANGE[dt]
    from_bytes = int.from_bytes

    def enc(value: Any) -> bytes:
        try:
            return value.to_bytes(size, "little", signed=signed)  # type: ignore[no-any-return]
        except (OverflowError, AttributeError, TypeError):
            try:
                number = operator.index(value)
            except TypeError:
                raise _int_error(dt, value) from None
            if lo <= number <= hi:
                return number.to_bytes(size, "little", signed=signed)
            raise _int_error(dt, value) from None

    def dec(data: Any) -> int:
        if len(data) != size:
            raise _length_error(dt, size, data)
        return from_bytes(data, "little", signed=signed)

    return enc, dec


def _real(dt: DataType, fmt: str) -> tuple[_Encoder, _Decoder]:
    st = struct.Struct(fmt)
    pack = st.pack
    unpack = st.unpack
    size = st.size

    def enc(value: Any) -> bytes:
        if type(value) is float:
            try:
                return pack(value)
            except OverflowError:
                raise ValueRangeError(
                    f"{value!r} is out of range for {dt.name}: its largest finite magnitude is "
                    f"{_REAL_MAX[dt]!r} (inf and nan are allowed)"
                ) from None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueRangeError(f"{dt.name} needs a float, got {_describe(value)}")
        try:
            return enc(float(value))
        except OverflowError:
            raise ValueRangeError(
                f"{value!r} is out of range for {dt.name}: its largest finite magnitude is "
                f"{_REAL_MAX[dt]!r}"
            ) from None

    def dec(data: Any) -> float:
        try:
            return unpack(data)[0]  # type: ignore[no-any-return]
        except (struct.error, TypeError):
            raise _length_error(dt, size, data) from None

    return enc, dec


_REAL_MAX = {
    _D.REAL32: struct.unpack("<f", b"\xff\xff\x7f\x7f")[0],
    _D.REAL64: 1.7976931348623157e308,
}


def _enc_bool(value: Any) -> bytes:
    if value is True:
        return b"\x01"
    if value is False:
        return b"\x00"
    if type(value) is int and (value == 0 or value == 1):
        return b"\x01" if value else b"\x00"
    raise ValueRangeError(f"BOOLEAN needs True/False (or 0/1), got {_describe(value)}")


def _dec_bool(data: Any) -> bool:
    if len(data) != 1:
        raise _length_error(_D.BOOLEAN, 1, data)
    return bool(data[0])


def _enc_visible(value: Any) -> bytes:
    if isinstance(value, str) and value.isascii() and value.isprintable():
        return value.encode("ascii")
    if not isinstance(value, str):
        raise ValueRangeError(f"VISIBLE_STRING needs a str, got {_describe(value)}")
    bad = next(c for c in value if not (c.isascii() and c.isprintable()))
    raise ValueRangeError(
        f"VISIBLE_STRING holds visible ASCII characters 0x20..0x7E only; {value!r} contains "
        f"{bad!r} (U+{ord(bad):04X})"
    )


def _dec_visible(data: Any) -> str:
    # Devices pad strings with NULs (C strings); the padding is not part of the value.
    return bytes(data).rstrip(b"\x00").decode("latin-1")


def _enc_unicode(value: Any) -> bytes:
    if not isinstance(value, str):
        raise ValueRangeError(f"UNICODE_STRING needs a str, got {_describe(value)}")
    if "\x00" in value:
        raise ValueRangeError(
            "UNICODE_STRING cannot contain NUL (U+0000): NUL terminates CANopen strings"
        )
    return value.encode("utf-16-le", "surrogatepass")


def _dec_unicode(data: Any) -> str:
    if len(data) % 2:
        raise DataLengthError(
            f"UNICODE_STRING takes an even number of bytes (16-bit code units); got {len(data)}"
        )
    return bytes(data).decode("utf-16-le", "surrogatepass").rstrip("\x00")


def _enc_octets(dt: DataType) -> _Encoder:
    def enc(value: Any) -> bytes:
        if isinstance(value, (bytes, bytearray, memoryview)):
            return bytes(value)
        raise ValueRangeError(f"{dt.name} needs bytes, got {_describe(value)}")

    return enc


def _dec_octets(data: Any) -> bytes:
    return bytes(data)


_TIME = struct.Struct("<IH")


def _time(dt: DataType) -> tuple[_Encoder, _Decoder]:
    pack = _TIME.pack
    unpack = _TIME.unpack
    of_day = dt is _D.TIME_OF_DAY
    ms_limit = _MS_PER_DAY if of_day else _MS_MASK + 1
    kind: type[TimeOfDay] | type[TimeDifference] = TimeOfDay if of_day else TimeDifference
    native = _dt.datetime if of_day else _dt.timedelta

    def check(days: Any, ms: Any) -> None:
        if type(days) is not int or type(ms) is not int:
            raise ValueRangeError(
                f"{dt.name} needs integer days and milliseconds, got {days!r}, {ms!r}"
            )
        if not 0 <= ms < ms_limit:
            what = "milliseconds after midnight" if of_day else "milliseconds"
            raise ValueRangeError(f"{dt.name} {what} must be in 0..{ms_limit - 1}, got {ms}")
        if not 0 <= days <= 0xFFFF:
            raise ValueRangeError(f"{dt.name} days must be in 0..65535, got {days}")

    def enc(value: Any) -> bytes:
        if isinstance(value, native):
            value = (
                TimeOfDay.from_datetime(value)  # type: ignore[arg-type]
                if of_day
                else TimeDifference.from_timedelta(value)  # type: ignore[arg-type]
            )
        if not isinstance(value, tuple) or len(value) != 2:
            raise ValueRangeError(
                f"{dt.name} needs a {kind.__name__} or {native.__name__}, got {_describe(value)}"
            )
        days, ms = value
        check(days, ms)
        return pack(ms, days)

    def dec(data: Any) -> TimeOfDay | TimeDifference:
        try:
            ms, days = unpack(data)
        except (struct.error, TypeError):
            raise _length_error(dt, 6, data) from None
        ms &= _MS_MASK
        if ms >= ms_limit:
            raise ValueRangeError(
                f"{dt.name} milliseconds after midnight must be below {ms_limit}, got {ms}"
            )
        return kind(days, ms)

    return enc, dec


_Unpack = Callable[[Any], tuple[Any, ...]]
_UNPACKERS: dict[int, _Unpack] = {}


def _build() -> tuple[dict[int, _Encoder], dict[int, _Decoder]]:
    enc: dict[int, _Encoder] = {}
    dec: dict[int, _Decoder] = {}
    fmts = {8: "b", 16: "<h", 32: "<i", 64: "<q"}
    for dt, (bits, signed) in _INT_WIDTH.items():
        if bits in fmts:
            fmt = fmts[bits] if signed else fmts[bits].upper()
            enc[dt], dec[dt] = _struct_int(dt, fmt)
            _UNPACKERS[dt] = struct.Struct(fmt).unpack
        else:
            enc[dt], dec[dt] = _odd_int(dt)
    enc[_D.REAL32], dec[_D.REAL32] = _real(_D.REAL32, "<f")
    enc[_D.REAL64], dec[_D.REAL64] = _real(_D.REAL64, "<d")
    _UNPACKERS[_D.REAL32] = struct.Struct("<f").unpack
    _UNPACKERS[_D.REAL64] = struct.Struct("<d").unpack
    enc[_D.BOOLEAN], dec[_D.BOOLEAN] = _enc_bool, _dec_bool
    enc[_D.VISIBLE_STRING], dec[_D.VISIBLE_STRING] = _enc_visible, _dec_visible
    enc[_D.UNICODE_STRING], dec[_D.UNICODE_STRING] = _enc_unicode, _dec_unicode
    for dt in (_D.OCTET_STRING, _D.DOMAIN):
        enc[dt], dec[dt] = _enc_octets(dt), _dec_octets
    for dt in (_D.TIME_OF_DAY, _D.TIME_DIFFERENCE):
        enc[dt], dec[dt] = _time(dt)
    return enc, dec


ENCODERS, DECODERS = _build()


def _unknown(data_type: object) -> DataTypeError:
    shown = f"0x{data_type:04X}" if isinstance(data_type, int) else repr(data_type)
    return DataTypeError(
        f"data type {shown} is not a CiA 301 basic data type (known: "
        + ", ".join(f"0x{dt:02X} {dt.name}" for dt in DataType)
        + ")"
    )


def encode(data_type: DataType | int, value: Any) -> bytes:
    """Encode ``value`` as ``data_type`` (little-endian, CiA 301)."""
    f = ENCODERS.get(data_type)
    if f is None:
        raise _unknown(data_type)
    return f(value)


def codec(data_type: DataType | int) -> tuple[_Encoder, _Decoder]:
    """The encoder and decoder :func:`encode` and :func:`decode` call for ``data_type``, for
    code that converts values of one type many times (:class:`DataTypeError` if unknown)."""
    enc, dec = ENCODERS.get(data_type), DECODERS.get(data_type)
    if enc is None or dec is None:
        raise _unknown(data_type)
    return enc, dec


def struct_unpacker(data_type: DataType | int) -> _Unpack | None:
    """The :meth:`struct.Struct.unpack` behind the decoder of ``data_type`` when that decoder
    is ``unpack(data)[0]`` and nothing else: bytes of exactly the type's size then always
    decode, so a hot path that checked the length may call it without the decoder's call.
    Only the 8-, 16-, 32- and 64-bit integers and the reals have one; None for the rest."""
    return _UNPACKERS.get(data_type)


def decode(data_type: DataType | int, data: bytes | bytearray | memoryview) -> Any:
    """Decode bytes of ``data_type``; the length must be exactly the type's size."""
    f = DECODERS.get(data_type)
    if f is None:
        raise _unknown(data_type)
    return f(data)


def same_value(a: object, b: object) -> bool:
    """Equality that also holds between two NaNs (for REAL values)."""
    if a == b:
        return True
    return isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)


_SHORT_TYPES = {
    "bool": DataType.BOOLEAN,
    "i8": DataType.INTEGER8,
    "i16": DataType.INTEGER16,
    "i32": DataType.INTEGER32,
    "i64": DataType.INTEGER64,
    "u8": DataType.UNSIGNED8,
    "u16": DataType.UNSIGNED16,
    "u32": DataType.UNSIGNED32,
    "u64": DataType.UNSIGNED64,
    "int8": DataType.INTEGER8,
    "int16": DataType.INTEGER16,
    "int32": DataType.INTEGER32,
    "int64": DataType.INTEGER64,
    "uint8": DataType.UNSIGNED8,
    "uint16": DataType.UNSIGNED16,
    "uint32": DataType.UNSIGNED32,
    "uint64": DataType.UNSIGNED64,
    "float": DataType.REAL32,
    "double": DataType.REAL64,
    "string": DataType.VISIBLE_STRING,
}


def data_type_named(name: Any) -> DataType | None:
    """The CiA 301 type ``name`` means: ``UNSIGNED16``, ``u16``, ``uint16``, ``float``,
    ``bool``, ``string``..., or its number; None when none."""
    if isinstance(name, int) and not isinstance(name, bool):
        try:
            return DataType(name)
        except ValueError:
            return None
    if not isinstance(name, str):
        return None
    text = name.strip()
    short = _SHORT_TYPES.get(text.lower())
    if short is not None:
        return short
    try:
        return DataType[text.upper()]
    except KeyError:
        return None
