"""Code → text tables for alarms, one per kind of device, read from data files: the
documents' tables (``cobus/profiles/tables/*.yaml``) and CiA 301's
(``cobus/proto/emcy_codes.yaml``); only the master's own alarm texts are in code. An
unknown code still shows its number and, where the table has classes, its class:
``table_text("zapi", 99)`` is ``"ALARM 99"``, ``table_text("cia301", 0x4399)`` is
``"Temperature (4399h)"``.

=========  ===========================================================================
table      codes
=========  ===========================================================================
cia301     EMCY error codes (1001h classes for the others)
cia402     603Fh error codes of a drive (CiA 402-2), else the CiA 301 class
zapi       ZAPI ACE2 alarm codes (decimal, TPDO2 byte 0)
stober     STÖBER MDS 5000 E82 events (30 = no event)
ecmotor    EC motor m_sss (200Eh) bit numbers
master     the master's own alarms (node missing, heartbeat lost, bus-off, ...)
=========  ===========================================================================
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from cobus._enum import NamedIntEnum
from cobus._moved import renamed_names
from cobus.proto.emcy import describe

__all__ = ["ALIASES", "TABLES", "AlarmSeverity", "MasterAlarm", "Table", "emcy_text", "table_text"]


class AlarmSeverity(NamedIntEnum):
    """How bad an alarm is (ordered: a higher one is worse)."""

    INFO = 0
    WARNING = 1
    ALARM = 2

    @classmethod
    def of(cls, value: AlarmSeverity | int | str) -> AlarmSeverity:
        """A severity from itself, its number or its name (``"warning"``)."""
        if isinstance(value, str):
            try:
                return cls[value.strip().upper()]
            except KeyError:
                names = ", ".join(s.name.lower() for s in cls)
                raise ValueError(f"severity {value!r}: one of {names}") from None
        return cls(value)


class MasterAlarm(NamedIntEnum):
    """The codes of the alarms the master's events raise (table ``master``)."""

    NODE_MISSING = 1
    ERROR_CONTROL_LOST = 2
    WRONG_DEVICE = 3
    CONFIGURATION_FAILED = 4
    UNEXPECTED_STATE = 5
    GUARDING_TOGGLE = 6
    TPDO_MISSING = 7
    BUS_OFF = 10
    ERROR_PASSIVE = 11
    NETWORK_STOPPED = 12


_MASTER_TEXTS = {
    MasterAlarm.NODE_MISSING: "node missing",
    MasterAlarm.ERROR_CONTROL_LOST: "heartbeat or node guarding lost",
    MasterAlarm.WRONG_DEVICE: "wrong device type or identity",
    MasterAlarm.CONFIGURATION_FAILED: "configuration failed",
    MasterAlarm.UNEXPECTED_STATE: "node in an unexpected NMT state",
    MasterAlarm.GUARDING_TOGGLE: "node guarding toggle bit wrong",
    MasterAlarm.TPDO_MISSING: "TPDO missing",
    MasterAlarm.BUS_OFF: "CAN bus-off",
    MasterAlarm.ERROR_PASSIVE: "CAN error passive",
    MasterAlarm.NETWORK_STOPPED: "network stopped",
}


@dataclass(frozen=True)
class Table:
    """One table: its name, what its codes are, and the text of a code."""

    name: str
    description: str
    text: Callable[[int], str]
    #: The severity an alarm of this table gets unless the caller says otherwise.
    severity: AlarmSeverity = AlarmSeverity.ALARM
    #: The code that means "no alarm" (besides 0).
    no_alarm: int = 0
    #: Whether the table can name an EMCY error code (for :func:`emcy_text`).
    emcy: bool = False


def _cia301(code: int) -> str:
    try:
        return describe(code)
    except ValueError:
        return f"code {code}"


def _cia402(code: int) -> str:
    from cobus.profiles.cia402 import error_text

    try:
        return error_text(code)
    except ValueError:
        return f"code {code}"


def _zapi(code: int) -> str:
    from cobus.profiles.zapi import alarm_text

    return alarm_text(code) or "no alarm"


def _stober(code: int) -> str:
    from cobus.profiles.stober import EVENTS

    event = EVENTS.get(code)
    return f"E82 event {code}" if event is None else event[0]


def _ecmotor(bit: int) -> str:
    from cobus.profiles.ecmotor import M_SSS_BITS

    return M_SSS_BITS.get(bit, f"m_sss bit {bit}")


def _master(code: int) -> str:
    try:
        return _MASTER_TEXTS[MasterAlarm(code)]
    except ValueError:
        return f"master alarm {code}"


#: The tables by name.
TABLES: Mapping[str, Table] = {
    t.name: t
    for t in (
        Table("cia301", "EMCY error codes (CiA 301)", _cia301, emcy=True),
        Table("cia402", "drive error codes, 603Fh (CiA 402-2)", _cia402, emcy=True),
        Table("zapi", "ZAPI ACE2 alarm codes", _zapi),
        Table("stober", "STÖBER MDS 5000 E82 events", _stober, no_alarm=30, emcy=True),
        Table("ecmotor", "EC motor m_sss bits", _ecmotor),
        Table("master", "the master's alarms", _master),
    )
}


#: Sources whose codes another table names.
ALIASES: Mapping[str, str] = {"emcy": "cia301"}


def table_text(table: str, code: int) -> str:
    """The text of ``code`` in ``table`` (an unknown code: its number and class)."""
    found = TABLES.get(ALIASES.get(table, table))
    if found is None:
        raise KeyError(f"no alarm text table {table!r}; the tables: {', '.join(TABLES)}")
    return found.text(code)


def emcy_text(table: str, code: int) -> str:
    """The text of EMCY error ``code`` as a device of ``table`` means it: a CiA 402 drive's
    wording, the STÖBER event sent with that code (``"overcurrent (E82 33)"``), else CiA 301."""
    found = TABLES.get(table)
    if found is None or not found.emcy:
        names = ", ".join(t.name for t in TABLES.values() if t.emcy)
        raise KeyError(f"table {table!r} does not name EMCY codes; these do: {names}")
    if table == "stober":
        from cobus.profiles.stober import EVENTS

        for number, (text, emcy_code, _register) in EVENTS.items():
            if emcy_code == code and number != 30:
                return f"{text} (E82 {number})"
        return _cia301(code)
    return found.text(code)


# (renamed: cobus.od.Severity is the severity of an EDS finding)
__getattr__ = renamed_names(__name__, {"Severity": ("AlarmSeverity", AlarmSeverity)})
