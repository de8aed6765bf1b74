"""The runtime: binds protocol machines to a python-can bus and a clock.

- :class:`AsyncNetwork` — the asyncio API.
- :class:`Network` — the same operations for blocking code (loop in a background thread, or
  inline on the simulated clock).
- :class:`SimulatedEventLoop` — the virtual clock.
"""

from cobus.runtime.blocking import Network, ReentrantCallError, RemoteNode
from cobus.runtime.bus import BusOpenError, open_bus
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
from cobus.runtime.loop import SimulatedEventLoop, SimulationStalledError, new_event_loop
from cobus.runtime.network import (
    AsyncNetwork,
    MachineHost,
    NetworkClosedError,
    Subscription,
    TxOverflowError,
)
from cobus.runtime.remote import NmtMaster, ObjectNotFoundError, SdoChannel, SyncService
from cobus.runtime.remote import RemoteNode as AsyncRemoteNode

__all__ = [
    "AsyncNetwork",
    "AsyncRemoteNode",
    "BusErrorFrame",
    "BusOpenError",
    "BusState",
    "BusStateChanged",
    "HandlerFailed",
    "MachineHost",
    "Network",
    "NetworkClosedError",
    "NmtMaster",
    "ObjectNotFoundError",
    "ReceiveFailed",
    "ReentrantCallError",
    "RemoteNode",
    "RxOverflow",
    "SdoChannel",
    "SimulatedEventLoop",
    "SimulationStalledError",
    "Subscription",
    "SyncService",
    "TxBufferOverflow",
    "TxOverflowError",
    "TxQueueFull",
    "TxResumed",
    "new_event_loop",
    "open_bus",
]
