"""A complete CANopen device (slave) in Python.

- :class:`Device` — a node on an :class:`~cobus.runtime.AsyncNetwork`
  (``add_device(net, node_id, od)``): SDO server on every configured channel, NMT slave,
  heartbeat, node and life guarding, EMCY, SYNC and TIME consumer, PDOs of every transmission
  type, store/restore of parameters, runtime node-ID change, an LSS slave, EDS export.
- :class:`BlockingDevice` — the same for blocking code (``add_device(net, ...)`` on a
  :class:`~cobus.runtime.Network`).
- :func:`minimal_od` / :class:`DictionaryBuilder` — dictionaries built in code with every
  CiA 301 communication object.
- :class:`Simulation` — ``device.simulation``: late SDO answers, a muted heartbeat, the
  :class:`Deviations` from CiA 301 of a model of a real device.
- Events (:mod:`cobus.device.events`) go to the device's listeners and the network's.

Where each service lives (one module per service, named like its twin in :mod:`cobus.proto`;
each owns its protocol machines, timers, subscriptions, the objects it serves and their
write handlers, and defines those objects for :func:`minimal_od`):

- :mod:`~cobus.device.sdo_server` — SDO server channels, 1200h-127Fh;
- :mod:`~cobus.device.pdo` — TPDOs and RPDOs, 1400h-1BFFh (machines in ``_pdo_machines``);
- :mod:`~cobus.device.sync` — SYNC consumer and producer, 1005h-1007h, 1019h;
- :mod:`~cobus.device.timestamp` — TIME consumer, 1012h;
- :mod:`~cobus.device.emcy` — emergencies and errors, 1001h, 1003h, 1014h, 1015h;
- :mod:`~cobus.device.heartbeat` — producer and consumer, 1016h, 1017h;
- :mod:`~cobus.device.guarding` — node and life guarding, 100Ch, 100Dh;
- :mod:`~cobus.device.nmt` — the NMT slave, boot-up, error behaviour 1029h;
- :mod:`~cobus.device.storage` — power-on values, 1010h store, 1011h restore, the stores;
- :mod:`~cobus.device.lss` — the LSS slave (CiA 305): node-ID and bit rate by identity.

They share one port, ``_core.Core``: the entries, how a value is written, the events out, and
what each service declares there of the objects it owns (write handlers, the pre-defined
COB-IDs that follow the node-ID, objects never stored, downloads it decodes itself), so that
no service names another's objects. :class:`Device` (``device.py``) assembles them and
routes the NMT state to them; ``test_device_layout.py`` keeps each index in its service.
"""

from cobus._moved import renamed_names
from cobus.device.add import add_device
from cobus.device.blocking import BlockingDevice
from cobus.device.device import (
    LOAD_SIGNATURE,
    SAVE_SIGNATURE,
    UNCONFIGURED,
    CobIdRule,
    Deviations,
    Device,
    Listener,
)
from cobus.device.dictionary import DEFAULT_DEVICE_TYPE, DictionaryBuilder, minimal_od
from cobus.device.eds_export import export_eds
from cobus.device.errors import (
    DeviceConfigError,
    DeviceError,
    EntryError,
    EntryNotFoundError,
    EntryRefusedError,
    NodeIdInUseError,
    StorageError,
)
from cobus.device.events import (
    BitRateSwitched,
    Booted,
    ConfigurationProblem,
    DeviceEvent,
    EmergencySent,
    EntryWritten,
    HeartbeatLost,
    HeartbeatRestored,
    LifeGuardingLost,
    LifeGuardingRestored,
    LssBitTimingConfigured,
    LssConfigurationStored,
    LssNodeIdConfigured,
    LssStoreFailed,
    NmtCommandReceived,
    NodeIdChanged,
    ParametersRestored,
    ParametersStored,
    RpdoLost,
    RpdoReceived,
    RpdoRestored,
    StateChanged,
    StorageProblem,
    SyncLost,
    SyncRestored,
    TimeReceived,
    WrongLengthRpdoReceived,
)
from cobus.device.simulation import Simulation
from cobus.device.storage import FileStorage, MemoryStorage, ParameterStorage

__all__ = [
    "DEFAULT_DEVICE_TYPE",
    "LOAD_SIGNATURE",
    "SAVE_SIGNATURE",
    "UNCONFIGURED",
    "BitRateSwitched",
    "BlockingDevice",
    "Booted",
    "CobIdRule",
    "ConfigurationProblem",
    "Deviations",
    "Device",
    "DeviceConfigError",
    "DeviceError",
    "DeviceEvent",
    "DictionaryBuilder",
    "EmergencySent",
    "EntryError",
    "EntryNotFoundError",
    "EntryRefusedError",
    "EntryWritten",
    "FileStorage",
    "HeartbeatLost",
    "HeartbeatRestored",
    "LifeGuardingLost",
    "LifeGuardingRestored",
    "Listener",
    "LssBitTimingConfigured",
    "LssConfigurationStored",
    "LssNodeIdConfigured",
    "LssStoreFailed",
    "MemoryStorage",
    "NmtCommandReceived",
    "NodeIdChanged",
    "NodeIdInUseError",
    "ParameterStorage",
    "ParametersRestored",
    "ParametersStored",
    "RpdoLost",
    "RpdoReceived",
    "RpdoRestored",
    "Simulation",
    "StateChanged",
    "StorageError",
    "StorageProblem",
    "SyncLost",
    "SyncRestored",
    "TimeReceived",
    "WrongLengthRpdoReceived",
    "add_device",
    "export_eds",
    "minimal_od",
]


__getattr__ = renamed_names(
    __name__, {"PdoLengthError": ("WrongLengthRpdoReceived", WrongLengthRpdoReceived)}
)
