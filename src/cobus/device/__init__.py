"""A complete CANopen device (slave) in Python.

- :class:`Device` — a node on an :class:`~cobus.runtime.AsyncNetwork`
  (``add_device(net, node_id, od)``): SDO server on every configured channel, NMT slave,
  heartbeat, node and life guarding, EMCY, SYNC and TIME consumer, PDOs of every transmission
  type, store/restore of parameters, runtime node-ID change, EDS export.
- :class:`BlockingDevice` — the same for blocking code (``add_device(net, ...)`` on a
  :class:`~cobus.runtime.Network`).
- :func:`minimal_od` / :class:`DictionaryBuilder` — dictionaries built in code with every
  CiA 301 communication object.
- Events (:mod:`cobus.device.events`) go to the device's listeners and the network's.
"""

from cobus.device.add import add_device
from cobus.device.blocking import BlockingDevice
from cobus.device.device import (
    LOAD_SIGNATURE,
    SAVE_SIGNATURE,
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
    Booted,
    ConfigurationProblem,
    DeviceEvent,
    EmergencySent,
    EntryWritten,
    HeartbeatLost,
    HeartbeatRestored,
    LifeGuardingLost,
    LifeGuardingRestored,
    NmtCommandReceived,
    NodeIdChanged,
    ParametersRestored,
    ParametersStored,
    PdoLengthError,
    RpdoLost,
    RpdoReceived,
    RpdoRestored,
    StateChanged,
    StorageProblem,
    SyncLost,
    SyncRestored,
    TimeReceived,
)
from cobus.device.simulation import Simulation
from cobus.device.storage import FileStorage, MemoryStorage, ParameterStorage

__all__ = [
    "DEFAULT_DEVICE_TYPE",
    "LOAD_SIGNATURE",
    "SAVE_SIGNATURE",
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
    "MemoryStorage",
    "NmtCommandReceived",
    "NodeIdChanged",
    "NodeIdInUseError",
    "ParameterStorage",
    "ParametersRestored",
    "ParametersStored",
    "PdoLengthError",
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
    "add_device",
    "export_eds",
    "minimal_od",
]
