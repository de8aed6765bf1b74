"""The CANopen master: NMT manager with CiA 302-2 boot-up, supervision and a process image.

- :func:`load_network` reads a network description (YAML, in the spirit of ROS 2 canopen's
  ``bus.yml``) into a :class:`NetworkConfig`; ``cobus config check FILE`` lists its problems.
- :class:`Master` boots the network on an :class:`~cobus.runtime.AsyncNetwork` (every node in
  parallel: reset, boot-up, device type and identity check, start-up SDOs, heartbeat or node
  guarding, start), supervises it (error control with toggle check, TPDO presence and length,
  emergencies, unexpected states, re-booted nodes) and reacts per node and per network.
- ``master.inputs`` / ``master.outputs``: named, scaled signals carried by the PDOs;
  :meth:`Master.add_tpdo_listener` calls the application each time a TPDO is taken in.
- :class:`BlockingMaster`: the same for scripts, on :class:`cobus.runtime.Network`.
"""

from cobus.master.blocking import BlockingMaster
from cobus.master.config import (
    MasterConfig,
    NetworkConfig,
    NodeConfig,
    PdoLayout,
    SdoEntry,
    Signal,
    check_network,
    load_network,
    loads_network,
    parse_network,
)
from cobus.master.diagnostics import BusLoadMeter, MasterDiagnostics, frame_bits
from cobus.master.errors import (
    BootStepError,
    BootTimeoutError,
    ConfigProblem,
    MasterError,
    MasterValueError,
    NetworkConfigError,
    NodeNotFoundError,
    Severity,
    SignalError,
    SignalValueError,
)
from cobus.master.events import (
    BootStepDone,
    BootStepFailed,
    ConfigurationFailed,
    DeviceTypeMismatch,
    ErrorControlLost,
    ErrorControlRestored,
    GuardingToggleFault,
    IdentityMismatch,
    LssAssigned,
    LssNotAssigned,
    MasterEvent,
    MasterStateChanged,
    NetworkStopped,
    NodeBooted,
    NodeEmergency,
    NodeEvent,
    NodeMissing,
    NodeStateChanged,
    SdoUnanswered,
    StateRestored,
    TpdoLengthError,
    TpdoMissing,
    TpdoRestored,
    UnexpectedState,
)
from cobus.master.image import Inputs, Outputs
from cobus.master.master import BootStep, Master, MasterListener, TpdoListener
from cobus.master.node import ManagedNode
from cobus.master.states import (
    Diagnostic,
    EmcyRecord,
    LedPattern,
    Leds,
    MasterState,
    MasterStatus,
    NodeState,
)

__all__ = [
    "BlockingMaster",
    "BootStep",
    "BootStepDone",
    "BootStepError",
    "BootStepFailed",
    "BootTimeoutError",
    "BusLoadMeter",
    "ConfigProblem",
    "ConfigurationFailed",
    "DeviceTypeMismatch",
    "Diagnostic",
    "EmcyRecord",
    "ErrorControlLost",
    "ErrorControlRestored",
    "GuardingToggleFault",
    "IdentityMismatch",
    "Inputs",
    "LedPattern",
    "Leds",
    "LssAssigned",
    "LssNotAssigned",
    "ManagedNode",
    "Master",
    "MasterConfig",
    "MasterDiagnostics",
    "MasterError",
    "MasterEvent",
    "MasterListener",
    "MasterState",
    "MasterStateChanged",
    "MasterStatus",
    "MasterValueError",
    "NetworkConfig",
    "NetworkConfigError",
    "NetworkStopped",
    "NodeBooted",
    "NodeConfig",
    "NodeEmergency",
    "NodeEvent",
    "NodeMissing",
    "NodeNotFoundError",
    "NodeState",
    "NodeStateChanged",
    "Outputs",
    "PdoLayout",
    "SdoEntry",
    "SdoUnanswered",
    "Severity",
    "Signal",
    "SignalError",
    "SignalValueError",
    "StateRestored",
    "TpdoLengthError",
    "TpdoListener",
    "TpdoMissing",
    "TpdoRestored",
    "UnexpectedState",
    "check_network",
    "frame_bits",
    "load_network",
    "loads_network",
    "parse_network",
]
