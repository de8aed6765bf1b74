"""A sans-I/O CANopen decoder: a frame and its time in, typed records out.

>>> decoder = Decoder(dictionaries={5: load("servo.eds")})
>>> for record in decoder.feed(frame, now):
...     print(record)            # node 5 read 1008h:00 Device name = 'servo' (5 bytes, ...)

It knows the pre-defined connection set of CiA 301: NMT commands, boot-up, heartbeat, node
guarding (with its toggle bit), SYNC (with counter), TIME, EMCY (code text and error register
bits), LSS, SDO transfers **reassembled** across frames (expedited, segmented and block —
retransmitted segments counted once, the CRC checked — into one record with the value, its
size and how long it took; an abort with its text), and PDOs decoded into named values from
a node's dictionary — learning a new mapping when an SDO on the bus writes it. No threads,
no clock, no bus: the caller feeds frames (live, or from a trace file) and prints or keeps
what comes out.
"""

from __future__ import annotations

import bisect
import datetime as dt
import functools
import re
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from cobus._moved import renamed_names
from cobus.od import DataType, ObjectDictionary, Variable, decode
from cobus.profiles.cia402 import PowerState, error_text
from cobus.proto import Frame
from cobus.proto import emcy as _emcy
from cobus.proto.connection_set import (
    EMCY_BASE,
    ERROR_CONTROL_BASE,
    LSS_MASTER_COB_ID,
    LSS_SLAVE_COB_ID,
    MAX_NODE_ID,
    SDO_RX_BASE,
    SDO_TX_BASE,
    TPDO_BASE,
)
from cobus.proto.emcy import ErrorRegister, describe
from cobus.proto.sdo import SdoAbortCode, crc16
from cobus.trace._lss import LssSessions
from cobus.trace._lss import describe as describe_lss

__all__ = [
    "Bootup",
    "Decoder",
    "EmergencyRecord",
    "GuardRequest",
    "GuardResponse",
    "Heartbeat",
    "LssFrame",
    "LssSession",
    "NmtCommandRecord",
    "NodeStats",
    "PdoRecord",
    "SdoBlockFrame",
    "SdoTransfer",
    "SyncRecord",
    "TimeRecord",
    "TraceRecord",
    "Unknown",
    "frame_kind",
]

_STATES = {0x00: "BOOTUP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE_OPERATIONAL"}
_NMT = {
    0x01: "start",
    0x02: "stop",
    0x80: "enter pre-operational",
    0x81: "reset node",
    0x82: "reset communication",
}
_EPOCH = dt.datetime(1984, 1, 1, tzinfo=dt.UTC)
_SHOWN = 64  # characters of a value in a record's text
_GUARD_ANSWER = 1.0  # seconds within which a state frame answers a guarding request
#: A PDO's mapping object is its communication object + 200h (1600h/1A00h to 1400h/1800h).
_MAPPING = 0x200


@dataclass(frozen=True)
class TraceRecord:
    """What one or more frames meant: ``time`` of the (last) frame, its ``cob_id``."""

    time: float
    cob_id: int

    @property
    def kind(self) -> str:
        """The service: nmt, bootup, heartbeat, guarding, sync, time, emcy, sdo, pdo, lss..."""
        return _KINDS.get(type(self).__name__, "other")

    def concerns(self, node: int) -> bool:
        """Whether the record is about ``node``: its own frames, and NMT commands to it or to
        all nodes (a filter on one node must still show who stopped it)."""
        if getattr(self, "node", None) == node:
            return True
        return isinstance(self, NmtCommandRecord) and self.target in (0, node)


@dataclass(frozen=True)
class NmtCommandRecord(TraceRecord):
    """An NMT command: ``command`` to ``target`` (0: all nodes)."""

    command: str
    target: int

    def __str__(self) -> str:
        to = "all nodes" if self.target == 0 else f"node {self.target}"
        return f"NMT {self.command} -> {to}"


@dataclass(frozen=True)
class Bootup(TraceRecord):
    """A node's boot-up message."""

    node: int

    def __str__(self) -> str:
        return f"node {self.node} boot-up"


@dataclass(frozen=True)
class Heartbeat(TraceRecord):
    """A heartbeat: the NMT state the node reports."""

    node: int
    state: str

    def __str__(self) -> str:
        return f"node {self.node} heartbeat {self.state}"


@dataclass(frozen=True)
class GuardRequest(TraceRecord):
    """The master's node guarding request (a remote frame)."""

    node: int

    def __str__(self) -> str:
        return f"node {self.node} guarding request"


@dataclass(frozen=True)
class GuardResponse(TraceRecord):
    """A node guarding answer: state and toggle bit."""

    node: int
    state: str
    toggle: int
    #: The toggle bit did not alternate (the first answer after a boot-up carries 0):
    #: CiA 301 says the master treats a node's repeated toggle as a lost answer.
    toggle_error: bool = False

    def __str__(self) -> str:
        error = ", TOGGLE ERROR: not alternated" if self.toggle_error else ""
        return f"node {self.node} guarding {self.state} (toggle {self.toggle}{error})"


@dataclass(frozen=True)
class SyncRecord(TraceRecord):
    """A SYNC, with its counter when it has one."""

    counter: int | None

    def __str__(self) -> str:
        return "SYNC" if self.counter is None else f"SYNC {self.counter}"


@dataclass(frozen=True)
class TimeRecord(TraceRecord):
    """A TIME stamp (TIME_OF_DAY)."""

    moment: dt.datetime

    def __str__(self) -> str:
        return f"TIME {self.moment.isoformat(timespec='milliseconds')}"


@dataclass(frozen=True)
class EmergencyRecord(TraceRecord):
    """An emergency: code with its text, the error register and its bits. ``profile``: the
    device profile of the node (1000h), when the decoder knows it: a CiA 402 drive's codes
    have the CiA 402-2 texts."""

    node: int
    code: int
    register: int
    data: bytes
    profile: int | None = None

    @property
    def text(self) -> str:
        """The code's meaning (CiA 402-2's for a drive, else CiA 301's)."""
        if self.profile == 402:
            return error_text(self.code)
        return describe(self.code)

    @property
    def register_bits(self) -> list[str]:
        """The error register's bits by name (generic, current, voltage...)."""
        return [str(bit.name).lower() for bit in ErrorRegister if self.register & bit]

    @property
    def emergency(self) -> _emcy.Emergency:
        """The emergency as the rest of cobus keeps it (a remote node's ``emcy``, the master's
        histories): :class:`cobus.proto.emcy.Emergency`, ``data`` as its ``manufacturer_data``."""
        return _emcy.Emergency(
            self.node, self.time, self.code, ErrorRegister(self.register), self.data, self.text
        )

    def __str__(self) -> str:
        if self.code >> 8 == 0:
            register = f"{self.register:02X}h"
            return f"node {self.node} EMCY {self.code:04X}h error reset (register {register})"
        bits = ", ".join(self.register_bits) or "none"
        extra = f", data {self.data.hex(' ')}" if any(self.data) else ""
        return (
            f"node {self.node} EMCY {self.code:04X}h {self.text} (register {self.register:02X}h: "
            f"{bits}{extra})"
        )


@dataclass(frozen=True)
class SdoTransfer(TraceRecord):
    """A whole SDO transfer: read (upload) or write (download) of ``index``:``subindex``,
    its data and value (decoded with the node's dictionary, else as a number when short),
    how (expedited, segmented), how long from request to last answer; or its abort."""

    node: int
    write: bool
    index: int
    subindex: int
    data: bytes
    mode: str
    duration: float
    name: str | None = None
    value: Any = None
    abort_code: int | None = None

    @property
    def ok(self) -> bool:
        """Whether it ended without an abort."""
        return self.abort_code is None

    def __str__(self) -> str:
        verb = "write" if self.write else "read"
        name = f" {self.name}" if self.name else ""
        head = f"node {self.node} {verb} {self.index:04X}h:{self.subindex:02X}{name}"
        ms = f"{self.duration * 1000:.1f} ms"
        if self.abort_code is not None:
            try:
                text = SdoAbortCode(self.abort_code).text
            except ValueError:
                text = "unknown abort code"
            return f"{head} ABORTED 0x{self.abort_code:08X} {text} ({ms})"
        shown = repr(self.value) if self.value is not None else self.data.hex(" ")
        shown = shown or "(no data)"
        if len(shown) > _SHOWN:
            shown = shown[: _SHOWN - 3] + "..."
        size = f"{len(self.data)} byte{'' if len(self.data) == 1 else 's'}"
        return f"{head} = {shown} ({size}, {self.mode}, {ms})"


@dataclass(frozen=True)
class SdoBlockFrame(TraceRecord):
    """A frame of an SDO block transfer (not reassembled)."""

    node: int
    data: bytes

    def __str__(self) -> str:
        return f"node {self.node} SDO block frame {self.data.hex(' ')}"


@dataclass(frozen=True)
class PdoRecord(TraceRecord):
    """A PDO: its number and direction as the node sees it (``tpdo``: sent by the node), the
    data, and its values by name when the mapping is known."""

    node: int | None
    number: int | None
    tpdo: bool
    data: bytes
    values: Mapping[str, Any] = field(default_factory=dict)
    #: Units of the values that have one (the signals of a network file).
    units: Mapping[str, str] = field(default_factory=dict)

    def __str__(self) -> str:
        kind = "TPDO" if self.tpdo else "RPDO"
        number = f"{kind}{self.number}" if self.number else "PDO"
        who = f"node {self.node} " if self.node is not None else ""
        if self.values:
            body = ", ".join(
                f"{k}={v!r}" + (f" {self.units[k]}" if k in self.units else "")
                for k, v in self.values.items()
            )
        else:
            body = self.data.hex(" ") or "(no data)"
        return f"{who}{number} {body}"


@dataclass(frozen=True)
class LssFrame(TraceRecord):
    """An LSS frame (master request 7E5h, slave answer 7E4h) by its command specifier."""

    command: int
    data: bytes

    def __str__(self) -> str:
        who = "master" if self.cob_id == 0x7E5 else "slave"
        return f"LSS {who} {describe_lss(self.cob_id, self.data)}"


@dataclass(frozen=True)
class LssSession(TraceRecord):
    """What an LSS exchange came to, as a sentence: "LSS: serial 0x0000002A (...) got
    node-ID 12", "LSS: fastscan found ...", "... stored its configuration"."""

    sentence: str

    def __str__(self) -> str:
        return f"LSS: {self.sentence}"


@dataclass(frozen=True)
class Unknown(TraceRecord):
    """A frame the decoder has no meaning for."""

    data: bytes
    rtr: bool = False

    def __str__(self) -> str:
        return f"{self.cob_id:03X} {'RTR' if self.rtr else self.data.hex(' ')}"


_KINDS = {
    "NmtCommandRecord": "nmt",
    "Bootup": "hb",
    "Heartbeat": "hb",
    "GuardRequest": "hb",
    "GuardResponse": "hb",
    "SyncRecord": "sync",
    "TimeRecord": "time",
    "EmergencyRecord": "emcy",
    "SdoTransfer": "sdo",
    "SdoBlockFrame": "sdo",
    "PdoRecord": "pdo",
    "LssFrame": "lss",
    "LssSession": "lss",
}


def frame_kind(frame: Frame) -> str:
    """The service of one frame by its COB-ID in the pre-defined connection set of CiA 301
    (what a sniffer without the network's configuration shows): nmt, sync, emcy, time, pdo,
    sdo, hb (boot-up, heartbeat, guarding), lss or other. The :class:`Decoder` goes further:
    it follows PDOs moved to other COB-IDs and reassembles SDO transfers."""
    cob = frame.cob_id
    if frame.extended:
        return "other"
    if cob == 0x000:
        return "nmt"
    if cob == 0x080:
        return "sync"
    if EMCY_BASE < cob <= EMCY_BASE + MAX_NODE_ID:
        return "emcy"
    if cob == 0x100:
        return "time"
    if cob < 0x180:
        return "other"
    if TPDO_BASE <= cob < SDO_TX_BASE:
        return "pdo"
    if (SDO_TX_BASE < cob <= SDO_TX_BASE + MAX_NODE_ID) or (
        SDO_RX_BASE < cob <= SDO_RX_BASE + MAX_NODE_ID
    ):
        return "sdo"
    if ERROR_CONTROL_BASE < cob <= ERROR_CONTROL_BASE + MAX_NODE_ID:
        return "hb"
    if cob in (0x7E4, 0x7E5):
        return "lss"
    return "other"


@dataclass
class _Sdo:
    write: bool
    index: int
    subindex: int
    began: float
    data: bytearray = field(default_factory=bytearray)
    size: int | None = None
    segmented: bool = False
    last_segment: bool = False
    #: Block transfer: "" (not one), "init", "segments" (a sub-block under way), "acked"
    #: (waiting for the next sub-block or the end).
    block: str = ""
    crc: bool = False
    #: The current sub-block's segments by sequence number (retransmissions overwrite).
    segments: dict[int, bytes] = field(default_factory=dict)
    last_seq: int = 0
    crc_value: int | None = None
    #: The toggle bit the next segment carries (segmented transfers).
    toggle: int = 0


@dataclass
class _Pdo:
    node: int
    number: int
    tpdo: bool
    entries: list[tuple[str | None, DataType, int]]  # name (None: a gap), type, bits
    #: From a network file: the PDO's codec and, per value, (name, signal or None).
    layout: Any = None
    named: tuple[tuple[str, Any], ...] = ()
    #: The name of the value that is a CiA 402 statusword (6041h, or 6841h... of axis 2..8).
    statusword: str | None = None
    axis: int = 1
    stats: Any = None  # the node's NodeStats, once a statusword came


class NodeStats:
    """What the bus shows of one node over time: SDO answer latency, heartbeat interval,
    jitter and missed beats, emergencies, and a time line of its states and emergencies."""

    #: How many samples (latencies, intervals) and time-line entries are kept.
    KEEP = 1000

    def __init__(self, node: int) -> None:
        self.node = node
        self.sdo_latencies: deque[float] = deque(maxlen=self.KEEP)
        self.heartbeat_intervals: deque[float] = deque(maxlen=self.KEEP)
        self._sorted_intervals: list[float] = []  # (the same, sorted: the period at once)
        self.heartbeats = 0
        self.missed_beats = 0
        self.last_heartbeat: float | None = None
        self.emcy_count = 0
        self.toggle_errors = 0  # guarding answers whose toggle bit did not alternate
        self.last_emcy: str | None = None
        self.state: str | None = None
        #: Axis (1..8) -> the CiA 402 power state its statusword (6041h, 6841h... in a PDO
        #: or an SDO answer) reports.
        self.drive_states: dict[int, str] = {}
        self._statuswords: dict[int, int] = {}  # axis -> the last raw statusword
        self.timeline: deque[tuple[float, str]] = deque(maxlen=self.KEEP)

    @property
    def sdo_latency(self) -> tuple[float, float, float] | None:
        """(min, median, max) seconds from an SDO request to its answer, None before one."""
        if not self.sdo_latencies:
            return None
        values = sorted(self.sdo_latencies)
        return values[0], values[len(values) // 2], values[-1]

    @property
    def heartbeat_period(self) -> float | None:
        """The median interval between heartbeats (None before two came)."""
        values = self._sorted_intervals
        if len(values) != len(self.heartbeat_intervals):  # (someone filled the deque)
            values = self._sorted_intervals = sorted(self.heartbeat_intervals)
        if not values:
            return None
        return values[len(values) // 2]

    @property
    def jitter(self) -> float | None:
        """The largest deviation of an interval from the median one (seconds)."""
        period = self.heartbeat_period
        if period is None:
            return None
        return max(abs(i - period) for i in self.heartbeat_intervals)

    def _heartbeat(self, now: float, state: str) -> None:
        if self.last_heartbeat is not None:
            interval = now - self.last_heartbeat
            period = self.heartbeat_period
            if period and interval > 1.5 * period:
                self.missed_beats += max(1, round(interval / period) - 1)
            intervals, ordered = self.heartbeat_intervals, self._sorted_intervals
            if len(intervals) == intervals.maxlen and len(ordered) == len(intervals):
                del ordered[bisect.bisect_left(ordered, intervals[0])]
            intervals.append(interval)
            if len(ordered) == len(intervals) - 1:
                bisect.insort(ordered, interval)
        self.last_heartbeat = now
        self.heartbeats += 1
        self._state(now, state)

    def _state(self, now: float, state: str) -> None:
        if state != self.state:
            self.state = state
            self.timeline.append((now, state))

    @property
    def drive_state(self) -> str | None:
        """The CiA 402 power state of the (first) axis, None before a statusword came."""
        return self.drive_states.get(1)

    def _statusword(self, now: float, statusword: Any, axis: int = 1) -> None:
        if self._statuswords.get(axis) == statusword:  # (most frames: nothing new)
            return
        if isinstance(statusword, bool) or not isinstance(statusword, int):
            return
        self._statuswords[axis] = statusword
        state = PowerState.from_statusword(statusword).name
        if state != self.drive_states.get(axis):
            self.drive_states[axis] = state
            where = "" if axis == 1 else f"axis {axis} "
            self.timeline.append((now, f"CiA 402 {where}{state}"))

    def summary(self) -> dict[str, Any]:
        """The figures as plain data (a node table, ``--json``)."""
        latency = self.sdo_latency
        return {
            "node": self.node,
            "state": self.state,
            "drive_state": self.drive_state,
            "drive_states": dict(self.drive_states),
            "heartbeats": self.heartbeats,
            "heartbeat_period": self.heartbeat_period,
            "jitter": self.jitter,
            "missed_beats": self.missed_beats,
            "sdo_latency": None
            if latency is None
            else dict(zip(("min", "median", "max"), latency, strict=True)),
            "emcy_count": self.emcy_count,
            "last_emcy": self.last_emcy,
            "toggle_errors": self.toggle_errors,
        }


class Decoder:
    """Decodes frames of a CANopen bus. ``dictionaries``: node-ID → its dictionary (from
    its EDS/DCF) for object names, value types and PDO mappings. ``stats`` holds what it saw
    of each node (:class:`NodeStats`)."""

    def __init__(
        self,
        dictionaries: Mapping[int, ObjectDictionary] | None = None,
        network: Any = None,
    ) -> None:
        self.dictionaries = dict(dictionaries or {})
        if network is not None:  # a master's NetworkConfig: its nodes' EDS for names
            for cfg in network.nodes.values():
                self.dictionaries.setdefault(cfg.node_id, cfg.od)
        #: Node-ID -> what the bus showed of it.
        self.stats: dict[int, NodeStats] = {}
        self._requested: dict[int, float] = {}
        self._sdo: dict[int, _Sdo] = {}
        self._guard_asked: dict[int, float] = {}  # node -> when the master's RTR came
        self._toggle: dict[int, int] = {}  # node -> the toggle bit its next guard answer carries
        #: LSS requests and answers followed into sessions (the slave being configured).
        self.lss = LssSessions()
        self._pdos: dict[int, _Pdo] = {}
        #: Counts the changes of ``_pdos`` (the batch decoder re-reads the mappings on one).
        self._pdo_generation = 0
        #: (node, tpdo, number) -> the PDO as a network file has it.
        self._layouts: dict[tuple[int, bool, int], _Pdo] = {}
        self._params: dict[int, dict[tuple[int, int], int]] = {}
        #: Node -> its device profile (1000h bits 0-15), from its EDS or a read of 1000h.
        self._profiles: dict[int, int] = {}
        for node, od in self.dictionaries.items():
            device_type = od.get_variable(0x1000, 0)
            if device_type is not None and isinstance(device_type.value, int):
                self._profiles[node] = device_type.value & 0xFFFF
            if od.node_id is None:
                od.node_id = node  # ($NODEID in COB-IDs: the node it is given for)
            self._learn(node, od)
        if network is not None:
            for cfg in network.nodes.values():
                self._configured(cfg)

    def _configured(self, cfg: Any) -> None:
        """The PDOs as the network file configures them (the master writes that mapping at
        boot), with its signal names, scales and units: ``drive1 TPDO1 position=12.5 mm``."""
        for layout in (*cfg.tpdos, *cfg.rpdos):
            if layout.extended or layout.linked:  # (a linked RPDO is another node's TPDO)
                continue
            real = [e for e in layout.codec.entries if not e.is_dummy]
            named = []
            for entry, signal in zip(real, layout.positions, strict=False):
                if signal is not None:
                    named.append((signal.name, signal))
                else:
                    var = cfg.od.get_variable(entry.index, entry.subindex)
                    label = _name(var) if var is not None else None
                    named.append((label or f"{entry.index:04X}h:{entry.subindex:02X}", None))
            tpdo = layout.direction == "tpdo"
            pdo = _Pdo(cfg.node_id, layout.number, tpdo, [], layout, tuple(named))
            if tpdo:
                for (label, _), entry in zip(named, real, strict=False):
                    if _is_statusword(entry.index):
                        pdo.statusword, pdo.axis = label, _axis(entry.index)
                        break
            self._layouts[(cfg.node_id, tpdo, layout.number)] = pdo
            self._place(layout.cob_id, pdo)

    def _place(self, key: int, pdo: _Pdo) -> None:
        """Let ``pdo`` name frames of COB-ID ``key``, unless another node's TPDO does: a
        node's TPDO names the frame, not another's RPDO of it (PDO linking)."""
        other = self._pdos.get(key)
        if other is not None and other.node != pdo.node and other.tpdo and not pdo.tpdo:
            return
        self._pdos[key] = pdo
        self._pdo_generation += 1

    # ------------------------------------------------------------------ PDO mappings

    def _learn(self, node: int, od: ObjectDictionary) -> None:
        """Take the node's PDO parameters (1400h-1BFFh) from its dictionary."""
        params: dict[tuple[int, int], int] = {}
        for var in od.variables():
            if 0x1400 <= var.index <= 0x1BFF and isinstance(var.value, int):
                params[(var.index, var.subindex)] = var.value
        self._params[node] = params
        self._rebuild(node)

    def _rebuild(self, node: int) -> None:
        """Make the node's PDOs anew from its parameters; where nothing comes out changed
        (a write of an inhibit time, an event timer...), the PDOs stay as they were."""
        was, generation = dict(self._pdos), self._pdo_generation
        self._make(node)
        if {c: _pdo_key(p) for c, p in self._pdos.items()} == {
            c: _pdo_key(p) for c, p in was.items()
        }:
            self._pdos.clear()
            self._pdos.update(was)
            self._pdo_generation = generation

    def _make(self, node: int) -> None:
        for cob_id in [c for c, p in self._pdos.items() if p.node == node]:
            del self._pdos[cob_id]
            self._pdo_generation += 1
        params = self._params.get(node, {})
        od = self.dictionaries.get(node)
        for base, tpdo in ((0x1400, False), (0x1800, True)):
            for n in range(512):
                cob = params.get((base + n, 1))
                if cob is None or cob & (1 << 31):
                    continue
                count = params.get((base + _MAPPING + n, 0), 0)
                mapped = [
                    params.get((base + _MAPPING + n, k), 0) for k in range(1, min(count, 64) + 1)
                ]
                configured = self._layouts.get((node, tpdo, n + 1))
                if configured is not None:
                    wanted = [
                        (e.index << 16) | (e.subindex << 8) | e.bit_length
                        for e in configured.layout.codec.entries
                    ]
                    if wanted == mapped:  # the file's mapping (wherever the PDO is moved)
                        self._place(cob & 0x7FF, configured)
                        continue
                entries: list[tuple[str | None, DataType, int]] = []
                names: set[str] = set()
                statusword: str | None = None
                axis = 1
                for sub in range(1, min(count, 64) + 1):
                    raw = params.get((base + _MAPPING + n, sub), 0)
                    index, subindex, bits = raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF
                    if index < 0x1000:  # a dummy entry (a data type index): a gap
                        entries.append((None, DataType.UNSIGNED8, bits))
                        continue
                    var = od.get_variable(index, subindex) if od is not None else None
                    if var is None:
                        name = f"{index:04X}h:{subindex:02X}"
                        data_type = DataType.UNSIGNED32 if bits > 16 else DataType.UNSIGNED16
                        data_type = DataType.UNSIGNED8 if bits <= 8 else data_type
                    else:
                        name, data_type = _name(var), var.data_type
                    if name in names:  # the same object mapped twice
                        name = f"{name}#{sub}"
                    names.add(name)
                    entries.append((name, data_type, bits))
                    if tpdo and statusword is None and _is_statusword(index):
                        statusword, axis = name, _axis(index)
                self._place(
                    cob & 0x7FF, _Pdo(node, n + 1, tpdo, entries, statusword=statusword, axis=axis)
                )

    # ------------------------------------------------------------------ frames

    def node_stats(self, node: int) -> NodeStats:
        """What the bus showed of ``node`` (created when first asked for)."""
        found = self.stats.get(node)
        if found is None:
            found = self.stats[node] = NodeStats(node)
        return found

    def pdo_of(self, cob_id: int) -> tuple[int, int, bool] | None:
        """(node, PDO number, whether the node sends it) of the PDO on ``cob_id`` as the
        decoder knows it (an EDS, the network file, a configuration it saw), else None."""
        pdo = self._pdos.get(cob_id)
        return None if pdo is None else (pdo.node, pdo.number, pdo.tpdo)

    def feed(self, frame: Frame, now: float) -> list[TraceRecord]:
        """The records ``frame`` completes (none while an SDO transfer is under way)."""
        records = self._decode(frame, now)
        cob = frame.cob_id
        if SDO_TX_BASE < cob <= SDO_TX_BASE + MAX_NODE_ID and not frame.rtr:
            asked = self._requested.pop(cob - SDO_TX_BASE, None)
            if asked is not None:
                self.node_stats(cob - SDO_TX_BASE).sdo_latencies.append(now - asked)
        elif SDO_RX_BASE < cob <= SDO_RX_BASE + MAX_NODE_ID and not frame.rtr:
            self._requested[cob - SDO_RX_BASE] = now
        for rec in records:
            if isinstance(rec, Heartbeat | GuardResponse):
                stats = self.node_stats(rec.node)
                stats._heartbeat(now, rec.state)
                if isinstance(rec, GuardResponse) and rec.toggle_error:
                    stats.toggle_errors += 1
                    stats.timeline.append((now, "guarding toggle error"))
            elif isinstance(rec, Bootup):
                stats = self.node_stats(rec.node)
                stats._state(now, "BOOTUP")
                stats.last_heartbeat = None  # (a reset: the intervals start again)
            elif isinstance(rec, SdoTransfer) and rec.write and rec.index == 0x1017 and rec.ok:
                if rec.value:  # the node produces heartbeats now: guarding is over
                    self._toggle.pop(rec.node, None)
            elif isinstance(rec, SdoTransfer) and _is_statusword(rec.index) and rec.subindex == 0:
                if not rec.write and rec.ok and rec.mode != "incomplete":
                    value = rec.value
                    if value is None and len(rec.data) == 2:
                        value = int.from_bytes(rec.data, "little")
                    self.node_stats(rec.node)._statusword(now, value, _axis(rec.index))
            elif isinstance(rec, EmergencyRecord):
                stats = self.node_stats(rec.node)
                stats.emcy_count += 1
                stats.last_emcy = str(rec).split(" ", 2)[2]
                stats.timeline.append((now, f"EMCY {rec.code:04X}h"))
        return records

    def flush(self, now: float) -> list[TraceRecord]:
        """The SDO transfers still open (a trace that ended mid-transfer), as records of
        mode "incomplete" with the data seen so far."""
        out: list[TraceRecord] = []
        for node in sorted(self._sdo):
            t = self._sdo.pop(node)
            cob = (SDO_RX_BASE if t.write else SDO_TX_BASE) + node
            name = self._object_name(node, t.index, t.subindex)
            out.append(
                SdoTransfer(
                    now,
                    cob,
                    node,
                    t.write,
                    t.index,
                    t.subindex,
                    bytes(t.data),
                    "incomplete",
                    now - t.began,
                    name,
                )
            )
        return out

    def _decode(self, frame: Frame, now: float) -> list[TraceRecord]:
        cob, data = frame.cob_id, bytes(frame.data)
        if frame.extended:
            return [Unknown(now, cob, data, frame.rtr)]
        if cob in self._pdos and not frame.rtr:
            return [self._pdo(now, cob, data)]
        func, node = cob & 0x780, cob & 0x7F
        if cob == 0x000 and len(data) >= 2:
            if data[0] in (0x81, 0x82):  # a reset: the next guarding answer carries toggle 0
                for target in list(self._toggle) if data[1] == 0 else [data[1]]:
                    self._toggle[target] = 0
            return [
                NmtCommandRecord(now, cob, _NMT.get(data[0], f"command {data[0]:02X}h"), data[1])
            ]
        if cob == 0x080:
            return [SyncRecord(now, cob, data[0] if data else None)]
        if cob == 0x100 and len(data) >= 6:
            ms = int.from_bytes(data[:4], "little") & 0x0FFFFFFF
            days = int.from_bytes(data[4:6], "little")
            moment = _EPOCH + dt.timedelta(days=days, milliseconds=ms)
            return [TimeRecord(now, cob, moment)]
        if func == 0x080 and node and len(data) >= 3:
            code = int.from_bytes(data[:2], "little")
            profile = self._profiles.get(node)
            extra = data[3:8].ljust(5, b"\0")
            return [EmergencyRecord(now, cob, node, code, data[2], extra, profile)]
        if func == ERROR_CONTROL_BASE and node:
            if frame.rtr:
                self._guard_asked[node] = now
                return [GuardRequest(now, cob, node)]
            if len(data) == 1:
                state = data[0] & 0x7F
                if state == 0:
                    self._toggle[node] = 0  # the first guarding answer carries 0
                    return [Bootup(now, cob, node)]
                name = _STATES.get(state, f"state {state:02X}h")
                asked = self._guard_asked.pop(node, None)
                if asked is not None and now - asked <= _GUARD_ANSWER:
                    toggle = data[0] >> 7
                    expected = self._toggle.get(node)
                    self._toggle[node] = toggle ^ 1
                    wrong = expected is not None and toggle != expected
                    return [GuardResponse(now, cob, node, name, toggle, wrong)]
                self._toggle.pop(node, None)  # a heartbeat (or a late answer): start afresh
                return [Heartbeat(now, cob, node, name)]
        if cob in (LSS_SLAVE_COB_ID, LSS_MASTER_COB_ID) and data:
            said = self.lss.feed(cob, data, now)
            return [LssFrame(now, cob, data[0], data), *(LssSession(now, cob, x) for x in said)]
        if func == SDO_RX_BASE and node and len(data) == 8:
            return self._sdo_request(now, cob, node, data)
        if func == SDO_TX_BASE and node and len(data) == 8:
            return self._sdo_response(now, cob, node, data)
        if TPDO_BASE <= cob < SDO_TX_BASE and not frame.rtr:
            k = (cob - TPDO_BASE) >> 7
            number, tpdo = k // 2 + 1, k % 2 == 0
            return [PdoRecord(now, cob, cob & 0x7F, number, tpdo, data)]
        return [Unknown(now, cob, data, frame.rtr)]

    def _pdo(self, now: float, cob: int, data: bytes) -> PdoRecord:
        pdo = self._pdos[cob]
        values, units = pdo_values(pdo, data)
        if pdo.statusword is not None and (pdo.layout is None or values):
            # (a frame too short for a network file's mapping shows its bytes only)
            if pdo.stats is None:
                pdo.stats = self.node_stats(pdo.node)
            pdo.stats._statusword(now, values.get(pdo.statusword), pdo.axis)
        if units is None:
            return PdoRecord(now, cob, pdo.node, pdo.number, pdo.tpdo, data, values)
        return PdoRecord(now, cob, pdo.node, pdo.number, pdo.tpdo, data, values, units)

    # ------------------------------------------------------------------ SDO

    def _sdo_request(self, now: float, cob: int, node: int, data: bytes) -> list[TraceRecord]:
        ccs = data[0] >> 5
        index, sub = int.from_bytes(data[1:3], "little"), data[3]
        t0 = self._sdo.get(node)
        if t0 is not None and t0.block == "segments" and t0.write and data[0] != 0x80:
            return self._block_segment(t0, data)  # sub-block data (80h: an abort)
        if ccs == 6:  # block download: initiate (cs 0) or end (cs 1)
            if data[0] & 0x01 == 0:
                t = _Sdo(True, index, sub, now, block="init", crc=bool(data[0] & 0x04))
                t.size = int.from_bytes(data[4:8], "little") if data[0] & 0x02 else None
                self._sdo[node] = t
                return []
            if t0 is not None and t0.block:
                n = (data[0] >> 2) & 0x7
                if n:
                    del t0.data[len(t0.data) - n :]
                t0.block = "end"
                t0.segments = {}
                t0.crc_value = int.from_bytes(data[1:3], "little")
            return []
        if ccs == 5:  # block upload: initiate (cs 0), start (3), ack (2), end response (1)
            cs = data[0] & 0x03
            if cs == 0:
                self._sdo[node] = _Sdo(
                    False, index, sub, now, block="init", crc=bool(data[0] & 0x04)
                )
            elif t0 is not None and t0.block:
                if cs == 3:
                    t0.block = "segments"
                elif cs == 2:
                    self._block_ack(t0, data[1])
                elif cs == 1 and t0.block == "end":
                    return self._done(now, cob, node, "block")
            return []
        if ccs == 1:  # initiate download
            t = _Sdo(True, index, sub, now)
            if data[0] & 0x02:  # expedited
                n = (data[0] >> 2) & 0x3 if data[0] & 0x01 else 0
                t.data = bytearray(data[4 : 8 - n])
            else:
                t.segmented = True
                t.size = int.from_bytes(data[4:8], "little") if data[0] & 0x01 else None
            self._sdo[node] = t
        elif ccs == 2:  # initiate upload
            self._sdo[node] = _Sdo(False, index, sub, now)
        elif ccs == 0:  # download segment
            t2 = self._sdo.get(node)
            if t2 is not None and t2.write and (data[0] >> 4) & 1 == t2.toggle:
                n = (data[0] >> 1) & 0x7
                t2.data += data[1 : 8 - n]
                t2.last_segment = bool(data[0] & 0x01)
                t2.toggle ^= 1  # (a segment repeated with the old toggle bit is not data)
        elif data[0] == 0x80:  # abort by the client
            return self._abort(now, cob, node, data)
        return []

    def _sdo_response(self, now: float, cob: int, node: int, data: bytes) -> list[TraceRecord]:
        scs = data[0] >> 5
        t = self._sdo.get(node)
        if t is not None and t.block == "segments" and not t.write and data[0] != 0x80:
            return self._block_segment(t, data)  # sub-block data (80h: an abort)
        if data[0] == 0x80:
            return self._abort(now, cob, node, data)
        answered = (int.from_bytes(data[1:3], "little"), data[3])
        if t is not None and scs in (2, 3) and not t.block and answered != (t.index, t.subindex):
            del self._sdo[node]  # an answer about another object: the request was not it
            t = None
        if t is None:
            if scs == 2 and data[0] & 0x02:  # a whole expedited answer: its request not seen
                t = self._sdo[node] = _Sdo(False, int.from_bytes(data[1:3], "little"), data[3], now)
                n = (data[0] >> 2) & 0x3 if data[0] & 0x01 else 0
                t.data = bytearray(data[4 : 8 - n])
                return self._done(now, cob, node, "expedited, request not seen")
            return [SdoBlockFrame(now, cob, node, data)] if scs in (5, 6) else []
        if t.block and t.write and scs == 5:  # block download answers
            ss = data[0] & 0x03
            if ss == 0:
                t.block = "segments"
                t.crc = t.crc and bool(data[0] & 0x04)  # (both must support it)
            elif ss == 2:
                self._block_ack(t, data[1])
            elif ss == 1:
                return self._done(now, cob, node, "block")
            return []
        if t.block and not t.write and scs == 6:  # block upload: initiate answer or end
            if data[0] & 0x01 == 0:
                t.size = int.from_bytes(data[4:8], "little") if data[0] & 0x02 else None
                t.crc = t.crc and bool(data[0] & 0x04)
            else:
                n = (data[0] >> 2) & 0x7
                if n:
                    del t.data[len(t.data) - n :]
                t.block = "end"
                t.crc_value = int.from_bytes(data[1:3], "little")
            return []
        if t.block == "init" and not t.write and scs == 2:
            t.block = ""  # the server switched to a normal upload (protocol switch)
        if scs == 3 and t.write:  # initiate download response
            return [] if t.segmented else self._done(now, cob, node, "expedited")
        if scs == 1 and t.write:  # download segment response
            return self._done(now, cob, node, "segmented") if t.last_segment else []
        if scs == 2 and not t.write:  # initiate upload response
            if data[0] & 0x02:
                n = (data[0] >> 2) & 0x3 if data[0] & 0x01 else 0
                t.data = bytearray(data[4 : 8 - n])
                return self._done(now, cob, node, "expedited")
            t.segmented = True
            t.size = int.from_bytes(data[4:8], "little") if data[0] & 0x01 else None
            return []
        if scs == 0 and not t.write and (data[0] >> 4) & 1 == t.toggle:  # upload segment
            n = (data[0] >> 1) & 0x7
            t.data += data[1 : 8 - n]
            t.toggle ^= 1
            if data[0] & 0x01:
                return self._done(now, cob, node, "segmented")
        return []

    def _block_segment(self, t: _Sdo, data: bytes) -> list[TraceRecord]:
        seq = data[0] & 0x7F
        t.segments[seq] = data[1:8]
        if data[0] & 0x80:
            t.last_segment, t.last_seq = True, seq
        return []

    def _block_ack(self, t: _Sdo, ackseq: int) -> None:
        """The receiver confirmed segments 1..ackseq of the sub-block: they count, the
        rest will come again."""
        for seq in range(1, ackseq + 1):
            chunk = t.segments.get(seq)
            if chunk is not None:
                t.data += chunk
        t.segments = {}
        if t.last_segment and ackseq >= t.last_seq:
            t.block = "end"  # the whole data went through
        else:
            t.last_segment = False  # (the rest of the sub-block comes again)
            t.block = "segments"

    def _abort(self, now: float, cob: int, node: int, data: bytes) -> list[TraceRecord]:
        t = self._sdo.pop(node, None)
        index, sub = int.from_bytes(data[1:3], "little"), data[3]
        code = int.from_bytes(data[4:8], "little")
        write = t.write if t is not None else False
        began = t.began if t is not None else now
        name = self._object_name(node, index, sub)
        return [
            SdoTransfer(
                now, cob, node, write, index, sub, b"", "aborted", now - began, name, None, code
            )
        ]

    def _done(self, now: float, cob: int, node: int, mode: str) -> list[TraceRecord]:
        t = self._sdo.pop(node)
        data = bytes(t.data)
        if t.block and t.size is not None:
            data = data[: t.size]
        if not t.block and t.size is not None and len(data) != t.size:
            mode = f"{mode}, {t.size} bytes announced"
        if t.block and t.crc and t.crc_value is not None and crc16(data) != t.crc_value:
            mode = f"block, CRC {t.crc_value:04X}h WRONG (data gives {crc16(data):04X}h)"
        var = self._variable(node, t.index, t.subindex)
        value: Any = None
        size = var.data_type.size if var is not None else None
        if var is not None and node not in self.dictionaries and size and size != len(data):
            # CiA 301's type of an object, but the node sent another length: its own type
            # (unknown without its EDS) rules, so the bytes are shown as they came.
            value = int.from_bytes(data, "little") if 0 < len(data) <= 4 else None
        elif var is not None:
            try:
                size = var.data_type.size
                value = decode(var.data_type, data[:size] if size else data)
            except ValueError:
                value = None
        elif 0 < len(data) <= 4:
            value = int.from_bytes(data, "little")
        if (t.index, t.subindex) == (0x1000, 0) and len(data) >= 2:
            self._profiles[node] = int.from_bytes(data[:2], "little")  # what the node says
        if t.write and 0x1400 <= t.index <= 0x1BFF and isinstance(value, int):
            self._params.setdefault(node, {})[(t.index, t.subindex)] = value
            self._rebuild(node)  # a mapping written on the bus: learnt
        name = _name(var) if var is not None else None
        return [
            SdoTransfer(
                now, cob, node, t.write, t.index, t.subindex, data, mode, now - t.began, name, value
            )
        ]

    def _variable(self, node: int, index: int, sub: int) -> Variable | None:
        od = self.dictionaries.get(node)
        if od is not None:
            return od.get_variable(index, sub)
        return standard_variable(index, sub)  # no EDS: CiA 301 still names 1000h-1BFFh

    def _object_name(self, node: int, index: int, sub: int) -> str | None:
        var = self._variable(node, index, sub)
        return _name(var) if var is not None else None


def _pdo_key(pdo: _Pdo) -> tuple[Any, ...]:
    """What decides how ``pdo`` decodes a frame."""
    return (
        pdo.node,
        pdo.number,
        pdo.tpdo,
        tuple(pdo.entries),
        id(pdo.layout),
        pdo.named,
        pdo.statusword,
        pdo.axis,
    )


def pdo_values(pdo: _Pdo, data: bytes) -> tuple[dict[str, Any], dict[str, str] | None]:
    """The values of ``pdo`` in ``data`` by name, and their units (None: a mapping from a
    dictionary, whose values have none; a network file's signals may)."""
    values: dict[str, Any] = {}
    if pdo.layout is not None:
        units: dict[str, str] = {}
        try:
            raws = pdo.layout.codec.unpack(data)
        except Exception:  # shorter than the mapping: the bytes as they came
            return values, units
        for (label, signal), raw in zip(pdo.named, raws, strict=False):
            if signal is None:
                values[label] = raw
                continue
            try:
                values[label] = signal.to_engineering(raw)
            except (TypeError, ValueError):
                values[label] = raw
            if signal.unit:
                units[label] = signal.unit
        return values, units
    raw = int.from_bytes(data, "little")
    bit = 0
    for name, data_type, bits in pdo.entries:
        if bit + bits > 8 * len(data):
            break
        chunk = (raw >> bit) & ((1 << bits) - 1)
        size = data_type.size or (bits + 7) // 8
        if name is None:  # a dummy entry: a gap
            bit += bits
            continue
        if bits == 8 * size:
            try:
                values[name] = decode(data_type, chunk.to_bytes(size, "little"))
            except ValueError:
                values[name] = chunk
        else:
            values[name] = chunk
        bit += bits
    return values, None


def _axis(index: int) -> int:
    """The axis (1..8) of a CiA 402 object: 6xxxh is axis 1, 68xxh axis 2, 70xxh axis 3..."""
    return (index - 0x6000) // 0x800 + 1


def _is_statusword(index: int) -> bool:
    """6041h, or the statusword of axis 2..8 (6841h, 7041h... : 800h apart)."""
    return 0x6041 <= index <= 0x6041 + 7 * 0x800 and (index - 0x6041) % 0x800 == 0


_FAMILIES = (
    (0x1200, 0x127F),
    (0x1400, 0x15FF),
    (0x1600, 0x17FF),
    (0x1800, 0x19FF),
    (0x1A00, 0x1BFF),
)
_LISTS = {0x1003, 0x1016, 0x1600, 0x1A00}  # sub-indexes 1..n: the same kind of entry
_TRAILING_NUMBER = re.compile(r"\d+$")


@functools.cache
def _cia301() -> ObjectDictionary:
    from cobus.device.dictionary import minimal_od

    return minimal_od(rpdos=1, tpdos=1, mapping_entries=1, heartbeat_consumers=1, error_history=1)


@functools.cache
def standard_variable(index: int, subindex: int) -> Variable | None:
    """The CiA 301 communication object at ``index``:``subindex`` (its standard name and
    type), for a node whose EDS is not known; None outside what CiA 301 defines."""
    if not 0x1000 <= index <= 0x1BFF:
        return None
    base, number = index, None
    for start, end in _FAMILIES:
        if start <= index <= end:
            base, number = start, index - start + 1
    od = _cia301()
    var = od.get_variable(base, subindex)
    renumber = False
    if var is None and base in _LISTS and 1 <= subindex <= 254:
        var, renumber = od.get_variable(base, 1), True
    if var is None:
        return None
    name = _TRAILING_NUMBER.sub(str(subindex), var.name) if renumber else var.name
    if var.parent is not None:
        parent = var.parent.name
        if number is not None:
            parent = _TRAILING_NUMBER.sub(str(number), parent)
        name = f"{parent}.{name}"
    return Variable(index, subindex, name, var.data_type, var.access)


def _name(var: Variable) -> str:
    if var.parent is None:
        return var.name
    return f"{var.parent.name}.{var.name}"


#: One name per idea: cobus.od.Record is a RECORD object, cobus.proto.nmt.NmtCommand the
#: command itself and cobus.proto.emcy.Emergency the emergency (:attr:`EmergencyRecord.emergency`).
__getattr__ = renamed_names(
    __name__,
    {
        "Record": ("TraceRecord", TraceRecord),
        "NmtCommand": ("NmtCommandRecord", NmtCommandRecord),
        "Emergency": ("EmergencyRecord", EmergencyRecord),
    },
)
