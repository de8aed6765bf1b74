"""Sans-I/O CANopen protocol machines: ``(frame, now)`` in, frames and events out."""

from cobus.proto._base import NOTHING, Event, Machine, Out
from cobus.proto.frame import Frame, FrameError

__all__ = ["NOTHING", "Event", "Frame", "FrameError", "Machine", "Out"]
