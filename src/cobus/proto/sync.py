"""SYNC producer and consumer (CiA 301).

Objects: 1005h COB-ID (bit 30 = this node generates SYNC, bit 29 = 29-bit identifier),
1006h communication cycle period (µs), 1007h synchronous window length (µs), 1019h counter
overflow value (0 = SYNC without data; 2..240 = one data byte counting 1..overflow).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from cobus._moved import renamed_names
from cobus.errors import CobusError
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto._cobid import split_cob_id
from cobus.proto.connection_set import SYNC_COB_ID
from cobus.proto.frame import Frame

__all__ = [
    "SYNC_COB_ID",
    "SyncCobId",
    "SyncConfigError",
    "SyncConsumer",
    "SyncProducer",
    "SyncReceived",
    "SyncResumed",
    "SyncTimedOut",
    "UnexpectedSyncLength",
    "check_overflow",
]

_GENERATE = 1 << 30
_EXTENDED = 1 << 29
_MAX_US = 0xFFFFFFFF


class SyncConfigError(CobusError, ValueError):
    """A SYNC setting CiA 301 does not allow."""


class SyncCobId(NamedTuple):
    """The 1005h value: identifier, whether this node generates SYNC, identifier format."""

    can_id: int = SYNC_COB_ID
    generate: bool = False
    extended: bool = False

    @classmethod
    def from_u32(cls, value: int) -> SyncCobId:
        can_id, extended = split_cob_id(value, "1005h value", SyncConfigError)
        return cls(can_id, bool(value & _GENERATE), extended)

    def to_u32(self) -> int:
        """The 1005h value: identifier and flags."""
        return (
            self.can_id | (_GENERATE if self.generate else 0) | (_EXTENDED if self.extended else 0)
        )


def check_overflow(value: int) -> int:
    """Return ``value`` if it is a valid 1019h counter overflow value (0 or 2..240)."""
    if not isinstance(value, int) or not (value == 0 or 2 <= value <= 240):
        raise SyncConfigError(
            f"SYNC counter overflow (1019h) {value!r} is invalid: use 0 (no counter) or 2..240"
        )
    return value


def _check_can_id(can_id: int, extended: bool) -> None:
    limit = 0x1FFFFFFF if extended else 0x7FF
    if not isinstance(can_id, int) or not 0 <= can_id <= limit:
        kind = "29-bit" if extended else "11-bit"
        raise SyncConfigError(f"SYNC identifier {can_id!r} does not fit an {kind} identifier")


def _check_us(us: int, what: str) -> int:
    if not isinstance(us, int) or not 0 <= us <= _MAX_US:
        raise SyncConfigError(f"{what} {us!r} µs is out of range: use 0 (off) to 4294967295 µs")
    return us


@dataclass(frozen=True, slots=True)
class SyncReceived(Event):
    """A SYNC arrived; ``counter`` is its counter byte or None for a SYNC without data."""

    counter: int | None


@dataclass(frozen=True, slots=True)
class SyncTimedOut(Event):
    """No SYNC within ``loss_factor`` x the communication cycle period (once per loss)."""


@dataclass(frozen=True, slots=True)
class SyncResumed(Event):
    """A SYNC arrived again after :class:`SyncTimedOut`."""


@dataclass(frozen=True, slots=True)
class UnexpectedSyncLength(Event):
    """A SYNC whose length does not fit 1019h (CiA 301: EMCY 8240h); it is not processed.

    ``expected`` is 0 or 1 byte, or None when either is accepted."""

    expected: int | None
    received: int


class SyncProducer:
    """Sends SYNC every 1006h µs when 1005h bit 30 is set, with the 1019h counter.

    When its timer is served late (a busy host), the SYNC goes out at once and the next one
    stays on the period's grid; after more than a whole period, SYNC resumes one period
    from then, and the periods that passed without one are not made up for:
    :attr:`skipped` counts those, :attr:`late_max` keeps the worst delay, so an application
    can tell why its drives saw SYNC jitter.
    """

    __slots__ = (
        "_counter",
        "_deadline",
        "_outs",
        "_period",
        "can_id",
        "extended",
        "generate",
        "late_max",
        "overflow",
        "period_us",
        "skipped",
    )

    def __init__(
        self,
        can_id: int = SYNC_COB_ID,
        *,
        extended: bool = False,
        generate: bool = True,
        overflow: int = 0,
    ) -> None:
        _check_can_id(can_id, extended)
        self.can_id = can_id
        self.extended = extended
        self.generate = generate
        self.overflow = check_overflow(overflow)
        self.period_us = 0
        #: The longest delay of a SYNC behind its time, in seconds.
        self.late_max = 0.0
        #: SYNC periods that passed without a SYNC (the timer came more than a period late).
        self.skipped = 0
        self._period = 0.0
        self._deadline: float | None = None
        self._counter = 1
        self._outs: list[Out] = []
        self._build()

    def _build(self) -> None:
        cid, ext = self.can_id, self.extended
        if self.overflow:
            self._outs = [Out((Frame(cid, bytes((c,)), extended=ext),), ()) for c in range(256)]
        else:
            self._outs = [Out((Frame(cid, extended=ext),), ())]
        self._counter = 1

    @property
    def deadline(self) -> float | None:
        return self._deadline

    @property
    def counter(self) -> int | None:
        """The counter the next SYNC carries (None: SYNC without counter)."""
        return self._counter if self.overflow else None

    def set_period(self, us: int, now: float) -> None:
        """Write 1006h: 0 stops; otherwise the first SYNC goes out one period after ``now``."""
        _check_us(us, "communication cycle period (1006h)")
        if us and not self.period_us:
            self._counter = 1
        self.period_us = us
        self._period = us / 1e6
        self._arm(now)

    def set_overflow(self, value: int) -> None:
        """Write 1019h; CiA 301 allows it only while 1006h is 0."""
        check_overflow(value)
        if self.period_us:
            raise SyncConfigError(
                "1019h can only change while the SYNC period 1006h is 0 (CiA 301: abort "
                "08000022); write 1006h = 0 first"
            )
        self.overflow = value
        self._build()

    def set_cob_id(self, value: int, now: float) -> None:
        """Write 1005h; the identifier cannot change while the node generates SYNC."""
        new = SyncCobId.from_u32(value)
        if (
            self.generate
            and new.generate
            and (new.can_id, new.extended) != (self.can_id, self.extended)
        ):
            raise SyncConfigError(
                f"1005h: cannot change the SYNC identifier 0x{self.can_id:X} while bit 30 "
                "(generate) is set; write it with bit 30 clear first"
            )
        changed = (new.can_id, new.extended) != (self.can_id, self.extended)
        self.can_id, self.extended = new.can_id, new.extended
        if changed:
            self._build()
        if new.generate and not self.generate:
            self._counter = 1
        self.generate = new.generate
        self._arm(now)

    def _arm(self, now: float) -> None:
        self._deadline = now + self._period if self.generate and self.period_us else None

    def send(self, now: float) -> Out:
        """Send one SYNC now (on demand, e.g. once per task cycle); the counter advances."""
        if self.overflow:
            counter = self._counter
            self._counter = counter + 1 if counter < self.overflow else 1
            return self._outs[counter]
        return self._outs[0]

    def on_frame(self, frame: Frame, now: float) -> Out:
        return NOTHING

    def on_timer(self, now: float) -> Out:
        deadline = self._deadline
        if deadline is None or now < deadline:
            return NOTHING
        late = now - deadline
        if late > self.late_max:
            self.late_max = late
        period = self._period
        deadline += period
        if deadline <= now:  # whole periods passed: they are not made up for
            # whole periods between the missed deadline and now (1 ns tolerance for floats)
            self.skipped += int((now - deadline) / period + 1e-9) + 1
            deadline = now + period
        self._deadline = deadline
        return self.send(now)


_RECEIVED: list[Out] = [Out((), (SyncReceived(c),)) for c in range(256)]
_RECEIVED_NONE = Out((), (SyncReceived(None),))
_RESUMED: list[Out] = [Out((), (SyncResumed(), SyncReceived(c))) for c in range(256)]
_RESUMED_NONE = Out((), (SyncResumed(), SyncReceived(None)))


class SyncConsumer:
    """Receives SYNC, detects its loss and tells whether the synchronous window is open.

    ``overflow`` is the local 1019h value the SYNC length is checked against (0: no data,
    2..240: one counter byte); None accepts both. Loss detection needs the period (1006h)
    and starts with the first SYNC received: no SYNC within ``loss_factor`` x period
    reports :class:`SyncTimedOut` once, the next SYNC :class:`SyncResumed`.
    """

    __slots__ = (
        "_expected",
        "_expiry",
        "_loss",
        "_lost",
        "_window",
        "can_id",
        "counter",
        "extended",
        "last_sync",
        "loss_factor",
        "overflow",
        "period_us",
        "window_us",
    )

    def __init__(
        self,
        can_id: int = SYNC_COB_ID,
        *,
        extended: bool = False,
        overflow: int | None = None,
        loss_factor: float = 1.5,
    ) -> None:
        _check_can_id(can_id, extended)
        if not loss_factor >= 1.0:
            raise SyncConfigError(f"SYNC loss factor {loss_factor!r} must be >= 1 period")
        self.can_id = can_id
        self.extended = extended
        self.loss_factor = loss_factor
        self.overflow: int | None = None
        self._expected: int | None = None
        self.set_overflow(overflow)
        self.period_us = 0
        self.window_us = 0
        self._loss = 0.0
        self._window = 0.0
        self._expiry: float | None = None
        self._lost = False
        self.counter: int | None = None
        self.last_sync: float | None = None

    @property
    def deadline(self) -> float | None:
        return self._expiry

    @property
    def lost(self) -> bool:
        """Whether SYNC stopped arriving within its expected period."""
        return self._lost

    def set_overflow(self, value: int | None) -> None:
        """Set the local 1019h value the SYNC length is checked against (None: accept any)."""
        if value is not None:
            check_overflow(value)
        self.overflow = value
        self._expected = None if value is None else (1 if value else 0)

    def set_period(self, us: int, now: float) -> None:
        """Write 1006h: 0 turns loss detection off; a running supervision restarts at ``now``."""
        _check_us(us, "communication cycle period (1006h)")
        self.period_us = us
        self._loss = us / 1e6 * self.loss_factor
        if not us:
            self._expiry = None
            self._lost = False
        elif self._expiry is not None:
            self._expiry = now + self._loss

    def set_window(self, us: int) -> None:
        """Write 1007h: synchronous window length (0 = no window)."""
        _check_us(us, "synchronous window length (1007h)")
        self.window_us = us
        self._window = us / 1e6

    def set_cob_id(self, value: int) -> None:
        """Write 1005h (the consumer uses identifier and format; bit 30 is the producer's)."""
        new = SyncCobId.from_u32(value)
        self.can_id, self.extended = new.can_id, new.extended

    def in_window(self, now: float) -> bool:
        """Whether synchronous PDOs may still be sent/applied for the last SYNC at ``now``."""
        last = self.last_sync
        if last is None:
            return False
        return not self._window or now - last <= self._window

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.cob_id != self.can_id or frame.rtr or frame.extended != self.extended:
            return NOTHING
        n = len(frame.data)
        expected = self._expected
        if n > 1 or (expected is not None and n != expected):
            return Out((), (UnexpectedSyncLength(expected, n),))
        counter = frame.data[0] if n else None
        self.counter = counter
        self.last_sync = now
        if self._loss:
            self._expiry = now + self._loss
        if self._lost:
            self._lost = False
            return _RESUMED_NONE if counter is None else _RESUMED[counter]
        return _RECEIVED_NONE if counter is None else _RECEIVED[counter]

    def on_timer(self, now: float) -> Out:
        expiry = self._expiry
        if expiry is None or now < expiry:
            return NOTHING
        self._expiry = None
        self._lost = True
        return Out((), (SyncTimedOut(),))


#: One name per idea: SyncLost is the device's event (see :mod:`cobus.device.events`).
__getattr__ = renamed_names(__name__, {"SyncLost": ("SyncTimedOut", SyncTimedOut)})
