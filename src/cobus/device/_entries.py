"""The device's values: one :class:`Entry` per variable of the dictionary, with the checks an
SDO download or an application write goes through and the abort code of each failure."""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cobus.od import (
    DataLengthError,
    DataType,
    TimeDifference,
    TimeOfDay,
    ValueRangeError,
    Variable,
    codec,
    encode,
    struct_unpacker,
)
from cobus.proto.sdo import SdoAbort, SdoAbortCode

if TYPE_CHECKING:
    from cobus.device._pdo_machines import Tpdo

__all__ = ["Entry", "check_value", "decode_download", "zero_value"]

Reader = Callable[[], Any]
Writer = Callable[[Any], object]


class Entry:
    """The current value of one variable and what is bound to it."""

    __slots__ = (
        "data_type",
        "decoder",
        "download_limit",
        "encoder",
        "high",
        "index",
        "key",
        "limited",
        "low",
        "reader",
        "size",
        "subindex",
        "tpdos",
        "unpack",
        "value",
        "var",
        "writer",
    )

    def __init__(self, var: Variable) -> None:
        self.var = var
        self.index = var.index
        self.subindex = var.subindex
        self.key = var.index << 8 | var.subindex
        self.data_type = var.data_type
        #: The codec of the data type, asked once (an SDO request saves a lookup).
        self.encoder: Callable[[Any], bytes]
        self.decoder: Callable[[bytes], Any]
        self.encoder, self.decoder = codec(var.data_type)
        self.size = var.data_type.size
        self.low = var.low_limit
        self.high = var.high_limit
        self.limited = self.low is not None or self.high is not None
        #: The type's struct unpacker when bytes of its size need no other check (an integer
        #: or real type, no limits): a download's value in one C call, no decoder's.
        self.unpack = None if self.limited else struct_unpacker(var.data_type)
        self.value: Any = None
        #: The most bytes an SDO download may bring into it when its type has no fixed size
        #: (None: the server's 1 MiB); set with Device.limit_download.
        self.download_limit: int | None = None
        #: Where reads get the value from instead of ``value`` (application binding or a
        #: value the device computes).
        self.reader: Reader | None = None
        #: The application's write callback (SDO and RPDO writes).
        self.writer: Writer | None = None
        #: The TPDOs that map this entry (sent or flagged when the value changes).
        self.tpdos: list[Tpdo] = []

    def current(self) -> Any:
        reader = self.reader
        return self.value if reader is None else reader()

    def __repr__(self) -> str:
        return f"<Entry 0x{self.index:04X}:{self.subindex:02X} {self.value!r}>"


_ZERO: dict[DataType, Any] = {
    DataType.BOOLEAN: False,
    DataType.REAL32: 0.0,
    DataType.REAL64: 0.0,
    DataType.VISIBLE_STRING: "",
    DataType.UNICODE_STRING: "",
    DataType.OCTET_STRING: b"",
    DataType.DOMAIN: b"",
    DataType.TIME_OF_DAY: TimeOfDay(0, 0),
    DataType.TIME_DIFFERENCE: TimeDifference(0, 0),
}


def zero_value(data_type: DataType) -> Any:
    """The value of an entry whose dictionary gives no default."""
    return _ZERO.get(data_type, 0)


def _limits(entry: Entry, value: Any) -> None:
    try:
        if entry.low is not None and value < entry.low:
            raise SdoAbort(
                SdoAbortCode.VALUE_TOO_LOW,
                f"{value!r} is below the low limit {entry.low!r} of {entry.var.name!r}",
            )
        if entry.high is not None and value > entry.high:
            raise SdoAbort(
                SdoAbortCode.VALUE_TOO_HIGH,
                f"{value!r} is above the high limit {entry.high!r} of {entry.var.name!r}",
            )
    except TypeError:
        raise SdoAbort(
            SdoAbortCode.INVALID_VALUE,
            f"{value!r} cannot be compared with the limits of {entry.var.name!r}",
        ) from None


def check_value(entry: Entry, value: Any) -> Any:
    """``value`` if it fits the entry's type and limits (a native ``datetime``/``timedelta``
    becomes a TimeOfDay/TimeDifference); else :class:`SdoAbort` 06090030/31/32."""
    dt = entry.data_type
    try:
        encode(dt, value)
    except ValueRangeError as exc:
        rng = dt.range
        if rng is not None and isinstance(value, int) and not isinstance(value, bool):
            code = SdoAbortCode.VALUE_TOO_HIGH if value > rng[1] else SdoAbortCode.VALUE_TOO_LOW
            raise SdoAbort(code, str(exc)) from None
        raise SdoAbort(SdoAbortCode.INVALID_VALUE, str(exc)) from None
    if dt is DataType.TIME_OF_DAY and isinstance(value, _dt.datetime):
        value = TimeOfDay.from_datetime(value)
    elif dt is DataType.TIME_DIFFERENCE and isinstance(value, _dt.timedelta):
        value = TimeDifference.from_timedelta(value)
    elif dt.is_real and not isinstance(value, float):
        value = float(value)
    elif dt is DataType.BOOLEAN:
        value = bool(value)
    elif isinstance(value, bytearray | memoryview):
        value = bytes(value)
    if entry.limited:
        _limits(entry, value)
    return value


_VISIBLE_STRING = DataType.VISIBLE_STRING  # a global: an Enum class attribute costs ~0.5 us


def decode_download(entry: Entry, data: bytes) -> Any:
    """The value of downloaded bytes; :class:`SdoAbort` 0607xxxx for a wrong length and
    0609003x for a value the type or the limits do not allow."""
    size = entry.size
    n = len(data)
    if size is not None and n != size:
        code = SdoAbortCode.LENGTH_TOO_HIGH if n > size else SdoAbortCode.LENGTH_TOO_LOW
        raise SdoAbort(
            code, f"{entry.var.name!r} is {entry.data_type.name} ({size} bytes), got {n} bytes"
        )
    dt = entry.data_type
    try:
        value = entry.decoder(data)
        if dt is _VISIBLE_STRING:
            encode(dt, value)
    except DataLengthError as exc:
        raise SdoAbort(SdoAbortCode.LENGTH_MISMATCH, str(exc)) from None
    except ValueRangeError as exc:
        raise SdoAbort(SdoAbortCode.INVALID_VALUE, str(exc)) from None
    if entry.limited:
        _limits(entry, value)
    return value
