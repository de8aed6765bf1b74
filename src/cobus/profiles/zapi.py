"""The ZAPI ACE2 AC inverter of the thesis (seed 000), run from the master side: the toggle
handshake kept every SYNC cycle, speed in Hz, direction, ramp, the controlword bits by name,
the alarm byte decoded, and the thesis's command/feedback check.

The inverter speaks a manufacturer profile, not CiA 402: RPDO1 carries the speed set-point
(Hz x 100), the controlword, the pedal-brake and torque requests and the ramp (Hz/s x 10);
TPDO1 the actual speed and the statusword, every SYNC; TPDO2 the alarm code. It expects, in
every cycle, an RPDO1 whose controlword byte 3 bit 7 is the opposite of the toggle in the
TPDO1 it just sent; a missed answer makes it raise alarm 248 "CAN BUS KO" and drop to
pre-operational. :class:`AsyncZapiDrive` answers each TPDO1 in the master's TPDO listener,
with the current command, in one RPDO1 frame.

It runs on a node the :class:`~cobus.master.Master` manages, whose network file maps RPDO1
and TPDO1 (the thesis's layout: ``examples/networks/thesis.yml``). The thesis's EDS was hand
made and its object indexes were never published: :class:`ZapiObjects` names the ones in use
(the defaults are those of the simulated inverter, ``cobus.sim.zapi``).
"""

from __future__ import annotations

import asyncio
import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from cobus.errors import CobusError
from cobus.profiles._port import ManagedNodePort, port_for
from cobus.profiles._tables import table as data_table
from cobus.runtime._service import Callbacks
from cobus.runtime.twin import BlockingTwin

__all__ = [
    "ALARM_TEXTS",
    "FEEDBACK_OUTPUTS",
    "AlarmChanged",
    "AsyncZapiDrive",
    "FeedbackMismatch",
    "FeedbackRestored",
    "HandshakeLost",
    "HandshakeRestored",
    "ZapiControl",
    "ZapiDrive",
    "ZapiError",
    "ZapiEvent",
    "ZapiObjects",
    "ZapiStatus",
    "alarm_text",
]

#: ZAPI alarm codes (decimal) the thesis names, with the controller's text.
ALARM_TEXTS: Mapping[int, str] = dict(data_table("zapi_alarms")["codes"])


def alarm_text(code: int) -> str:
    """The text of ZAPI alarm ``code`` (``"ALARM 99"`` for a code the documents do not name;
    ``""`` for 0, no alarm)."""
    if code == 0:
        return ""
    return ALARM_TEXTS.get(code, f"ALARM {code}")


class ZapiControl(enum.IntFlag):
    """The controlword bits (RPDO1 bytes 2-3: bit n of byte 2 is bit n, of byte 3 bit 8+n)."""

    A16_MAIN_CONTACTOR = 1 << 1
    A18_OUTPUT = 1 << 2
    ENABLE = 1 << 3
    FAULT_ACKNOWLEDGE = 1 << 4
    A18_POWER_ON = 1 << 5
    CLOCKWISE = 1 << 6
    COUNTER_CLOCKWISE = 1 << 7
    PUMP_MOTOR = 1 << 8
    SAFETY_OUTPUT = 1 << 9
    BRAKE_TYPE_0 = 1 << 11
    BRAKE_TYPE_1 = 1 << 12
    HANDSHAKE = 1 << 15


class ZapiStatus(enum.IntFlag):
    """The statusword bits (TPDO1 bytes 2-3)."""

    A16_MAIN_CONTACTOR = 1 << 1
    A18_OUTPUT = 1 << 2
    ENABLED = 1 << 3
    A19_OUTPUT = 1 << 4
    INPUT_0 = 1 << 8
    INPUT_1 = 1 << 9
    INPUT_2 = 1 << 10
    EMERGENCY_STOP = 1 << 11
    IDLE = 1 << 14
    HANDSHAKE = 1 << 15


_C = ZapiControl
_DIRECTION = _C.CLOCKWISE | _C.COUNTER_CLOCKWISE
_RUN = _C.A16_MAIN_CONTACTOR | _C.ENABLE


@dataclass(frozen=True)
class ZapiObjects:
    """The object indexes (sub-index 0) of the inverter's process values."""

    speed_setpoint: int = 0x2200
    controlword: int = 0x2201
    ramp: int = 0x2204
    actual_speed: int = 0x2100
    statusword: int = 0x2101
    alarm: int = 0x2110


class ZapiError(CobusError):
    """The ZAPI adapter cannot run the node as asked (the text says what to fix)."""


@dataclass(frozen=True)
class ZapiEvent:
    """Something the adapter saw, at ``time`` on the network's clock."""

    node_id: int
    time: float


@dataclass(frozen=True)
class HandshakeLost(ZapiEvent):
    """No TPDO1 for ``silence`` seconds while the handshake ran: the inverter stopped its
    side (an alarm, a dropped node, a lost SYNC)."""

    silence: float

    def __str__(self) -> str:
        return f"node {self.node_id}: handshake lost (no TPDO1 for {self.silence * 1000:.0f} ms)"


@dataclass(frozen=True)
class HandshakeRestored(ZapiEvent):
    """TPDO1 came again after a :class:`HandshakeLost`."""

    def __str__(self) -> str:
        return f"node {self.node_id}: handshake running again"


@dataclass(frozen=True)
class AlarmChanged(ZapiEvent):
    """The alarm byte changed: ``code`` (0: cleared) with its ``text``; ``previous``."""

    code: int
    previous: int

    @property
    def text(self) -> str:
        """The controller's text of the new code."""
        return alarm_text(self.code)

    def __str__(self) -> str:
        if self.code == 0:
            return f"node {self.node_id}: alarm {self.previous} {alarm_text(self.previous)} cleared"
        return f"node {self.node_id}: alarm {self.code} {self.text}"


@dataclass(frozen=True)
class FeedbackMismatch(ZapiEvent):
    """A commanded output was not reported back for ``cycles`` cycles (the thesis's check:
    A16 commanded but not in the statusword is an alarm of the application)."""

    output: str
    cycles: int

    def __str__(self) -> str:
        return (
            f"node {self.node_id}: {self.output} commanded but not reported back for "
            f"{self.cycles} cycles"
        )


#: The outputs the feedback check watches, by name.
FEEDBACK_OUTPUTS = ("A16 main contactor", "A18 output", "enable")


@dataclass(frozen=True)
class FeedbackRestored(ZapiEvent):
    """An output of a :class:`FeedbackMismatch` is reported as commanded again (or is no
    longer commanded)."""

    output: str

    def __str__(self) -> str:
        return f"node {self.node_id}: {self.output} feedback matches again"


#: The commanded outputs the statusword reports back, checked each cycle.
_FEEDBACK: tuple[tuple[ZapiControl, ZapiStatus, str], ...] = (
    (_C.A16_MAIN_CONTACTOR, ZapiStatus.A16_MAIN_CONTACTOR, "A16 main contactor"),
    (_C.A18_OUTPUT, ZapiStatus.A18_OUTPUT, "A18 output"),
    (_C.ENABLE, ZapiStatus.ENABLED, "enable"),
)


class AsyncZapiDrive:
    """A ZAPI ACE2 on a node the master manages (see the module docstring):
    ``AsyncZapiDrive(master, "zapi")``.

    ``objects``: the indexes of the process values; ``watchdog``: seconds without TPDO1,
    while the handshake runs, before :class:`HandshakeLost` (default three SYNC periods, at
    least 50 ms); ``feedback_cycles``: cycles a commanded output may stay unreported before
    :class:`FeedbackMismatch`.
    """

    #: The node-ID of the inverter.
    node_id: int
    #: The indexes of the process values.
    objects: ZapiObjects
    #: Seconds without TPDO1 before :class:`HandshakeLost`.
    watchdog: float
    #: Cycles a commanded output may stay unreported before :class:`FeedbackMismatch`.
    feedback_cycles: int
    #: Whether each TPDO1 is answered (False breaks the handshake, e.g. to test the
    #: inverter's reaction).
    answering: bool
    #: TPDO1 cycles answered.
    cycles: int
    #: The steepest ramp RPDO1 can carry (Hz/s; 25.5 in one byte, 6553.5 in two).
    max_ramp: float

    def __init__(
        self,
        master: Any,
        node: int | str = "zapi",
        *,
        objects: ZapiObjects | None = None,
        watchdog: float | None = None,
        feedback_cycles: int = 5,
    ) -> None:
        if not callable(getattr(master, "node", None)) or not hasattr(master, "image"):
            raise TypeError(
                f"AsyncZapiDrive runs on a node the master manages: AsyncZapiDrive(master, "
                f"'zapi'), not on {type(master).__name__}"
            )
        port = port_for(master.node(node))
        assert isinstance(port, ManagedNodePort)
        try:
            self._setup(master, port, objects, watchdog, feedback_cycles)
        except BaseException:
            port.close()  # no listener left behind on the master
            raise

    def _setup(
        self,
        master: Any,
        port: ManagedNodePort,
        objects: ZapiObjects | None,
        watchdog: float | None,
        feedback_cycles: int,
    ) -> None:
        self._port = port
        self._master = master
        self.node_id = port.node_id
        self.objects = objects or ZapiObjects()
        obj = self.objects
        image = master.image
        for index, table, what in (
            (obj.speed_setpoint, image.outputs_by_name, "RPDO"),
            (obj.controlword, image.outputs_by_name, "RPDO"),
            (obj.statusword, image.inputs_by_name, "TPDO"),
            (obj.actual_speed, image.inputs_by_name, "TPDO"),
        ):
            sig = port._signal(table, index, 0)
            if sig is None:
                raise ZapiError(
                    f"node {self.node_id}: no {what} of the network file maps 0x{index:04X} "
                    f"(the ZAPI's RPDO1 carries set-point 0x{obj.speed_setpoint:04X} and "
                    f"controlword 0x{obj.controlword:04X}, TPDO1 actual speed "
                    f"0x{obj.actual_speed:04X} and statusword 0x{obj.statusword:04X}; map them "
                    "or give ZapiObjects(...) with the indexes your EDS uses)"
                )
            if what == "TPDO" and index == obj.statusword:
                self._tpdo1 = sig.pdo
        ramp = port._signal(image.outputs_by_name, obj.ramp, 0)
        self._has_ramp = ramp is not None
        self.max_ramp = (2**ramp.bits - 1) / 10 if ramp is not None else 0.0
        self._has_alarm = port._signal(image.inputs_by_name, obj.alarm, 0) is not None
        sync = master.config.master.sync_period
        self.watchdog = watchdog if watchdog is not None else max(3 * sync, 0.05)
        self.feedback_cycles = feedback_cycles
        self.answering = True
        self.cycles = 0
        self._command = _C(0)
        self._speed = 0.0
        self._ramp: float | None = None
        self._alarm = 0
        self._running = False
        self._lost = False
        self._closed = False
        self._misses: dict[str, int] = {}
        self._watchdog: asyncio.TimerHandle | None = None
        self._listeners: Callbacks[ZapiEvent] = Callbacks(port.network, f"ZAPI node {self.node_id}")
        self._waiters: list[tuple[Callable[[], bool], asyncio.Future[None]]] = []
        port.add_input_callback(self._on_tpdo)

    def __repr__(self) -> str:
        return (
            f"<ZapiDrive node {self.node_id}: {self.speed:g} Hz, command {self._command!r}, "
            f"alarm {self.alarm or 'none'}>"
        )

    # ------------------------------------------------------------------ what it reports
    def _input(self, index: int) -> int:
        got = self._port.input(index, 0)
        return int(got[0]) if got is not None else 0

    @property
    def speed(self) -> float:
        """The actual speed in Hz (TPDO1; clockwise positive)."""
        return self._input(self.objects.actual_speed) / 100

    @property
    def status(self) -> ZapiStatus:
        """The last statusword, decoded."""
        return ZapiStatus(self._input(self.objects.statusword))

    @property
    def alarm(self) -> int:
        """The alarm code TPDO2 reports (0: none; 0 too when TPDO2 is not mapped)."""
        return self._alarm

    @property
    def alarm_text(self) -> str:
        """The text of :attr:`alarm` (empty when none)."""
        return alarm_text(self._alarm)

    @property
    def handshake_running(self) -> bool:
        """Whether TPDO1 comes and is answered (not lost, not stopped on purpose)."""
        return self._running and not self._lost and self.answering

    @property
    def command(self) -> ZapiControl:
        """The controlword bits commanded (without the handshake toggle)."""
        return self._command

    @property
    def setpoint(self) -> float:
        """The commanded speed in Hz (signed: clockwise positive)."""
        return self._speed

    # ------------------------------------------------------------------ commands
    def run(self, speed: float, ramp: float | None = None) -> None:
        """Run at ``speed`` Hz, clockwise when positive, counter-clockwise when negative:
        main contactor A16, enable and the direction bit; ``ramp`` in Hz/s (None keeps the
        last, 0 the inverter's default). Sent with this cycle's answer."""
        if not -327.67 <= speed <= 327.67:
            raise ValueError(f"speed {speed} Hz: RPDO1 carries at most 327.67 Hz (x 100)")
        if ramp is not None:
            if not self._has_ramp:
                raise ValueError(
                    f"ramp {ramp} Hz/s: RPDO1 of the network file does not map the ramp "
                    f"0x{self.objects.ramp:04X}"
                )
            if not 0 <= ramp <= self.max_ramp:
                raise ValueError(
                    f"ramp {ramp} Hz/s: RPDO1 carries 0..{self.max_ramp:g} Hz/s (x 10; 0 is "
                    "the inverter's default ramp)"
                )
            self._ramp = ramp
        direction = _C.CLOCKWISE if speed >= 0 else _C.COUNTER_CLOCKWISE
        self._speed = float(speed)
        self._command = (self._command & ~(_DIRECTION | _C.FAULT_ACKNOWLEDGE)) | _RUN | direction
        self._send(always=False)

    def stop(self) -> None:
        """Set-point 0 (the inverter ramps down), contactor and enable held."""
        self._speed = 0.0
        self._command &= ~_DIRECTION
        self._send(always=False)

    def release(self) -> None:
        """Everything off: no direction, power stage disabled, main contactor open."""
        self._speed = 0.0
        self._command = _C(0)
        self._send(always=False)

    def set_output(self, bit: ZapiControl | str, on: bool = True) -> None:
        """Switch a controlword bit by name (``set_output("A18_OUTPUT")``, ``"PUMP_MOTOR"``);
        the handshake bit is the adapter's."""
        flag = ZapiControl[bit.upper()] if isinstance(bit, str) else ZapiControl(bit)
        if flag & _C.HANDSHAKE:
            raise ValueError("the handshake bit is kept by the adapter every cycle")
        self._command = self._command | flag if on else self._command & ~flag
        self._send(always=False)

    async def acknowledge(self, timeout: float = 2.0) -> None:
        """Clear the alarm: the run bits released, NMT start again through the master, then -
        once TPDO1 comes and a cycle was answered without it - fault acknowledge (2.4, which
        acts on its rising edge) until the alarm byte reads 0. The motor stays off: call
        :meth:`run` again. :class:`ZapiError` when the alarm stays (its cause is still there)
        or TPDO1 does not come; the acknowledge bit is then released, so that the next try
        makes an edge again."""
        self._speed = 0.0
        self._command = _C(0)
        self._send(always=True)
        await self._master.restart_node(self.node_id)
        since = self.cycles
        try:
            try:
                await self._wait(lambda: self.cycles > since, timeout)
            except TimeoutError:
                raise ZapiError(
                    f"node {self.node_id}: no TPDO1 within {timeout:g} s after the restart"
                ) from None
            self._command = _C.FAULT_ACKNOWLEDGE
            self._send(always=True)
            since = self.cycles
            try:
                await self._wait(lambda: self.cycles > since + 1 and self._alarm == 0, timeout)
            except TimeoutError:
                raise ZapiError(
                    f"node {self.node_id}: alarm {self._alarm} {self.alarm_text} still set after "
                    f"acknowledge and restart ({timeout:g} s); its cause is still there"
                    if self._alarm
                    else f"node {self.node_id}: TPDO1 stopped again after the restart"
                ) from None
        finally:
            self._command = _C(0)
            self._send(always=False)

    async def wait_for_speed(
        self, speed: float, tolerance: float = 0.2, timeout: float = 30.0
    ) -> None:
        """Wait until the actual speed TPDO1 reports is within ``tolerance`` Hz of ``speed``;
        :class:`ZapiError` if an alarm comes first or the handshake is lost (or not
        answered), a TimeoutError after ``timeout``."""

        def there() -> bool:
            if self._alarm:
                raise ZapiError(
                    f"node {self.node_id}: alarm {self._alarm} {self.alarm_text} while "
                    f"waiting for {speed:g} Hz"
                )
            if self._lost or not self.answering:
                why = "handshake lost (no TPDO1)" if self._lost else "answering is off"
                raise ZapiError(f"node {self.node_id}: {why} while waiting for {speed:g} Hz")
            # only a speed a TPDO1 brought counts (none before the first one)
            return self._running and abs(self.speed - speed) <= tolerance

        try:
            await self._wait(there, timeout)
        except TimeoutError:
            raise TimeoutError(
                f"node {self.node_id}: {speed:g} Hz not reached within {timeout:g} s "
                f"(at {self.speed:g} Hz)"
            ) from None

    # ------------------------------------------------------------------ events
    def add_listener(self, listener: Callable[[ZapiEvent], object]) -> None:
        """Call ``listener(event)`` for each :class:`HandshakeLost`,
        :class:`HandshakeRestored`, :class:`AlarmChanged` and :class:`FeedbackMismatch`."""
        self._listeners.add(listener)

    def remove_listener(self, listener: Callable[[ZapiEvent], object]) -> None:
        """Stop calling ``listener``."""
        self._listeners.remove(listener)

    def close(self) -> None:
        """Stop answering and watching the node (nothing of the adapter runs afterwards, no
        timer fires into a network closed after it)."""
        if self._closed:
            return
        self._closed = True
        self._port.remove_input_callback(self._on_tpdo)
        self._port.close()
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        for _test, future in self._waiters:
            if not future.done():
                future.set_exception(ZapiError(f"node {self.node_id}: the adapter was closed"))

    # ------------------------------------------------------------------ the cycle
    def _send(self, *, always: bool) -> None:
        """RPDO1 with the command, the set-point and the answer to the last toggle."""
        obj = self.objects
        toggle = self._input(obj.statusword) & ZapiStatus.HANDSHAKE
        word = int(self._command) | (0 if toggle else int(_C.HANDSHAKE))
        values = {
            (obj.speed_setpoint, 0): round(abs(self._speed) * 100),
            (obj.controlword, 0): word,
        }
        if self._has_ramp and self._ramp is not None:
            values[(obj.ramp, 0)] = round(self._ramp * 10)
        self._port.set_outputs(values, always=always)

    def _on_tpdo(self, number: int, now: float) -> None:
        if self._closed:
            return
        if self._has_alarm:
            code = self._input(self.objects.alarm)
            if code != self._alarm:
                previous, self._alarm = self._alarm, code
                self._listeners(AlarmChanged(self.node_id, now, code, previous))
        if number == self._tpdo1:
            self._cycle(now)
        self._wake()

    def _cycle(self, now: float) -> None:
        self._running = True
        if self._lost:
            self._lost = False
            self._listeners(HandshakeRestored(self.node_id, now))
        self._arm(now)
        if not self.answering:
            return
        self.cycles += 1
        self._send(always=True)  # an answer every cycle, changed or not
        status = self.status
        for commanded, reported, name in _FEEDBACK:
            if self._command & commanded and not status & reported and not self._alarm:
                misses = self._misses.get(name, 0) + 1
                self._misses[name] = misses
                if misses == self.feedback_cycles:
                    self._listeners(FeedbackMismatch(self.node_id, now, name, misses))
            else:
                if self._misses.get(name, 0) >= self.feedback_cycles:
                    self._listeners(FeedbackRestored(self.node_id, now, name))
                self._misses[name] = 0

    def _arm(self, now: float) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
        loop = self._port.network.loop
        self._watchdog = loop.call_at(now + self.watchdog, self._silent, now)

    def _silent(self, since: float) -> None:
        self._watchdog = None
        if self._closed or not self._port.network.connected:
            return  # (the network went away under a running adapter: nothing to watch)
        if self._running and not self._lost:
            self._lost = True
            now = self._port.network.time()
            self._listeners(HandshakeLost(self.node_id, now, now - since))
            self._wake()

    def _wake(self) -> None:
        for test, future in list(self._waiters):
            if future.done():
                continue
            try:
                if test():
                    future.set_result(None)
            except Exception as exc:
                future.set_exception(exc)

    async def _wait(self, test: Callable[[], bool], timeout: float) -> None:
        if isinstance(timeout, bool) or not isinstance(timeout, int | float) or not timeout > 0:
            raise ValueError(f"timeout must be a number of seconds above 0, not {timeout!r}")
        if test():
            return
        future: asyncio.Future[None] = self._port.network.loop.create_future()
        item = (test, future)
        self._waiters.append(item)
        try:
            await asyncio.wait_for(future, timeout)
        finally:
            self._waiters.remove(item)


class ZapiDrive(BlockingTwin, twin_of=AsyncZapiDrive):
    """The ZAPI ACE2 adapter for blocking code: ``ZapiDrive(master, "zapi")`` on a
    :class:`~cobus.master.BlockingMaster`, with the methods of :class:`AsyncZapiDrive`;
    listeners run in the network's callback thread (inline on the simulated clock)."""

    def __init__(self, master: Any, node: Any = "zapi", **options: Any) -> None:
        if isinstance(master, AsyncZapiDrive):  # a twin made for an async adapter
            super().__init__(master, node)
            return
        runner = getattr(master, "_runner", None)
        if runner is None:
            raise TypeError(
                "ZapiDrive takes a BlockingMaster and the node; in async code use "
                "AsyncZapiDrive(master, node)"
            )
        aio = runner.call(lambda: AsyncZapiDrive(master.aio, node, **options))
        super().__init__(aio, runner)
