"""One node under the master: its CiA 302-2 boot-up sequence and its supervision.

The boot-up of a node runs as an asyncio task of its own (all nodes in parallel): reset,
boot-up, device type and identity check, optional restore of defaults, start-up SDO list,
heartbeat (or node guarding when the node refuses heartbeat); the master then starts it.
While it runs, its heartbeat or guarding replies, emergencies and TPDOs are watched; a node
that boots again by itself is configured again.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Awaitable, Callable
from functools import partial
from typing import TYPE_CHECKING, Any

from cobus.master.config import NodeConfig, PdoLayout, SdoEntry
from cobus.master.errors import BootStepError
from cobus.master.events import (
    BootStepDone,
    BootStepFailed,
    ConfigurationFailed,
    DeviceTypeMismatch,
    ErrorControlLost,
    ErrorControlRestored,
    GuardingToggleFault,
    IdentityMismatch,
    NodeBooted,
    NodeEmergency,
    NodeMissing,
    NodeStateChanged,
    SdoUnanswered,
    StateRestored,
    TpdoLengthError,
    TpdoMissing,
    TpdoRestored,
    UnexpectedState,
)
from cobus.master.states import Diagnostic, EmcyRecord, LedPattern, Leds, MasterStatus, NodeState
from cobus.proto import Event, Frame
from cobus.proto import guarding as _guarding
from cobus.proto.connection_set import error_control_cob_id
from cobus.proto.emcy import EmcyReceived
from cobus.proto.nmt import NmtState
from cobus.proto.pdo import RpdoResumed, RpdoTimeout, RpdoWatchdog
from cobus.proto.sdo import SdoAbortedError, SdoError, SdoProtocolError, SdoTimeoutError
from cobus.runtime.events import BusState, HandlerFailed
from cobus.runtime.remote import SdoChannel

if TYPE_CHECKING:
    from cobus.master._context import NodeContext
    from cobus.master.master import Master
    from cobus.runtime import MachineHost

__all__ = ["ManagedNode"]

log = logging.getLogger(__name__)

#: 1011h: "load" as a little-endian UNSIGNED32.
LOAD_SIGNATURE = 0x64616F6C
_PRESENCE_RETRY = 0.5  # s between 1000h reads of a mandatory node
_RPDO_TIMEOUT_EMCY = 0x8250
_IDENTITY = ("vendor_id", "product_code", "revision_number", "serial_number")
_BOOTING = (
    NodeState.RESETTING,
    NodeState.AWAITING_BOOTUP,
    NodeState.WAITING,
    NodeState.CONFIGURING,
    NodeState.CONFIGURED,
)
_VALID_STATES = {int(s) for s in NmtState if s is not NmtState.INITIALISING}


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
        self.emcy_count = 0
        self._emcy: deque[EmcyRecord] = deque(maxlen=8)
        self.error_register = 0
        #: Every failed write of the start-up lists, oldest first.
        self.config_errors: list[ConfigurationFailed] = []
        #: Why the node holds the network back or failed, in words (None: it does not).
        self.problem: str | None = None
        self.boot_count = 0
        self.boot_task: asyncio.Task[None] | None = None
        self._bootup: asyncio.Future[None] | None = None
        self._restored = False
        self._rebooted = False
        self._not_found = False
        self._sdo_error = False
        self._mismatch = False
        self._ec_lost = False
        self._toggle_fault = False
        self._heard_again = False
        self._rpdo_missing = False
        self._last_ec: float | None = None
        #: The NMT state the node's last heartbeat (or guarding reply) gave, and when.
        self._heard: tuple[float, NmtState] | None = None
        self._wakes: list[float] = []  # when NMT commands made a silent node answer SDO
        #: The limit of those was reached: no more until the node answers SDO again or the
        #: application restarts it (a hung node is not reset three times a minute for ever).
        self._wakes_spent = False
        #: The last NMT state this process commanded the node into since its boot-up (the
        #: application's or the master's own stop is not undone by a wake).
        self._last_commanded: NmtState | None = None
        self._left_said: str | None = None  # the "left as it is" SdoUnanswered last emitted
        self._first_check: asyncio.TimerHandle | None = None
        #: A pending NMT command bringing the node back to the state the master expects.
        self._heal: asyncio.TimerHandle | None = None
        self._unexpected = False  # an UnexpectedState not yet followed by StateRestored
        self._heals: list[float] = []  # when the last heals were sent (a limit per window)
        self._guard: _guarding.GuardingMaster | None = None
        self._guard_host: MachineHost | None = None
        self._guard_bad = False
        self._watchdogs: dict[int, tuple[RpdoWatchdog, MachineHost, PdoLayout]] = {}
        self._tpdos_seen: set[int] = set()
        self._tpdos_missing: set[int] = set()
        self._tpdos_short: set[int] = set()
        #: Frames counted per PDO: received TPDOs and sent RPDOs by number.
        self.tpdo_received: dict[int, int] = {}
        self.rpdo_sent: dict[int, int] = {}
        #: The application's boot steps (:meth:`Master.add_boot_step`), as (name, step).
        self.boot_steps: list[tuple[str, Callable[[ManagedNode], Awaitable[str | None]]]] = []
        #: What each boot step said at the last boot-up (name -> detail).
        self.step_results: dict[str, str] = {}

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
        return None if self._heard is None else self._heard[0]

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
        return tuple(self._emcy)

    @property
    def diagnostic(self) -> Diagnostic:
        """The Beckhoff diagnostic code of the node."""
        diag = self.context.diagnostics
        state = self._state
        if not self.config.enabled:
            return Diagnostic.DEACTIVATED
        if diag.bus_off:
            return Diagnostic.BUS_OFF
        if diag.bus_state is BusState.PASSIVE:
            return Diagnostic.SEVERE_BUS_FAULT
        if self._toggle_fault:
            return Diagnostic.GUARDING_TOGGLE
        if self._not_found or self._ec_lost or state in (NodeState.ABSENT, NodeState.ERROR_CONTROL):
            return Diagnostic.NOT_FOUND
        if self._sdo_error:
            return Diagnostic.SDO_SYNTAX_ERROR
        if self._mismatch:
            return Diagnostic.SDO_DATA_MISMATCH
        if state in _BOOTING or (state is NodeState.UNDEFINED and self.context.started):
            return Diagnostic.PRE_OPERATIONAL if self._rebooted else Diagnostic.STARTING
        if state is NodeState.OPERATIONAL:
            if self.nmt_state is NmtState.PRE_OPERATIONAL:
                return Diagnostic.REPORTS_PRE_OPERATIONAL
            if self.nmt_state is NmtState.STOPPED:
                return Diagnostic.REPORTS_STOPPED
            if self._tpdos_short:
                return Diagnostic.TPDO_TOO_SHORT
            if self._tpdos_missing:
                return Diagnostic.TPDO_MISSING
            if self._rpdo_missing:
                return Diagnostic.RPDO_MISSING
            if any(n not in self._tpdos_seen for n in self._watchdogs):
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
        elif self._ec_lost or self._toggle_fault:
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

    def _reset_supervision(self) -> None:
        """A new boot: supervision stopped, its flags and its count of commands back
        cleared."""
        self.stop_supervision()
        self._ec_lost = self._toggle_fault = self._heard_again = False
        self._tpdos_missing.clear()
        self._tpdos_short.clear()
        self._tpdos_seen.clear()
        self._heal_done()
        self._heals.clear()  # (a new boot: a new count of commands back)

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
        self.stop_supervision()

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
        self._reset_supervision()
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
        self._start_supervision()
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
                pause = self.HEAL_DELAY if woke else _PRESENCE_RETRY - (loop.time() - began)
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
        heard = self._heard
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
            self._last_commanded is NmtState.STOPPED
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

    # ================================================================== start / stop

    def mark_started(self, now: float) -> None:
        """The master sent the NMT start (to this node or to all)."""
        self._heal_done()
        self.expected_nmt = NmtState.OPERATIONAL
        self.nmt_state = NmtState.OPERATIONAL
        self._rebooted = False
        self._tpdos_seen.clear()
        self._tpdos_missing.clear()
        self._tpdos_short.clear()
        for watchdog, host, layout in self._watchdogs.values():
            assert layout.timeout is not None
            ms = max(1, min(0xFFFF, round(layout.timeout * 1000)))
            watchdog.set_event_timer(0, now)
            watchdog.set_event_timer(ms, now)
            host.apply(watchdog.on_timer(now))
        self.set_state(NodeState.OPERATIONAL)

    def mark_stopped(self) -> None:
        """The master sent an NMT stop to this node (or to all)."""
        self._heal_done()
        self.expected_nmt = NmtState.STOPPED
        self.nmt_state = NmtState.STOPPED
        self._disarm_watchdogs()
        self.context.image.zero_inputs(self.node_id)

    # ================================================================== supervision

    def install(self) -> None:
        """Subscribe what the node's supervision needs (called once by the master)."""
        context = self.context
        net = context.network
        context.keep(net.subscribe(error_control_cob_id(self.node_id), self._on_ec_frame))
        for layout in self.config.tpdos:
            context.keep(
                net.subscribe(
                    layout.cob_id, partial(self._on_tpdo, layout), extended=layout.extended
                )
            )
            if layout.timeout is not None:
                watchdog = RpdoWatchdog(layout.cob_id, 0, extended=layout.extended)
                host = net.attach(watchdog, (), partial(self._on_watchdog, layout.number))
                context.keep_host(host)
                self._watchdogs[layout.number] = (watchdog, host, layout)

    def _start_supervision(self) -> None:
        now = self.context.network.time()
        kind = self.error_control
        cfg = self.config
        if kind == "heartbeat":
            self.context.watch_heartbeat(self.node_id, cfg.heartbeat_consumer_time, now)
            self._first_check = self.context.network.loop.call_later(
                cfg.heartbeat_consumer_time, self._check_first_heartbeat, now
            )
        elif kind == "guarding":
            guard_ms, factor = (
                (cfg.guard_time, cfg.life_time_factor or 3)
                if cfg.guard_time
                else cfg.fallback_guarding
            )
            self._guard = _guarding.GuardingMaster(self.node_id, guard_ms, factor)
            self._guard_host = self.context.network.attach(self._guard, (), self._on_guard_event)
            guard = self._guard
            self._guard_host.run(lambda t: guard.start(t))

    def stop_supervision(self) -> None:
        """Stop watching the node (error control, first heartbeat, healing, TPDO watchdogs)."""
        if self._first_check is not None:
            self._first_check.cancel()
            self._first_check = None
        if self._heal is not None:
            self._heal.cancel()
            self._heal = None
        now = self.context.network.time() if self.context.network.connected else 0.0
        self.context.watch_heartbeat(self.node_id, 0.0, now)
        if self._guard_host is not None:
            self._guard_host.close()
        self._guard = None
        self._guard_host = None
        self._disarm_watchdogs()

    def _disarm_watchdogs(self) -> None:
        if not self.context.network.connected:
            return
        now = self.context.network.time()
        for watchdog, host, _layout in self._watchdogs.values():
            watchdog.set_event_timer(0, now)
            host.apply(watchdog.on_timer(now))

    def _check_first_heartbeat(self, since: float) -> None:
        self._first_check = None
        if self._last_ec is None or self._last_ec < since:
            self.error_control_lost("heartbeat")

    def _on_ec_frame(self, frame: Frame, now: float) -> None:
        if frame.rtr:
            return
        self._last_ec = now
        data = frame.data
        if len(data) == 1:
            code = data[0] & 0x7F
            if code in _VALID_STATES:
                self._heard = (now, NmtState(code))
            elif code == 0:  # a boot-up: pre-operational from now on
                self._heard = (now, NmtState.PRE_OPERATIONAL)
        if self.error_control != "guarding" or data == b"\x00":
            # A guarding reply is no heartbeat (its toggle bit would read as a malformed
            # one); the monitor only needs a guarded node's boot-up, to see it re-boot.
            self.context.heartbeat_frame(frame, now)
        if self.error_control == "guarding" and self._guard_host is not None:
            self._guard_bad = False
            self._guard_host.feed(frame, now)
            if len(data) == 1 and data[0] & 0x7F in _VALID_STATES and not self._guard_bad:
                self._alive("guarding", NmtState(data[0] & 0x7F))
        elif (
            self.error_control == "heartbeat"
            and len(data) == 1
            and data[0] in _VALID_STATES
            and (self._ec_lost or self._state is NodeState.ERROR_CONTROL)
        ):
            self._alive("heartbeat", NmtState(data[0]))

    def _on_guard_event(self, event: Event) -> None:
        if isinstance(event, _guarding.GuardingToggleError):
            self._guard_bad = True
            self._toggle_fault = True
            self.problem = f"guarding toggle {event.received}, expected {event.expected}"
            self.context.emit(GuardingToggleFault(self.node_id, event.expected, event.received))
            self._fault()
        elif isinstance(event, _guarding.MalformedGuardingReply):
            self._guard_bad = True
        elif isinstance(event, _guarding.GuardingNodeLost):
            self.error_control_lost("guarding")
        elif (
            isinstance(event, _guarding.GuardingStateChanged)
            and event.new is not NmtState.INITIALISING
        ):
            self._reported(event.new)

    def error_control_lost(self, kind: str) -> None:
        """The node's error control (``kind``: heartbeat or guarding) was lost: its error
        reaction."""
        if self._ec_lost:
            return
        self._ec_lost = True
        self.problem = f"no {kind} within its time"
        self.context.emit(ErrorControlLost(self.node_id, kind))
        self._fault()

    def _fault(self) -> None:
        """An error control fault: state 99, inputs 0, the configured reaction."""
        was_running = self._state is NodeState.OPERATIONAL
        self.set_state(NodeState.ERROR_CONTROL)
        self._disarm_watchdogs()
        if self.config.zero_inputs:
            self.context.image.zero_inputs(self.node_id)
        reaction = self.config.error_reaction
        if reaction == "stop_node":
            self.context.network.nmt.stop(self.node_id)
            self.expected_nmt = NmtState.STOPPED
        elif reaction == "stop_all" and (was_running or self.context.running):
            self.context.stop_all(self, self.problem or "error control fault")

    def _alive(self, kind: str, state: NmtState) -> None:
        """A valid heartbeat or guarding reply: ends a loss or a toggle fault. With a manual
        restart the fault stays shown until the application restarts the node."""
        if not (self._ec_lost or self._toggle_fault):
            return
        manual = self.config.restart == "manual"
        if self._state is NodeState.ERROR_CONTROL and manual:
            if not self._heard_again:
                self._heard_again = True
                self.problem = "heard again; waiting for a manual restart"
                self.context.emit(ErrorControlRestored(self.node_id, kind, state))
            return
        self._ec_lost = False
        self._toggle_fault = False
        self.context.emit(ErrorControlRestored(self.node_id, kind, state))
        if self._state is not NodeState.ERROR_CONTROL:
            return
        if (
            state is NmtState.OPERATIONAL
            and self.expected_nmt is NmtState.OPERATIONAL
            and not self._rebooted
        ):
            # The cheap check: its own report says it never re-booted (a re-booted node
            # comes back pre-operational, with a boot-up) - its configuration is intact,
            # so it goes on as it is. Only a real re-boot costs a full reconfiguration:
            # on a lossy bus a node then degrades for a moment instead of collapsing.
            self.problem = None
            self.mark_started(self.context.network.time())
            if self.context.running:  # outputs set while it was away reach it now
                self.context.send_all_rpdos([self])
            return
        self.spawn_boot("reset")

    def _reported(self, state: NmtState) -> None:
        """The node reports ``state`` by heartbeat or guarding."""
        old = self.nmt_state
        self.nmt_state = state
        expected = self.expected_nmt
        if (
            expected is not None
            and state is not expected
            and state is not old
            and self._state is NodeState.OPERATIONAL
        ):
            self.context.emit(UnexpectedState(self.node_id, expected, state))
            self._unexpected = True
            self._disarm_watchdogs()
            if self.config.zero_inputs:
                self.context.image.zero_inputs(self.node_id)
            self._bring_back(expected, state)
        elif (
            state is NmtState.OPERATIONAL
            and expected is NmtState.OPERATIONAL
            and old is not state
            and self._state is NodeState.OPERATIONAL
        ):
            # back in operational: supervise the TPDOs again
            self.mark_started(self.context.network.time())
        if expected is not None and state is expected and old is not None and old is not state:
            self._heal_done()
            if self._unexpected:
                self._unexpected = False
                self.context.emit(StateRestored(self.node_id, state))

    #: At most this many NMT commands bring a node back within HEAL_WINDOW seconds; a node
    #: that keeps leaving the expected state after that is left as it is (and says so).
    HEAL_LIMIT = 3
    HEAL_WINDOW = 10.0
    #: Seconds between noticing the unexpected state and the command (someone else's
    #: command sequence, or the node's own reset, may still be under way).
    HEAL_DELAY = 0.2

    def _bring_back(self, expected: NmtState, state: NmtState) -> None:
        """A node left the state the master expects (someone else's NMT command, a local
        fault): with ``restart: auto`` it gets the command back, a few times at most; with
        ``restart: manual`` it waits for the application (``master.restart``)."""
        if self.config.restart == "manual":
            self._say(f"reports {state.name}; waiting for a manual restart")
            return
        network = self.context.network
        now = network.time()
        self._heals = [t for t in self._heals if now - t < self.HEAL_WINDOW]
        if len(self._heals) >= self.HEAL_LIMIT:
            self._say(
                f"reports {state.name} again after {self.HEAL_LIMIT} commands back to "
                f"{expected.name} within {self.HEAL_WINDOW:g} s: left as it is"
            )
            return
        if self._heal is not None:
            self._heal.cancel()
        self._say(f"reports {state.name}; bringing it back to {expected.name}")
        self._heal = network.loop.call_later(self.HEAL_DELAY, self._send_back)

    def _say(self, text: str) -> None:
        """Show ``text`` as the node's problem unless another problem is shown already."""
        if self.problem is None or self.problem.startswith("reports "):
            self.problem = text

    def _heal_done(self) -> None:
        """The node is where the master wants it (or the master took over): no command
        back is pending and the 'reports ...' text goes."""
        if self._heal is not None:
            self._heal.cancel()
            self._heal = None
        if self.problem is not None and self.problem.startswith("reports "):
            self.problem = None

    def _send_back(self) -> None:
        self._heal = None
        expected = self.expected_nmt
        if (
            expected is None
            or self._state is not NodeState.OPERATIONAL
            or not self.context.network.connected
        ):
            return
        if self.nmt_state is expected:
            self._heal_done()
            return
        command = {
            NmtState.OPERATIONAL: "start",
            NmtState.PRE_OPERATIONAL: "enter_preoperational",
            NmtState.STOPPED: "stop",
        }.get(expected)
        if command is None:
            return
        network = self.context.network
        self._heals.append(network.time())
        try:
            getattr(network.nmt, command)(self.node_id)
        except Exception as exc:  # (a full transmit backlog, a closed network)
            network.report_failure(f"master: node {self.node_id} NMT {command}", exc)
        # Did it take? If the node still reports the old state, count it and try again.
        check = max(self.HEAL_DELAY, 2 * (self.config.heartbeat_consumer_time or 0.5))
        self._heal = network.loop.call_later(check, self._check_back)

    def _check_back(self) -> None:
        self._heal = None
        expected, state = self.expected_nmt, self.nmt_state
        if expected is None or state is None or self._state is not NodeState.OPERATIONAL:
            return
        if state is expected:
            self._heal_done()
        else:
            self._bring_back(expected, state)

    def commanded(self, command: int) -> None:
        """This process sent NMT ``command`` to the node (the application or the master): the
        state it asks for is the one expected from now on."""
        wanted = {
            0x01: NmtState.OPERATIONAL,
            0x02: NmtState.STOPPED,
            0x80: NmtState.PRE_OPERATIONAL,
        }.get(command)
        if wanted is not None:
            self._last_commanded = wanted
        if wanted is None or self._state is not NodeState.OPERATIONAL:
            return  # (a reset: the boot-up that follows is handled; a node not running yet)
        self._heal_done()
        if wanted is self.expected_nmt:
            return
        self.expected_nmt = wanted
        if wanted is not NmtState.OPERATIONAL:
            self._disarm_watchdogs()
            if self.config.zero_inputs:
                self.context.image.zero_inputs(self.node_id)

    def on_bootup(self) -> None:
        """The node sent its boot-up message."""
        self.nmt_state = NmtState.PRE_OPERATIONAL
        self._last_commanded = None
        if self._take_bootup():
            self.context.emit(NodeBooted(self.node_id, True))
            return
        self.context.emit(NodeBooted(self.node_id, False))
        if not self.context.started or not self.config.enabled:
            return
        running = self.boot_task is not None and not self.boot_task.done()
        if running and self._state is NodeState.UNDEFINED:
            return  # a boot-up from before the master's reset, which is on its way
        if self._state is NodeState.ERROR_CONTROL and self.config.restart == "manual":
            self.problem = "booted again; waiting for a manual restart"
            return
        if self._state is NodeState.OPERATIONAL and self.config.zero_inputs:
            self.context.image.zero_inputs(self.node_id)
        self._rebooted = True
        self.spawn_boot("booted")

    def _take_bootup(self) -> bool:
        """The boot waits for this boot-up: it has it now (False: nobody waited)."""
        future = self._bootup
        if future is None or future.done():
            return False
        future.set_result(None)
        return True

    def on_heartbeat_state(self, state: NmtState) -> None:
        """The master's heartbeat consumer heard the node in ``state``."""
        if self.error_control == "heartbeat" or self.error_control is None:
            self._reported(state)

    def on_emcy(self, event: EmcyReceived, now: float) -> None:
        """An emergency of the node (from the master's EMCY consumer) at ``now``."""
        self.emcy_count += 1
        self.error_register = int(event.register)
        record = EmcyRecord(
            self.node_id, now, event.code, event.register, event.manufacturer_data, event.text
        )
        self._emcy.appendleft(record)
        if event.code == _RPDO_TIMEOUT_EMCY:
            self._rpdo_missing = True
        elif event.is_reset:
            self._rpdo_missing = False
        self.context.emit(
            NodeEmergency(
                self.node_id, event.code, int(event.register), event.manufacturer_data, event.text
            )
        )

    # ================================================================== process data

    def _on_tpdo(self, layout: PdoLayout, frame: Frame, now: float) -> None:
        if frame.rtr or not self.operational:
            return  # process data is blocked unless the node is operational
        number = layout.number
        self.tpdo_received[number] = self.tpdo_received.get(number, 0) + 1
        counters = self.context.diagnostics.pdo_counters
        key = (self.node_id, "tpdo", number)
        counters[key] = counters.get(key, 0) + 1
        watch = self._watchdogs.get(number)
        if watch is not None:
            watch[1].feed(frame, now)
        data = frame.data
        if len(data) < layout.length:
            if number not in self._tpdos_short:
                self._tpdos_short.add(number)
                self.context.emit(TpdoLengthError(self.node_id, number, layout.length, len(data)))
            return
        self._tpdos_short.discard(number)
        self._tpdos_seen.add(number)
        self.context.image.update_tpdo(self.node_id, number, layout.codec.unpack(data))
        self.context.tpdo_taken(self.node_id, number, now)

    def _on_watchdog(self, number: int, event: Event) -> None:
        watch = self._watchdogs.get(number)
        if watch is None:
            return
        layout = watch[2]
        if isinstance(event, RpdoTimeout):
            self._tpdos_missing.add(number)
            if self.config.zero_inputs:
                self.context.image.zero_inputs(self.node_id, number)
            self.context.emit(TpdoMissing(self.node_id, number, layout.cob_id))
        elif isinstance(event, RpdoResumed):
            self._tpdos_missing.discard(number)
            self.context.emit(TpdoRestored(self.node_id, number, layout.cob_id))

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
