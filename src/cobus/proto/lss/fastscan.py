"""Fastscan (CiA 305): find one device without a node-ID, field by field, bit by bit.

The master first asks every unconfigured slave to answer (BitChecked 80h, which also resets
their scan). Then, for each field of the identity (vendor, product, revision, serial), it
probes from bit 31 down to bit 0 with the value found so far: an answer means some slave has
that bit 0, silence means 1. A field is then confirmed with BitChecked 0, which moves the
matching slaves on to the next field; the serial's confirmation puts the one slave left into
configuration state. A field known beforehand (from the network file) is confirmed at once.

Each probe waits its whole window, so that every slave's answer (several may match) belongs
to it; the window adapts to the round trip measured on the first answers (``factor`` x the
slowest, between ``floor`` and ``ceiling`` seconds; the ceiling until the first answer). A field
whose confirmation gets no answer was misread (an answer later than its window, taken for the
next probe's): it is scanned again once, waiting the ceiling, before the scan gives up.
The serial's confirmation counts its answers: two mean two devices share one identity.
A late answer can still make a wrong last bit look confirmed: ask the selected slave its
serial before trusting :class:`FastscanFound` (``net.lss.fastscan`` does).
"""

from __future__ import annotations

from dataclasses import dataclass

from cobus.proto._base import NOTHING, Event, Out
from cobus.proto.frame import Frame
from cobus.proto.lss import _wire as w
from cobus.proto.lss._wire import FIELDS, LssError, LssIdentity

__all__ = [
    "Fastscan",
    "FastscanFailed",
    "FastscanFieldFound",
    "FastscanFieldRetried",
    "FastscanFound",
    "FastscanNothingFound",
    "FastscanStarted",
]

_BITS = 32


@dataclass(frozen=True, slots=True)
class FastscanStarted(Event):
    """Unconfigured slaves answered: the scan takes about ``estimate`` seconds."""

    estimate: float
    window: float


@dataclass(frozen=True, slots=True)
class FastscanFieldFound(Event):
    """``field`` (vendor, product, revision, serial) is ``value`` (``known``: given, confirmed)."""

    field: str
    value: int
    known: bool


@dataclass(frozen=True, slots=True)
class FastscanFieldRetried(Event):
    """The confirmation of ``field`` as ``value`` got no answer: scanned again."""

    field: str
    value: int


@dataclass(frozen=True, slots=True)
class FastscanFound(Event):
    """The slave with ``identity`` is in configuration state; ``answers`` slaves confirmed it
    (more than one: two devices share the identity)."""

    identity: LssIdentity
    answers: int


@dataclass(frozen=True, slots=True)
class FastscanNothingFound(Event):
    """No unconfigured slave answered (``field`` None), or none has the known ``field``."""

    field: str | None
    value: int | None


@dataclass(frozen=True, slots=True)
class FastscanFailed(Event):
    """The scan could not settle ``field``: ``reason``."""

    field: str
    reason: str


class Fastscan:
    """One fastscan (sans-I/O): :meth:`start`, then frames on 7E4h and the deadline."""

    def __init__(
        self,
        known: dict[str, int] | None = None,
        *,
        floor: float = 0.01,
        ceiling: float = 0.5,
        factor: float = 4.0,
    ) -> None:
        known = dict(known or {})
        for name, value in known.items():
            if name not in FIELDS:
                raise LssError(f"fastscan: known field {name!r}: give {', '.join(FIELDS)}")
            w.u32(value, name)
        if not 0 < floor <= ceiling:
            raise LssError(f"fastscan: floor {floor!r} s must be above 0 and below the ceiling")
        if factor < 1:
            raise LssError(f"fastscan: factor {factor!r} must be 1 or more")
        self.known = known
        self.floor, self.ceiling, self.factor = float(floor), float(ceiling), float(factor)
        self.slowest: float | None = None  # the longest round trip measured
        self.exchanges = 0
        self._values = [0, 0, 0, 0]
        self._field = -1  # -1: the reset probe
        self._bit = _BITS  # the bit probed; -1: confirming the field
        self._retried = False
        self._sent_at = 0.0
        self._deadline: float | None = None
        self._answers = 0
        self.done = False

    @property
    def window(self) -> float:
        """How long a probe waits for an answer now."""
        if self.slowest is None:
            return self.ceiling
        wait = max(self.floor, min(self.ceiling, self.slowest * self.factor))
        return self.ceiling if self._retried else wait

    @property
    def deadline(self) -> float | None:
        return self._deadline

    def start(self, now: float) -> Out:
        """Ask every unconfigured slave to answer (and reset their scan)."""
        if self._field != -1 or self._deadline is not None or self.done:
            raise LssError("this fastscan was started already: make a new one")
        return self._probe(now, 0, w.FASTSCAN_RESET, 0, 0)

    # ---------------------------------------------------------------- the machine

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.cob_id != w.SLAVE or len(frame.data) != 8 or frame.data[0] != w.IDENTIFIED:
            return NOTHING
        if self._deadline is None:
            return NOTHING  # late: the scan is over (or not started)
        rtt = now - self._sent_at  # every answer: the slowest slave sets the window
        self.slowest = rtt if self.slowest is None else max(self.slowest, rtt)
        self._answers += 1
        return NOTHING  # decided when the window closes: every slave has had its say

    def on_timer(self, now: float) -> Out:
        if self._deadline is None or now < self._deadline:
            return NOTHING
        self._deadline = None
        if self._final_confirmation and self._answers:
            return self._found(self._answers)
        return self._answered(now) if self._answers else self._silent(now)

    # ---------------------------------------------------------------- steps

    @property
    def _final_confirmation(self) -> bool:
        return self._field == 3 and self._bit == -1

    def _probe(self, now: float, number: int, bit: int, sub: int, following: int) -> Out:
        self.exchanges += 1
        self._sent_at, self._answers = now, 0
        self._deadline = now + self.window
        body = w.le32(number) + bytes((bit, sub, following))
        return Out((w.request(w.FASTSCAN, body),))

    def _answered(self, now: float) -> Out:
        if self._field == -1:
            unknown = sum(1 for name in FIELDS if name not in self.known)
            estimate = (unknown * _BITS + len(FIELDS)) * self.window
            return self._next_field(now, (FastscanStarted(estimate, self.window),))
        if self._bit >= 0:  # some slave has this bit 0: it stays 0
            return self._next_bit(now)
        # the field is confirmed: the matching slaves moved on to the next one
        name = FIELDS[self._field]
        found = FastscanFieldFound(name, self._values[self._field], name in self.known)
        self._retried = False
        return self._next_field(now, (found,))

    def _silent(self, now: float) -> Out:
        if self._field == -1:
            self.done = True
            return Out((), (FastscanNothingFound(None, None),))
        if self._bit >= 0:  # nobody has this bit 0: it is 1
            self._values[self._field] |= 1 << self._bit
            return self._next_bit(now)
        name, value = FIELDS[self._field], self._values[self._field]
        if name in self.known:
            self.done = True
            return Out((), (FastscanNothingFound(name, value),))
        if self._retried:
            self.done = True
            reason = f"the confirmation of 0x{value:08X} got no answer twice"
            return Out((), (FastscanFailed(name, reason),))
        self._retried = True  # the field again, waiting the ceiling
        self._values[self._field], self._bit = 0, _BITS
        out = self._next_bit(now)
        return Out(out.frames, (FastscanFieldRetried(name, value), *out.events))

    def _next_field(self, now: float, events: tuple[Event, ...]) -> Out:
        self._field += 1
        if self._field == len(FIELDS):
            raise AssertionError("fastscan went past the serial")  # _found ends the scan
        name = FIELDS[self._field]
        if name in self.known:
            self._values[self._field] = self.known[name]
            self._bit = -1
            out = self._confirm(now)
        else:
            self._bit = _BITS
            out = self._next_bit(now)
        return Out(out.frames, events + out.events)

    def _next_bit(self, now: float) -> Out:
        self._bit -= 1
        if self._bit < 0:
            return self._confirm(now)
        field = self._field
        return self._probe(now, self._values[field], self._bit, field, field)

    def _confirm(self, now: float) -> Out:
        self._bit = -1
        field = self._field
        return self._probe(now, self._values[field], 0, field, (field + 1) % len(FIELDS))

    def _found(self, answers: int) -> Out:
        self.done = True
        identity = LssIdentity(*self._values)
        serial = FastscanFieldFound("serial", self._values[3], "serial" in self.known)
        return Out((), (serial, FastscanFound(identity, answers)))
