"""Events the master reports to the application.

They go to the master's listeners (:meth:`Master.add_listener`) and to the network's
(:meth:`AsyncNetwork.add_listener`). Every node event names the node by ``node_id``.
"""

from __future__ import annotations

from dataclasses import dataclass

from cobus._moved import Renamed
from cobus.master.states import MasterState, NodeState
from cobus.proto import Event
from cobus.proto.nmt import NmtState

__all__ = [
    "BootStepDone",
    "BootStepFailed",
    "ConfigurationFailed",
    "DeviceTypeMismatch",
    "ErrorControlLost",
    "ErrorControlRestored",
    "GuardingToggleFault",
    "IdentityMismatch",
    "LssAssigned",
    "LssNotAssigned",
    "MasterEvent",
    "MasterStateChanged",
    "NetworkStopped",
    "NodeBooted",
    "NodeEmergency",
    "NodeEvent",
    "NodeMissing",
    "NodeStateChanged",
    "SdoUnanswered",
    "StateRestored",
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

    def __str__(self) -> str:
        return f"master state {self.old.name} -> {self.new.name}"


@dataclass(frozen=True, slots=True)
class NetworkStopped(MasterEvent):
    """The network reaction stopped every node because node ``node_id`` failed."""

    node_id: int
    reason: str

    def __str__(self) -> str:
        return f"network stopped because of node {self.node_id}: {self.reason}"


@dataclass(frozen=True, slots=True)
class NodeEvent(MasterEvent):
    """Base class of the events about one node."""

    node_id: int


@dataclass(frozen=True, slots=True)
class NodeStateChanged(NodeEvent):
    """The master's state of the node changed (Lenze codes)."""

    old: NodeState
    new: NodeState

    def __str__(self) -> str:
        return f"node {self.node_id}: {self.old.text} -> {self.new.text}"


@dataclass(frozen=True, slots=True)
class NodeBooted(NodeEvent):
    """The node sent its boot-up message; ``expected`` is False when nobody reset it."""

    expected: bool

    def __str__(self) -> str:
        how = "after its reset" if self.expected else "by itself (nobody reset it)"
        return f"node {self.node_id} booted {how}"


@dataclass(frozen=True, slots=True)
class NodeMissing(NodeEvent):
    """The node does not answer (no boot-up and no answer to the 1000h read)."""

    mandatory: bool
    reason: str

    def __str__(self) -> str:
        kind = "mandatory" if self.mandatory else "optional"
        return f"{kind} node {self.node_id} missing: {self.reason}"


@dataclass(frozen=True, slots=True)
class DeviceTypeMismatch(NodeEvent):
    """1000h reads ``actual`` (-1: the node refused the read) where ``expected`` was due."""

    expected: int
    actual: int

    def __str__(self) -> str:
        actual = "refused" if self.actual == -1 else f"0x{self.actual:08X}"
        return f"node {self.node_id}: device type {actual}, expected 0x{self.expected:08X}"


@dataclass(frozen=True, slots=True)
class IdentityMismatch(NodeEvent):
    """1018h sub ``subindex`` (``field``) reads ``actual`` (None: refused) not ``expected``."""

    field: str
    subindex: int
    expected: int
    actual: int | None

    def __str__(self) -> str:
        actual = "refused" if self.actual is None else f"0x{self.actual:08X}"
        return (
            f"node {self.node_id}: {self.field} (1018h sub {self.subindex}) {actual}, "
            f"expected 0x{self.expected:08X}"
        )


@dataclass(frozen=True, slots=True)
class LssAssigned(NodeEvent):
    """Before the node's boot, LSS (CiA 305) gave the device with the node's LSS address
    (``vendor``, ``product``, ``revision``, ``serial``) the node-ID ``node_id``; it had
    ``previous`` (0xFF: none; -1: it did not say); ``stored``: the device stored it (not
    asked when it had the node-ID already)."""

    vendor: int
    product: int
    revision: int
    serial: int
    previous: int
    stored: bool
    #: Why the device does not keep it over a power cycle though ``lss_store`` asked ("":
    #: it does, or nobody asked).
    problem: str = ""

    def __str__(self) -> str:
        had = "it had none" if self.previous == 0xFF else f"it had {self.previous}"
        if self.previous == -1:
            had = "it did not say which it had"
        elif self.previous == self.node_id:
            had = "it had it already"
        kept = ", stored" if self.stored else ""
        if self.problem:
            kept = f"; {self.problem}"
        return (
            f"node {self.node_id}: LSS gave the device with serial 0x{self.serial:08X} its "
            f"node-ID ({had}{kept})"
        )


@dataclass(frozen=True, slots=True)
class LssNotAssigned(NodeEvent):
    """LSS could not give the node's device its node-ID (``reason`` says why); the node
    boots as it is."""

    reason: str

    def __str__(self) -> str:
        return f"node {self.node_id}: no node-ID by LSS: {self.reason}"


@dataclass(frozen=True, slots=True)
class ConfigurationFailed(NodeEvent):
    """A write of the start-up list failed: the object, the abort code (None: no answer)
    and the reason, as the SDO error tells it."""

    index: int
    subindex: int
    abort_code: int | None
    reason: str

    def __str__(self) -> str:
        return (
            f"node {self.node_id}: configuring 0x{self.index:04X}:{self.subindex:02X} "
            f"failed: {self.reason}"
        )


@dataclass(frozen=True, slots=True)
class BootStepDone(NodeEvent):
    """A boot step of the application (:meth:`Master.add_boot_step`) finished for the node;
    ``detail`` is what it says it did (e.g. "re-parameterised, 3 of 12 written...")."""

    step: str
    detail: str

    def __str__(self) -> str:
        return f"node {self.node_id}: {self.step}: {self.detail}"


@dataclass(frozen=True, slots=True)
class BootStepFailed(NodeEvent):
    """A boot step failed: the node is held back (not started), ``reason`` says why."""

    step: str
    reason: str

    def __str__(self) -> str:
        return f"node {self.node_id}: {self.step} failed: {self.reason}"


@dataclass(frozen=True, slots=True)
class ErrorControlLost(NodeEvent):
    """No heartbeat or guarding reply within the node's time (``kind``: which of them)."""

    kind: str

    def __str__(self) -> str:
        return f"node {self.node_id}: {self.kind} lost"


@dataclass(frozen=True, slots=True)
class ErrorControlRestored(NodeEvent):
    kind: str
    state: NmtState

    def __str__(self) -> str:
        return f"node {self.node_id}: {self.kind} back, state {self.state.name}"


@dataclass(frozen=True, slots=True)
class GuardingToggleFault(NodeEvent):
    expected: int
    received: int

    def __str__(self) -> str:
        return f"node {self.node_id}: guarding toggle bit {self.received}, expected {self.expected}"


@dataclass(frozen=True, slots=True)
class UnexpectedState(NodeEvent):
    """The node reports an NMT state other than the one the master put it in."""

    expected: NmtState
    reported: NmtState

    def __str__(self) -> str:
        return f"node {self.node_id} reports {self.reported.name}, expected {self.expected.name}"


@dataclass(frozen=True, slots=True)
class SdoUnanswered(NodeEvent):
    """The node did not answer SDO while the master configured it, though its heartbeat says
    it is there in ``reported``: the master sent ``command`` to make it answer again
    (``"enter_preoperational"`` for a stopped node, ``"reset_node"`` for one whose SDO server
    is silent), or ``""`` when it has sent as many as its limit allows and leaves the node as
    it is (``reason`` says so)."""

    reported: NmtState
    command: str
    reason: str

    def __str__(self) -> str:
        return f"node {self.node_id}: {self.reason}"


@dataclass(frozen=True, slots=True)
class StateRestored(NodeEvent):
    """The node reports the NMT state the master put it in again (after another one)."""

    state: NmtState

    def __str__(self) -> str:
        return f"node {self.node_id} reports {self.state.name} again"


@dataclass(frozen=True, slots=True)
class NodeEmergency(NodeEvent):
    """An emergency of the node; ``text`` is the code's meaning (CiA 301); the fields are
    named as :class:`cobus.proto.emcy.Emergency` names them."""

    code: int
    register: int
    manufacturer_data: bytes
    text: str
    #: Deprecated name of :attr:`manufacturer_data` (as :class:`~cobus.proto.emcy.Emergency`
    #: has it); goes in the next release.
    data = Renamed("manufacturer_data")

    def __str__(self) -> str:
        return f"node {self.node_id}: EMCY 0x{self.code:04X} {self.text}"


@dataclass(frozen=True, slots=True)
class TpdoMissing(NodeEvent):
    """TPDO ``number`` of the node stopped arriving (its inputs read 0 until it is back)."""

    number: int
    cob_id: int

    def __str__(self) -> str:
        return f"node {self.node_id}: TPDO {self.number} (0x{self.cob_id:X}) missing"


@dataclass(frozen=True, slots=True)
class TpdoRestored(NodeEvent):
    number: int
    cob_id: int

    def __str__(self) -> str:
        return f"node {self.node_id}: TPDO {self.number} (0x{self.cob_id:X}) back"


@dataclass(frozen=True, slots=True)
class TpdoLengthError(NodeEvent):
    """TPDO ``number`` arrived with ``received`` bytes where the mapping has ``expected``."""

    number: int
    expected: int
    received: int

    def __str__(self) -> str:
        return (
            f"node {self.node_id}: TPDO {self.number} with {self.received} bytes, "
            f"its mapping has {self.expected}"
        )
