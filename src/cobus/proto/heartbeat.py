"""Heartbeat producer and consumers (CiA 301 error control).

A producer sends ``700h+id [1] state`` every 1017h ms. A consumer watches other nodes'
heartbeats with the times of 1016h (sub n: node-ID in bits 16-23, time in ms in bits 0-15).
Supervision of a node starts with the first heartbeat received from it; a boot-up message
(state 00) stops it again until the node sends its next heartbeat, because a freshly booted
node may not produce heartbeats before it is configured.

:class:`HeartbeatMonitor` is the master-side consumer: any number of nodes, a time in seconds
per node, state tracking of every node it hears. :class:`HeartbeatConsumer` is the 1016h view
of the same machine for a device.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

from cobus.errors import CobusError
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.connection_set import ERROR_CONTROL_BASE as _BASE
from cobus.proto.frame import Frame
from cobus.proto.nmt import NmtState

__all__ = [
    "BootupReceived",
    "ConsumerEntry",
    "HeartbeatConfigError",
    "HeartbeatConsumer",
    "HeartbeatMonitor",
    "HeartbeatProducer",
    "HeartbeatResumed",
    "HeartbeatTimeout",
    "MalformedHeartbeat",
    "RemoteStateChanged",
    "decode_consumer_entry",
    "encode_consumer_entry",
    "heartbeat_frame",
]

_STATES: dict[int, NmtState] = {int(s): s for s in NmtState}
# A global, asked for every heartbeat: an Enum class attribute costs ~0.5 us in Python 3.11.
_INITIALISING = NmtState.INITIALISING


class HeartbeatConfigError(CobusError, ValueError):
    """A heartbeat producer or consumer setting that CiA 301 does not allow."""


@dataclass(frozen=True, slots=True)
class HeartbeatTimeout(Event):
    """No heartbeat from ``node_id`` within its consumer time (reported once per loss)."""

    node_id: int

    def __str__(self) -> str:
        return f"node {self.node_id}: heartbeat lost"


@dataclass(frozen=True, slots=True)
class HeartbeatResumed(Event):
    """A heartbeat from ``node_id`` arrived again after a :class:`HeartbeatTimeout`."""

    node_id: int
    state: NmtState

    def __str__(self) -> str:
        return f"node {self.node_id}: heartbeat back, state {self.state.name}"


@dataclass(frozen=True, slots=True)
class BootupReceived(Event):
    """``node_id`` sent its boot-up message (it was powered on or reset).

    A boot-up ends a loss without :class:`HeartbeatResumed` and stops supervision of the node
    until its next heartbeat."""

    node_id: int

    def __str__(self) -> str:
        return f"node {self.node_id}: boot-up"


@dataclass(frozen=True, slots=True)
class RemoteStateChanged(Event):
    """``node_id`` reports a state other than the last one heard (``old`` None: first heard)."""

    node_id: int
    old: NmtState | None
    new: NmtState

    def __str__(self) -> str:
        old = "unknown" if self.old is None else self.old.name
        return f"node {self.node_id}: {old} -> {self.new.name}"


@dataclass(frozen=True, slots=True)
class MalformedHeartbeat(Event):
    """A frame on 700h+``node_id`` that is no heartbeat; it does not count as one."""

    node_id: int
    data: bytes
    reason: str

    def __str__(self) -> str:
        return f"node {self.node_id}: malformed heartbeat {self.data.hex(' ')}: {self.reason}"


class ConsumerEntry(NamedTuple):
    """One 1016h entry: which node is watched and its consumer time in ms (0 = not used)."""

    node_id: int
    time_ms: int


def _check_node(node_id: int) -> int:
    if not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise HeartbeatConfigError(f"node-ID {node_id!r} is out of range: use 1..127")
    return node_id


def _check_ms(ms: int, what: str) -> int:
    if not isinstance(ms, int) or not 0 <= ms <= 0xFFFF:
        raise HeartbeatConfigError(f"{what} {ms!r} ms is out of range: use 0 (off) to 65535 ms")
    return ms


def decode_consumer_entry(value: int) -> ConsumerEntry:
    """Split a 1016h sub-index value into node-ID (bits 16-23) and time in ms (bits 0-15)."""
    if not isinstance(value, int) or not 0 <= value <= 0xFFFFFFFF:
        raise HeartbeatConfigError(f"1016h entry {value!r} is not an UNSIGNED32")
    if value >> 24:
        raise HeartbeatConfigError(
            f"1016h entry 0x{value:08X} sets reserved bits 24-31; they must be 0"
        )
    return ConsumerEntry((value >> 16) & 0xFF, value & 0xFFFF)


def encode_consumer_entry(node_id: int, time_ms: int) -> int:
    """The 1016h sub-index value watching ``node_id`` (0 = unused) with ``time_ms``."""
    if node_id != 0:
        _check_node(node_id)
    _check_ms(time_ms, "heartbeat consumer time")
    return (node_id << 16) | time_ms


def heartbeat_frame(node_id: int, state: NmtState | int) -> Frame:
    """The heartbeat ``700h+id [1] state`` of ``node_id``."""
    _check_node(node_id)
    if state not in _STATES:
        raise HeartbeatConfigError(
            f"state {state!r} is not an NMT state code (00h, 04h, 05h or 7Fh)"
        )
    return Frame(_BASE + node_id, bytes((int(state),)))


class HeartbeatProducer:
    """Sends the node's heartbeat every ``period`` (1017h, ms; 0 = off).

    The state sent comes from ``state_getter`` when one is given (e.g. ``lambda: slave.state``),
    otherwise from the settable :attr:`state`.
    """

    __slots__ = ("_deadline", "_frames", "_getter", "_period", "node_id", "period_ms", "state")

    def __init__(
        self,
        node_id: int,
        *,
        state: NmtState = NmtState.PRE_OPERATIONAL,
        state_getter: Callable[[], NmtState] | None = None,
    ) -> None:
        self.node_id = _check_node(node_id)
        self.state = state
        self._getter = state_getter
        self.period_ms = 0
        self._period = 0.0
        self._deadline: float | None = None
        self._frames = {s: Frame(_BASE + node_id, bytes((s,))) for s in _STATES}

    @property
    def deadline(self) -> float | None:
        return self._deadline

    def set_period(self, ms: int, now: float) -> None:
        """Write 1017h: the first heartbeat goes out ``ms`` after ``now``; 0 stops."""
        self.period_ms = _check_ms(ms, "heartbeat producer time")
        self._period = ms / 1000.0
        self._deadline = now + self._period if ms else None

    def restart(self, now: float) -> None:
        """Count the period from ``now`` again (after the boot-up message, say)."""
        if self.period_ms:
            self._deadline = now + self._period

    def on_frame(self, frame: Frame, now: float) -> Out:
        return NOTHING

    def on_timer(self, now: float) -> Out:
        deadline = self._deadline
        if deadline is None or now < deadline:
            return NOTHING
        deadline += self._period
        # after a stall, skip the missed beats instead of sending a burst
        self._deadline = deadline if deadline > now else now + self._period
        state = self._getter() if self._getter is not None else self.state
        frame = self._frames.get(state)
        if frame is None:
            raise HeartbeatConfigError(
                f"node {self.node_id}: the state source returned {state!r}, not an NmtState"
            )
        return Out((frame,), ())


class _Watch:
    __slots__ = ("expiry", "lost", "state", "timeout")

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.expiry: float | None = None
        self.lost = False
        self.state: NmtState | None = None


class HeartbeatMonitor:
    """Watches the heartbeats of many nodes, each with its own time in seconds.

    ``track_all`` (the default) makes it follow the state of every node it hears, watched or
    not; otherwise frames from unwatched nodes are ignored.
    """

    __slots__ = ("_deadline", "_nodes", "_track_all")

    def __init__(self, *, track_all: bool = True) -> None:
        self._nodes: dict[int, _Watch] = {}
        self._track_all = track_all
        self._deadline: float | None = None

    @property
    def deadline(self) -> float | None:
        # may be early after a heartbeat moved the first expiry later: on_timer recomputes
        return self._deadline

    def watch(self, node_id: int, timeout: float, now: float) -> None:
        """Supervise ``node_id`` with ``timeout`` seconds (0 = only track its state).

        A node already supervised is re-armed from ``now`` with the new time; otherwise
        supervision starts with its next heartbeat.
        """
        _check_node(node_id)
        if not timeout >= 0:
            raise HeartbeatConfigError(f"heartbeat timeout {timeout!r} s must be >= 0")
        w = self._nodes.get(node_id)
        if w is None:
            w = self._nodes[node_id] = _Watch(timeout)
        w.timeout = timeout
        if w.expiry is not None:
            if timeout:
                w.expiry = now + timeout
                if self._deadline is None or w.expiry < self._deadline:
                    self._deadline = w.expiry
            else:
                w.expiry = None

    def forget(self, node_id: int) -> None:
        """Stop supervising and tracking ``node_id``."""
        self._nodes.pop(node_id, None)

    def state(self, node_id: int) -> NmtState | None:
        """The last state heard from ``node_id`` (None: never heard)."""
        w = self._nodes.get(node_id)
        return None if w is None else w.state

    def is_lost(self, node_id: int) -> bool:
        """Whether ``node_id`` timed out and has not been heard since."""
        w = self._nodes.get(node_id)
        return w is not None and w.lost

    def timeout(self, node_id: int) -> float:
        """The supervision time of ``node_id`` in seconds (0: not supervised)."""
        w = self._nodes.get(node_id)
        return 0.0 if w is None else w.timeout

    def on_frame(self, frame: Frame, now: float) -> Out:
        node_id = frame.cob_id - _BASE
        if not 0 < node_id < 128 or frame.rtr or frame.extended:
            return NOTHING
        w = self._nodes.get(node_id)
        if w is None:
            if not self._track_all:
                return NOTHING
            w = self._nodes[node_id] = _Watch(0.0)
        data = frame.data
        state = _STATES.get(data[0]) if len(data) == 1 else None
        if state is None:
            return Out((), (MalformedHeartbeat(node_id, data, _reason(data)),))
        old = w.state
        if state is old and not w.lost and state is not _INITIALISING:
            if w.timeout:
                expiry = w.expiry = now + w.timeout
                if self._deadline is None or expiry < self._deadline:
                    self._deadline = expiry
            return NOTHING
        events: list[Event] = []
        if state is _INITIALISING:
            # boot-up: the node starts over; supervise again from its next heartbeat
            w.lost = False
            w.expiry = None
            if old is not state:
                events.append(RemoteStateChanged(node_id, old, state))
            events.append(BootupReceived(node_id))
        else:
            if w.lost:
                w.lost = False
                events.append(HeartbeatResumed(node_id, state))
            if old is not state:
                events.append(RemoteStateChanged(node_id, old, state))
            if w.timeout:
                w.expiry = now + w.timeout
                if self._deadline is None or w.expiry < self._deadline:
                    self._deadline = w.expiry
        w.state = state
        return Out((), tuple(events))

    def on_timer(self, now: float) -> Out:
        events: list[Event] = []
        first: float | None = None
        for node_id, w in self._nodes.items():
            expiry = w.expiry
            if expiry is None:
                continue
            if expiry <= now:
                w.expiry = None
                w.lost = True
                events.append(HeartbeatTimeout(node_id))
            elif first is None or expiry < first:
                first = expiry
        self._deadline = first
        return Out((), tuple(events)) if events else NOTHING


def _reason(data: bytes) -> str:
    if len(data) != 1:
        return f"heartbeat with {len(data)} data bytes; it must carry exactly 1"
    return f"heartbeat state 0x{data[0]:02X} is no NMT state (00h, 04h, 05h, 7Fh)"


class HeartbeatConsumer(HeartbeatMonitor):
    """The heartbeat consumer of a device, configured through 1016h entries (ms).

    Only the nodes of non-zero entries are watched; frames from other nodes are ignored.
    """

    __slots__ = ("_entries",)

    def __init__(self, entries: int = 127) -> None:
        super().__init__(track_all=False)
        if not isinstance(entries, int) or not 1 <= entries <= 127:
            raise HeartbeatConfigError(f"1016h can hold 1..127 entries, not {entries!r}")
        self._entries = [0] * entries

    @property
    def size(self) -> int:
        """1016h sub 0: the number of entries."""
        return len(self._entries)

    def entry(self, sub: int) -> int:
        """The value of 1016h sub ``sub``."""
        self._check_sub(sub)
        return self._entries[sub - 1]

    def set_entry(self, sub: int, value: int, now: float) -> None:
        """Write 1016h sub ``sub``; a node-ID of 0 or a time of 0 leaves the entry unused."""
        self._check_sub(sub)
        node_id, ms = decode_consumer_entry(value)
        if node_id > 127:
            raise HeartbeatConfigError(
                f"1016h sub {sub}: node-ID {node_id} in 0x{value:08X} is outside 1..127"
            )
        if node_id and ms:
            for other, existing in enumerate(self._entries, start=1):
                o_node, o_ms = (existing >> 16) & 0xFF, existing & 0xFFFF
                if other != sub and o_node == node_id and o_ms:
                    raise HeartbeatConfigError(
                        f"1016h sub {sub} would watch node {node_id} a second time (sub "
                        f"{other} already does); clear one entry first (CiA 301: 06040043)"
                    )
        old_node = (self._entries[sub - 1] >> 16) & 0xFF
        self._entries[sub - 1] = value
        if old_node and old_node != node_id and not self._watched_by_entry(old_node):
            self.forget(old_node)
        if node_id and ms:
            self.watch(node_id, ms / 1000.0, now)
        elif node_id and not self._watched_by_entry(node_id):
            self.forget(node_id)

    def _watched_by_entry(self, node_id: int) -> bool:
        return any((e >> 16) & 0xFF == node_id and e & 0xFFFF for e in self._entries)

    def _check_sub(self, sub: int) -> None:
        if not isinstance(sub, int) or not 1 <= sub <= len(self._entries):
            raise HeartbeatConfigError(
                f"1016h has sub-indexes 1..{len(self._entries)}, not {sub!r}"
            )
