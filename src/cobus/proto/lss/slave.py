"""The LSS slave (CiA 305): how a device is found, named and given a node-ID and a bit rate.

A slave is in the *waiting* state until a master switches it (all slaves at once, one by its
identity, or the one a fastscan singles out) into *configuration*; only then does it take a
node-ID, a bit timing, a store request or an inquiry. A device without a node-ID
(:data:`UNCONFIGURED`, FFh) takes part in LSS only, and in fastscan; once a node-ID is
configured and the master switches it back to waiting, it reports
:class:`NodeIdAssigned`: the device resets its communication and boots under the new ID.

``store`` makes :meth:`LssSlave.on_frame` persist the pending node-ID and bit timing: it is
called with both and returns 0 (stored), 1 (storing not supported) or 2 (storage media access
error); without it the answer says "not supported". ``answer_delay`` holds every answer back
for slow masters (on :meth:`LssSlave.on_timer`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from cobus._enum import NamedIntEnum
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.frame import Frame
from cobus.proto.lss import _wire as w
from cobus.proto.lss._wire import (
    AUTO_BIT_RATE,
    BIT_RATES,
    UNCONFIGURED,
    LssError,
    LssIdentity,
)

__all__ = [
    "BitTimingActivated",
    "BitTimingConfigured",
    "ConfigurationStored",
    "LssSlave",
    "LssState",
    "LssStateSwitched",
    "NodeIdAssigned",
    "NodeIdConfigured",
    "StoreFailed",
]

#: What ``store`` may answer: stored, storing not supported, storage media access error.
STORED, STORE_UNSUPPORTED, STORE_MEDIA_ERROR = 0, 1, 2


class LssState(NamedIntEnum):
    """The LSS state of a slave."""

    WAITING = 0
    CONFIGURATION = 1


@dataclass(frozen=True, slots=True)
class LssStateSwitched(Event):
    """The slave entered ``state`` (``how``: global, selective or fastscan)."""

    state: LssState
    how: str


@dataclass(frozen=True, slots=True)
class NodeIdConfigured(Event):
    """A master configured ``node_id`` (pending: it takes effect at the next reset of the
    communication, or at once by :class:`NodeIdAssigned` for a device that had none)."""

    node_id: int


@dataclass(frozen=True, slots=True)
class NodeIdAssigned(Event):
    """An unconfigured device got ``node_id`` and was switched back to waiting: reset the
    communication now and boot under it (CiA 305)."""

    node_id: int


@dataclass(frozen=True, slots=True)
class BitTimingConfigured(Event):
    """A master configured bit timing ``index`` of table 0 (``kbits``; None: automatic)."""

    index: int
    kbits: int | None


@dataclass(frozen=True, slots=True)
class BitTimingActivated(Event):
    """Switch to the configured bit timing: send nothing for ``delay`` seconds, switch, wait
    ``delay`` again before sending (CiA 305's switch delay)."""

    delay: float
    index: int


@dataclass(frozen=True, slots=True)
class ConfigurationStored(Event):
    """The pending node-ID and bit timing were stored (the answer said so)."""

    node_id: int
    bit_timing: int | None


@dataclass(frozen=True, slots=True)
class StoreFailed(Event):
    """A store request failed: ``error`` 1 not supported, 2 media access error."""

    error: int
    reason: str


class LssSlave:
    """The LSS slave of one device (sans-I/O: frames on 7E5h in, answers on 7E4h out)."""

    def __init__(
        self,
        identity: LssIdentity,
        node_id: int = UNCONFIGURED,
        *,
        bit_rates: frozenset[int] | set[int] | None = None,
        store: Callable[[int, int | None], int | bool | None] | None = None,
        answer_delay: float = 0.0,
    ) -> None:
        if not isinstance(identity, LssIdentity):
            raise LssError(f"identity {identity!r}: give an LssIdentity(vendor, product, ...)")
        self.identity = identity
        w.check_node_id(node_id)
        self.active_node_id = node_id
        self.pending_node_id = node_id
        #: The table-0 indices this device can run at (default: every rate of the table).
        self.bit_rates = frozenset(BIT_RATES) if bit_rates is None else frozenset(bit_rates)
        if not self.bit_rates <= set(BIT_RATES) | {AUTO_BIT_RATE}:
            raise LssError(
                f"bit_rates {sorted(self.bit_rates)}: give indices of CiA 305's table "
                "(0-4, 6-8; 9 automatic), e.g. bit_timing_index(250)"
            )
        self.pending_bit_timing: int | None = None
        self.state = LssState.WAITING
        self.store = store
        if not isinstance(answer_delay, int | float) or not 0 <= answer_delay < 10:
            raise LssError(f"answer_delay {answer_delay!r}: give seconds, 0 to 10")
        self.answer_delay = float(answer_delay)
        self._selective: list[int] = []
        self._ranges: list[int] = []
        self._position = 0  # fastscan: the field this slave is at (LSSSub)
        self._held: list[tuple[float, Frame]] = []  # answers held back by answer_delay

    # ---------------------------------------------------------------- the machine

    @property
    def configured(self) -> bool:
        """Whether the device has a node-ID (then it takes no part in fastscan)."""
        return not (self.active_node_id == UNCONFIGURED and self.pending_node_id == UNCONFIGURED)

    @property
    def deadline(self) -> float | None:
        return self._held[0][0] if self._held else None

    def on_timer(self, now: float) -> Out:
        due = [f for t, f in self._held if t <= now]
        self._held = [(t, f) for t, f in self._held if t > now]
        return Out(tuple(due)) if due else NOTHING

    def node_id_active(self) -> None:
        """The communication was reset: the pending node-ID is now the active one."""
        self.active_node_id = self.pending_node_id

    def on_frame(self, frame: Frame, now: float) -> Out:
        data = frame.data
        if frame.cob_id != w.MASTER or frame.rtr or len(data) != 8:
            return NOTHING  # CiA 305: 8 bytes, always
        cs = data[0]
        if cs == w.SWITCH_GLOBAL:
            return self._switch_global(data[1])
        if cs in w.IDENTIFY_REMOTE:
            return self._identify_remote(cs, w.read_u32(data), now)
        if cs == w.IDENTIFY_UNCONFIGURED:
            return self._send(now, w.UNCONFIGURED_IDENTIFIED) if not self.configured else NOTHING
        if self.state is LssState.WAITING:
            if cs in w.SWITCH_SELECTIVE:
                return self._switch_selective(cs, w.read_u32(data), now)
            if cs == w.FASTSCAN:
                return self._fastscan(data, now)
            return NOTHING
        return self._configure(cs, data, now)

    # ---------------------------------------------------------------- services

    def _send(self, now: float, cs: int, body: bytes = b"", events: tuple[Event, ...] = ()) -> Out:
        reply = w.answer(cs, body)
        if self.answer_delay:
            self._held.append((now + self.answer_delay, reply))
            return Out((), events)
        return Out((reply,), events)

    def _switch_global(self, mode: int) -> Out:
        if mode == LssState.CONFIGURATION:
            self.state = LssState.CONFIGURATION
            return Out((), (LssStateSwitched(LssState.CONFIGURATION, "global"),))
        if mode != LssState.WAITING:
            return NOTHING
        was = self.state
        self.state = LssState.WAITING
        self._selective.clear()
        events: list[Event] = []
        if was is LssState.CONFIGURATION:
            events.append(LssStateSwitched(LssState.WAITING, "global"))
            if self.active_node_id == UNCONFIGURED and self.pending_node_id != UNCONFIGURED:
                self.active_node_id = self.pending_node_id
                events.append(NodeIdAssigned(self.pending_node_id))
        return Out((), tuple(events))

    def _switch_selective(self, cs: int, value: int, now: float) -> Out:
        step = cs - w.SWITCH_SELECTIVE[0]
        if step == 0:
            self._selective = [value]
        elif len(self._selective) == step:
            self._selective.append(value)
        else:
            self._selective.clear()  # out of order: start again at the vendor
            return NOTHING
        if step < 3:
            return NOTHING
        asked, self._selective = tuple(self._selective), []
        if asked != self.identity.fields:
            return NOTHING
        self.state = LssState.CONFIGURATION
        return self._send(
            now, w.SELECTED, events=(LssStateSwitched(LssState.CONFIGURATION, "selective"),)
        )

    def _identify_remote(self, cs: int, value: int, now: float) -> Out:
        step = cs - w.IDENTIFY_REMOTE[0]
        if step == 0:
            self._ranges = [value]
        elif len(self._ranges) == step:
            self._ranges.append(value)
        else:
            self._ranges.clear()
            return NOTHING
        if step < 5:
            return NOTHING
        vendor, product, rev_low, rev_high, serial_low, serial_high = self._ranges
        self._ranges = []
        me = self.identity
        inside = (
            me.vendor == vendor
            and me.product == product
            and rev_low <= me.revision <= rev_high
            and serial_low <= me.serial <= serial_high
        )
        return self._send(now, w.IDENTIFIED) if inside else NOTHING

    def _fastscan(self, data: bytes, now: float) -> Out:
        if self.configured:
            return NOTHING  # fastscan finds devices without a node-ID only
        number, bit, sub, following = w.read_u32(data), data[5], data[6], data[7]
        if bit == w.FASTSCAN_RESET:
            self._position = 0
            return self._send(now, w.IDENTIFIED)
        if bit > 31 or sub > 3 or following > 3 or sub != self._position:
            return NOTHING
        mask = (0xFFFF_FFFF << bit) & 0xFFFF_FFFF
        if (self.identity.fields[sub] ^ number) & mask:
            return NOTHING
        self._position = following
        events: tuple[Event, ...] = ()
        if bit == 0 and following < sub:  # the whole identity matched: this slave, and only it
            self.state = LssState.CONFIGURATION
            events = (LssStateSwitched(LssState.CONFIGURATION, "fastscan"),)
        return self._send(now, w.IDENTIFIED, events=events)

    def _configure(self, cs: int, data: bytes, now: float) -> Out:
        if cs == w.CONFIGURE_NODE_ID:
            node_id = data[1]
            if node_id == 0 or (node_id > 127 and node_id != UNCONFIGURED):
                return self._send(now, cs, b"\x01")  # node-ID out of range
            self.pending_node_id = node_id
            return self._send(now, cs, b"\x00", (NodeIdConfigured(node_id),))
        if cs == w.CONFIGURE_BIT_TIMING:
            table, index = data[1], data[2]
            if table != 0 or not (index in self.bit_rates or index == AUTO_BIT_RATE):
                return self._send(now, cs, b"\x01")  # bit timing not supported
            if index == AUTO_BIT_RATE and AUTO_BIT_RATE not in self.bit_rates:
                return self._send(now, cs, b"\x01")
            self.pending_bit_timing = index
            event = BitTimingConfigured(index, BIT_RATES.get(index))
            return self._send(now, cs, b"\x00", (event,))
        if cs == w.ACTIVATE_BIT_TIMING:
            if self.pending_bit_timing is None:
                return NOTHING  # nothing configured: nothing to switch to
            delay = int.from_bytes(data[1:3], "little") / 1000
            return Out((), (BitTimingActivated(delay, self.pending_bit_timing),))
        if cs == w.STORE:
            return self._store(now)
        if cs in w.INQUIRE:
            value = self.identity.fields[cs - w.INQUIRE[0]]
            return self._send(now, cs, w.le32(value))
        if cs == w.INQUIRE_NODE_ID:
            return self._send(now, cs, bytes((self.active_node_id,)))
        if cs in w.SWITCH_SELECTIVE or cs == w.FASTSCAN:
            return NOTHING  # already in configuration
        return NOTHING

    def _store(self, now: float) -> Out:
        if self.store is None:
            return self._send(
                now, w.STORE, b"\x01", (StoreFailed(STORE_UNSUPPORTED, "not supported"),)
            )
        try:
            said = self.store(self.pending_node_id, self.pending_bit_timing)
        except Exception as exc:  # a storage failure is the media's, not the protocol's
            code, reason = STORE_MEDIA_ERROR, f"{type(exc).__name__}: {exc}"
        else:
            code, reason = _store_answer(said)
        if code == STORED:
            event: Event = ConfigurationStored(self.pending_node_id, self.pending_bit_timing)
            return self._send(now, w.STORE, b"\x00", (event,))
        return self._send(now, w.STORE, bytes((code,)), (StoreFailed(code, reason),))


def _store_answer(said: object) -> tuple[int, str]:
    """What ``store`` returned as (error code, reason): 0, None or True stored; 1 not
    supported; 2 or False a media access error; anything else is a media error too."""
    if said is None or said is True or (type(said) is int and said == STORED):
        return STORED, "stored"
    if type(said) is int and said == STORE_UNSUPPORTED:
        return STORE_UNSUPPORTED, "not supported"
    if said is False or (type(said) is int and said == STORE_MEDIA_ERROR):
        return STORE_MEDIA_ERROR, "media access error"
    return STORE_MEDIA_ERROR, f"store returned {said!r}, not 0, 1 or 2"
