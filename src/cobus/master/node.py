"""One node under the master: its CiA 302-2 boot-up sequence and its supervision.

The boot-up of a node runs as an asyncio task of its own (all nodes in parallel): reset,
boot-up, device type and identity check, optional restore of defaults, start-up SDO list,
heartbeat (or node guarding when the node refuses heartbeat); the master then starts it.
Once configured, :attr:`ManagedNode.supervision` (``master/supervision.py``) watches its
heartbeat or guarding replies, emergencies, TPDOs and NMT state; a node that boots again by
itself is configured again.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

from cobus.master.config import NodeConfig, PdoLayout, SdoEntry
from cobus.master.errors import BootStepError
from cobus.master.events import (
    BootStepDone,
    BootStepFailed,
    ConfigurationFailed,
    DeviceTypeMismatch,
    IdentityMismatch,
    NodeMissing,
    NodeStateChanged,
    SdoUnanswered,
)
from cobus.master.states import Diagnostic, EmcyRecord, LedPattern, Leds, MasterStatus, NodeState
from cobus.master.supervision import NodeSupervision
from cobus.proto import Frame
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbortedError, SdoError, SdoProtocolError, SdoTimeoutError
from cobus.runtime.events import BusState, HandlerFailed
from cobus.runtime.remote import SdoChannel

if TYPE_CHECKING:
    from cobus.master._context import NodeContext
    from cobus.master.master import Master

__all__ = ["ManagedNode"]

log = logging.getLogger(__name__)

#: 1011h: "load" as a little-endian UNSIGNED32.
LOAD_SIGNATURE = 0x64616F6C
_PRESENCE_RETRY = 0.5  # s between 1000h reads of a mandatory node
_IDENTITY = ("vendor_id", "product_code", "revision_number", "serial_number")
_BOOTING = (
    NodeState.RESETTING,
    NodeState.AWAITING_BOOTUP,
    NodeState.WAITING,
    NodeState.CONFIGURING,
    NodeState.CONFIGURED,
)


class _NodeSilent(Exception):
    """The node stopped answering SDO during its configuration."""


class _Held(Exception):
    """The boot-up of the node stops here (wrong device, aborted configuration)."""


class ManagedNode:
    """A node of the network as the master manages it: ``master.nodes[node_id]``.

    ``state`` is the Lenze node state code, ``diagnostic`` the Beckhoff diagnostic code,
    ``nmt_state`` the NMT state last reported (or commanded), ``emcy_history`` the last 8
    emergencies (newest first), ``led`` the CiA 303-3 indicators, ``sdo`` an SDO channel to
    the node (``await node.sdo.read(0x1008)``), on the network's one SDO transport to it:
    a remote node or gateway asking the same node waits for its turn.
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
        self._bootup: asyncio.Future[None] | None = None
        self._restored = False
        self._not_found = False
        self._sdo_error = False
        self._mismatch = False
        self._wakes: list[float] = []  # when NMT commands made a silent node answer SDO
        #: The limit of those was reached: no more until the node answers SDO again or the
        #: application restarts it (a hung node is not reset three times a minute for ever).
        self._wakes_spent = False
        self._left_said: str | None = None  # the "left as it is" SdoUnanswered last emitted
        #: Frames counted per PDO: received TPDOs and sent RPDOs by number.
        self.tpdo_received: dict[int, int] = {}
        self.rpdo_sent: dict[int, int] = {}
        #: The application's boot steps (:meth:`Master.add_boot_step`), as (name, step).
        self.boot_steps: list[tuple[str, Callable[[ManagedNode], Awaitable[str | None]]]] = []
        #: What each boot step said at the last boot-up (name -> detail).
        self.step_results: dict[str, str] = {}
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
        """How many emergencies the node sent since the master was made."""
        return self.supervision.emcy_count

    @property
    def error_register(self) -> int:
        """1001h as the node's last emergency gave it."""
        return self.supervision.error_register

    @property
    def diagnostic(self) -> Diagnostic:
        """The Beckhoff diagnostic code of the node."""
        diag = self.context.diagnostics
        state = self._state
        watch = self.supervision
        if not self.config.enabled:
            return Diagnostic.DEACTIVATED
        if diag.bus_off:
            return Diagnostic.BUS_OFF
        if diag.bus_state is BusState.PASSIVE:
            return Diagnostic.SEVERE_BUS_FAULT
        if watch.toggle_fault:
            return Diagnostic.GUARDING_TOGGLE
        if self._not_found or watch.lost or state in (NodeState.ABSENT, NodeState.ERROR_CONTROL):
            return Diagnostic.NOT_FOUND
        if self._sdo_error:
            return Diagnostic.SDO_SYNTAX_ERROR
        if self._mismatch:
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
        self._allow_wakes()  # (the application asks: the wakes may be tried again)
        task = self.spawn_boot("reset")
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

    def _allow_wakes(self) -> None:
        """The wakes of an absent node may be tried again (a manual restart)."""
        self._wakes_spent = False
        self._wakes.clear()

    # ================================================================== the boot-up task

    def spawn_boot(self, mode: str) -> asyncio.Task[None]:
        """Start the boot-up sequence (``mode``: reset, await, booted, none), replacing a
        running one."""
        old = self.boot_task
        if old is not None and not old.done():
            old.cancel()
        else:
            old = None
        loop = self.context.network.loop
        task = loop.create_task(self._run(old, mode), name=f"cobus-master-node-{self.node_id}")
        task.add_done_callback(self._finished)
        self.boot_task = task
        return task

    def _finished(self, task: asyncio.Task[None]) -> None:
        if task is self.boot_task and not task.cancelled():
            self.context.node_finished(self)

    def expect_bootup(self) -> None:
        """The master is about to reset every node with one broadcast."""
        self._bootup = self.context.network.loop.create_future()
        self.set_state(NodeState.RESETTING)

    def cancel_boot(self) -> None:
        """Cancel the node's boot task (the master stops)."""
        if self.boot_task is not None and not self.boot_task.done():
            self.boot_task.cancel()
        self.supervision.stop()

    async def _run(self, previous: asyncio.Task[None] | None, mode: str) -> None:
        if previous is not None:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await previous
        try:
            await self._sequence(mode)
        except asyncio.CancelledError:
            raise
        except _Held:
            pass
        except Exception as exc:  # a failure here must not end silently
            log.exception("master: boot-up of node %d failed", self.node_id)
            self.problem = f"boot-up failed: {exc!r}"
            self.context.network.emit(HandlerFailed(f"master: node {self.node_id}", repr(exc)))

    async def _sequence(self, mode: str) -> None:
        cfg = self.config
        self.supervision.reset()
        self._not_found = self._sdo_error = self._mismatch = False
        self.problem = None
        self.expected_nmt = None
        self.step_results.clear()  # (what the steps say of this boot only)
        self.boot_count += 1
        if cfg.do_not_initialise:
            mode = "none"
        while True:
            try:
                await self._boot_once(mode)
                return
            except _NodeSilent:
                self._not_found = True
                self.problem = "stopped answering SDO while being configured"
                if not cfg.mandatory and not self._wake(True):
                    self.set_state(NodeState.ABSENT)
                    self.context.emit(NodeMissing(self.node_id, False, self.problem))
                    return
                mode = "poll"

    async def _boot_once(self, mode: str) -> None:
        cfg = self.config
        if mode == "reset":
            await self._reset_and_wait()
        elif mode == "await":
            await self._wait_bootup()
        if mode != "none":
            self.set_state(NodeState.WAITING)
            if mode != "poll":
                await asyncio.sleep(self.context.config.master.bootup_delay)
        else:
            self.set_state(NodeState.WAITING)
        if cfg.sdo_server:
            if not await self._presence():
                return
            await self._check_identity()
        else:
            self._not_found = False  # no SDO to ask it with: taken as present
        if cfg.restore_defaults and not self._restored and mode != "none":
            self._restored = True
            await self._write(
                SdoEntry(0x1011, 1, LOAD_SIGNATURE.to_bytes(4, "little"), LOAD_SIGNATURE, "load")
            )
            await self._reset_and_wait()
            self.set_state(NodeState.WAITING)
            await asyncio.sleep(self.context.config.master.bootup_delay)
        self.set_state(NodeState.CONFIGURING)
        self.context.note_configuring()
        kind = cfg.error_control
        if mode != "none":
            for entry in cfg.startup:
                await self._write(entry)
            wanted = kind
            kind = await self._set_up_error_control(kind)
            if wanted is not None and kind is None:
                # it runs, but nothing would tell if it stopped: not OK, say why
                self._sdo_error = True
                self.problem = (
                    "no error control: the node refused heartbeat (1017h) and node guarding "
                    "(100Ch/100Dh)"
                )
        self.error_control = kind
        await self._run_boot_steps()
        self.supervision.start()
        self.set_state(NodeState.CONFIGURED)
        self.context.node_configured(self)

    async def _run_boot_steps(self) -> None:
        for name, step in self.boot_steps:
            try:
                detail = await step(self)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                if not isinstance(exc, BootStepError):
                    log.exception("master: boot step %r of node %d failed", name, self.node_id)
                reason = str(exc) or repr(exc)
                self.step_results[name] = f"failed: {reason}"
                self._sdo_error = True
                self.problem = f"boot step {name!r} failed: {reason}"
                self.context.emit(BootStepFailed(self.node_id, name, reason))
                raise _Held() from None
            text = "done" if detail is None else str(detail)
            self.step_results[name] = text
            self.context.emit(BootStepDone(self.node_id, name, text))

    async def _reset_and_wait(self) -> None:
        self._bootup = self.context.network.loop.create_future()
        self.set_state(NodeState.RESETTING)
        self.context.network.nmt.reset_node(self.node_id)
        await self._wait_bootup()

    async def _wait_bootup(self) -> None:
        self.set_state(NodeState.AWAITING_BOOTUP)
        future = self._bootup
        if future is None:
            return
        try:
            await asyncio.wait_for(asyncio.shield(future), self.config.boot_timeout)
        except TimeoutError:
            # no boot-up (some devices send none): the 1000h read tells if the node is there
            pass
        finally:
            self._bootup = None

    async def _presence(self) -> bool:
        """Read 1000h (a mandatory node every 0.5 s until it answers, an optional one once).

        A node silent on SDO whose heartbeat says it is there is made to answer
        (:meth:`_wake`); a protocol error (a reply that makes no sense, as a late reply of
        an earlier transfer may) is asked again before it counts as the node's answer."""
        cfg = self.config
        loop = self.context.network.loop
        reported = False
        silent = garbled = 0
        while True:
            began = loop.time()
            try:
                data = await self.sdo.upload(0x1000, 0)
            except SdoTimeoutError:
                silent += 1
                self._not_found = True
                self.problem = "no boot-up and no answer to the 1000h read"
                woke = self._wake(silent > cfg.sdo_retries)
                if not cfg.mandatory and not woke:
                    self.set_state(NodeState.ABSENT)
                    self.context.emit(NodeMissing(self.node_id, False, self.problem))
                    return False
                if not reported and cfg.mandatory:
                    reported = True
                    self.context.note_configuring()
                    self.context.emit(NodeMissing(self.node_id, True, self.problem))
                pause = (
                    self.supervision.HEAL_DELAY if woke else _PRESENCE_RETRY - (loop.time() - began)
                )
                await asyncio.sleep(max(0.0, pause))
                continue
            except SdoError as exc:
                if isinstance(exc, SdoProtocolError) and garbled < cfg.sdo_retries:
                    garbled += 1
                    continue
                # the node is there but refuses 1000h (a mandatory object: it is broken)
                self._not_found = False
                self.device_type = None
                if cfg.device_type:
                    self._mismatched(f"refuses the 1000h read: {exc}")
                    self.context.emit(DeviceTypeMismatch(self.node_id, cfg.device_type, -1))
                    raise _Held() from None
                return True
            self._not_found = False
            self._left_said = None
            self._wakes_spent = False  # (it answers: a later silence may be woken again)
            self.problem = None
            actual = int.from_bytes(data[:4].ljust(4, b"\0"), "little")
            self.device_type = actual
            expected = cfg.device_type
            if expected:
                if cfg.device_type_low16:
                    ok = actual & 0xFFFF == expected & 0xFFFF
                else:
                    ok = actual == expected
                if not ok:
                    self._mismatched(
                        f"device type 0x{actual:08X}, expected 0x{expected:08X}"
                        + (" (low 16 bits compared)" if cfg.device_type_low16 else "")
                    )
                    self.context.emit(DeviceTypeMismatch(self.node_id, expected, actual))
                    raise _Held()
            return True

    #: At most this many NMT commands in WAKE_WINDOW seconds make a node that does not answer
    #: SDO answer again; then it is left as it is (and the event says so) until it answers
    #: SDO or the application restarts it.
    WAKE_LIMIT = 3
    WAKE_WINDOW = 60.0

    def _wake(self, reset_too: bool) -> bool:
        """The node did not answer SDO while the master needs it. If its heartbeat (heard
        lately) says it is STOPPED, it gets enter pre-operational (a stopped node answers no
        SDO, CiA 301); if it says PRE-OPERATIONAL or OPERATIONAL and ``reset_too``, its SDO
        server is silent: it gets reset node. True when a command went out."""
        heard = self.supervision.heard
        cfg = self.config
        network = self.context.network
        now = network.time()
        recent = max(2.0, 3 * cfg.heartbeat_time / 1000.0)
        if heard is None or now - heard[0] > recent:
            return False  # nothing says it is there: it is missing
        if cfg.do_not_initialise:
            return False  # (the master sends such a node no reset, not even the broadcast)
        state = heard[1]
        if state is NmtState.STOPPED and (
            self.supervision.last_commanded is NmtState.STOPPED
            or self.expected_nmt is NmtState.STOPPED
            or self.context.status is MasterStatus.STOP
        ):
            return False  # stopped by this process (a reaction, the application): it stays
        if state is NmtState.STOPPED:
            command = "enter_preoperational"
            action = "enter pre-operational sent"
        elif reset_too and state in (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL):
            command = "reset_node"
            action = "reset node sent"
        else:
            return False
        said = f"reports {state.name} but does not answer SDO"
        self._wakes = [t for t in self._wakes if now - t < self.WAKE_WINDOW]
        if len(self._wakes) >= self.WAKE_LIMIT:
            self._wakes_spent = True
        if cfg.restart == "manual" or self._wakes_spent:
            if cfg.restart == "manual":
                reason = f"{said}; waiting for a manual restart (restart: manual)"
            else:
                reason = (
                    f"{said} after {self.WAKE_LIMIT} NMT commands within "
                    f"{self.WAKE_WINDOW:g} s: left as it is until it answers SDO or the "
                    "application restarts it"
                )
            self.problem = reason
            if self._left_said != reason:  # said once, not at every read
                self._left_said = reason
                self.context.emit(SdoUnanswered(self.node_id, state, "", reason))
            return False
        self._wakes.append(now)
        self._left_said = None
        reason = f"{said}: {action}"
        self.problem = reason
        self.context.emit(SdoUnanswered(self.node_id, state, command, reason))
        try:
            getattr(network.nmt, command)(self.node_id)
        except Exception as exc:  # (a full transmit backlog, a closed network)
            network.report_failure(f"master: node {self.node_id} NMT {command}", exc)
            return False
        return True

    def _mismatched(self, reason: str) -> None:
        self._mismatch = True
        self.problem = reason
        self.set_state(NodeState.WRONG_DEVICE)

    async def _check_identity(self) -> None:
        for sub, (field, expected) in enumerate(
            zip(_IDENTITY, self.config.identity, strict=True), 1
        ):
            if not expected:
                continue
            actual: int | None = None
            for _attempt in range(self.config.sdo_retries + 1):
                try:
                    data = await self.sdo.upload(0x1018, sub)
                except SdoTimeoutError:
                    raise _NodeSilent() from None
                except SdoProtocolError:
                    continue  # a reply that made no sense: asked again before it counts
                except SdoError:
                    break  # refused
                actual = int.from_bytes(data[:4].ljust(4, b"\0"), "little")
                break
            self.identity[field] = actual
            if actual != expected:
                shown = "refused" if actual is None else f"0x{actual:08X}"
                self._mismatched(f"1018h sub {sub} ({field}) is {shown}, expected 0x{expected:08X}")
                self.context.emit(IdentityMismatch(self.node_id, field, sub, expected, actual))
                raise _Held()

    async def _write(self, entry: SdoEntry) -> bool:
        """Write one entry: timeouts are retried; an abort is reported (and ends the boot-up
        with ``stop_on_abort``)."""
        cfg = self.config
        for _attempt in range(cfg.sdo_retries + 1):
            try:
                await self.sdo.download(entry.index, entry.subindex, entry.data)
                return True
            except SdoTimeoutError:
                continue
            except SdoError as exc:
                code = int(exc.code) if isinstance(exc, SdoAbortedError) else None
                failure = ConfigurationFailed(
                    self.node_id, entry.index, entry.subindex, code, str(exc)
                )
                self.config_errors.append(failure)
                self.context.emit(failure)
                if cfg.stop_on_abort:
                    self._sdo_error = True
                    self.problem = f"start-up write {entry} failed: {exc}"
                    raise _Held() from None
                return False
        raise _NodeSilent()

    async def _set_up_error_control(self, kind: str | None) -> str | None:
        cfg = self.config
        if kind == "heartbeat":
            entry = cfg.error_control_entries("heartbeat")[0]
            try:
                await self.sdo.download(entry.index, entry.subindex, entry.data)
                return "heartbeat"
            except SdoTimeoutError:
                raise _NodeSilent() from None
            except SdoError:
                kind = "guarding"  # the node refuses 1017h: node guarding instead
        if kind == "guarding":
            for entry in cfg.error_control_entries("guarding"):
                if not await self._write(entry):
                    return None
            return "guarding"
        return None

    def take_bootup(self) -> bool:
        """The boot waits for this boot-up: it has it now (False: nobody waited)."""
        future = self._bootup
        if future is None or future.done():
            return False
        future.set_result(None)
        return True

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
