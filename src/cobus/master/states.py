"""The numbers the master reports: node states (Lenze codes), diagnostic node states
(Beckhoff codes), master states, CiA 303-3 LED patterns and kept emergencies."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from cobus._enum import NamedIntEnum
from cobus.runtime.emcy import Emergency

__all__ = [
    "Diagnostic",
    "EmcyRecord",
    "LedPattern",
    "Leds",
    "MasterState",
    "MasterStatus",
    "NodeState",
]


class NodeState(NamedIntEnum):
    """State of a node as the master's boot-up sees it (the Lenze master's numeric codes)."""

    UNDEFINED = 0
    RESETTING = -1
    AWAITING_BOOTUP = 1
    WAITING = 2  # before the 1000h read
    CONFIGURING = 3
    CONFIGURED = 4
    OPERATIONAL = 5
    ABSENT = 97  # optional node not found
    WRONG_DEVICE = 98  # device type or identity differs: configured, PDOs stay disabled
    ERROR_CONTROL = 99  # heartbeat or guarding error

    @property
    def text(self) -> str:
        """What the code means, in words."""
        return _NODE_TEXTS[self]


_NODE_TEXTS = {
    NodeState.UNDEFINED: "undefined",
    NodeState.RESETTING: "being reset",
    NodeState.AWAITING_BOOTUP: "reset, awaiting boot-up",
    NodeState.WAITING: "waiting before the device type read",
    NodeState.CONFIGURING: "configuring",
    NodeState.CONFIGURED: "configured",
    NodeState.OPERATIONAL: "operational",
    NodeState.ABSENT: "optional node absent",
    NodeState.WRONG_DEVICE: "wrong device type or identity",
    NodeState.ERROR_CONTROL: "heartbeat or guarding error",
}


class Diagnostic(NamedIntEnum):
    """Diagnostic state of a node (the Beckhoff master's codes)."""

    OK = 0
    DEACTIVATED = 1
    NOT_FOUND = 2
    SDO_SYNTAX_ERROR = 4  # an SDO of the start-up list was aborted
    SDO_DATA_MISMATCH = 5  # device type or identity read at start-up differ
    STARTING = 8
    BUS_OFF = 11
    PRE_OPERATIONAL = 12  # the node booted again by itself and is being configured again
    SEVERE_BUS_FAULT = 13  # the controller is error-passive
    GUARDING_TOGGLE = 14
    TPDO_TOO_SHORT = 20
    TPDO_MISSING = 22
    TPDOS_PENDING = 23  # operational, not every expected TPDO received yet
    RPDO_MISSING = 128  # the node reports an RPDO timeout (EMCY 8250h)
    REPORTS_PRE_OPERATIONAL = 129
    REPORTS_STOPPED = 130

    @property
    def text(self) -> str:
        """What the code means, in words."""
        return _DIAG_TEXTS[self]


_DIAG_TEXTS = {
    Diagnostic.OK: "no error",
    Diagnostic.DEACTIVATED: "deactivated",
    Diagnostic.NOT_FOUND: "not found (no answer)",
    Diagnostic.SDO_SYNTAX_ERROR: "SDO error at start-up",
    Diagnostic.SDO_DATA_MISMATCH: "device type or identity mismatch at start-up",
    Diagnostic.STARTING: "start-up in progress",
    Diagnostic.BUS_OFF: "bus-off",
    Diagnostic.PRE_OPERATIONAL: "booted again, being configured",
    Diagnostic.SEVERE_BUS_FAULT: "severe bus fault (error-passive)",
    Diagnostic.GUARDING_TOGGLE: "guarding toggle error",
    Diagnostic.TPDO_TOO_SHORT: "TPDO too short",
    Diagnostic.TPDO_MISSING: "expected TPDO missing",
    Diagnostic.TPDOS_PENDING: "operational, not all TPDOs received",
    Diagnostic.RPDO_MISSING: "the node misses RPDOs",
    Diagnostic.REPORTS_PRE_OPERATIONAL: "reports pre-operational",
    Diagnostic.REPORTS_STOPPED: "reports stopped",
}


class MasterState(NamedIntEnum):
    """State of the master (the Lenze master's codes: 0-2 start, 3 configuring, 5 running)."""

    INITIALISING = 0
    RESETTING = 1
    AWAITING_BOOTUP = 2
    CONFIGURING = 3  # stays here while a mandatory node is missing
    RUNNING = 5


class MasterStatus(enum.Enum):
    """State of the master as the Beckhoff master names it."""

    OFFLINE = "OFFLINE"  # not started, or stopped
    RESET = "RESET"  # booting the network
    RUN = "RUN"
    STOP = "STOP"  # the network reaction stopped every node


class LedPattern(enum.Enum):
    """CiA 303-3 indicator patterns; :meth:`lit` tells whether the LED is on at a time."""

    OFF = "off"
    ON = "on"
    BLINKING = "blinking"  # 200 ms on, 200 ms off
    SINGLE_FLASH = "single flash"  # 200 ms on, 1000 ms off
    DOUBLE_FLASH = "double flash"  # 200 on, 200 off, 200 on, 1000 off

    def lit(self, t: float) -> bool:
        """Whether the LED is on at ``t`` seconds (any time base; patterns repeat)."""
        if self is LedPattern.OFF:
            return False
        if self is LedPattern.ON:
            return True
        ms = round(t * 1000.0)
        if self is LedPattern.BLINKING:
            return ms % 400 < 200
        if self is LedPattern.SINGLE_FLASH:
            return ms % 1200 < 200
        phase = ms % 1600
        return phase < 200 or 400 <= phase < 600


@dataclass(frozen=True, slots=True)
class Leds:
    """The two CiA 303-3 indicators of a node: the run LED (NMT state) and the error LED."""

    run: LedPattern
    error: LedPattern


#: One emergency a node sent, as the master keeps it: the runtime's :class:`Emergency`
#: (time, code with the standard's text, register, manufacturer data).
EmcyRecord = Emergency
