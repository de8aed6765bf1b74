"""Reading and writing values as CiA 306 writes them (``DefaultValue=$NODEID+0x180`` ...).

Number literals follow CiA 306: ``0x`` hexadecimal, a leading ``0`` octal, otherwise decimal,
with an optional sign. Integer values may be ``$NODEID`` expressions (``$NODEID+0x180``,
``0x180+$NODEID``). Signed types also accept the two's complement written in hex
(``LowLimit=0x80000000`` for INTEGER32 is -2147483648), as editors commonly write them.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from cobus.od._errors import ValueRangeError
from cobus.od._types import (
    ENCODERS,
    INT_INFO,
    DataType,
    TimeDifference,
    TimeOfDay,
)

__all__ = ["TextError", "format_value", "parse_int", "parse_value"]

_D = DataType


class TextError(Exception):
    """A value text that cannot be read; ``reason`` says why (turned into a finding)."""

    def __init__(self, reason: str, *, out_of_range: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.out_of_range = out_of_range


#: The longest integer literal taken (a 64-bit value in octal with its sign and zeros fits):
#: longer ones are refused before Python builds a number that no object can hold.
MAX_LITERAL = 40


def parse_int(text: str) -> int:
    """A CiA 306 integer literal: ``0x1F``, ``017`` (octal), ``-5``, ``+12``."""
    if len(text) > MAX_LITERAL and len(text.strip()) > MAX_LITERAL:
        raise TextError(
            f"number {text.strip()[:16]!r}... is {len(text.strip())} characters long; CiA 306 "
            f"values fit in 64 bits (at most {MAX_LITERAL} characters here)"
        )
    try:
        return int(text, 0)
    except ValueError:
        pass
    s = text.strip()
    sign = 1
    if s[:1] in "+-" and s:
        sign = -1 if s[0] == "-" else 1
        s = s[1:].lstrip()
    if len(s) > 1 and s[0] == "0" and s.isdigit():
        try:
            return sign * int(s, 8)
        except ValueError:
            raise TextError(
                f"bad number {text!r}: a leading 0 makes it octal (CiA 306), and 8 and 9 are "
                "not octal digits; drop the leading zeros for a decimal number"
            ) from None
    if not s:
        raise TextError("empty number")
    raise TextError(f"bad number {text!r}: expected a decimal, 0x-hex or 0-octal integer literal")


def _split_nodeid(text: str) -> tuple[str, bool]:
    """Remove ``$NODEID`` and its ``+`` from an expression; the rest is the offset literal."""
    if "$" not in text:
        return text, False
    compact = "".join(text.split())
    upper = compact.upper()
    pos = upper.find("$NODEID")
    if pos < 0 or upper.count("$") != 1:
        raise TextError(f"bad $NODEID expression {text!r}: write $NODEID+0x180 or 0x180+$NODEID")
    before = compact[:pos]
    after = compact[pos + 7 :]
    if before and after:
        raise TextError(f"bad $NODEID expression {text!r}: write $NODEID+0x180 or 0x180+$NODEID")
    if after:
        if not after.startswith("+"):
            raise TextError(f"bad $NODEID expression {text!r}: only $NODEID+offset is allowed")
        rest = after[1:]
    elif before:
        if not before.endswith("+"):
            raise TextError(f"bad $NODEID expression {text!r}: only offset+$NODEID is allowed")
        rest = before[:-1]
    else:
        rest = "0"
    if not rest:
        raise TextError(f"bad $NODEID expression {text!r}: the offset is missing")
    return rest, True


def _int_value(dt: DataType, text: str, node_id: int | None) -> tuple[int | None, bool]:
    lo, hi, signed, bits = INT_INFO[dt]
    if "$" in text:
        body, relative = _split_nodeid(text)
    else:
        body, relative = text, False
    number = parse_int(body)
    if (
        number > hi
        and signed
        and number >> bits == 0
        and not relative
        and body.strip().startswith("0")  # the bits written in hex (or octal)
    ):
        number -= 1 << bits
    if relative:
        if node_id is None:
            if not lo <= number <= hi:
                raise TextError(
                    f"{text!r}: the offset {number} is out of range for {dt.name} ({lo}..{hi})",
                    out_of_range=True,
                )
            return None, True
        number += node_id
    if not lo <= number <= hi:
        raise TextError(
            f"{text!r} = {number} is out of range for {dt.name} ({lo}..{hi})", out_of_range=True
        )
    return number, relative


def _unquote(text: str) -> str:
    if len(text) >= 2 and text[0] == '"' and text[-1] == '"':
        return text[1:-1]
    return text


_F32 = struct.Struct("<f")
_U32 = struct.Struct("<I")
_F64 = struct.Struct("<d")
_U64 = struct.Struct("<Q")


def _real_value(dt: DataType, text: str) -> float:
    s = text.strip()
    if s[:2].lower() == "0x":
        bits = parse_int(s)
        try:
            if dt is _D.REAL32:
                return float(_F32.unpack(_U32.pack(bits))[0])
            return float(_F64.unpack(_U64.pack(bits))[0])
        except struct.error:
            raise TextError(f"{text!r} has more bits than {dt.name}", out_of_range=True) from None
    try:
        value = float(s)
    except ValueError:
        raise TextError(f"bad number {text!r} for {dt.name}: expected a decimal number") from None
    if dt is _D.REAL32 and math.isfinite(value):
        try:
            _F32.pack(value)
        except OverflowError:
            raise TextError(
                f"{text!r} is out of range for REAL32 (largest magnitude about 3.4e38)",
                out_of_range=True,
            ) from None
    return value


def parse_value(dt: DataType, text: str, node_id: int | None) -> tuple[Any, bool]:
    """Read ``text`` as a value of ``dt``: ``(value, relative)``.

    ``value`` is None for an empty numeric text and for a ``$NODEID`` expression when the node
    id is unknown. Raises :class:`TextError` when the text is not a value of the type.
    """
    if dt in INT_INFO:
        if not text:
            return None, False
        return _int_value(dt, text, node_id)
    if "$" in text and "$NODEID" in text.upper() and dt is not _D.VISIBLE_STRING:
        raise TextError(f"$NODEID is only allowed in integer values, not in {dt.name}")
    if dt is _D.VISIBLE_STRING or dt is _D.UNICODE_STRING:
        value = _unquote(text)
        if dt is _D.UNICODE_STRING and "\x00" in value:
            raise TextError("UNICODE_STRING cannot contain NUL", out_of_range=True)
        return value, False
    if not text:
        if dt is _D.OCTET_STRING or dt is _D.DOMAIN:
            return b"", False
        return None, False
    if dt is _D.BOOLEAN:
        low = text.strip().lower()
        if low in ("true", "false"):
            return low == "true", False
        number = parse_int(text)
        if number not in (0, 1):
            raise TextError(f"{text!r} is not a BOOLEAN: use 0 or 1", out_of_range=True)
        return number == 1, False
    if dt is _D.REAL32 or dt is _D.REAL64:
        return _real_value(dt, text), False
    if dt is _D.OCTET_STRING or dt is _D.DOMAIN:
        digits = _unquote(text).strip()
        if digits[:2] in ("0x", "0X"):  # some tools prefix the hex bytes with 0x
            digits = digits[2:]
        try:
            return bytes.fromhex(digits), False
        except ValueError:
            raise TextError(
                f"bad {dt.name} value {text!r}: write the bytes as hex digits, e.g. 0A1B2C"
            ) from None
    if dt is _D.TIME_OF_DAY or dt is _D.TIME_DIFFERENCE:
        parts = text.split()
        if len(parts) == 1:
            days, ms = 0, parse_int(parts[0])
        elif len(parts) == 2:
            days, ms = parse_int(parts[0]), parse_int(parts[1])
        else:
            raise TextError(
                f"bad {dt.name} value {text!r}: write days and milliseconds, e.g. '365 43200000'"
            )
        kind = TimeOfDay if dt is _D.TIME_OF_DAY else TimeDifference
        moment = kind(days, ms)
        try:
            ENCODERS[dt](moment)
        except ValueRangeError as exc:
            raise TextError(str(exc), out_of_range=True) from None
        return moment, False
    raise TextError(f"values of {dt.name} cannot be written in a file")  # pragma: no cover


def format_value(dt: DataType, value: Any, relative_offset: int | None = None) -> str:
    """The text CiA 306 files use for ``value`` (or for ``$NODEID+offset``)."""
    if relative_offset is not None:
        return (
            f"$NODEID+0x{relative_offset:X}"
            if relative_offset >= 0
            else (f"$NODEID+{relative_offset}")
        )
    if value is None:
        return ""
    if dt is _D.BOOLEAN:
        return "1" if value else "0"
    if dt.is_integer:
        if dt.is_signed:
            return str(value)
        return f"0x{value:X}"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        if value != value.strip() or (value[:1] == '"' and value[-1:] == '"' and len(value) > 1):
            return f'"{value}"'
        return value
    if isinstance(value, bytes):
        return value.hex().upper()
    if isinstance(value, tuple):
        return f"{value[0]} {value[1]}"
    return str(value)
