"""The CiA 302-2 boot of one node under the master ("boot slave"), in the standard's order.

The boot runs as an asyncio task of its own (all nodes in parallel); its steps, as CiA 302-2
orders them (the letters are its boot error statuses, named where a step can end in one):

0. For a node with ``lss: true``: the device with the node's identity takes its node-ID by
   LSS (CiA 305), one node after another, before any reset (:meth:`NodeBoot.assign_by_lss`).
1. Reset the node (NMT reset node, or the master's one broadcast) and wait for its boot-up;
   a node with "do not initialise" is taken as it is (:meth:`NodeBoot._boot_once`).
2. Check the device type, 1000h against the configured one (B: no answer, C: it differs;
   a mandatory node is asked every 0.5 s until it answers) (:meth:`NodeBoot._presence`).
3. Check the identity, 1018h sub 1..4 against the configured one (D: vendor-ID, M: product
   code, N: revision, O: serial number) (:meth:`NodeBoot._check_identity`).
4. Restore defaults when asked (1011h "load", once) and boot the node again.
5. Download the configuration: the start-up SDO list (J: the download failed, with
   ``stop_on_abort``) (:meth:`NodeBoot._write`).
6. Start error control: heartbeat, or node guarding when the node refuses 1017h (E and F
   are then the supervision's) (:meth:`NodeBoot._set_up_error_control`).
7. The application's boot steps (:meth:`Master.add_boot_step`), then one call to the
   master: ``context.node_configured`` (the master starts the node when the network runs).

:class:`NodeBoot` is ``node.boot``; it writes the node's public state (``problem``,
``device_type``, ``identity``, ``config_errors`` ...), hands the node to supervision when it
ends, and sees the master only through the node's :class:`~cobus.master._context.NodeContext`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import TYPE_CHECKING

from cobus.master.config import SdoEntry
from cobus.master.errors import BootStepError
from cobus.master.events import (
    BootStepDone,
    BootStepFailed,
    ConfigurationFailed,
    DeviceTypeMismatch,
    IdentityMismatch,
    LssAssigned,
    LssNotAssigned,
    NodeMissing,
    SdoUnanswered,
)
from cobus.master.states import MasterStatus, NodeState
from cobus.proto.lss import LssIdentity, LssState
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbortedError, SdoError, SdoProtocolError, SdoTimeoutError
from cobus.runtime.errors import LssRefusedError, LssTimeoutError, NetworkClosedError
from cobus.runtime.events import HandlerFailed

if TYPE_CHECKING:
    from cobus.master.node import ManagedNode
    from cobus.runtime import AsyncNetwork

__all__ = ["LOAD_SIGNATURE", "LssStep", "NodeBoot"]

log = logging.getLogger(__name__)

#: 1011h: "load" as a little-endian UNSIGNED32.
LOAD_SIGNATURE = 0x64616F6C
_PRESENCE_RETRY = 0.5  # s between 1000h reads of a mandatory node
_IDENTITY = ("vendor_id", "product_code", "revision_number", "serial_number")


class _NodeSilent(Exception):
    """The node stopped answering SDO during its configuration."""


class _Held(Exception):
    """The boot-up of the node stops here (wrong device, aborted configuration)."""


class LssStep:
    """Step 0 of the network's boot: the nodes with ``lss: true``, one after another (LSS
    addresses one device at a time), before any reset."""

    #: Seconds between the last node named and the resets: the boot-ups of the devices
    #: that LSS just named come (and are let pass) before the master's own resets.
    SETTLE = 0.2

    def __init__(self, network: AsyncNetwork, nodes: list[ManagedNode]) -> None:
        self.network = network
        self.nodes = nodes
        self.done = 0  # nodes the step is through with
        self.problem = ""  # why the step could not end (the network closed)

    async def run(self) -> bool:
        """Name every node's device; False when the network closed on the way."""
        net = self.network
        named = 0
        if net.connected:  # (a device left in configuration state by an earlier tool)
            net.lss.switch_global(LssState.WAITING)
        for node in self.nodes:
            try:
                named += await node.boot.assign_by_lss()
            except Exception as exc:  # a failure here must not stop the boot
                net.report_failure(f"master: LSS for node {node.node_id}", exc)
            self.done += 1
        if not net.connected:
            self.problem = (
                "the network closed during the master's LSS step: stop() and start() the "
                "master again"
            )
            return False
        if any(n.boot.lss_reset_all for n in self.nodes):
            # a device that did not say its node-ID takes the new one at a reset
            # communication (CiA 305): one to all, before the master's own resets
            net.nmt.reset_communication(0)
        if named:
            await asyncio.sleep(self.SETTLE)
        return True

    def progress(self) -> str:
        """Where the step is, in words (for a boot that times out during it)."""
        return (
            f"the LSS step (node-IDs before any reset) is still running: {self.done} of "
            f"{len(self.nodes)} nodes done (a revision the file does not give costs about "
            "3.5 s to search for: give revision_number)"
        )


class NodeBoot:
    """The boot of one node: ``node.boot``.

    The master starts it (:meth:`spawn`, or :meth:`expect_bootup` before its broadcast
    reset), supervision restarts it when the node re-boots; what it found is on the node
    (``problem``, ``device_type``, ``identity``) and in :attr:`not_found`, :attr:`sdo_error`
    and :attr:`mismatch`, which the node's diagnostic reads.
    """

    def __init__(self, node: ManagedNode) -> None:
        self.node = node
        self.context = node.context
        self.config = node.config
        self.node_id = node.node_id
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
        #: What LSS did for the node at the master's start, when it could not give it its
        #: node-ID (the node's :meth:`~ManagedNode.describe` says it).
        self.lss_note: str | None = None
        self.lss_reset_all = False

    @property
    def not_found(self) -> bool:
        """The node did not answer (no boot-up and no 1000h answer, or it went silent)."""
        return self._not_found

    @property
    def sdo_error(self) -> bool:
        """The configuration failed (an abort with ``stop_on_abort``, a failed boot step, no
        error control the node accepts)."""
        return self._sdo_error

    @property
    def mismatch(self) -> bool:
        """The node is not the configured one (device type or identity)."""
        return self._mismatch

    async def assign_by_lss(self) -> bool:
        """Step 0, before the boot (CiA 302-2 with CiA 305, for a node with ``lss: true``):
        the device with the node's LSS address (its identity) takes the node's node-ID - at
        once when it had none, at a reset under the node-ID it had otherwise - and stores
        it with ``lss_store`` (unless it had it already: no wear of its memory at every
        start). True when it took it (:class:`LssAssigned`); False (said by
        :class:`LssNotAssigned`) when no device or several answered or the device refused:
        the node then boots as it is. Every device is back in waiting state after it."""
        cfg = self.config
        network = self.context.network
        lss = network.lss
        self.lss_note = None
        #: The device did not say which node-ID it had: a reset communication to all
        #: moves it (the master sends one after its LSS step).
        self.lss_reset_all = False
        previous = -1
        stored = False
        kept = ""
        try:
            try:
                found = await self._select_by_lss()
                if isinstance(found, str):
                    return self._not_assigned(found)
                try:
                    previous = await lss.inquire("node_id")
                except LssTimeoutError:  # (an optional service of CiA 305)
                    previous = -1
                await lss.configure_node_id(self.node_id)
                if cfg.lss_store and previous != self.node_id:
                    try:
                        await lss.store()
                        stored = True
                    except (LssRefusedError, LssTimeoutError) as exc:
                        kept = f"the device did not store it: {exc}"
            finally:
                if network.connected:  # (also when the master stops in the middle)
                    lss.switch_global(LssState.WAITING)
        except LssRefusedError as exc:
            return self._not_assigned(f"the device refused the node-ID: {exc}")
        except LssTimeoutError as exc:
            return self._not_assigned(f"the device stopped answering: {exc}")
        except NetworkClosedError:
            return self._not_assigned("the network closed during the LSS step")
        if previous != self.node_id and network.connected:
            if 1 <= previous <= 127:
                # a configured device takes a new node-ID at its reset (CiA 305): now,
                # under the node-ID it still has, so that the master's reset finds it
                network.nmt.reset_node(previous)
            elif previous == -1:
                self.lss_reset_all = True
        if kept:
            self.lss_note = kept
        self.context.emit(LssAssigned(self.node_id, *found.fields, previous, stored, kept))
        return True

    async def _select_by_lss(self) -> LssIdentity | str:
        """The device with the node's LSS address, put into configuration state (or why
        not). A revision the file does not give is first taken from the node's EDS (1018h
        sub 3: one request when the device is the one the EDS describes), then searched for
        (about 66 requests, 3.5 s at the default timeout)."""
        lss = self.context.network.lss
        vendor, product, revision, serial = self.config.identity
        hint = " (is it there, powered, an LSS slave, at this bit rate?)"
        guesses = [revision]
        if not revision:
            var = self.config.od.get_variable(0x1018, 3)
            guess = var.value if var is not None else None
            guesses = [guess] if isinstance(guess, int) and 0 < guess <= 0xFFFFFFFF else []
        for guess in guesses:
            identity = LssIdentity(vendor, product, guess, serial)
            try:
                await lss.select(identity)
                return identity
            except LssTimeoutError:
                if revision:
                    return f"no device answers to {identity}{hint}"
        revisions = await lss.find_revisions(vendor, product, serial)
        if not revisions:
            tried = f" (nor with revision 0x{guesses[0]:08X}, the EDS's)" if guesses else ""
            return (
                f"no device answers to vendor 0x{vendor:08X}, product 0x{product:08X}, "
                f"serial 0x{serial:08X} with any revision{tried}{hint}"
            )
        if len(revisions) > 1:
            shown = ", ".join(f"0x{r:08X}" for r in revisions)
            return (
                f"{len(revisions)} devices answer to its vendor, product and serial "
                f"(revisions {shown}): give revision_number"
            )
        identity = LssIdentity(vendor, product, revisions[0], serial)
        try:
            await lss.select(identity)
        except LssTimeoutError:
            return f"no device answers to {identity}{hint}"
        return identity

    def _not_assigned(self, reason: str) -> bool:
        self.lss_note = reason
        self.context.emit(LssNotAssigned(self.node_id, reason))
        return False

    def allow_wakes(self) -> None:
        """The wakes of an absent node may be tried again (a manual restart)."""
        self._wakes_spent = False
        self._wakes.clear()

    # ================================================================== the boot-up task

    def spawn(self, mode: str) -> asyncio.Task[None]:
        """Start the boot-up sequence (``mode``: reset, await, booted, none), replacing a
        running one."""
        old = self.node.boot_task
        if old is not None and not old.done():
            old.cancel()
        else:
            old = None
        loop = self.context.network.loop
        task = loop.create_task(self._run(old, mode), name=f"cobus-master-node-{self.node_id}")
        task.add_done_callback(self._finished)
        self.node.boot_task = task
        return task

    def _finished(self, task: asyncio.Task[None]) -> None:
        if task is self.node.boot_task and not task.cancelled():
            self.context.node_finished(self.node)

    def expect_bootup(self) -> None:
        """The master is about to reset every node with one broadcast."""
        self._bootup = self.context.network.loop.create_future()
        self.node.set_state(NodeState.RESETTING)

    def cancel(self) -> None:
        """Cancel the node's boot task (the master stops)."""
        if self.node.boot_task is not None and not self.node.boot_task.done():
            self.node.boot_task.cancel()
        self.node.supervision.stop()

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
            self.node.problem = f"boot-up failed: {exc!r}"
            self.context.network.emit(HandlerFailed(f"master: node {self.node_id}", repr(exc)))

    async def _sequence(self, mode: str) -> None:
        cfg = self.config
        self.node.supervision.reset()
        self._not_found = self._sdo_error = self._mismatch = False
        self.node.problem = None
        self.node.expected_nmt = None
        self.node.step_results.clear()  # (what the steps say of this boot only)
        self.node.boot_count += 1
        if cfg.do_not_initialise:
            mode = "none"
        while True:
            try:
                await self._boot_once(mode)
                return
            except _NodeSilent:
                self._not_found = True
                self.node.problem = "stopped answering SDO while being configured"
                if not cfg.mandatory and not self._wake(True):
                    self.node.set_state(NodeState.ABSENT)
                    self.context.emit(NodeMissing(self.node_id, False, self.node.problem))
                    return
                mode = "poll"

    async def _boot_once(self, mode: str) -> None:
        cfg = self.config
        if mode == "reset":
            await self._reset_and_wait()
        elif mode == "await":
            await self._wait_bootup()
        if mode != "none":
            self.node.set_state(NodeState.WAITING)
            if mode != "poll":
                await asyncio.sleep(self.context.config.master.bootup_delay)
        else:
            self.node.set_state(NodeState.WAITING)
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
            self.node.set_state(NodeState.WAITING)
            await asyncio.sleep(self.context.config.master.bootup_delay)
        self.node.set_state(NodeState.CONFIGURING)
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
                self.node.problem = (
                    "no error control: the node refused heartbeat (1017h) and node guarding "
                    "(100Ch/100Dh)"
                )
        self.node.error_control = kind
        await self._run_boot_steps()
        self.node.supervision.start()
        self.lss_note = None  # (what LSS could not do did not hold the node back)
        self.node.set_state(NodeState.CONFIGURED)
        self.context.node_configured(self.node)

    async def _run_boot_steps(self) -> None:
        for name, step in self.node.boot_steps:
            try:
                detail = await step(self.node)
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                if not isinstance(exc, BootStepError):
                    log.exception("master: boot step %r of node %d failed", name, self.node_id)
                reason = str(exc) or repr(exc)
                self.node.step_results[name] = f"failed: {reason}"
                self._sdo_error = True
                self.node.problem = f"boot step {name!r} failed: {reason}"
                self.context.emit(BootStepFailed(self.node_id, name, reason))
                raise _Held() from None
            text = "done" if detail is None else str(detail)
            self.node.step_results[name] = text
            self.context.emit(BootStepDone(self.node_id, name, text))

    async def _reset_and_wait(self) -> None:
        self._bootup = self.context.network.loop.create_future()
        self.node.set_state(NodeState.RESETTING)
        self.context.network.nmt.reset_node(self.node_id)
        await self._wait_bootup()

    async def _wait_bootup(self) -> None:
        self.node.set_state(NodeState.AWAITING_BOOTUP)
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
                data = await self.node.sdo.upload(0x1000, 0)
            except SdoTimeoutError:
                silent += 1
                self._not_found = True
                self.node.problem = "no boot-up and no answer to the 1000h read"
                woke = self._wake(silent > cfg.sdo_retries)
                if not cfg.mandatory and not woke:
                    self.node.set_state(NodeState.ABSENT)
                    self.context.emit(NodeMissing(self.node_id, False, self.node.problem))
                    return False
                if not reported and cfg.mandatory:
                    reported = True
                    self.context.note_configuring()
                    self.context.emit(NodeMissing(self.node_id, True, self.node.problem))
                pause = (
                    self.node.supervision.HEAL_DELAY
                    if woke
                    else _PRESENCE_RETRY - (loop.time() - began)
                )
                await asyncio.sleep(max(0.0, pause))
                continue
            except SdoError as exc:
                if isinstance(exc, SdoProtocolError) and garbled < cfg.sdo_retries:
                    garbled += 1
                    continue
                # the node is there but refuses 1000h (a mandatory object: it is broken)
                self._not_found = False
                self.node.device_type = None
                if cfg.device_type:
                    self._mismatched(f"refuses the 1000h read: {exc}")
                    self.context.emit(DeviceTypeMismatch(self.node_id, cfg.device_type, -1))
                    raise _Held() from None
                return True
            self._not_found = False
            self._left_said = None
            self._wakes_spent = False  # (it answers: a later silence may be woken again)
            self.node.problem = None
            actual = int.from_bytes(data[:4].ljust(4, b"\0"), "little")
            self.node.device_type = actual
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
        heard = self.node.supervision.heard
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
            self.node.supervision.last_commanded is NmtState.STOPPED
            or self.node.expected_nmt is NmtState.STOPPED
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
            self.node.problem = reason
            if self._left_said != reason:  # said once, not at every read
                self._left_said = reason
                self.context.emit(SdoUnanswered(self.node_id, state, "", reason))
            return False
        self._wakes.append(now)
        self._left_said = None
        reason = f"{said}: {action}"
        self.node.problem = reason
        self.context.emit(SdoUnanswered(self.node_id, state, command, reason))
        try:
            getattr(network.nmt, command)(self.node_id)
        except Exception as exc:  # (a full transmit backlog, a closed network)
            network.report_failure(f"master: node {self.node_id} NMT {command}", exc)
            return False
        return True

    def _mismatched(self, reason: str) -> None:
        self._mismatch = True
        self.node.problem = reason
        self.node.set_state(NodeState.WRONG_DEVICE)

    async def _check_identity(self) -> None:
        for sub, (field, expected) in enumerate(
            zip(_IDENTITY, self.config.identity, strict=True), 1
        ):
            if not expected:
                continue
            actual: int | None = None
            for _attempt in range(self.config.sdo_retries + 1):
                try:
                    data = await self.node.sdo.upload(0x1018, sub)
                except SdoTimeoutError:
                    raise _NodeSilent() from None
                except SdoProtocolError:
                    continue  # a reply that made no sense: asked again before it counts
                except SdoError:
                    break  # refused
                actual = int.from_bytes(data[:4].ljust(4, b"\0"), "little")
                break
            self.node.identity[field] = actual
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
                await self.node.sdo.download(entry.index, entry.subindex, entry.data)
                return True
            except SdoTimeoutError:
                continue
            except SdoError as exc:
                code = int(exc.code) if isinstance(exc, SdoAbortedError) else None
                failure = ConfigurationFailed(
                    self.node_id, entry.index, entry.subindex, code, str(exc)
                )
                self.node.config_errors.append(failure)
                self.context.emit(failure)
                if cfg.stop_on_abort:
                    self._sdo_error = True
                    self.node.problem = f"start-up write {entry} failed: {exc}"
                    raise _Held() from None
                return False
        raise _NodeSilent()

    async def _set_up_error_control(self, kind: str | None) -> str | None:
        cfg = self.config
        if kind == "heartbeat":
            entry = cfg.error_control_entries("heartbeat")[0]
            try:
                await self.node.sdo.download(entry.index, entry.subindex, entry.data)
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
