"""ZAPI ACE2 AC inverter (traction/pump controller) as the thesis rig of seed 000 shows it.

A manufacturer profile on node 8 (not CiA 402), run by a PLC: SYNC every 20 ms, NMT start,
then RPDO1 208h (setpoint, controlword) against TPDO1 188h (actual speed, statusword) every
SYNC cycle with a toggle handshake in byte 3 bit 7; TPDO2 288h carries the alarm code and
temperatures. The controller's observed departures from CiA 301 are :attr:`ZapiAce2.QUIRKS`.

Process data (little-endian; ``b.n`` = byte b, bit n of the PDO):

- RPDO1 208h: 0-1 speed setpoint (Hz x 100), 2-3 controlword, 4 pedal-brake request,
  5 torque request, 6 (or 6-7, ``ramp_bytes=2``) acc/dec ramp (Hz/s x 10; 0 = the default
  ramp). Controlword: 2.1 main contactor A16, 2.2 output A18, 2.3 enable power stage,
  2.4 fault acknowledge, 2.5 A18 power on, 2.6 clockwise, 2.7 counter-clockwise, 3.0 pump
  motor, 3.1 safety output, 3.3-3.4 brake type, 3.7 handshake toggle.
- TPDO1 188h (every SYNC once started): 0-1 actual speed (Hz x 100, signed: clockwise > 0),
  2-3 statusword, 4 analogue in 3, 5 analogue in 1, 6 analogue in 2, 7 motor current (A).
  Statusword: 2.1 A16, 2.2 A18, 2.3 controller enabled, 2.4 output A19, 3.0-3.2 digital
  inputs, 3.3 emergency stop input, 3.6 idle, 3.7 handshake toggle.
- TPDO2 288h: 0 alarm code (decimal ZAPI code, 0 = none), 4 controller temperature (degC),
  5 battery charge BDI (%), 6 motor temperature (degC); the other bytes are 0.
- TPDO4 488h: content undocumented (the thesis found none); sent as 8 zero bytes.

The thesis prints the dictionary tables as images; apart from 20A8h "main contactor voltage"
(100 %), the object indexes of the process values below are this simulator's own:
RPDO1 objects 2200h-2204h, TPDO1 objects 2100h-2105h, TPDO2 objects 2110h-2113h, TPDO4
2120h-2121h. Unknown indexes in 2000h-5FFFh are refused with the CiA abort 06020000.

Assumptions where the thesis is silent, each documented and tested: the handshake alarm and
the SYNC watchdog raise 248 "CAN BUS KO"; an alarm disables the power stage and opens the
outputs until it is acknowledged (rising edge of 2.4) with its cause gone; the digital input
CNA6 (3.2) is active by default, which gives the thesis's byte 3 = 44h / C4h at standstill;
TPDO2 and TPDO4 go out every ``background_period`` (and TPDO2 at once when the alarm
changes); the pedal-brake request brakes to standstill; the torque request, the brake type,
A18 power on (2.5), the pump motor (3.0) and the safety output (3.1) are held (readable by
SDO) but not modelled, and output A19 (statusword 2.4) stays 0: the thesis says nothing of
what drives them.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

from cobus.device import (
    Booted,
    Device,
    DeviceConfigError,
    DeviceEvent,
    DictionaryBuilder,
    MemoryStorage,
    ParameterStorage,
    RpdoReceived,
    StateChanged,
)
from cobus.device.device import Deviations
from cobus.od import DataType, ObjectDictionary
from cobus.profiles.zapi import ALARM_TEXTS, alarm_text
from cobus.proto import Frame
from cobus.proto.connection_set import tpdo_cob_id
from cobus.proto.nmt import NmtCommand, NmtState
from cobus.runtime.network import AsyncNetwork, Subscription
from cobus.sim.base import SimulatedDevice, SimulationError

__all__ = ["ALARM_TEXTS", "ZapiAce2"]

CAN_BUS_KO = 248

# object indexes (see the module docstring)
SPEED_SETPOINT, CONTROLWORD, PEDAL_BRAKE, TORQUE, RAMP = 0x2200, 0x2201, 0x2202, 0x2203, 0x2204
ACTUAL_SPEED, STATUSWORD, ANALOGUE_3, ANALOGUE_1, ANALOGUE_2, CURRENT = range(0x2100, 0x2106)
ALARM, CONTROLLER_TEMP, BDI, MOTOR_TEMP = 0x2110, 0x2111, 0x2112, 0x2113
TPDO4_LOW, TPDO4_HIGH = 0x2120, 0x2121
MAIN_CONTACTOR_VOLTAGE = 0x20A8

# controlword / statusword bits (bit n of byte 2 is bit n, of byte 3 bit 8 + n)
CW_A16, CW_A18, CW_ENABLE, CW_ACK, CW_A18_POWER, CW_CW, CW_CCW = 1, 2, 3, 4, 5, 6, 7
CW_PUMP, CW_SAFETY, CW_HANDSHAKE = 8, 9, 15
SW_A16, SW_A18, SW_ENABLED, SW_A19 = 1, 2, 3, 4
SW_EMERGENCY_STOP, SW_IDLE, SW_HANDSHAKE = 11, 14, 15
#: digital inputs CNA13 (3.0), CNA5 (3.1), CNA6 (3.2): CNA6 is active on the thesis rig.
DEFAULT_INPUTS = 0b100

_AMBIENT = 25.0  # degC
_THERMAL_TIME = 300.0  # s, time constant of both temperatures
_IDLE_HZ = 0.005


def _bit(word: int, n: int) -> bool:
    return bool(word >> n & 1)


class ZapiAce2(SimulatedDevice):
    """A ZAPI ACE2 on ``network`` as node ``node_id`` (8 on the thesis rig).

    Options: ``quirks`` (see :attr:`QUIRKS`), ``storage`` (where 1010h "save" keeps the
    parameters: a path, a :class:`~cobus.device.ParameterStorage`, or None for memory kept
    across power cycles of this object), ``ramp_bytes`` 1 or 2 (RPDO1 byte 6 or bytes 6-7),
    ``sync_timeout`` (s without SYNC before the watchdog trips), ``handshake_misses``
    (handshake cycles the drive forgives in a row), ``default_ramp`` (Hz/s when RPDO1 says 0),
    ``background_period`` (s between TPDO2/TPDO4), ``tick`` (s between model steps),
    ``max_speed`` (Hz), ``parameters`` (more manufacturer objects: index -> (name, data type,
    default)).
    """

    kind: ClassVar[str] = "zapi_ace2"
    QUIRKS: ClassVar[Mapping[str, str]] = {
        "no_bootup": "sends no boot-up message when it powers up or resets",
        "no_error_control": "produces no heartbeat and answers no node guarding",
        "pdos_before_start": "sends TPDO2 (288h) and TPDO4 (488h) already in pre-operational",
        "sync_before_start": "refuses NMT start (alarm 248) unless SYNC already runs",
        "handshake": "checks the master's answer to the TPDO1 toggle (byte 3 bit 7) every SYNC "
        "cycle and the SYNC itself; a broken handshake raises alarm 248 (off: the check "
        "disabled on the controller, the toggle still alternates)",
        "fault_to_preoperational": "an alarm drops the controller to pre-operational",
        "save_on_subindex_0": "1010h sub 0 accepts 'save' as sub 1 does",
    }
    FAULTS: ClassVar[Mapping[str, str]] = {
        "alarm": "raise ZAPI alarm code= (default 17 LOGIC FAILURE #3); active=True keeps its "
        "cause until inject('alarm', code=..., active=False); an alarm is cleared by "
        "controlword 2.4 once its cause is gone",
        "contactor_failure": "the main contactor does not close (active=True/False): A16 is "
        "not reported back and the motor gets no power",
        "emergency_stop": "the emergency stop input (statusword 3.3) opens (active=True/False): "
        "the power stage stops the motor",
        "temperature": "set the controller= and/or motor= temperature (degC)",
        "battery": "set the battery charge bdi= (%)",
    }
    #: The parameters each fault takes (kind, "?" when optional): checked when a rig loads.
    FAULT_PARAMS: ClassVar[Mapping[str, Mapping[str, str]]] = {
        "alarm": {"code": "int?", "active": "bool?"},
        "contactor_failure": {"active": "bool?"},
        "emergency_stop": {"active": "bool?"},
        "temperature": {"controller": "number?", "motor": "number?"},
        "battery": {"bdi": "int?"},
    }

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        quirks: Mapping[str, bool] | None = None,
        name: str | None = None,
        storage: str | Path | ParameterStorage | None = None,
        ramp_bytes: int = 1,
        sync_timeout: float = 0.1,
        handshake_misses: int = 0,
        default_ramp: float = 10.0,
        background_period: float = 0.1,
        tick: float = 0.01,
        max_speed: float = 200.0,
        parameters: Mapping[int, tuple[str, DataType, int]] | None = None,
    ) -> None:
        super().__init__(network, node_id, quirks=quirks, name=name)
        if ramp_bytes not in (1, 2):
            raise SimulationError(
                f"ramp_bytes={ramp_bytes!r}: the ramp is RPDO1 byte 6 (1) or bytes 6-7 (2)"
            )
        for what, value in (
            ("sync_timeout", sync_timeout),
            ("default_ramp", default_ramp),
            ("background_period", background_period),
            ("tick", tick),
            ("max_speed", max_speed),
        ):
            if not isinstance(value, int | float) or not value > 0:
                raise SimulationError(f"{what}={value!r} must be a positive number")
        if max_speed > 327.67:
            raise SimulationError(
                f"max_speed={max_speed!r} Hz does not fit TPDO1's actual speed (INTEGER16 of "
                "Hz x 100): use at most 327.67"
            )
        if not isinstance(handshake_misses, int) or handshake_misses < 0:
            raise SimulationError(f"handshake_misses={handshake_misses!r} must be 0 or more")
        self.ramp_bytes = ramp_bytes
        self.sync_timeout = float(sync_timeout)
        self.handshake_misses = handshake_misses
        self.default_ramp = float(default_ramp)
        self.background_period = float(background_period)
        self.tick = float(tick)
        self.max_speed = float(max_speed)
        self.storage: str | Path | ParameterStorage = (
            storage if storage is not None else MemoryStorage()
        )
        self.od = self._dictionary(dict(parameters or {}))
        self.device: Device | None = None
        self._sync_sub: Subscription | None = None
        # physical state, kept while the power is off
        self.controller_temperature = _AMBIENT
        self.motor_temperature = _AMBIENT
        self.bdi = 80
        self.inputs = DEFAULT_INPUTS
        #: analogue inputs 1, 2, 3 as the bytes TPDO1 reports (0-255)
        self.analogue = [0, 0, 0]
        self.contactor_failure = False
        self.emergency_stop = False
        self._reset_volatile()

    # ------------------------------------------------------------------ dictionary
    def _dictionary(self, extra: dict[int, tuple[str, DataType, int]]) -> ObjectDictionary:
        b = DictionaryBuilder(
            device_type=0,  # manufacturer profile
            device_name="ZAPI ACE2",
            vendor_name="ZAPI",
            rpdos=1,
            tpdos=4,
            mapping_entries=8,
        )
        u8, u16, i8, i16 = (
            DataType.UNSIGNED8,
            DataType.UNSIGNED16,
            DataType.INTEGER8,
            DataType.INTEGER16,
        )
        b.variable(MAIN_CONTACTOR_VOLTAGE, "main contactor voltage", u8, default=100, unit="%")
        for index, (pname, dtype, default) in sorted(extra.items()):
            if not 0x2000 <= index <= 0x5FFF or b.od.get(index) is not None:
                raise SimulationError(
                    f"parameter 0x{index:04X}: manufacturer parameters take a free index in "
                    "2000h-5FFFh"
                )
            b.variable(index, pname, dtype, default=default)
        ramp_type = u8 if self.ramp_bytes == 1 else u16
        for index, rname, dtype in (
            (SPEED_SETPOINT, "speed setpoint", u16),
            (CONTROLWORD, "controlword", u16),
            (PEDAL_BRAKE, "pedal brake request", u8),
            (TORQUE, "torque request", u8),
            (RAMP, "acc/dec ramp", ramp_type),
        ):
            b.variable(index, rname, dtype, access="rww", mappable=True, default=0)
        for index, tname, dtype in (
            (ACTUAL_SPEED, "actual speed", i16),
            (STATUSWORD, "statusword", u16),
            (ANALOGUE_3, "analogue input 3", u8),
            (ANALOGUE_1, "analogue input 1", u8),
            (ANALOGUE_2, "analogue input 2", u8),
            (CURRENT, "motor current", u8),
            (ALARM, "alarm code", u8),
            (CONTROLLER_TEMP, "controller temperature", i8),
            (BDI, "battery charge (BDI)", u8),
            (MOTOR_TEMP, "motor temperature", i8),
            (TPDO4_LOW, "TPDO4 word 0 (undocumented)", DataType.UNSIGNED32),
            (TPDO4_HIGH, "TPDO4 word 1 (undocumented)", DataType.UNSIGNED32),
        ):
            b.variable(index, tname, dtype, access="ro", mappable=True, default=0)

        b.rpdo(1, [(i, 0) for i in (SPEED_SETPOINT, CONTROLWORD, PEDAL_BRAKE, TORQUE, RAMP)])
        pad = (0x0005, 0)  # a dummy UNSIGNED8: a byte the controller leaves 0
        b.tpdo(
            1,
            [
                (i, 0)
                for i in (ACTUAL_SPEED, STATUSWORD, ANALOGUE_3, ANALOGUE_1, ANALOGUE_2, CURRENT)
            ],
            transmission_type=1,
        )
        period_ms = max(1, round(self.background_period * 1000))
        tpdo2 = [(ALARM, 0), pad, pad, pad, (CONTROLLER_TEMP, 0), (BDI, 0), (MOTOR_TEMP, 0), pad]
        b.tpdo(2, tpdo2, transmission_type=255, event_timer_ms=period_ms)
        b.tpdo(
            4, [(TPDO4_LOW, 0), (TPDO4_HIGH, 0)], transmission_type=255, event_timer_ms=period_ms
        )
        od = b.build()
        comm3 = od.get_variable(0x1802, 1)
        assert comm3 is not None
        comm3.default = 0x80000000 | tpdo_cob_id(3, self.node_id)  # TPDO3 is not used
        return od

    # ------------------------------------------------------------------ life cycle
    def _deviations(self) -> Deviations:
        q = self.quirks
        return Deviations(
            send_bootup=not q["no_bootup"],
            error_control=not q["no_error_control"],
            tpdos_outside_operational=frozenset({2, 4}) if q["pdos_before_start"] else (),
            store_on_subindex_0=q["save_on_subindex_0"],
            # an expedited write without size indication (22h) to an 8- or 16-bit object
            # carries 4 bytes: the controller takes the object's size, as CiA 301 allows
            padded_writes=True,
        )

    def start(self) -> None:
        if self.powered:
            return
        other = self.network.devices.get(self.node_id)
        if other is not None:
            raise SimulationError(
                f"{self.name}: node-ID {self.node_id} is already used by {other!r} on this "
                "network; give the controller a free node-ID"
            )
        super().start()
        self._reset_volatile()
        # SYNC is seen here before the device's own PDO processing (subscribed first), so
        # TPDO1 carries the toggle of this cycle
        self._sync_sub = self.network.subscribe(0x80, self._on_sync)
        device = Device(
            self.network, self.node_id, self.od, storage=self.storage, deviations=self._deviations()
        )
        self.device = device
        for index, reader in (
            (ACTUAL_SPEED, lambda: round(self.speed * 100)),
            (STATUSWORD, self.statusword),
            (ANALOGUE_3, lambda: self.analogue[2]),
            (ANALOGUE_1, lambda: self.analogue[0]),
            (ANALOGUE_2, lambda: self.analogue[1]),
            (CURRENT, lambda: min(255, round(self.current))),
            (ALARM, lambda: self.alarm),
            (CONTROLLER_TEMP, lambda: _i8(self.controller_temperature)),
            (BDI, lambda: self.bdi),
            (MOTOR_TEMP, lambda: _i8(self.motor_temperature)),
        ):
            device.on_read(index, 0, reader)
        device.on_write(CONTROLWORD, 0, self._on_controlword)
        device.add_listener(self._on_device_event)
        device.start()
        self.every(self.tick, self._step)

    def power_off(self) -> None:
        if self._sync_sub is not None:
            self._sync_sub.cancel()
            self._sync_sub = None
        if self.device is not None:
            self.device.close()
            self.device = None
        super().power_off()
        self._reset_volatile()

    def _reset_volatile(self) -> None:
        self.speed = 0.0  # Hz, clockwise > 0
        self.current = 0.0
        self.alarms: dict[int, bool] = {}  # code -> its cause is still there
        self.toggle = 0
        self._handshake_started = False  # a TPDO1 went out since the last start
        self._answer: int | None = None  # handshake bit of the last RPDO1 this cycle
        self._misses = 0
        self._last_sync: float | None = None
        self._ack = False

    # ------------------------------------------------------------------ values
    def _get(self, index: int) -> int:
        device = self.device
        if device is None:
            return 0
        value: int = device.get(index, 0)
        return value

    @property
    def state(self) -> NmtState | None:
        """The NMT state (None while the power is off)."""
        return self.device.state if self.device is not None else None

    @property
    def controlword(self) -> int:
        """The controlword the inverter last received (RPDO1 bytes 2-3)."""
        return self._get(CONTROLWORD)

    @property
    def setpoint(self) -> float:
        """The commanded speed in Hz (signed by the direction bits)."""
        cw = self.controlword
        magnitude = self._get(SPEED_SETPOINT) / 100
        if _bit(cw, CW_CW) == _bit(cw, CW_CCW):
            return 0.0
        return magnitude if _bit(cw, CW_CW) else -magnitude

    @property
    def alarm(self) -> int:
        """The alarm code TPDO2 reports: the oldest active alarm, 0 when none."""
        return next(iter(self.alarms), 0)

    @property
    def contactor_closed(self) -> bool:
        """Whether the main contactor (A16) is closed: asked for, no failure, no alarm."""
        return _bit(self.controlword, CW_A16) and not self.contactor_failure and not self.alarms

    @property
    def power_stage_on(self) -> bool:
        """Power stage on: operational, enabled, contactor closed, no emergency stop."""
        return (
            self.state is NmtState.OPERATIONAL
            and _bit(self.controlword, CW_ENABLE)
            and self.contactor_closed
            and not self.emergency_stop
        )

    def statusword(self) -> int:
        """The statusword the inverter sends (TPDO1 bytes 2-3)."""
        cw = self.controlword
        operational = self.state is NmtState.OPERATIONAL
        word = 0
        if self.contactor_closed and operational:
            word |= 1 << SW_A16
        if _bit(cw, CW_A18) and not self.alarms and operational:
            word |= 1 << SW_A18
        if _bit(cw, CW_ENABLE) and not self.alarms and operational:
            word |= 1 << SW_ENABLED
        word |= (self.inputs & 0b111) << 8
        if self.emergency_stop:
            word |= 1 << SW_EMERGENCY_STOP
        if abs(self.speed) < _IDLE_HZ:
            word |= 1 << SW_IDLE
        if self.toggle:
            word |= 1 << SW_HANDSHAKE
        return word

    def status(self) -> dict[str, Any]:
        state = self.state
        alarm = self.alarm
        if not self.quirks["handshake"]:
            handshake = "off"
        elif state is not NmtState.OPERATIONAL:
            handshake = "idle"
        else:
            handshake = "running" if self._handshake_started else "waiting"
        return {
            **super().status(),
            "state": state.name.lower() if state is not None else "off",
            "speed_hz": round(self.speed, 3),
            "setpoint_hz": self.setpoint,
            "current_a": round(self.current, 1),
            "controlword": self.controlword,
            "statusword": self.statusword() if self.device is not None else 0,
            "alarm": alarm,
            "alarm_text": alarm_text(alarm) if alarm else "",
            "alarms": list(self.alarms),
            "controller_temperature": round(self.controller_temperature, 1),
            "motor_temperature": round(self.motor_temperature, 1),
            "bdi": self.bdi,
            "handshake": handshake,
            "toggle": self.toggle,
        }

    # ------------------------------------------------------------------ alarms
    def raise_alarm(self, code: int, *, active: bool = False) -> None:
        """Raise ZAPI alarm ``code``: functions aborted, TPDO2 reports it, and the controller
        drops to pre-operational (quirk ``fault_to_preoperational``). ``active`` keeps its
        cause (it cannot be acknowledged) until :meth:`alarm_cause_gone`."""
        if not isinstance(code, int) or not 1 <= code <= 255:
            raise SimulationError(f"ZAPI alarm code {code!r} must be 1..255 (TPDO2 byte 0)")
        new = code not in self.alarms
        self.alarms[code] = active or self.alarms.get(code, False)
        if not new:
            return
        device = self.device
        if device is None:
            return
        self._alarm_changed()
        if self.quirks["fault_to_preoperational"] and device.state is NmtState.OPERATIONAL:
            device.apply_nmt(NmtCommand.ENTER_PREOPERATIONAL)

    def alarm_cause_gone(self, code: int) -> None:
        """The cause of alarm ``code`` is gone: the next acknowledge clears it."""
        if code in self.alarms:
            self.alarms[code] = False

    def _acknowledge(self) -> None:
        before = self.alarm
        self.alarms = {code: held for code, held in self.alarms.items() if held}
        if before != self.alarm:
            self._alarm_changed()

    def _alarm_changed(self) -> None:
        """TPDO2 reports a new alarm code at once (where it transmits in this state)."""
        device = self.device
        if device is None:
            return
        with contextlib.suppress(DeviceConfigError):  # unless a master switched TPDO2 off
            device.send_tpdo(2)

    # ------------------------------------------------------------------ bus side
    def _on_controlword(self, value: int) -> None:
        ack = _bit(value, CW_ACK)
        if ack and not self._ack:
            self._acknowledge()
        self._ack = ack

    def _on_device_event(self, event: DeviceEvent) -> None:
        if isinstance(event, RpdoReceived) and event.number == 1:
            for (index, _), value in zip(event.entries, event.values, strict=True):
                if index == CONTROLWORD:
                    self._answer = value >> CW_HANDSHAKE & 1
        elif isinstance(event, StateChanged):
            self._state_changed(event.old, event.new)
        elif isinstance(event, Booted):
            self._ack = False
            device = self.device
            if device is not None:  # process values do not survive a reset
                for index in (SPEED_SETPOINT, CONTROLWORD, PEDAL_BRAKE, TORQUE, RAMP):
                    device.set(index, 0, 0)

    def _state_changed(self, old: NmtState, new: NmtState) -> None:
        self._handshake_started = False
        self._answer = None
        self._misses = 0
        self.toggle = 0
        self._cancel_sync_watchdog()
        if new is not NmtState.OPERATIONAL or not self.quirks["handshake"]:
            return
        now = self.network.time()
        last = self._last_sync
        if self.quirks["sync_before_start"]:
            if last is None or now - last > self.sync_timeout:
                self.raise_alarm(CAN_BUS_KO)
                return
            self._arm_sync_watchdog(last)

    def _cancel_sync_watchdog(self) -> None:
        handle = self._timers.pop("sync", None)
        if handle is not None:
            handle.cancel()

    def _arm_sync_watchdog(self, since: float) -> None:
        self._cancel_sync_watchdog()
        self._timers["sync"] = self.network.loop.call_at(since + self.sync_timeout, self._sync_lost)

    def _sync_lost(self) -> None:
        self._timers.pop("sync", None)
        if self.state is NmtState.OPERATIONAL:
            self.raise_alarm(CAN_BUS_KO)

    def _on_sync(self, frame: Frame, now: float) -> None:
        device = self.device
        if (
            device is None
            or frame.rtr
            or device.state
            not in (
                NmtState.PRE_OPERATIONAL,
                NmtState.OPERATIONAL,
            )
        ):
            return
        self._last_sync = now
        if device.state is not NmtState.OPERATIONAL:
            return
        check = self.quirks["handshake"]
        if check:
            self._arm_sync_watchdog(now)
        if self._handshake_started:
            if check and self._answer != 1 - self.toggle:
                self._misses += 1
                if self._misses > self.handshake_misses:
                    self.raise_alarm(CAN_BUS_KO)
                    return
            else:
                self._misses = 0
            self.toggle ^= 1
        else:
            self._handshake_started = True
            self.toggle = 0
        self._answer = None

    # ------------------------------------------------------------------ physics
    def _step(self, dt: float) -> None:
        if self.device is None:
            return
        target = 0.0
        pedal = self._get(PEDAL_BRAKE)
        if self.power_stage_on and not pedal:
            target = max(-self.max_speed, min(self.max_speed, self.setpoint))
        ramp_raw = self._get(RAMP)
        rate = ramp_raw / 10 if ramp_raw else self.default_ramp
        before = self.speed
        step = rate * dt
        if abs(target - before) <= step:
            self.speed = target
        else:
            self.speed = before + math.copysign(step, target - before)
        accel = (self.speed - before) / dt if dt > 0 else 0.0
        if self.power_stage_on or abs(self.speed) >= _IDLE_HZ:
            self.current = 2.0 + 0.1 * abs(self.speed) + 0.5 * abs(accel)
        else:
            self.current = 0.0
        # first-order heating by the current, cooling to the ambient temperature
        k = dt / _THERMAL_TIME
        self.controller_temperature += (
            _AMBIENT + 0.2 * self.current - self.controller_temperature
        ) * k
        self.motor_temperature += (_AMBIENT + 0.3 * self.current - self.motor_temperature) * k

    # ------------------------------------------------------------------ faults
    def inject(self, fault: str, **params: Any) -> None:
        if fault == "alarm":
            code = int(params.get("code", 17))
            active = params.get("active")
            if active is False:
                self.alarm_cause_gone(code)
            else:
                self.raise_alarm(code, active=bool(active))
        elif fault == "contactor_failure":
            self.contactor_failure = bool(params.get("active", True))
        elif fault == "emergency_stop":
            self.emergency_stop = bool(params.get("active", True))
        elif fault == "temperature":
            if "controller" in params:
                self.controller_temperature = float(params["controller"])
            if "motor" in params:
                self.motor_temperature = float(params["motor"])
        elif fault == "battery":
            bdi = int(params.get("bdi", 0))
            if not 0 <= bdi <= 100:
                raise SimulationError(f"battery charge bdi={bdi!r} must be 0..100 %")
            self.bdi = bdi
        else:
            super().inject(fault, **params)


def _i8(value: float) -> int:
    return max(-128, min(127, round(value)))
