"""TIME: the TIME_OF_DAY time stamp (CiA 301), its producer and consumer.

TIME_OF_DAY is 6 bytes: a U32 (little-endian) whose low 28 bits are the milliseconds after
midnight (bits 28-31 reserved, 0), then a U16 of days since 1984-01-01. Values here are
``datetime`` objects in UTC. The COB-ID object 1012h has bit 31 = consume, bit 30 = produce,
bit 29 = 29-bit identifier; the default identifier is 100h.

Machines never read a clock: the producer is told the wall time that goes with a ``now``
(:meth:`TimeProducer.set_interval`) and derives later stamps from ``now``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import NamedTuple

from cobus._moved import renamed_names
from cobus.errors import CobusError
from cobus.proto._base import NOTHING, Event, Out
from cobus.proto._cobid import split_cob_id
from cobus.proto.connection_set import TIME_COB_ID
from cobus.proto.frame import Frame

__all__ = [
    "EPOCH",
    "TIME_COB_ID",
    "MalformedTime",
    "TimeCobId",
    "TimeConsumer",
    "TimeError",
    "TimeProducer",
    "TimeStampReceived",
    "decode_time_of_day",
    "encode_time_of_day",
]

EPOCH = datetime(1984, 1, 1, tzinfo=UTC)
_LAST = EPOCH + timedelta(days=0xFFFF, milliseconds=86_399_999)
_MS_PER_DAY = 86_400_000
_MS_MASK = 0x0FFFFFFF
_TOD = struct.Struct("<IH")
_CONSUME = 1 << 31
_PRODUCE = 1 << 30
_EXTENDED = 1 << 29


class TimeError(CobusError, ValueError):
    """A time stamp or TIME setting that cannot be encoded or used."""


class TimeCobId(NamedTuple):
    """The 1012h value: identifier, consume and produce flags, identifier format."""

    can_id: int = TIME_COB_ID
    consume: bool = False
    produce: bool = False
    extended: bool = False

    @classmethod
    def from_u32(cls, value: int) -> TimeCobId:
        can_id, extended = split_cob_id(value, "1012h value", TimeError)
        return cls(can_id, bool(value & _CONSUME), bool(value & _PRODUCE), extended)

    def to_u32(self) -> int:
        """The 1012h value: identifier and flags."""
        return (
            self.can_id
            | (_CONSUME if self.consume else 0)
            | (_PRODUCE if self.produce else 0)
            | (_EXTENDED if self.extended else 0)
        )


def encode_time_of_day(when: datetime) -> bytes:
    """The 6 TIME_OF_DAY bytes of an aware ``datetime`` (sub-millisecond parts are dropped)."""
    if when.tzinfo is None or when.utcoffset() is None:
        raise TimeError(
            f"{when!r} has no time zone; TIME_OF_DAY is UTC: pass an aware datetime, "
            "e.g. value.replace(tzinfo=datetime.UTC)"
        )
    if not EPOCH <= when <= _LAST:
        raise TimeError(
            f"{when.isoformat()} is outside what TIME_OF_DAY can carry "
            f"({EPOCH.date()} to {_LAST.date()})"
        )
    delta = when - EPOCH
    ms = delta.seconds * 1000 + delta.microseconds // 1000
    return _TOD.pack(ms, delta.days)


def decode_time_of_day(data: bytes) -> datetime:
    """The UTC ``datetime`` of 6 TIME_OF_DAY bytes (reserved bits 28-31 are ignored)."""
    if len(data) != 6:
        raise TimeError(f"TIME_OF_DAY has 6 bytes, not {len(data)} ({bytes(data).hex(' ')})")
    raw, days = _TOD.unpack(data)
    ms = raw & _MS_MASK
    if ms >= _MS_PER_DAY:
        raise TimeError(f"TIME_OF_DAY says {ms} ms after midnight; a day has {_MS_PER_DAY} ms")
    return EPOCH + timedelta(days=days, milliseconds=ms)


@dataclass(frozen=True, slots=True)
class TimeStampReceived(Event):
    """A TIME frame arrived carrying ``time`` (UTC)."""

    time: datetime


@dataclass(frozen=True, slots=True)
class MalformedTime(Event):
    """A frame on the TIME identifier that is no valid TIME_OF_DAY."""

    data: bytes
    reason: str


def _check_can_id(can_id: int, extended: bool) -> None:
    limit = 0x1FFFFFFF if extended else 0x7FF
    if not isinstance(can_id, int) or not 0 <= can_id <= limit:
        kind = "29-bit" if extended else "11-bit"
        raise TimeError(f"TIME identifier {can_id!r} does not fit an {kind} identifier")


class TimeProducer:
    """Sends TIME frames on demand (:meth:`send`) or every ``interval`` seconds."""

    __slots__ = ("_deadline", "_interval", "_ref_now", "_ref_wall", "can_id", "extended")

    def __init__(self, can_id: int = TIME_COB_ID, *, extended: bool = False) -> None:
        _check_can_id(can_id, extended)
        self.can_id = can_id
        self.extended = extended
        self._interval = 0.0
        self._deadline: float | None = None
        self._ref_now = 0.0
        self._ref_wall = EPOCH

    @property
    def deadline(self) -> float | None:
        return self._deadline

    def send(self, when: datetime) -> Out:
        """One TIME frame carrying ``when``."""
        frame = Frame(self.can_id, encode_time_of_day(when), extended=self.extended)
        return Out((frame,), ())

    def set_interval(self, seconds: float, now: float, wall: datetime | None = None) -> Out:
        """Send periodically: ``wall`` is the time of day at ``now`` (sent at once); later
        stamps are ``wall`` plus the elapsed ``now``. ``seconds`` = 0 stops."""
        if not seconds >= 0:
            raise TimeError(f"TIME interval {seconds!r} s must be >= 0")
        if not seconds:
            self._interval = 0.0
            self._deadline = None
            return NOTHING
        if wall is None:
            raise TimeError("periodic TIME needs the wall time at `now` (the `wall` argument)")
        out = self.send(wall)
        self._interval = seconds
        self._ref_now = now
        self._ref_wall = wall
        self._deadline = now + seconds
        return out

    def on_frame(self, frame: Frame, now: float) -> Out:
        return NOTHING

    def on_timer(self, now: float) -> Out:
        deadline = self._deadline
        if deadline is None or now < deadline:
            return NOTHING
        deadline += self._interval
        self._deadline = deadline if deadline > now else now + self._interval
        return self.send(self._ref_wall + timedelta(seconds=now - self._ref_now))


class TimeConsumer:
    """Receives TIME frames and reports :class:`TimeStampReceived`."""

    __slots__ = ("can_id", "extended")

    def __init__(self, can_id: int = TIME_COB_ID, *, extended: bool = False) -> None:
        _check_can_id(can_id, extended)
        self.can_id = can_id
        self.extended = extended

    @property
    def deadline(self) -> float | None:
        return None

    def on_frame(self, frame: Frame, now: float) -> Out:
        if frame.cob_id != self.can_id or frame.extended != self.extended:
            return NOTHING
        if frame.rtr:
            return Out((), (MalformedTime(b"", "remote frame on the TIME identifier"),))
        try:
            when = decode_time_of_day(frame.data)
        except TimeError as exc:
            return Out((), (MalformedTime(frame.data, str(exc)),))
        return Out((), (TimeStampReceived(when),))

    def on_timer(self, now: float) -> Out:
        return NOTHING


#: One name per idea: TimeReceived is the device's event (see :mod:`cobus.device.events`).
__getattr__ = renamed_names(__name__, {"TimeReceived": ("TimeStampReceived", TimeStampReceived)})
