"""CODESYS ``.gvl`` files: the network variable lists a CODESYS project exports ("Export"
of a network variable list, or "link to file"), read into
:class:`~cobus.blocks.netvar_udp.UdpVarList`, and written for the lists cobus sends, so a
CODESYS user imports them ("Import from file")::

    <GVL>
      <Declarations><![CDATA[VAR_GLOBAL
        speed : REAL;
        temps : ARRAY[0..3] OF INT;
      END_VAR]]></Declarations>
      <NetvarSettings Protocol="UDP">
        <ListIdentifier>1</ListIdentifier>
        <Pack>True</Pack>
        <Checksum>False</Checksum>
        <Acknowledge>False</Acknowledge>
        <CyclicTransmission>True</CyclicTransmission>
        <TransmissionOnChange>False</TransmissionOnChange>
        <TransmissionOnEvent>False</TransmissionOnEvent>
        <Interval>T#50ms</Interval>
        <MinGap>T#20ms</MinGap>
        <EventVariable></EventVariable>
        <ProtocolSettings>
          <ProtocolSetting Name="Broadcast Adr." Value="255.255.255.255" />
          <ProtocolSetting Name="Port" Value="1202" />
        </ProtocolSettings>
      </NetvarSettings>
    </GVL>

The declarations are the ST subset CODESYS puts there: comments ``(* *)`` and ``//``,
pragmas ``{...}``, several names per declaration (``a, b : INT;``), initial values
(ignored: a reader takes the sender's), ``ARRAY[a..b] OF`` (and ``[a..b, c..d]``),
``STRING(n)``, ``WSTRING(n)`` and the elementary types. User STRUCT and ENUM types are not
in the file: give their ST definitions (``TYPE ... END_TYPE``) beside it. A list with
``Checksum`` or ``Acknowledge`` on is refused: neither is published.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from cobus.blocks.netvar_lists import MIN_INTERVAL
from cobus.blocks.netvar_udp import (
    DEFAULT_PORT,
    IecType,
    UdpVarList,
    iec_type,
    layout,
)
from cobus.errors import CobusError

__all__ = ["GvlError", "StTypes", "dumps_gvl", "load_gvl", "loads_gvl", "parse_st_types"]

#: Bytes of a .gvl file cobus reads at most (a list is 64 KiB of values at most).
MAX_FILE = 4 << 20
#: Values (array elements and struct members) of one list at most.
MAX_VALUES = 65_535
_MAX_DEPTH = 8
#: Types whose layout in a telegram nobody has published.
_UNKNOWN_LAYOUT = {"LTIME", "LDATE", "LDT", "LTOD", "LDATE_AND_TIME", "LTIME_OF_DAY"}
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_ARRAY = re.compile(r"ARRAY\s*\[(.*?)\]\s*OF\s+(.*)\Z", re.IGNORECASE | re.DOTALL)
_RANGE = re.compile(r"\s*([+-]?\d+)\s*\.\.\s*([+-]?\d+)\s*\Z")
_ENUM_BASES = (
    "SINT",
    "USINT",
    "INT",
    "UINT",
    "DINT",
    "UDINT",
    "LINT",
    "ULINT",
    "BYTE",
    "WORD",
    "DWORD",
    "LWORD",
)


class GvlError(CobusError, ValueError):
    """A .gvl file (or ST type definition) cobus cannot use: where and why."""


# ------------------------------------------------------------------ ST text


def _clean(text: str, source: str, line: int = 1) -> str:
    """``text`` with comments and pragmas blanked out, and the insides of strings (an
    initial value, which cobus does not use: a ``;``, ``END_VAR`` or ``$'`` in one changes
    nothing), newlines kept so lines stay where they were; a comment or string that does
    not end is an error (it would hide the rest)."""

    def unended(what: str, at: int) -> GvlError:
        return GvlError(f"{source}: line {line + text.count(chr(10), 0, at)}: {what} does not end")

    out: list[str] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("(*", i):
            depth, j = 1, i + 2
            while j < n and depth:  # (CODESYS nests them)
                if text.startswith("(*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*)", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            if depth:
                raise unended("a (* comment", i)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif c == "{":
            j = text.find("}", i)
            if j < 0:
                raise unended("a { pragma", i)
            j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c in "'\"":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "$" else 1
            if j >= n:
                raise unended("a string", i)
            out.append(c + re.sub(r"[^\n]", "_", text[i + 1 : min(j, n)]) + text[j : j + 1])
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def _statements(text: str, base: int) -> list[tuple[str, int]]:
    """Cleaned ``text`` split at ``;`` (none is left in a string): (statement, its line
    counted from ``base``)."""
    out: list[tuple[str, int]] = []
    start = 0
    for statement in text.split(";"):
        if statement.strip():
            out.append((statement, base + text.count("\n", 0, start) + _lead(statement)))
        start += len(statement) + 1
    return out


def _lead(statement: str) -> int:
    """Newlines before a statement's first character."""
    stripped = statement.lstrip()
    return statement[: len(statement) - len(stripped)].count("\n")


def _without_init(declared: str) -> str:
    """A type without its initial value (``INT := 5`` -> ``INT``; cleaned text: no string
    holds a ``:=``)."""
    return declared.split(":=", 1)[0]


@dataclass
class _Struct:
    members: list[tuple[str, str, int]]  # (name, type text, line)


@dataclass
class StTypes:
    """User types from ST ``TYPE ... END_TYPE`` text: structs (members), enums (their
    base type) and aliases, by upper-case name."""

    structs: dict[str, _Struct]
    enums: dict[str, str]
    aliases: dict[str, str]
    source: str = "<types>"
    #: Each type's name as it was written, by upper-case name.
    spelled: dict[str, str] = field(default_factory=dict)

    def names(self) -> list[str]:
        """The types' names, as written."""
        return sorted(self.spelled.get(n, n) for n in {*self.structs, *self.enums, *self.aliases})


def parse_st_types(text: str, source: str = "<types>") -> StTypes:
    """The STRUCT, ENUM and alias types of ST ``TYPE ... END_TYPE`` blocks (what CODESYS
    shows as a DUT's declaration); :class:`GvlError` says where a definition is wrong."""
    types = StTypes({}, {}, {}, source)
    clean = _clean(text, source)
    for block in re.finditer(r"\bTYPE\b(.*?)\bEND_TYPE\b", clean, re.IGNORECASE | re.DOTALL):
        body = block.group(1)
        base = clean.count("\n", 0, block.start(1)) + 1
        _types_of(body, base, types)
    if not (types.structs or types.enums or types.aliases) and clean.strip():
        raise GvlError(f"{source}: no TYPE ... END_TYPE block: give the types as ST")
    return types


def _types_of(body: str, base: int, types: StTypes) -> None:
    source = types.source
    odd = re.search(r"\b(UNION|EXTENDS|POINTER|REFERENCE|INTERFACE)\b", body, re.IGNORECASE)
    if odd is not None:
        line = base + body.count("\n", 0, odd.start())
        raise GvlError(
            f"{source}: line {line}: {odd.group(1).upper()} is not something cobus sends as "
            "network variables: give the values as a STRUCT of elementary types and arrays"
        )
    # structs first (their members hold semicolons)
    pattern = re.compile(
        r"([A-Za-z_]\w*)\s*:\s*STRUCT\b(.*?)\bEND_STRUCT\b\s*;?", re.IGNORECASE | re.DOTALL
    )
    rest_parts: list[tuple[str, int]] = []
    at = 0
    for match in pattern.finditer(body):
        rest_parts.append((body[at : match.start()], base + body.count("\n", 0, at)))
        at = match.end()
        name = match.group(1).upper()
        types.spelled[name] = match.group(1)
        line0 = base + body.count("\n", 0, match.start(2))
        members: list[tuple[str, str, int]] = []
        for statement, line in _statements(match.group(2), line0):
            members += _declaration(statement, line, source)
        if not members:
            raise GvlError(f"{source}: line {line0}: STRUCT {match.group(1)} has no members")
        types.structs[name] = _Struct(members)
    rest_parts.append((body[at:], base + body.count("\n", 0, at)))
    for part, line0 in rest_parts:
        for statement, line in _statements(part, line0):
            name, colon, declared = statement.partition(":")
            name = name.strip()
            if not colon or not _IDENT.match(name):
                raise GvlError(
                    f"{source}: line {line}: {statement.strip()!r} is no type definition"
                )
            declared = declared.strip()
            types.spelled[name.upper()] = name
            enum = re.match(r"\((.*)\)\s*(\w*)\s*(?::=.*)?\Z", declared, re.DOTALL)
            if enum is not None:
                base_type = (enum.group(2) or "INT").upper()
                if base_type not in _ENUM_BASES:
                    raise GvlError(
                        f"{source}: line {line}: ENUM {name} on {base_type}: an enum's base is "
                        "an integer type"
                    )
                types.enums[name.upper()] = base_type
            else:
                types.aliases[name.upper()] = _without_init(declared).strip()


def _declaration(statement: str, line: int, source: str) -> list[tuple[str, str, int]]:
    """``a, b : INT := 1`` -> [(a, INT, line), (b, INT, line)]."""
    if not statement.strip():
        return []
    names, colon, declared = statement.partition(":")
    if not colon or declared.startswith("="):
        raise GvlError(f"{source}: line {line}: {statement.strip()!r}: write NAME : TYPE;")
    declared = _without_init(declared).strip()
    out = []
    for raw in names.split(","):
        name = re.sub(r"\s+AT\s+%\S+\s*\Z", "", raw.strip(), flags=re.IGNORECASE)
        if not _IDENT.match(name):
            raise GvlError(f"{source}: line {line}: {raw.strip()!r} is no variable name")
        out.append((name, declared, line))
    if not declared:
        raise GvlError(f"{source}: line {line}: {names.strip()} has no type")
    return out


def _flatten(
    name: str,
    declared: str,
    line: int,
    types: StTypes,
    source: str,
    budget: list[int],
    depth: int = 0,
) -> list[tuple[str, IecType]]:
    """The elementary values of a declaration, in the order they go on the wire;
    ``budget[0]``: values the list may still take (counted down as they are found, so a
    type that would give millions stops at once)."""
    if depth > _MAX_DEPTH:
        raise GvlError(f"{source}: line {line}: {name}: types nested deeper than {_MAX_DEPTH}")
    text = " ".join(declared.split())
    subrange = re.match(r"(\w+)\s*\(\s*[+-]?\d+\s*\.\.\s*[+-]?\d+\s*\)\Z", text)
    if subrange is not None:  # (INT(0..10): an INT)
        text = subrange.group(1)
    array = _ARRAY.match(text)
    if array is not None:
        ranges = []
        for dim in array.group(1).split(","):
            bounds = _RANGE.match(dim)
            if bounds is None:
                raise GvlError(
                    f"{source}: line {line}: {name}: ARRAY[{array.group(1)}]: give each "
                    "dimension as two whole numbers, LOW..HIGH (no constants)"
                )
            low, high = int(bounds.group(1)), int(bounds.group(2))
            if high < low:
                raise GvlError(f"{source}: line {line}: {name}: ARRAY[{low}..{high}] is empty")
            ranges.append(range(low, high + 1))
        total = 1
        for r in ranges:
            total *= len(r)
        if total > budget[0]:
            raise GvlError(
                f"{source}: line {line}: {name}: more than {MAX_VALUES} values in a list"
            )
        out: list[tuple[str, IecType]] = []
        for index in _indices(ranges):
            label = f"{name}[{', '.join(str(i) for i in index)}]"
            out += _flatten(label, array.group(2), line, types, source, budget, depth + 1)
        return out
    upper = text.upper()
    if upper in types.structs:
        out = []
        for member, member_type, _ in types.structs[upper].members:
            out += _flatten(f"{name}.{member}", member_type, line, types, source, budget, depth + 1)
        return out
    if upper in types.aliases:
        return _flatten(name, types.aliases[upper], line, types, source, budget, depth + 1)
    budget[0] -= 1
    if budget[0] < 0:
        raise GvlError(f"{source}: line {line}: {name}: more than {MAX_VALUES} values in a list")
    if upper in types.enums:
        return [(name, iec_type(types.enums[upper]))]
    if upper in _UNKNOWN_LAYOUT:
        raise GvlError(
            f"{source}: line {line}: {name}: {upper}: how it goes in a telegram is published "
            "nowhere, so cobus refuses it"
        )
    try:
        return [(name, iec_type(text))]
    except ValueError as exc:
        if re.match(r"W?STRING\b", upper):
            raise GvlError(f"{source}: line {line}: {name}: {exc}") from None
    if _IDENT.match(text):
        given = f" (types given: {', '.join(types.names())})" if types.names() else ""
        raise GvlError(
            f"{source}: line {line}: {name}: type {text} is not elementary and not defined: "
            f"give its TYPE ... END_TYPE text beside the .gvl{given}"
        )
    raise GvlError(f"{source}: line {line}: {name}: {text!r} is no type cobus reads")


def _indices(ranges: list[range]) -> Iterable[tuple[int, ...]]:
    """Every index of an array, the last dimension fastest."""
    if not ranges:
        yield ()
        return
    for first in ranges[0]:
        for rest in _indices(ranges[1:]):
            yield (first, *rest)


def declared_values(
    declarations: str, types: StTypes | None = None, source: str = "<gvl>", line: int = 1
) -> list[tuple[str, IecType]]:
    """The values of ``VAR_GLOBAL ... END_VAR`` declarations, flattened in wire order."""
    types = types or StTypes({}, {}, {}, source)
    clean = _clean(declarations, source, line)
    blocks = list(
        re.finditer(
            r"\bVAR_GLOBAL\b((?:\s+(?:CONSTANT|RETAIN|PERSISTENT|NON_RETAIN)\b)*)(.*?)\bEND_VAR\b",
            clean,
            re.IGNORECASE | re.DOTALL,
        )
    )
    if not blocks:
        raise GvlError(f"{source}: no VAR_GLOBAL ... END_VAR in the declarations")
    values: list[tuple[str, IecType]] = []
    seen: set[str] = set()
    budget = [MAX_VALUES]
    for block in blocks:
        at = line + clean.count("\n", 0, block.start())
        qualifier = block.group(1).strip().upper()
        if "CONSTANT" in qualifier.split():
            raise GvlError(
                f"{source}: line {at}: VAR_GLOBAL CONSTANT: constants are not network variables"
            )
        base = line + clean.count("\n", 0, block.start(2))
        for statement, where in _statements(block.group(2), base):
            for name, declared, _ in _declaration(statement, where, source):
                if name.upper() in seen:
                    raise GvlError(f"{source}: line {where}: {name} is declared twice")
                seen.add(name.upper())
                values += _flatten(name, declared, where, types, source, budget)
    return values


# ------------------------------------------------------------------ the XML


def _bool(element: ET.Element | None, what: str, source: str, default: bool = False) -> bool:
    if element is None or element.text is None or not element.text.strip():
        return default
    text = element.text.strip().lower()
    if text in ("true", "1"):
        return True
    if text in ("false", "0"):
        return False
    raise GvlError(f"{source}: <{what}>{element.text.strip()}</{what}>: write True or False")


_DURATION = re.compile(r"(\d+(?:\.\d+)?)(ms|us|ns|d|h|m|s)", re.IGNORECASE)
_UNITS = {"d": 86_400.0, "h": 3_600.0, "m": 60.0, "s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def iec_time(text: str) -> float:
    """Seconds of an IEC TIME literal (``T#50ms``, ``TIME#1s500ms``, ``t#1m``); ValueError
    when it is none."""
    word = text.strip().replace("_", "")
    head, sharp, body = word.partition("#")
    if not sharp or head.upper() not in ("T", "TIME", "LTIME", "LT"):
        raise ValueError(f"{text!r} is no TIME literal (T#50ms)")
    body = body.lstrip("+")
    parts = _DURATION.findall(body)
    if not parts or "".join(n + u for n, u in parts).lower() != body.lower():
        raise ValueError(f"{text!r} is no TIME literal (T#50ms)")
    return sum(float(n) * _UNITS[u.lower()] for n, u in parts)


def loads_gvl(
    text: str | bytes,
    *,
    name: str = "list",
    types: StTypes | None = None,
    source: str = "<gvl>",
) -> UdpVarList:
    """The list a .gvl file's text defines (``name``: the list's, the file's stem)."""
    raw = text.encode("utf-8") if isinstance(text, str) else bytes(text)
    if len(raw) > MAX_FILE:
        raise GvlError(f"{source}: {len(raw)} bytes: not a .gvl file (they are small)")
    if b"<!DOCTYPE" in raw.upper() or b"<!ENTITY" in raw.upper():
        raise GvlError(f"{source}: a DOCTYPE or ENTITY: not a .gvl file CODESYS writes")
    try:
        root = ET.fromstring(raw)
    except ET.ParseError as exc:
        raise GvlError(f"{source}: not XML: {exc}") from None
    if root.tag != "GVL":
        raise GvlError(f"{source}: <{root.tag}>: a .gvl file starts with <GVL>")
    declarations = root.find("Declarations")
    if declarations is None or not (declarations.text or "").strip():
        raise GvlError(f"{source}: no <Declarations>: the list's variables are missing")
    settings = root.find("NetvarSettings")
    if settings is None:
        raise GvlError(f"{source}: no <NetvarSettings>: a plain GVL, not a network variable list")
    protocol = settings.get("Protocol", "")
    if protocol.upper() != "UDP":
        raise GvlError(
            f"{source}: Protocol {protocol or '(none)'}: cobus reads network variable lists "
            "over UDP (its CAN lists are YAML: docs/network-variables.md)"
        )

    def child(tag: str) -> ET.Element | None:
        return settings.find(tag)

    for flag, why in (
        ("Checksum", "its algorithm is not published, so cobus can neither send nor check it"),
        ("Acknowledge", "the acknowledgement telegram is not published"),
    ):
        if _bool(child(flag), flag, source):
            raise GvlError(
                f"{source}: {flag} is on: {why}; turn {flag} off in the list's network "
                "properties in CODESYS"
            )
    id_element = child("ListIdentifier")
    try:
        list_id = int((id_element.text or "").strip()) if id_element is not None else -1
    except ValueError:
        list_id = -1
    if not 0 <= list_id <= 0xFFFF:
        shown = (id_element.text or "").strip() if id_element is not None else "(none)"
        raise GvlError(f"{source}: <ListIdentifier>{shown}: give the list's number, 0..65535")
    cyclic = _bool(child("CyclicTransmission"), "CyclicTransmission", source)
    on_change = _bool(child("TransmissionOnChange"), "TransmissionOnChange", source)
    on_event = _bool(child("TransmissionOnEvent"), "TransmissionOnEvent", source)

    def duration(tag: str, default: float) -> float:
        element = child(tag)
        if element is None or not (element.text or "").strip():
            return default
        try:
            return iec_time(element.text or "")
        except ValueError as exc:
            raise GvlError(f"{source}: <{tag}>: {exc}") from None

    interval = duration("Interval", 0.05)
    min_gap = duration("MinGap", 0.02)
    event_element = child("EventVariable")
    event = (event_element.text or "").strip() if event_element is not None else ""
    address, port = "255.255.255.255", DEFAULT_PORT
    for setting in settings.iter("ProtocolSetting"):
        key = (setting.get("Name") or "").lower()
        value = (setting.get("Value") or "").strip()
        if "port" in key:
            if not (value.isascii() and value.isdigit()) or not 1 <= int(value) <= 65_535:
                raise GvlError(f"{source}: Port {value!r}: give a UDP port, 1..65535")
            port = int(value)
        elif "adr" in key or "addr" in key:
            address = value
    line = raw[: raw.find(b"<Declarations")].count(b"\n") + 1
    items = declared_values(declarations.text or "", types, source, line)
    if not items:
        raise GvlError(f"{source}: the list declares no variable")
    if cyclic and interval < MIN_INTERVAL:
        raise GvlError(
            f"{source}: <Interval>: a cyclic list every {interval * 1000:g} ms would flood the "
            f"network: {MIN_INTERVAL * 1000:g} ms at least"
        )
    modes = [
        m for m, on in (("cyclic", cyclic), ("on_change", on_change), ("on_event", on_event)) if on
    ]
    variables = layout(items)
    event_text, event_var = event, None
    if on_event:
        # (CODESYS takes any BOOL of the project, PLC_PRG.xSend...: one of the list's own
        # sends it from cobus on its rising edge; another, only on send())
        if not event:
            raise GvlError(
                f"{source}: TransmissionOnEvent is on but <EventVariable> is empty: name the "
                "BOOL whose rising edge sends the list"
            )
        found = {v.name.upper(): v for v in variables}.get(event.upper())
        if found is not None and found.type.name != "BOOL":
            raise GvlError(
                f"{source}: <EventVariable>{event}: a {found.type.name}; the event is a BOOL"
            )
        event_var = found.name if found is not None else None
    try:
        return UdpVarList(
            name,
            list_id,
            variables,
            pack=_bool(child("Pack"), "Pack", source, default=True),
            transmit=modes[0] if modes else "cyclic",
            modes=frozenset(modes),
            interval=interval,
            min_gap=min_gap,
            event=event_var,
            event_text=event_text,
            address=address,
            port=port,
            declarations=declarations.text or "",
        )
    except ValueError as exc:
        raise GvlError(f"{source}: {exc}") from None


def load_gvl(path: str | os.PathLike[str], *, types: StTypes | None = None) -> UdpVarList:
    """The list of the .gvl file ``path`` (named as the file, without .gvl)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise GvlError(f"{p}: {exc.strerror or exc}") from None
    return loads_gvl(raw, name=p.stem, types=types, source=str(p))


def _bool_text(value: bool) -> str:
    return "True" if value else "False"


def _time_text(seconds: float) -> str:
    ms = seconds * 1000
    if ms == int(ms):
        return f"T#{int(ms)}ms"
    return f"T#{round(seconds * 1e6)}us"


#: Words ST keeps for itself: never written as a variable's name.
_KEYWORDS = frozenset(
    """AND ANY ARRAY AT BOOL BY BYTE CASE CONSTANT DATE DATE_AND_TIME DINT DO DT DWORD ELSE
    ELSIF END_CASE END_FOR END_IF END_REPEAT END_STRUCT END_TYPE END_VAR END_WHILE EXIT
    FALSE FOR FUNCTION IF INT LINT LREAL LTIME LWORD MOD NOT OF OR PERSISTENT POINTER
    PROGRAM REAL REFERENCE REPEAT RETAIN RETURN SINT STRING STRUCT THEN TIME TIME_OF_DAY TO
    TOD TRUE TYPE UDINT UINT ULINT UNTIL USINT VAR VAR_GLOBAL VAR_INPUT VAR_OUTPUT WHILE
    WORD WSTRING XOR""".split()  # noqa: SIM905 (a word list, read as one)
)


def declarations_of(var_list: UdpVarList) -> tuple[str, dict[str, str]]:
    """``VAR_GLOBAL ... END_VAR`` for a list's values: arrays of one type as ``ARRAY``,
    struct members and anything else under a name of its own (``motor_current``; the
    bytes are the same, a .gvl cannot carry struct types); and each value's declared name.
    Each name is declared once (ST does not tell case), none is an ST keyword or starts
    with a digit: the plain names keep theirs, the others get ``_2``... when taken."""
    variables = list(var_list.variables)
    # the units declared: (first value, values, the name wanted); arrays of one type as one
    units: list[tuple[int, int, str]] = []
    i = 0
    while i < len(variables):
        match = re.match(r"([A-Za-z_]\w*)\[0\]\Z", variables[i].name)
        n = 1
        if match is not None:
            base = match.group(1)
            while (
                i + n < len(variables)
                and variables[i + n].name == f"{base}[{n}]"
                and variables[i + n].type == variables[i].type
            ):
                n += 1
        units.append((i, n, match.group(1) if match is not None else variables[i].name))
        i += n
    taken: set[str] = set()
    names: dict[int, str] = {}

    def plain(name: str) -> bool:
        return bool(_IDENT.match(name)) and name.upper() not in _KEYWORDS

    for first, _, wanted in units:  # (first the plain names, as they are)
        if plain(wanted) and wanted.upper() not in taken:
            names[first] = wanted
            taken.add(wanted.upper())
    for first, _, wanted in units:
        if first in names:
            continue
        stem = re.sub(r"\W+", "_", wanted).strip("_") or "value"
        if stem[0].isdigit() or stem.upper() in _KEYWORDS:
            stem = "v_" + stem
        found, k = stem, 2
        while found.upper() in taken:
            found, k = f"{stem}_{k}", k + 1
        names[first] = found
        taken.add(found.upper())
    lines = ["VAR_GLOBAL"]
    renamed: dict[str, str] = {}
    for first, count, wanted in units:
        var, name = variables[first], names[first]
        comment = f"  (* {wanted} *)" if name != wanted else ""
        if wanted != var.name:  # (an array: its first value is wanted[0])
            for k in range(count):
                renamed[variables[first + k].name] = f"{name}[{k}]"
            lines.append(f"\t{name} : ARRAY[0..{count - 1}] OF {var.type.name};{comment}")
        else:
            renamed[var.name] = name
            lines.append(f"\t{name} : {var.type.name};{comment}")
    lines.append("END_VAR")
    return "\n".join(lines), renamed


def dumps_gvl(var_list: UdpVarList) -> str:
    """The .gvl text of a list, as CODESYS writes it (CODESYS: "Import from file")."""
    modes = var_list.modes
    if var_list.declarations:
        declarations, event = var_list.declarations, var_list.event_text or var_list.event
    else:
        declarations, renamed = declarations_of(var_list)
        event = renamed.get(var_list.event, var_list.event) if var_list.event else ""
    if "]]>" in declarations:
        raise GvlError(f"list {var_list.name}: its declarations hold ']]>'")

    def esc(value: str) -> str:
        return (
            value.replace("&", "&amp;")
            .replace("<", "&lt;")
            .replace(">", "&gt;")
            .replace('"', "&quot;")
        )

    return "\n".join(
        [
            "<GVL>",
            f"  <Declarations><![CDATA[{declarations}]]></Declarations>",
            '  <NetvarSettings Protocol="UDP">',
            f"    <ListIdentifier>{var_list.list_id}</ListIdentifier>",
            f"    <Pack>{_bool_text(var_list.pack)}</Pack>",
            "    <Checksum>False</Checksum>",
            "    <Acknowledge>False</Acknowledge>",
            f"    <CyclicTransmission>{_bool_text('cyclic' in modes)}</CyclicTransmission>",
            f"    <TransmissionOnChange>{_bool_text('on_change' in modes)}</TransmissionOnChange>",
            f"    <TransmissionOnEvent>{_bool_text('on_event' in modes)}</TransmissionOnEvent>",
            f"    <Interval>{_time_text(var_list.interval or 0.05)}</Interval>",
            f"    <MinGap>{_time_text(var_list.min_gap)}</MinGap>",
            f"    <EventVariable>{esc(event or '')}</EventVariable>",
            "    <ProtocolSettings>",
            f'      <ProtocolSetting Name="Broadcast Adr." Value="{esc(var_list.address)}" />',
            f'      <ProtocolSetting Name="Port" Value="{var_list.port}" />',
            "    </ProtocolSettings>",
            "  </NetvarSettings>",
            "</GVL>",
            "",
        ]
    )
