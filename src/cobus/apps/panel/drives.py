"""The Drive pages' data: CiA 402 drives and the ZAPI inverter, and who commands them.

:func:`serve_drive` shows a :class:`~cobus.profiles.AsyncDrive402` or a
:class:`~cobus.profiles.zapi.AsyncZapiDrive` on a :class:`~cobus.apps.panel.Panel`:

- state key ``drive/<name>``: its kind, node, power state, statusword decoded (CiA 402) or
  the ZAPI's alarm and handshake, the set-point, the actual values, and who commands it;
- plotted keys ``drive/<name>/speed`` (and, for CiA 402, ``position``, ``current`` and
  ``temperature`` where the drive has them);
- the command ``drive`` (it writes): ``{"cmd": "drive", "drive": NAME, "action": ...}``;
- the command ``drive.watch`` (it reads): ``{"cmd": "drive.watch", "drive": NAME}``, sent
  every few seconds by a page that shows the drive.

What it costs the bus: a CiA 402 drive's statusword is read once a second (by SDO where no
TPDO brings it); its actual values, its mode and the statusword ``rate`` times a second only
while a page watches it (``WATCH`` seconds after the last ``drive.watch``), each taken from a
TPDO that maps it where one is fresh, else read by SDO (an object the drive refuses is not
asked again).

Safety — nothing moves a drive unless the operator asked for exactly that:

- ``enable`` needs ``"confirm": true`` (the page asks the operator first); it writes the
  speed set-point 0 (CiA 402 60FFh; the ZAPI's RPDO) before it switches the power stage on,
  so that a set-point an application left behind never moves the drive;
- ``speed`` sets exactly the signed value given, checked against the drive's limits (CiA 402:
  INTEGER32 and its max profile velocity 607Fh where it has one; ZAPI: ±327.67 Hz); it never
  enables a drive that is off;
- ``position`` (CiA 402) starts a profile position move to ``value`` (``"relative": true``:
  by ``value`` from the last target), checked against INTEGER32 and the software position
  limits 607Dh where the drive has them; like ``speed`` only in the drive's mode (profile
  position) and only while it is enabled - the panel never writes the mode 6060h;
- ``quick_stop``, ``halt``, ``disable`` (and the ZAPI's ``stop`` and ``release``) are always
  accepted, also while the application commands the drive — a page is never kept from
  stopping it;
- while the application commands a drive (``holder`` "application"), ``enable``, ``speed``
  and ``fault_reset`` are refused until the operator takes it over (``take``); ``give``
  hands it back. The application asks :meth:`DriveView.panel_holds` before it writes;
- a ZAPI inverter served by :func:`serve_zapi` has no handshake until the operator starts
  it (``handshake``: its adapter then answers every TPDO1 with an RPDO1, released and at
  0 Hz); ``end_handshake`` releases it and ends the handshake (the inverter then raises
  its "CAN BUS KO" alarm, as it does when a controller goes away).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable, Mapping
from typing import Any

from cobus.apps.panel.server import CommandError, Panel
from cobus.errors import CobusError, clip
from cobus.proto.sdo.errors import SdoAbortedError

__all__ = ["DriveView", "is_cia402", "serve_cia402_drives", "serve_drive", "serve_zapi"]

log = logging.getLogger(__name__)

#: Who may command a drive.
HOLDERS = ("panel", "application")
_STOPS = frozenset({"quick_stop", "halt", "disable", "stop", "release", "end_handshake"})
_PROFILE_VELOCITY = 3
#: Power states in which a drive cannot move: a quick stop there is answered at once.
_STANDING = frozenset({"NOT_READY_TO_SWITCH_ON", "SWITCH_ON_DISABLED", "FAULT"})
_PROFILE_POSITION = 1
#: The ZAPI's alarm for a missed handshake answer.
_CAN_BUS_KO = 248
#: Seconds a page's ``drive.watch`` keeps the actual values read.
WATCH = 6.0
#: Seconds between statusword reads while no page watches the drive.
IDLE_PERIOD = 1.0
#: Seconds between reads of the mode (6061h) while a page watches.
MODE_PERIOD = 1.0
#: The modes the panel enables a drive in, and the set-point it zeroes first (profile
#: position moves only on a new set-point bit: nothing to zero).
_ENABLE_MODES: dict[int, int | None] = {1: None, 3: 0x60FF, 4: 0x6071}
_INT32 = (-(2**31), 2**31 - 1)
#: SDO abort codes that say the object is not there (it is not asked again).
_NO_OBJECT = frozenset({0x06020000, 0x06090011, 0x06010001})
#: CiA 402 actual values read by SDO when no PDO brings them: key -> (index, sub, scale).
_ACTUALS_402 = {
    "speed": (0x606C, 0, 1.0),
    "position": (0x6064, 0, 1.0),
    "current": (0x6078, 0, 1.0),
}


class DriveView:
    """One drive on the panel (see the module text). ``kind``: "cia402" or "zapi".
    ``temperature``: (index, subindex, scale) of a manufacturer temperature object.
    ``holder``: who commands the drive at first ("panel", or "application" when a program
    drives it)."""

    def __init__(
        self,
        panel: Panel,
        name: str,
        drive: Any,
        *,
        kind: str,
        holder: str = "panel",
        temperature: tuple[int, int, float] | None = None,
        rate: float = 4.0,
        ready: Callable[[], bool] | None = None,
        node_id: int | None = None,
        factory: Callable[[], Any] | None = None,
        on_start: Callable[[Any], object] | None = None,
    ) -> None:
        if drive is None and (factory is None or node_id is None):
            raise ValueError("a drive, or a factory and the node_id of the drive it makes")
        if kind not in ("cia402", "zapi"):
            raise ValueError(f"kind {kind!r}: cia402 or zapi")
        if holder not in HOLDERS:
            raise ValueError(f"holder {holder!r}: one of {', '.join(HOLDERS)}")
        if not rate > 0:
            raise ValueError(f"rate {rate}: reads per second above 0")
        self.panel = panel
        self.name = name
        #: The drive's adapter (None while a ``factory`` has not made it: no handshake).
        self.drive = drive
        self.node_id: int = drive.node_id if drive is not None else node_id or 0
        self.kind = kind
        self._factory = factory
        self._on_start = on_start
        self.holder = holder
        self.actual: dict[str, float | None] = {}
        self.max_velocity: int | None = None
        #: The software position limits 607Dh (increments; None: the drive has none).
        self.position_limits: tuple[int, int] | None = None
        #: Why the last statusword read failed ("" when it worked).
        self.read_error = ""
        self._until = 0.0
        self._wake = asyncio.Event()
        self._order = asyncio.Lock()
        #: The command under way (not a stop), and those a stop cut short.
        self._running: asyncio.Task[Any] | None = None
        self._cut: set[asyncio.Task[Any]] = set()
        #: Stops sent so far (a command waiting its turn when one came is dropped).
        self._stops = 0
        self._objects = dict(_ACTUALS_402) if kind == "cia402" else {}
        if temperature is not None:
            self._objects["temperature"] = temperature
        self._period = 1.0 / rate
        self._ready = ready
        self._task: asyncio.Task[None] | None = None
        drives = [
            *panel.hub.info.get("drives", []),
            {
                "name": name,
                "kind": kind,
                "node": self.node_id,
                "unit": self._unit(),
                "on_demand": factory is not None,
            },
        ]
        panel.hub.set_info("drives", drives)
        for key in ("speed", *self._objects):
            self.panel.hub.plot(f"drive/{name}/{key}")
        panel.sample(self.sample)

    def _unit(self) -> str:
        return "Hz" if self.kind == "zapi" else f"{self.drive.unit}/s"

    def panel_holds(self) -> bool:
        """Whether the panel commands the drive (the application then leaves it alone)."""
        return self.holder == "panel"

    @property
    def watched(self) -> bool:
        """Whether a page showed the drive within the last ``WATCH`` seconds."""
        return self.panel.hub.clock() < self._until

    def watch(self) -> dict[str, Any]:
        """A page shows the drive: read its actual values for ``WATCH`` seconds more."""
        self._until = self.panel.hub.clock() + WATCH
        self._wake.set()
        return {"drive": self.name, "watching": True, "for": WATCH}

    def start(self) -> None:
        """Start reading the actual values (once the loop runs)."""
        if self._task is None and (self._objects or self.kind == "cia402"):
            self._task = asyncio.create_task(self._read(), name=f"cobus panel drive {self.name}")

    def close(self) -> None:
        """Stop reading; end a handshake the view started (the drive released first)."""
        if self._task is not None:
            self._task.cancel()
            self._task = None
        if self._factory is not None and self.drive is not None:
            self._end_handshake()

    def _end_handshake(self) -> None:
        drive, self.drive = self.drive, None
        drive.release()  # set-point 0, power stage off, contactor open: sent at once
        drive.close()

    # ------------------------------------------------------------------ samples
    def sample(self) -> dict[str, Any]:
        """The drive's key and its plotted values."""
        drive = self.drive
        values: dict[str, Any] = {}
        if self.kind == "cia402":
            status = drive.status
            state = status.state
            actual = dict(self.actual)
            record: dict[str, Any] = {
                "state": state.name,
                "state_text": state.value,
                "statusword": status.value,
                "flags": status.flags(),
                "fault": state.name in ("FAULT", "FAULT_REACTION_ACTIVE"),
                "enabled": state.name == "OPERATION_ENABLED",
                "controlword": drive.controlword,
                "mode": status.mode or None,
                "mode_text": _mode_name(status.mode) if status.mode else "",
                "position_limits": (
                    None
                    if self.position_limits is None
                    else [limit / drive.scale for limit in self.position_limits]
                ),
                "read_error": self.read_error,
            }
        elif drive is None:
            actual = {"speed": None}
            record = {
                "state": "HANDSHAKE NOT STARTED",
                "alarm": 0,
                "alarm_text": "",
                "fault": False,
                "enabled": False,
                "setpoint": 0.0,
                "cycles": 0,
                "handshake": False,
                "note": (
                    "No controller answers the inverter's TPDO1: it raises alarm 248 CAN BUS "
                    "KO and waits in pre-operational (the master, with no heartbeat from it, "
                    "cannot tell). Starting the handshake restarts it, released, motor off."
                ),
            }
        else:
            actual = {"speed": drive.speed}
            record = {
                "handshake": True,
                "state": "RUNNING" if drive.handshake_running else "NO HANDSHAKE",
                "alarm": drive.alarm,
                "alarm_text": drive.alarm_text,
                "fault": bool(drive.alarm),
                "enabled": bool(drive.command),
                "setpoint": drive.setpoint,
                "cycles": drive.cycles,
            }
        record.update(
            {
                "name": self.name,
                "kind": self.kind,
                "node": self.node_id,
                "holder": self.holder,
                "actual": actual,
                "max_velocity": self.max_velocity,
            }
        )
        values[f"drive/{self.name}"] = record
        for key, value in actual.items():
            if value is not None:
                values[f"drive/{self.name}/{key}"] = value
        return values

    async def _read(self) -> None:
        """Read the drive (see the module text): its statusword each ``IDLE_PERIOD``; its
        actual values and mode ``rate`` times a second while a page watches it."""
        drive = self.drive
        while self._ready is not None and not self._ready():
            await asyncio.sleep(self._period)  # (no SDO while the master boots the node)
        cia402 = self.kind == "cia402"
        if cia402:
            with contextlib.suppress(CobusError, TimeoutError, ValueError):
                self.max_velocity = int(await drive.read(0x607F)) or None
            with contextlib.suppress(CommandError):
                self.position_limits = await self._read_limits(drive)
        mode_read_at = -math.inf
        was_watched = False
        while True:
            if self._ready is not None and not self._ready():
                await asyncio.sleep(self._period)  # (the master boots it again: no SDO)
                continue
            watched = self.watched
            if cia402:
                try:
                    await asyncio.wait_for(drive.read_statusword(), 2.0)
                    self.read_error = ""
                except (CobusError, ValueError) as exc:
                    self.read_error = clip(str(exc))
                except TimeoutError:
                    self.read_error = "the drive did not answer within 2 s"
                except Exception as exc:  # (whatever it is, the reading goes on)
                    self.read_error = clip(f"{type(exc).__name__}: {exc}")
                now = self.panel.hub.clock()
                if watched and now - mode_read_at >= MODE_PERIOD:
                    mode_read_at = now
                    await self._mode(drive)
            if watched:
                await self._read_actuals(drive)
            elif was_watched:
                for key in self.actual:  # (nobody looks: no value is shown as current)
                    self.actual[key] = None
            was_watched = watched
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), self._period if watched else IDLE_PERIOD)

    async def _read_actuals(self, drive: Any) -> None:
        fresh = 2 * self._period  # (a TPDO younger than two reads is as good as one)
        for key, (index, sub, scale) in list(self._objects.items()):
            try:
                if self.kind == "cia402":
                    raw = await asyncio.wait_for(drive.read_fresh(index, sub, fresh), 2.0)
                else:
                    raw = await asyncio.wait_for(drive.read(index, sub), 2.0)
                self.actual[key] = float(raw) * scale
            except (SdoAbortedError, ValueError):
                del self._objects[key]  # the drive has no such object: not asked again
                self.actual.pop(key, None)
            except (CobusError, TimeoutError):
                self.actual[key] = None
            except Exception:  # (a value of a type that is no number: not plotted)
                log.exception("panel: %s's %s cannot be read", self.name, key)
                del self._objects[key]
                self.actual.pop(key, None)

    # ------------------------------------------------------------------ commands
    async def command(self, message: Mapping[str, Any]) -> Any:
        """Carry out one ``drive`` command (see the module text). Commands other than stops
        run one at a time in the order they came, so that a set-point sent before ``give``
        reaches the drive before the application has it back; a stop never waits behind
        them."""
        action = message.get("action")
        if isinstance(action, str) and action in _STOPS:
            # a move or a set-point still under way would send its controlwords after the
            # stop and undo it: it is cut short first (nothing more of it is sent), and those
            # sent before the stop that still wait their turn are not carried out
            self._stops += 1
            running = self._running
            if running is not None and not running.done():
                self._cut.add(running)
                running.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await running
            return await self._command(message)
        stops = self._stops
        async with self._order:
            if self._stops != stops:
                raise CommandError(
                    "stopped", f"a stop came after {action} was sent: it is not carried out"
                )
            task = asyncio.create_task(self._command(message))
            self._running = task
            try:
                return await task
            except asyncio.CancelledError:
                if task not in self._cut:
                    raise  # (the panel stops: not a stop's doing)
                raise CommandError(
                    "stopped",
                    f"a stop cut {message.get('action')} short: nothing more of it was sent",
                ) from None
            finally:
                self._cut.discard(task)
                self._running = None

    async def _command(self, message: Mapping[str, Any]) -> Any:
        action = message.get("action")
        actions = _ACTIONS[self.kind]
        if not isinstance(action, str) or action not in actions:
            raise ValueError(f"action {action!r}: one of {', '.join(actions)}")
        if action == "take":
            self.holder = "panel"
            return {"holder": self.holder}
        if action == "give":
            self.holder = "application"
            return {"holder": self.holder}
        if action in _STOPS and self.holder != "panel":
            # a stop from the panel lasts: the application must not undo it, so the operator
            # holds the drive from now on (give hands it back)
            self.holder = "panel"
        if action not in _STOPS and self.holder != "panel":
            raise CommandError(
                "not-holder",
                f"the application commands {self.name}: take it over first (stopping is "
                "always allowed)",
            )
        drive = self.drive
        if self.kind == "zapi":
            if action == "handshake":
                return await self._start_handshake()
            if drive is None:
                if action in _STOPS:  # (no handshake: the inverter stands, nothing to stop)
                    return {"action": action, "handshake": False, "moving": False}
                raise CommandError(
                    "no-handshake",
                    f"{self.name} has no handshake: start it first (action handshake)",
                )
            if action == "end_handshake":
                if self._factory is None:
                    raise CommandError(
                        "not-yours",
                        f"the application runs {self.name}'s handshake: the panel cannot end it",
                    )
                self._end_handshake()
                return {"action": action, "handshake": False}
            return await self._zapi(drive, action, message)
        if action == "enable":
            if message.get("confirm") is not True:
                raise CommandError(
                    "confirm",
                    f"enabling {self.name} switches its power stage on (at speed 0): send "
                    '"confirm": true once the operator has agreed',
                )
            mode = await self._mode(drive)
            if mode not in _ENABLE_MODES:
                raise CommandError(
                    "mode",
                    f"{self.name} is in mode {_mode_name(mode)}: the panel enables a drive only "
                    "in profile position, velocity or torque mode (6060h 1, 3 or 4), where it "
                    "can zero the set-point first",
                )
            zero = _ENABLE_MODES[mode]
            if zero is not None:
                await drive.write(zero, 0, 0)  # the set-point an application left: 0
            await drive.enable()
        elif action == "disable":
            await drive.disable()
        elif action == "quick_stop":
            status = await drive.read_statusword()
            if status.state.name in _STANDING:  # (it cannot move: answered at once)
                return {"action": action, "state": status.state.name, "moving": False}
            await drive.quick_stop()
        elif action == "halt":
            status = await drive.read_statusword()  # (not a stale one: it may be moving)
            if status.state.name != "OPERATION_ENABLED":
                return {"action": action, "state": status.state.name, "moving": False}
            await drive.halt()
        elif action == "fault_reset":
            await drive.fault_reset()
        elif action == "speed":
            value = self._speed(message.get("value"))
            await self._ready_for(drive, _PROFILE_VELOCITY, "sets a speed", "velocity")
            await drive.set_velocity(value, wait=False, switch_mode=False)
            return {"action": action, "value": value}
        elif action == "position":
            relative = message.get("relative", False)
            if not isinstance(relative, bool):
                raise ValueError(f"relative {clip(repr(relative))}: true or false")
            value = self._target(message.get("value"), relative)
            self.position_limits = await self._read_limits(drive)  # (now: they may change)
            if self.position_limits is not None and not relative:
                self._within_limits(value, f"{value:g}")
            await self._ready_for(drive, _PROFILE_POSITION, "moves to a position", "position")
            if self.position_limits is not None and relative:
                for index in (0x607A, 0x6064):  # (from the last target, or from where it is)
                    start = float(await drive.read(index)) / drive.scale
                    self._within_limits(start + value, f"{start:g} + {value:g}")
            await drive.move_to(value, relative=relative, wait=False, switch_mode=False)
            return {"action": action, "value": value, "relative": relative}
        return {"action": action, "state": drive.status.state.name}

    async def _ready_for(self, drive: Any, mode: int, doing: str, profile: str) -> None:
        """Refuse a set-point unless the drive is in ``mode`` (never changed here) and
        enabled (a set-point never enables a drive)."""
        shown = await self._mode(drive)
        if shown != mode:
            raise CommandError(
                "mode",
                f"{self.name} is in mode {_mode_name(shown)}: the panel {doing} only in profile "
                f"{profile} mode (6060h = {mode}); it never changes the mode itself",
            )
        status = await drive.read_statusword()
        if status.state.name != "OPERATION_ENABLED":
            raise CommandError(
                "not-enabled",
                f"{self.name} is {status.state.value}: enable it first (a set-point never "
                "enables a drive)",
            )

    async def _mode(self, drive: Any) -> int:
        """The mode 6061h shows now (-1 when the drive cannot say)."""
        try:
            return int(await drive.read_mode())
        except (CobusError, ValueError, TimeoutError):
            return -1

    def _speed(self, value: Any) -> Any:
        """The signed speed asked for, checked: finite, within INTEGER32 and the drive's max
        profile velocity 607Fh (both in increments: the limits are turned into user units)."""
        scale = self.drive.scale
        if self.max_velocity is None:
            low, high, limit = _INT32[0] / scale, _INT32[1] / scale, "INTEGER32"
        else:
            low, high = -self.max_velocity / scale, self.max_velocity / scale
            limit = "its max profile velocity 607Fh"
        return self._number(value, "speed", self._unit(), (low, high), limit)

    def _target(self, value: Any, relative: bool) -> Any:
        """The position (or, ``relative``, the distance) asked for in user units, checked:
        a finite number within INTEGER32 (the limits 607Dh are checked by the caller)."""
        scale = self.drive.scale
        what = "distance" if relative else "position"
        bounds = (_INT32[0] / scale, _INT32[1] / scale)
        return self._number(value, what, self.drive.unit, bounds, "INTEGER32")

    def _number(
        self, value: Any, what: str, unit: str, bounds: tuple[float, float], limit: str
    ) -> Any:
        """``value`` as a signed ``what`` in ``unit``: a finite number within ``bounds``
        (``limit`` names them), whole where the drive has no scale."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"value {clip(repr(value))}: a signed {what} in {unit}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"value {value}: a finite {what} in {unit}")
        low, high = bounds
        if not low <= value <= high:  # (an int beyond any float compares right too)
            raise ValueError(f"value {clip(repr(value))}: {low:g}..{high:g} {unit} ({limit})")
        if self.drive.scale == 1.0:
            if value != int(value):
                raise ValueError(f"value {value}: a whole number of {unit}")
            return int(value)
        return value

    async def _read_limits(self, drive: Any) -> tuple[int, int] | None:
        """The software position limits 607Dh now (increments; None: the drive has none -
        an abort saying there is no such object, or min >= max). Any other failure refuses
        the move: the limits cannot be checked."""
        try:
            low, high = int(await drive.read(0x607D, 1)), int(await drive.read(0x607D, 2))
        except SdoAbortedError as exc:
            if exc.code in _NO_OBJECT:
                return None
            raise CommandError(
                "limits", f"{self.name}: its position limits 607Dh cannot be read ({exc})"
            ) from None
        except (CobusError, TimeoutError, ValueError) as exc:
            raise CommandError(
                "limits",
                f"{self.name}: its position limits 607Dh cannot be read ({exc or 'no answer'}): "
                "no move without them",
            ) from None
        return (low, high) if low < high else None

    def _within_limits(self, target: float, shown: str) -> None:
        if self.position_limits is None:
            return
        scale, unit = self.drive.scale, self.drive.unit
        low, high = (limit / scale for limit in self.position_limits)
        if not low <= target <= high:
            raise ValueError(
                f"position {shown} {unit}: {low:g}..{high:g} {unit} (its software position "
                "limits 607Dh)"
            )

    async def _start_handshake(self) -> dict[str, Any]:
        """Make the adapter (it answers each TPDO1 from now on, released and at 0 Hz); an
        inverter that lost its handshake before (alarm 248, pre-operational: no TPDO1) is
        started again and its alarm acknowledged, the motor still off."""
        if self.drive is not None:
            return {"action": "handshake", "handshake": True, "started": False}
        if self._factory is None:  # (a view given its drive always has one)
            raise CommandError("not-yours", f"{self.name}'s handshake is the application's")
        try:
            drive = self.drive = self._factory()
        except (CobusError, ValueError, TypeError, KeyError) as exc:
            raise CommandError("failed", f"{self.name}: {clip(str(exc), 400)}") from None
        if self._on_start is not None:
            self._on_start(drive)
        for _ in range(10):  # (a few SYNC cycles: TPDO1 comes each one while it runs)
            if drive.cycles >= 2:
                break
            await asyncio.sleep(max(drive.watchdog / 3, 0.02))
            if self.drive is not drive:  # (ended meanwhile: nothing more is done)
                return {"action": "handshake", "handshake": False, "started": False}
        # only a lost handshake (alarm 248 CAN BUS KO, no TPDO1) is acknowledged here; any
        # other alarm is the operator's to acknowledge once its cause is gone
        restarted = drive.alarm == _CAN_BUS_KO or drive.cycles < 2
        if restarted:
            try:
                await drive.acknowledge()
            except CobusError as exc:  # (the handshake stays: acknowledge may be tried again)
                raise CommandError(
                    "failed",
                    f"{self.name}: the handshake runs, but the inverter did not come back: "
                    f"{clip(str(exc), 300)}",
                ) from None
        result: dict[str, Any] = {"action": "handshake", "handshake": True, "started": True}
        result["restarted"] = restarted
        if drive.alarm:
            result["alarm"] = (
                f"{drive.alarm} {drive.alarm_text}: acknowledge it once its cause is gone"
            )
        return result

    async def _zapi(self, drive: Any, action: str, message: Mapping[str, Any]) -> Any:
        if action == "speed":
            value = message.get("value")
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float)
                or not -327.67 <= value <= 327.67
            ):
                raise ValueError(
                    f"value {clip(repr(value))}: a signed speed in Hz, -327.67..327.67 "
                    "(clockwise positive)"
                )
            if not drive.command:
                raise CommandError(
                    "not-enabled",
                    f"{self.name} is released: enable it first (a set-point never enables a drive)",
                )
            drive.run(float(value))  # ValueError beyond +-327.67 Hz
            return {"action": action, "value": float(value)}
        if action == "enable":
            if message.get("confirm") is not True:
                raise CommandError(
                    "confirm",
                    f"enabling {self.name} closes its main contactor and enables it at 0 Hz: "
                    'send "confirm": true once the operator has agreed',
                )
            drive.run(0.0)
        elif action == "stop":
            drive.stop()
        elif action == "release":
            drive.release()
        elif action == "acknowledge":
            await drive.acknowledge()
        return {"action": action}


_ACTIONS = {
    "cia402": (
        "enable",
        "disable",
        "quick_stop",
        "halt",
        "fault_reset",
        "speed",
        "position",
        "take",
        "give",
    ),
    "zapi": (
        "handshake",
        "end_handshake",
        "enable",
        "stop",
        "release",
        "acknowledge",
        "speed",
        "take",
        "give",
    ),
}


class _Drives:
    """The ``drive`` command of a panel, routed to its views by name."""

    def __init__(self, panel: Panel) -> None:
        self.views: dict[str, DriveView] = {}
        panel.command(
            "drive",
            self.command,
            writes=True,
            help="command a drive: drive, action (enable + confirm, speed + value, quick_stop...)",
        )
        panel.command(
            "drive.watch",
            self.watch,
            writes=False,
            help="read a drive's actual values for a few seconds: drive",
        )

    def view(self, message: Mapping[str, Any]) -> DriveView:
        name = message.get("drive")
        view = self.views.get(name) if isinstance(name, str) else None
        if view is None:
            known = ", ".join(self.views) or "none"
            given = "no drive given" if name is None else f"drive {clip(repr(name))}"
            raise CommandError("no-drive", f"{given}: name one of {known}")
        return view

    async def watch(self, message: Mapping[str, Any]) -> Any:
        return self.view(message).watch()

    async def command(self, message: Mapping[str, Any]) -> Any:
        return await self.view(message).command(message)


def _mode_name(mode: int) -> str:
    from cobus.profiles.cia402 import OperationMode

    try:
        return f"{OperationMode(mode).name} ({mode})"
    except ValueError:
        return "unknown (6061h unreadable)" if mode == -1 else str(mode)


def is_cia402(node: Any) -> bool:
    """Whether a master's node is a CiA 402 drive: the device type (1000h) its network file
    or, failing that, its EDS gives names profile 402."""
    device_type = node.config.device_type
    if not device_type:
        var = node.config.od.get_variable(0x1000, 0)
        default = var.default if var is not None else None
        device_type = default if isinstance(default, int) else 0
    return bool(device_type & 0xFFFF == 402)


def serve_cia402_drives(panel: Panel, master: Any) -> list[DriveView]:
    """A Drive page for each CiA 402 drive of ``master``'s network, commanded from the panel
    only (nothing is written until the operator asks), read once the master started it. A
    drive's signal named ``temperature`` in the network file (a TPDO of the drive maps it;
    its scale gives °C) is plotted as its temperature."""
    from cobus.master.states import NodeState
    from cobus.profiles import AsyncDrive402

    signals = master.config.signals
    views = []
    for node in master.nodes.values():
        if is_cia402(node):

            def ready(node: Any = node) -> bool:
                return bool(node.state is NodeState.OPERATIONAL)

            sig = signals.get(f"{node.name}.temperature")
            temperature = None
            if sig is not None and sig.direction == "input" and not sig.offset:
                temperature = (sig.index, sig.subindex, sig.scale or 1.0)
            views.append(
                serve_drive(
                    panel, node.name, AsyncDrive402(node), ready=ready, temperature=temperature
                )
            )
    return views


def serve_zapi(
    panel: Panel,
    master: Any,
    node: int | str,
    *,
    on_start: Callable[[Any], object] | None = None,
) -> DriveView:
    """A Drive page for the ZAPI inverter ``node`` of ``master``'s network, whose handshake
    adapter (:class:`~cobus.profiles.zapi.AsyncZapiDrive`: an RPDO1 every SYNC cycle) is
    made only when the operator starts the handshake on the page, and ended by the page or
    by ``view.close()``; ``on_start(adapter)`` is called once it is made (e.g. an alarm
    handler's ``attach_zapi``)."""
    from cobus.profiles.zapi import AsyncZapiDrive

    managed = master.node(node)  # (KeyError, naming the nodes, for one not in the network)

    def make() -> Any:
        return AsyncZapiDrive(master, managed.node_id)

    drives = _router(panel)
    if managed.name in drives.views:
        raise ValueError(f"the panel already shows a drive {managed.name!r}")
    view = DriveView(
        panel,
        managed.name,
        None,
        kind="zapi",
        node_id=managed.node_id,
        factory=make,
        on_start=on_start,
    )
    drives.views[managed.name] = view
    return view


def _router(panel: Panel) -> _Drives:
    drives = panel.views.get("drives")
    if drives is None:
        drives = panel.views["drives"] = _Drives(panel)
    assert isinstance(drives, _Drives)
    return drives


def serve_drive(
    panel: Panel,
    name: str,
    drive: Any,
    *,
    kind: str | None = None,
    holder: str = "panel",
    temperature: tuple[int, int, float] | None = None,
    ready: Callable[[], bool] | None = None,
) -> DriveView:
    """Show ``drive`` as ``name`` on ``panel`` (a Drive page); ``kind`` defaults from its
    class (an AsyncZapiDrive is "zapi", else "cia402"); ``ready`` tells when the drive may be
    read (e.g. once the master started it). Call ``view.start()`` in the loop."""
    if kind is None:
        kind = "zapi" if type(drive).__name__.endswith("ZapiDrive") else "cia402"
    drives = _router(panel)
    if name in drives.views:
        raise ValueError(f"the panel already shows a drive {name!r}")
    view = DriveView(
        panel, name, drive, kind=kind, holder=holder, temperature=temperature, ready=ready
    )
    drives.views[name] = view
    return view
