"""CiA 402 (IEC 61800-7-201), sans I/O: the power state machine decoded from the statusword
(6041h), the controlword (6040h) commands, the transitions 0-16 as the standard numbers them,
the path from any state to any other, the modes of operation (6060h/6061h), and the texts of
the error codes (603Fh).

Nothing here touches a bus; :mod:`cobus.profiles.drive402` runs a drive with it (the master
side), and the simulated drive (:mod:`cobus.sim.drive402`) follows the same transitions.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

from cobus._enum import NamedIntEnum
from cobus.profiles._tables import table
from cobus.proto.emcy import describe as _describe_emcy

__all__ = [
    "STATE_BITS",
    "TRANSITIONS",
    "Command",
    "OperationMode",
    "PowerState",
    "Statusword",
    "Transition",
    "command_of",
    "command_towards",
    "error_text",
    "transition",
]


class PowerState(enum.Enum):
    """The states of the CiA 402 power drive state machine (statusword bits 0-3, 5, 6)."""

    NOT_READY_TO_SWITCH_ON = "not ready to switch on"
    SWITCH_ON_DISABLED = "switch on disabled"
    READY_TO_SWITCH_ON = "ready to switch on"
    SWITCHED_ON = "switched on"
    OPERATION_ENABLED = "operation enabled"
    QUICK_STOP_ACTIVE = "quick stop active"
    FAULT_REACTION_ACTIVE = "fault reaction active"
    FAULT = "fault"

    def __str__(self) -> str:
        return self.name

    @classmethod
    def from_statusword(cls, statusword: int) -> PowerState:
        """The state a statusword reports (CiA 402 table of bits 0-3, 5 and 6)."""
        for mask, value, state in _DECODE:
            if statusword & mask == value:
                return state
        # 0bxx0x_1111 with bit 6 set, and similar combinations CiA 402 leaves undefined:
        # the nearest reading is "not ready" (the drive is not in any defined state)
        return cls.NOT_READY_TO_SWITCH_ON


_P = PowerState
#: (mask, value, state): CiA 402's decoding of the statusword, in its order.
_DECODE: tuple[tuple[int, int, PowerState], ...] = (
    (0x4F, 0x00, _P.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, _P.SWITCH_ON_DISABLED),
    (0x6F, 0x21, _P.READY_TO_SWITCH_ON),
    (0x6F, 0x23, _P.SWITCHED_ON),
    (0x6F, 0x27, _P.OPERATION_ENABLED),
    (0x6F, 0x07, _P.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, _P.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, _P.FAULT),
)
#: The statusword bits (0-3, 5, 6) each state is reported with: what a drive sends, the
#: other side of the decoding above (the simulated drive builds its statusword from it).
STATE_BITS: Mapping[PowerState, int] = {state: value for _mask, value, state in _DECODE}


class Command(NamedIntEnum):
    """The controlword device-control commands (bits 0-3 and 7; the other bits are the
    mode's and are kept by the caller)."""

    SHUTDOWN = 0x06
    SWITCH_ON = 0x07
    DISABLE_VOLTAGE = 0x00
    QUICK_STOP = 0x02
    DISABLE_OPERATION = 0x07
    ENABLE_OPERATION = 0x0F
    FAULT_RESET = 0x80

    @staticmethod
    def mask() -> int:
        """The controlword bits the commands own: 0-3 and 7."""
        return 0x8F


def command_of(controlword: int) -> Command | None:
    """The device-control command a controlword gives (CiA 402 table "device control
    commands", bits 0-3 and 7); None for the bit patterns that give none. Bit 7 set is a
    fault reset whatever the other bits (it acts on its rising edge: the drive's part).
    SWITCH_ON and DISABLE_OPERATION are one pattern (0x07): the state tells them apart."""
    if controlword & 0x80:
        return Command.FAULT_RESET
    if not controlword & 0x02:
        return Command.DISABLE_VOLTAGE
    if not controlword & 0x04:
        return Command.QUICK_STOP
    if controlword & 0x07 == 0x06:
        return Command.SHUTDOWN
    if controlword & 0x0F == 0x07:
        return Command.SWITCH_ON
    if controlword & 0x0F == 0x0F:
        return Command.ENABLE_OPERATION
    return None


@dataclass(frozen=True, slots=True)
class Transition:
    """One transition of the power state machine, numbered as CiA 402 numbers it."""

    number: int
    source: PowerState | None  # None: any state (13, a fault) or power-on (0)
    target: PowerState
    #: The commands that cause it (empty: the drive takes it by itself).
    commands: tuple[Command, ...]


#: The transitions 0-16 of the CiA 402 power state machine. 16 (quick stop active ->
#: operation enabled) is only taken when the quick stop option code (605Ah) is 5-8; 12 is
#: also taken by the drive when its quick stop is done with option code 1-3.
TRANSITIONS: tuple[Transition, ...] = (
    Transition(0, None, _P.NOT_READY_TO_SWITCH_ON, ()),
    Transition(1, _P.NOT_READY_TO_SWITCH_ON, _P.SWITCH_ON_DISABLED, ()),
    Transition(2, _P.SWITCH_ON_DISABLED, _P.READY_TO_SWITCH_ON, (Command.SHUTDOWN,)),
    # (enable operation in ready to switch on: 3, then 4 by itself — CiA 402's "3 + 4")
    Transition(
        3, _P.READY_TO_SWITCH_ON, _P.SWITCHED_ON, (Command.SWITCH_ON, Command.ENABLE_OPERATION)
    ),
    Transition(4, _P.SWITCHED_ON, _P.OPERATION_ENABLED, (Command.ENABLE_OPERATION,)),
    Transition(5, _P.OPERATION_ENABLED, _P.SWITCHED_ON, (Command.DISABLE_OPERATION,)),
    Transition(6, _P.SWITCHED_ON, _P.READY_TO_SWITCH_ON, (Command.SHUTDOWN,)),
    Transition(
        7,
        _P.READY_TO_SWITCH_ON,
        _P.SWITCH_ON_DISABLED,
        (Command.QUICK_STOP, Command.DISABLE_VOLTAGE),
    ),
    Transition(8, _P.OPERATION_ENABLED, _P.READY_TO_SWITCH_ON, (Command.SHUTDOWN,)),
    Transition(9, _P.OPERATION_ENABLED, _P.SWITCH_ON_DISABLED, (Command.DISABLE_VOLTAGE,)),
    Transition(
        10, _P.SWITCHED_ON, _P.SWITCH_ON_DISABLED, (Command.QUICK_STOP, Command.DISABLE_VOLTAGE)
    ),
    Transition(11, _P.OPERATION_ENABLED, _P.QUICK_STOP_ACTIVE, (Command.QUICK_STOP,)),
    Transition(12, _P.QUICK_STOP_ACTIVE, _P.SWITCH_ON_DISABLED, (Command.DISABLE_VOLTAGE,)),
    Transition(13, None, _P.FAULT_REACTION_ACTIVE, ()),
    Transition(14, _P.FAULT_REACTION_ACTIVE, _P.FAULT, ()),
    Transition(15, _P.FAULT, _P.SWITCH_ON_DISABLED, (Command.FAULT_RESET,)),
    Transition(16, _P.QUICK_STOP_ACTIVE, _P.OPERATION_ENABLED, (Command.ENABLE_OPERATION,)),
)
_BY_COMMAND: dict[tuple[PowerState, Command], Transition] = {
    (t.source, command): t for t in TRANSITIONS if t.source is not None for command in t.commands
}


def transition(state: PowerState, command: Command | None) -> Transition | None:
    """The transition ``command`` takes a drive in ``state`` through (None: the command
    does nothing there). 16 is listed whatever the quick stop option code: the drive
    checks it."""
    if command is None:
        return None
    return _BY_COMMAND.get((state, command))


class OperationMode(NamedIntEnum):
    """The modes of operation of CiA 402 (6060h / 6061h values)."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    VELOCITY = 2
    PROFILE_VELOCITY = 3
    PROFILE_TORQUE = 4
    HOMING = 6
    INTERPOLATED_POSITION = 7
    CYCLIC_SYNC_POSITION = 8
    CYCLIC_SYNC_VELOCITY = 9
    CYCLIC_SYNC_TORQUE = 10

    @property
    def supported_bit(self) -> int:
        """This mode's bit in 6502h "supported drive modes" (0 for NO_MODE)."""
        return 0 if self is OperationMode.NO_MODE else 1 << (self.value - 1)


#: Statusword bits by their CiA 402 names (bits 10, 12 and 13 depend on the mode).
SW_READY_TO_SWITCH_ON = 1 << 0
SW_SWITCHED_ON = 1 << 1
SW_OPERATION_ENABLED = 1 << 2
SW_FAULT = 1 << 3
SW_VOLTAGE_ENABLED = 1 << 4
SW_QUICK_STOP = 1 << 5
SW_SWITCH_ON_DISABLED = 1 << 6
SW_WARNING = 1 << 7
SW_REMOTE = 1 << 9
SW_TARGET_REACHED = 1 << 10
SW_INTERNAL_LIMIT = 1 << 11
SW_BIT12 = 1 << 12
SW_BIT13 = 1 << 13

#: Controlword bits of the modes.
CW_NEW_SETPOINT = 1 << 4  # profile position; homing: start
CW_CHANGE_IMMEDIATELY = 1 << 5
CW_RELATIVE = 1 << 6
CW_FAULT_RESET = 1 << 7
CW_HALT = 1 << 8
CW_CHANGE_ON_SETPOINT = 1 << 9


@dataclass(frozen=True, slots=True)
class Statusword:
    """A statusword decoded: the state and each flag, with the mode-specific bits 12 and 13
    named for ``mode`` (``print(Statusword(0x1637, OperationMode.PROFILE_POSITION))``)."""

    value: int
    mode: int = 0

    @property
    def state(self) -> PowerState:
        """The power state the statusword reports."""
        return PowerState.from_statusword(self.value)

    @property
    def voltage_enabled(self) -> bool:
        """Bit 4: high voltage is applied to the drive."""
        return bool(self.value & SW_VOLTAGE_ENABLED)

    @property
    def warning(self) -> bool:
        """Bit 7: a warning (the drive still runs)."""
        return bool(self.value & SW_WARNING)

    @property
    def remote(self) -> bool:
        """Bit 9: the controlword is obeyed (else the drive is under local control)."""
        return bool(self.value & SW_REMOTE)

    @property
    def target_reached(self) -> bool:
        """Bit 10: the target is reached (or, after halt, the drive stands still)."""
        return bool(self.value & SW_TARGET_REACHED)

    @property
    def internal_limit(self) -> bool:
        """Bit 11: an internal limit is active (a limit switch, a clamped set-point...)."""
        return bool(self.value & SW_INTERNAL_LIMIT)

    def flags(self) -> list[str]:
        """The flags that are set, in words, the mode-specific bits named for :attr:`mode`."""
        names = [
            (SW_VOLTAGE_ENABLED, "voltage enabled"),
            (SW_WARNING, "warning"),
            (SW_REMOTE, "remote"),
            (SW_TARGET_REACHED, "target reached"),
            (SW_INTERNAL_LIMIT, "internal limit active"),
        ]
        bit12, bit13 = _MODE_BITS.get(self.mode, ("operation mode specific (bit 12)", "bit 13"))
        names += [(SW_BIT12, bit12), (SW_BIT13, bit13)]
        return [text for bit, text in names if self.value & bit]

    def __str__(self) -> str:
        flags = ", ".join(self.flags())
        return f"0x{self.value:04X} {self.state.name}" + (f" ({flags})" if flags else "")


#: The names of statusword bits 12 and 13 in each mode.
_MODE_BITS: dict[int, tuple[str, str]] = {
    OperationMode.PROFILE_POSITION: ("set-point acknowledge", "following error"),
    OperationMode.PROFILE_VELOCITY: ("speed is zero", "max slippage error"),
    OperationMode.PROFILE_TORQUE: ("bit 12 reserved", "bit 13 reserved"),
    OperationMode.HOMING: ("homing attained", "homing error"),
    OperationMode.INTERPOLATED_POSITION: ("interpolation active", "bit 13"),
    OperationMode.CYCLIC_SYNC_POSITION: ("drive follows the command value", "following error"),
    OperationMode.CYCLIC_SYNC_VELOCITY: ("drive follows the command value", "bit 13"),
    OperationMode.CYCLIC_SYNC_TORQUE: ("drive follows the command value", "bit 13"),
}


#: The next command on the way from a state to OPERATION_ENABLED, SWITCHED_ON,
#: READY_TO_SWITCH_ON or SWITCH_ON_DISABLED (None: nothing the controlword can do — wait).
_TOWARDS: dict[PowerState, dict[PowerState, Command | None]] = {
    _P.OPERATION_ENABLED: {
        _P.NOT_READY_TO_SWITCH_ON: None,
        _P.SWITCH_ON_DISABLED: Command.SHUTDOWN,
        _P.READY_TO_SWITCH_ON: Command.SWITCH_ON,
        _P.SWITCHED_ON: Command.ENABLE_OPERATION,
        _P.QUICK_STOP_ACTIVE: Command.DISABLE_VOLTAGE,
        _P.FAULT_REACTION_ACTIVE: None,
        _P.FAULT: Command.FAULT_RESET,
    },
    _P.SWITCHED_ON: {
        _P.NOT_READY_TO_SWITCH_ON: None,
        _P.SWITCH_ON_DISABLED: Command.SHUTDOWN,
        _P.READY_TO_SWITCH_ON: Command.SWITCH_ON,
        _P.OPERATION_ENABLED: Command.DISABLE_OPERATION,
        _P.QUICK_STOP_ACTIVE: Command.DISABLE_VOLTAGE,
        _P.FAULT_REACTION_ACTIVE: None,
        _P.FAULT: Command.FAULT_RESET,
    },
    _P.READY_TO_SWITCH_ON: {
        _P.NOT_READY_TO_SWITCH_ON: None,
        _P.SWITCH_ON_DISABLED: Command.SHUTDOWN,
        _P.SWITCHED_ON: Command.SHUTDOWN,
        _P.OPERATION_ENABLED: Command.SHUTDOWN,
        _P.QUICK_STOP_ACTIVE: Command.DISABLE_VOLTAGE,
        _P.FAULT_REACTION_ACTIVE: None,
        _P.FAULT: Command.FAULT_RESET,
    },
    _P.SWITCH_ON_DISABLED: {
        _P.NOT_READY_TO_SWITCH_ON: None,
        _P.READY_TO_SWITCH_ON: Command.DISABLE_VOLTAGE,
        _P.SWITCHED_ON: Command.DISABLE_VOLTAGE,
        _P.OPERATION_ENABLED: Command.DISABLE_VOLTAGE,
        _P.QUICK_STOP_ACTIVE: Command.DISABLE_VOLTAGE,
        _P.FAULT_REACTION_ACTIVE: None,
        _P.FAULT: Command.FAULT_RESET,
    },
}


def command_towards(current: PowerState, target: PowerState) -> Command | None:
    """The command that takes a drive one transition from ``current`` towards ``target``
    (OPERATION_ENABLED, SWITCHED_ON, READY_TO_SWITCH_ON or SWITCH_ON_DISABLED): ``None``
    when ``current`` is ``target`` or a state only the drive leaves by itself (not ready to
    switch on, fault reaction active). From FAULT it is a fault reset, the caller's choice."""
    if current is target:
        return None
    table = _TOWARDS.get(target)
    if table is None:
        raise ValueError(
            f"{target.name} is not a state a controlword command leads to; the targets are "
            + ", ".join(s.name for s in _TOWARDS)
        )
    return table[current]


#: The CiA 402-2 error codes (603Fh) a drive reports, with their texts; any other code is
#: described by its CiA 301 emergency class.
_ERROR_TEXTS: dict[int, str] = dict(table("cia402_errors")["codes"])


def error_text(code: int) -> str:
    """The text of a 603Fh error code: the CiA 402 wording when the code is one of its
    drive errors, else the CiA 301 emergency class it belongs to."""
    text = _ERROR_TEXTS.get(code)
    return text if text is not None else _describe_emcy(code)
