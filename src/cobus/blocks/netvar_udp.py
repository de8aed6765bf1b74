"""Network variables over UDP, the form CODESYS controllers speak on Ethernet: telegrams,
the IEC 61131-3 types of their values, and lists cut into telegrams.

A telegram is a 20-byte header and up to 256 data bytes, little-endian::

    00 2D 53 33   identity
    type u32      0: data; 6: a request for a list (header only)
    list id u16   the list identifier
    sub-index u16 the telegram's number in a packed list; the value's in an unpacked one
    count u16     values in the telegram (each array element, each struct member)
    length u16    of the telegram, header included
    counter u16   the same in every telegram of one transmission; +1 per transmission
    flags u8      bit 0 acknowledgement wanted, bit 1 checksum present (bit 2 invalid)
    checksum u8

The values follow in declaration order, without padding: BOOL one byte, ``STRING(n)``
n + 1 bytes (zero-filled; the text ends at the first NUL), REAL and LREAL IEEE 754, TIME
and TIME_OF_DAY milliseconds, DATE and DATE_AND_TIME seconds since 1970, all 32 bits. A
packed list puts as many values in a telegram as 256 bytes take (a value is never split);
an unpacked one sends a telegram per value. Nobody has published the checksum or the
acknowledgement: lists that ask for them are refused (:mod:`cobus.blocks.gvl`), and
telegrams that carry those flags are counted and dropped, not guessed at.

The runtime (sockets, transmission modes, reassembly) is
:class:`cobus.blocks.netvars.AsyncUdpNetworkVariables`; the wire format and what is known
of it: ``docs/network-variables.md``.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

from cobus.blocks.netvar_lists import VarList
from cobus.errors import CobusError

__all__ = [
    "ACK_WANTED",
    "CHECKSUM_PRESENT",
    "DATA",
    "DEFAULT_PORT",
    "HEADER_SIZE",
    "IDENTITY",
    "MAX_DATA",
    "REQUEST",
    "IecType",
    "Telegram",
    "TelegramError",
    "UdpDefinition",
    "UdpVar",
    "UdpVarList",
    "iec_type",
    "udp_list",
]

IDENTITY = b"\x00\x2d\x53\x33"
#: The port CODESYS uses unless a list says otherwise.
DEFAULT_PORT = 1202
HEADER_SIZE = 20
#: Data bytes a telegram carries at most.
MAX_DATA = 256
#: Telegram types: values, and a request for a list's values (header only).
DATA, REQUEST = 0, 6
#: Flag bits: the sender wants an acknowledgement; a checksum is there (bit 2: invalid).
ACK_WANTED, CHECKSUM_PRESENT = 0x01, 0x02
_HEADER = struct.Struct("<4sIHHHHHBB")


class TelegramError(CobusError, ValueError):
    """A datagram that is no network-variable telegram, or does not fit its list."""


@dataclass(frozen=True)
class Telegram:
    """One telegram: header fields and data."""

    list_id: int
    sub_index: int
    count: int
    counter: int
    data: bytes = b""
    kind: int = DATA
    flags: int = 0
    checksum: int = 0

    def to_bytes(self) -> bytes:
        """The datagram."""
        if len(self.data) > MAX_DATA:
            raise TelegramError(f"{len(self.data)} data bytes: a telegram takes {MAX_DATA}")
        head = _HEADER.pack(
            IDENTITY,
            self.kind,
            self.list_id,
            self.sub_index,
            self.count,
            HEADER_SIZE + len(self.data),
            self.counter & 0xFFFF,
            self.flags,
            self.checksum,
        )
        return head + self.data

    @classmethod
    def parse(cls, datagram: bytes) -> Telegram:
        """The telegram of ``datagram``; :class:`TelegramError` says why it is none."""
        if len(datagram) < HEADER_SIZE:
            raise TelegramError(f"{len(datagram)} bytes: shorter than a header ({HEADER_SIZE})")
        identity, kind, list_id, sub, count, length, counter, flags, checksum = _HEADER.unpack_from(
            datagram
        )
        if identity != IDENTITY:
            raise TelegramError(f"identity {identity.hex(' ')}: not a network-variable telegram")
        if length != len(datagram):
            raise TelegramError(f"length field {length}, datagram {len(datagram)} bytes")
        if len(datagram) > HEADER_SIZE + MAX_DATA:
            raise TelegramError(f"{len(datagram) - HEADER_SIZE} data bytes: more than {MAX_DATA}")
        if kind not in (DATA, REQUEST):
            raise TelegramError(f"type {kind}: neither values (0) nor a request (6)")
        return cls(
            list_id, sub, count, counter, bytes(datagram[HEADER_SIZE:]), kind, flags, checksum
        )


# ------------------------------------------------------------------ IEC 61131-3 types

#: Elementary types: struct format (little-endian), and the range of an integer.
_FORMATS: dict[str, str] = {
    "BOOL": "B",
    "BYTE": "B",
    "USINT": "B",
    "SINT": "b",
    "WORD": "H",
    "UINT": "H",
    "INT": "h",
    "DWORD": "I",
    "UDINT": "I",
    "DINT": "i",
    "LWORD": "Q",
    "ULINT": "Q",
    "LINT": "q",
    "REAL": "f",
    "LREAL": "d",
    "TIME": "I",  # milliseconds
    "TIME_OF_DAY": "I",  # milliseconds since midnight
    "TOD": "I",
    "DATE": "I",  # seconds since 1970-01-01
    "DATE_AND_TIME": "I",  # seconds since 1970-01-01
    "DT": "I",
}
#: What each type's value is, for messages.
_MEANING = {
    "TIME": "milliseconds",
    "TIME_OF_DAY": "milliseconds since midnight",
    "TOD": "milliseconds since midnight",
    "DATE": "seconds since 1970",
    "DATE_AND_TIME": "seconds since 1970",
    "DT": "seconds since 1970",
}
#: The length of a STRING or WSTRING without one.
DEFAULT_STRING = 80
_STRING = re.compile(r"(W?STRING)\s*(?:[(\[]\s*(\d+)\s*[)\]])?\Z", re.IGNORECASE)


@dataclass(frozen=True)
class IecType:
    """An elementary IEC 61131-3 type as it goes in a telegram: ``name`` as CODESYS writes
    it (``INT``, ``STRING(20)``), ``size`` in bytes."""

    name: str
    size: int
    #: The struct format, or "s" (STRING, single-byte text) / "w" (WSTRING, UTF-16).
    code: str
    #: Characters of a STRING or WSTRING.
    length: int = 0

    def encode(self, value: Any) -> bytes:
        """The value's bytes; ValueError says what the type takes."""
        if self.code == "s":
            if not isinstance(value, str):
                raise ValueError(f"{self.name} takes text, not {value!r}")
            try:
                data = value.encode("cp1252")
            except UnicodeEncodeError:
                raise ValueError(f"{value!r}: a {self.name} holds Windows-1252 text") from None
            if len(data) > self.length or b"\0" in data:
                raise ValueError(f"{value!r}: a {self.name} holds {self.length} characters")
            return data.ljust(self.size, b"\0")
        if self.code == "w":
            if not isinstance(value, str):
                raise ValueError(f"{self.name} takes text, not {value!r}")
            data = value.encode("utf-16-le", errors="surrogatepass")
            if len(data) > 2 * self.length or "\0" in value:
                raise ValueError(f"{value!r}: a {self.name} holds {self.length} characters")
            return data.ljust(self.size, b"\0")
        if self.name == "BOOL":
            if value is True or value is False or (type(value) is int and value in (0, 1)):
                return b"\x01" if value else b"\x00"
            raise ValueError(f"BOOL takes TRUE or FALSE (1 or 0), not {value!r}")
        if self.code in "fd":
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{self.name} takes a number, not {value!r}")
            try:
                return struct.pack("<" + self.code, value)
            except OverflowError:
                raise ValueError(f"{value!r} is out of the range of {self.name}") from None
        if isinstance(value, bool) or not isinstance(value, int):
            meaning = f" ({_MEANING[self.name]})" if self.name in _MEANING else ""
            raise ValueError(f"{self.name} takes a whole number{meaning}, not {value!r}")
        low, high = self.range
        if not low <= value <= high:
            raise ValueError(f"{value} is out of the range of {self.name}: {low}..{high}")
        return struct.pack("<" + self.code, value)

    def decode(self, data: bytes) -> Any:
        """The value of the type's bytes (text up to its first NUL)."""
        if self.code == "s":
            return data.split(b"\0", 1)[0].decode("cp1252", errors="replace")
        if self.code == "w":
            end = next((i for i in range(0, len(data) - 1, 2) if data[i : i + 2] == b"\0\0"), None)
            return data[:end].decode("utf-16-le", errors="replace")
        (value,) = struct.unpack("<" + self.code, data)
        if self.name == "BOOL":
            return value != 0
        return value

    @property
    def range(self) -> tuple[int, int]:
        """The lowest and highest value of an integer type."""
        bits = 8 * self.size
        if self.code.islower():
            return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        return 0, (1 << bits) - 1

    @property
    def zero(self) -> Any:
        """The value before anything was received or set."""
        return self.decode(bytes(self.size))


def iec_type(text: str) -> IecType:
    """The elementary type ``text`` names (``INT``, ``string(20)``, ``WSTRING``);
    ValueError names the ones there are."""
    word = text.strip()
    upper = word.upper()
    if upper in _FORMATS:
        fmt = _FORMATS[upper]
        return IecType(upper, struct.calcsize("<" + fmt), fmt)
    match = _STRING.match(word)
    if match is not None:
        kind = match.group(1).upper()
        length = int(match.group(2)) if match.group(2) else DEFAULT_STRING
        if not 1 <= length <= 65_535:
            raise ValueError(f"{word}: a string of 1 to 65535 characters")
        if kind == "STRING":
            return IecType(f"STRING({length})", length + 1, "s", length)
        return IecType(f"WSTRING({length})", 2 * (length + 1), "w", length)
    known = ", ".join(sorted(_FORMATS)) + ", STRING(n), WSTRING(n)"
    raise ValueError(f"{word!r} is no elementary type cobus sends over UDP; there are: {known}")


# ------------------------------------------------------------------ lists


@dataclass(frozen=True)
class UdpVar:
    """One value of a list (array elements and struct members each one: ``temps[2]``,
    ``motor.current``), its type and where it lies in the list's bytes."""

    name: str
    type: IecType
    offset: int

    @property
    def size(self) -> int:
        """Bytes of the value."""
        return self.type.size

    def encode(self, value: Any) -> bytes:
        """The value's bytes; ValueError names the variable and what its type takes."""
        try:
            return self.type.encode(value)
        except ValueError as exc:
            raise ValueError(f"{self.name}: {exc}") from None

    def decode(self, data: bytes) -> Any:
        """The value of its bytes."""
        return self.type.decode(data)

    @property
    def zero(self) -> Any:
        """The value before anything was received or set."""
        return self.type.zero


@dataclass(frozen=True)
class UdpVarList:
    """A network variable list as it goes over UDP (what a ``.gvl`` file defines).

    ``name`` is the list's (the file's); ``list_id`` its identifier; ``pack``: values share
    telegrams (else one telegram per value); how it is sent (``transmit``: cyclic,
    on_change or on_event, with ``interval``, ``min_gap`` and the BOOL ``event``); where
    (``address``, ``port``)."""

    name: str
    list_id: int
    variables: tuple[UdpVar, ...]
    pack: bool = True
    transmit: str = "cyclic"
    #: Every way the list is sent (CODESYS may combine them: cyclic and on change).
    modes: frozenset[str] = frozenset({"cyclic"})
    interval: float | None = 0.05
    min_gap: float = 0.0
    event: str | None = None
    address: str = "255.255.255.255"
    port: int = DEFAULT_PORT
    #: Ask for the list when the reader starts (a type-6 request).
    request_at_boot: bool = False
    #: The event variable as the file names it (CODESYS takes any BOOL of the project;
    #: ``event`` is set only when it is a BOOL of the list).
    event_text: str = field(default="", compare=False)
    #: Who writes the list (the runtime's ``send``); "" when the file does not say.
    sender: str = ""
    #: The ST declarations' text, as the file had it (written back into a .gvl).
    declarations: str = field(default="", compare=False, repr=False)

    def __post_init__(self) -> None:
        if not 0 <= self.list_id <= 0xFFFF:
            raise ValueError(f"list {self.name}: identifier {self.list_id} is not 0..65535")
        for var in self.variables:
            if var.size > MAX_DATA:
                raise ValueError(
                    f"list {self.name}: {var.name} ({var.type.name}) takes {var.size} bytes; "
                    f"a telegram carries {MAX_DATA} (values are never split)"
                )

    @property
    def size(self) -> int:
        """Bytes of all the values."""
        return sum(v.size for v in self.variables)

    @cached_property
    def parts(self) -> tuple[tuple[int, int, int], ...]:
        """Each telegram of a transmission: (first value, values, data bytes)."""
        if not self.pack:
            return tuple((i, 1, v.size) for i, v in enumerate(self.variables))
        found: list[tuple[int, int, int]] = []
        first, size = 0, 0
        for i, var in enumerate(self.variables):
            if size and size + var.size > MAX_DATA:
                found.append((first, i - first, size))
                first, size = i, 0
            size += var.size
        found.append((first, len(self.variables) - first, size))
        return tuple(found)

    @property
    def frames(self) -> int:
        """Telegrams per transmission."""
        return len(self.parts)

    @cached_property
    def _by_name(self) -> dict[str, UdpVar]:
        return {v.name: v for v in self.variables}

    def variable(self, name: str) -> UdpVar:
        """The value ``name``; KeyError names the ones there are."""
        found = self._by_name.get(name)
        if found is not None:
            return found
        names = ", ".join(v.name for v in self.variables[:20])
        more = f" and {len(self.variables) - 20} more" if len(self.variables) > 20 else ""
        raise KeyError(f"list {self.name!r} has no variable {name!r}; it has: {names}{more}")

    def pack_values(self, values: Mapping[str, Any]) -> bytes:
        """The list's bytes from its values (each must be there)."""
        return b"".join(var.encode(values[var.name]) for var in self.variables)

    def unpack(self, data: bytes) -> dict[str, Any]:
        """The values of the list's bytes."""
        return {v.name: v.decode(data[v.offset : v.offset + v.size]) for v in self.variables}

    def telegrams(self, payload: bytes, counter: int) -> list[Telegram]:
        """The telegrams of one transmission of ``payload`` (the list's bytes)."""
        out = []
        for number, (first, count, size) in enumerate(self.parts):
            start = self.variables[first].offset if self.variables else 0
            out.append(
                Telegram(self.list_id, number, count, counter, payload[start : start + size])
            )
        return out

    def request(self) -> Telegram:
        """The request for the list (type 6, header only)."""
        return Telegram(self.list_id, 0, len(self.variables) if self.pack else 1, 0, kind=REQUEST)


def layout(items: list[tuple[str, IecType]]) -> tuple[UdpVar, ...]:
    """Values named and typed, in order, at their offsets."""
    out, offset = [], 0
    for name, kind in items:
        out.append(UdpVar(name, kind, offset))
        offset += kind.size
    return tuple(out)


@dataclass(frozen=True)
class UdpDefinition:
    """Lists sent over UDP, by name (those of .gvl files, or cobus's own YAML lists)."""

    lists: Mapping[str, UdpVarList]
    controllers: tuple[str, ...] = ()
    path: str | None = None

    def __getitem__(self, name: str) -> UdpVarList:
        found = self.lists.get(name)
        if found is None:
            raise KeyError(f"no variable list {name!r}; the lists: {', '.join(self.lists)}")
        return found

    @classmethod
    def of(cls, lists: Iterable[UdpVarList]) -> UdpDefinition:
        """The lists by name (two of one name: ValueError)."""
        found: dict[str, UdpVarList] = {}
        for lst in lists:
            if lst.name in found:
                raise ValueError(f"two lists named {lst.name}: rename one of the files")
            found[lst.name] = lst
        return cls(found)


#: The IEC type of each CiA 301 type a YAML list may hold.
_IEC_OF = {
    "BOOLEAN": "BOOL",
    "INTEGER8": "SINT",
    "UNSIGNED8": "USINT",
    "INTEGER16": "INT",
    "UNSIGNED16": "UINT",
    "INTEGER32": "DINT",
    "UNSIGNED32": "UDINT",
    "INTEGER64": "LINT",
    "UNSIGNED64": "ULINT",
    "REAL32": "REAL",
    "REAL64": "LREAL",
}


def udp_list(
    var_list: VarList, *, address: str = "255.255.255.255", port: int = DEFAULT_PORT
) -> UdpVarList:
    """cobus's own (YAML) list as it goes over UDP: the same values in the same order,
    each as the IEC type of its CiA 301 type; a ``{string: N}`` is a ``STRING(N-1)``
    (N bytes with its terminator). ValueError for a type IEC 61131-3 has not
    (INTEGER24...) or an identifier above 65535."""
    items: list[tuple[str, IecType]] = []
    for var in var_list.variables:
        kind = var.data_type.name
        if kind == "VISIBLE_STRING":
            if var.size < 2:
                raise ValueError(
                    f"list {var_list.name}: {var.name}: a string of {var.size} byte has no room "
                    "for text and its terminator over UDP"
                )
            items.append((var.name, iec_type(f"STRING({var.size - 1})")))
        elif kind in _IEC_OF:
            items.append((var.name, iec_type(_IEC_OF[kind])))
        else:
            raise ValueError(
                f"list {var_list.name}: {var.name} is {kind}, which has no IEC 61131-3 type: "
                f"use one of {', '.join(_IEC_OF)} or a string"
            )
    return UdpVarList(
        var_list.name,
        var_list.cob_id,
        layout(items),
        transmit=var_list.transmit,
        modes=frozenset({var_list.transmit}),
        interval=var_list.interval,
        min_gap=var_list.min_gap,
        event=var_list.event,
        address=address,
        port=port,
        request_at_boot=var_list.request_at_boot,
        sender=var_list.sender,
    )
