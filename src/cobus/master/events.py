"""Events the master reports to the application.

They go to the master's listeners (:meth:`Master.add_listener`) and to the network's
(:meth:`AsyncNetwork.add_listener`). Every node event names the node by ``node_id``.
"""

from __future__ import annotations

from dataclasses import dataclass

from cobus.master.states import MasterState, NodeState
from cobus.proto import Event
from cobus.proto.nmt import NmtState

__all__ = [
    "ConfigurationFailed",
    "DeviceTypeMismatch",
    "ErrorControlLost",
    "ErrorControlRestored",
    "GuardingToggleFault",
    "IdentityMismatch",
    "MasterEvent",
    "MasterStateChanged",
    "NetworkStopped",
    "NodeBooted",
    "NodeEmergency",
    "NodeEvent",
    "NodeMissing",
    "NodeStateChanged",
    "TpdoLengthError",
    "TpdoMissing",
    "TpdoRestored",
    "UnexpectedState",
]


@dataclass(frozen=True, slots=True)
class MasterEvent(Event):
    """Base class of every event of the master."""


@dataclass(frozen=True, slots=True)
class MasterStateChanged(MasterEvent):
    old: MasterState
    new: MasterState


@dataclass(frozen=True, slots=True)
class NetworkStopped(MasterEvent):
    """The network reaction stopped every node because node ``node_id`` failed."""

    node_id: int
    reason: str


@dataclass(frozen=True, slots=True)
class NodeEvent(MasterEvent):
    """Base class of the events about one node."""

    node_id: int


@dataclass(frozen=True, slots=True)
class NodeStateChanged(NodeEvent):
    """The master's state of the node changed (Lenze codes)."""

    old: NodeState
    new: NodeState


@dataclass(frozen=True, slots=True)
class NodeBooted(NodeEvent):
    """The node sent its boot-up message; ``expected`` is False when nobody reset it."""

    expected: bool


@dataclass(frozen=True, slots=True)
class NodeMissing(NodeEvent):
    """The node does not answer (no boot-up and no answer to the 1000h read)."""

    mandatory: bool
    reason: str


@dataclass(frozen=True, slots=True)
class DeviceTypeMismatch(NodeEvent):
    """1000h reads ``actual`` (-1: the node refused the read) where ``expected`` was due."""

    expected: int
    actual: int


@dataclass(frozen=True, slots=True)
class IdentityMismatch(NodeEvent):
    """1018h sub ``subindex`` (``field``) reads ``actual`` (None: refused) not ``expected``."""

    field: str
    subindex: int
    expected: int
    actual: int | None


@dataclass(frozen=True, slots=True)
class ConfigurationFailed(NodeEvent):
    """A write of the start-up list failed: the object, the abort code (None: no answer)
    and the reason, as the SDO error tells it."""

    index: int
    subindex: int
    abort_code: int | None
    reason: str


@dataclass(frozen=True, slots=True)
class ErrorControlLost(NodeEvent):
    """No heartbeat or guarding reply within the node's time (``kind``: which of them)."""

    kind: str


@dataclass(frozen=True, slots=True)
class ErrorControlRestored(NodeEvent):
    kind: str
    state: NmtState


@dataclass(frozen=True, slots=True)
class GuardingToggleFault(NodeEvent):
    expected: int
    received: int


@dataclass(frozen=True, slots=True)
class UnexpectedState(NodeEvent):
    """The node reports an NMT state other than the one the master put it in."""

    expected: NmtState
    reported: NmtState


@dataclass(frozen=True, slots=True)
class NodeEmergency(NodeEvent):
    """An emergency of the node; ``text`` is the code's meaning (CiA 301)."""

    code: int
    register: int
    data: bytes
    text: str


@dataclass(frozen=True, slots=True)
class TpdoMissing(NodeEvent):
    """TPDO ``number`` of the node stopped arriving (its inputs read 0 until it is back)."""

    number: int
    cob_id: int


@dataclass(frozen=True, slots=True)
class TpdoRestored(NodeEvent):
    number: int
    cob_id: int


@dataclass(frozen=True, slots=True)
class TpdoLengthError(NodeEvent):
    """TPDO ``number`` arrived with ``received`` bytes where the mapping has ``expected``."""

    number: int
    expected: int
    received: int
