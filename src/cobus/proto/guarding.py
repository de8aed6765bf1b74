"""Node guarding and life guarding (CiA 301 error control).

The guarding master sends a remote frame on ``700h+id`` every guard time; the node answers
``700h+id [1] t|state``: bits 0-6 the NMT state, bit 7 a toggle that is 0 in the first reply
and alternates with each reply. The master declares the node lost when no valid reply came
within the life time (guard time x life time factor).

The node watches the master too (life guarding): with guard time 100Ch (ms) and life time
factor 100Dh both non-zero, the first remote request arms a timer of guard time x factor that
each further request restarts; expiry is reported as :class:`LifeGuardingExpired` (the device
then sends EMCY 8130h and enters pre-operational).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from cobus.errors import CobusError
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.connection_set import ERROR_CONTROL_BASE as _BASE
from cobus.proto.frame import Frame
from cobus.proto.heartbeat import BootupReceived
from cobus.proto.nmt import NmtState

__all__ = [
    "BootupReceived",
    "GuardingConfigError",
    "GuardingMaster",
    "GuardingNodeLost",
    "GuardingResponder",
    "GuardingResumed",
    "GuardingStateChanged",
    "GuardingTimeout",
    "GuardingToggleError",
    "LifeGuardingExpired",
    "LifeGuardingResumed",
    "MalformedGuardingReply",
]

_TOGGLE = 0x80
_STATES: dict[int, NmtState] = {int(s): s for s in NmtState}


class GuardingConfigError(CobusError, ValueError):
    """A node guarding or life guarding setting out of its range."""


@dataclass(frozen=True, slots=True)
class GuardingTimeout(Event):
    """No reply from ``node_id`` to the last remote request within the guard time."""

    node_id: int


@dataclass(frozen=True, slots=True)
class GuardingToggleError(Event):
    """A reply of ``node_id`` carried toggle ``received`` where ``expected`` was due.

    The reply is discarded; the master expects the opposite of ``received`` next."""

    node_id: int
    expected: int
    received: int


@dataclass(frozen=True, slots=True)
class GuardingStateChanged(Event):
    """``node_id`` reports a state other than the last one (``old`` None: first reply)."""

    node_id: int
    old: NmtState | None
    new: NmtState


@dataclass(frozen=True, slots=True)
class GuardingNodeLost(Event):
    """No valid reply from ``node_id`` within the life time (reported once per loss)."""

    node_id: int


@dataclass(frozen=True, slots=True)
class GuardingResumed(Event):
    """A valid reply from ``node_id`` after :class:`GuardingNodeLost`."""

    node_id: int
    state: NmtState


@dataclass(frozen=True, slots=True)
class MalformedGuardingReply(Event):
    """A data frame on 700h+``node_id`` that is no guarding reply; it is discarded."""

    node_id: int
    data: bytes
    reason: str


@dataclass(frozen=True, slots=True)
class LifeGuardingExpired(Event):
    """No remote request from the master within the life time (reported once per loss)."""

    node_id: int


@dataclass(frozen=True, slots=True)
class LifeGuardingResumed(Event):
    """Remote requests from the master arrive again after :class:`LifeGuardingExpired`."""

    node_id: int


def _check_node(node_id: int) -> int:
    if not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise GuardingConfigError(f"node-ID {node_id!r} is out of range: use 1..127")
    return node_id


def _check_guard_time(ms: int, low: int) -> int:
    if not isinstance(ms, int) or not low <= ms <= 0xFFFF:
        raise GuardingConfigError(
            f"guard time (100Ch) {ms!r} ms is out of range: use {low}..65535 ms"
        )
    return ms


def _check_factor(factor: int, low: int) -> int:
    if not isinstance(factor, int) or not low <= factor <= 0xFF:
        raise GuardingConfigError(
            f"life time factor (100Dh) {factor!r} is out of range: use {low}..255"
        )
    return factor


class GuardingMaster:
    """The master side of node guarding for one node.

    Call :meth:`start` to send the first remote request; then every guard time
    :meth:`on_timer` sends the next one, after reporting :class:`GuardingTimeout` if the
    previous request went unanswered. Replies are checked for their toggle and state.
    """

    __slots__ = (
        "_awaiting",
        "_expected",
        "_guard",
        "_life",
        "_lost",
        "_lost_at",
        "_next_rtr",
        "_request",
        "_state",
        "cob_id",
        "guard_time_ms",
        "life_time_factor",
        "node_id",
    )

    def __init__(self, node_id: int, guard_time_ms: int, life_time_factor: int) -> None:
        self.node_id = _check_node(node_id)
        self.guard_time_ms = _check_guard_time(guard_time_ms, 1)
        self.life_time_factor = _check_factor(life_time_factor, 1)
        self._guard = guard_time_ms / 1000.0
        self._life = self._guard * life_time_factor
        self.cob_id = _BASE + node_id
        self._request = Out((Frame(self.cob_id, rtr=True),), ())
        self._next_rtr: float | None = None
        self._lost_at: float | None = None
        self._awaiting = False
        self._lost = False
        self._expected = 0
        self._state: NmtState | None = None

    @property
    def state(self) -> NmtState | None:
        """The state of the last valid reply (None: no reply yet)."""
        return self._state

    @property
    def lost(self) -> bool:
        """Whether the node's guarding replies stopped (life time elapsed)."""
        return self._lost

    @property
    def next_toggle(self) -> int:
        """The toggle bit (0 or 1) the node's next reply must carry."""
        return self._expected >> 7

    def carry_on(self, state: NmtState | None, toggle: int) -> None:
        """Go on where another master object of the node stopped (new guard times): the
        state its last reply gave and the toggle bit the next one carries, so that the
        first reply is neither a toggle error nor reported as a new state."""
        if toggle not in (0, 1):
            raise GuardingConfigError(f"toggle bit {toggle!r}: 0 or 1")
        self._state = state
        self._expected = toggle << 7

    @property
    def running(self) -> bool:
        """Whether guarding requests are being sent."""
        return self._next_rtr is not None

    @property
    def deadline(self) -> float | None:
        nxt = self._next_rtr
        lost_at = self._lost_at
        if nxt is None or lost_at is None or self._lost:
            return nxt
        return lost_at if lost_at < nxt else nxt

    def start(self, now: float) -> Out:
        """Start guarding: send the first remote request; the life time counts from now."""
        self._next_rtr = now + self._guard
        self._lost_at = now + self._life
        self._awaiting = True
        self._lost = False
        self._expected = 0
        return self._request

    def stop(self) -> None:
        """Stop guarding (no more requests, no more timeouts)."""
        self._next_rtr = None
        self._lost_at = None
        self._awaiting = False

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.cob_id != self.cob_id or frame.rtr or frame.extended:
            return NOTHING
        data = frame.data
        if len(data) != 1:
            reason = f"guarding reply with {len(data)} data bytes; it must carry exactly 1"
            return Out((), (MalformedGuardingReply(self.node_id, data, reason),))
        byte = data[0]
        if byte == 0:
            # boot-up message: the node restarted, its toggle starts at 0 again
            self._expected = 0
            return Out((), self._new_state(NmtState.INITIALISING, [BootupReceived(self.node_id)]))
        state = _STATES.get(byte & 0x7F)
        if state is None or state is NmtState.INITIALISING:
            reason = f"guarding reply state 0x{byte & 0x7F:02X} is no NMT state (04h, 05h, 7Fh)"
            return Out((), (MalformedGuardingReply(self.node_id, data, reason),))
        toggle = byte & _TOGGLE
        expected = self._expected
        if toggle != expected:
            self._expected = toggle ^ _TOGGLE
            self._awaiting = False
            error = GuardingToggleError(self.node_id, expected >> 7, toggle >> 7)
            return Out((), (error,))
        self._expected = toggle ^ _TOGGLE
        self._awaiting = False
        if self._next_rtr is not None:
            self._lost_at = now + self._life
        if state is self._state and not self._lost:
            return NOTHING
        events: list[Event] = []
        if self._lost:
            self._lost = False
            events.append(GuardingResumed(self.node_id, state))
        return Out((), self._new_state(state, events))

    def _new_state(self, state: NmtState, events: list[Event]) -> tuple[Event, ...]:
        old = self._state
        if old is not state:
            self._state = state
            events.insert(0, GuardingStateChanged(self.node_id, old, state))
        return tuple(events)

    def on_timer(self, now: float) -> Out:
        nxt = self._next_rtr
        if nxt is None:
            return NOTHING
        events: list[Event] = []
        due = now >= nxt
        if due and self._awaiting and not self._lost:
            events.append(GuardingTimeout(self.node_id))
        lost_at = self._lost_at
        if not self._lost and lost_at is not None and now >= lost_at:
            self._lost = True
            events.append(GuardingNodeLost(self.node_id))
        if not due:
            return Out((), tuple(events)) if events else NOTHING
        nxt += self._guard
        self._next_rtr = nxt if nxt > now else now + self._guard
        self._awaiting = True
        if not events:
            return self._request
        return Out(self._request.frames, tuple(events))


class GuardingResponder:
    """The node side: answers remote requests on 700h+id and watches the master's life time.

    ``state_getter`` gives the current NMT state (e.g. ``lambda: slave.state``); a node still
    initialising does not answer.
    """

    __slots__ = (
        "_expiry",
        "_getter",
        "_life",
        "_lost",
        "_outs",
        "_toggle",
        "cob_id",
        "guard_time_ms",
        "life_time_factor",
        "node_id",
    )

    def __init__(self, node_id: int, state_getter: Callable[[], NmtState]) -> None:
        self.node_id = _check_node(node_id)
        self.cob_id = _BASE + node_id
        self._getter = state_getter
        self._toggle = 0
        self.guard_time_ms = 0
        self.life_time_factor = 0
        self._life = 0.0
        self._expiry: float | None = None
        self._lost = False
        cob_id = self.cob_id
        self._outs: tuple[dict[int, Out], dict[int, Out]] = (
            {s: Out((Frame(cob_id, bytes((s,))),), ()) for s in _STATES if s},
            {s: Out((Frame(cob_id, bytes((s | _TOGGLE,))),), ()) for s in _STATES if s},
        )

    @property
    def toggle(self) -> int:
        """The toggle bit (0 or 1) of the next reply."""
        return self._toggle

    @property
    def life_time(self) -> float:
        """Guard time x life time factor in seconds (0: life guarding off)."""
        return self._life

    @property
    def deadline(self) -> float | None:
        return self._expiry

    def set_guard_time(self, ms: int, now: float) -> None:
        """Write 100Ch (ms)."""
        self.guard_time_ms = _check_guard_time(ms, 0)
        self._configure(now)

    def set_life_time_factor(self, factor: int, now: float) -> None:
        """Write 100Dh."""
        self.life_time_factor = _check_factor(factor, 0)
        self._configure(now)

    def _configure(self, now: float) -> None:
        self._life = self.guard_time_ms * self.life_time_factor / 1000.0
        if not self._life:
            self._expiry = None
            self._lost = False
        elif self._expiry is not None:
            self._expiry = now + self._life

    def reset(self) -> None:
        """Reset communication: the toggle starts at 0 and life guarding waits for the
        first remote request again."""
        self._toggle = 0
        self._expiry = None
        self._lost = False

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.cob_id != self.cob_id or not frame.rtr or frame.extended:
            return NOTHING
        state = self._getter()
        out = self._outs[self._toggle].get(state)
        if out is None:
            if state == NmtState.INITIALISING:
                return NOTHING
            raise GuardingConfigError(
                f"node {self.node_id}: the state source returned {state!r}, not an NmtState"
            )
        self._toggle ^= 1
        if self._life:
            self._expiry = now + self._life
            if self._lost:
                self._lost = False
                return Out(out.frames, (LifeGuardingResumed(self.node_id),))
        return out

    def on_timer(self, now: float) -> Out:
        expiry = self._expiry
        if expiry is None or now < expiry:
            return NOTHING
        self._expiry = None
        self._lost = True
        return Out((), (LifeGuardingExpired(self.node_id),))
