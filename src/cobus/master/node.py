"""One node under the master: its public state, its diagnostic code and LEDs.

A :class:`ManagedNode` holds the two parts that act on it: :attr:`~ManagedNode.boot`, its
CiA 302-2 boot (``master/boot.py``: reset, checks, configuration, error control set-up, as
an asyncio task of its own, all nodes in parallel), and :attr:`~ManagedNode.supervision`,
what the master watches once it is configured (``master/supervision.py``: heartbeat or
guarding, emergencies, TPDOs, NMT state; a node that boots again by itself is configured
again). The node reads both to say what it is (:attr:`~ManagedNode.diagnostic`,
:attr:`~ManagedNode.led`, :meth:`~ManagedNode.describe`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from cobus.master.boot import NodeBoot
from cobus.master.config import NodeConfig, PdoLayout
from cobus.master.events import ConfigurationFailed, NodeStateChanged
from cobus.master.states import Diagnostic, EmcyRecord, LedPattern, Leds, NodeState
from cobus.master.supervision import NodeSupervision
from cobus.proto import Frame
from cobus.proto.nmt import NmtState
from cobus.runtime.events import BusState
from cobus.runtime.remote import SdoChannel

if TYPE_CHECKING:
    from cobus.master._context import NodeContext
    from cobus.master.master import Master

__all__ = ["ManagedNode"]

_BOOTING = (
    NodeState.RESETTING,
    NodeState.AWAITING_BOOTUP,
    NodeState.WAITING,
    NodeState.CONFIGURING,
    NodeState.CONFIGURED,
)


class ManagedNode:
    """A node of the network as the master manages it: ``master.nodes[node_id]``.

    ``state`` is the Lenze node state code, ``diagnostic`` the Beckhoff diagnostic code,
    ``nmt_state`` the NMT state last reported (or commanded), ``emcy_history`` the last 8
    emergencies (newest first), ``led`` the CiA 303-3 indicators, ``sdo`` an SDO channel to
    the node (``await node.sdo.read(0x1008)``), on the network's one SDO transport to it:
    a remote node or gateway asking the same node waits for its turn.

    What the master does with the node is in its two parts: ``boot`` (:class:`NodeBoot`,
    with the wake limits ``WAKE_LIMIT``/``WAKE_WINDOW``) and ``supervision``
    (:class:`NodeSupervision`, with the heal limits ``HEAL_LIMIT``/``HEAL_WINDOW``/
    ``HEAL_DELAY``): set those on a node's part (``node.supervision.HEAL_LIMIT = 5``) or
    on the class for every node.
    """

    def __init__(self, context: NodeContext, config: NodeConfig) -> None:
        #: The node's port to its master (all it may ask of it).
        self.context = context
        self.config = config
        self.node_id = config.node_id
        self.name = config.name
        # the master's transfers stay off the network's event stream, as its own events say
        self.sdo = SdoChannel(
            context.network, self.node_id, config.od, timeout=config.sdo_timeout, emit=False
        )
        self._state = NodeState.UNDEFINED
        #: The NMT state last reported by heartbeat, guarding or boot-up (or commanded).
        self.nmt_state: NmtState | None = None
        #: The NMT state the master put the node in (None while it configures).
        self.expected_nmt: NmtState | None = None
        #: Which error control runs: "heartbeat", "guarding" or None.
        self.error_control: str | None = None
        #: 1000h as read at the last boot-up, and 1018h sub 1..4 where they were checked.
        self.device_type: int | None = None
        self.identity: dict[str, int | None] = {}
        #: Every failed write of the start-up lists, oldest first.
        self.config_errors: list[ConfigurationFailed] = []
        #: Why the node holds the network back or failed, in words (None: it does not).
        self.problem: str | None = None
        self.boot_count = 0
        self.boot_task: asyncio.Task[None] | None = None
        #: Frames counted per PDO: received TPDOs and sent RPDOs by number.
        self.tpdo_received: dict[int, int] = {}
        self.rpdo_sent: dict[int, int] = {}
        #: The application's boot steps (:meth:`Master.add_boot_step`), as (name, step).
        self.boot_steps: list[tuple[str, Callable[[ManagedNode], Awaitable[str | None]]]] = []
        #: What each boot step said at the last boot-up (name -> detail).
        self.step_results: dict[str, str] = {}
        #: Its CiA 302-2 boot (reset, checks, configuration, error control set-up).
        self.boot = NodeBoot(self)
        #: Its error control, emergencies, TPDOs and NMT state, watched once configured.
        self.supervision = NodeSupervision(self)

    # ================================================================== public

    def __repr__(self) -> str:
        return f"<ManagedNode {self.node_id} {self.name!r} {self._state.name}>"

    @property
    def master(self) -> Master:
        """The master that manages the node (for the application's ports)."""
        return self.context.master

    @property
    def state(self) -> NodeState:
        """The master's state of the node (the Lenze node state codes)."""
        return self._state

    @property
    def heard_at(self) -> float | None:
        """When (network time) the node's last heartbeat or guarding answer came (None: none
        since the master started)."""
        heard = self.supervision.heard
        return None if heard is None else heard[0]

    @property
    def mandatory(self) -> bool:
        """Whether the network cannot run without this node."""
        return self.config.mandatory

    @property
    def operational(self) -> bool:
        """Whether process data flows: started by the master and not reported otherwise."""
        return self._state is NodeState.OPERATIONAL and self.nmt_state in (
            None,
            NmtState.OPERATIONAL,
        )

    @property
    def emcy_history(self) -> tuple[EmcyRecord, ...]:
        """The last 8 emergencies, newest first."""
        return self.supervision.emcy_history

    @property
    def emcy_count(self) -> int:
        """How many emergencies the node sent since the master was made (the application
        may set it back to 0)."""
        return self.supervision.emcy_count

    @emcy_count.setter
    def emcy_count(self, value: int) -> None:
        self.supervision.emcy_count = value

    @property
    def error_register(self) -> int:
        """1001h as the node's last emergency gave it."""
        return self.supervision.error_register

    @error_register.setter
    def error_register(self, value: int) -> None:
        self.supervision.error_register = value

    @property
    def diagnostic(self) -> Diagnostic:
        """The Beckhoff diagnostic code of the node."""
        diag = self.context.diagnostics
        state = self._state
        watch = self.supervision
        boot = self.boot
        if not self.config.enabled:
            return Diagnostic.DEACTIVATED
        if diag.bus_off:
            return Diagnostic.BUS_OFF
        if diag.bus_state is BusState.PASSIVE:
            return Diagnostic.SEVERE_BUS_FAULT
        if watch.toggle_fault:
            return Diagnostic.GUARDING_TOGGLE
        if boot.not_found or watch.lost or state in (NodeState.ABSENT, NodeState.ERROR_CONTROL):
            return Diagnostic.NOT_FOUND
        if boot.sdo_error:
            return Diagnostic.SDO_SYNTAX_ERROR
        if boot.mismatch:
            return Diagnostic.SDO_DATA_MISMATCH
        if state in _BOOTING or (state is NodeState.UNDEFINED and self.context.started):
            return Diagnostic.PRE_OPERATIONAL if watch.rebooted else Diagnostic.STARTING
        if state is NodeState.OPERATIONAL:
            if self.nmt_state is NmtState.PRE_OPERATIONAL:
                return Diagnostic.REPORTS_PRE_OPERATIONAL
            if self.nmt_state is NmtState.STOPPED:
                return Diagnostic.REPORTS_STOPPED
            if watch.tpdo_too_short:
                return Diagnostic.TPDO_TOO_SHORT
            if watch.tpdo_missing:
                return Diagnostic.TPDO_MISSING
            if watch.rpdo_missing:
                return Diagnostic.RPDO_MISSING
            if watch.tpdos_pending:
                return Diagnostic.TPDOS_PENDING
        return Diagnostic.OK

    @property
    def led(self) -> Leds:
        """The CiA 303-3 run and error LEDs the node shows (as the master sees it)."""
        nmt = self.nmt_state
        if nmt is NmtState.OPERATIONAL:
            run = LedPattern.ON
        elif nmt is NmtState.PRE_OPERATIONAL:
            run = LedPattern.BLINKING
        elif nmt is NmtState.STOPPED:
            run = LedPattern.SINGLE_FLASH
        else:
            run = LedPattern.OFF
        diag = self.context.diagnostics
        if diag.bus_off:
            error = LedPattern.ON
        elif self.supervision.lost or self.supervision.toggle_fault:
            error = LedPattern.DOUBLE_FLASH
        elif diag.warning:
            error = LedPattern.SINGLE_FLASH
        else:
            error = LedPattern.OFF
        return Leds(run, error)

    @property
    def settled(self) -> bool:
        """Whether the first boot of the network may go on without waiting for this node."""
        if not self.config.enabled:
            return True
        if self.boot_task is not None and not self.boot_task.done():
            return False
        if self.config.mandatory:
            return self._state is NodeState.CONFIGURED or self._state is NodeState.OPERATIONAL
        return True

    async def restart(self) -> None:
        """Boot the node again (reset, check, configure) and start it when the network runs;
        returns when its boot-up sequence is over (see :attr:`state`)."""
        if not self.context.started:
            from cobus.master.errors import MasterError

            raise MasterError("the master is not started: call master.start() first")
        self.boot.allow_wakes()  # (the application asks: the wakes may be tried again)
        task = self.boot.spawn("reset")
        try:
            await asyncio.shield(task)
        except asyncio.CancelledError:
            if not task.cancelled():  # the caller itself was cancelled
                raise

    # ================================================================== state

    def set_state(self, new: NodeState) -> None:
        """The node's state becomes ``new`` (diagnostic and LED follow; the master is told)."""
        old = self._state
        if new is old:
            return
        self._state = new
        self.context.emit(NodeStateChanged(self.node_id, old, new))

    # ================================================================== process data

    def send_rpdo(self, layout: PdoLayout) -> bool:
        """Send RPDO ``layout`` with the current outputs (only while operational); returns
        whether it went out."""
        if layout.linked or not self.operational or not self.context.running:
            return False
        image = self.context.image
        if not image.has_rpdo(self.node_id, layout.number):
            return False
        frame = Frame(
            layout.cob_id, image.rpdo_data(self.node_id, layout.number), extended=layout.extended
        )
        if not self.context.send(frame):
            return False
        number = layout.number
        self.rpdo_sent[number] = self.rpdo_sent.get(number, 0) + 1
        counters = self.context.diagnostics.pdo_counters
        key = (self.node_id, "rpdo", number)
        counters[key] = counters.get(key, 0) + 1
        return True

    def describe(self) -> str:
        """What holds the node back, in words (the master's boot report)."""
        role = "mandatory" if self.config.mandatory else "optional"
        text = (
            f"node {self.node_id} {self.name!r} ({role}): {self._state.text} "
            f"[state {int(self._state)}, diagnostic {int(self.diagnostic)} "
            f"{self.diagnostic.text}]"
        )
        if self.problem:
            text += f": {self.problem}"
        if self.boot.lss_note:
            text += f" (LSS: {self.boot.lss_note})"
        return text

    def summary(self) -> dict[str, Any]:
        """The node in one flat mapping, for the master's status display."""
        return {
            "node_id": self.node_id,
            "name": self.name,
            "state": int(self._state),
            "diagnostic": int(self.diagnostic),
            "nmt_state": None if self.nmt_state is None else self.nmt_state.name,
            "emcy_count": self.emcy_count,
            "error_control": self.error_control,
            "problem": self.problem,
            "steps": dict(self.step_results),
        }
