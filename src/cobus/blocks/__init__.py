"""Program blocks: the reusable parts a controller program is built from, on top of the
master, the drive profiles and any node with an SDO server.

- :mod:`cobus.blocks.parameters` — parameter sets from YAML, CSV or a DCF;
- :mod:`cobus.blocks.param_manager` — read, compare, write, save, read back and verify a
  node's parameters, by hand or by the master before it starts the node;
- :mod:`cobus.blocks.alarms` — the alarm handler: active alarms from codes, rules, EMCY and
  the master's events, the rotating current alarm, acknowledgement;
  :mod:`cobus.blocks.alarm_history` its SQLite history, :mod:`cobus.blocks.alarm_texts`
  the code → text tables;
- :mod:`cobus.blocks.netvars` — CAN network variables between controllers, lists defined in
  one shared file (:mod:`cobus.blocks.netvar_lists`; wire format in
  ``docs/network-variables.md``).
"""

from cobus._moved import renamed_names
from cobus.blocks.alarm_history import (
    AlarmHistory,
    AlarmHistoryDamagedError,
    AlarmHistoryError,
    AlarmRecord,
)
from cobus.blocks.alarm_texts import AlarmSeverity, MasterAlarm, table_text
from cobus.blocks.alarms import (
    Alarm,
    AlarmAcknowledged,
    AlarmCleared,
    AlarmEvent,
    AlarmHandler,
    AlarmRaised,
    AlarmRuleError,
)
from cobus.blocks.netvar_lists import (
    NetVarConfigError,
    NetVarDefinition,
    VarList,
    load_netvars,
    loads_netvars,
)
from cobus.blocks.netvars import (
    AsyncNetworkVariables,
    ListIncomplete,
    ListMalformed,
    ListReceived,
    ListRequested,
    ListStale,
    NetVarEvent,
    NetworkVariables,
)
from cobus.blocks.param_manager import (
    AsyncParameterManager,
    CommandsInSetError,
    ParameterFailure,
    Parameterise,
    ParameterManager,
    ParameterReport,
    ParameterStep,
)
from cobus.blocks.parameters import (
    Parameter,
    ParameterFileError,
    ParameterProblem,
    ParameterSet,
    SaveCommand,
    load_parameters,
    loads_parameters,
)

__all__ = [
    "Alarm",
    "AlarmAcknowledged",
    "AlarmCleared",
    "AlarmEvent",
    "AlarmHandler",
    "AlarmHistory",
    "AlarmHistoryDamagedError",
    "AlarmHistoryError",
    "AlarmRaised",
    "AlarmRecord",
    "AlarmRuleError",
    "AlarmSeverity",
    "AsyncNetworkVariables",
    "AsyncParameterManager",
    "CommandsInSetError",
    "ListIncomplete",
    "ListMalformed",
    "ListReceived",
    "ListRequested",
    "ListStale",
    "MasterAlarm",
    "NetVarConfigError",
    "NetVarDefinition",
    "NetVarEvent",
    "NetworkVariables",
    "Parameter",
    "ParameterFailure",
    "ParameterFileError",
    "ParameterManager",
    "ParameterProblem",
    "ParameterReport",
    "ParameterSet",
    "ParameterStep",
    "Parameterise",
    "SaveCommand",
    "VarList",
    "load_netvars",
    "load_parameters",
    "loads_netvars",
    "loads_parameters",
    "table_text",
]


# (renamed: cobus.od.Severity is the severity of an EDS finding)
__getattr__ = renamed_names(__name__, {"Severity": ("AlarmSeverity", AlarmSeverity)})
