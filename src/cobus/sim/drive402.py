"""A CiA 402 servo drive with a motor model (kind ``cia402_drive``).

**State machine** (controlword 6040h, statusword 6041h): Not ready to switch on -> Switch on
disabled -> Ready to switch on -> Switched on -> Operation enabled, Quick stop active, Fault
reaction active, Fault, with the commands Shutdown, Switch on, Enable operation, Disable
voltage, Quick stop, Disable operation and Fault reset (rising edge of bit 7). The quick stop
option code 605Ah (0 coast, 1/5 profile deceleration, 2/6 quick stop deceleration 6085h; 1-4
end in Switch on disabled, 5-8 stay in Quick stop active) and the fault reaction option code
605Eh (0 coast, 1 profile deceleration, 2 quick stop deceleration) apply. The abort
connection option code 6007h (0 nothing, 1 fault 8100h, 2 disable voltage, 3 quick stop)
applies when a heartbeat or life guarding is lost, the node is stopped or reset by NMT.

**Modes of operation** (6060h, shown in 6061h):

- 1 profile position: target 607Ah, profile velocity 6081h (capped by 607Fh), acceleration
  6083h, deceleration 6084h; new set-point bit 4 / set-point acknowledge bit 12, change set
  immediately bit 5 (else one set-point is buffered), relative bit 6 (to the previous target),
  halt bit 8, target reached bit 10 (within 6067h for 6068h ms), following error bit 13;
  software position limits 607Dh (min >= max: none) clamp targets (bit 11).
- 3 profile velocity: target velocity 60FFh, ramps 6083h/6084h, halt; target reached bit 10
  (within 606Dh for 606Eh ms), bit 12 speed zero (below 606Fh).
- 4 profile torque: target torque 6071h (per mille of 6076h) with the slope 6087h; the speed
  is limited to 6080h.
- 6 homing: method 6098h (the supported ones listed in 60E3h) — 1/2 limit switch
  negative/positive then the encoder index pulse, 17/18 limit switch negative/positive,
  35/37 the current position; speeds 6099h (sub 1 search for the switch, sub 2 search for
  zero), acceleration 609Ah, home offset 607Ch (the position the home point gets); start
  with the rising edge of bit 4; bit 12 homing attained, bit 13 homing error.
- 7 interpolated position (linear, 60C0h = 0): while controlword bit 4 "enable ip mode"
  is set, the set-point 60C1h sub 1 is taken at each SYNC and interpolated over the period
  as in cyclic synchronous position; bit 12 "ip mode active".
- 8/9/10 cyclic synchronous position/velocity/torque: 607Ah/60FFh/6071h are taken at each
  SYNC (received by RPDO of any type); positions are interpolated over the SYNC period
  (60C2h when set, else the measured interval); bit 12 "drive follows the command value".

Actual values: 6064h position (6063h, the same: user unit = encoder increment), 606Ch
velocity (increments/s), 6077h torque and 6078h current (per mille of rated), 60F4h following
error (6062h demand minus 6064h), 60FDh digital inputs (bit 0 negative limit switch, bit 1
positive limit switch), 2000h motor temperature (0.1 °C).

**Faults**: following error (|60F4h| > 6065h for longer than 6066h ms) EMCY 8611h, error
register bit 5 (device profile); motor overtemperature 4310h (temperature); overcurrent 2310h
(current); the error code is in 603Fh; the generic bit of 1001h is set while any is active.

**Motor model**, integrated in steps of at most 1 ms of network time: inertia, viscous and
Coulomb friction, load torque, torque limit (6072h/6073h of the rated torque/current),
encoder resolution, index pulse, limit switches at machine positions, a first-order thermal
model (winding temperature rises with the square of the current). The drive closes a
position loop (in profile position, homing, cyclic position and while ramping to a stop) and
a PI velocity loop with velocity and acceleration feed-forward. An incremental encoder: after
each power-on the position counts from 0 and homing attained is cleared.

**Default PDOs** (transmission type 255 unless said): RPDO1 6040h; RPDO2 6040h + 6060h; RPDO3
6040h + 607Ah; RPDO4 6040h + 60FFh; TPDO1 6041h; TPDO2 6041h + 6064h (type 1); TPDO3 6041h +
606Ch (type 1); TPDO4 6041h + 6077h (type 1).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, ClassVar

from cobus._enum import NamedIntEnum
from cobus._moved import renamed_names
from cobus.device import (
    Device,
    DeviceEvent,
    DictionaryBuilder,
    EntryWritten,
    HeartbeatLost,
    LifeGuardingLost,
    NmtCommandReceived,
    RpdoReceived,
    StateChanged,
)
from cobus.device.events import Booted
from cobus.od import DataType, ObjectDictionary
from cobus.profiles.cia402 import (
    STATE_BITS,
    Command,
    PowerState,
    Transition,
    command_of,
    transition,
)
from cobus.proto import Frame
from cobus.proto.emcy import EmcyCode, ErrorRegister
from cobus.proto.nmt import NmtCommand, NmtState
from cobus.proto.sdo import SdoAbort, SdoAbortCode
from cobus.runtime.network import AsyncNetwork, Subscription
from cobus.sim.base import SimulationError
from cobus.sim.generic import CanopenSimDevice, FaultParameterError, check_fault_params

__all__ = ["DriveState", "Mode", "SimulatedDrive402"]

_I32_MIN, _I32_MAX = -(2**31), 2**31 - 1
_I16_MIN, _I16_MAX = -(2**15), 2**15 - 1
_MAX_STEP = 0.001  # seconds: the longest physics step


#: The states of the CiA 402 drive state machine (the master side's own enum: one set of
#: states for both sides).
DriveState = PowerState


class Mode(NamedIntEnum):
    """The modes of operation this drive supports (6060h values)."""

    PROFILE_POSITION = 1
    PROFILE_VELOCITY = 3
    PROFILE_TORQUE = 4
    HOMING = 6
    INTERPOLATED_POSITION = 7
    CYCLIC_SYNC_POSITION = 8
    CYCLIC_SYNC_VELOCITY = 9
    CYCLIC_SYNC_TORQUE = 10


_S = DriveState
#: Statusword bits 0-3, 5, 6 of each state, as the master side decodes them (bit 4 "voltage
#: enabled" is added separately).
_STATE_BITS = STATE_BITS
_VOLTAGE = frozenset(
    (
        _S.READY_TO_SWITCH_ON,
        _S.SWITCHED_ON,
        _S.OPERATION_ENABLED,
        _S.QUICK_STOP_ACTIVE,
        _S.FAULT_REACTION_ACTIVE,
        _S.FAULT,
    )
)
_HOMING_METHODS = frozenset((1, 2, 17, 18, 35, 37))
_SUPPORTED_MODES = 0x1 | 0x4 | 0x8 | 0x20 | 0x40 | 0x80 | 0x100 | 0x200  # 6502h bits
_CYCLIC = frozenset(
    (
        Mode.INTERPOLATED_POSITION,
        Mode.CYCLIC_SYNC_POSITION,
        Mode.CYCLIC_SYNC_VELOCITY,
        Mode.CYCLIC_SYNC_TORQUE,
    )
)

# controlword bits
_CW_NEW_SETPOINT = 0x0010
_CW_IMMEDIATE = 0x0020
_CW_RELATIVE = 0x0040
_CW_FAULT_RESET = 0x0080
_CW_HALT = 0x0100
# statusword bits
_SW_WARNING = 0x0080
_SW_REMOTE = 0x0200
_SW_TARGET_REACHED = 0x0400
_SW_INTERNAL_LIMIT = 0x0800
_SW_BIT12 = 0x1000
_SW_BIT13 = 0x2000

# control structure of a step
_POSITION, _VELOCITY, _TORQUE, _OFF = "position", "velocity", "torque", "off"

FOLLOWING_ERROR = 0x8611
MOTOR_OVERTEMPERATURE = 0x4310
OVERCURRENT = 0x2310
COMMUNICATION_FAULT = int(EmcyCode.COMMUNICATION)


def _positive(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
        raise SimulationError(f"cia402_drive: {name} {value!r} must be a number above 0")
    return float(value)


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SimulationError(f"cia402_drive: {name} {value!r} must be a number")
    return float(value)


def _clamp_int(value: float, low: int, high: int) -> int:
    return max(low, min(high, round(value)))


def _approach(value: float, target: float, up: float, down: float) -> float:
    """``value`` moved toward ``target`` in one step: by at most ``up`` while its magnitude
    grows, by at most ``down`` while it shrinks (through zero first when the sign changes)."""
    if value == target:
        return value
    if value != 0.0 and (target == 0.0 or (target > 0) != (value > 0)):
        if abs(value) <= down:
            return 0.0 if target == 0.0 or (target > 0) != (value > 0) else target
        return value - math.copysign(down, value)
    step = up if abs(target) > abs(value) else down
    if abs(target - value) <= step:
        return target
    return value + math.copysign(step, target - value)


class _Motor:
    """The mechanics, the encoder and the winding temperature of the motor."""

    def __init__(
        self,
        *,
        inertia: float,
        viscous_friction: float,
        coulomb_friction: float,
        load_torque: float,
        rated_torque: float,
        rated_current: float,
        resolution: int,
        position: float,
        ambient: float,
        rise: float,
        time_constant: float,
    ) -> None:
        self.inertia = inertia
        self.viscous = viscous_friction
        self.coulomb = coulomb_friction
        self.load = load_torque
        self.rated_torque = rated_torque
        self.rated_current = rated_current
        self.kt = rated_torque / rated_current  # N·m per A
        self.resolution = resolution
        self.rad_per_inc = 2 * math.pi / resolution
        self.theta = position * self.rad_per_inc  # rad, machine position
        self.omega = 0.0  # rad/s
        self.torque = 0.0  # N·m produced by the motor
        self.ambient = ambient
        self.rise = rise
        self.time_constant = time_constant
        self.temperature = ambient
        self.blocked = False

    @property
    def raw(self) -> float:
        """The machine position in encoder increments."""
        return self.theta / self.rad_per_inc

    @property
    def speed(self) -> float:
        """Increments per second."""
        return self.omega / self.rad_per_inc

    @property
    def current(self) -> float:
        return self.torque / self.kt

    def step(self, torque: float, h: float) -> None:
        self.torque = torque
        if self.blocked:
            self.omega = 0.0
        else:
            omega = self.omega
            drive = torque - self.load - self.viscous * omega
            if omega == 0.0 and abs(drive) <= self.coulomb:
                pass  # static friction holds the shaft
            else:
                direction = omega if omega != 0.0 else drive
                net = drive - math.copysign(self.coulomb, direction)
                new = omega + net / self.inertia * h
                if omega != 0.0 and (new > 0) != (omega > 0) and abs(drive) <= self.coulomb:
                    new = 0.0  # friction brought it to rest within the step
                self.theta += (omega + new) / 2 * h
                self.omega = new
        heat = (self.current / self.rated_current) ** 2 * self.rise
        self.temperature += (heat - (self.temperature - self.ambient)) / self.time_constant * h

    def cool(self, seconds: float) -> None:
        """Time passes without power: the shaft stops, the winding cools toward ambient."""
        self.omega = 0.0
        self.torque = 0.0
        if seconds > 0:
            excess = self.temperature - self.ambient
            self.temperature = self.ambient + excess * math.exp(-seconds / self.time_constant)


class SimulatedDrive402(CanopenSimDevice):
    """A CiA 402 servo drive (see the module docstring).

    Model options (SI units; positions in encoder increments): ``inertia`` (kg·m², default
    0.0002), ``viscous_friction`` (N·m·s/rad, 0.0005), ``coulomb_friction`` (N·m, 0.02),
    ``load_torque`` (N·m, 0), ``rated_torque`` (N·m, 1.0), ``rated_current`` (A, 4.0),
    ``encoder_resolution`` (increments per revolution, 4096), ``index_offset`` (increment of
    the index pulse within a revolution, 0), ``position`` (machine position at the start, 0),
    ``negative_limit`` / ``positive_limit`` (machine positions of the limit switches; None:
    none), ``bandwidth`` (Hz of the velocity loop, 30), ``ambient_temperature`` (°C, 25),
    ``temperature_rise`` (K at rated current, 60), ``thermal_time_constant`` (s, 60),
    ``temperature_warning`` (°C, 100), ``temperature_limit`` (°C, 120), ``overcurrent_trip``
    (multiple of the rated current, 3.5), ``tick`` (seconds between model updates, 0.001).
    """

    kind = "cia402_drive"
    FAULTS: ClassVar[Mapping[str, str]] = {
        **CanopenSimDevice.FAULTS,
        "blocked_rotor": (
            "the load jams: the shaft cannot turn; a moving axis builds up a following error "
            "(fault 8611h once past 6065h for 6066h ms); free_rotor ends it"
        ),
        "free_rotor": "the jammed load comes free",
        "overtemperature": (
            "the motor winding is at temperature °C (default 5 K above the limit): fault 4310h, "
            "which cannot be reset until the winding has cooled 10 K below the limit"
        ),
        "overcurrent": (
            "a short circuit at the motor output: the power stage switches off at once, fault 2310h"
        ),
        "drive_fault": (
            "any other drive fault with EMCY code (default 5000h, hardware) and register bits "
            "(default: from the code's class); a fault reset clears it"
        ),
    }
    #: The parameters each fault takes (kind, "?" when optional): checked when a rig loads.
    FAULT_PARAMS: ClassVar[Mapping[str, Mapping[str, str]]] = {
        "blocked_rotor": {},
        "free_rotor": {},
        "overtemperature": {"temperature": "number?"},
        "overcurrent": {},
        "drive_fault": {"code": "int?", "register": "int?"},
    }

    def __init__(
        self,
        network: AsyncNetwork,
        node_id: int,
        *,
        inertia: float = 0.0002,
        viscous_friction: float = 0.0005,
        coulomb_friction: float = 0.02,
        load_torque: float = 0.0,
        rated_torque: float = 1.0,
        rated_current: float = 4.0,
        encoder_resolution: int = 4096,
        index_offset: int = 0,
        position: int = 0,
        negative_limit: int | None = None,
        positive_limit: int | None = None,
        bandwidth: float = 30.0,
        ambient_temperature: float = 25.0,
        temperature_rise: float = 60.0,
        thermal_time_constant: float = 60.0,
        temperature_warning: float = 100.0,
        temperature_limit: float = 120.0,
        overcurrent_trip: float = 3.5,
        tick: float = 0.001,
        **options: Any,
    ) -> None:
        if (
            isinstance(encoder_resolution, bool)
            or not isinstance(encoder_resolution, int)
            or encoder_resolution < 4
        ):
            raise SimulationError(
                f"cia402_drive: encoder_resolution {encoder_resolution!r} must be an integer "
                "of at least 4 increments per revolution"
            )
        for name, limit in (("negative_limit", negative_limit), ("positive_limit", positive_limit)):
            if limit is not None:
                _number(name, limit)
        if (
            negative_limit is not None
            and positive_limit is not None
            and not negative_limit < position < positive_limit
        ):
            raise SimulationError(
                f"cia402_drive: the start position {position} must lie between the limit "
                f"switches ({negative_limit} .. {positive_limit})"
            )
        if not _number("temperature_warning", temperature_warning) < _number(
            "temperature_limit", temperature_limit
        ):
            raise SimulationError(
                "cia402_drive: temperature_warning must be below temperature_limit"
            )
        self.motor = _Motor(
            inertia=_positive("inertia", inertia),
            viscous_friction=max(0.0, _number("viscous_friction", viscous_friction)),
            coulomb_friction=max(0.0, _number("coulomb_friction", coulomb_friction)),
            load_torque=_number("load_torque", load_torque),
            rated_torque=_positive("rated_torque", rated_torque),
            rated_current=_positive("rated_current", rated_current),
            resolution=encoder_resolution,
            position=_number("position", position),
            ambient=_number("ambient_temperature", ambient_temperature),
            rise=max(0.0, _number("temperature_rise", temperature_rise)),
            time_constant=_positive("thermal_time_constant", thermal_time_constant),
        )
        self.index_offset = int(_number("index_offset", index_offset)) % encoder_resolution
        self.negative_limit = negative_limit
        self.positive_limit = positive_limit
        self.temperature_warning = float(temperature_warning)
        self.temperature_limit = float(temperature_limit)
        self.overcurrent_trip = _positive("overcurrent_trip", overcurrent_trip) * rated_current
        self.tick = _positive("tick", tick)
        omega_v = 2 * math.pi * _positive("bandwidth", bandwidth)
        self._kp_v = inertia * omega_v  # N·m per rad/s
        self._ki_v = self._kp_v * omega_v / 4
        self._kp_p = omega_v / 6  # 1/s
        self._sync_sub: Subscription | None = None
        self._sync_cob = 0x80
        self._last_sync: float | None = None
        self._off_since: float | None = None
        self._cache: dict[int, int] = {}
        self._offset = -self.motor.raw
        super().__init__(network, node_id, **options)
        self._reset_application()

    # ================================================================== dictionary
    def build_od(self) -> ObjectDictionary:
        m = self.motor
        b = DictionaryBuilder(
            device_type=0x00020192,
            device_name="cobus CiA 402 drive",
            vendor_id=0x00C0B005,
            product_code=402,
            revision=1,
            hardware_version="sim",
            software_version="1.0",
        )
        I8, I16, I32 = DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER32
        U16, U32 = DataType.UNSIGNED16, DataType.UNSIGNED32

        def var(index: int, name: str, dt: DataType, access: str = "rw", **kw: Any) -> None:
            b.variable(index, name, dt, access=access, **kw)

        var(0x2000, "Motor temperature", I16, "ro", mappable=True, default=0, unit="0.1 °C")
        var(0x6007, "Abort connection option code", I16, default=2, low=0, high=3)
        var(0x603F, "Error code", U16, "ro", mappable=True, default=0)
        var(0x6040, "Controlword", U16, "rww", mappable=True, default=0)
        var(0x6041, "Statusword", U16, "ro", mappable=True, default=0)
        var(0x605A, "Quick stop option code", I16, default=2, low=0, high=8)
        var(0x605E, "Fault reaction option code", I16, default=2, low=0, high=2)
        var(0x6060, "Modes of operation", I8, "rww", mappable=True, default=1)
        var(0x6061, "Modes of operation display", I8, "ro", mappable=True, default=0)
        var(0x6062, "Position demand value", I32, "ro", mappable=True, default=0)
        var(0x6063, "Position actual internal value", I32, "ro", mappable=True, default=0)
        var(0x6064, "Position actual value", I32, "ro", mappable=True, default=0)
        var(0x6065, "Following error window", U32, default=2000)
        var(0x6066, "Following error time out", U16, default=10, unit="ms")
        var(0x6067, "Position window", U32, default=20)
        var(0x6068, "Position window time", U16, default=10, unit="ms")
        var(0x606B, "Velocity demand value", I32, "ro", mappable=True, default=0)
        var(0x606C, "Velocity actual value", I32, "ro", mappable=True, default=0)
        var(0x606D, "Velocity window", U16, default=100)
        var(0x606E, "Velocity window time", U16, default=10, unit="ms")
        var(0x606F, "Velocity threshold", U16, default=20)
        var(0x6071, "Target torque", I16, "rww", mappable=True, default=0)
        var(0x6072, "Max torque", U16, "rww", mappable=True, default=3000)
        var(0x6073, "Max current", U16, default=3000)
        var(0x6074, "Torque demand", I16, "ro", mappable=True, default=0)
        var(
            0x6075,
            "Motor rated current",
            U32,
            "ro",
            default=round(m.rated_current * 1000),
            unit="mA",
        )
        var(
            0x6076,
            "Motor rated torque",
            U32,
            "ro",
            default=round(m.rated_torque * 1000),
            unit="mNm",
        )
        var(0x6077, "Torque actual value", I16, "ro", mappable=True, default=0)
        var(0x6078, "Current actual value", I16, "ro", mappable=True, default=0)
        var(0x607A, "Target position", I32, "rww", mappable=True, default=0)
        var(0x607C, "Home offset", I32, default=0)
        b.record(0x607D, "Software position limit")
        b.variable(0x607D, "Min position limit", I32, subindex=1, default=0)
        b.variable(0x607D, "Max position limit", I32, subindex=2, default=0)
        var(0x607F, "Max profile velocity", U32, default=200_000)
        var(0x6080, "Max motor speed", U32, default=250_000)
        var(0x6081, "Profile velocity", U32, "rww", mappable=True, default=50_000)
        var(0x6083, "Profile acceleration", U32, "rww", mappable=True, default=500_000)
        var(0x6084, "Profile deceleration", U32, "rww", mappable=True, default=500_000)
        var(0x6085, "Quick stop deceleration", U32, default=2_000_000)
        var(0x6087, "Torque slope", U32, default=10_000)
        var(0x6098, "Homing method", I8, default=37)
        methods = b.array(0x60E3, "Supported homing methods", I8, len(_HOMING_METHODS), access="ro")
        for n, method in enumerate(sorted(_HOMING_METHODS), 1):
            methods[n].default = method
        b.record(0x6099, "Homing speeds")
        b.variable(0x6099, "Speed during search for switch", U32, subindex=1, default=20_000)
        b.variable(0x6099, "Speed during search for zero", U32, subindex=2, default=2_000)
        var(0x609A, "Homing acceleration", U32, default=200_000)
        b.record(0x60C2, "Interpolation time period")
        b.variable(
            0x60C2, "Interpolation time period value", DataType.UNSIGNED8, subindex=1, default=0
        )
        b.variable(
            0x60C2, "Interpolation time index", I8, subindex=2, default=-3, low=-128, high=63
        )
        var(0x60C0, "Interpolation sub mode select", I16, default=0, low=0, high=0)
        b.record(0x60C1, "Interpolation data record")
        b.variable(
            0x60C1,
            "Interpolation position set-point",
            I32,
            subindex=1,
            access="rww",
            mappable=True,
            default=0,
        )
        var(0x60F4, "Following error actual value", I32, "ro", mappable=True, default=0)
        var(0x60FD, "Digital inputs", U32, "ro", mappable=True, default=0)
        var(0x60FF, "Target velocity", I32, "rww", mappable=True, default=0)
        var(0x6502, "Supported drive modes", U32, "ro", default=_SUPPORTED_MODES)
        b.rpdo(1, [(0x6040, 0)])
        b.rpdo(2, [(0x6040, 0), (0x6060, 0)])
        b.rpdo(3, [(0x6040, 0), (0x607A, 0)])
        b.rpdo(4, [(0x6040, 0), (0x60FF, 0)])
        b.tpdo(1, [(0x6041, 0)])
        b.tpdo(2, [(0x6041, 0), (0x6064, 0)], transmission_type=1)
        b.tpdo(3, [(0x6041, 0), (0x606C, 0)], transmission_type=1)
        b.tpdo(4, [(0x6041, 0), (0x6077, 0)], transmission_type=1)
        return b.build()

    def bind(self, device: Device) -> None:
        device.on_write(0x6060, 0, self._check_mode)
        device.on_write(0x6098, 0, self._check_homing_method)
        self._cache.clear()

    @staticmethod
    def _check_mode(value: Any) -> None:
        if value not in Mode.__members__.values():
            modes = ", ".join(f"{int(m)} {m.name.lower()}" for m in Mode)
            raise SdoAbort(
                SdoAbortCode.INVALID_VALUE,
                f"mode of operation {value} is not supported; this drive has {modes}",
            )

    @staticmethod
    def _check_homing_method(value: Any) -> None:
        if value not in _HOMING_METHODS:
            raise SdoAbort(
                SdoAbortCode.INVALID_VALUE,
                f"homing method {value} is not supported; this drive has "
                f"{', '.join(str(m) for m in sorted(_HOMING_METHODS))}",
            )

    # ================================================================== life cycle
    def _reset_application(self) -> None:
        """The drive application starts over (power-on, NMT reset node)."""
        self.state = DriveState.NOT_READY_TO_SWITCH_ON
        self._cw = 0
        self.mode: int = int(self._od(0x6060, 0, 0))
        self._error_code = 0
        self._fault_reason = ""
        self._stop_decel = 0.0
        self._stop_then: DriveState | None = None
        self._fe_time = 0.0
        self._homed = False
        self._init_control()

    def _init_control(self) -> None:
        """Demand values start from where the motor is (no jump on enable or mode change)."""
        self._p_d = self._p_act()
        self._v_d = 0.0
        self._t_d = 0.0  # per mille
        self._a_d = 0.0
        self._integral = 0.0
        self._control = _OFF
        # profile position
        self._target = self._p_d
        self._moving = False
        self._buffer: float | None = None
        self._ack = False
        self._in_window = 0.0
        # profile velocity / torque and cyclic modes
        self._cyclic_target: float | None = None
        self._csp_left = 0.0
        self._csp_v = 0.0
        self._halted = False
        self._limited = False
        # homing
        self._homing: str | None = None
        self._homing_error = False
        self._homing_dir = 0
        self._homing_index = False
        self._index_raw = 0.0
        self._found = False
        self._stop_hold = 0.0

    def on_power_on(self) -> None:
        now = self.network.time()
        if self._off_since is not None:
            self.motor.cool(now - self._off_since)
            self._off_since = None
        self.motor.omega = 0.0
        self._offset = -self.motor.raw  # incremental encoder: counts from 0
        self._reset_application()
        self._subscribe_sync()
        self.every(self.tick, self._tick)
        self._step(0.0)
        self._publish()

    def on_power_off(self) -> None:
        self._off_since = self.network.time()
        if self._sync_sub is not None:
            self._sync_sub.cancel()
            self._sync_sub = None
        self.motor.torque = 0.0
        self._cache.clear()

    def _subscribe_sync(self) -> None:
        if self._sync_sub is not None:
            self._sync_sub.cancel()
            self._sync_sub = None
        device = self._device
        if device is None:
            return
        value = int(device.get(0x1005, 0)) if 0x1005 in device.od else 0x80
        self._sync_cob = value & 0x7FF
        self._sync_sub = self.network.subscribe(self._sync_cob, self._on_sync_frame)

    # ================================================================== events
    def on_event(self, event: DeviceEvent) -> None:
        if isinstance(event, RpdoReceived):
            values = dict(zip(event.entries, event.values, strict=True))
            if (0x6060, 0) in values:
                self._set_mode(int(values[(0x6060, 0)]))
            if (0x6040, 0) in values:
                self._controlword(int(values[(0x6040, 0)]))
        elif isinstance(event, EntryWritten):
            if event.index == 0x6060:
                self._set_mode(int(event.value))
            elif event.index == 0x6040:
                self._controlword(int(event.value))
            elif event.index == 0x1005:
                self._subscribe_sync()
        elif isinstance(event, NmtCommandReceived):
            if event.command in (NmtCommand.RESET_NODE, NmtCommand.RESET_COMMUNICATION):
                self._abort_connection("NMT reset")
            if event.command is NmtCommand.RESET_NODE:
                self.network.loop.call_soon(self._after_reset_node)
        elif isinstance(event, StateChanged) and event.new is NmtState.STOPPED:
            self._abort_connection("NMT stopped")
        elif isinstance(event, HeartbeatLost | LifeGuardingLost):
            self._abort_connection(type(event).__name__)
        elif isinstance(event, Booted):
            self._cache.clear()

    def _after_reset_node(self) -> None:
        if self._device is None:
            return
        self._reset_application()
        self._subscribe_sync()
        self._step(0.0)
        self._publish()

    def _abort_connection(self, why: str) -> None:
        if self._device is None or self.state is not DriveState.OPERATION_ENABLED:
            return
        option = int(self._od(0x6007, 0, 2))
        if option == 1:
            self._fault(COMMUNICATION_FAULT, int(ErrorRegister.COMMUNICATION), why)
        elif option == 2:
            self._power_stage_off(DriveState.SWITCH_ON_DISABLED)
        elif option == 3:
            self._quick_stop()
        self._publish()

    def _on_sync_frame(self, frame: Frame, now: float) -> None:
        device = self._device
        if device is None or frame.rtr or device.state is NmtState.STOPPED:
            return
        # after the device has applied its synchronous RPDOs for this SYNC
        self.network.loop.call_soon(self._on_sync, now)

    def _on_sync(self, now: float) -> None:
        if self._device is None:
            return
        last, self._last_sync = self._last_sync, now
        if self.state is not DriveState.OPERATION_ENABLED or self.mode not in _CYCLIC:
            return
        if self.mode == Mode.INTERPOLATED_POSITION and not self._cw & _CW_NEW_SETPOINT:
            return  # interpolation not enabled (controlword bit 4): hold
        if self.mode in (Mode.CYCLIC_SYNC_POSITION, Mode.INTERPOLATED_POSITION):
            index, sub = (0x607A, 0) if self.mode == Mode.CYCLIC_SYNC_POSITION else (0x60C1, 1)
            target = float(self._od(index, sub, 0))
            period = self._interpolation_period(now, last)
            self._cyclic_target = target
            self._csp_v = (target - self._p_d) / period
            self._csp_left = period
        elif self.mode == Mode.CYCLIC_SYNC_VELOCITY:
            self._cyclic_target = float(self._od(0x60FF, 0, 0))
        else:
            self._cyclic_target = float(self._od(0x6071, 0, 0))

    def _interpolation_period(self, now: float, last: float | None) -> float:
        value = int(self._od(0x60C2, 1, 0))
        if value:
            return float(value * 10.0 ** int(self._od(0x60C2, 2, -3)))
        if last is not None and now > last:
            return now - last
        cycle = int(self._od(0x1006, 0, 0))
        return cycle / 1e6 if cycle else self.tick

    # ================================================================== helpers
    def _od(self, index: int, sub: int, default: Any) -> Any:
        device = self._device
        if device is None:
            return default
        return device.get(index, sub)

    def _p_act(self) -> float:
        return self.motor.raw + self._offset

    def _torque_limit(self) -> float:
        m = self.motor
        by_torque = self._od(0x6072, 0, 3000) / 1000 * m.rated_torque
        by_current = self._od(0x6073, 0, 3000) / 1000 * m.rated_current * m.kt
        return float(min(by_torque, by_current))

    def _switches(self) -> tuple[bool, bool]:
        raw = self.motor.raw
        neg = self.negative_limit is not None and raw <= self.negative_limit
        pos = self.positive_limit is not None and raw >= self.positive_limit
        return neg, pos

    # ================================================================== state machine
    def _set_mode(self, mode: int) -> None:
        if mode == self.mode:
            return
        self.mode = mode
        if self.state is DriveState.OPERATION_ENABLED:
            self._enter_mode()
        self._publish()

    def _enter_mode(self) -> None:
        p_d, v_d = self._p_act(), self.motor.speed
        self._init_control()
        self._p_d, self._v_d = p_d, v_d
        self._target = p_d
        if self.mode in (Mode.PROFILE_VELOCITY, Mode.CYCLIC_SYNC_VELOCITY):
            self._control = _VELOCITY
        elif self.mode in (Mode.PROFILE_TORQUE, Mode.CYCLIC_SYNC_TORQUE):
            self._control = _TORQUE
        else:
            self._control = _POSITION
            self._v_d = 0.0 if self.mode != Mode.HOMING else v_d

    def _controlword(self, cw: int) -> None:
        prev, self._cw = self._cw, cw
        state = self.state
        S = DriveState
        if state is S.FAULT:
            if cw & _CW_FAULT_RESET and not prev & _CW_FAULT_RESET:
                self._fault_reset()
        elif state not in (S.FAULT_REACTION_ACTIVE, S.NOT_READY_TO_SWITCH_ON):
            # the numbered transitions of CiA 402 (profiles.cia402): the one the command
            # asks for, and on from there while the same command leads further (enable
            # operation in ready to switch on: 3 and 4 at once)
            command = command_of(cw)  # (bit 7 set: a fault reset, nothing outside FAULT)
            step = transition(state, command)
            while step is not None and self._take(step, command):
                step = transition(self.state, command)
        if self.state is S.OPERATION_ENABLED and self._stop_then is None:
            self._mode_bits(prev, cw)
        self._publish()

    def _take(self, step: Transition, command: Command | None) -> bool:
        """Go through transition ``step`` (2-12, 16) with what it does to the power stage;
        False: not taken (16 with a quick stop option code that keeps the drive stopping)."""
        S = DriveState
        number = step.number
        if number == 11:
            self._quick_stop()
        elif number == 16:
            if int(self._od(0x605A, 0, 2)) < 5:
                return False
            self.state = S.OPERATION_ENABLED
            self._stop_then = None
            self._enter_mode()
        elif number == 4:
            self.state = S.OPERATION_ENABLED
            self._enter_mode()
        elif number in (5, 8, 9, 12) or (number in (7, 10) and command is Command.DISABLE_VOLTAGE):
            self._power_stage_off(step.target)
        else:  # 2, 3, 6, and 7 / 10 by a quick stop: no power at the motor either way
            self.state = step.target
        return True

    def _mode_bits(self, prev: int, cw: int) -> None:
        rising = cw & ~prev
        falling = prev & ~cw
        self._halted = bool(cw & _CW_HALT)
        if self.mode == Mode.PROFILE_POSITION:
            if rising & _CW_NEW_SETPOINT:
                self._new_setpoint(cw)
            elif falling & _CW_NEW_SETPOINT and self._buffer is None:
                self._ack = False
        elif self.mode == Mode.HOMING:
            if rising & _CW_NEW_SETPOINT:
                self._start_homing()
            elif falling & _CW_NEW_SETPOINT and self._homing is not None:
                self._homing = "stop"  # interrupted: stop, not attained

    def _power_stage_off(self, then: DriveState) -> None:
        self.state = then
        self._control = _OFF
        self._stop_then = None
        self._integral = 0.0

    def _quick_stop(self) -> None:
        option = int(self._od(0x605A, 0, 2))
        if option == 0:
            self._power_stage_off(DriveState.SWITCH_ON_DISABLED)
            return
        self.state = DriveState.QUICK_STOP_ACTIVE
        slow = option in (1, 5)
        self._start_ramp(
            self._od(0x6084 if slow else 0x6085, 0, 1),
            DriveState.SWITCH_ON_DISABLED if option <= 4 else DriveState.QUICK_STOP_ACTIVE,
        )

    def _start_ramp(self, decel: float, then: DriveState) -> None:
        """Ramp the velocity to zero under position control, then go to ``then``."""
        if self._control in (_TORQUE, _OFF):
            self._p_d, self._v_d = self._p_act(), self.motor.speed
        self._control = _POSITION
        self._stop_decel = max(float(decel), 1.0)
        self._stop_then = then
        self._stop_hold = 0.0

    def _fault(self, code: int, register: int | None, reason: str, *, coast: bool = False) -> None:
        if self.state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            return
        device = self._device
        if device is None:
            return
        self._error_code = code
        self._fault_reason = reason
        device.set(0x603F, 0, code)
        device.send_emergency(code, register)
        reaction = int(self._od(0x605E, 0, 2))
        powered = self._control is not _OFF
        if coast or reaction == 0 or not powered:
            self._power_stage_off(DriveState.FAULT)
            return
        self.state = DriveState.FAULT_REACTION_ACTIVE
        self._start_ramp(self._od(0x6084 if reaction == 1 else 0x6085, 0, 1), DriveState.FAULT)

    def _fault_reset(self) -> None:
        if self._error_code == MOTOR_OVERTEMPERATURE and (
            self.motor.temperature > self.temperature_limit - 10
        ):
            return  # the cause is still there
        device = self._device
        self.state = DriveState.SWITCH_ON_DISABLED
        self._error_code = 0
        self._fault_reason = ""
        self._fe_time = 0.0
        if device is not None:
            device.set(0x603F, 0, 0)
            device.clear_emergency()

    # ================================================================== profile position
    def _new_setpoint(self, cw: int) -> None:
        if self._ack and self._buffer is not None:
            return  # the buffer is full: not taken
        value = float(self._od(0x607A, 0, 0))
        base = self._buffer if self._buffer is not None else self._target
        target = base + value if cw & _CW_RELATIVE else value
        low, high = int(self._od(0x607D, 1, 0)), int(self._od(0x607D, 2, 0))
        self._limited = False
        if low < high and not low <= target <= high:
            target = min(max(target, low), high)
            self._limited = True
        if cw & _CW_IMMEDIATE or not self._moving:
            self._target = target
            self._buffer = None
            self._moving = True
            self._in_window = 0.0
        else:
            self._buffer = target
        self._ack = True

    def _pp_step(self, h: float) -> None:
        vmax = float(min(self._od(0x6081, 0, 0), self._od(0x607F, 0, 0)))
        acc = max(float(self._od(0x6083, 0, 1)), 1.0)
        dec = max(float(self._od(0x6084, 0, 1)), 1.0)
        if self._halted or not self._moving:
            self._v_d = _approach(self._v_d, 0.0, acc * h, dec * h)
            self._p_d += self._v_d * h
            return
        s = self._target - self._p_d
        v = self._v_d
        if abs(s) < 1e-9 and abs(v) <= dec * h:
            self._p_d, self._v_d = self._target, 0.0
            self._trajectory_done()
            return
        direction = 1.0 if s > 0 else -1.0
        along = v * direction
        if along < 0:  # moving away from the target: brake first
            along = min(along + dec * h, 0.0)
        else:
            # accelerate up to the profile velocity, but no faster than the deceleration can
            # still stop at the target; slow down at most with the deceleration
            cap = min(vmax, math.sqrt(2 * dec * abs(s)))
            along = min(along + acc * h, cap) if along < cap else max(along - dec * h, cap)
        step = along * h
        if along >= 0 and step >= abs(s):
            self._p_d, self._v_d = self._target, 0.0
            self._trajectory_done()
            return
        self._v_d = along * direction
        self._p_d += step * direction

    def _trajectory_done(self) -> None:
        self._moving = False
        if self._buffer is not None:
            self._target, self._buffer = self._buffer, None
            self._moving = True
            self._in_window = 0.0
            if not self._cw & _CW_NEW_SETPOINT:
                self._ack = False

    # ================================================================== homing
    def _start_homing(self) -> None:
        method = int(self._od(0x6098, 0, 37))
        self._homed = False
        self._homing_error = False
        self._found = False
        self._v_d = self.motor.speed
        self._p_d = self._p_act()
        if method in (35, 37):
            self._home_found(self._p_act())
            return
        negative = method in (1, 17)
        limit = self.negative_limit if negative else self.positive_limit
        if limit is None:
            self._homing_error = True
            self._homing = "stop"
            self._fault_reason = f"homing method {method}: the drive has no such limit switch"
            return
        self._homing_dir = -1 if negative else 1
        neg, pos = self._switches()
        on_switch = neg if negative else pos
        self._homing = "leave" if on_switch else "search"
        self._homing_index = method in (1, 2)

    def _set_home(self, at: float) -> None:
        """The home point is at actual position ``at``: it becomes the home offset 607Ch."""
        delta = float(self._od(0x607C, 0, 0)) - at
        self._offset += delta
        self._p_d += delta
        self._target += delta

    def _hm_step(self, h: float) -> None:
        phase = self._homing
        acc = max(float(self._od(0x609A, 0, 1)), 1.0)
        fast, slow = float(self._od(0x6099, 1, 0)), float(self._od(0x6099, 2, 0))
        d = self._homing_dir
        if phase == "search":
            want = d * fast
        elif phase in ("leave", "index"):
            want = -d * slow
        else:
            want = 0.0
        if self._halted:
            want = 0.0
        self._v_d = _approach(self._v_d, want, acc * h, acc * h)
        self._p_d += self._v_d * h
        if phase is None or phase == "stop":
            if self._v_d == 0.0 and phase == "stop":
                self._homing = None
                self._homed = self._found and not self._homing_error
            return
        neg, pos = self._switches()
        on_switch, other = (neg, pos) if d < 0 else (pos, neg)
        if phase == "search":
            if other:
                self._homing_error = True
                self._homing = "stop"
            elif on_switch:
                self._homing = "leave"
        elif phase == "leave" and not on_switch:
            if self._homing_index:
                self._homing = "index"
                self._index_raw = self.motor.raw
            else:
                self._home_found(self._p_act())
        elif phase == "index":  # the index pulse passed since the last step?
            res = self.motor.resolution
            before, now = self._index_raw, self.motor.raw
            self._index_raw = now
            a = math.floor((before - self.index_offset) / res)
            b = math.floor((now - self.index_offset) / res)
            if a != b:
                edge = max(a, b) * res + self.index_offset
                self._home_found(edge + self._offset)

    def _home_found(self, at: float) -> None:
        self._set_home(at)
        self._homing = "stop"
        self._found = True

    # ================================================================== physics and control
    def _tick(self, dt: float) -> None:
        steps = max(1, math.ceil(dt / _MAX_STEP - 1e-9))
        h = dt / steps
        for _ in range(steps):
            self._step(h)
        self._publish()

    def _step(self, h: float) -> None:
        S = DriveState
        if self.state is S.NOT_READY_TO_SWITCH_ON:
            self.state = S.SWITCH_ON_DISABLED  # the self-test has passed
        if h <= 0:
            return
        m = self.motor
        v_before = self._v_d
        if self._stop_then is not None:
            self._v_d = _approach(self._v_d, 0.0, 0.0, self._stop_decel * h)
            self._p_d += self._v_d * h
            if self._v_d == 0.0:
                self._stop_hold += h
            stopped = abs(m.speed) <= max(float(self._od(0x606F, 0, 20)), 1.0)
            if self._v_d == 0.0 and (stopped or self._stop_hold >= 0.5):
                then, self._stop_then = self._stop_then, None
                self._stop_hold = 0.0
                if then is S.QUICK_STOP_ACTIVE:
                    self.state = S.QUICK_STOP_ACTIVE  # holds the position
                else:
                    self._power_stage_off(then)
        elif self.state is S.OPERATION_ENABLED:
            self._generate(h)
        self._guard_limits(h, v_before)
        self._a_d = (self._v_d - v_before) / h if self._control is not _OFF else 0.0
        torque = self._controller(h)
        m.step(torque, h)
        self._monitor(h)

    def _generate(self, h: float) -> None:
        mode = self.mode
        if mode == Mode.PROFILE_POSITION:
            self._pp_step(h)
        elif mode == Mode.PROFILE_VELOCITY:
            acc = max(float(self._od(0x6083, 0, 1)), 1.0)
            dec = max(float(self._od(0x6084, 0, 1)), 1.0)
            want = 0.0 if self._halted else float(self._od(0x60FF, 0, 0))
            self._v_d = _approach(self._v_d, want, acc * h, dec * h)
            self._p_d += self._v_d * h
        elif mode == Mode.PROFILE_TORQUE:
            slope = max(float(self._od(0x6087, 0, 1)), 1.0) * h
            want = 0.0 if self._halted else float(self._od(0x6071, 0, 0))
            self._t_d = _approach(self._t_d, want, slope, slope)
        elif mode == Mode.HOMING:
            self._hm_step(h)
        elif mode in (Mode.CYCLIC_SYNC_POSITION, Mode.INTERPOLATED_POSITION):
            if self._csp_left > 0:
                used = min(h, self._csp_left)
                self._p_d += self._csp_v * used
                self._csp_left -= used
                self._v_d = self._csp_v
                if self._csp_left <= 1e-12 and self._cyclic_target is not None:
                    self._p_d = self._cyclic_target
                    self._csp_left = 0.0
            else:
                self._v_d = 0.0
        elif mode == Mode.CYCLIC_SYNC_VELOCITY:
            if self._cyclic_target is not None:
                self._v_d = self._cyclic_target
            self._p_d += self._v_d * h
        elif mode == Mode.CYCLIC_SYNC_TORQUE and self._cyclic_target is not None:
            self._t_d = self._cyclic_target

    def _guard_limits(self, h: float, v_before: float) -> None:
        """Outside homing a limit switch stops the motion toward it (quick stop deceleration)."""
        if self._control is _OFF or (self.mode == Mode.HOMING and self._homing is not None):
            return
        neg, pos = self._switches()
        blocked = (pos and self._v_d > 0) or (neg and self._v_d < 0)
        if self._control is _TORQUE:
            if (pos and self._t_d > 0) or (neg and self._t_d < 0):
                self._t_d = 0.0
            return
        if blocked:
            # undo this step's motion toward the switch and brake from the last velocity
            self._p_d -= self._v_d * h
            toward = (pos and v_before > 0) or (neg and v_before < 0)
            decel = max(float(self._od(0x6085, 0, 1)), 1.0) * h
            self._v_d = _approach(v_before, 0.0, 0.0, decel) if toward else 0.0
            self._p_d += self._v_d * h
            if self.mode == Mode.PROFILE_POSITION and self._moving:
                self._moving = False  # the positioning is aborted, the target not reached
                self._buffer = None
                self._ack = bool(self._cw & _CW_NEW_SETPOINT)

    def _controller(self, h: float) -> float:
        m = self.motor
        limit = self._torque_limit()
        control = self._control
        if control is _OFF:
            self._integral = 0.0
            return 0.0
        if control is _TORQUE:
            torque = self._t_d / 1000 * m.rated_torque
            vmax = float(self._od(0x6080, 0, 0))
            if vmax:  # speed limit: the torque falls off toward the maximum motor speed
                speed = m.speed
                if torque > 0:
                    torque = min(torque, self._kp_v * (vmax - speed) * m.rad_per_inc)
                elif torque < 0:
                    torque = max(torque, self._kp_v * (-vmax - speed) * m.rad_per_inc)
            return max(-limit, min(limit, torque))
        v_cmd = self._v_d
        if control is _POSITION:
            v_cmd += self._kp_p * (self._p_d - self._p_act())
        err = (v_cmd - m.speed) * m.rad_per_inc
        feed = m.inertia * self._a_d * m.rad_per_inc
        integral = self._integral + self._ki_v * err * h
        torque = self._kp_v * err + integral + feed
        if abs(torque) > limit:
            torque = math.copysign(limit, torque)  # saturated: the integral does not wind up
        else:
            self._integral = integral
        return torque

    def _monitor(self, h: float) -> None:
        m = self.motor
        S = DriveState
        if abs(m.current) > self.overcurrent_trip:
            self._fault(
                OVERCURRENT,
                int(ErrorRegister.CURRENT),
                f"motor current {abs(m.current):.1f} A above the trip {self.overcurrent_trip:g} A",
                coast=True,
            )
        if m.temperature >= self.temperature_limit:
            self._fault(
                MOTOR_OVERTEMPERATURE,
                int(ErrorRegister.TEMPERATURE),
                f"motor at {m.temperature:.0f} °C, limit {self.temperature_limit:g} °C",
            )
        watch = self._control is _POSITION and self.state in (
            S.OPERATION_ENABLED,
            S.QUICK_STOP_ACTIVE,
        )
        window = int(self._od(0x6065, 0, 0xFFFFFFFF))
        fe = self._p_d - self._p_act()
        if watch and window != 0xFFFFFFFF and abs(fe) > window:
            self._fe_time += h
            if self._fe_time * 1000 > int(self._od(0x6066, 0, 0)):
                self._fault(
                    FOLLOWING_ERROR,
                    int(ErrorRegister.DEVICE_PROFILE),
                    f"following error {fe:.0f} beyond the window {window}",
                )
        else:
            self._fe_time = 0.0
        # target reached of profile position: inside the position window long enough
        if self.mode == Mode.PROFILE_POSITION and not self._moving:
            if abs(self._target - self._p_act()) <= int(self._od(0x6067, 0, 0)):
                self._in_window += h
            else:
                self._in_window = 0.0
        # velocity window of profile velocity
        if self.mode == Mode.PROFILE_VELOCITY:
            target = float(self._od(0x60FF, 0, 0)) if not self._halted else 0.0
            if abs(target - m.speed) <= int(self._od(0x606D, 0, 0)):
                self._in_window += h
            else:
                self._in_window = 0.0

    # ================================================================== statusword
    def _statusword(self) -> int:
        S = DriveState
        state = self.state
        sw = _STATE_BITS[state] | _SW_REMOTE
        if state in _VOLTAGE:
            sw |= 0x10
        m = self.motor
        if m.temperature >= self.temperature_warning:
            sw |= _SW_WARNING
        neg, pos = self._switches()
        homing = self.mode == Mode.HOMING and self._homing is not None
        if ((neg or pos) and not homing) or self._limited:
            sw |= _SW_INTERNAL_LIMIT
        if state is not S.OPERATION_ENABLED:
            if state is S.QUICK_STOP_ACTIVE and self._stop_then is None:
                sw |= _SW_TARGET_REACHED
            return sw
        mode = self.mode
        fe = abs(self._p_d - self._p_act())
        window = int(self._od(0x6065, 0, 0xFFFFFFFF))
        fe_bit = window != 0xFFFFFFFF and fe > window
        if mode == Mode.PROFILE_POSITION:
            time = int(self._od(0x6068, 0, 0)) / 1000
            if self._halted:
                reached = self._v_d == 0.0
            else:
                reached = not self._moving and self._in_window >= time
            sw |= _SW_TARGET_REACHED if reached else 0
            sw |= _SW_BIT12 if self._ack else 0
            sw |= _SW_BIT13 if fe_bit else 0
        elif mode == Mode.PROFILE_VELOCITY:
            time = int(self._od(0x606E, 0, 0)) / 1000
            sw |= _SW_TARGET_REACHED if self._in_window >= time else 0
            if abs(m.speed) <= int(self._od(0x606F, 0, 0)):
                sw |= _SW_BIT12
        elif mode == Mode.PROFILE_TORQUE:
            want = 0.0 if self._halted else float(self._od(0x6071, 0, 0))
            sw |= _SW_TARGET_REACHED if self._t_d == want else 0
        elif mode == Mode.HOMING:
            done = self._homing is None
            sw |= _SW_TARGET_REACHED if done or (self._halted and self._v_d == 0.0) else 0
            sw |= _SW_BIT12 if self._homed and done else 0
            sw |= _SW_BIT13 if self._homing_error else 0
        elif mode == Mode.INTERPOLATED_POSITION:  # bit 12: interpolation active
            active = bool(self._cw & _CW_NEW_SETPOINT) and not self._halted
            sw |= _SW_BIT12 if active else 0
            sw |= _SW_BIT13 if fe_bit else 0
            sw |= _SW_TARGET_REACHED if self._csp_left <= 0 else 0
        elif mode in _CYCLIC:
            sw |= _SW_BIT12 if not self._halted else 0
            if mode == Mode.CYCLIC_SYNC_POSITION and fe_bit:
                sw |= _SW_BIT13
        return sw

    def _publish(self) -> None:
        device = self._device
        if device is None:
            return
        m = self.motor
        p_act = self._p_act()
        neg, pos = self._switches()
        values = (
            (0x6041, self._statusword()),
            (0x6061, max(-128, min(127, self.mode))),
            (0x6062, _clamp_int(self._p_d, _I32_MIN, _I32_MAX)),
            (0x6063, _clamp_int(math.floor(p_act), _I32_MIN, _I32_MAX)),
            (0x6064, _clamp_int(math.floor(p_act), _I32_MIN, _I32_MAX)),
            (0x606B, _clamp_int(self._v_d, _I32_MIN, _I32_MAX)),
            (0x606C, _clamp_int(m.speed, _I32_MIN, _I32_MAX)),
            (0x6074, _clamp_int(self._t_d, _I16_MIN, _I16_MAX)),
            (0x6077, _clamp_int(m.torque / m.rated_torque * 1000, _I16_MIN, _I16_MAX)),
            (0x6078, _clamp_int(m.current / m.rated_current * 1000, _I16_MIN, _I16_MAX)),
            (0x60F4, _clamp_int(self._p_d - p_act, _I32_MIN, _I32_MAX)),
            (0x60FD, int(neg) | int(pos) << 1),
            (0x2000, _clamp_int(m.temperature * 10, _I16_MIN, _I16_MAX)),
        )
        cache = self._cache
        for index, value in values:
            if cache.get(index) != value:
                cache[index] = value
                device.set(index, 0, value)

    # ================================================================== faults and panel
    def inject(self, fault: str, **params: Any) -> None:
        m = self.motor
        if fault == "blocked_rotor":
            check_fault_params(self.kind, fault, params, {})
            m.blocked = True
            m.omega = 0.0
        elif fault == "free_rotor":
            check_fault_params(self.kind, fault, params, {})
            m.blocked = False
        elif fault == "overtemperature":
            p = check_fault_params(
                self.kind, fault, params, {"temperature": self.temperature_limit + 5}
            )
            self._running()
            m.temperature = _number("temperature", p["temperature"])
            self._step(0.0)
            self._monitor(0.0)
            self._publish()
        elif fault == "overcurrent":
            check_fault_params(self.kind, fault, params, {})
            self._running()
            self._fault(
                OVERCURRENT,
                int(ErrorRegister.CURRENT),
                "short circuit at the motor output",
                coast=True,
            )
            self._publish()
        elif fault == "drive_fault":
            p = check_fault_params(
                self.kind, fault, params, {"code": int(EmcyCode.HARDWARE), "register": None}
            )
            code = p["code"]
            if isinstance(code, bool) or not isinstance(code, int) or not 0x1000 <= code <= 0xFFFF:
                raise FaultParameterError(
                    f"drive_fault: code {code!r} must be an EMCY error code 1000h..FFFFh"
                )
            self._running()
            self._fault(code, p["register"], "injected drive fault")
            self._publish()
        else:
            super().inject(fault, **params)

    def active_faults(self) -> list[str]:
        active = super().active_faults()
        if self.motor.blocked:
            active.append("blocked_rotor")
        return active

    def status(self) -> dict[str, Any]:
        out = super().status()
        m = self.motor
        try:
            mode = Mode(self.mode).name.lower()
        except ValueError:
            mode = str(self.mode)
        out.update(
            state=self.state.value,
            mode=mode,
            position=math.floor(self._p_act()),
            velocity=round(m.speed),
            torque=round(m.torque, 3),
            current=round(m.current, 2),
            temperature=round(m.temperature, 1),
            following_error=round(self._p_d - self._p_act()),
            error_code=f"{self._error_code:04X}h" if self._error_code else "",
        )
        return out

    @property
    def error_code(self) -> int:
        """603Fh: the code of the fault in effect (0: none)."""
        return self._error_code

    @property
    def fault_reason(self) -> str:
        """Why the drive faulted, in words (empty without a fault)."""
        return self._fault_reason


#: One name per idea: :class:`cobus.profiles.Drive402` drives a real one.
__getattr__ = renamed_names(__name__, {"Drive402": ("SimulatedDrive402", SimulatedDrive402)})
