"""The shape every sans-I/O protocol machine shares.

A machine is fed inputs and the current time and answers with an :class:`Out`: the frames to
send and the events that happened. It never reads a clock, sleeps, or touches a bus.

- ``machine.on_frame(frame, now) -> Out`` for a received frame addressed to it;
- ``machine.on_timer(now) -> Out`` when ``now >= machine.deadline``;
- ``machine.deadline -> float | None``: the next time it wants ``on_timer``; ``None`` = never.

Times are seconds as ``float`` on any monotonic scale the caller chooses (real or simulated).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

from cobus.proto.frame import Frame

__all__ = ["NOTHING", "Event", "Machine", "Out"]


@dataclass(frozen=True, slots=True)
class Event:
    """Base class of every event a protocol machine reports."""


class Out(NamedTuple):
    """What a machine returns: frames to transmit, in order, and events, in order."""

    frames: tuple[Frame, ...] = ()
    events: tuple[Event, ...] = ()

    def __add__(self, other: object) -> Out:
        if not isinstance(other, Out):
            return NotImplemented
        if not other.frames and not other.events:
            return self
        if not self.frames and not self.events:
            return other
        return Out(self.frames + other.frames, self.events + other.events)


NOTHING = Out()


class Machine(Protocol):
    """A protocol machine driven by frames and time."""

    @property
    def deadline(self) -> float | None:
        """When :meth:`on_timer` must be called next, on the network's clock (None: never)."""
        ...

    def on_frame(self, frame: Frame, now: float) -> Out:
        """A frame on one of the machine's identifiers arrived at ``now``: what to send, what
        happened."""
        ...

    def on_timer(self, now: float) -> Out:
        """The deadline has come (``now`` >= it): what to send, what happened."""
        ...
