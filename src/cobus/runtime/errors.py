"""The errors of the runtime layer, in one module that every runtime module may import
(the network, the remote node and the services do not import each other for them)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from cobus.errors import CobusError
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError

if TYPE_CHECKING:
    from cobus.od import Variable

__all__ = [
    "BusOpenError",
    "EmcyTimeoutError",
    "LssRefusedError",
    "LssScanError",
    "LssTimeoutError",
    "NetworkClosedError",
    "NmtTimeoutError",
    "NodeIdInUseError",
    "ObjectAccessError",
    "ObjectNotFoundError",
    "PdoConfigurationError",
    "PdoTimeoutError",
    "ReentrantCallError",
    "SimulationStalledError",
    "TxOverflowError",
]


class NetworkClosedError(CobusError, RuntimeError):
    """The network is not connected (never connected, or already disconnected)."""


class TxOverflowError(CobusError):
    """The transmit backlog is full: the interface has refused frames for too long.

    Raised by :meth:`AsyncNetwork.send` instead of dropping the frame silently. The bus is
    probably off or disconnected; see the :class:`~cobus.runtime.events.TxQueueFull` event.
    """


class ObjectNotFoundError(CobusError, KeyError):
    """An object named by index or name is not in the node's object dictionary."""

    def __str__(self) -> str:
        return str(self.args[0])


class ObjectAccessError(SdoAbortedError):
    """Refused before anything was sent: the EDS says the object cannot be read (or written).

    An :class:`SdoAbortedError` with the code the node would have answered, so code that
    handles aborts handles this too."""

    def __init__(self, var: Variable, node_id: int, *, write: bool) -> None:
        code = SdoAbortCode.WRITE_READ_ONLY if write else SdoAbortCode.READ_WRITE_ONLY
        super().__init__(code, index=var.index, subindex=var.subindex, node=node_id, by_peer=False)
        what = "written" if write else "read"
        raw = "download" if write else "upload"
        self.args = (
            f"node {node_id}: {var.name!r} (0x{var.index:04X}:{var.subindex:02X}) is "
            f"{var.access} in its EDS and cannot be {what}; nothing was sent (the node would "
            f"abort 0x{int(code):08X}). If the device allows more than its EDS says, use "
            f"sdo.{raw}() for raw bytes",
        )


class ReentrantCallError(CobusError, RuntimeError):
    """A blocking call was made where it would deadlock or re-enter the event loop."""


class BusOpenError(CobusError):
    """The CAN interface could not be opened; the message says which and why."""


class SimulationStalledError(CobusError, RuntimeError):
    """The simulated loop has nothing scheduled and nothing to poll: it would wait forever.

    This means an awaited operation can never complete (e.g. a future nobody resolves and no
    timeout armed). Add a timeout to the operation, or check that the peer is on the network.
    """


class EmcyTimeoutError(CobusError, TimeoutError):
    """No emergency arrived within the time waited for one."""


class LssTimeoutError(CobusError, TimeoutError):
    """No LSS slave answered a request in time (none in configuration, or none with that
    identity)."""


class LssRefusedError(CobusError):
    """An LSS slave answered a configuration request with an error (``service``, ``error``,
    ``spec``: the answer's bytes; the message says what they mean)."""

    def __init__(self, service: str, error: int, spec: int, text: str) -> None:
        super().__init__(f"{service}: the slave refused: {text}")
        self.service, self.error, self.spec = service, error, spec


class LssScanError(CobusError):
    """A fastscan could not settle an identity field (answers too late or missing twice)."""


class NmtTimeoutError(CobusError, TimeoutError):
    """A node did not report the awaited NMT state (or boot-up, or heartbeat) in time."""


class PdoConfigurationError(CobusError):
    """A PDO configuration that could not be read from, or written to, the node: which PDO,
    which step, and the node's answer."""


class PdoTimeoutError(CobusError, TimeoutError):
    """A PDO expected from the node did not arrive in time."""


class NodeIdInUseError(CobusError, ValueError):
    """A node-ID this process already answers to on the network (another local device holds
    it); give each local device a node-ID of its own. The device layer raises this one too
    (``cobus.device.NodeIdInUseError`` is the same class; it is no ``DeviceError``)."""
