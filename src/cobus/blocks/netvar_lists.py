"""CAN network variable lists: the shared definition file and how each list packs into
frames (the wire format is written down in ``docs/network-variables.md``).

One YAML file, the same on every controller::

    controllers: [plc1, plc2]            # optional: the senders must be among them
    lists:
      line_status:
        id: 0x300                        # the list identifier: COB-ID of its first frame
        sender: plc1                     # the controller that writes it; the others read
        transmit: cyclic                 # cyclic | on_change | on_event
        interval: 100 ms                 # cyclic: the period
        request_at_boot: true            # a reader asks for it when it starts
        variables:
          speed: REAL32
          running: BOOLEAN
          temps: {array: INTEGER16, length: 4}
          motor: {struct: {current: REAL32, voltage: UNSIGNED16}}
          label: {string: 8}
      alarms:
        id: 0x310
        sender: plc2
        transmit: on_change
        min_gap: 20 ms                   # on_change: at most one transmission per gap
        variables: {code: UNSIGNED16, active: BOOLEAN}
      recipe:
        id: 0x320
        sender: plc1
        transmit: on_event
        event: send                      # on_event: a BOOLEAN of the list; its rising edge sends
        frames: 4                        # optional: the frames (COB-IDs) the list may take
        variables: {send: BOOLEAN, number: UNSIGNED32, setpoint: REAL64}

Structs and arrays are flattened into variables named ``motor.current`` and ``temps[2]``.
Every problem is reported with file, line and key (:class:`NetVarConfigError`): an unknown
type, overlapping COB-ID ranges, a COB-ID CANopen reserves, a list longer than its frames allow.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cobus._yaml import DataFileError, FileProblem, LineMap, line_of, milliseconds, read_yaml
from cobus.od import DataType, data_type_named, decode, encode
from cobus.proto.connection_set import SYNC_COB_ID, TIME_COB_ID
from cobus.proto.pdo import is_restricted_can_id


def _reserved(can_id: int) -> bool:
    """CiA 301's restricted identifiers, and those of SYNC (080h), EMCY (081h-0FFh) and
    TIME (100h), which a PDO may take over but a variable list must not."""
    return is_restricted_can_id(can_id) or SYNC_COB_ID <= can_id <= TIME_COB_ID


__all__ = [
    "MAX_FRAMES",
    "NetVar",
    "NetVarConfigError",
    "NetVarDefinition",
    "NetVarProblem",
    "VarList",
    "load_netvars",
    "loads_netvars",
]

#: Frames a list may take at most (7 data bytes each when there are several: 112 bytes).
MAX_FRAMES = 16
_MODES = ("cyclic", "on_change", "on_event")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_MAX_ELEMENTS = 256
_MAX_DEPTH = 8
_MAX_PROBLEMS = 100
#: The shortest interval of a cyclic list (a shorter one would flood the bus).
MIN_INTERVAL = 0.001


class NetVarProblem(FileProblem):
    """One problem of a network variable definition: where (file, line, key) and why."""


class NetVarConfigError(DataFileError):
    """A network variable definition that cannot be used; ``problems`` lists every one found."""

    what = "the network variable definition"


@dataclass(frozen=True)
class NetVar:
    """One (flattened) variable: its name, type, and where it lies in the list's bytes."""

    name: str
    data_type: DataType
    offset: int
    size: int

    def encode(self, value: Any) -> bytes:
        """The variable's bytes (a string padded with NUL to its length)."""
        if self.data_type is DataType.VISIBLE_STRING:
            if not isinstance(value, str):
                raise ValueError(f"{self.name}: give text, not {value!r}")
            data = value.encode("latin-1", errors="strict")
            if len(data) > self.size:
                raise ValueError(f"{self.name}: {value!r} is longer than {self.size} characters")
            return data.ljust(self.size, b"\0")
        return encode(self.data_type, value)

    def decode(self, data: bytes) -> Any:
        """The value of the variable's bytes."""
        if self.data_type is DataType.VISIBLE_STRING:
            return data.split(b"\0", 1)[0].decode("latin-1")
        return decode(self.data_type, data)

    @property
    def zero(self) -> Any:
        """The value before anything was received or set."""
        if self.data_type is DataType.VISIBLE_STRING:
            return ""
        return self.decode(bytes(self.size))


@dataclass(frozen=True)
class VarList:
    """One variable list and how it goes on the bus."""

    name: str
    #: The list identifier: the COB-ID of its first frame (frame k: ``cob_id + k``).
    cob_id: int
    sender: str
    #: "cyclic", "on_change" or "on_event".
    transmit: str
    variables: tuple[NetVar, ...]
    #: Seconds between transmissions (cyclic), or None.
    interval: float | None = None
    #: Seconds at least between two transmissions (on_change).
    min_gap: float = 0.0
    #: The BOOLEAN variable whose rising edge sends the list (on_event), or None.
    event: str | None = None
    request_at_boot: bool = False
    #: The frames (COB-IDs) reserved for the list: at least those it needs.
    reserved: int = 1
    line: int | None = None
    #: The line of its ``id`` (for messages).
    id_line: int | None = None

    @property
    def size(self) -> int:
        """Bytes of the packed variables."""
        return sum(v.size for v in self.variables)

    @property
    def headed(self) -> bool:
        """Whether each frame starts with a counter byte: when the list takes, or reserves,
        more than one frame (a one-frame list without reserve is its payload alone)."""
        return self.reserved > 1 or self.size > 8

    @property
    def frames(self) -> int:
        """Frames per transmission: 1 for up to 8 bytes without a header, else one per 7
        payload bytes (each with a counter byte first)."""
        return max(1, -(-self.size // 7)) if self.headed else 1

    @property
    def cob_ids(self) -> range:
        """The COB-IDs the list's frames use."""
        return range(self.cob_id, self.cob_id + self.frames)

    def variable(self, name: str) -> NetVar:
        """The variable ``name``; KeyError names the ones there are."""
        for var in self.variables:
            if var.name == name:
                return var
        names = ", ".join(v.name for v in self.variables)
        raise KeyError(f"list {self.name!r} has no variable {name!r}; it has: {names}")

    def pack(self, values: Mapping[str, Any]) -> bytes:
        """The list's bytes from its values (each variable must be there)."""
        return b"".join(var.encode(values[var.name]) for var in self.variables)

    def unpack(self, data: bytes) -> dict[str, Any]:
        """The values of the list's bytes."""
        return {v.name: v.decode(data[v.offset : v.offset + v.size]) for v in self.variables}

    def split(self, payload: bytes, counter: int) -> list[bytes]:
        """The data of each frame: the payload itself when it fits one frame, else a
        counter byte and up to 7 payload bytes per frame."""
        if not self.headed:
            return [payload]
        head = bytes([counter & 0xFF])
        return [head + payload[k : k + 7] for k in range(0, max(len(payload), 1), 7)]


def frames_for(size: int) -> int:
    """Frames a list of ``size`` bytes takes."""
    return 1 if size <= 8 else -(-size // 7)


@dataclass(frozen=True)
class NetVarDefinition:
    """Every list of a definition file, by name."""

    lists: Mapping[str, VarList]
    controllers: tuple[str, ...] = ()
    path: str | None = None

    def __getitem__(self, name: str) -> VarList:
        found = self.lists.get(name)
        if found is None:
            raise KeyError(f"no variable list {name!r}; the lists: {', '.join(self.lists)}")
        return found


# ------------------------------------------------------------------------------- reading


class _Reader:
    def __init__(self, path: str) -> None:
        self.path = path
        self.problems: list[NetVarProblem] = []

    def error(self, line: int | None, key: str | None, reason: str) -> None:
        self.problems.append(NetVarProblem(self.path, line, key, reason))

    def flatten(
        self,
        name: str,
        spec: Any,
        line: int | None,
        out: list[tuple[str, DataType, int]],
        depth: int,
        key: str,
    ) -> bool:
        """Append (name, type, size) of every scalar ``spec`` holds; False when ``spec`` is
        wrong (reported once, under ``key``: its place in the file)."""
        where = f"{key}.{name}"
        if depth > _MAX_DEPTH:
            self.error(line, where, f"nested more than {_MAX_DEPTH} deep")
            return False
        if len(out) > _MAX_ELEMENTS:
            return True  # (reported by the caller: too many values)
        if isinstance(spec, str | int) and not isinstance(spec, bool):
            data_type = data_type_named(spec)
            if data_type is None or data_type.size is None:
                self.error(
                    line,
                    where,
                    f"type {spec!r} is not a CiA 301 type of fixed size (UNSIGNED16, REAL32, "
                    "BOOLEAN...; text: {string: LENGTH})",
                )
                return False
            out.append((name, data_type, data_type.size))
            return True
        shapes = "give a type, {array: T, length: N}, {struct: {...}} or {string: N}"
        if not isinstance(spec, Mapping):
            self.error(line, where, shapes)
            return False
        if set(spec) == {"string"}:
            length = spec["string"]
            if isinstance(length, bool) or not isinstance(length, int) or not 1 <= length <= 112:
                self.error(line, where, f"string length {length!r}: 1..112 characters")
                return False
            out.append((name, DataType.VISIBLE_STRING, length))
            return True
        if set(spec) == {"array", "length"}:
            length = spec["length"]
            if isinstance(length, bool) or not isinstance(length, int) or not 1 <= length <= 112:
                self.error(line, where, f"array length {length!r}: 1..112 elements")
                return False
            for n in range(length):  # (a wrong element type is reported once, not n times)
                if not self.flatten(f"{name}[{n}]", spec["array"], line, out, depth + 1, key):
                    return False
                if len(out) > _MAX_ELEMENTS:
                    break
            return True
        if set(spec) == {"struct"} and isinstance(spec["struct"], Mapping) and spec["struct"]:
            members = spec["struct"]
            fine = True
            for member, sub in members.items():
                mline = line_of(members, member)
                if not isinstance(member, str) or not _NAME.match(member):
                    self.error(mline, f"{where}.{member}", "not a valid name")
                    fine = False
                    continue
                fine = self.flatten(f"{name}.{member}", sub, mline, out, depth + 1, key) and fine
                if len(self.problems) > _MAX_PROBLEMS:
                    return False
            return fine
        self.error(line, where, shapes)
        return False

    def seconds(self, raw: Any, line: int | None, key: str) -> float | None:
        try:
            ms = milliseconds(raw, 3_600_000)
        except ValueError as exc:
            self.error(line, key, str(exc))
            return None
        return ms / 1000.0

    def read_list(self, name: Any, raw: Any, line: int | None) -> VarList | None:
        key = f"lists.{name}"
        if not isinstance(name, str) or not _NAME.match(name):
            self.error(line, key, "a list name is a word (letters, digits, _)")
            return None
        if not isinstance(raw, Mapping):
            self.error(line, key, "give the list's id, sender, transmit and variables")
            return None
        known = {
            "id",
            "sender",
            "transmit",
            "interval",
            "min_gap",
            "event",
            "request_at_boot",
            "frames",
            "variables",
        }
        for extra in set(raw) - known:
            self.error(
                line_of(raw, extra), f"{key}.{extra}", f"unknown key ({', '.join(sorted(known))})"
            )
        problems = len(self.problems)
        cob_id = raw.get("id")
        if isinstance(cob_id, bool) or not isinstance(cob_id, int) or not 1 <= cob_id <= 0x7FF:
            self.error(line_of(raw, "id"), f"{key}.id", f"{cob_id!r}: an 11-bit COB-ID 001h..7FFh")
            cob_id = None
        sender = raw.get("sender")
        if not isinstance(sender, str) or not sender:
            self.error(
                line_of(raw, "sender"), f"{key}.sender", "name the controller that writes it"
            )
        transmit = raw.get("transmit", "cyclic")
        if transmit not in _MODES:
            self.error(
                line_of(raw, "transmit"), f"{key}.transmit", f"{transmit!r}: {', '.join(_MODES)}"
            )
        interval = None
        if "interval" in raw:
            interval = self.seconds(raw["interval"], line_of(raw, "interval"), f"{key}.interval")
        if interval is not None and transmit != "cyclic":
            self.error(line_of(raw, "interval"), f"{key}.interval", "only a cyclic list has one")
        if transmit == "cyclic" and interval is not None and 0 < interval < MIN_INTERVAL:
            self.error(line_of(raw, "interval"), f"{key}.interval", "at least 1 ms")
        if transmit == "cyclic" and not interval:
            self.error(
                line_of(raw, "interval"),
                f"{key}.interval",
                "a cyclic list needs an interval above 0",
            )
        min_gap = 0.0
        if "min_gap" in raw and transmit != "on_change":
            self.error(line_of(raw, "min_gap"), f"{key}.min_gap", "only an on_change list has one")
        if "min_gap" in raw:
            min_gap = self.seconds(raw["min_gap"], line_of(raw, "min_gap"), f"{key}.min_gap") or 0.0
        request = raw.get("request_at_boot", False)
        if not isinstance(request, bool):
            self.error(line_of(raw, "request_at_boot"), f"{key}.request_at_boot", "true or false")
            request = False
        raw_vars = raw.get("variables")
        flat: list[tuple[str, DataType, int]] = []
        if not isinstance(raw_vars, Mapping) or not raw_vars:
            self.error(line_of(raw, "variables"), f"{key}.variables", "give the list's variables")
        else:
            for var_name, spec in raw_vars.items():
                vline = line_of(raw_vars, var_name)
                if not isinstance(var_name, str) or not _NAME.match(var_name):
                    self.error(vline, f"{key}.variables.{var_name}", "not a valid name")
                    continue
                self.flatten(var_name, spec, vline, flat, 0, f"{key}.variables")
                if len(self.problems) > _MAX_PROBLEMS:
                    break
        if len(flat) > _MAX_ELEMENTS:
            self.error(line_of(raw, "variables"), f"{key}.variables", "more than 256 values")
        variables, offset = [], 0
        for var_name, data_type, size in flat[:_MAX_ELEMENTS]:
            variables.append(NetVar(var_name, data_type, offset, size))
            offset += size
        needed = frames_for(offset)
        reserved = needed
        if "frames" in raw:
            frames = raw["frames"]
            fline = line_of(raw, "frames")
            if (
                isinstance(frames, bool)
                or not isinstance(frames, int)
                or not 1 <= frames <= MAX_FRAMES
            ):
                self.error(fline, f"{key}.frames", f"{frames!r}: 1..{MAX_FRAMES}")
            elif needed > frames:
                room = 8 if frames == 1 else frames * 7
                self.error(
                    fline,
                    f"{key}.frames",
                    f"the variables take {offset} bytes, {needed} frames; {frames} frame(s) "
                    f"carry {room} bytes",
                )
            else:
                reserved = frames
        if needed > MAX_FRAMES:
            self.error(
                line_of(raw, "variables"),
                f"{key}.variables",
                f"the variables take {offset} bytes, {needed} frames; a list carries at most "
                f"{MAX_FRAMES * 7} bytes ({MAX_FRAMES} frames): split it",
            )
        event = raw.get("event")
        if transmit == "on_event" and event is not None:
            try:
                kind = next(v.data_type for v in variables if v.name == event)
            except StopIteration:
                self.error(
                    line_of(raw, "event"), f"{key}.event", f"{event!r} is no variable of the list"
                )
            else:
                if kind is not DataType.BOOLEAN:
                    self.error(line_of(raw, "event"), f"{key}.event", f"{event!r} is no BOOLEAN")
        elif event is not None:
            self.error(line_of(raw, "event"), f"{key}.event", "only an on_event list has an event")
        if cob_id is not None:
            last = cob_id + reserved - 1
            if last > 0x7FF:
                self.error(line_of(raw, "id"), f"{key}.id", f"its {reserved} frames run past 7FFh")
            for can_id in range(cob_id, min(last, 0x7FF) + 1):
                if _reserved(can_id):
                    self.error(
                        line_of(raw, "id"),
                        f"{key}.id",
                        f"COB-ID {can_id:03X}h is reserved by CANopen (NMT, SYNC, EMCY, SDO, "
                        "heartbeat, LSS)",
                    )
                    break
        if len(self.problems) > problems:
            return None
        assert cob_id is not None and isinstance(sender, str)
        return VarList(
            name,
            cob_id,
            sender,
            str(transmit),
            tuple(variables),
            interval,
            min_gap,
            event,
            request,
            reserved,
            line,
            line_of(raw, "id"),
        )


def loads_netvars(text: str, *, path: str = "<string>") -> NetVarDefinition:
    """Read a definition from YAML text; :class:`NetVarConfigError` lists every problem."""
    reader = _Reader(path)
    data, problems = read_yaml(text)
    for problem in problems:
        reader.error(problem.line, problem.key, problem.reason)
    if data is None or problems:
        if not problems:
            reader.error(None, None, "the file is empty: give 'lists:'")
        raise NetVarConfigError(reader.problems)
    if not isinstance(data, LineMap):
        raise NetVarConfigError([NetVarProblem(path, None, None, "give a mapping with 'lists:'")])
    for key in data:
        if key not in ("lists", "controllers"):
            reader.error(line_of(data, key), str(key), "unknown key (lists, controllers)")
    controllers: tuple[str, ...] = ()
    raw_controllers = data.get("controllers", [])
    if not isinstance(raw_controllers, list) or not all(
        isinstance(c, str) for c in raw_controllers
    ):
        reader.error(line_of(data, "controllers"), "controllers", "a list of names")
    elif len(set(raw_controllers)) != len(raw_controllers) or "" in raw_controllers:
        reader.error(line_of(data, "controllers"), "controllers", "names given twice or empty")
    else:
        controllers = tuple(raw_controllers)
    raw_lists = data.get("lists")
    lists: dict[str, VarList] = {}
    if not isinstance(raw_lists, Mapping) or not raw_lists:
        reader.error(line_of(data, "lists"), "lists", "give the variable lists")
    else:
        for name, raw in raw_lists.items():
            found = reader.read_list(name, raw, line_of(raw_lists, name))
            if found is None:
                continue
            if controllers and found.sender not in controllers:
                reader.error(
                    line_of(raw, "sender"),
                    f"lists.{name}.sender",
                    f"{found.sender!r} is not one of the controllers ({', '.join(controllers)})",
                )
            lists[name] = found
    widest: VarList | None = None  # of the lists so far, the one reaching highest
    for second in sorted(lists.values(), key=lambda lst: (lst.cob_id, lst.reserved)):
        if widest is not None and second.cob_id <= widest.cob_id + widest.reserved - 1:
            first = widest
            reader.error(
                second.id_line,
                f"lists.{second.name}.id",
                f"COB-IDs {second.cob_id:03X}h.. overlap list {first.name!r} "
                f"({first.cob_id:03X}h..{first.cob_id + first.reserved - 1:03X}h)",
            )
        if widest is None or (second.cob_id + second.reserved > widest.cob_id + widest.reserved):
            widest = second
    if reader.problems:
        raise NetVarConfigError(reader.problems)
    return NetVarDefinition(lists, controllers, path)


def load_netvars(path: str | os.PathLike[str]) -> NetVarDefinition:
    """Read a definition file; :class:`NetVarConfigError` lists every problem."""
    name = os.fspath(path)
    try:
        text = Path(name).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else str(exc)
        raise NetVarConfigError(
            [NetVarProblem(name, None, None, f"cannot read: {reason}")]
        ) from None
    return loads_netvars(text, path=name)
