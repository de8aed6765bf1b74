"""The runtime: binds protocol machines to a python-can bus and a clock.

- :class:`AsyncNetwork` — the asyncio API.
- :class:`Network` — the same operations for blocking code (loop in a background thread, or
  inline on the simulated clock).
- :class:`SimulatedEventLoop` — the virtual clock; :class:`RealTimeLoop` and :func:`run` —
  real time with reader threads dispatching frames directly (``docs/realtime.md``).
- ``net.add_remote(node_id, eds)`` — a node this side is the client of: ``sdo``
  (:mod:`~cobus.runtime.remote`), ``nmt`` (:mod:`~cobus.runtime.nmt`), ``emcy``
  (:mod:`~cobus.runtime.emcy`), ``tpdo``/``rpdo`` (:mod:`~cobus.runtime.pdo`).

The errors a user of a remote node meets are importable from here as well.
"""

from cobus._moved import renamed_names
from cobus.od import ValueRangeError
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError, SdoError, SdoTimeoutError
from cobus.runtime.blocking import Network, ReentrantCallError, RemoteNode
from cobus.runtime.bus import BusOpenError, open_bus
from cobus.runtime.emcy import EmcyTimeoutError, Emergency
from cobus.runtime.errors import (
    LssRefusedError,
    LssScanError,
    LssTimeoutError,
    NodeIdInUseError,
)
from cobus.runtime.events import (
    BusErrorFrame,
    BusState,
    BusStateChanged,
    HandlerFailed,
    ReceiveFailed,
    RxOverflow,
    TxBufferOverflow,
    TxQueueFull,
    TxResumed,
)
from cobus.runtime.local_nodes import LocalNodes
from cobus.runtime.loop import (
    RealTimeLoop,
    SimulatedEventLoop,
    SimulationStalledError,
    new_event_loop,
    run,
)
from cobus.runtime.network import (
    AsyncNetwork,
    MachineHost,
    NetworkClosedError,
    Subscription,
    TxOverflowError,
)
from cobus.runtime.nmt import NmtTimeoutError
from cobus.runtime.pdo import (
    PdoConfigurationError,
    PdoReceived,
    PdoRejected,
    PdoTimeoutError,
)
from cobus.runtime.periodic import InterfaceTimingError
from cobus.runtime.remote import (
    AsyncRemoteNode,
    NetworkSync,
    NmtMaster,
    ObjectAccessError,
    ObjectNotFoundError,
    SdoChannel,
)

__all__ = [
    "AsyncNetwork",
    "AsyncRemoteNode",
    "BusErrorFrame",
    "BusOpenError",
    "BusState",
    "BusStateChanged",
    "EmcyTimeoutError",
    "Emergency",
    "HandlerFailed",
    "InterfaceTimingError",
    "LocalNodes",
    "LssRefusedError",
    "LssScanError",
    "LssTimeoutError",
    "MachineHost",
    "Network",
    "NetworkClosedError",
    "NetworkSync",
    "NmtMaster",
    "NmtTimeoutError",
    "NodeIdInUseError",
    "ObjectAccessError",
    "ObjectNotFoundError",
    "PdoConfigurationError",
    "PdoReceived",
    "PdoRejected",
    "PdoTimeoutError",
    "RealTimeLoop",
    "ReceiveFailed",
    "ReentrantCallError",
    "RemoteNode",
    "RxOverflow",
    "SdoAbortCode",
    "SdoAbortedError",
    "SdoChannel",
    "SdoError",
    "SdoTimeoutError",
    "SimulatedEventLoop",
    "SimulationStalledError",
    "Subscription",
    "TxBufferOverflow",
    "TxOverflowError",
    "TxQueueFull",
    "TxResumed",
    "ValueRangeError",
    "new_event_loop",
    "open_bus",
    "run",
]

__getattr__ = renamed_names(__name__, {"SyncService": ("NetworkSync", NetworkSync)})
