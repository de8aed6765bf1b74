"""The CiA 309-3 ASCII command language, without I/O: one line in, a request or an error out;
values formatted and parsed per data type, in CANopenNode's or Lely's way.

A line is ``[seq] [[net] node] command [args] [# comment]``: case-insensitive, numbers in
decimal, ``0x`` hex or leading-0 octal. cobus also takes a line without ``[seq]`` (typed by
hand) and answers it without one.
"""

from __future__ import annotations

import base64
import binascii
import re
from dataclasses import dataclass, field
from typing import Any

from cobus.od import DataType, TimeDifference, TimeOfDay, decode, encode

__all__ = [
    "DIALECTS",
    "ERRORS",
    "TYPES",
    "GatewayError",
    "Request",
    "format_error",
    "format_value",
    "mnemonic",
    "parse_line",
    "parse_number",
    "parse_value",
    "split_name",
]

#: The reply dialects: CANopenNode's (decimal numbers, ``ERROR:101 #text``) and Lely's
#: (unsigned numbers in hex, ``ERROR: 101 (text)``).
DIALECTS = ("canopennode", "lely")

#: The CiA 309-3 gateway error numbers and their texts.
ERRORS = {
    100: "Request not supported",
    101: "Syntax error",
    102: "Request not processed due to internal state",
    103: "Time-out",
    104: "No default net set",
    105: "No default node set",
    106: "Unsupported net",
    107: "Unsupported node",
    200: "Lost guarding message",
    201: "Lost connection",
    202: "Heartbeat started",
    203: "Heartbeat lost",
    204: "Wrong NMT state",
    205: "Boot-up",
    300: "Error passive",
    301: "Bus off",
    303: "CAN buffer overflow",
    304: "CAN init",
    305: "CAN active",
    400: "PDO already used",
    401: "PDO length exceeded",
    501: "LSS implementation- / manufacturer-specific error",
    502: "LSS node-ID not supported",
    503: "LSS bit-rate not supported",
    504: "LSS parameter storing failed",
    505: "LSS command failed because of media error",
    600: "Running out of memory",
}

_D = DataType
#: Data type mnemonics: the standard's, Lely's 24..56-bit ones, CANopenNode's ``x8..x64``
#: (unsigned, shown in hex) and ``hex`` (bytes).
TYPES: dict[str, DataType | None] = {
    "b": _D.BOOLEAN,
    "i8": _D.INTEGER8,
    "i16": _D.INTEGER16,
    "i24": _D.INTEGER24,
    "i32": _D.INTEGER32,
    "i40": _D.INTEGER40,
    "i48": _D.INTEGER48,
    "i56": _D.INTEGER56,
    "i64": _D.INTEGER64,
    "u8": _D.UNSIGNED8,
    "u16": _D.UNSIGNED16,
    "u24": _D.UNSIGNED24,
    "u32": _D.UNSIGNED32,
    "u40": _D.UNSIGNED40,
    "u48": _D.UNSIGNED48,
    "u56": _D.UNSIGNED56,
    "u64": _D.UNSIGNED64,
    "x8": _D.UNSIGNED8,
    "x16": _D.UNSIGNED16,
    "x32": _D.UNSIGNED32,
    "x64": _D.UNSIGNED64,
    "r32": _D.REAL32,
    "r64": _D.REAL64,
    "vs": _D.VISIBLE_STRING,
    "os": _D.OCTET_STRING,
    "us": _D.UNICODE_STRING,
    "d": _D.DOMAIN,
    "t": _D.TIME_OF_DAY,
    "td": _D.TIME_DIFFERENCE,
    "hex": None,
}
_BASE64 = ("os", "us", "d")


class GatewayError(Exception):
    """A request the gateway answers with ``ERROR:<code>``; the text says what to fix."""

    def __init__(self, code: int, text: str = "") -> None:
        super().__init__(text or ERRORS.get(code, "error"))
        self.code = code
        self.text = text or ERRORS.get(code, "error")


@dataclass(slots=True)
class Request:
    """One parsed line: its sequence number (None: the line had none), the net and node it
    names (None: the session's defaults), the command word and the words after it."""

    seq: int | None
    net: int | None
    node: int | None
    command: str
    args: list[str] = field(default_factory=list)
    #: The text after the command (a visible string written with spaces keeps them).
    rest: str = ""


_NUMBER = re.compile(r"[+-]?(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)\Z")
_SEQ = re.compile(r"\s*\[\s*([0-9]+)\s*\]\s*")
_WORD = re.compile(r"\s*(\S+)")


def parse_number(text: str, what: str = "number") -> int:
    """An integer as CiA 309-3 writes it: decimal, ``0x`` hex or leading-0 octal."""
    if len(text) > 40 or not _NUMBER.match(text):
        raise GatewayError(101, f"{what} {text!r} is not a number (decimal, 0x hex or 0 octal)")
    sign = -1 if text[0] == "-" else 1
    body = text.lstrip("+-")
    if body[:2].lower() == "0x":
        return sign * int(body[2:], 16)
    if len(body) > 1 and body[0] == "0":
        return sign * int(body[1:], 8)
    return sign * int(body)


def _strip_comment(line: str) -> str:
    """The line without a ``#`` comment (a ``#`` inside a quoted string stays)."""
    quoted = False
    for i, ch in enumerate(line):
        if ch == '"':
            quoted = not quoted
        elif ch == "#" and not quoted:
            return line[:i]
    return line


def parse_line(line: str) -> Request | None:
    """The request of ``line`` (None: an empty line or a comment); :class:`GatewayError`
    101 for a line that is no request."""
    text = _strip_comment(line.rstrip("\r\n")).strip()
    if not text:
        return None
    seq: int | None = None
    match = _SEQ.match(text)
    if match:
        seq = int(match.group(1))
        text = text[match.end() :]
    elif text.startswith("["):
        raise GatewayError(101, "a sequence number is written [N], N a decimal number")
    numbers: list[int] = []
    pos = 0
    while True:
        word = _WORD.match(text, pos)
        if word is None:
            raise GatewayError(101, "no command after the net and node numbers")
        token = word.group(1)
        if not _NUMBER.match(token) or len(numbers) == 2:
            break
        numbers.append(parse_number(token, "net or node"))
        pos = word.end()
    command = token.lower()
    rest = text[word.end() :].strip()
    net = node = None
    if len(numbers) == 2:
        net, node = numbers
    elif len(numbers) == 1:
        node = numbers[0]
    return Request(seq, net, node, command, rest.split(), rest)


#: The mnemonic of each data type (the standard's, not x8..x64).
_MNEMONICS = {t: name for name, t in TYPES.items() if t is not None and not name.startswith("x")}


def mnemonic(data_type: DataType) -> str:
    """The type mnemonic a value of ``data_type`` is read and written as (``hex``: bytes)."""
    return _MNEMONICS.get(data_type, "hex")


def split_name(text: str) -> tuple[str, str]:
    """The object name at the start of ``text`` (``"Device name"`` quoted, with ``""`` for a
    quote, or one word) and the text after it."""
    text = text.strip()
    if not text.startswith('"'):
        word, _, after = text.partition(" ")
        return word, after.strip()
    out, i = [], 1
    while i < len(text):
        if text[i] == '"':
            if text[i + 1 : i + 2] == '"':
                out.append('"')
                i += 2
                continue
            after = text[i + 1 :]
            if after and not after[0].isspace():
                raise GatewayError(101, "a space after the name's closing quote")
            return "".join(out), after.strip()
        out.append(text[i])
        i += 1
    raise GatewayError(101, "the name has no closing quote")


def _type_of(name: str) -> DataType | None:
    try:
        return TYPES[name.lower()]
    except KeyError:
        known = " ".join(TYPES)
        raise GatewayError(101, f"no data type {name!r} (the types: {known})") from None


def format_value(type_name: str | None, data: bytes, dialect: str = "canopennode") -> str:
    """``data`` as the reply to a read with ``type_name`` (None: bytes in hex)."""
    name = (type_name or "hex").lower()
    data_type = _type_of(name)
    if data_type is None:
        return " ".join(f"{b:02X}" for b in data)
    size = data_type.size
    if size is not None and len(data) != size:
        return " ".join(f"{b:02X}" for b in data)  # (the server's size: shown as it came)
    if name in _BASE64:
        return base64.b64encode(bytes(data)).decode("ascii")  # (the bytes as they came)
    try:
        value: Any = decode(data_type, data)
    except ValueError:  # (bytes the type cannot hold, a time out of range...: as they came)
        return " ".join(f"{b:02X}" for b in data)
    if name.startswith("x"):
        return f"0x{value:0{2 * (size or 1)}X}"
    if data_type is _D.BOOLEAN:
        return "1" if value else "0"
    if data_type.is_integer:
        if dialect == "lely" and not data_type.is_signed:
            return f"0x{value:0{2 * (size or 1)}x}"
        return str(value)
    if data_type is _D.REAL32:
        return f"{value:g}" if dialect == "canopennode" else f"{value:.6g}"
    if data_type is _D.REAL64:  # (CANopenNode: six significant digits, as for r32)
        return f"{value:g}" if dialect == "canopennode" else f"{value:.15g}"
    if data_type is _D.VISIBLE_STRING:  # (UTF-8, as devices keep it; other bytes \xNN)
        return '"' + _escaped(bytes(data).decode("utf-8", "surrogateescape")) + '"'
    if isinstance(value, TimeOfDay | TimeDifference):
        return f"{value.days} {value.milliseconds}"
    return str(value)


_ESCAPES = {"\\": "\\\\", "\n": "\\n", "\r": "\\r", "\t": "\\t"}
_UNESCAPES = {"\\": "\\", "n": "\n", "r": "\r", "t": "\t"}


def _escaped(text: str) -> str:
    """A visible string on one reply line: ``""`` for a quote, ``\\`` for a backslash,
    ``\\n``, ``\\r``, ``\\t`` and ``\\xNN`` for control characters (a line end inside
    would split the reply) and for bytes that are no UTF-8 (decoded with surrogateescape)."""
    out = []
    for ch in text:
        if ch == '"':
            out.append('""')
        elif ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\x{ord(ch):02X}")
        elif 0xDC80 <= ord(ch) <= 0xDCFF:  # (a byte that is no UTF-8)
            out.append(f"\\x{ord(ch) - 0xDC00:02X}")
        else:
            out.append(ch)
    return "".join(out)


def _quoted(text: str) -> str:
    """A visible string as written: ``"..."`` with ``""`` for a quote and the escapes of
    :func:`_escaped`, or the words as they are."""
    text = text.strip()
    if not text.startswith('"'):
        return text
    out = []
    i = 1
    while i < len(text):
        ch = text[i]
        if ch == '"':
            if text[i + 1 : i + 2] == '"':
                out.append('"')
                i += 2
                continue
            if text[i + 1 :].strip():
                raise GatewayError(101, "text after the closing quote of the string")
            return "".join(out)
        if ch == "\\" and i + 1 < len(text):
            nxt = text[i + 1]
            if nxt in _UNESCAPES:
                out.append(_UNESCAPES[nxt])
                i += 2
                continue
            hex_digits = text[i + 2 : i + 4]
            if nxt == "x" and re.fullmatch(r"[0-9A-Fa-f]{2}", hex_digits):
                byte = int(hex_digits, 16)  # (that byte, UTF-8 or not: surrogateescape)
                out.append(chr(byte) if byte < 0x80 else chr(0xDC00 + byte))
                i += 4
                continue
        out.append(ch)
        i += 1
    raise GatewayError(101, "the string has no closing quote")


def parse_value(type_name: str, text: str) -> bytes:
    """The bytes to write for ``text`` given as ``type_name``."""
    name = type_name.lower()
    data_type = _type_of(name)
    text = text.strip()
    if data_type is not _D.VISIBLE_STRING and len(text) >= 2 and text[0] == text[-1] == '"':
        text = _quoted(text).strip()  # (a value quoted as one word: "e8 03", "2 500")
    if not text:
        raise GatewayError(101, "no value to write")
    try:
        if data_type is None:
            digits = "".join(part.zfill(2) if len(part) == 1 else part for part in text.split())
            return bytes.fromhex(digits)
        if name in _BASE64:
            return base64.b64decode(text, validate=True)
        if data_type is _D.VISIBLE_STRING:  # (UTF-8, as CANopenNode and devices take it)
            return _quoted(text).encode("utf-8", "surrogateescape")
        if data_type is _D.BOOLEAN:
            word = text.lower()
            value: Any = {"true": True, "false": False}.get(word)
            if value is None:
                number = parse_number(text, "boolean")
                if number not in (0, 1):
                    raise GatewayError(101, f"a boolean is 0 or 1, not {text}")
                value = bool(number)
            return encode(data_type, value)
        if data_type.is_integer:
            return encode(data_type, parse_number(text, data_type.name))
        if data_type in (_D.REAL32, _D.REAL64):
            return encode(data_type, float(text))
        if data_type in (_D.TIME_OF_DAY, _D.TIME_DIFFERENCE):
            days, ms = (parse_number(part, "days or ms") for part in text.split())
            kind = TimeOfDay if data_type is _D.TIME_OF_DAY else TimeDifference
            return encode(data_type, kind(days, ms))
    except GatewayError:
        raise
    except (ValueError, binascii.Error) as exc:
        raise GatewayError(101, f"{text!r} is no {name} value: {exc}") from None
    raise GatewayError(100, f"writing {name} is not supported")


def format_error(seq: int | None, code: int, text: str, dialect: str = "canopennode") -> str:
    """The error line: ``[seq] ERROR:101 #text`` (CANopenNode) or ``[seq] ERROR: 101
    (text)`` (Lely); an SDO abort code (above 0xFFFF) in hex."""
    head = "" if seq is None else f"[{seq}] "
    if dialect == "lely":
        number = f"{code:08X}" if code > 0xFFFF else str(code)
        return f"{head}ERROR: {number} ({text})"
    number = f"0x{code:08X}" if code > 0xFFFF else str(code)
    return f"{head}ERROR:{number} #{text}"
