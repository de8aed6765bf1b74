"""A CiA 402 drive run from the master side: ``await drive.enable()``, ``await
drive.move_to(1000)``, ``await drive.home()`` — each returns when the drive reports it done.

:class:`AsyncDrive402` runs on a bare :class:`~cobus.runtime.remote.AsyncRemoteNode` or on a node
the :class:`~cobus.master.Master` manages; :class:`Drive402` is its blocking twin. The
statusword comes from a TPDO where one maps it (a value that came after the last write and
is not older than ``max_age``), by SDO otherwise; the controlword and the set-points go
through the master's process image where an RPDO maps them and the master sends it, by SDO
otherwise (always on a bare node).
Objects are written as their CiA 402 data types, so no EDS is needed.

Positions, velocities and accelerations are in user units: ``scale`` drive increments per
user unit (``Drive402(node, scale=4096, unit="rev")``); torques in per mille of the rated
torque.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from cobus.errors import CobusError
from cobus.od import DataType, decode, encode
from cobus.profiles._port import DrivePort, port_for
from cobus.profiles.cia402 import (
    CW_CHANGE_IMMEDIATELY,
    CW_FAULT_RESET,
    CW_HALT,
    CW_NEW_SETPOINT,
    CW_RELATIVE,
    SW_BIT12,
    SW_BIT13,
    SW_TARGET_REACHED,
    Command,
    OperationMode,
    PowerState,
    Statusword,
    command_towards,
    error_text,
)
from cobus.profiles.trajectory import Trajectory
from cobus.proto import Frame
from cobus.proto.sdo import SdoAbortedError
from cobus.runtime.twin import BlockingTwin

__all__ = [
    "AsyncDrive402",
    "Drive402",
    "DriveError",
    "DriveFault",
    "DriveStateError",
    "DriveTimeoutError",
    "HomingError",
    "Quirks",
]

_D = DataType
#: The CiA 402 objects (sub-index 0 unless keyed with one), with their data types.
_TYPES: dict[int | tuple[int, int], DataType] = {
    0x6007: _D.INTEGER16,
    0x603F: _D.UNSIGNED16,
    0x6040: _D.UNSIGNED16,
    0x6041: _D.UNSIGNED16,
    0x605A: _D.INTEGER16,
    0x605B: _D.INTEGER16,
    0x605C: _D.INTEGER16,
    0x605D: _D.INTEGER16,
    0x605E: _D.INTEGER16,
    0x6060: _D.INTEGER8,
    0x6061: _D.INTEGER8,
    0x6062: _D.INTEGER32,
    0x6063: _D.INTEGER32,
    0x6064: _D.INTEGER32,
    0x6065: _D.UNSIGNED32,
    0x6066: _D.UNSIGNED16,
    0x6067: _D.UNSIGNED32,
    0x6068: _D.UNSIGNED16,
    0x606B: _D.INTEGER32,
    0x606C: _D.INTEGER32,
    0x606D: _D.UNSIGNED16,
    0x606E: _D.UNSIGNED16,
    0x606F: _D.UNSIGNED16,
    0x6070: _D.UNSIGNED16,
    0x6071: _D.INTEGER16,
    0x6072: _D.UNSIGNED16,
    0x6073: _D.UNSIGNED16,
    0x6074: _D.INTEGER16,
    0x6075: _D.UNSIGNED32,
    0x6076: _D.UNSIGNED32,
    0x6077: _D.INTEGER16,
    0x6078: _D.INTEGER16,
    0x607A: _D.INTEGER32,
    0x607C: _D.INTEGER32,
    (0x607D, 0): _D.UNSIGNED8,
    0x607D: _D.INTEGER32,
    0x607E: _D.UNSIGNED8,
    0x607F: _D.UNSIGNED32,
    0x6080: _D.UNSIGNED32,
    0x6081: _D.UNSIGNED32,
    0x6083: _D.UNSIGNED32,
    0x6084: _D.UNSIGNED32,
    0x6085: _D.UNSIGNED32,
    0x6086: _D.INTEGER16,
    0x6087: _D.UNSIGNED32,
    0x6098: _D.INTEGER8,
    (0x6099, 0): _D.UNSIGNED8,
    0x6099: _D.UNSIGNED32,
    0x609A: _D.UNSIGNED32,
    0x60C0: _D.INTEGER16,
    (0x60C1, 0): _D.UNSIGNED8,
    (0x60C1, 1): _D.INTEGER32,
    (0x60C2, 0): _D.UNSIGNED8,
    (0x60C2, 1): _D.UNSIGNED8,
    (0x60C2, 2): _D.INTEGER8,
    (0x60E3, 0): _D.UNSIGNED8,
    0x60E3: _D.INTEGER8,
    0x60F4: _D.INTEGER32,
    0x60FD: _D.UNSIGNED32,
    0x60FF: _D.INTEGER32,
    0x6502: _D.UNSIGNED32,
}
_I32 = (-(2**31), 2**31 - 1)
_MODE_NAMES = ", ".join(f"{m.value} {m.name}" for m in OperationMode)


def _number(what: str, value: Any) -> float:
    """A finite real number, or a ValueError/TypeError that names ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{what} must be a number, not {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, not {value!r}")
    return float(value)


def _seconds(what: str, value: Any) -> float:
    seconds = _number(what, value)
    if seconds <= 0:
        raise ValueError(f"{what} must be above 0 s, not {value!r}")
    return seconds


def _integer(what: str, value: Any, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{what} must be an integer, not {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{what} {value} is outside {low}..{high}")
    return value


def _left(state: PowerState, status: Statusword) -> bool:
    return status.state is not state


class DriveError(CobusError):
    """A drive did not do what it was asked (the subclasses say why)."""


class DriveStateError(DriveError):
    """The drive is not in a state the operation needs (e.g. a move while not enabled)."""


class DriveTimeoutError(DriveError, TimeoutError):
    """A transition or a move did not happen in time; the text names it and the statusword
    the drive was left with."""


class DriveFault(DriveError):
    """The drive is in FAULT (or reacting to one): the 603Fh ``code`` with its ``text``, the
    last ``emergency`` the node sent, the decoded ``statusword`` and the ``state``."""

    def __init__(
        self,
        node_id: int,
        code: int | None,
        statusword: Statusword,
        emergency: Any = None,
        doing: str = "",
    ) -> None:
        self.node_id = node_id
        self.code = code
        self.text = error_text(code) if code else "no error code in 603Fh"
        self.statusword = statusword
        self.state = statusword.state
        self.emergency = emergency
        where = f" while {doing}" if doing else ""
        shown = f"0x{code:04X} {self.text}" if code else self.text
        last = f"; last EMCY: {emergency}" if emergency is not None else ""
        super().__init__(
            f"drive {node_id} faulted{where}: {shown}{last}; statusword {statusword}; "
            "fault_reset() clears it once the cause is gone"
        )


class HomingError(DriveError):
    """The drive reported a homing error (statusword bit 13 in homing mode)."""


@dataclass
class Quirks:
    """What real drives need beyond CiA 402, per drive.

    ``halt_during_mode_change``: set Halt while 6060h changes and clear it afterwards (drives
    that refuse a mode change while moving). ``mode_change_state``: the power state to switch
    modes in (e.g. SWITCHED_ON for drives that accept 6060h only with the power stage off);
    None changes the mode in any state. ``fault_reset_pulse``: how long bit 7 is held high.
    ``clear_halt``: clear Halt before a move or a mode change (a Halt left over from a stop
    blocks every move, and some drives refuse a mode change while it is set).
    """

    halt_during_mode_change: bool = False
    mode_change_state: PowerState | None = None
    fault_reset_pulse: float = 0.01
    clear_halt: bool = True


class AsyncDrive402:
    """A CiA 402 drive on ``node`` (see the module docstring).

    ``scale``: drive increments per user unit of position (velocities per second,
    accelerations per second squared); ``unit``: the unit's name, for messages. ``poll``:
    seconds between statusword reads while waiting (a TPDO that carries it wakes the wait
    sooner; its value is used when it came after the last write and is at most ``max_age``
    seconds old). ``timeout``: the default time for a state transition or a mode change.
    """

    #: The node-ID of the drive.
    node_id: int
    #: Drive increments per user unit.
    scale: float
    #: The user unit's name.
    unit: str
    #: Seconds between statusword reads while waiting.
    poll: float
    #: The oldest TPDO value (seconds) taken instead of an SDO read; only values that came
    #: after the last write count.
    max_age: float
    #: Seconds a state transition or a mode change may take.
    timeout: float
    #: The drive's deviations from CiA 402.
    quirks: Quirks

    def __init__(
        self,
        node: Any,
        *,
        scale: float = 1.0,
        unit: str = "inc",
        poll: float = 0.005,
        max_age: float = 0.05,
        timeout: float = 2.0,
        quirks: Quirks | None = None,
    ) -> None:
        if not _number("scale", scale):
            raise ValueError("scale: drive increments per user unit, not 0")
        poll, max_age = _seconds("poll", poll), _seconds("max_age", max_age)
        timeout = _seconds("timeout", timeout)
        self._port: DrivePort = port_for(node)
        self.node_id = self._port.node_id
        self.scale = float(scale)
        self.unit = unit
        self.poll = poll
        self.timeout = timeout
        self.max_age = max_age
        self._written_at = -math.inf
        self.quirks = quirks or Quirks()
        self._cw = 0
        self._sw = 0
        self._mode: int | None = None
        self._supported: int | None = None
        self._homing_methods: list[int] | None = None
        self._updated = asyncio.Event()
        self._jog_timer: asyncio.TimerHandle | None = None
        self._halt_task: asyncio.Future[None] | None = None
        self._jog_deadman = 0.0
        #: Why the last jog ended ("" while one runs or none ran): "stopped", or "dead-man:
        #: no keep_jogging() for 0.2 s".
        self.jog_ended = ""
        self._port.add_input_callback(self._on_input)

    def __repr__(self) -> str:
        return f"<Drive402 node {self.node_id}: {self.status}>"

    # ------------------------------------------------------------------ the objects
    def _type(self, index: int, subindex: int) -> DataType:
        dt = _TYPES.get((index, subindex)) or _TYPES.get(index)
        if dt is not None:
            return dt
        od = self._port.od
        var = od.get_variable(index, subindex) if od is not None else None
        if var is None:
            raise ValueError(
                f"0x{index:04X}:{subindex:02X} is not a CiA 402 object whose type cobus "
                "knows: give the node its EDS (net.add_remote(node_id, 'drive.eds')) or use "
                "node.sdo for manufacturer objects"
            )
        return var.data_type

    async def read(self, index: int, subindex: int = 0) -> Any:
        """Read an object by SDO, decoded as its data type (CiA 402's, else the EDS's)."""
        dt = self._type(index, subindex)
        data = await self._port.upload(index, subindex)
        return decode(dt, data[: dt.size or len(data)])

    async def write(self, index: int, subindex: int, value: int) -> None:
        """Write an object: into its RPDO where the master maps it, else by SDO."""
        data = encode(self._type(index, subindex), value)  # checks type and range first
        # always=True: a command goes out even when the image already holds the value (a
        # drive that was reset or power-cycled meanwhile has not seen it)
        if not self._port.set_outputs({(index, subindex): value}, always=True):
            await self._port.download(index, subindex, data)  # (also while no RPDO goes)
        elif not await self._port.settle(self.timeout):
            raise DriveTimeoutError(
                f"drive {self.node_id}: 0x{index:04X} waits in a synchronous RPDO, but no "
                f"SYNC came within {self.timeout:g} s"
            )
        self._written_at = self._port.network.time()

    def _fresh(self, index: int) -> Any:
        got = self._port.input(index, 0)
        if got is None:
            return None
        value, when = got
        if when <= self._written_at or self._port.network.time() - when > self.max_age:
            return None
        return value

    async def read_fresh(self, index: int, subindex: int = 0, max_age: float | None = None) -> Any:
        """An object's value: the newest TPDO value where a TPDO maps it and one came within
        ``max_age`` seconds (this drive's ``max_age`` by default), else read by SDO."""
        got = self._port.input(index, subindex)
        age = self.max_age if max_age is None else max_age
        if got is not None and self._port.network.time() - got[1] <= age:
            return got[0]
        return await self.read(index, subindex)

    def _on_input(self, number: int, now: float) -> None:
        self._updated.set()

    async def read_statusword(self) -> Statusword:
        """The statusword now: the newest TPDO value when one is fresh, else read by SDO."""
        value = self._fresh(0x6041)
        self._sw = int(value if value is not None else await self.read(0x6041))
        return self.status

    @property
    def statusword(self) -> int:
        """The statusword as last read or received."""
        return self._sw

    @property
    def status(self) -> Statusword:
        """The last statusword, decoded (state and flags named for the mode)."""
        return Statusword(self._sw, self._mode or 0)

    @property
    def state(self) -> PowerState:
        """The power state of the last statusword."""
        return PowerState.from_statusword(self._sw)

    @property
    def controlword(self) -> int:
        """The controlword as last sent."""
        return self._cw

    async def _send_cw(self, cw: int) -> None:
        self._cw = cw & 0xFFFF
        await self.write(0x6040, 0, self._cw)

    async def _fault(self, doing: str) -> DriveFault:
        try:
            code: int | None = int(await self.read(0x603F))
        except SdoAbortedError:
            code = None  # the drive has no 603Fh
        return DriveFault(self.node_id, code, self.status, self._port.last_emergency(), doing)

    async def _wait(
        self,
        done: Callable[[Statusword], bool],
        timeout: float,
        what: str,
        *,
        fault_ok: bool = False,
        progress: Callable[[Statusword], object] | None = None,
        check: Callable[[Statusword], Awaitable[None]] | None = None,
    ) -> Statusword:
        """Read the statusword until ``done`` accepts it; DriveFault if the drive faults,
        DriveTimeoutError naming ``what`` after ``timeout`` seconds; ``check`` may end the
        wait with its own error."""
        loop = self._port.network
        deadline = loop.time() + _seconds("timeout", timeout)
        while True:
            status = await self.read_statusword()
            if not fault_ok and status.state in (
                PowerState.FAULT,
                PowerState.FAULT_REACTION_ACTIVE,
            ):
                raise await self._fault(what)
            if done(status):
                return status
            if progress is not None:
                progress(status)
            if check is not None:
                await check(status)
            left = deadline - loop.time()
            if left <= 1e-6:  # (a timer shorter than the clock's resolution would not fire)
                raise DriveTimeoutError(
                    f"drive {self.node_id}: {what} did not happen within {timeout:g} s; "
                    f"statusword {status}"
                )
            self._updated.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._updated.wait(), min(self.poll, left))

    # ------------------------------------------------------------------ the state machine
    async def set_state(self, target: PowerState | str, timeout: float | None = None) -> None:
        """Take the drive to ``target`` (OPERATION_ENABLED, SWITCHED_ON, READY_TO_SWITCH_ON or
        SWITCH_ON_DISABLED) one transition at a time, each within ``timeout`` (default
        :attr:`timeout`). A drive in FAULT raises :class:`DriveFault` (call
        :meth:`fault_reset` first); a transition that does not happen raises
        :class:`DriveTimeoutError` naming it."""
        if isinstance(target, PowerState):
            goal = target
        else:
            try:
                goal = PowerState[str(target).upper().replace(" ", "_")]
            except KeyError:
                raise ValueError(
                    f"state {target!r}: the states are " + ", ".join(s.name for s in PowerState)
                ) from None
        limit = self.timeout if timeout is None else _seconds("timeout", timeout)
        status = await self.read_statusword()
        for _step in range(8):
            state = status.state
            if state is goal:
                return
            if state in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE):
                raise await self._fault(f"going to {goal.name}")
            command = command_towards(state, goal)
            if command is None:  # not ready to switch on: the drive leaves it by itself
                status = await self._wait(
                    functools.partial(_left, state),
                    limit,
                    f"leaving {state.name} (the drive's own initialisation)",
                )
                continue
            await self._send_cw((self._cw & ~Command.mask()) | command)
            name = command.name
            if command == Command.DISABLE_OPERATION and state is PowerState.OPERATION_ENABLED:
                name = "DISABLE_OPERATION"  # the same bits as SWITCH_ON
            status = await self._wait(
                functools.partial(_left, state),
                limit,
                f"{state.name} -> {goal.name} by {name} (controlword 0x{self._cw:04X})",
            )
        raise DriveStateError(
            f"drive {self.node_id} did not settle in {goal.name}: it is {status.state.name}"
        )

    async def enable(self, timeout: float | None = None) -> None:
        """Shutdown -> switch on -> enable operation: the drive holds its position (or its
        mode's set-point) with the power stage on. A drive in FAULT raises
        :class:`DriveFault`; reset it with :meth:`fault_reset` first."""
        await self.set_state(PowerState.OPERATION_ENABLED, timeout)

    async def disable(self, timeout: float | None = None) -> None:
        """Switch the power stage off (disable voltage: SWITCH_ON_DISABLED); the motor
        coasts unless the drive has a brake."""
        await self.set_state(PowerState.SWITCH_ON_DISABLED, timeout)

    async def quick_stop(self, timeout: float | None = None) -> None:
        """Stop with the quick stop deceleration (the drive's 605Ah option) and return once it
        stands: in SWITCH_ON_DISABLED, or in QUICK_STOP_ACTIVE with target reached."""
        await self._send_cw((self._cw & ~Command.mask()) | Command.QUICK_STOP)
        await self._wait(
            lambda s: (
                s.state is PowerState.SWITCH_ON_DISABLED
                or (s.state is PowerState.QUICK_STOP_ACTIVE and s.target_reached)
            ),
            self.timeout if timeout is None else timeout,
            "quick stop",
        )

    async def fault_reset(self, timeout: float | None = None) -> None:
        """Clear a fault (a rising edge of controlword bit 7, held ``quirks.fault_reset_pulse``
        seconds) and wait for SWITCH_ON_DISABLED; :class:`DriveFault` when the fault stays
        (its cause is still there). Does nothing to a drive that is not faulted."""
        status = await self.read_statusword()
        limit = self.timeout if timeout is None else timeout
        if status.state is PowerState.FAULT_REACTION_ACTIVE:
            status = await self._wait(
                lambda s: s.state is not PowerState.FAULT_REACTION_ACTIVE,
                limit,
                "the end of the fault reaction",
                fault_ok=True,
            )
        if status.state is not PowerState.FAULT:
            return
        base = self._cw & ~(Command.mask() | CW_NEW_SETPOINT)
        await self._send_cw(base)
        await self._send_cw(base | CW_FAULT_RESET)
        await asyncio.sleep(self.quirks.fault_reset_pulse)
        await self._send_cw(base)
        try:
            await self._wait(
                lambda s: s.state is not PowerState.FAULT,
                limit,
                "FAULT -> SWITCH_ON_DISABLED",
                fault_ok=True,
            )
        except DriveTimeoutError:
            raise await self._fault("resetting the fault (its cause is still there?)") from None

    # ------------------------------------------------------------------ modes
    async def supported_modes(self) -> list[OperationMode]:
        """The modes 6502h lists (every mode when the drive has no 6502h)."""
        if self._supported is None:
            try:
                self._supported = int(await self.read(0x6502))
            except SdoAbortedError:
                self._supported = 0xFFFFFFFF
        return [m for m in OperationMode if m.supported_bit & self._supported]

    async def set_mode(self, mode: OperationMode | int | str, timeout: float | None = None) -> None:
        """Switch to ``mode`` and wait until 6061h shows it. A mode 6502h does not list
        raises :class:`DriveStateError` at once; the quirks apply (halt during the change,
        the state to change in)."""
        try:
            if isinstance(mode, bool):
                raise ValueError
            wanted = OperationMode[mode.upper()] if isinstance(mode, str) else OperationMode(mode)
        except (KeyError, ValueError, AttributeError):
            raise ValueError(f"mode {mode!r}: the modes are {_MODE_NAMES}") from None
        limit = self.timeout if timeout is None else _seconds("timeout", timeout)
        if await self.read_mode() == wanted:  # the drive's own word: a reset changes it
            return
        if wanted not in await self.supported_modes():
            modes = ", ".join(m.name for m in await self.supported_modes())
            raise DriveStateError(
                f"drive {self.node_id} does not support {wanted.name} (6502h lists: {modes})"
            )
        quirks = self.quirks
        back_to: PowerState | None = None
        if quirks.mode_change_state is not None:
            before = (await self.read_statusword()).state
            await self.set_state(quirks.mode_change_state, timeout)
            if before is PowerState.OPERATION_ENABLED:
                back_to = before
        if quirks.halt_during_mode_change:
            await self._send_cw(self._cw | CW_HALT)
        elif quirks.clear_halt and self._cw & CW_HALT:
            await self._send_cw(self._cw & ~CW_HALT)  # drives that refuse a change halted
        await self.write(0x6060, 0, int(wanted))
        deadline = self._port.network.time() + limit
        while True:
            shown = int(await self.read(0x6061))
            if shown == wanted:
                break
            if self._port.network.time() >= deadline:
                raise DriveTimeoutError(
                    f"drive {self.node_id}: mode {wanted.name} written to 6060h, but 6061h "
                    f"still shows {shown} after {limit:g} s"
                )
            await asyncio.sleep(self.poll)
        self._mode = wanted
        if quirks.halt_during_mode_change:
            await self._send_cw(self._cw & ~CW_HALT)
        if back_to is not None:
            await self.set_state(back_to, timeout)

    async def _enter(self, mode: OperationMode, switch: bool, doing: str) -> None:
        """Be in ``mode``: switched to it (``switch``), or checked to be in it."""
        if switch:
            await self.set_mode(mode)
            return
        shown = await self.read_mode()
        if shown != mode:
            raise DriveStateError(
                f"drive {self.node_id} cannot {doing}: 6061h shows mode "
                f"{getattr(shown, 'name', shown)}, not {mode.name}, and the mode is not to be "
                "changed here (6060h is not written)"
            )

    async def read_mode(self) -> OperationMode | int:
        """The mode 6061h shows now."""
        shown = int(await self.read(0x6061))
        self._mode = shown
        try:
            return OperationMode(shown)
        except ValueError:
            return shown  # a manufacturer's mode (negative values)

    def _require_enabled(self, doing: str) -> None:
        if self.state is not PowerState.OPERATION_ENABLED:
            raise DriveStateError(
                f"drive {self.node_id} cannot {doing}: it is {self.state.name}, not "
                "OPERATION_ENABLED (call enable() first)"
            )

    def _inc(self, what: str, value: Any, *, positive: bool = False) -> int:
        """``value`` user units as drive increments, checked: a finite number, in INTEGER32,
        above 0 (``positive``) also after the scaling."""
        number = _number(what, value)
        inc = round(number * self.scale)
        if not _I32[0] <= inc <= _I32[1]:
            raise ValueError(
                f"{what} {value:g} {self.unit} is {inc} increments, beyond INTEGER32 (scale "
                f"{self.scale:g} increments per {self.unit})"
            )
        if positive and inc <= 0:
            raise ValueError(
                f"{what} {value:g} {self.unit} is {inc} increments at scale {self.scale:g}: "
                "it must be above 0"
            )
        return inc

    def _profile(
        self, velocity: float | None, acceleration: float | None, deceleration: float | None
    ) -> list[tuple[int, int]]:
        """The profile objects to write, checked before anything is sent."""
        out = []
        for index, what, value in (
            (0x6081, "velocity", velocity),
            (0x6083, "acceleration", acceleration),
            (0x6084, "deceleration", deceleration),
        ):
            if value is not None:
                out.append((index, self._inc(what, value, positive=True)))
        return out

    # ------------------------------------------------------------------ profile position
    async def move_to(
        self,
        position: float,
        velocity: float | None = None,
        acceleration: float | None = None,
        deceleration: float | None = None,
        *,
        relative: bool = False,
        immediate: bool = True,
        wait: bool = True,
        timeout: float = 60.0,
        progress: Callable[[Statusword], object] | None = None,
        switch_mode: bool = True,
    ) -> None:
        """Move to ``position`` (user units) in profile position mode, with the profile
        ``velocity``, ``acceleration`` and ``deceleration`` when given (else the drive's).

        The set-point handshake: new set-point (bit 4) -> set-point acknowledge (bit 12) ->
        bit 4 cleared. ``immediate=False`` queues it behind the move in progress (the drive
        buffers one set-point; the call waits for room). ``wait=False`` returns once the
        drive took the set-point; :meth:`wait_for_target` waits for the end. ``progress`` is
        called with each statusword read while waiting, on the event loop (in blocking code
        too: it must not call the drive's blocking methods). ``switch_mode=False``: never
        write the mode 6060h - :class:`DriveStateError` when 6061h shows another mode."""
        target = self._inc("position", position)
        profile = self._profile(velocity, acceleration, deceleration)
        _seconds("timeout", timeout)
        await self._enter(OperationMode.PROFILE_POSITION, switch_mode, "move")
        await self.read_statusword()
        self._require_enabled("move")
        for index, value in profile:
            await self.write(index, 0, value)
        await self.write(0x607A, 0, target)
        bits = (CW_RELATIVE if relative else 0) | (CW_CHANGE_IMMEDIATELY if immediate else 0)
        base = self._cw & ~(CW_NEW_SETPOINT | CW_RELATIVE | CW_CHANGE_IMMEDIATELY)
        if self.quirks.clear_halt:
            base &= ~CW_HALT
        what = f"the set-point {position:g} {self.unit}"
        if self._cw & CW_NEW_SETPOINT:
            await self._send_cw(base | bits)
        await self._wait(lambda s: not s.value & SW_BIT12, timeout, f"room for {what}")
        await self._send_cw(base | bits | CW_NEW_SETPOINT)
        await self._wait(lambda s: bool(s.value & SW_BIT12), self.timeout, f"acknowledge of {what}")
        await self._send_cw(base | bits)
        if wait:
            await self.wait_for_target(timeout, progress=progress, what=f"reaching {what}")

    async def move_by(
        self,
        distance: float,
        velocity: float | None = None,
        acceleration: float | None = None,
        deceleration: float | None = None,
        **options: Any,
    ) -> None:
        """Move ``distance`` user units from the previous target (relative profile
        position); the options are those of :meth:`move_to`."""
        await self.move_to(distance, velocity, acceleration, deceleration, relative=True, **options)

    async def wait_for_target(
        self,
        timeout: float = 60.0,
        *,
        progress: Callable[[Statusword], object] | None = None,
        what: str = "reaching the target",
    ) -> Statusword:
        """Wait for target reached (statusword bit 10) with no set-point pending (bit 12
        clear in profile position)."""
        pp = self._mode == OperationMode.PROFILE_POSITION
        stalled = [0]

        def reached(s: Statusword) -> bool:
            return s.target_reached and not (pp and s.value & SW_BIT12)

        async def at_a_limit(s: Statusword) -> None:
            """A drive stopped by a limit (a limit switch, bit 11) never reaches the target:
            say so at once rather than after the timeout."""
            if not s.internal_limit:
                stalled[0] = 0
                return
            if abs(await self.read_velocity() * self.scale) > 1:
                stalled[0] = 0
                return
            stalled[0] += 1
            if stalled[0] >= 3:
                raise DriveStateError(
                    f"drive {self.node_id} stopped at a limit at "
                    f"{await self.read_position():g} {self.unit} before {what}; "
                    f"statusword {s}"
                )

        return await self._wait(reached, timeout, what, progress=progress, check=at_a_limit)

    async def _read_window(self, index: int, fallback: int) -> int:
        try:
            return max(int(await self.read(index)), 1)
        except SdoAbortedError:
            return fallback

    async def _wait_velocity(
        self, target: int, window: int, timeout: float, what: str, *, reached: bool = True
    ) -> None:
        """Until the actual velocity 606Ch is within ``window`` increments/s of ``target``
        (and, with ``reached``, the statusword shows target reached): a statusword from
        before the command cannot end the wait, the measured velocity must agree."""
        loop = self._port.network
        deadline = loop.time() + _seconds("timeout", timeout)
        while True:
            status = await self.read_statusword()
            if status.state in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE):
                raise await self._fault(what)
            actual = round(await self.read_velocity() * self.scale)
            if abs(actual - target) <= window and (status.target_reached or not reached):
                return
            if loop.time() >= deadline:
                raise DriveTimeoutError(
                    f"drive {self.node_id}: {what} did not happen within {timeout:g} s "
                    f"(velocity {actual / self.scale:g} {self.unit}/s); statusword {status}"
                )
            await asyncio.sleep(self.poll)

    async def halt(self, timeout: float | None = None) -> None:
        """Stop with the profile deceleration (controlword bit 8), stay enabled, and return
        once the drive stands (its actual velocity within the velocity threshold 606Fh); the
        next move clears Halt (unless ``quirks.clear_halt`` is False)."""
        limit = self.timeout if timeout is None else _seconds("timeout", timeout)
        await self.read_statusword()
        self._require_enabled("halt")
        await self._send_cw(self._cw | CW_HALT)
        window = await self._read_window(0x606F, 1)
        await self._wait_velocity(0, window, limit, "standstill after halt", reached=False)

    # ------------------------------------------------------------------ velocity and torque
    async def set_velocity(
        self,
        velocity: float,
        acceleration: float | None = None,
        deceleration: float | None = None,
        *,
        wait: bool = True,
        timeout: float = 30.0,
        switch_mode: bool = True,
    ) -> None:
        """Run at ``velocity`` (user units per second) in profile velocity mode; with ``wait``
        return when the actual velocity 606Ch is within the velocity window 606Dh of it and
        the drive reports target reached. ``switch_mode=False``: never write the mode 6060h -
        :class:`DriveStateError` when 6061h shows another mode."""
        target = self._inc("velocity", velocity)
        profile = self._profile(None, acceleration, deceleration)
        _seconds("timeout", timeout)
        await self._enter(OperationMode.PROFILE_VELOCITY, switch_mode, "run at a velocity")
        await self.read_statusword()
        self._require_enabled("run at a velocity")
        for index, value in profile:
            await self.write(index, 0, value)
        await self.write(0x60FF, 0, target)
        if self.quirks.clear_halt and self._cw & CW_HALT:
            await self._send_cw(self._cw & ~CW_HALT)
        if wait:
            window = await self._read_window(0x606D, max(abs(target) // 100, 1))
            await self._wait_velocity(
                target, window, timeout, f"velocity {velocity:g} {self.unit}/s"
            )

    async def set_torque(
        self,
        torque: int,
        slope: int | None = None,
        *,
        wait: bool = True,
        timeout: float = 10.0,
    ) -> None:
        """Apply ``torque`` (per mille of the rated torque) in profile torque mode, ramped
        with ``slope`` (per mille per second) when given; with ``wait`` return when the
        drive reports it reached (bit 10, read one poll period after the command)."""
        torque = _integer("torque", torque, -32768, 32767)
        if slope is not None:
            slope = _integer("slope", slope, 1, 2**32 - 1)
        _seconds("timeout", timeout)
        await self.set_mode(OperationMode.PROFILE_TORQUE)
        await self.read_statusword()
        self._require_enabled("apply a torque")
        if slope is not None:
            await self.write(0x6087, 0, slope)
        await self.write(0x6071, 0, torque)
        if self.quirks.clear_halt and self._cw & CW_HALT:
            await self._send_cw(self._cw & ~CW_HALT)
        if wait:
            await asyncio.sleep(self.poll)
            await self.wait_for_target(timeout, what=f"torque {torque} per mille")

    # ------------------------------------------------------------------ cyclic synchronous
    async def follow(
        self,
        trajectory: Trajectory,
        *,
        mode: str = "position",
        sync_cob_id: int = 0x80,
        timeout: float | None = None,
        progress: Callable[[float], object] | None = None,
    ) -> None:
        """Follow ``trajectory`` in a cyclic synchronous mode: at each SYNC the set-point for
        the next SYNC goes out by the RPDO that maps it (with the controlword, if it maps it
        too). Someone must produce SYNC (``net.sync.start(0.001)``, or the master).

        ``mode="position"`` (CSP): ``trajectory.position(t)`` in user units into 607Ah; ends
        when the drive stands within its position window 6067h of ``trajectory.end``.
        ``mode="velocity"`` (CSV): ``trajectory.velocity_at(t)`` in user units/s into 60FFh
        (:class:`~cobus.profiles.trajectory.Trapezoid` and ``SCurve`` have it); ends when the
        actual velocity is within 606Dh of the last one. ``mode="torque"`` (CST): the
        trajectory's ``position(t)`` read as a torque in per mille into 6071h (a torque
        profile); ends with the last set-point. ``mode="interpolated"`` (IP, linear): as
        position, into 60C1h sub 1 with controlword bit 4 "enable ip mode" set (and left set:
        the drive holds the last point). ``progress(fraction)`` is called each cycle,
        on the event loop.

        :class:`DriveStateError` when the drive is not enabled, is not at the trajectory's
        start (position mode), or no RPDO maps the set-point; :class:`DriveFault` if it
        faults on the way (the feeding stops); an error while feeding (the trajectory, a
        range check, ``progress``) is raised as it is; :class:`DriveTimeoutError` when no
        SYNC comes or the end is not reached within ``timeout`` (default: the duration +
        1 s)."""
        modes = {
            "position": (OperationMode.CYCLIC_SYNC_POSITION, 0x607A, 0, "target position"),
            "velocity": (OperationMode.CYCLIC_SYNC_VELOCITY, 0x60FF, 0, "target velocity"),
            "torque": (OperationMode.CYCLIC_SYNC_TORQUE, 0x6071, 0, "target torque"),
            "interpolated": (
                OperationMode.INTERPOLATED_POSITION,
                0x60C1,
                1,
                "interpolation set-point",
            ),
        }
        if mode not in modes:
            raise ValueError(f"mode {mode!r}: position, velocity, torque or interpolated")
        drive_mode, index, sub, name = modes[mode]
        key = (index, sub)
        positional = mode in ("position", "interpolated")
        if mode == "velocity" and not callable(getattr(trajectory, "velocity_at", None)):
            raise TypeError("velocity mode needs a trajectory with velocity_at(t)")
        velocity_at: Callable[[float], float] = getattr(trajectory, "velocity_at", None) or (
            lambda t: 0.0
        )

        def setpoint(t: float) -> int:
            if positional:
                return self._inc("set-point", trajectory.position(t))
            if mode == "velocity":
                return self._inc("velocity set-point", velocity_at(t))
            return _integer("torque set-point", round(trajectory.position(t)), -32768, 32767)

        first = setpoint(0.0)
        duration = _number("trajectory duration", trajectory.duration)
        limit = duration + 1.0 if timeout is None else _seconds("timeout", timeout)
        await self.set_mode(drive_mode)
        await self.read_statusword()
        self._require_enabled("follow a trajectory")
        window = await self._read_window(0x6067 if positional else 0x606D, 20)
        if positional:
            actual = round(await self.read_position() * self.scale)
            if abs(actual - first) > window:
                raise DriveStateError(
                    f"drive {self.node_id} is at {actual / self.scale:g} {self.unit}, the "
                    f"trajectory starts at {trajectory.start:g} (more than the position "
                    f"window 6067h, {window} increments, away): start it where the drive stands"
                )
        if self._cw & CW_HALT:  # a halted drive ignores its set-points
            await self._send_cw(self._cw & ~CW_HALT)
        cw = self._cw
        if not self._port.send_cyclic({key: first, (0x6040, 0): cw}):
            if self._port.maps(*key):
                raise DriveStateError(
                    f"drive {self.node_id}: its RPDOs do not go out (the node is not "
                    "operational, or the master does not run): start it first"
                )
            raise DriveStateError(
                f"drive {self.node_id}: no RPDO maps the {name} {index:04X}h:{sub:02X} (with "
                "nothing but the controlword beside it): map one (the network file's rpdoN, or "
                "node.rpdo.read() on a bare node) to feed it every SYNC"
            )
        if mode == "interpolated":  # controlword bit 4: enable ip mode
            await self._send_cw(self._cw | CW_NEW_SETPOINT)
            cw = self._cw
        loop = self._port.network
        done: asyncio.Future[None] = loop.loop.create_future()
        began: list[float] = []
        cycles = [0]

        def on_sync(frame: Frame, now: float) -> None:
            if done.done() or frame.rtr:
                return
            try:
                if not began:
                    began.append(now)
                k = cycles[0]
                cycles[0] += 1
                # the set-point the drive takes at the next SYNC is the trajectory at k
                # periods (measured over the SYNCs so far): the start first, then one sample
                # per period, none skipped
                period = (now - began[0]) / k if k else 0.0
                t = k * period
                self._port.send_cyclic({key: setpoint(t), (0x6040, 0): cw})
                if progress is not None:
                    progress(min(t / duration, 1.0) if duration > 0 else 1.0)
                if k and t >= duration:
                    done.set_result(None)
            except Exception as exc:  # the trajectory's, the range check's, progress's
                done.set_exception(exc)

        subscription = loop.subscribe(sync_cob_id, on_sync)
        deadline = loop.time() + limit
        try:
            while not done.done():
                status = await self.read_statusword()
                if status.state in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE):
                    raise await self._fault("following a trajectory")
                if status.state is not PowerState.OPERATION_ENABLED:
                    raise DriveStateError(
                        f"drive {self.node_id} left OPERATION_ENABLED while following a "
                        f"trajectory: statusword {status}"
                    )
                if loop.time() >= deadline:
                    why = "no SYNC came" if not began else "the trajectory did not end"
                    raise DriveTimeoutError(
                        f"drive {self.node_id}: {why} within {limit:g} s (is a SYNC producer "
                        "running?)"
                    )
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(
                        asyncio.shield(done), min(0.05, max(deadline - loop.time(), 1e-3))
                    )
        finally:
            subscription.cancel()
            if not done.done():
                done.cancel()
        done.result()  # an error in the feeding is the caller's
        if mode == "torque":
            return
        last = setpoint(duration)
        settle_by = loop.time() + max(deadline - loop.time(), self.timeout)
        while True:
            status = await self.read_statusword()
            if status.state in (PowerState.FAULT, PowerState.FAULT_REACTION_ACTIVE):
                raise await self._fault("reaching the trajectory's end")
            if positional:
                actual = round(await self.read_position() * self.scale)
            else:
                actual = round(await self.read_velocity() * self.scale)
            if abs(actual - last) <= window:
                return
            if loop.time() >= settle_by:
                raise DriveTimeoutError(
                    f"drive {self.node_id}: the trajectory's end {last / self.scale:g} "
                    f"{self.unit}{'' if positional else '/s'} not reached (at "
                    f"{actual / self.scale:g}); statusword {status}"
                )
            await asyncio.sleep(self.poll)

    # ------------------------------------------------------------------ homing
    async def homing_methods(self) -> list[int] | None:
        """The methods 60E3h lists (None: the drive has no 60E3h, so any may be tried)."""
        if self._homing_methods is None:
            try:
                count = int(await self.read(0x60E3, 0))
            except SdoAbortedError:
                return None
            self._homing_methods = [int(await self.read(0x60E3, s)) for s in range(1, count + 1)]
        return self._homing_methods

    async def home(
        self,
        method: int | None = None,
        *,
        speeds: tuple[float, float] | None = None,
        acceleration: float | None = None,
        offset: float | None = None,
        timeout: float = 60.0,
        progress: Callable[[Statusword], object] | None = None,
    ) -> None:
        """Home the drive: ``method`` (6098h; None keeps the drive's), ``speeds`` (search for
        the switch, search for zero; user units/s), ``acceleration`` and ``offset`` (the
        position the home point gets). Returns when homing is attained; a method 60E3h does
        not list raises :class:`DriveStateError` before anything moves, a homing error
        :class:`HomingError`, no result within ``timeout`` :class:`DriveTimeoutError`."""
        if method is not None:
            method = _integer("homing method", method, -128, 127)
        writes: list[tuple[int, int, int]] = []
        if speeds is not None:
            if len(speeds) != 2:
                raise ValueError(f"speeds {speeds!r}: (search for the switch, search for zero)")
            writes.append((0x6099, 1, self._inc("switch search speed", speeds[0], positive=True)))
            writes.append((0x6099, 2, self._inc("zero search speed", speeds[1], positive=True)))
        if acceleration is not None:
            writes.append((0x609A, 0, self._inc("acceleration", acceleration, positive=True)))
        if offset is not None:
            writes.append((0x607C, 0, self._inc("offset", offset)))
        _seconds("timeout", timeout)
        if method is not None:
            methods = await self.homing_methods()
            if methods is not None and method not in methods:
                raise DriveStateError(
                    f"drive {self.node_id} does not support homing method {method} (60E3h "
                    f"lists: {', '.join(map(str, methods)) or 'none'})"
                )
        await self.set_mode(OperationMode.HOMING)
        await self.read_statusword()
        self._require_enabled("home")
        if method is not None:
            await self.write(0x6098, 0, method)
        for index, subindex, value in writes:
            await self.write(index, subindex, value)
        base = self._cw & ~(CW_NEW_SETPOINT | CW_HALT)
        await self._send_cw(base)
        await self._send_cw(base | CW_NEW_SETPOINT)

        def over(s: Statusword) -> bool:
            return bool(s.value & SW_BIT13) or (
                bool(s.value & SW_BIT12) and bool(s.value & SW_TARGET_REACHED)
            )

        try:
            status = await self._wait(over, timeout, "homing attained", progress=progress)
        finally:
            await self._send_cw(base)
        if status.value & SW_BIT13:
            raise HomingError(
                f"drive {self.node_id}: homing error (method {method if method else 'as set'}); "
                f"statusword {status}"
            )

    # ------------------------------------------------------------------ actual values
    async def read_position(self) -> float:
        """The actual position 6064h in user units."""
        value = self._fresh(0x6064)
        return float(value if value is not None else await self.read(0x6064)) / self.scale

    async def read_velocity(self) -> float:
        """The actual velocity 606Ch in user units per second."""
        value = self._fresh(0x606C)
        return float(value if value is not None else await self.read(0x606C)) / self.scale

    # ------------------------------------------------------------------ jog
    async def jog(self, velocity: float, *, deadman: float = 0.2) -> None:
        """Run at ``velocity`` (user units/s, profile velocity) for as long as someone says
        so: :meth:`keep_jogging` must come at least every ``deadman`` seconds (a held
        button, a panel's heartbeat), else the drive halts by itself — a lost operator
        link never leaves a motor running. :meth:`stop_jog` ends it; :attr:`jog_ended` says
        how the last one ended."""
        deadman = _seconds("deadman", deadman)
        await self.set_velocity(velocity, wait=False)
        self._jog_deadman = deadman
        self.jog_ended = ""
        self.keep_jogging()

    @property
    def jogging(self) -> bool:
        """Whether a jog runs (its dead-man timer is armed)."""
        return self._jog_timer is not None

    def keep_jogging(self) -> None:
        """The operator still holds the jog: the dead-man timer starts again."""
        if self._jog_deadman <= 0:
            raise DriveStateError(f"drive {self.node_id}: no jog runs (call jog() first)")
        if self._jog_timer is not None:
            self._jog_timer.cancel()
        loop = self._port.network.loop
        self._jog_timer = loop.call_later(self._jog_deadman, self._deadman_expired)

    def _deadman_expired(self) -> None:
        self._jog_timer = None
        self.jog_ended = f"dead-man: no keep_jogging() for {self._jog_deadman:g} s"
        self._jog_deadman = 0.0
        self._halt_task = asyncio.ensure_future(self._send_cw(self._cw | CW_HALT))
        self._halt_task.add_done_callback(self._halt_done)

    def _halt_done(self, task: asyncio.Future[None]) -> None:
        """The dead-man halt could not be sent: reported (a HandlerFailed event), not lost."""
        if not task.cancelled() and task.exception() is not None:
            self.jog_ended += f"; the halt could not be sent: {task.exception()}"
            exc = task.exception()
            assert exc is not None
            self._port.network.report_failure(f"dead-man halt of drive {self.node_id}", exc)

    async def stop_jog(self, timeout: float | None = None) -> None:
        """End the jog: halt and wait for standstill."""
        if self._jog_timer is not None:
            self._jog_timer.cancel()
            self._jog_timer = None
        self._jog_deadman = 0.0
        if not self.jog_ended:
            self.jog_ended = "stopped"
        await self.halt(timeout)

    def close(self) -> None:
        """Stop listening to the node's process data (and end a jog: the drive halts)."""
        if self._jog_timer is not None:
            self._deadman_expired()
            self.jog_ended = "closed"
        self._port.remove_input_callback(self._on_input)
        self._port.close()


class Drive402(BlockingTwin, twin_of=AsyncDrive402):
    """A CiA 402 drive for blocking code, with the methods of :class:`AsyncDrive402`, each
    returning once done: ``Drive402(node)`` on a node of a blocking
    :class:`~cobus.runtime.Network` (``net.add_remote(...)``), or ``Drive402(master,
    "servo")`` on a node a :class:`~cobus.master.BlockingMaster` manages (its process image
    carries the PDOs). The keyword options are :class:`AsyncDrive402`'s."""

    def __init__(self, node: Any, name: Any = None, **options: Any) -> None:
        if isinstance(node, AsyncDrive402):  # a twin made for an async drive
            super().__init__(node, name)
            return
        runner = getattr(node, "_runner", None)
        if runner is None:
            raise TypeError(
                "Drive402 takes a node of a blocking Network (net.add_remote(...)) or a "
                "BlockingMaster and a node name; in async code use AsyncDrive402"
            )
        target = node.aio
        if name is not None:
            from cobus.master import Master

            if not isinstance(target, Master):
                raise TypeError("Drive402(master, name): the name is for a master's node")
            target = runner.call(target.node, name)
        aio = runner.call(lambda: AsyncDrive402(target, **options))
        super().__init__(aio, runner)
