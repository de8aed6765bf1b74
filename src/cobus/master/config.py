"""The network description: a YAML file in the spirit of ROS 2 canopen's ``bus.yml``.

```yaml
master:
  node_id: 1               # optional: without it the master sends no heartbeat
  bitrate: 500000          # bit/s
  sync_period: 10          # ms (0: no SYNC); sync_cob_id: 0x80, sync_overflow: 0
  sync_by_interface: false # true: the CAN interface times SYNC (SocketCAN: the kernel;
                           # a simulated network's loop does)
  heartbeat_time: 100      # ms: the master's own heartbeat (needs node_id)
  reset: node              # node | broadcast (one 81h 00 for every node)
  start: node              # node | broadcast (one 01h 00 once every node is configured)
defaults:                  # keys every node takes unless it sets them itself
  heartbeat_time: 100
nodes:
  drive1:
    node_id: 2
    eds: drives/e35.eds    # EDS or DCF, relative to this file (key ``dcf`` works too)
    mandatory: true
    device_type: 0x20192
    tpdo1: {mapping: [statusword, position_actual_value], transmission_type: 1}
    rpdo1: {mapping: [controlword, "0x607A:00"], transmission_type: 255}
    signals:
      position: {object: position_actual_value, scale: 0.001, unit: mm}
```

Times are milliseconds, as plain numbers or as text with a unit (``"1.5 s"``, ``"500 us"``);
``inhibit_time`` is in 100 µs units, as in the dictionary. Objects are named as the node's
EDS names them (case, spaces and punctuation do not matter: ``"Position actual value"`` =
``position_actual_value``), as ``record.sub_name``, ``record[sub]``, or by address
``"0x6041:00"`` (sub-index in hex). :func:`load_network` reads and checks a file;
:func:`check_network` lists every problem with file, line, node and key.

The start-up SDO list of each node is derived from its dictionary: every writable object
whose configured value (DCF ParameterValue, or what this file sets) differs from the EDS
default, the PDOs as the mapping procedure of CiA 301 wants them (disable, clear, map, count,
enable), then the explicit ``sdo`` entries. :meth:`NodeConfig.to_dcf` writes the node's DCF
and :meth:`NodeConfig.concise_dcf` the CiA 302 concise DCF of what the master downloads.
A device whose mapping sub-index 0 is a read-only constant while its entries are writable
(direct mapping, e.g. the STÖBER MDS 5000 of seed 004) gets every entry written instead, 0 for
the unused ones; the master skips those when it reads the mapping.

Devices that are only "based on CANopen" (the EC motor of seed 002: an SDO dialect of its own,
no boot-up, no error control) take ``do_not_initialise: true`` with ``sdo_server: false``: the
master then sends the node no SDO at all (no 1000h/1018h check, no start-up list), counts it
present, and started once it sent the NMT start, and runs its PDOs. An RPDO given an empty
mapping (``rpdo1: {mapping: []}``) is sent with no data (DLC 0), a trigger such a device may
answer, e.g. the EC motor's status poll: a synchronous one with every SYNC, an event-driven
one at the start and with its event timer.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import struct
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from cobus._files import replace_file
from cobus._yaml import line_of, milliseconds, read_yaml
from cobus.errors import CobusError, clip
from cobus.master.errors import (
    ConfigProblem,
    NetworkConfigError,
    NodeNotFoundError,
    Severity,
    SignalValueError,
)
from cobus.od import (
    Array,
    DataType,
    EdsError,
    Finding,
    NameLookupError,
    Object,
    ObjectDictionary,
    Record,
    ValueRangeError,
    Variable,
    encode,
    loads,
    mapping_entries,
    parse_address,
    resolve,
    resolve_object,
    suggestions,
)
from cobus.proto.pdo import (
    Kind,
    MappingEntry,
    PdoCobId,
    PdoError,
    PdoMap,
    RemapStep,
    TransmissionType,
    in_remap_order,
    is_restricted_can_id,
    kind_of_type,
)

__all__ = [
    "BIT_RATES",
    "MasterConfig",
    "NetworkConfig",
    "NodeConfig",
    "PdoLayout",
    "SdoEntry",
    "Signal",
    "check_network",
    "load_network",
    "loads_network",
    "normalise",
    "parse_network",
]

#: The CiA 301 bit rates, in bit/s.
BIT_RATES = (10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000)
_INVALID = 1 << 31
_EXTENDED = 1 << 29
_SAVE, _RESTORE = 0x1010, 0x1011
_ERROR_CONTROL = (0x100C, 0x100D, 0x1017)
_IDENTITY_KEYS = ("vendor_id", "product_code", "revision_number", "serial_number")

# ------------------------------------------------------------------------------- YAML reading


# ------------------------------------------------------------------------------- problems


class _Report:
    def __init__(self, path: str) -> None:
        self.path = path
        self.problems: list[ConfigProblem] = []
        self._seen: set[str] = set()

    def add(
        self,
        severity: Severity,
        node: str | None,
        key: str | None,
        reason: str,
        line: int | None = None,
    ) -> None:
        problem = ConfigProblem(self.path, line, node, key, severity, reason)
        text = str(problem)
        if text not in self._seen:
            self._seen.add(text)
            self.problems.append(problem)

    def error(self, node: str | None, key: str | None, reason: str, line: int | None) -> None:
        self.add(Severity.ERROR, node, key, reason, line)

    def warning(self, node: str | None, key: str | None, reason: str, line: int | None) -> None:
        self.add(Severity.WARNING, node, key, reason, line)

    @property
    def errors(self) -> list[ConfigProblem]:
        return [p for p in self.problems if p.severity is Severity.ERROR]


class _Bad(ValueError):
    """A value that cannot be used; the text says why (a ValueError: what the public
    :class:`ObjectIndex` raises)."""


def _suggest(word: str, choices: Iterable[str]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=3, cutoff=0.6)
    return f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""


# ------------------------------------------------------------------------------- value parsers


def _int(value: Any, low: int, high: int, what: str = "value") -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _Bad(f"{value!r} is not an integer; give a {what} in {low}..{high}")
    if not low <= value <= high:
        raise _Bad(f"{value} is out of range: use {low}..{high}")
    return value


def _bool(value: Any) -> bool:
    if not isinstance(value, bool):
        raise _Bad(f"{value!r} is not true or false (write them without quotes)")
    return value


def _number(value: Any, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise _Bad(f"{value!r} is not a number")
    if not low <= value <= high:
        raise _Bad(f"{value} is out of range: use {low:g}..{high:g}")
    return float(value)


def _choice(value: Any, options: tuple[str, ...]) -> str:
    if not isinstance(value, str) or value not in options:
        raise _Bad(f"{value!r} is not one of {', '.join(options)}")
    return value


def _ms(value: Any, high: float = 1e9) -> float:
    """A duration in milliseconds: a number (ms) or text with a unit."""
    try:
        return milliseconds(value, high)
    except ValueError as exc:
        raise _Bad(str(exc)) from None


def _whole_ms(value: Any, high: int = 0xFFFF) -> int:
    ms = _ms(value, high)
    if ms != int(ms):
        raise _Bad(f"{ms:g} ms is not a whole number of milliseconds (the object counts ms)")
    return int(ms)


# ------------------------------------------------------------------------------- object names


def normalise(name: str) -> str:
    """The lookup form of a name: lower case, runs of other characters as one ``_``."""
    return re.sub(r"[^0-9a-z]+", "_", name.lower()).strip("_")


_DUMMY = re.compile(r"\s*dummy\s*(8|16|32)\s*\Z")
_DUMMY_TYPES = {8: 0x0005, 16: 0x0006, 32: 0x0007}


def _object_named(od: ObjectDictionary, text: str) -> Object | None:
    """The object ``text`` names as a whole (None: it names none, or a sub-object)."""
    try:
        return resolve_object(od, text, suggest=False)
    except NameLookupError:
        return None


class ObjectIndex:
    """Finds a node's objects as a file names them (through :func:`cobus.od.resolve`), with
    the file named in each error, and names its signals (:meth:`canonical`)."""

    #: Unknown names that get "did you mean" (a close-match search each); the ones after
    #: them get none, so that a file of 5,000 unknown names costs no minutes.
    SUGGESTIONS = 20
    #: Names longer than this get no suggestions (a close-match search grows with the
    #: product of the lengths).
    SUGGEST_LENGTH = 100

    def __init__(self, od: ObjectDictionary, file: str) -> None:
        self.od = od
        self.file = file
        self._suggestions = self.SUGGESTIONS
        #: The variables by signal-name key (several: the name is shared).
        self._names: dict[str, list[Variable]] = {}
        for obj in od:
            if obj.index < 0x1000:
                continue
            if isinstance(obj, Variable):
                self._names.setdefault(normalise(obj.name), []).append(obj)
                continue
            parent = normalise(obj.name)
            for var in obj:
                self._names.setdefault(f"{parent}.{normalise(var.name)}", []).append(var)
                self._names.setdefault(f"{parent}[{var.subindex}]", []).append(var)

    def canonical(self, var: Variable) -> str:
        """The signal name of ``var``: its normalised name (``record.sub`` for sub-objects);
        ``record[n]`` when sub-objects share a name, ``name_iiii`` when objects do."""
        if var.parent is None:
            key = normalise(var.name)
            return key if len(self._names.get(key, ())) < 2 else f"{key}_{var.index:04x}"
        parent = normalise(var.parent.name)
        key = f"{parent}.{normalise(var.name)}"
        if len(self._names.get(key, ())) < 2:
            return key
        key = f"{parent}[{var.subindex}]"
        return key if len(self._names.get(key, ())) < 2 else f"{key}_{var.index:04x}"

    def resolve(self, text: Any) -> Variable:
        """The variable ``text`` names, in every form :func:`cobus.od.resolve` takes; a
        ValueError says why none (with close names) or which several."""
        if not isinstance(text, str):
            raise _Bad(
                f"{text!r} is not an object name or address; write a name from the EDS or an "
                'address in quotes, e.g. "0x6041:00"'
            )
        try:
            var = resolve(self.od, text, suggest=False)
            if parse_address(text) is None and var.subindex == 0 and var.parent is not None:
                whole = _object_named(self.od, text)  # (a record's own name?)
                if whole is var.parent:
                    subs = ", ".join(repr(f"{whole.name}.{v.name}") for v in list(whole)[1:4])
                    raise _Bad(
                        f"{text!r} is {'an array' if isinstance(whole, Array) else 'a record'} "
                        f"in {self.file}: name one "
                        f"of its sub-objects ({subs}...) or give the address"
                    )
            return var
        except NameLookupError as exc:
            if exc.candidates:
                where = ", ".join(
                    f"0x{c.index:04X}:{getattr(c, 'subindex', 0):02X}" for c in exc.candidates
                )
                raise _Bad(
                    f"{text!r} names several objects in {self.file} ({where}); use the address"
                ) from None
            address = parse_address(text)
            if address is not None:
                index, sub = address
                raise _Bad(f"{self.file} has no object 0x{index:04X}:{sub or 0:02X}") from None
            if exc.found is not None:
                raise _Bad(f"{self.file}: {exc}") from None
            raise _Bad(
                f"{self.file} has no object named {clip(repr(text), 120)}{self._hint(text)}"
            ) from None

    def _hint(self, text: str) -> str:
        """ " (did you mean ...?)" for the first :attr:`SUGGESTIONS` unknown names."""
        if len(text) > self.SUGGEST_LENGTH:
            return ""
        if self._suggestions <= 0:
            return " (no suggestions after the first ones: fix those first)"
        self._suggestions -= 1
        close = suggestions(self.od, text)
        if not close:
            return ""
        return f" (did you mean {', '.join(repr(c) for c in close)}?)"


_SECTION = re.compile(r"([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]+))?\Z")


def _dropped_value(od: ObjectDictionary, finding: Finding) -> bool:
    """Whether ``finding`` is a ParameterValue the reader could not keep."""
    if not finding.reason.startswith("ParameterValue") or finding.section is None:
        return False
    match = _SECTION.match(finding.section)
    if match is None:
        return False
    var = od.get_variable(int(match.group(1), 16), int(match.group(2) or "0", 16))
    return var is not None and var.parameter_value is None


def _kind(var: Variable, bits: int) -> Kind:
    """proto's rule (:func:`~cobus.proto.pdo.kind_of_type`); a type without a Kind (a
    string, a time) is kept as its bytes in the process image."""
    kind = kind_of_type(var.data_type)
    if kind is not None:
        return kind
    if bits % 8:
        raise _Bad(
            f"0x{var.index:04X}:{var.subindex:02X} ({var.data_type.name}) cannot be mapped "
            f"with {bits} bits"
        )
    return Kind.BYTES


# ------------------------------------------------------------------------------- the model


@dataclass(frozen=True, slots=True)
class SdoEntry:
    """One write of the start-up list: object, encoded data, value and why it is written."""

    index: int
    subindex: int
    data: bytes
    value: Any
    name: str

    def __str__(self) -> str:
        shown = f"0x{self.value:X}" if isinstance(self.value, int) else repr(self.value)
        return f"0x{self.index:04X}:{self.subindex:02X} = {shown} ({self.name})"


@dataclass(frozen=True, slots=True)
class Signal:
    """A named value of the process image, carried by a PDO of a node."""

    name: str  # "node.signal"
    node_id: int
    direction: str  # "input" (from a TPDO of the node) or "output" (to one of its RPDOs)
    pdo: int
    position: int  # among the PDO's non-dummy values
    index: int
    subindex: int
    data_type: DataType
    bits: int
    kind: Kind
    scale: float | None = None
    offset: float = 0.0
    unit: str | None = None
    #: LowLimit / HighLimit of the object in the EDS (raw values), if any.
    low: float | None = None
    high: float | None = None

    def to_engineering(self, raw: Any) -> Any:
        """Value of the signal from the raw mapped value (``raw * scale + offset``)."""
        if self.scale is None:
            return raw + self.offset if self.offset and isinstance(raw, int | float) else raw
        return raw * self.scale + self.offset

    def to_raw(self, value: Any) -> Any:
        """The raw mapped value of an engineering value (rounded for integer objects)."""
        if self.scale is None and not self.offset:
            return value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SignalValueError(f"{self.name}: {value!r} is not a number")
        raw = (value - self.offset) / (self.scale if self.scale is not None else 1.0)
        if self.kind in (Kind.SIGNED, Kind.UNSIGNED):
            return round(raw)
        return raw

    @property
    def zero(self) -> Any:
        """What the signal reads while its node is faulty (inputs set to 0)."""
        if self.kind is Kind.BOOL:
            return False
        if self.kind is Kind.BYTES:
            return bytes(self.bits // 8)
        if self.kind in (Kind.REAL32, Kind.REAL64) or self.scale is not None:
            return 0.0
        return 0


@dataclass(frozen=True, slots=True, eq=False)
class PdoLayout:
    """A PDO as the master sees it: a TPDO of the node (master input) or an RPDO (output)."""

    direction: str  # "tpdo" or "rpdo" (the node's point of view)
    number: int
    cob_id: int
    extended: bool
    transmission_type: int
    event_timer: int  # ms
    inhibit_time: int  # 100 µs
    timeout: float | None  # s: presence supervision of a TPDO (None: not supervised)
    codec: PdoMap
    #: One per non-dummy mapped value: the signal, or None when another PDO exposes it.
    positions: tuple[Signal | None, ...]
    #: An RPDO fed by another node's TPDO (PDO linking): the master does not send it.
    linked: bool = False

    @property
    def signals(self) -> tuple[Signal, ...]:
        """The process image signals the PDO carries, in mapping order."""
        return tuple(s for s in self.positions if s is not None)

    @property
    def synchronous(self) -> bool:
        """Whether the PDO follows SYNC (transmission types 0..240)."""
        return self.transmission_type <= 240

    @property
    def length(self) -> int:
        """The number of data bytes of the PDO."""
        return self.codec.length


@dataclass
class MasterConfig:
    """The ``master`` section."""

    node_id: int | None = None
    bitrate: int = 500_000
    sync_period: float = 0.0  # s
    sync_cob_id: int = 0x80
    sync_overflow: int = 0
    sync_by_interface: bool = False  # the CAN interface times SYNC (SocketCAN: the kernel)
    heartbeat_time: int = 0  # ms
    time_period: float = 0.0  # s
    time_cob_id: int = 0x100
    reset: str = "node"
    start: str = "node"
    bootup_delay: float = 0.3  # s
    pdo_timeout_factor: float = 3.0
    bus_load_window: float = 0.25  # s

    @property
    def sync_period_us(self) -> int:
        """The SYNC period in microseconds (1006h)."""
        return round(self.sync_period * 1e6)


@dataclass
class NodeConfig:
    """One node of the network: the ``nodes`` entry and everything derived from its EDS."""

    name: str
    node_id: int
    eds_path: Path
    od: ObjectDictionary
    bitrate: int = 500_000
    enabled: bool = True
    mandatory: bool = False
    do_not_initialise: bool = False
    #: False: the node has no CiA 301 SDO server; the master sends it no SDO (see the module).
    sdo_server: bool = True
    auto_start: bool = True
    device_type: int = 0
    device_type_low16: bool = False
    vendor_id: int = 0
    product_code: int = 0
    revision_number: int = 0
    serial_number: int = 0
    heartbeat_time: int = 0  # ms, the node's producer time (1017h)
    guard_time: int = 0  # ms (100Ch)
    life_time_factor: int = 0  # (100Dh)
    consumer_factor: float = 1.5
    watch_master: bool = False
    sdo_timeout: float = 1.0  # s
    sdo_retries: int = 2
    boot_timeout: float = 2.0  # s
    restore_defaults: bool = False
    sdo_from_dcf: bool = True
    sdo_all_pdo: bool = False
    stop_on_abort: bool = False
    set_sync_period: bool = True
    error_reaction: str = "none"  # none | stop_node | stop_all
    #: auto: a node back after an error-control fault, re-booted, or put out of the state
    #: the master expects by someone else is brought back; manual: it waits for
    #: ``master.restart(node)``.
    restart: str = "auto"  # auto | manual
    zero_inputs: bool = True
    #: The start-up SDO list (without the error control writes, see below).
    startup: list[SdoEntry] = field(default_factory=list)
    tpdos: list[PdoLayout] = field(default_factory=list)
    rpdos: list[PdoLayout] = field(default_factory=list)
    #: Alias -> canonical signal name (both find the signal).
    aliases: dict[str, str] = field(default_factory=dict)

    @property
    def identity(self) -> tuple[int, int, int, int]:
        """Expected 1018h sub 1..4 (0: not checked)."""
        return (self.vendor_id, self.product_code, self.revision_number, self.serial_number)

    @property
    def error_control(self) -> str | None:
        """``"heartbeat"``, ``"guarding"`` or None (the node is not supervised)."""
        if self.heartbeat_time:
            return "heartbeat"
        if self.guard_time:
            return "guarding"
        return None

    @property
    def heartbeat_consumer_time(self) -> float:
        """Seconds without heartbeat before the node counts as lost."""
        return self.heartbeat_time * self.consumer_factor / 1000.0

    @property
    def fallback_guarding(self) -> tuple[int, int]:
        """Guard time (ms) and life time factor used when the node refuses heartbeat."""
        return (self.guard_time or self.heartbeat_time, self.life_time_factor or 3)

    def error_control_entries(self, kind: str | None = None) -> list[SdoEntry]:
        """The writes that set up ``kind`` (default: the configured error control)."""
        kind = kind or self.error_control
        if kind == "heartbeat":
            return [_entry(self.od, 0x1017, 0, self.heartbeat_time, "producer heartbeat time")]
        if kind == "guarding":
            guard, factor = (
                (self.guard_time, self.life_time_factor or 3)
                if self.guard_time
                else self.fallback_guarding
            )
            return [
                _entry(self.od, 0x100C, 0, guard, "guard time"),
                _entry(self.od, 0x100D, 0, factor, "life time factor"),
            ]
        return []

    def concise_dcf(self) -> bytes:
        """The CiA 302 concise DCF (the format of 1F22h) of what the master downloads:
        count U32, then per entry index U16, sub-index U8, size U32 and the data."""
        entries = [*self.startup, *self.error_control_entries()]
        out = [struct.pack("<I", len(entries))]
        for e in entries:
            out.append(struct.pack("<HBI", e.index, e.subindex, len(e.data)))
            out.append(e.data)
        return b"".join(out)

    def to_dcf(self) -> str:
        """The node's DCF: its EDS with every configured value as ParameterValue."""
        return self.od.to_dcf(self.node_id, self.bitrate)


_FIXED_TYPES = {
    0x1017: DataType.UNSIGNED16,
    0x100C: DataType.UNSIGNED16,
    0x100D: DataType.UNSIGNED8,
}


def _entry(od: ObjectDictionary, index: int, sub: int, value: Any, name: str) -> SdoEntry:
    var = od.get_variable(index, sub)
    data = var.encode(value) if var is not None else encode(_FIXED_TYPES[index], value)
    return SdoEntry(index, sub, data, value, name)


@dataclass
class NetworkConfig:
    """A whole network: the master's settings and the nodes by node-ID (file order)."""

    path: str
    master: MasterConfig
    nodes: dict[int, NodeConfig]
    #: Warnings found while reading (errors raise :class:`NetworkConfigError`).
    warnings: list[ConfigProblem] = field(default_factory=list)

    def node(self, key: int | str) -> NodeConfig:
        """A node by node-ID or name."""
        if isinstance(key, int):
            found = self.nodes.get(key)
        else:
            found = next((n for n in self.nodes.values() if n.name == key), None)
        if found is None:
            names = ", ".join(f"{n.name} ({n.node_id})" for n in self.nodes.values())
            raise NodeNotFoundError(f"no node {key!r} in {self.path}; the nodes are: {names}")
        return found

    @property
    def signals(self) -> dict[str, Signal]:
        """Every signal of the process image by full name (inputs and outputs)."""
        out: dict[str, Signal] = {}
        for node in self.nodes.values():
            for layout in (*node.tpdos, *node.rpdos):
                for sig in layout.signals:
                    out.setdefault(sig.name, sig)
        return out

    def dcf_files(self, outdir: str | os.PathLike[str]) -> list[Path]:
        """The files :meth:`write_dcfs` writes into ``outdir``."""
        target = Path(outdir)
        return [target / f"{n.name}{ext}" for n in self.nodes.values() for ext in (".dcf", ".bin")]

    def write_dcfs(self, outdir: str | os.PathLike[str]) -> list[Path]:
        """Write ``<node>.dcf`` and the concise ``<node>.bin`` of every node into ``outdir``,
        each whole or not at all; a symbolic link there is replaced, never written through."""
        target = Path(outdir)
        target.mkdir(parents=True, exist_ok=True)
        written: list[Path] = []
        for node in self.nodes.values():
            dcf = target / f"{node.name}.dcf"
            replace_file(dcf, node.to_dcf().replace("\n", "\r\n").encode("utf-8"))
            concise = target / f"{node.name}.bin"
            replace_file(concise, node.concise_dcf())
            written += [dcf, concise]
        return written


# ------------------------------------------------------------------------------- parsing

_TOP_KEYS = ("master", "defaults", "nodes")
_MASTER_KEYS = (
    "node_id",
    "bitrate",
    "sync_period",
    "sync_cob_id",
    "sync_overflow",
    "sync_by_interface",
    "heartbeat_time",
    "time_period",
    "time_cob_id",
    "reset",
    "start",
    "bootup_delay",
    "pdo_timeout_factor",
    "bus_load_window",
)
_NODE_KEYS = (
    "node_id",
    "eds",
    "dcf",
    "enabled",
    "mandatory",
    "do_not_initialise",
    "sdo_server",
    "auto_start",
    "device_type",
    "device_type_low16",
    "vendor_id",
    "product_code",
    "revision_number",
    "serial_number",
    "heartbeat_time",
    "guard_time",
    "life_time_factor",
    "consumer_factor",
    "watch_master",
    "sdo_timeout",
    "sdo_retries",
    "boot_timeout",
    "restore_defaults",
    "sdo_from_dcf",
    "sdo_all_pdo",
    "sdo",
    "stop_on_abort",
    "set_sync_period",
    "error_reaction",
    "restart",
    "zero_inputs",
    "signals",
)
_NOT_DEFAULTABLE = ("node_id", "eds", "dcf", "sdo", "signals")
_PDO_KEY = re.compile(r"([tr])pdo([0-9]+)\Z")
_PDO_FIELDS = (
    "enabled",
    "cob_id",
    "transmission_type",
    "event_timer",
    "inhibit_time",
    "sync_start",
    "mapping",
    "timeout",
)
_NODE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]*\Z")
_ALIAS = re.compile(r"[A-Za-z_][A-Za-z0-9_.\[\]]*\Z")
_U32 = 0xFFFFFFFF


def _mapping(value: Any, what: str) -> Mapping[Any, Any]:
    if not isinstance(value, Mapping):
        raise _Bad(f"{what} must be a mapping of keys to values, not {type(value).__name__}")
    return value


class _NodeReader:
    """Reads one node entry into a :class:`NodeConfig`, reporting every problem."""

    def __init__(
        self,
        name: str,
        raw: Mapping[Any, Any],
        defaults: Mapping[Any, Any],
        master: MasterConfig,
        base_dir: Path,
        report: _Report,
        texts: dict[Path, str],
    ) -> None:
        self.name = name
        self.raw = raw
        self.defaults = defaults
        self.master = master
        self.base_dir = base_dir
        self.report = report
        self.texts = texts
        self.yaml_set: set[tuple[int, int]] = set()
        self.explicit: list[SdoEntry] = []
        self.yaml_pdos: set[tuple[str, int]] = set()
        #: RPDOs the network file maps with nothing ("rpdo3"): sent with DLC 0.
        self.empty_rpdos: set[str] = set()

    # --- helpers
    def error(self, key: str | None, reason: str, container: Any = None, at: Any = None) -> None:
        where = container if container is not None else self.raw
        line = line_of(where, at if at is not None else key)
        self.report.error(self.name, key, reason, line)

    def warning(self, key: str | None, reason: str, container: Any = None, at: Any = None) -> None:
        where = container if container is not None else self.raw
        line = line_of(where, at if at is not None else key)
        self.report.warning(self.name, key, reason, line)

    def value(self, key: str) -> tuple[bool, Any, Any]:
        """(given, value, container) of ``key`` from the node, else from ``defaults``."""
        if key in self.raw:
            return True, self.raw[key], self.raw
        if key in self.defaults and key not in _NOT_DEFAULTABLE:
            return True, self.defaults[key], self.defaults
        return False, None, None

    def get(self, key: str, parse: Any, default: Any) -> Any:
        given, value, where = self.value(key)
        if not given:
            return default
        try:
            return parse(value)
        except _Bad as exc:
            self.error(key, str(exc), where)
            return default

    # --- the node
    def read(self, node_ids: dict[int, str]) -> NodeConfig | None:
        raw = self.raw
        for key in raw:
            skey = str(key)
            if skey not in _NODE_KEYS and not _PDO_KEY.match(skey):
                self.error(skey, f"unknown key{_suggest(skey, _NODE_KEYS)}")
        if "node_id" not in raw:
            self.error("node_id", "missing: give the node-ID (1..127)", raw, None)
            return None
        try:
            node_id = _int(raw["node_id"], 1, 127, "node-ID")
        except _Bad as exc:
            self.error("node_id", str(exc))
            return None
        if node_id in node_ids:
            self.error("node_id", f"node-ID {node_id} is used by node {node_ids[node_id]!r} too")
            return None
        node_ids[node_id] = self.name
        if self.master.node_id == node_id:
            self.error("node_id", f"node-ID {node_id} is the master's own node-ID")
        od, path = self._dictionary(node_id)
        if od is None or path is None:
            return None
        cfg = NodeConfig(self.name, node_id, path, od, bitrate=self.master.bitrate)
        self._scalars(cfg)
        self._pdos(cfg)
        self._explicit_sdo(cfg)
        self._error_control(cfg)
        self._sync(cfg)
        cfg.startup = _startup(cfg, self.yaml_set, self.explicit, self._unwritable)
        cfg.tpdos = self._layouts(cfg, transmit=True)
        cfg.rpdos = self._layouts(cfg, transmit=False)
        self._signals(cfg)
        # (a node without error control whose TPDO the master supervises is watched all the
        # same: a missing TPDO tells it failed, as with the ZAPI inverter of the thesis)
        watched = any(layout.timeout for layout in cfg.tpdos)
        if cfg.error_control is None and cfg.enabled and not watched:
            self.warning(
                None,
                "neither heartbeat_time nor guard_time, nor a supervised TPDO: the master "
                "cannot tell when this node fails",
                raw,
                "node_id",
            )
        return cfg

    def _unwritable(self, var: Variable, value: Any, exc: Exception, fatal: bool) -> None:
        key = "eds" if "eds" in self.raw else "dcf"
        where = f"line {var.line} of " if var.line is not None else ""
        file = Path(self.raw_path()).name
        ident = f"0x{var.index:04X}:{var.subindex:02X} ({var.name})"
        if fatal:
            self.error(
                key,
                f"{ident} would be written {value!r}, which it cannot hold: {exc}; correct "
                f"the value ({where}{file})",
            )
        else:
            self.warning(
                key,
                f"{ident} is configured as {value!r}, outside its limits in the EDS ({exc}); "
                f"it is written as configured ({where}{file})",
            )

    def _dictionary(self, node_id: int) -> tuple[ObjectDictionary | None, Path | None]:
        keys = [k for k in ("eds", "dcf") if k in self.raw]
        if len(keys) != 1:
            reason = (
                "give the node's EDS or DCF file (eds: path relative to the network file)"
                if not keys
                else "give either eds or dcf, not both"
            )
            self.error(keys[-1] if keys else "eds", reason, self.raw, keys[-1] if keys else None)
            return None, None
        key = keys[0]
        value = self.raw[key]
        if not isinstance(value, str) or not value.strip():
            self.error(key, f"{value!r} is not a file path")
            return None, None
        path = (self.base_dir / value).resolve()
        text = self.texts.get(path)
        if text is None:
            try:
                data = path.read_bytes()
            except OSError as exc:
                self.error(key, f"cannot read {path}: {exc.strerror}")
                return None, None
            try:
                text = data.decode("utf-8")
            except UnicodeDecodeError:
                text = data.decode("latin-1")
            self.texts[path] = text
        try:
            od = loads(text, node_id, path=str(path))
        except EdsError as exc:
            self.error(key, f"the file cannot be read: {exc}")
            return None, None
        od.path = str(path)
        if not len(od):
            self.error(key, f"{path.name} is not an EDS or DCF: it defines no objects")
            return None, None
        lost = [f for f in od.errors if _dropped_value(od, f)]
        for finding in lost:
            # a configured value the reader had to drop: the node would not get it
            self.error(key, f"{finding}; the master cannot write it: correct the value")
        others = [f for f in od.errors if f not in lost]
        if others:
            self.warning(
                key,
                f"{path.name} has {len(others)} error(s) (`cobus eds check {path}` lists "
                f"them); first: {others[0].reason}",
            )
        return od, path

    def _scalars(self, cfg: NodeConfig) -> None:
        g = self.get
        cfg.enabled = g("enabled", _bool, True)
        cfg.mandatory = g("mandatory", _bool, False)
        cfg.do_not_initialise = g("do_not_initialise", _bool, False)
        cfg.sdo_server = g("sdo_server", _bool, True)
        cfg.auto_start = g("auto_start", _bool, True)
        cfg.device_type = g("device_type", lambda v: _int(v, 0, _U32, "device type"), 0)
        cfg.device_type_low16 = g("device_type_low16", _bool, False)
        for key in _IDENTITY_KEYS:
            setattr(cfg, key, g(key, lambda v: _int(v, 0, _U32, "1018h value"), 0))
        cfg.heartbeat_time = g("heartbeat_time", _whole_ms, 0)
        cfg.guard_time = g("guard_time", _whole_ms, 0)
        cfg.life_time_factor = g("life_time_factor", lambda v: _int(v, 0, 255, "factor"), 0)
        cfg.consumer_factor = g("consumer_factor", lambda v: _number(v, 1.0, 100.0), 1.5)
        cfg.watch_master = g("watch_master", _bool, False)
        cfg.sdo_timeout = g("sdo_timeout", lambda v: _ms(v, 600_000), 1000.0) / 1000.0
        if cfg.sdo_timeout <= 0:
            self.error("sdo_timeout", "must be above 0 ms")
            cfg.sdo_timeout = 1.0
        cfg.sdo_retries = g("sdo_retries", lambda v: _int(v, 0, 100, "retry count"), 2)
        cfg.boot_timeout = g("boot_timeout", lambda v: _ms(v, 3_600_000), 2000.0) / 1000.0
        cfg.restore_defaults = g("restore_defaults", _bool, False)
        cfg.sdo_from_dcf = g("sdo_from_dcf", _bool, True)
        cfg.sdo_all_pdo = g("sdo_all_pdo", _bool, False)
        cfg.stop_on_abort = g("stop_on_abort", _bool, False)
        cfg.set_sync_period = g("set_sync_period", _bool, True)
        cfg.error_reaction = g(
            "error_reaction", lambda v: _choice(v, ("none", "stop_node", "stop_all")), "none"
        )
        cfg.restart = g("restart", lambda v: _choice(v, ("auto", "manual")), "auto")
        cfg.zero_inputs = g("zero_inputs", _bool, True)
        if cfg.restore_defaults and cfg.od.get(_RESTORE) is None:
            self.error("restore_defaults", f"{cfg.eds_path.name} has no 1011h to restore from")
        if cfg.do_not_initialise and cfg.restore_defaults:
            self.error("restore_defaults", "a node that is not initialised cannot be restored")
        if not cfg.sdo_server:
            if not cfg.do_not_initialise:
                self.error(
                    "sdo_server",
                    "the master configures a node by SDO: a node without an SDO server needs "
                    "do_not_initialise: true",
                )
            checks = [k for k in ("device_type", *_IDENTITY_KEYS) if getattr(cfg, k)]
            if checks:
                self.error(
                    "sdo_server",
                    f"{', '.join(checks)} would be checked by SDO reads (1000h, 1018h), which a "
                    "node without an SDO server cannot answer: leave them out",
                )

    # --- values set in the dictionary
    def set_value(self, var: Variable, value: Any, key: str, where: Any, at: Any) -> bool:
        """Set ``var``'s ParameterValue (checked); False after reporting a problem."""
        if value == var.value:
            self.yaml_set.add((var.index, var.subindex))
            return True
        if not var.writable:
            self.error(
                key,
                f"0x{var.index:04X}:{var.subindex:02X} ({var.name}) is {var.access} in "
                f"{Path(self.raw_path()).name}: it cannot be configured",
                where,
                at,
            )
            return False
        try:
            var.parameter_value = value
        except Exception as exc:  # the od's typed errors say what does not fit
            self.error(key, f"0x{var.index:04X}:{var.subindex:02X}: {exc}", where, at)
            return False
        self.yaml_set.add((var.index, var.subindex))
        return True

    def raw_path(self) -> str:
        value = self.raw.get("eds", self.raw.get("dcf", ""))
        return str(value)

    # --- PDOs
    def _pdos(self, cfg: NodeConfig) -> None:
        for key in self.raw:
            match = _PDO_KEY.match(str(key))
            if match is None:
                continue
            tx = match.group(1) == "t"
            number = int(match.group(2))
            self._pdo(cfg, str(key), tx, number, self.raw[key])

    def _pdo(self, cfg: NodeConfig, key: str, tx: bool, number: int, raw: Any) -> None:
        kind = "TPDO" if tx else "RPDO"
        try:
            spec = _mapping(raw, key)
        except _Bad as exc:
            self.error(key, str(exc))
            return
        if not 1 <= number <= 512:
            self.error(key, f"{kind} numbers run 1..512, not {number}")
            return
        od = cfg.od
        comm_index = (0x1800 if tx else 0x1400) + number - 1
        map_index = (0x1A00 if tx else 0x1600) + number - 1
        comm = od.get(comm_index)
        mapping = od.get(map_index)
        if not isinstance(comm, Record | Array) or not isinstance(mapping, Record | Array):
            self.error(
                key,
                f"{cfg.eds_path.name} has no {kind} {number} (objects 0x{comm_index:04X} and "
                f"0x{map_index:04X})",
            )
            return
        self.yaml_pdos.add(("tpdo" if tx else "rpdo", number))
        for field_key in spec:
            if field_key not in _PDO_FIELDS or (field_key == "timeout" and not tx):
                fields = [f for f in _PDO_FIELDS if tx or f != "timeout"]
                self.error(
                    f"{key}.{field_key}",
                    f"unknown PDO setting{_suggest(str(field_key), fields)}",
                    spec,
                    field_key,
                )
        if "timeout" in spec:
            try:
                _ms(spec["timeout"], 0xFFFF)
            except _Bad as exc:
                self.error(f"{key}.timeout", str(exc), spec, "timeout")
        enabled = True
        if "enabled" in spec:
            try:
                enabled = _bool(spec["enabled"])
            except _Bad as exc:
                self.error(f"{key}.enabled", str(exc), spec, "enabled")
        cob_var = comm.get(1)
        if cob_var is None or not isinstance(cob_var.value, int):
            self.error(key, f"0x{comm_index:04X} has no COB-ID (sub-index 1) with a value")
            return
        current = cob_var.value
        if "cob_id" in spec:
            try:
                cob = _int(spec["cob_id"], 1, 0x1FFFFFFF | _EXTENDED, "COB-ID")
            except _Bad as exc:
                self.error(f"{key}.cob_id", str(exc), spec, "cob_id")
                return
        else:
            cob = current & ~_INVALID
        if enabled:
            try:
                parsed = PdoCobId.from_u32(cob & ~_INVALID)
            except PdoError as exc:
                self.error(f"{key}.cob_id", str(exc), spec, "cob_id")
                return
            if parsed.can_id == 0 or (not parsed.extended and is_restricted_can_id(parsed.can_id)):
                self.error(
                    f"{key}.cob_id",
                    f"identifier 0x{parsed.can_id:X} is restricted by CiA 301 (NMT, SYNC, EMCY, "
                    "SDO, error control) or unset: give a free cob_id",
                    spec,
                    "cob_id" if "cob_id" in spec else None,
                )
                return
            cob &= ~_INVALID
        else:
            cob |= _INVALID
        self.set_value(cob_var, cob, f"{key}.cob_id", spec, "cob_id" if "cob_id" in spec else None)
        for field_key, sub, check in (
            ("transmission_type", 2, None),
            ("inhibit_time", 3, (0, 0xFFFF)),
            ("event_timer", 5, None),
            ("sync_start", 6, (0, 240)),
        ):
            if field_key not in spec:
                continue
            label = f"{key}.{field_key}"
            var = comm.get(sub)
            if var is None:
                self.error(label, f"0x{comm_index:04X} has no sub-index {sub}", spec, field_key)
                continue
            if field_key == "sync_start" and not tx:
                self.error(label, "RPDOs have no SYNC start value", spec, field_key)
                continue
            try:
                if field_key == "transmission_type":
                    tt = TransmissionType(_int(spec[field_key], 0, 255, "transmission type"))
                    if not tx and not tt.valid_for_rpdo:
                        raise _Bad(f"{tt.value} is for TPDOs only (RPDOs take 0..240, 254, 255)")
                    value = tt.value
                elif field_key == "event_timer":
                    value = _whole_ms(spec[field_key])
                else:
                    assert check is not None
                    value = _int(spec[field_key], check[0], check[1], field_key.replace("_", " "))
            except (_Bad, PdoError) as exc:
                self.error(label, str(exc), spec, field_key)
                continue
            self.set_value(var, value, label, spec, field_key)
        if "mapping" in spec:
            self._mapping(cfg, key, tx, mapping, spec)

    def _mapping(
        self, cfg: NodeConfig, key: str, tx: bool, mapping: Record | Array, spec: Mapping[Any, Any]
    ) -> None:
        items = spec["mapping"]
        label = f"{key}.mapping"
        if not isinstance(items, list):
            self.error(label, "give a list of object names or addresses", spec, "mapping")
            return
        if not items and not tx:
            self.empty_rpdos.add(key)
        index = ObjectIndex(cfg.od, cfg.eds_path.name)
        values: list[int] = []
        bits_total = 0
        ok = True
        for pos, item in enumerate(items):
            where = f"{label}[{pos}]"
            if isinstance(item, str) and (dummy := _DUMMY.match(item.lower())):
                bits = int(dummy.group(1))
                values.append(_DUMMY_TYPES[bits] << 16 | bits)
                bits_total += bits
                continue
            try:
                var = index.resolve(item)
            except _Bad as exc:
                self.error(where, str(exc), items, pos)
                ok = False
                continue
            ident = f"0x{var.index:04X}:{var.subindex:02X} ({var.name})"
            length = var.bit_length
            if length is None:
                self.error(where, f"{ident} is {var.data_type.name}: no fixed length", items, pos)
                ok = False
                continue
            if not var.pdo_mappable:
                self.error(where, f"{ident} is not PDO-mappable in the EDS", items, pos)
                ok = False
                continue
            if tx and not var.readable:
                self.error(where, f"{ident} is write-only: it cannot go in a TPDO", items, pos)
                ok = False
                continue
            if not tx and not var.writable:
                self.error(where, f"{ident} is {var.access}: it cannot go in an RPDO", items, pos)
                ok = False
                continue
            values.append(var.index << 16 | var.subindex << 8 | length)
            bits_total += length
        slots = max((s for s in mapping.subindices if s), default=0)
        if len(values) > slots:
            self.error(
                label,
                f"{len(values)} entries but 0x{mapping.index:04X} has {slots} mapping entries",
                spec,
                "mapping",
            )
            return
        if bits_total > 64:
            self.error(
                label, f"the mapping takes {bits_total} bits; a PDO carries 64", spec, "mapping"
            )
            return
        if not ok:
            return
        count_var = mapping.get(0)
        if count_var is None:
            self.error(label, f"0x{mapping.index:04X} has no sub-index 0", spec, "mapping")
            return
        if _direct_mapping(mapping):
            values += [0] * (slots - len(values))  # direct mapping: 0 = an unused entry
        else:
            self.set_value(count_var, len(values), label, spec, "mapping")
        for sub, value in enumerate(values, 1):
            slot = mapping.get(sub)
            if slot is None:
                self.error(label, f"0x{mapping.index:04X} has no sub-index {sub}", spec, "mapping")
                return
            self.set_value(slot, value, label, spec, "mapping")

    # --- explicit SDO writes
    def _explicit_sdo(self, cfg: NodeConfig) -> None:
        if "sdo" not in self.raw:
            return
        items = self.raw["sdo"]
        if not isinstance(items, list):
            self.error("sdo", "give a list of {object: ..., value: ...} entries")
            return
        index = ObjectIndex(cfg.od, cfg.eds_path.name)
        for pos, item in enumerate(items):
            label = f"sdo[{pos}]"
            if not isinstance(item, Mapping) or "value" not in item or "object" not in item:
                self.error(label, "each entry needs object (name or address) and value", items, pos)
                continue
            for extra in item:
                if extra not in ("object", "value"):
                    self.error(
                        f"{label}.{extra}", "unknown key (use object and value)", item, extra
                    )
            try:
                var = index.resolve(item["object"])
            except _Bad as exc:
                self.error(f"{label}.object", str(exc), item, "object")
                continue
            value = item["value"]
            if var.data_type in (DataType.OCTET_STRING, DataType.DOMAIN) and isinstance(value, str):
                try:
                    value = bytes.fromhex(value)
                except ValueError:
                    self.error(f"{label}.value", f"{value!r} is not hex bytes", item, "value")
                    continue
            if not var.writable:
                self.error(
                    f"{label}.object",
                    f"0x{var.index:04X}:{var.subindex:02X} ({var.name}) is {var.access}",
                    item,
                    "object",
                )
                continue
            try:
                data = var.encode(value)
                var.parameter_value = value
            except Exception as exc:  # the od's typed errors say what does not fit
                self.error(f"{label}.value", str(exc), item, "value")
                continue
            self.explicit.append(SdoEntry(var.index, var.subindex, data, value, var.name))

    # --- heartbeat / guarding and SYNC, as values of the DCF
    def _error_control(self, cfg: NodeConfig) -> None:
        od = cfg.od
        given_hb = self.value("heartbeat_time")[0]
        given_guard = self.value("guard_time")[0]
        if not given_hb and not given_guard:
            # none in the network file: take what the DCF configures
            hb = od.get_variable(0x1017, 0)
            guard = od.get_variable(0x100C, 0)
            factor = od.get_variable(0x100D, 0)
            if hb is not None and isinstance(hb.parameter_value, int) and hb.parameter_value:
                cfg.heartbeat_time = hb.parameter_value
            elif (
                guard is not None
                and isinstance(guard.parameter_value, int)
                and guard.parameter_value
            ):
                cfg.guard_time = guard.parameter_value
                if factor is not None and isinstance(factor.value, int):
                    cfg.life_time_factor = cfg.life_time_factor or factor.value
        if cfg.heartbeat_time and od.get_variable(0x1017, 0) is None:
            self.warning(
                "heartbeat_time",
                f"{cfg.eds_path.name} has no 1017h: the master will fall back to node guarding",
            )
        for index, value in (
            (0x1017, cfg.heartbeat_time),
            (0x100C, cfg.guard_time),
            (0x100D, cfg.life_time_factor if cfg.guard_time else 0),
        ):
            var = od.get_variable(index, 0)
            if var is not None and value:
                try:
                    var.parameter_value = value
                except Exception as exc:  # the od's typed errors say what does not fit
                    self.error(None, f"0x{index:04X}: {exc}")
        if cfg.watch_master:
            self._watch_master(cfg)

    def _watch_master(self, cfg: NodeConfig) -> None:
        master = self.master
        if master.node_id is None or not master.heartbeat_time:
            self.error(
                "watch_master",
                "the master needs node_id and heartbeat_time for a node to watch it",
            )
            return
        var = cfg.od.get_variable(0x1016, 1)
        if var is None or not var.writable:
            self.error("watch_master", f"{cfg.eds_path.name} has no writable 1016h sub 1")
            return
        ms = min(round(master.heartbeat_time * cfg.consumer_factor), 0xFFFF)
        value = master.node_id << 16 | ms
        current = var.parameter_value
        if isinstance(current, int) and current and (current >> 16) & 0xFF != master.node_id:
            self.error("watch_master", "the DCF already uses 1016h sub 1 for another node")
            return
        self.set_value(var, value, "watch_master", self.raw, "watch_master")

    def _sync(self, cfg: NodeConfig) -> None:
        master = self.master
        if not cfg.set_sync_period or not master.sync_period:
            return
        period = cfg.od.get_variable(0x1006, 0)
        if period is not None and period.writable:
            try:
                period.parameter_value = master.sync_period_us
                self.yaml_set.add((0x1006, 0))
            except Exception as exc:  # the od's typed errors say what does not fit
                self.error("set_sync_period", f"0x1006: {exc}")
        overflow = cfg.od.get_variable(0x1019, 0)
        if overflow is not None and overflow.writable and master.sync_overflow:
            try:
                overflow.parameter_value = master.sync_overflow
                self.yaml_set.add((0x1019, 0))
            except Exception as exc:  # the od's typed errors say what does not fit
                self.error("set_sync_period", f"0x1019: {exc}")

    # --- what the process image sees
    def _layouts(self, cfg: NodeConfig, *, transmit: bool) -> list[PdoLayout]:
        od = cfg.od
        direction = "tpdo" if transmit else "rpdo"
        kind = "TPDO" if transmit else "RPDO"
        comm_base, map_base = (0x1800, 0x1A00) if transmit else (0x1400, 0x1600)
        names = ObjectIndex(od, cfg.eds_path.name)
        layouts: list[PdoLayout] = []
        for number in range(1, 513):
            comm = od.get(comm_base + number - 1)
            if not isinstance(comm, Record | Array):
                continue
            in_yaml = (direction, number) in self.yaml_pdos
            key = f"{direction}{number}"

            def problem(
                reason: str, key: str = key, in_yaml: bool = in_yaml, number: int = number
            ) -> None:
                if in_yaml:
                    self.error(key, reason)
                else:
                    self.warning(None, f"{kind} {number} (EDS default): {reason}; it is left out")

            cob_var = comm.get(1)
            if cob_var is None or not isinstance(cob_var.value, int):
                continue
            try:
                cob = PdoCobId.from_u32(cob_var.value)
            except PdoError as exc:
                problem(str(exc))
                continue
            if not cob.valid:
                continue
            mapping = od.get(map_base + number - 1)
            if not isinstance(mapping, Record | Array):
                continue
            fields: list[tuple[MappingEntry, Kind | None]] = []
            variables: list[tuple[Variable, int, Kind]] = []
            broken = False
            direct = _direct_mapping(mapping)
            for _entry_var, index, sub, bits in mapping_entries(mapping):
                if direct and not (index or sub or bits):
                    continue  # an unused entry of a direct mapping
                entry = MappingEntry(index, sub, bits)
                if entry.is_dummy:
                    fields.append((entry, None))
                    continue
                var = od.get_variable(index, sub)
                if var is None:
                    problem(f"maps 0x{index:04X}:{sub:02X}, which is not in the EDS")
                    broken = True
                    break
                try:
                    kind_of = _kind(var, bits)
                except _Bad as exc:
                    problem(str(exc))
                    broken = True
                    break
                fields.append((entry, kind_of))
                variables.append((var, bits, kind_of))
            if broken or (not variables and (fields or key not in self.empty_rpdos)):
                continue
            try:
                codec = PdoMap(fields)
            except PdoError as exc:
                problem(str(exc))
                continue
            tt = _sub_value(comm, 2, 255)
            event_timer = _sub_value(comm, 5, 0)
            timeout: float | None = None
            if transmit:
                timeout = self._tpdo_timeout(cfg, number, tt, event_timer)
            positions: list[Signal | None] = []
            for pos, (var, bits, kind_) in enumerate(variables):
                positions.append(
                    Signal(
                        name=names.canonical(var),
                        node_id=cfg.node_id,
                        direction="input" if transmit else "output",
                        pdo=number,
                        position=pos,
                        index=var.index,
                        subindex=var.subindex,
                        data_type=var.data_type,
                        bits=bits,
                        kind=kind_,
                        low=_limit(var.low_limit),
                        high=_limit(var.high_limit),
                    )
                )
            layouts.append(
                PdoLayout(
                    direction=direction,
                    number=number,
                    cob_id=cob.can_id,
                    extended=cob.extended,
                    transmission_type=tt,
                    event_timer=event_timer,
                    inhibit_time=_sub_value(comm, 3, 0),
                    timeout=timeout,
                    codec=codec,
                    positions=tuple(positions),
                )
            )
        return layouts

    def _tpdo_timeout(
        self, cfg: NodeConfig, number: int, tt: int, event_timer: int
    ) -> float | None:
        spec = self.raw.get(f"tpdo{number}")
        if isinstance(spec, Mapping) and "timeout" in spec:
            try:
                ms = _ms(spec["timeout"], 0xFFFF)
            except _Bad:
                return None
            return ms / 1000.0 if ms else None
        factor = self.master.pdo_timeout_factor
        if 1 <= tt <= 240 and self.master.sync_period:
            return min(tt * self.master.sync_period * factor, 65.535)
        if tt >= 254 and event_timer:
            return min(event_timer / 1000.0 * factor, 65.535)
        return None

    def _signals(self, cfg: NodeConfig) -> None:
        """Name the signals (aliases, scaling). An object mapped in several PDOs of a
        direction is one signal: its value comes from (or goes to) each of them."""
        specs: dict[str, tuple[str, float | None, float, str | None]] = {}
        if "signals" in self.raw:
            specs = self._aliases(cfg)
        for layouts in (cfg.tpdos, cfg.rpdos):
            for li, layout in enumerate(layouts):
                new: list[Signal | None] = []
                for sig in layout.positions:
                    if sig is None:
                        new.append(None)
                        continue
                    alias = specs.get(sig.name)
                    local = alias[0] if alias is not None else sig.name
                    scale, offset, unit = (None, 0.0, None) if alias is None else alias[1:]
                    new.append(
                        replace(
                            sig, name=f"{cfg.name}.{local}", scale=scale, offset=offset, unit=unit
                        )
                    )
                layouts[li] = replace(layout, positions=tuple(new))
        cfg.aliases = {alias: canonical for canonical, (alias, *_rest) in specs.items()}

    def _aliases(self, cfg: NodeConfig) -> dict[str, tuple[str, float | None, float, str | None]]:
        raw = self.raw["signals"]
        out: dict[str, tuple[str, float | None, float, str | None]] = {}
        if not isinstance(raw, Mapping):
            self.error(
                "signals", "give a mapping of alias: object (or {object, scale, offset, unit})"
            )
            return out
        index = ObjectIndex(cfg.od, cfg.eds_path.name)
        mapped = {(s.index, s.subindex): s for lay in (*cfg.tpdos, *cfg.rpdos) for s in lay.signals}
        canon_names = {s.name for s in mapped.values()}
        for alias, spec in raw.items():
            label = f"signals.{alias}"
            if not isinstance(alias, str) or not _ALIAS.match(alias):
                self.error(
                    label, f"alias {alias!r} must be a name (letters, digits, _ .)", raw, alias
                )
                continue
            scale: float | None = None
            offset = 0.0
            unit: str | None = None
            target: Any = spec
            if isinstance(spec, Mapping):
                for extra in spec:
                    if extra not in ("object", "scale", "offset", "unit"):
                        hint = _suggest(str(extra), ("object", "scale", "offset", "unit"))
                        self.error(f"{label}.{extra}", f"unknown key{hint}", spec, extra)
                target = spec.get("object", alias)
                try:
                    if "scale" in spec:
                        scale = _number(spec["scale"], -1e12, 1e12)
                        if scale == 0:
                            raise _Bad("a scale of 0 loses the value")
                    if "offset" in spec:
                        offset = _number(spec["offset"], -1e12, 1e12)
                except _Bad as exc:
                    self.error(label, str(exc), raw, alias)
                    continue
                if "unit" in spec:
                    unit = str(spec["unit"])
            try:
                var = index.resolve(target)
            except _Bad as exc:
                self.error(label, str(exc), raw, alias)
                continue
            sig = mapped.get((var.index, var.subindex))
            if sig is None:
                self.error(
                    label,
                    f"0x{var.index:04X}:{var.subindex:02X} ({var.name}) is not mapped in any "
                    "valid PDO: map it in a tpdoN or rpdoN to see it in the process image",
                    raw,
                    alias,
                )
                continue
            if (scale is not None or offset) and sig.kind not in (
                Kind.SIGNED,
                Kind.UNSIGNED,
                Kind.REAL32,
                Kind.REAL64,
            ):
                self.error(
                    label, f"{var.name} is {var.data_type.name}: it cannot be scaled", raw, alias
                )
                continue
            if alias != sig.name and alias in canon_names:
                self.error(
                    label, f"{alias!r} is already the name of another mapped object", raw, alias
                )
                continue
            if sig.name in out:
                self.error(label, f"{var.name} has two aliases", raw, alias)
                continue
            out[sig.name] = (alias, scale, offset, unit)
        return out


def _limit(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return value


def _sub_value(obj: Record | Array, sub: int, default: int) -> int:
    var = obj.get(sub)
    value = var.value if var is not None else None
    return value if isinstance(value, int) else default


def _direct_mapping(mapping: Record | Array) -> bool:
    """Whether a PDO mapping is written directly: sub-index 0 is a read-only constant count
    and every entry is writable (0 = unused), as the STÖBER MDS 5000 of seed 004 does."""
    count = mapping.get(0)
    entries = [v for v in mapping if v.subindex]
    if count is None or count.writable or not entries:
        return False
    return all(v.writable for v in entries)


def _differs(var: Variable) -> bool:
    return var.parameter_value is not None and var.parameter_value != var.default


#: ``bad(variable, value, error, fatal)``: a value the object cannot hold (fatal) or that
#: lies outside its EDS limits (written anyway).
_Bad_value = Callable[[Variable, Any, Exception, bool], None]


class _Writes:
    """Collects start-up writes; a value the object cannot hold is reported, not written."""

    def __init__(self, bad: _Bad_value) -> None:
        self.entries: list[SdoEntry] = []
        self._bad = bad

    def add(self, var: Variable, value: Any, name: str) -> None:
        try:
            data = var.encode(value)
        except ValueRangeError as exc:
            try:  # within the type but outside the EDS limits: the device decides
                data = encode(var.data_type, value)
            except CobusError:
                self._bad(var, value, exc, True)
                return
            self._bad(var, value, exc, False)
        except CobusError as exc:
            self._bad(var, value, exc, True)
            return
        self.entries.append(SdoEntry(var.index, var.subindex, data, value, name))


def _startup(
    cfg: NodeConfig,
    yaml_set: set[tuple[int, int]],
    explicit: list[SdoEntry],
    bad: _Bad_value,
) -> list[SdoEntry]:
    """The start-up SDO list of a node (see the module text)."""
    od = cfg.od
    skip = {(e.index, e.subindex) for e in explicit}

    def wanted(var: Variable) -> bool:
        if (var.index, var.subindex) in skip or not var.writable:
            return False
        if not cfg.sdo_from_dcf and (var.index, var.subindex) not in yaml_set:
            return False
        return _differs(var)

    plain: list[Variable] = []
    for var in od.variables():
        index = var.index
        if index < 0x1000 or 0x1400 <= index <= 0x1BFF:
            continue
        if index in (_SAVE, _RESTORE) or index in _ERROR_CONTROL:
            continue
        if wanted(var):
            plain.append(var)
    # 1019h may only change while 1006h is 0: write it first
    plain.sort(key=lambda v: (0x1005 if v.index == 0x1019 else v.index, v.index, v.subindex))
    writes = _Writes(bad)
    for var in plain:
        writes.add(var, var.value, var.name)
    for comm_base, map_base, kind in ((0x1400, 0x1600, "RPDO"), (0x1800, 0x1A00, "TPDO")):
        for number in range(1, 513):
            comm = od.get(comm_base + number - 1)
            mapping = od.get(map_base + number - 1)
            if not isinstance(comm, Record | Array):
                continue
            _pdo_steps(cfg, comm, mapping, f"{kind} {number}", wanted, writes)
    return [*writes.entries, *explicit]


def _pdo_steps(
    cfg: NodeConfig,
    comm: Record | Array,
    mapping: Any,
    label: str,
    wanted: Callable[[Variable], bool],
    writes: _Writes,
) -> None:
    """The writes that (re)configure one PDO in the order CiA 301 wants: disable, clear the
    mapping, map, count, communication parameters, enable."""
    all_pdo = cfg.sdo_all_pdo
    comm_subs = [comm.get(s) for s in (2, 3, 5, 6)]
    map_vars = list(mapping) if isinstance(mapping, Record | Array) else []
    cob = comm.get(1)
    map_changed = all_pdo or any(wanted(v) for v in map_vars)
    comm_changed = all_pdo or any(v is not None and wanted(v) for v in comm_subs)
    cob_changed = cob is not None and (all_pdo or wanted(cob))
    if not (map_changed or comm_changed or cob_changed) or cob is None:
        return
    final = cob.value
    if not isinstance(final, int):
        return
    step = RemapStep
    steps: list[tuple[RemapStep, tuple[Variable, int, str]]] = []
    if cob.writable:
        steps.append((step.DISABLE, (cob, final | _INVALID, f"{label}: disable")))
    if map_changed and isinstance(mapping, Record | Array):
        count_var = mapping.get(0)
        count = count_var.value if count_var is not None else None
        if count_var is not None and count_var.writable and isinstance(count, int):
            steps.append((step.CLEAR_MAPPING, (count_var, 0, f"{label}: clear mapping")))
            for sub in sorted(k for k in mapping.subindices if 1 <= k <= count):
                var = mapping.get(sub)  # (the sub-indexes there are: a count may be damaged)
                if var is not None and isinstance(var.value, int):
                    steps.append((step.MAP, (var, var.value, f"{label}: map")))
            steps.append((step.COUNT, (count_var, count, f"{label}: mapped objects")))
        elif _direct_mapping(mapping):
            for var in map_vars:
                if var.subindex and isinstance(var.value, int):
                    steps.append((step.MAP, (var, var.value, f"{label}: map")))
    for var in comm_subs:
        if var is None or not var.writable or not isinstance(var.value, int):
            continue
        if all_pdo or wanted(var):
            steps.append((step.COMMUNICATION, (var, var.value, f"{label}: {var.name}")))
    if cob.writable and not final & _INVALID:
        steps.append((step.ENABLE, (cob, final, f"{label}: enable")))
    for var, value, name in in_remap_order(steps):
        writes.add(var, value, name)


def _read_master(raw: Any, report: _Report) -> MasterConfig:
    cfg = MasterConfig()
    if raw is None:
        return cfg
    try:
        spec = _mapping(raw, "master")
    except _Bad as exc:
        report.error(None, "master", str(exc), None)
        return cfg
    for key in spec:
        if key not in _MASTER_KEYS:
            report.error(
                None,
                f"master.{key}",
                f"unknown key{_suggest(str(key), _MASTER_KEYS)}",
                line_of(spec, key),
            )

    def get(key: str, parse: Any, default: Any) -> Any:
        if key not in spec:
            return default
        try:
            return parse(spec[key])
        except _Bad as exc:
            report.error(None, f"master.{key}", str(exc), line_of(spec, key))
            return default

    if "node_id" in spec and spec["node_id"] is not None:
        cfg.node_id = get("node_id", lambda v: _int(v, 1, 127, "node-ID"), None)

    def bitrate(value: Any) -> int:
        if value not in BIT_RATES:
            rates = ", ".join(str(r) for r in BIT_RATES)
            raise _Bad(f"{value!r} bit/s is no CiA 301 bit rate ({rates})")
        return int(value)

    cfg.bitrate = get("bitrate", bitrate, 500_000)
    cfg.sync_period = get("sync_period", lambda v: _ms(v, 4_294_967.295), 0.0) / 1000.0
    cfg.sync_cob_id = get("sync_cob_id", lambda v: _int(v, 1, 0x7FF, "COB-ID"), 0x80)

    def overflow(value: Any) -> int:
        v = _int(value, 0, 240, "counter overflow")
        if v == 1:
            raise _Bad("1 is not allowed: use 0 (no counter) or 2..240")
        return v

    cfg.sync_overflow = get("sync_overflow", overflow, 0)
    cfg.sync_by_interface = get("sync_by_interface", _bool, False)
    cfg.heartbeat_time = get("heartbeat_time", _whole_ms, 0)
    cfg.time_period = get("time_period", lambda v: _ms(v, 86_400_000), 0.0) / 1000.0
    cfg.time_cob_id = get("time_cob_id", lambda v: _int(v, 1, 0x7FF, "COB-ID"), 0x100)
    cfg.reset = get("reset", lambda v: _choice(v, ("node", "broadcast")), "node")
    cfg.start = get("start", lambda v: _choice(v, ("node", "broadcast")), "node")
    cfg.bootup_delay = get("bootup_delay", lambda v: _ms(v, 60_000), 300.0) / 1000.0
    cfg.pdo_timeout_factor = get("pdo_timeout_factor", lambda v: _number(v, 1.0, 100.0), 3.0)
    cfg.bus_load_window = get("bus_load_window", lambda v: _ms(v, 10_000), 250.0) / 1000.0
    if cfg.bus_load_window < 0.01:
        report.error(
            None, "master.bus_load_window", "use at least 10 ms", line_of(spec, "bus_load_window")
        )
        cfg.bus_load_window = 0.25
    if cfg.heartbeat_time and cfg.node_id is None:
        report.error(
            None,
            "master.heartbeat_time",
            "a master heartbeat needs master.node_id",
            line_of(spec, "heartbeat_time"),
        )
    if cfg.sync_period and cfg.sync_period_us < 1:
        report.error(None, "master.sync_period", "use at least 1 µs", line_of(spec, "sync_period"))
    if cfg.sync_by_interface and not cfg.sync_period:
        report.warning(
            None,
            "master.sync_by_interface",
            "the master sends no SYNC without a sync_period",
            line_of(spec, "sync_by_interface"),
        )
    return cfg


def _cross_checks(network: NetworkConfig, report: _Report) -> None:
    producers: dict[int, str] = {}
    for node in network.nodes.values():
        for layout in node.tpdos:
            other = producers.get(layout.cob_id)
            here = f"{node.name} TPDO {layout.number}"
            if other is not None:
                report.error(
                    node.name,
                    f"tpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is also sent by {other}: two producers collide",
                    None,
                )
            producers.setdefault(layout.cob_id, here)
    consumers: dict[int, str] = {}
    for node in network.nodes.values():
        for i, layout in enumerate(node.rpdos):
            here = f"{node.name} RPDO {layout.number}"
            other = consumers.get(layout.cob_id)
            if other is not None:
                report.error(
                    node.name,
                    f"rpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is also {other}'s; give each RPDO its own",
                    None,
                )
            consumers.setdefault(layout.cob_id, here)
            source = producers.get(layout.cob_id)
            if source is not None:
                report.warning(
                    node.name,
                    f"rpdo{layout.number}",
                    f"COB-ID 0x{layout.cob_id:X} is fed by {source} (PDO linking): the master "
                    "does not send it",
                    None,
                )
                node.rpdos[i] = replace(
                    layout, positions=tuple(None for _ in layout.positions), linked=True
                )
    master = network.master
    if master.time_period:
        for node in network.nodes.values():
            for layout in (*node.tpdos, *node.rpdos):
                if layout.cob_id == master.time_cob_id:
                    report.error(
                        node.name,
                        f"{layout.direction}{layout.number}",
                        f"COB-ID 0x{layout.cob_id:X} is the master's TIME identifier",
                        None,
                    )


def parse_network(
    data: Any, *, base_dir: str | os.PathLike[str] = ".", path: str = "<network>"
) -> tuple[NetworkConfig | None, list[ConfigProblem]]:
    """Read a network description already parsed from YAML (or built in code).

    Returns the configuration (None when there are errors) and every problem found."""
    report = _Report(path)
    return _parse(data, Path(base_dir), report), report.problems


def _parse(data: Any, base_dir: Path, report: _Report) -> NetworkConfig | None:
    if not isinstance(data, Mapping):
        report.error(None, None, "the file must be a mapping with master, defaults and nodes", None)
        return None
    for key in data:
        if key not in _TOP_KEYS:
            report.error(
                None,
                str(key),
                f"unknown section{_suggest(str(key), _TOP_KEYS)}",
                line_of(data, key),
            )
    master = _read_master(data.get("master"), report)
    defaults: Mapping[Any, Any] = {}
    if data.get("defaults") is not None:
        try:
            defaults = _mapping(data["defaults"], "defaults")
        except _Bad as exc:
            report.error(None, "defaults", str(exc), line_of(data, "defaults"))
        for key in defaults:
            if str(key) not in _NODE_KEYS or key in _NOT_DEFAULTABLE:
                allowed = [k for k in _NODE_KEYS if k not in _NOT_DEFAULTABLE]
                report.error(
                    None,
                    f"defaults.{key}",
                    f"not a key nodes can share{_suggest(str(key), allowed)}",
                    line_of(defaults, key),
                )
    nodes_raw = data.get("nodes")
    if not isinstance(nodes_raw, Mapping) or not nodes_raw:
        report.error(
            None,
            "nodes",
            "give the nodes: a mapping of node name to its settings",
            line_of(data, "nodes"),
        )
        return None
    nodes: dict[int, NodeConfig] = {}
    node_ids: dict[int, str] = {}
    texts: dict[Path, str] = {}
    for name, raw in nodes_raw.items():
        sname = str(name)
        if not isinstance(name, str) or not _NODE_NAME.match(name):
            report.error(
                sname,
                None,
                "node names start with a letter and use letters, digits, _ and -",
                line_of(nodes_raw, name),
            )
            continue
        if not isinstance(raw, Mapping):
            report.error(
                sname, None, "the node's settings must be a mapping", line_of(nodes_raw, name)
            )
            continue
        reader = _NodeReader(sname, raw, defaults, master, base_dir, report, texts)
        cfg = reader.read(node_ids)
        if cfg is not None:
            nodes[cfg.node_id] = cfg
    network = NetworkConfig(report.path, master, nodes)
    _cross_checks(network, report)
    network.warnings = [p for p in report.problems if p.severity is Severity.WARNING]
    if report.errors:
        return None
    return network


def _read_text(text: str, path: str, report: _Report) -> Any:
    data, problems = read_yaml(text)
    for problem in problems:
        report.error(None, problem.key, problem.reason, problem.line)
    return data


def check_network(
    path: str | os.PathLike[str],
) -> tuple[NetworkConfig | None, list[ConfigProblem]]:
    """Read ``path`` and list every problem (errors and warnings) without raising."""
    name = os.fspath(path)
    report = _Report(name)
    try:
        text = Path(name).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) else str(exc)
        report.error(None, None, f"cannot read the file: {reason}", None)
        return None, report.problems
    data = _read_text(text, name, report)
    if report.errors:
        return None, report.problems
    # Relative EDS paths start beside the file as it was named: a network file reached
    # through a symbolic link finds the EDS files beside the link.
    cfg = _parse(data, Path(os.path.abspath(name)).parent, report)
    return cfg, report.problems


def loads_network(
    text: str, *, base_dir: str | os.PathLike[str] = ".", path: str = "<string>"
) -> NetworkConfig:
    """Read a network description from YAML text; raise :class:`NetworkConfigError` on errors."""
    report = _Report(path)
    data = _read_text(text, path, report)
    cfg = None if report.errors else _parse(data, Path(base_dir), report)
    if cfg is None:
        raise NetworkConfigError(report.problems)
    return cfg


def load_network(path: str | os.PathLike[str]) -> NetworkConfig:
    """Read a network description file; raise :class:`NetworkConfigError` on errors."""
    cfg, problems = check_network(path)
    if cfg is None:
        raise NetworkConfigError(problems)
    return cfg
