"""Frames the CAN interface sends by itself, one per period: SYNC that Python's pauses cannot
delay (``docs/realtime.md``, "Timers and cyclic work").

A network's own timers run on its loop: a garbage collection, another thread holding the GIL
or the loop serving a burst of frames delays them, and a 1 ms SYNC then comes late or not at
all. SocketCAN's broadcast manager (BCM) sends a sequence of frames from the kernel instead,
in turn, one per period, whatever the process does. python-canopen's SYNC uses it (through
python-can's ``send_periodic``), without a counter; here a counter is a sequence of frames
(CiA 301: 1..overflow, the kernel takes up to 256).

The network has to hear what the interface sends, as it hears what it sends itself: a SYNC
drives its own synchronous PDOs and a device on the same network. Only two interfaces hand
such frames back to the bus object that started them, and only those are accepted:

- SocketCAN: the kernel loops every frame the BCM sends back to the other CAN sockets of the
  host, this bus's raw socket included (it is not that socket's own frame);
- python-can's ``udp_multicast``: python-can sends from a thread of its own through its own
  socket, and multicast loopback hands the datagram back to it (cobus's echo-free filter,
  :mod:`cobus.runtime.multicast`, drops only what cobus's sending socket sends). The timing is
  then a Python thread's, as python-canopen's on every interface but SocketCAN.

Elsewhere (``virtual``, python-can-remote, vendor interfaces, a wrapper such as
``cobus.sim.FaultyBus``) python-can would send from a thread whose frames this network never
hears, and IXXAT's scheduler takes one frame: :class:`InterfaceTimingError` says so, and the
loop's producer (the default) is the way there. So it does on the simulated clock (whose
time python-can's timing is not); a network not connected raises
:class:`~cobus.runtime.NetworkClosedError`, as the loop's producer does.

python-can's thread sends through the timer, under its lock, without blocking: once
:meth:`InterfaceTimer.stop` returns, nothing more goes out, and a send that fails (buffer
full, bus-off) is counted and reported as :class:`~cobus.runtime.HandlerFailed` (the 1st,
10th, 100th... of them) while sending goes on; a bus shut down ends it. The kernel reports
nothing of its own failed sends.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import can
from can.broadcastmanager import ThreadBasedCyclicSendTask

from cobus.errors import CobusError
from cobus.proto import Frame
from cobus.runtime.bus import _is_udp_multicast, frame_to_message

if TYPE_CHECKING:
    from cobus.runtime.network import AsyncNetwork

__all__ = [
    "InterfaceTimer",
    "InterfaceTimingError",
    "check_interface_timing",
    "interface_timing",
]

#: frames a SocketCAN broadcast manager task sends in turn at most (the kernel's MAX_NFRAMES)
MAX_FRAMES = 256


class InterfaceTimingError(CobusError, ValueError):
    """The bus cannot send these frames periodically by itself so that its network hears them
    too."""


def interface_timing(bus: can.BusABC) -> str | None:
    """How ``bus`` sends a periodic sequence of frames by itself and hands it back to its
    reader: ``"kernel"`` (SocketCAN's broadcast manager), ``"thread"`` (python-can's
    ``udp_multicast``: a python-can thread, heard back through multicast loopback), or None.
    python-can's ``ThreadSafeBus`` is seen through; any other wrapper is not (it would send
    from a thread through its own ``send``)."""
    cls = bus.__class__  # (ThreadSafeBus is a proxy: this is the wrapped class)
    if cls.__name__ == "SocketcanBus" and cls.__module__.startswith("can.interfaces.socketcan"):
        return "kernel"
    if _is_udp_multicast(bus):
        return "thread"
    return None


def check_interface_timing(network: AsyncNetwork) -> str:
    """How the interface of ``network`` would time periodic frames (see
    :func:`interface_timing`); :class:`InterfaceTimingError` where it cannot, on the
    simulated clock, and :class:`~cobus.runtime.NetworkClosedError` while not connected
    (python-can would send all the same)."""
    network.loop  # noqa: B018  # (raises NetworkClosedError)
    if network.simulated:
        raise InterfaceTimingError(
            "on the simulated clock the interface's timing would be wall-clock time: "
            "let the network's loop send the frames"
        )
    bus = network.bus
    kind = interface_timing(bus)
    if kind is None:
        raise InterfaceTimingError(
            f"the {_interface_name(bus)} interface cannot send periodic frames by itself so "
            "that this network hears them too (SocketCAN and python-can's udp_multicast "
            "can); let the network's loop send them instead"
        )
    return kind


def _interface_name(bus: can.BusABC) -> str:
    """The python-can interface name of ``bus`` (``"virtual"``), or its class name."""
    cls = bus.__class__
    for name, (module, class_name) in can.interfaces.BACKENDS.items():
        if class_name == cls.__name__ and cls.__module__.startswith(module):
            return name
    return cls.__name__


class InterfaceTimer:
    """``frames`` sent by the network's interface in turn, one every ``period`` seconds, from
    :meth:`start` until :meth:`stop` or the network disconnects (whoever made it makes a new
    one when the network connects again). The first goes out at once, on both interfaces.

    Made stopped: a timer it replaces is stopped first, so that two never send at once.
    """

    def __init__(self, network: AsyncNetwork, frames: Sequence[Frame], period: float) -> None:
        kind = check_interface_timing(network)
        bus = network.bus
        if not frames or len(frames) > MAX_FRAMES:
            raise InterfaceTimingError(
                f"{len(frames)} frames to send in turn: give 1 to {MAX_FRAMES}"
            )
        if not 0 < period <= 4294.967295:  # (NaN fails too)
            raise InterfaceTimingError(f"period {period!r} s: give a positive time up to 4295 s")
        self._network = network
        self._bus = bus
        self.kind = kind
        self.period = period
        #: Sends python-can's thread could not make (buffer full, bus-off).
        self.errors = 0
        #: What it sends, in turn.
        self.frames = tuple(frames)
        # python-can's thread sends under this lock, through send() below: once stop() has
        # taken it, nothing more goes out
        self._lock = threading.Lock()
        self._stopped = True
        self._started = False
        messages = [frame_to_message(frame) for frame in frames]
        self._task: Any
        try:
            if kind == "kernel":
                # python-can hands the kernel whole microseconds, cut off: half a microsecond
                # more keeps a period of 1001 us from becoming 1000
                us = period * 1e6
                if abs(us - round(us)) < 1e-6:
                    period = (round(us) + 0.5) / 1e6
                # one TX_SETUP with every frame: the kernel cycles through them. The bus does
                # not keep the task (store_task): this timer stops it, and a task the kernel
                # refused to start would otherwise get a TX_DELETE at the bus's shutdown,
                # which raises where the TX_SETUP failed (an interface that is down)
                self._task = bus.send_periodic(messages, period, autostart=False, store_task=False)
            else:
                sender: Any = self  # (python-can's task calls send(msg) on its "bus")
                self._task = ThreadBasedCyclicSendTask(
                    sender, self._lock, messages, period, autostart=False
                )
        except (can.CanError, OSError, ValueError) as exc:
            raise self._refused(exc) from exc

    @property
    def running(self) -> bool:
        """Whether the interface is sending the frames."""
        return not self._stopped

    def start(self) -> None:
        """Start sending (once: a stopped timer is not started again)."""
        if self._started:
            return
        self._started = True
        self._stopped = False
        try:
            self._task.start()
        except (can.CanError, OSError) as exc:
            self._stopped = True
            raise self._refused(exc) from exc
        # a network disconnected from a bus the user keeps: the interface would go on
        self._network.on_disconnect(self.stop)

    def stop(self) -> None:
        """Stop sending (again: nothing happens); once it returns, nothing more is sent."""
        with self._lock:
            was = self._stopped
            self._stopped = True
        self._network._forget(self.stop)
        if was:  # (or ended by its thread: a bus shut down)
            return
        # (raises when the bus is already shut down, and the task with it)
        with contextlib.suppress(can.CanError, OSError):
            self._task.stop()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """python-can's thread sends each frame here, under the lock. A failed send is
        counted and reported (the 1st, 10th, 100th... on the loop), and sending goes on,
        unless the bus has been shut down or the network disconnected."""
        if self._stopped:
            return
        try:
            self._bus.send(msg, timeout=0)  # (as the network sends: never blocks)
        except (can.CanError, OSError) as exc:
            self._failed(exc)

    def _failed(self, exc: BaseException) -> None:
        network = self._network
        loop = network._loop
        if loop is None or getattr(self._bus, "_is_shutdown", False):
            self._stopped = True  # for good: the bus is gone
            self._task.stop()
            if loop is not None:  # (the network's lists are the loop's)
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(network._forget, self.stop)
            return
        self.errors = count = self.errors + 1
        if count in (1, 10, 100, 1000) or count % 10_000 == 0:
            cob_id = self.frames[0].cob_id
            where = f"periodic frame 0x{cob_id:X} sent by the interface ({count} failed)"
            with contextlib.suppress(RuntimeError):  # the loop is closed
                loop.call_soon_threadsafe(network.report_failure, where, exc)

    def _refused(self, exc: BaseException) -> InterfaceTimingError:
        return InterfaceTimingError(
            f"the interface refused to send frame 0x{self.frames[0].cob_id:X} every "
            f"{self.period:g} s: {exc}"
        )
