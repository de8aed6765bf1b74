"""Faults of the bus and of nodes, for tests and for an operator panel.

- :class:`FaultyBus` wraps any python-can bus: it loses and corrupts frames at given rates,
  deterministically for a seed, and goes bus-off on request (``send`` raises
  :class:`can.CanOperationError`, as a controller in bus-off refuses frames) and back, with the
  SocketCAN error frames the runtime turns into
  :class:`~cobus.runtime.BusStateChanged` events.
- :class:`Babbler` is a babbling node: it sends one frame on a high-priority identifier every
  ``period_us`` microseconds of the network's clock.
- :func:`fault_catalogue` lists what a device (or the bus) can be made to do, with a
  description each, so a panel can offer them.

Device faults (power loss and return, node-ID change, heartbeat stop, late SDO answers, drive
faults) belong to each simulated device: see ``FAULTS`` on its class and its ``inject``.
"""

from __future__ import annotations

import asyncio
import math
import random
from collections import deque
from collections.abc import Mapping
from typing import Any

import can

from cobus.proto import Frame
from cobus.runtime.network import AsyncNetwork, NetworkClosedError, TxOverflowError
from cobus.sim.base import SimulatedDevice, SimulationError

__all__ = [
    "BUS_FAULTS",
    "BUS_FAULT_PARAMS",
    "COMMON_FAULTS",
    "Babbler",
    "FaultConfigError",
    "FaultyBus",
    "check_fault_parameters",
    "fault_catalogue",
    "fault_parameters",
]

#: Faults every simulated device has (handled by :class:`~cobus.sim.SimulatedDevice`).
COMMON_FAULTS: Mapping[str, str] = {
    "power_loss": "the node loses its power: it falls silent and forgets its volatile state",
    "power_return": "the power returns: the node boots again (boot-up message) with its "
    "stored parameters",
}

#: Faults of the bus a rig runs on (``rig.inject(None, fault, ...)``).
BUS_FAULTS: Mapping[str, str] = {
    "bus_off": "the rig's CAN controller goes bus-off: it sends nothing and hears nothing until "
    "bus_restart, or for duration seconds",
    "bus_restart": "the controller leaves bus-off (the simulated nodes report EMCY 8140h)",
    "frame_loss": "frames to and from the rig's nodes are lost at rate 0..1 (seed makes it "
    "repeatable)",
    "frame_corruption": "frames with data get one bit flipped at rate 0..1, a corruption the "
    "CRC missed (seed makes it repeatable)",
    "babbling": "a babbling node sends a frame on cob_id (default 001h) every period_us "
    "microseconds (default 200) until babbling_stop",
    "babbling_stop": "the babbling node falls silent",
}

#: SocketCAN error frame classes (linux/can/error.h) the runtime decodes.
_ERR_BUSOFF = 0x040
_ERR_RESTARTED = 0x100
_ERR_CNT = 0x200


class FaultConfigError(SimulationError, ValueError):
    """A fault setting out of its range (a rate outside 0..1, a period of 0...)."""


def _rate(value: float, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value <= 1:
        raise FaultConfigError(f"{what} {value!r} must be a probability from 0 to 1")
    return float(value)


def _error_frame(classes: int, tx_errors: int, rx_errors: int) -> can.Message:
    data = bytearray(8)
    data[6], data[7] = tx_errors, rx_errors
    return can.Message(
        arbitration_id=classes | _ERR_CNT,
        data=bytes(data),
        is_error_frame=True,
        is_extended_id=False,
        check=False,
    )


class FaultyBus(can.BusABC):
    """A python-can bus between ``inner`` and its user that loses and corrupts frames.

    ``loss`` and ``corruption`` are probabilities per frame, drawn from one
    :class:`random.Random` seeded with ``seed``: the same frames in the same order meet the
    same fate in every run. ``direction`` says which frames they apply to: ``"both"``, ``"tx"``
    (sent through this bus) or ``"rx"`` (received from ``inner``). A corrupted frame gets one
    bit of its data flipped (frames without data are never corrupted).

    :meth:`bus_off` makes ``send`` raise :class:`can.CanOperationError` and drops what arrives
    until :meth:`restart`; both put an error frame in the receive queue (bus-off, restarted),
    which :class:`~cobus.runtime.AsyncNetwork` reports as
    :class:`~cobus.runtime.BusStateChanged`.

    Counters: :attr:`sent`, :attr:`received`, :attr:`lost`, :attr:`corrupted`.
    """

    def __init__(
        self,
        inner: can.BusABC,
        *,
        loss: float = 0.0,
        corruption: float = 0.0,
        seed: int | None = None,
        direction: str = "both",
    ) -> None:
        if direction not in ("both", "tx", "rx"):
            raise FaultConfigError(
                f"direction {direction!r} is not one of 'both', 'tx' (sent), 'rx' (received)"
            )
        self.inner = inner
        from cobus.runtime.bus import error_frames_are_local

        #: Error frames the wrapped bus receives are other participants' (a virtual bus).
        self._foreign_errors = not error_frames_are_local(inner)
        self._loss = _rate(loss, "frame loss rate")
        self._corruption = _rate(corruption, "frame corruption rate")
        self._rng = random.Random(seed)
        self._tx = direction in ("both", "tx")
        self._rx = direction in ("both", "rx")
        self._bus_off = False
        self._errors: deque[can.Message] = deque()
        self.sent = 0
        self.received = 0
        self.lost = 0
        self.corrupted = 0
        super().__init__(channel=f"faulty:{getattr(inner, 'channel_info', 'bus')}")
        self.channel_info = f"faulty({getattr(inner, 'channel_info', 'bus')})"

    # ------------------------------------------------------------------ settings
    @property
    def loss(self) -> float:
        """The share of frames lost, 0.0..1.0."""
        return self._loss

    @loss.setter
    def loss(self, rate: float) -> None:
        self._loss = _rate(rate, "frame loss rate")

    @property
    def corruption(self) -> float:
        """The share of frames corrupted, 0.0..1.0."""
        return self._corruption

    @corruption.setter
    def corruption(self, rate: float) -> None:
        self._corruption = _rate(rate, "frame corruption rate")

    def reseed(self, seed: int | None) -> None:
        """Start the random sequence again from ``seed``."""
        self._rng = random.Random(seed)

    @property
    def is_bus_off(self) -> bool:
        """Whether the bus is off (frames are refused)."""
        return self._bus_off

    def bus_off(self) -> None:
        """The controller goes bus-off (transmit error counter past 255)."""
        if self._bus_off:
            return
        self._bus_off = True
        self._errors.append(_error_frame(_ERR_BUSOFF, 255, 0))

    def restart(self) -> None:
        """The controller is restarted and takes part in the bus again."""
        if not self._bus_off:
            return
        self._bus_off = False
        self._errors.append(_error_frame(_ERR_RESTARTED, 0, 0))

    # ------------------------------------------------------------------ python-can
    def _fate(self, msg: can.Message) -> can.Message | None:
        """``msg`` as it comes out of the faulty wire: None if lost."""
        rng = self._rng
        if self._loss and rng.random() < self._loss:
            self.lost += 1
            return None
        if self._corruption and rng.random() < self._corruption and msg.dlc and msg.data:
            data = bytearray(msg.data)
            bit = rng.randrange(len(data) * 8)
            data[bit // 8] ^= 1 << (bit % 8)
            self.corrupted += 1
            return can.Message(
                timestamp=msg.timestamp,
                arbitration_id=msg.arbitration_id,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                dlc=msg.dlc,
                data=bytes(data),
                channel=msg.channel,  # (the runtime tells its own messages by these two)
                is_rx=msg.is_rx,
                check=False,
            )
        return msg

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._bus_off:
            raise can.CanOperationError(
                "the controller is bus-off: it transmits nothing until it is restarted"
            )
        if self._tx:
            fated = self._fate(msg)
            if fated is None:
                self.sent += 1  # on the wire, destroyed there: the sender cannot tell
                return
            msg = fated
        self.inner.send(msg, timeout)
        self.sent += 1

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._errors:
            return self._errors.popleft(), True
        wait = timeout
        while True:
            msg = self.inner.recv(wait)
            if msg is None:
                return msg, False
            if msg.is_error_frame:
                if not self._foreign_errors:
                    return msg, False
                continue  # another participant's error frame on a software hub: not ours

            wait = 0.0  # a frame was lost: take the next one that is already waiting
            if self._bus_off:
                continue
            if self._rx:
                fated = self._fate(msg)
                if fated is None:
                    continue
                msg = fated
            self.received += 1
            return msg, False

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()


class Babbler:
    """A babbling node: one frame on ``cob_id`` every ``period_us`` µs of the network clock.

    Identifier 001h (the default) is the highest priority after NMT and serves no CiA 301
    service, so it disturbs by its load alone. The python-can virtual bus has no arbitration:
    there the flood shows as traffic, not as frames of lower priority that wait.
    """

    def __init__(
        self,
        network: AsyncNetwork,
        *,
        cob_id: int = 0x001,
        period_us: float = 200,
        data: bytes = b"\xff" * 8,
    ) -> None:
        if isinstance(period_us, bool) or not isinstance(period_us, int | float) or period_us < 1:
            raise FaultConfigError(f"babbling period {period_us!r} µs must be at least 1 µs")
        try:
            self._frame = Frame(cob_id, bytes(data))
        except (SimulationError, ValueError, TypeError) as exc:
            raise FaultConfigError(f"babbling frame: {exc}") from None
        self.network = network
        self.cob_id = cob_id
        self.period = period_us / 1e6
        self.sent = 0
        self.refused = 0
        self._handle: asyncio.TimerHandle | None = None
        self._next = 0.0

    @property
    def running(self) -> bool:
        """Whether the babbling node is sending."""
        return self._handle is not None

    def start(self) -> None:
        """Start flooding the bus with the babbling frames."""
        if self._handle is not None:
            return
        loop = self.network.loop
        self._next = loop.time() + self.period
        self._handle = loop.call_at(self._next, self._babble)

    def stop(self) -> None:
        """Stop flooding the bus."""
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None

    def _babble(self) -> None:
        try:
            self.network.send(self._frame)
            self.sent += 1
        except (TxOverflowError, NetworkClosedError):
            self.refused += 1
            if not self.network.connected:
                self._handle = None
                return
        loop = self.network.loop
        # scheduled on a fixed grid: a late wake-up does not stretch the period
        self._next = max(self._next + self.period, loop.time())
        self._handle = loop.call_at(self._next, self._babble)


#: The parameters of the bus faults (see SimulatedDevice.FAULT_PARAMS for the kinds).
BUS_FAULT_PARAMS: Mapping[str, Mapping[str, str]] = {
    "bus_off": {"duration": "seconds?"},
    "bus_restart": {},
    "frame_loss": {"rate": "rate", "seed": "int?"},
    "frame_corruption": {"rate": "rate", "seed": "int?"},
    "babbling": {"cob_id": "int?", "period_us": "number?"},
    "babbling_stop": {},
}


def _kind_problem(kind: str, value: Any) -> str | None:
    """Why ``value`` is no ``kind`` (None: it is one)."""
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if kind == "int":
        return None if isinstance(value, int) and not isinstance(value, bool) else "an integer"
    if kind == "bool":
        return None if isinstance(value, bool) else "true or false"
    if kind == "number":
        return None if number and math.isfinite(value) else "a number"
    if kind == "seconds":
        return None if number and math.isfinite(value) and value >= 0 else "seconds, 0 or more"
    if kind == "rate":
        return None if number and 0 <= value <= 1 else "a rate from 0 to 1"
    if kind == "node_id":
        whole = isinstance(value, int) and not isinstance(value, bool)
        return None if whole and 1 <= value <= 127 else "a node-ID 1..127"
    return None


def fault_parameters(
    device: SimulatedDevice | type[SimulatedDevice] | None, fault: str
) -> Mapping[str, str] | None:
    """The parameters ``fault`` takes on ``device`` (None: the bus), None when undeclared."""
    if device is None:
        return BUS_FAULT_PARAMS.get(fault)
    cls = device if isinstance(device, type) else type(device)
    for klass in cls.__mro__:
        table = vars(klass).get("FAULT_PARAMS")
        if table is not None and fault in table:
            found: Mapping[str, str] = table[fault]
            return found
    return None


def check_fault_parameters(
    device: SimulatedDevice | type[SimulatedDevice] | None,
    fault: str,
    params: Mapping[str, Any],
) -> None:
    """Refuse parameters ``fault`` does not take, is missing, or of the wrong kind, before the
    fault fires (a rig file's mistake shows when it loads, not minutes later);
    :class:`~cobus.sim.generic.FaultParameterError` says which and what it takes."""
    from cobus.sim.generic import FaultParameterError

    spec = fault_parameters(device, fault)
    if spec is None:
        return  # (a device's own fault without a declaration: its inject checks)
    takes = (
        ", ".join(
            f"{k} ({v.rstrip('?')}{', optional' if v.endswith('?') else ''})"
            for k, v in spec.items()
        )
        or "no parameters"
    )
    unknown = sorted(set(params) - set(spec))
    if unknown:
        raise FaultParameterError(f"{fault} takes {takes}; not {', '.join(unknown)}")
    for name, kind in spec.items():
        if name not in params or (params[name] is None and kind.endswith("?")):
            if not kind.endswith("?"):
                raise FaultParameterError(f"{fault} needs {name}; it takes {takes}")
            continue
        problem = _kind_problem(kind.rstrip("?"), params[name])
        if problem is not None:
            raise FaultParameterError(f"{fault}: {name} {params[name]!r} must be {problem}")


def fault_catalogue(
    device: SimulatedDevice | type[SimulatedDevice] | None = None,
) -> dict[str, str]:
    """Every fault ``device`` (an instance or a class) can be given, with its description;
    None: the bus faults a rig offers."""
    if device is None:
        return dict(BUS_FAULTS)
    out = dict(COMMON_FAULTS)
    out.update(device.FAULTS)
    return dict(sorted(out.items()))


def describe_params(params: Mapping[str, Any]) -> str:
    """``a=1, b='x'`` for messages and status lines."""
    return ", ".join(f"{k}={v!r}" for k, v in params.items())
