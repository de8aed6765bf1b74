"""The machines a device's hosts drive around its SDO servers and heartbeat producer, so that
:attr:`Simulation.sdo_response_delay <cobus.device.Simulation.sdo_response_delay>` and
:attr:`Simulation.heartbeat_muted <cobus.device.Simulation.heartbeat_muted>` act on them
without changing the protocol machines themselves.

Both read the device's :class:`~cobus.device.Simulation`, so a change applies at once to the
channels and the producer in place, and holds through every rebuild of the communication
(resets, node-ID changes, new COB-IDs). A channel goes behind its :class:`LateSdoServer`
only once a delay is set (the device's SDO service puts it there); until then its requests
skip the gate's calls.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

from cobus.proto import NOTHING, Frame, Out
from cobus.proto.heartbeat import HeartbeatProducer
from cobus.proto.sdo import SdoServer

if TYPE_CHECKING:
    from cobus.device.simulation import Simulation

__all__ = ["LateSdoServer", "MutableHeartbeat"]


class LateSdoServer:
    """An SDO server channel that takes each request up ``simulation.sdo_response_delay``
    seconds after it arrived, as a slow device does: its answers come that much later, and its
    own transfer timeout counts from when it took the request up.

    Requests keep their order: while any wait, a new one waits behind them (a shorter delay set
    later does not overtake). With no delay and nothing waiting, a request goes straight in.
    """

    __slots__ = ("_simulation", "_waiting", "server")

    def __init__(self, server: SdoServer, simulation: Simulation) -> None:
        self.server = server
        self._simulation = simulation
        self._waiting: deque[tuple[float, Frame]] = deque()

    @property
    def deadline(self) -> float | None:
        own = self.server.deadline
        if not self._waiting:
            return own
        due = self._waiting[0][0]
        return due if own is None or due < own else own

    @property
    def waiting(self) -> int:
        """Requests received and not yet taken up."""
        return len(self._waiting)

    def on_frame(self, frame: Frame, now: float) -> Out:
        delay = self._simulation.sdo_response_delay
        if delay <= 0 and not self._waiting:
            return self.server.on_frame(frame, now)
        self._waiting.append((now + delay, frame))
        return NOTHING

    def on_timer(self, now: float) -> Out:
        server = self.server
        out = NOTHING
        own = server.deadline
        waiting = self._waiting
        if own is not None and own <= now and (not waiting or own < waiting[0][0]):
            out = server.on_timer(now)  # the transfer timed out before the next request
        while waiting and waiting[0][0] <= now:
            _, frame = waiting.popleft()
            out = out + server.on_frame(frame, now)
        own = server.deadline
        if own is not None and own <= now:
            out = out + server.on_timer(now)
        return out


class MutableHeartbeat:
    """A heartbeat producer that keeps its period while ``simulation.heartbeat_muted`` silences it:
    the beats fall due as before and are not sent, so un-muting resumes on the same period."""

    __slots__ = ("_simulation", "producer")

    def __init__(self, producer: HeartbeatProducer, simulation: Simulation) -> None:
        self.producer = producer
        self._simulation = simulation

    @property
    def deadline(self) -> float | None:
        return self.producer.deadline

    def on_frame(self, frame: Frame, now: float) -> Out:
        return self.producer.on_frame(frame, now)

    def on_timer(self, now: float) -> Out:
        out = self.producer.on_timer(now)
        if out.frames and self._simulation.heartbeat_muted:
            return Out((), out.events)
        return out
