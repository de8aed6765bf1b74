"""The gateway's command core: executes parsed CiA 309-3 requests on cobus networks.

One :class:`Session` per client holds its defaults (net, node, SDO timeout, block transfer);
:class:`GatewayCore` runs its requests: SDO reads and writes on the network's one SDO
transport per node (a master or a remote node asking the same node waits its turn, and so
do other clients: requests to one node run in order, to different nodes side by side), NMT
commands, and the ``set``, ``info`` and ``help`` requests. A framing (the TCP server, JSON
lines) feeds it lines (:meth:`GatewayCore.submit`) and writes back what it is handed.

One client may have several requests under way (:data:`MAX_PENDING` at most): those with a
``[seq]`` run side by side, in turn per node, and are answered as they end (the client
matches the answers by their numbers); one without runs after every request before it and
before every request after it, so a client that numbers nothing gets its answers in order.
``cancel`` ends the client's requests still under way.

A core with a ``token`` takes what changes the bus or what others are told - writes, NMT
commands, LSS requests, the gateway's PDOs (``set rpdo``, ``w p``), heartbeat consumer
times, node guarding, the gateway's own device (``set id``, ``set heartbeat``) - and
``who`` only from a client that gave it first (``auth TOKEN``);
reads, ``set node`` and the like need none.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING

import cobus
from cobus.apps._serving import MIN_TOKEN, token_is, token_usable
from cobus.apps.gateway.grammar import (
    TYPES,
    GatewayError,
    Request,
    format_error,
    format_value,
    mnemonic,
    parse_line,
    parse_number,
    parse_value,
    split_name,
)
from cobus.apps.gateway.pdo import PdoTable, parse_pdo_config
from cobus.device import Device, NodeIdInUseError, add_device, minimal_od
from cobus.device.events import DeviceEvent, LifeGuardingLost, LifeGuardingRestored
from cobus.od import NameLookupError, ObjectDictionary, resolve
from cobus.proto import NOTHING, Event, Frame, Out
from cobus.proto.connection_set import ERROR_CONTROL_BASE, emcy_cob_id, error_control_cob_id
from cobus.proto.guarding import (
    GuardingMaster,
    GuardingNodeLost,
    GuardingResumed,
    GuardingStateChanged,
)
from cobus.proto.heartbeat import (
    BootupReceived,
    HeartbeatMonitor,
    HeartbeatResumed,
    HeartbeatTimeout,
    RemoteStateChanged,
)
from cobus.proto.lss import BIT_RATES, LssError, LssIdentity, LssState
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbortedError, SdoError, SdoTimeoutError, describe
from cobus.runtime import (
    LssRefusedError,
    LssScanError,
    LssTimeoutError,
    NetworkClosedError,
    SdoChannel,
    Subscription,
)

if TYPE_CHECKING:
    from cobus.runtime import AsyncNetwork
    from cobus.runtime.network import MachineHost

__all__ = ["HELP", "MAX_PENDING", "NODE_COMMANDS", "GatewayCore", "Session", "version_fields"]

#: Requests one client may have under way at once; one more is answered with ERROR:102.
MAX_PENDING = 64

#: Wrong tokens a client may give (each answered after a wait) before auth is refused.
_WRONG_TOKENS = 5
_WRONG_TOKEN_WAIT = 1.0  # s

#: The commands that need the token (when the core has one): they change the bus.
_GUARDED = frozenset(
    ("w", "write", "start", "stop", "preop", "preoperational", "reset", "enable", "disable")
)

#: Lely's LSS scans beside CiA 309-3's lss_ commands.
_LSS_SCANS = frozenset(("_lss_fastscan", "_lss_slowscan"))

#: The commands that address one node (and queue behind the client's others to that node).
NODE_COMMANDS = frozenset(
    (
        "r",
        "read",
        "w",
        "write",
        "start",
        "stop",
        "preop",
        "preoperational",
        "reset",
        "enable",
        "disable",
    )
)

HELP = """\
cobus CiA 309-3 gateway: one request a line, [seq] [[net] node] command [args] [# comment]
  r|read INDEX SUB [TYPE]          read an object (no TYPE: its bytes in hex, or the
                                   type the node's EDS gives)
  w|write INDEX SUB TYPE VALUE     write an object
  r NAME [TYPE] | w NAME [TYPE] VALUE   by its name in the node's EDS: "Device name",
                                   "Identity object.Vendor-ID" (TYPE from the EDS)
  start | stop | preop | reset node | reset comm    NMT (node 0: every node)
  set network N | set node N | set sdo_timeout MS | set sdo_block 0|1
  set command_timeout MS            end this client's requests not done after MS from
                                    their turn (waits for the node's SDO server count)
                                    (ERROR:103; an SDO under way is aborted; 0: no limit)
  [net] set id N | [net] set heartbeat MS    the gateway is node N of the net too, a
                                    device of its own (its heartbeat; a master that stops
                                    guarding it: NET N ERROR 201 (Lost connection));
                                    set id 255: no more
  lss_switch_glob 0|1 | lss_switch_sel VENDOR PRODUCT REVISION SERIAL | lss_set_node N
  lss_conf_bitrate 0 INDEX | lss_activate_bitrate DELAY_MS | lss_store
  lss_inquire_addr [0..3|0x5A..0x5D] | lss_get_node | lss_identity V P RL RH SL SH |
  lss_ident_nonconf | _lss_fastscan [MS] (or Lely's V VMASK P PMASK R RMASK S SMASK) |
  _lss_slowscan V P RL RH SL SH     (Lely's: the lowest slave in the ranges, selected)
                                    LSS (CiA 305)
  enable heartbeat MS | disable heartbeat    watch a node's heartbeat with this time
                                    (instead of the period the gateway learns)
  enable guarding GUARD_MS FACTOR | disable guarding    guard a node: a remote request
                                    every GUARD_MS; NET NODE ERROR 200 (Lost guarding
                                    message) after GUARD_MS x FACTOR without a reply,
                                    NET NODE ERROR 204 (Wrong NMT state) when a reply gives
                                    another state than the NMT commands on the bus asked
                                    for, then the state; refused (102) for a node another
                                    master guards, and stopped (a 200 line says why) when
                                    one starts to
  subscribe [boot_up|emcy|error_control|all] | unsubscribe [...]   unsolicited lines, as
  Lely writes them: NET NODE BOOT_UP, NET NODE EMCY CODE REG B0 B1 B2 B3 B4,
  NET NODE ERRORx STATE 202 (Heartbeat started) | 203 (Heartbeat lost), NET NODE ERRORx
  STATE (a new NMT state); STATE is OPER, PREO or STOP; NET NODE ERROR 200 (Lost guarding
  message) | 204 (Wrong NMT state) of a guarded node, NET ID ERROR 201 (Lost connection)
  when a master stops guarding the gateway's own device. A heartbeat counts as lost after
  2.5 times the period the gateway saw it come at.
  set rpdo|tpdo N COB-ID event|rtr|syncN COUNT [INDEX SUB] TYPE...   the gateway's own
  PDOs, as Lely's (set tpdox N COB-ID TRANS INHIBIT EVENT|SYNC-START ...);
  r p N -> NET pdo COUNT 0xV... what RPDO N last brought; w p N COUNT V...  send TPDO N
  (the net's PDOs, kept until the gateway stops or they are set again, COB-ID bit 31 off);
  subscribe pdo: NET pdo N COUNT 0xV... for each RPDO that comes in
  who                               the clients connected (this one marked *)
  cancel [SEQ]                      end this client's requests under way (or the one
                                    numbered SEQ): each is answered ERROR:102 #cancelled;
                                    cancel itself is answered at once, [seq] or not
  auth TOKEN                        give the gateway's token (when it has one: writes,
                                    NMT, LSS, set rpdo/tpdo/id/heartbeat, w p,
                                    enable/disable and who
                                    need it)
  info | info version | help       info version as Lely answers it: VENDOR PRODUCT
                                    REVISION SERIAL CLASS PROTOCOL IMPLEMENTATION
                                    (cobus has no identity: 0 0 its version 0 3 2.0 its
                                    version); help ends with [seq] OK
requests with [seq] run side by side (to one node in turn) and are answered as they end;
one without [seq] waits for all before it, so unnumbered requests are answered in order
types: b i8 i16 i24 i32 i40 i48 i56 i64 u8 u16 u24 u32 u40 u48 u56 u64 x8 x16 x32 x64
       r32 r64 vs ("text", "" for a quote) os us d (base64) t td (days ms) hex (bytes)
       (r32 and r64 with six significant digits as CANopenNode writes them; the lely
       dialect writes r64 with 15; hex gives the bytes)
numbers: decimal, 0x hex, leading-0 octal"""


@dataclass
class Session:
    """One client's defaults (``set network``, ``set node``...)."""

    net: int | None = None
    node: int | None = None
    sdo_timeout: float = 1.0  # s
    sdo_block: bool = False
    #: ``set command_timeout MS``: a request not done after it is ended (ERROR:103; an
    #: SDO transfer under way is aborted); None: no limit but each service's own.
    command_timeout: float | None = None
    #: The SDO channels this client opened, by (net, node).
    channels: dict[tuple[int, int], SdoChannel] = field(default_factory=dict)
    #: The unsolicited lines the client asked for ("boot_up", "emcy"), and how the framing
    #: hands it a line (None: it cannot take any).
    subscribed: set[str] = field(default_factory=set)
    notify: Callable[[str], None] | None = None
    #: Who the client is (its address), since when (monotonic s), its requests so far and
    #: when the last came - what ``who`` shows.
    peer: str = "?"
    since: float = field(default_factory=time.monotonic)
    requests: int = 0
    last: float = field(default_factory=time.monotonic)
    #: The client's requests under way (their tasks, with their sequence numbers).
    pending: dict[asyncio.Task[None], int | None] = field(default_factory=dict)
    #: The last request without [seq] still under way (later ones wait for it).
    barrier: asyncio.Task[None] | None = None
    #: Requests that hold their lane (their node, LSS), with the lane.
    running: dict[asyncio.Task[None], tuple[object, ...]] = field(default_factory=dict)
    #: Requests the client cancelled, with what their answer says.
    cancelled: dict[asyncio.Task[None], str] = field(default_factory=dict)
    #: One lock per node (and one for LSS): the client's requests to it in turn.
    lanes: dict[tuple[object, ...], asyncio.Lock] = field(default_factory=dict)
    #: Whether the client may write, send NMT commands and use LSS (it gave the token, or
    #: the gateway has none).
    authorised: bool = True
    #: Wrong tokens this client gave, and when (monotonic s) it may give the next.
    wrong_tokens: int = 0
    auth_not_before: float = 0.0

    def close(self) -> None:
        """The client left: its channels go (a transfer under way ends with it), its
        requests still under way end."""
        for task in list(self.pending):
            task.cancel()
        for channel in self.channels.values():
            channel.close()
        self.channels.clear()
        self.subscribed.clear()


#: The gateway error number of an LSS service the device refused (CiA 309-3).
_LSS_REFUSED = {"configure node-ID": 502, "configure bit timing": 503, "store configuration": 504}


class GatewayCore:
    """Runs CiA 309-3 requests on ``networks`` (by net number; the first is the default);
    with a ``token``, writes, NMT and LSS only for clients that gave it (``auth TOKEN``)."""

    def __init__(
        self,
        networks: dict[int, AsyncNetwork],
        *,
        dialect: str = "canopennode",
        token: str | None = None,
        dictionaries: dict[tuple[int, int], ObjectDictionary] | None = None,
    ) -> None:
        if not networks:
            raise ValueError("a gateway needs at least one network")
        bad = [n for n in networks if not 1 <= n <= 127]
        if bad:
            raise ValueError(f"net {bad[0]}: the nets of a gateway are numbered 1..127")
        if token is not None and not token_usable(token):
            raise ValueError(
                f"a token of {MIN_TOKEN} characters at least, without spaces or # (a client "
                "gives it as one word of a request line)"
            )
        #: What clients give before they write (None: nothing needed).
        self.token = token
        #: The nodes' object dictionaries, by (net, node): names and types for r and w.
        self.dictionaries = dict(dictionaries or {})
        self.networks = networks
        self.dialect = dialect
        self.default_net = next(iter(networks))
        self._sessions: list[Session] = []
        self._listening: list[Subscription] = []
        self._watches: list[_HeartbeatWatch] = []
        self._pdos: dict[int, PdoTable] = {}
        #: The gateway's own device on a net (``set id``), by net.
        self._devices: dict[int, Device] = {}
        #: Nodes the gateway must not take as its own node-ID, by (net, node): who uses
        #: them (``cobus run --gateway``: the master and its nodes).
        self.in_use: dict[tuple[int, int], str] = {}
        self._held = 0  # (servers serving it: hold, release)
        _CORES[0] += 1
        #: Who guards a node for this gateway, in the network's record (claim_guarding).
        self.guard_owner = (
            _GUARD_OWNER if _CORES[0] == 1 else f"{_GUARD_OWNER} (gateway {_CORES[0]})"
        )

    def session(self, *, trusted: bool = False) -> Session:
        """A new client's session (the default net, no default node); a ``trusted`` one
        (this user's Unix socket) needs no token."""
        session = Session(net=self.default_net, authorised=trusted or self.token is None)
        self._sessions.append(session)
        return session

    def forget(self, session: Session) -> None:
        """The client left: its session ends."""
        session.close()
        with contextlib.suppress(ValueError):
            self._sessions.remove(session)

    def _who(self, asker: Session) -> list[str]:
        now = time.monotonic()
        out = []
        for s in self._sessions:
            node = "-" if s.node is None else str(s.node)
            mark = "*" if s is asker else " "
            out.append(
                f"{mark} {s.peer} net {s.net} node {node}, {s.requests} requests "
                f"({len(s.pending)} under way), connected {now - s.since:.0f} s, "
                f"idle {now - s.last:.0f} s"
            )
        return out

    # ------------------------------------------------------------------ unsolicited lines

    def _subscribe(self, session: Session, request: Request) -> None:
        kinds = {"boot_up", "emcy", "error_control", "pdo"}
        words = [a.lower() for a in request.args]
        if request.command == "boot_up_indication":  # (Lely's)
            if words not in (["enable"], ["disable"]):
                raise GatewayError(101, "boot_up_indication takes enable or disable")
            wanted, on = {"boot_up"}, words == ["enable"]
        else:
            unknown = [w for w in words if w not in kinds | {"all"}]
            if unknown:
                raise GatewayError(
                    101,
                    f"no events {' '.join(unknown)} (boot_up, emcy, error_control, pdo, all)",
                )
            wanted = kinds if not words or "all" in words else set(words)
            on = request.command == "subscribe"
        if on and session.notify is None:
            raise GatewayError(100, "this connection takes no unsolicited lines")
        if on:
            session.subscribed |= wanted
            self.listen()
        else:
            session.subscribed -= wanted

    def listen(self) -> None:
        """Watch boot-ups, heartbeats, NMT commands and emergencies on every net (once:
        when a client first asks, or at once to know the nodes before ``set_node_id``)."""
        if self._listening:
            return
        for net_id, network in self.networks.items():
            watch = _HeartbeatWatch(self, net_id)
            watch.host = network.attach(watch.monitor, on_event=watch.on_event)
            self._watches.append(watch)
            self._listening.append(network.subscribe(0x000, watch.on_nmt))
            for node in range(1, 128):
                self._listening += [
                    network.subscribe(error_control_cob_id(node), watch.on_frame),
                    network.subscribe(emcy_cob_id(node), partial(self._emcy, net_id, node)),
                ]

    def hold(self) -> None:
        """A server serves this core from now on (the buses are watched from now on)."""
        self._held += 1
        self.listen()

    def release(self) -> None:
        """A server stopped serving this core: when none serves it any more, it closes."""
        self._held -= 1
        if self._held <= 0:
            self._held = 0
            self.close()

    def close(self) -> None:
        """The gateway stops: every session ends, the bus is no longer watched."""
        for session in list(self._sessions):
            self.forget(session)
        for subscription in self._listening:
            subscription.cancel()
        self._listening.clear()
        for watch in self._watches:
            watch.close()
        self._watches.clear()
        for table in self._pdos.values():
            table.close()
        self._pdos.clear()
        for device in self._devices.values():
            device.close()
        self._devices.clear()

    def _tell(self, kind: str, line: str) -> None:
        for session in self._sessions:
            if kind in session.subscribed and session.notify is not None:
                session.notify(line)

    def _emcy(self, net: int, node: int, frame: Frame, now: float) -> None:
        data = frame.data
        if len(data) == 8 and not frame.rtr:
            code = int.from_bytes(data[:2], "little")
            rest = " ".join(str(b) for b in data[3:8])
            self._tell("emcy", f"{net} {node} EMCY {code:04X} {data[2]:02X} {rest}")

    async def execute(self, session: Session, line: str) -> list[str]:
        """The reply lines to ``line`` (none for an empty line or a comment), one request
        at a time (:meth:`submit` takes several)."""
        try:
            request = parse_line(line)
        except GatewayError as exc:
            return [format_error(None, exc.code, exc.text, self.dialect)]
        if request is None:
            return []
        session.requests += 1
        session.last = time.monotonic()
        if request.command == "cancel":
            return self._cancel(session, request)
        return await self._answer(session, request)

    # ------------------------------------------------------------------ several at once

    def submit(self, session: Session, line: str, answer: Callable[[list[str]], None]) -> None:
        """Take ``line`` and hand its reply lines to ``answer`` when it is done (at once for
        ``cancel``, a full queue or an empty line: nothing). See the module's text for the
        order requests run in."""
        request: Request | GatewayError | None
        try:
            request = parse_line(line)
        except GatewayError as exc:
            request = exc
        if request is None:
            return
        seq = None
        if isinstance(request, Request):
            session.requests += 1
            session.last = time.monotonic()
            seq = request.seq
            if request.command == "cancel":
                answer(self._cancel(session, request))
                return
        full = len(session.pending) >= MAX_PENDING
        if full:
            refusal = GatewayError(
                102, f"{MAX_PENDING} requests of this client are under way: wait for their answers"
            )
            if seq is not None:
                answer([format_error(seq, refusal.code, refusal.text, self.dialect)])
                return
            request = refusal  # (answered in its turn, as every request without [seq])
        self._queue(session, request, seq, answer)

    def refuse(
        self, session: Session, code: int, text: str, answer: Callable[[list[str]], None]
    ) -> None:
        """Answer an error for a line the framing could not take (too long...), in its
        turn: after every request before it."""
        self._queue(session, GatewayError(code, text), None, answer)

    def _queue(
        self,
        session: Session,
        request: Request | GatewayError,
        seq: int | None,
        answer: Callable[[list[str]], None],
    ) -> None:
        ordered = seq is None
        if ordered:
            before = list(session.pending)
        else:
            before = [] if session.barrier is None else [session.barrier]
        task = asyncio.get_running_loop().create_task(self._job(session, request, before, answer))
        session.pending[task] = seq
        if ordered:
            session.barrier = task
        task.add_done_callback(partial(self._ended, session, seq, answer))

    def _ended(
        self,
        session: Session,
        seq: int | None,
        answer: Callable[[list[str]], None],
        task: asyncio.Task[None],
    ) -> None:
        session.last = time.monotonic()  # (idle from its last answer)
        session.pending.pop(task, None)
        session.running.pop(task, None)
        reason = session.cancelled.pop(task, None)
        if session.barrier is task:
            session.barrier = None
        if reason is not None and task.cancelled():  # (cancelled before it ever ran)
            answer([format_error(seq, 102, reason, self.dialect)])

    async def _job(
        self,
        session: Session,
        request: Request | GatewayError,
        before: list[asyncio.Task[None]],
        answer: Callable[[list[str]], None],
    ) -> None:
        task = asyncio.current_task()
        assert task is not None
        try:
            if before:
                await asyncio.wait(before)
            if isinstance(request, GatewayError):
                answer([format_error(None, request.code, request.text, self.dialect)])
                return
            view, lane = self._bind(session, request)
            if lane is None:
                lines = await self._answer(view, request)
            else:
                async with session.lanes.setdefault(lane, asyncio.Lock()):
                    session.running[task] = lane
                    lines = await self._answer(view, request)
        except asyncio.CancelledError:
            reason = session.cancelled.get(task)
            if reason is None:
                raise  # (the client left, the gateway stops: nobody to answer)
            seq = request.seq if isinstance(request, Request) else None
            answer([format_error(seq, 102, reason, self.dialect)])
            return
        answer(lines)

    def _bind(
        self, session: Session, request: Request
    ) -> tuple[Session, tuple[object, ...] | None]:
        """The session as ``request`` sees it (its defaults as they are when its turn
        comes, whatever the client sets later) and the lane it queues in (None: none)."""
        command = request.command
        if command in ("r", "read", "w", "write") and request.args[:1] in (["p"], ["pdo"]):
            return copy.copy(session), ("pdo",)  # (a whole net's: no node)
        if command in NODE_COMMANDS:
            net = request.net if request.net is not None else session.net
            node = request.node if request.node is not None else session.node
            request.net, request.node = net, node
            return copy.copy(session), ("node", net, node)
        if command.startswith("lss_") or command in _LSS_SCANS:
            return copy.copy(session), ("lss",)
        if command == "auth":  # (one at a time: each wrong token costs its wait)
            return session, ("auth",)
        return session, None

    def _cancel(self, session: Session, request: Request) -> list[str]:
        """``cancel [SEQ]``: end the client's requests under way (or those numbered SEQ)."""
        if len(request.args) > 1 or request.net is not None or request.node is not None:
            raise_text = "cancel takes the [seq] of one request at most: cancel 12"
            return [format_error(request.seq, 101, raise_text, self.dialect)]
        try:
            which = parse_number(request.args[0], "seq") if request.args else None
        except GatewayError as exc:
            return [format_error(request.seq, exc.code, exc.text, self.dialect)]
        head = "" if request.seq is None else f"[{request.seq}] "
        tasks = [t for t, s in session.pending.items() if which is None or s == which]
        if not tasks and which is not None:
            return [
                format_error(request.seq, 102, f"no request [{which}] is under way", self.dialect)
            ]
        by = "cancelled" if request.seq is None else f"cancelled by [{request.seq}]"
        for task in tasks:
            session.cancelled[task] = by
            task.cancel()
        return [f"{head}OK"]

    def abandon(self, session: Session) -> None:
        """The client is gone: its requests that have not had their turn yet end (no frame
        of theirs reaches the bus, even those queued at a node behind other clients'); a
        transfer under way ends as it would, and so does an LSS request."""
        for task in list(session.pending):
            lane = session.running.get(task)
            if lane is not None and lane[0] == "node":
                channel = session.channels.get((lane[1], lane[2]))  # type: ignore[arg-type]
                if channel is not None and channel.transport.owner is channel:
                    continue  # (its transfer is on the bus: it ends as it would)
            elif lane is not None and lane[0] == "lss":
                continue
            task.cancel()

    async def drain(self, session: Session) -> None:
        """Wait until every request of ``session`` has ended."""
        while session.pending:
            await asyncio.wait(list(session.pending))

    async def _answer(self, session: Session, request: Request) -> list[str]:
        head = "" if request.seq is None else f"[{request.seq}] "
        try:
            if session.command_timeout is None:
                out = await self._run(session, request)
            else:
                out = await asyncio.wait_for(self._run(session, request), session.command_timeout)
        except GatewayError as exc:
            return [format_error(request.seq, exc.code, exc.text, self.dialect)]
        except LssTimeoutError as exc:
            return [format_error(request.seq, 103, str(exc), self.dialect)]
        except LssRefusedError as exc:
            code = _LSS_REFUSED.get(exc.service, 501)
            if code == 504 and exc.error == 2:
                code = 505  # (storage media access error)
            return [format_error(request.seq, code, str(exc), self.dialect)]
        except (LssScanError, LssError) as exc:
            return [format_error(request.seq, 102, str(exc), self.dialect)]
        except SdoAbortedError as exc:
            code = int(exc.code)
            text = describe(code)
            text = text[:1].upper() + text[1:] + ("." if self.dialect == "canopennode" else "")
            return [format_error(request.seq, code, text, self.dialect)]
        except SdoTimeoutError:
            if self.dialect == "lely":
                return [format_error(request.seq, 103, "Time-out", self.dialect)]
            timed_out = "SDO protocol timed out."
            return [format_error(request.seq, 0x05040000, timed_out, self.dialect)]
        except (SdoError, NetworkClosedError) as exc:
            return [format_error(request.seq, 102, str(exc), self.dialect)]
        except TimeoutError as exc:  # (the command time-out's, or another service's)
            text = str(exc) or "Time-out"
            if session.command_timeout is not None and not str(exc) and self.dialect != "lely":
                ms = round(session.command_timeout * 1000)
                text = f"Time-out: not done within the command time-out, {ms} ms"
            return [format_error(request.seq, 103, text, self.dialect)]
        except Exception as exc:  # (never a dropped connection: the client is told)
            return [format_error(request.seq, 102, f"internal error: {exc!r}", self.dialect)]
        if out is None:
            return [f"{head}OK"]
        if isinstance(out, list):
            return [*out, f"{head}OK"]
        return [f"{head}{out}"]

    # ------------------------------------------------------------------ requests

    async def _run(self, session: Session, request: Request) -> str | list[str] | None:
        command, args = request.command, request.args
        if command == "auth":
            await self._auth(session, request)
            return None
        guarded = command in _GUARDED or command.startswith("lss_") or command in _LSS_SCANS
        if guarded and not session.authorised:
            raise GatewayError(
                102,
                f"{command}: this gateway writes to the bus only for clients that gave "
                "its token first: auth TOKEN",
            )
        pdo = bool(args) and args[0].lower() in ("p", "pdo")
        if command in ("r", "read"):
            return self._pdo_read(session, request) if pdo else await self._read(session, request)
        if command in ("w", "write"):
            if pdo:
                self._pdo_write(session, request)
            else:
                await self._write(session, request)
            return None
        if command in ("start", "stop", "preop", "preoperational", "reset"):
            self._nmt(session, request)
            return None
        if command == "set":
            self._set(session, request)
            return None
        if command in ("enable", "disable"):
            self._heartbeat(session, request)
            return None
        if command in ("subscribe", "unsubscribe", "boot_up_indication"):
            self._subscribe(session, request)
            return None
        if command.startswith("lss_") or command in _LSS_SCANS:
            return await self._lss(session, request)
        if command == "who":
            if not session.authorised:
                raise GatewayError(102, "who: this gateway lists its clients only after auth TOKEN")
            return self._who(session)
        if command in ("info", "help") and args and not (command == "info" and args == ["version"]):
            raise GatewayError(101, f"{command} takes no arguments")
        if command == "info" and args:
            return _version_line()
        if command == "info":
            nets = ", ".join(str(n) for n in self.networks)
            return (
                f"cobus {cobus.__version__} CiA 309-3 gateway, dialect {self.dialect}, nets {nets}"
            )
        if command == "help":
            return HELP.splitlines()
        if command == "init":
            raise GatewayError(
                100,
                "init: cobus's gateway does not re-open its adapter at another bit rate; "
                "switch the nodes (lss_conf_bitrate, lss_activate_bitrate) and start the "
                "gateway again with -b",
            )
        del args
        raise GatewayError(100, f"no command {command!r} (help lists them)")

    async def _auth(self, session: Session, request: Request) -> None:
        if self.token is None:
            raise GatewayError(102, "this gateway has no token: every client may write")
        words = request.rest.split()
        if len(words) != 1 or request.net is not None or request.node is not None:
            raise GatewayError(101, "auth takes the token: auth TOKEN")
        if session.wrong_tokens >= _WRONG_TOKENS:
            raise GatewayError(102, f"{_WRONG_TOKENS} wrong tokens: connect again")
        now = time.monotonic()
        if now < session.auth_not_before:  # (a wait cut short - cancel, a command time-out)
            raise GatewayError(102, "a wrong token came less than a second ago: auth later")
        if not token_is(words[0], self.token):
            session.authorised = False
            session.wrong_tokens += 1
            session.auth_not_before = now + _WRONG_TOKEN_WAIT
            await asyncio.sleep(_WRONG_TOKEN_WAIT)  # (guessing costs time)
            raise GatewayError(102, "that is not this gateway's token")
        session.authorised = True

    def _network(self, session: Session, request: Request) -> tuple[int, AsyncNetwork]:
        net = request.net if request.net is not None else session.net
        if net is None:
            raise GatewayError(104)
        network = self.networks.get(net)
        if network is None:
            known = ", ".join(str(n) for n in self.networks)
            raise GatewayError(106, f"no net {net} here (the nets: {known})")
        return net, network

    def _node(self, session: Session, request: Request, *, broadcast: bool = False) -> int:
        node = request.node if request.node is not None else session.node
        if node is None:
            raise GatewayError(105, "no node given and no default node: set node N")
        low = 0 if broadcast else 1
        if not low <= node <= 127:
            raise GatewayError(107, f"node {node} is not in {low}..127")
        return node

    def _channel(self, session: Session, request: Request) -> SdoChannel:
        net, network = self._network(session, request)
        node = self._node(session, request)
        channel = session.channels.get((net, node))
        if channel is None:
            channel = SdoChannel(network, node, None, timeout=session.sdo_timeout, emit=False)
            session.channels[(net, node)] = channel
        elif channel.timeout != session.sdo_timeout:
            channel.timeout = session.sdo_timeout
        return channel

    def dictionary(self, net: int, node: int) -> ObjectDictionary | None:
        """The object dictionary the gateway knows of ``node`` on ``net`` (given to it, or
        of a remote node added to that network), None: none."""
        od = self.dictionaries.get((net, node))
        if od is None:
            network = self.networks.get(net)
            remote = None if network is None else network.remotes.get(node)
            od = None if remote is None else remote.od
        return od

    def _target(self, session: Session, request: Request) -> tuple[int, int, str | None, str]:
        """The object a read or write names - ``INDEX SUB`` or a name from the node's EDS
        (``"Device name"``, ``Identity_object.Vendor-ID``) - the type mnemonic its
        dictionary gives (None: not known) and the text after it."""
        rest = request.rest.strip()
        words = rest.split(None, 2)
        index = _number_or_none(words[0]) if words and not words[0].startswith('"') else None
        net, _network = self._network(session, request)
        node = self._node(session, request)
        od = self.dictionary(net, node)
        if index is not None:
            if len(words) < 2:
                raise GatewayError(101, "give the object's index and sub-index (or its name)")
            sub = parse_number(words[1], "sub-index")
            if not 0 <= index <= 0xFFFF or not 0 <= sub <= 0xFF:
                raise GatewayError(
                    101, f"no object {words[0]} {words[1]} (index 0..0xFFFF, sub 0..255)"
                )
            after = words[2] if len(words) > 2 else ""
            known = None
            if od is not None:
                with contextlib.suppress(KeyError):
                    known = mnemonic(resolve(od, index, sub, suggest=False).data_type)
            return index, sub, known, after
        if not rest:
            raise GatewayError(101, "give the object's index and sub-index (or its name)")
        name, after = split_name(rest)
        if od is None:
            raise GatewayError(
                101,
                f"{name!r}: node {node} of net {net} has no EDS here to find names in "
                f"(cobus gateway --eds {node}=FILE), give index and sub-index",
            )
        try:
            variable = resolve(od, name)
        except NameLookupError as exc:
            raise GatewayError(101, str(exc.args[0]) if exc.args else str(exc)) from None
        return variable.index, variable.subindex, mnemonic(variable.data_type), after

    async def _read(self, session: Session, request: Request) -> str:
        index, sub, known, after = self._target(session, request)
        words = after.split()
        if len(words) > 1:
            raise GatewayError(101, "read takes the object and a data type at most")
        type_name = words[0] if words else known
        if type_name is not None and type_name.lower() not in TYPES:
            format_value(type_name, b"")  # (raises the error that names the types)
        channel = self._channel(session, request)
        data = await channel.upload(index, sub, block=session.sdo_block)
        return format_value(type_name, data, self.dialect)

    async def _write(self, session: Session, request: Request) -> None:
        index, sub, known, after = self._target(session, request)
        head, value_text = ([*after.split(None, 1), ""])[:2]
        if head.lower() in TYPES and (value_text.strip() or known is None):
            type_name = head  # (the type given; the value after it)
        elif known is not None:
            type_name, value_text = known, after  # (the type from the EDS)
        else:
            raise GatewayError(101, "write takes index, sub-index, data type and value")
        data = parse_value(type_name, value_text)
        channel = self._channel(session, request)
        await channel.download(index, sub, data, block=session.sdo_block)

    def _nmt(self, session: Session, request: Request) -> None:
        _net, network = self._network(session, request)
        node = self._node(session, request, broadcast=True)
        command, args = request.command, [a.lower() for a in request.args]
        nmt = network.nmt
        if command == "start" and not args:
            nmt.start(node)
        elif command == "stop" and not args:
            nmt.stop(node)
        elif command in ("preop", "preoperational") and not args:
            nmt.enter_preoperational(node)
        elif command == "reset" and args == ["node"]:
            nmt.reset_node(node)
        elif command == "reset" and args in (["comm"], ["communication"]):
            nmt.reset_communication(node)
        else:
            raise GatewayError(
                101, f"{request.command} {' '.join(request.args)}: no such NMT command"
            )

    def _set(self, session: Session, request: Request) -> None:
        if request.args and request.args[0].lower() in ("rpdo", "tpdo", "tpdox"):
            self._set_pdo(session, request)
            return
        if request.net is not None:
            raise GatewayError(101, "set takes one number before it at most: its net")
        if request.node is not None and request.node not in self.networks:  # ([net] set ...)
            known = ", ".join(str(n) for n in self.networks)
            raise GatewayError(106, f"no net {request.node} here (the nets: {known})")
        args = [a.lower() for a in request.args]
        if len(args) != 2:
            raise GatewayError(101, "set takes a name and a value: set node 5")
        name, value = args[0], parse_number(args[1], args[0])
        if name == "network":
            if value not in self.networks:
                known = ", ".join(str(n) for n in self.networks)
                raise GatewayError(106, f"no net {value} here (the nets: {known})")
            session.net = value
        elif name == "node":
            if not 1 <= value <= 127:
                raise GatewayError(107, f"node {value} is not in 1..127")
            session.node = value
        elif name == "sdo_timeout":
            if not 1 <= value <= 600_000:
                raise GatewayError(101, f"sdo_timeout {value} ms is not in 1..600000")
            session.sdo_timeout = value / 1000.0
        elif name == "sdo_block":
            if value not in (0, 1):
                raise GatewayError(101, "sdo_block is 0 or 1")
            session.sdo_block = bool(value)
        elif name == "command_timeout":
            if not 0 <= value <= 600_000:
                raise GatewayError(101, f"command_timeout {value} ms is not in 0..600000")
            session.command_timeout = value / 1000.0 if value else None
        elif name in ("id", "heartbeat"):
            if not session.authorised:
                raise GatewayError(
                    102, f"set {name}: the gateway's own device changes only after auth TOKEN"
                )
            net = request.node if request.node is not None else session.net
            if net is None:
                raise GatewayError(104)
            if name == "id":
                self.set_node_id(net, value)
            else:
                self._set_heartbeat(net, value)
        else:
            raise GatewayError(
                100,
                f"no setting {args[0]!r} (network, node, sdo_timeout, sdo_block, "
                "command_timeout, id, heartbeat)",
            )

    def set_node_id(self, net: int, node: int) -> None:
        """Make the gateway node ``node`` of net ``net`` (``[net] set id N``, Lely's): a
        CANopen device of its own - heartbeat producer (``set heartbeat``), node and life
        guarding (a master that stops guarding it: ``ERROR 201``), an SDO server of its
        communication objects; 255: no device any more. A :class:`GatewayError` (102) for
        a node-ID the net shows in use."""
        device = self._devices.get(net)
        watch = self._watch(net)
        if node == 255:
            if device is not None:
                device.close()
                del self._devices[net]
                watch.own = None
            return
        if not 1 <= node <= 127:
            raise GatewayError(101, f"node-ID {node}: 1..127, or 255 for none")
        if device is not None and device.node_id == node:
            return
        heard = self.in_use.get((net, node)) or watch.heard(node)
        if heard is not None:
            raise GatewayError(
                102, f"node {node} is on net {net} ({heard}): give the gateway a free node-ID"
            )
        try:
            if device is None:
                device = add_device(self.networks[net], node, _device_dictionary())
                device.add_listener(partial(self._device_event, net))
                self._devices[net] = device
            else:
                device.set_node_id(node)
        except NodeIdInUseError as exc:
            raise GatewayError(102, str(exc)) from None
        watch.own = node

    def _set_heartbeat(self, net: int, ms: int) -> None:
        """``[net] set heartbeat MS`` (Lely's): the gateway's own heartbeat (1017h)."""
        device = self._devices.get(net)
        if device is None:
            raise GatewayError(
                102, f"the gateway is no device on net {net}: give it a node-ID first (set id N)"
            )
        if not 0 <= ms <= 0xFFFF:
            raise GatewayError(101, f"heartbeat time {ms} ms: 0..65535")
        device.set(0x1017, 0, ms)

    def _device_event(self, net: int, event: DeviceEvent) -> None:
        """What the gateway's own device reports that its clients hear of: its life
        guarding lost (``ERROR 201``, Lost connection) and back (its state again)."""
        device = self._devices.get(net)
        if device is None:
            return
        if isinstance(event, LifeGuardingLost):
            self._tell("error_control", f"{net} {event.node_id} ERROR 201 (Lost connection)")
        elif isinstance(event, LifeGuardingRestored):
            word = _STATE_WORDS.get(device.state, "ERROR")
            self._tell("error_control", f"{net} {event.node_id} {word}")

    def _heartbeat(self, session: Session, request: Request) -> None:
        """``enable heartbeat MS`` / ``disable heartbeat`` (Lely's): watch the node's
        heartbeat with that time (0 or disable: not at all) instead of the learned one."""
        words = [a.lower() for a in request.args]
        if words[:1] == ["guarding"]:
            self._guarding(session, request, words)
            return
        enable = request.command == "enable"
        if words[:1] != ["heartbeat"] or len(words) != (2 if enable else 1):
            raise GatewayError(101, "enable heartbeat MS | disable heartbeat")
        ms = parse_number(words[1], "heartbeat consumer time") if enable else 0
        if not 0 <= ms <= 0xFFFF:
            raise GatewayError(101, f"heartbeat consumer time {ms} ms: 0..65535")
        net, _network = self._network(session, request)
        node = self._node(session, request)
        self._watch(net).fix(node, ms / 1000.0)

    def _guarding(self, session: Session, request: Request, words: list[str]) -> None:
        """``enable guarding GUARD_MS FACTOR`` / ``disable guarding`` (Lely's): guard the
        node - a remote request every guard time, lost after guard time x factor."""
        enable = request.command == "enable"
        if len(words) != (3 if enable else 1):
            raise GatewayError(
                101, "enable guarding GUARD_TIME_MS LIFE_TIME_FACTOR | disable guarding"
            )
        net, _network = self._network(session, request)
        node = self._node(session, request)
        watch = self._watch(net)
        if node == watch.own:
            raise GatewayError(102, f"node {node} is the gateway itself (set id)")
        if not enable:
            watch.unguard(node)
            return
        guard_ms = parse_number(words[1], "guard time")
        factor = parse_number(words[2], "life time factor")
        if not 1 <= guard_ms <= 0xFFFF:
            raise GatewayError(101, f"guard time {guard_ms} ms: 1..65535")
        if not 1 <= factor <= 0xFF:
            raise GatewayError(101, f"life time factor {factor}: 1..255")
        watch.guard(node, guard_ms, factor)

    def _watch(self, net: int) -> _HeartbeatWatch:
        if net not in self.networks:
            known = ", ".join(str(n) for n in self.networks)
            raise GatewayError(106, f"no net {net} here (the nets: {known})")
        self.listen()
        return next(w for w in self._watches if w.net == net)

    def _whole_net(self, session: Session, request: Request, what: str) -> tuple[int, AsyncNetwork]:
        """The net of a request that goes to a whole net (LSS, PDOs): one number before
        it names the net, as ``[net] lss_store``."""
        if request.net is not None:
            raise GatewayError(101, f"{what} goes to a whole net: one number before it, the net")
        if request.node is not None:
            if request.node not in self.networks:
                known = ", ".join(str(n) for n in self.networks)
                raise GatewayError(
                    106,
                    f"no net {request.node} here ({what} takes one number before it, its "
                    f"net: {known})",
                )
            request.net, request.node = request.node, None
        return self._network(session, request)

    def _pdo_table(self, net: int, network: AsyncNetwork) -> PdoTable:
        table = self._pdos.get(net)
        if table is None:
            table = self._pdos[net] = PdoTable(net, network, partial(self._tell, "pdo"))
        return table

    def _set_pdo(self, session: Session, request: Request) -> None:
        """``[net] set rpdo|tpdo|tpdox N COB-ID TRANS ... COUNT TYPE...`` (Lely's)."""
        if not session.authorised:
            raise GatewayError(
                102,
                "set rpdo/tpdo: this gateway changes its PDOs only for clients that gave "
                "its token first: auth TOKEN",
            )
        net, network = self._whole_net(session, request, "a PDO request")
        kind = request.args[0].lower()
        config = parse_pdo_config(request.args[1:], extended=kind == "tpdox")
        table = self._pdo_table(net, network)
        if kind == "rpdo":
            table.configure_rpdo(config)
        else:
            table.configure_tpdo(config)

    def _pdo_read(self, session: Session, request: Request) -> str:
        """``[net] r p N``: ``NET pdo COUNT 0xV ...`` (Lely's)."""
        net, network = self._whole_net(session, request, "a PDO request")
        if len(request.args) != 2:
            raise GatewayError(101, "r p takes the RPDO's number: r p 1")
        number = parse_number(request.args[1], "PDO number")
        values = self._pdo_table(net, network).read(number)
        return " ".join([str(net), "pdo", str(len(values)), *(f"0x{v:x}" for v in values)])

    def _pdo_write(self, session: Session, request: Request) -> None:
        """``[net] w p N COUNT V ...`` (Lely's)."""
        net, network = self._whole_net(session, request, "a PDO request")
        numbers = [parse_number(a, "PDO value") for a in request.args[1:]]
        if len(numbers) < 2 or numbers[1] != len(numbers) - 2:
            raise GatewayError(101, "w p takes the TPDO's number, how many values, the values")
        self._pdo_table(net, network).write(numbers[0], numbers[2:])

    async def _lss(self, session: Session, request: Request) -> str | None:
        """The LSS requests (CiA 305 through the network's LSS master)."""
        _net, network = self._whole_net(session, request, "an LSS request")
        lss = network.lss
        command = request.command
        numbers = [parse_number(a, command) for a in request.args]

        def want(count: int, usage: str) -> None:
            if len(numbers) != count:
                raise GatewayError(101, f"{command} takes {usage}")

        if command == "lss_switch_glob":
            want(1, "0 (waiting) or 1 (configuration)")
            if numbers[0] not in (0, 1):
                raise GatewayError(101, "lss_switch_glob takes 0 (waiting) or 1 (configuration)")
            lss.switch_global(LssState(numbers[0]))
            return None
        if command == "lss_switch_sel":
            want(4, "vendor, product, revision and serial")
            if not all(0 <= n <= 0xFFFFFFFF for n in numbers):
                raise GatewayError(101, "the identity fields are UNSIGNED32")
            await lss.select(LssIdentity(*numbers))
            return None
        if command == "lss_set_node":
            want(1, "a node-ID (1..127, or 255 to remove it)")
            if not (1 <= numbers[0] <= 127 or numbers[0] == 0xFF):
                raise GatewayError(502, f"node-ID {numbers[0]} is not 1..127 or 255")
            await lss.configure_node_id(numbers[0])
            return None
        if command == "lss_conf_bitrate":
            want(2, "table 0 and an index (0 1000, 1 800, 2 500, 3 250, 4 125, 6 50, 7 20, 8 10)")
            if numbers[0] != 0 or numbers[1] not in BIT_RATES:
                raise GatewayError(503, f"no bit timing {numbers[0]} {numbers[1]} in table 0")
            await lss.configure_bit_rate(BIT_RATES[numbers[1]])
            return None
        if command == "lss_activate_bitrate":
            want(1, "the switch delay in ms")
            if not 0 <= numbers[0] <= 0xFFFF:
                raise GatewayError(101, "the switch delay is 0..65535 ms")
            lss.activate_bit_rate(numbers[0] / 1000.0)
            return None
        if command == "lss_store":
            want(0, "no arguments")
            await lss.store()
            return None
        if command == "lss_inquire_addr":
            fields = ("vendor", "product", "revision", "serial")
            if not numbers:
                values = [await lss.inquire(what) for what in fields]
                return " ".join(f"0x{v:08X}" for v in values)
            usage = (
                "nothing (all four) or a field: 0..3 or Lely's 0x5A..0x5D (vendor, product, "
                "revision, serial)"
            )
            want(1, usage)
            field = numbers[0] - 0x5A if 0x5A <= numbers[0] <= 0x5D else numbers[0]
            if not 0 <= field <= 3:
                raise GatewayError(101, f"lss_inquire_addr takes {usage}")
            return f"0x{await lss.inquire(fields[field]):08X}"
        if command == "lss_get_node":
            want(0, "no arguments")
            return str(await lss.inquire("node_id"))
        if command == "lss_identity":  # (Lely's: is a slave in these ranges there?)
            want(6, "vendor, product, revision low and high, serial low and high")
            vendor, product, rev_low, rev_high, serial_low, serial_high = numbers
            if not await lss.identify_remote(
                vendor, product, (rev_low, rev_high), (serial_low, serial_high)
            ):
                raise GatewayError(103, "no slave of that identity answered")
            return None
        if command == "lss_ident_nonconf":  # (Lely's: is a slave without a node-ID there?)
            want(0, "no arguments")
            if not await lss.identify_unconfigured():
                raise GatewayError(103, "no slave without a node-ID answered")
            return None
        if command == "_lss_slowscan":  # (Lely's: find one slave in these ranges, select it)
            want(6, "vendor, product, revision low and high, serial low and high")
            vendor, product, rev_low, rev_high, serial_low, serial_high = numbers
            if not (rev_low <= rev_high and serial_low <= serial_high):
                raise GatewayError(101, "each range goes from its low value to its high one")
            found = await lss.slowscan(
                vendor, product, (rev_low, rev_high), (serial_low, serial_high)
            )
            if found is None:
                raise GatewayError(103, "no slave of that identity answered")
            await lss.select(found)
            return " ".join(f"0x{v:08X}" for v in found.fields)
        if command == "_lss_fastscan":
            known: dict[str, int] = {}
            if len(numbers) == 8:  # (Lely's: a value and a mask per field)
                fields = ("vendor", "product", "revision", "serial")
                for name, value, mask in zip(fields, numbers[::2], numbers[1::2], strict=True):
                    if mask == 0xFFFFFFFF:
                        known[name] = value
                    elif mask != 0:
                        raise GatewayError(
                            100,
                            f"{name} mask 0x{mask:08X}: cobus's fastscan takes a field "
                            "whole (mask 0xFFFFFFFF) or scans it (mask 0)",
                        )
                numbers = []
            if len(numbers) > 1:
                raise GatewayError(
                    101, "_lss_fastscan takes a time-out in ms at most (or Lely's eight values)"
                )
            ceiling = numbers[0] / 1000.0 if numbers else 0.5
            if not 0.001 <= ceiling <= 60:
                raise GatewayError(101, "the fastscan time-out is 1..60000 ms")
            found = await lss.fastscan(known or None, ceiling=ceiling)
            if found is None:
                raise GatewayError(103, "no device without a node-ID answered the fastscan")
            return " ".join(f"0x{v:08X}" for v in found.fields)
        raise GatewayError(100, f"no LSS command {command!r} (help lists them)")


#: How Lely names the NMT states in its error-control lines.
_STATE_WORDS = {
    NmtState.STOPPED: "ERRORx STOP",
    NmtState.OPERATIONAL: "ERRORx OPER",
    NmtState.PRE_OPERATIONAL: "ERRORx PREO",
}

#: A heartbeat is lost after this many times the period it came at.
_LOST_AFTER = 2.5


#: Who guards a node, for the network's record (AsyncNetwork.claim_guarding); the second
#: core of a process and further ones add their number.
_GUARD_OWNER = "the CiA 309-3 gateway"
_CORES = [0]  # (cores made so far)

#: The state each NMT command (its command specifier) asks a node for.
_COMMANDED = {
    0x01: NmtState.OPERATIONAL,
    0x02: NmtState.STOPPED,
    0x80: NmtState.PRE_OPERATIONAL,
    0x81: NmtState.PRE_OPERATIONAL,  # (after its boot-up)
    0x82: NmtState.PRE_OPERATIONAL,
}

#: A remote request for a node the gateway does not guard, seen this recently (s), means
#: another master guards it: ``enable guarding`` is refused.
_FOREIGN_RTR_WINDOW = 10.0


class _Guard:
    """Node guarding of one node (``enable guarding``), for the subscribed clients: a node
    lost after guard time x life time factor (``ERROR 200``), a reply in another state than
    the NMT commands on the bus asked for (``ERROR 204``), each new state. Runs as the
    network's machine; the watch counts the remote requests it sends, so that one it did
    not send (the network hands it back its own) shows another master guarding the node."""

    def __init__(self, watch: _HeartbeatWatch, node: int, guard_ms: int, factor: int) -> None:
        self.watch = watch
        self.node = node
        self.machine = GuardingMaster(node, guard_ms, factor)
        #: The state the last NMT command to the node asked for (None: the first reply's
        #: state is the one expected).
        self.expected: NmtState | None = None
        self.host: MachineHost | None = None
        #: The heartbeat time a client gave the node before (enable heartbeat), put back
        #: when guarding stops.
        self.heartbeat: float | None = None
        #: Where the guard it replaces stopped: (its state, the next toggle bit).
        self.carried: tuple[NmtState | None, int] | None = None
        self._told = False  # (a state line went out for the reply just fed)

    @property
    def deadline(self) -> float | None:
        return self.machine.deadline

    def start(self, now: float) -> Out:
        out = self.machine.start(now)
        if self.carried is not None:
            self.machine.carry_on(*self.carried)
        self.watch.owe(self.node, len(out.frames))
        return out

    def on_timer(self, now: float) -> Out:
        out = self.machine.on_timer(now)
        self.watch.owe(self.node, len(out.frames))
        return out

    def on_frame(self, frame: Frame, now: float) -> Out:
        self._told = False
        return self.machine.on_frame(frame, now)

    def stop(self, why: str | None = None) -> None:
        """Stop guarding (``why``: the subscribed clients are told, as a lost guarding)."""
        watch = self.watch
        if watch.guards.get(self.node) is self:
            del watch.guards[self.node]
        if self.host is not None:
            self.host.close()
            self.host = None
            watch.network.release_guarding(self.node, watch._core.guard_owner)
            watch.heartbeat_again(self.node, self.heartbeat)
        if why is not None:
            line = "ERROR 200 (Lost guarding message)"
            if watch._core.dialect != "lely":  # (Lely's clients read its exact form)
                line += f" #{why}: guarding stopped"
            self._line(line)

    def _line(self, text: str) -> None:
        self.watch._core._tell("error_control", f"{self.watch.net} {self.node} {text}")

    def on_event(self, event: Event) -> None:
        if isinstance(event, GuardingNodeLost):
            self._line("ERROR 200 (Lost guarding message)")
        elif isinstance(event, GuardingStateChanged) and event.new is not NmtState.INITIALISING:
            expected = self.expected
            if expected is None:
                self.expected = event.new
            elif event.new is not expected:
                self._line("ERROR 204 (Wrong NMT state)")
            self._line(_STATE_WORDS.get(event.new, "ERROR"))
            self._told = True
        elif isinstance(event, GuardingResumed) and not self._told:
            self._line(_STATE_WORDS.get(event.state, "ERROR"))


class _HeartbeatWatch:
    """The heartbeats of one net, for the subscribed clients: boot-ups, a heartbeat started
    (202) or lost (203), a new NMT state. The gateway is told no consumer times: it learns
    each node's period from the beats it sees (the median of the last three intervals).
    Nodes a client asked to guard go to their :class:`_Guard` instead."""

    def __init__(self, core: GatewayCore, net: int) -> None:
        self._core = core
        self._net = net
        #: The net it watches.
        self.net = net
        #: Nodes watched with a time a client gave (0: not watched), not a learned one.
        self.fixed: dict[int, float] = {}
        self.monitor = HeartbeatMonitor(track_all=True)
        self.host: MachineHost | None = None
        self.network = core.networks[net]
        #: The nodes guarded (enable guarding), by node-ID.
        self.guards: dict[int, _Guard] = {}
        self._last: dict[int, float] = {}
        self._intervals: dict[int, list[float]] = {}
        #: When a remote request for a node not guarded here last went by.
        self._foreign: dict[int, float] = {}
        #: When each node's last error control message (not a request) went by.
        self._seen: dict[int, float] = {}
        #: Remote requests the gateway sent per node whose echo has not come back yet.
        self._owed: dict[int, int] = {}
        #: The gateway's own node-ID on the net (``set id``): not watched.
        self.own: int | None = None

    def heard(self, node: int) -> str | None:
        """What shows ``node`` on the net lately (None: nothing seen)."""
        now = self._now()
        if node in self.guards:
            return "the gateway guards it"
        last = self._seen.get(node)
        if last is not None and now - last < _FOREIGN_RTR_WINDOW:
            return f"its error control message came {now - last:.1f} s ago"
        owner = self.network.guarding_owner(node)
        if owner is not None:
            return f"{owner} guards it"
        seen = self._foreign.get(node)
        if seen is not None and now - seen < _FOREIGN_RTR_WINDOW:
            return f"a master guards it: a remote request went by {now - seen:.1f} s ago"
        return None

    def close(self) -> None:
        for guard in list(self.guards.values()):
            guard.stop()
        if self.host is not None:
            self.host.close()
            self.host = None

    def guard(self, node: int, guard_ms: int, factor: int) -> None:
        """Guard ``node`` (again, with these times, if it is already)."""
        old = self.guards.get(node)
        now = self._now()
        if old is None:
            seen = self._foreign.get(node)
            if seen is not None and now - seen < _FOREIGN_RTR_WINDOW:
                raise GatewayError(
                    102,
                    f"node {node} is guarded by another master (its remote requests went by "
                    f"{now - seen:.1f} s ago): one guarding master per node",
                )
        guard = _Guard(self, node, guard_ms, factor)
        if old is not None:
            guard.expected = old.expected
            guard.heartbeat = old.heartbeat
            guard.carried = (old.machine.state, old.machine.next_toggle)
            old.stop()
        else:
            guard.heartbeat = self.fixed.get(node)
        owner = self.network.claim_guarding(
            node,
            self._core.guard_owner,
            on_taken=lambda who: guard.stop(f"{who} guards it now"),
        )
        if owner is not None:
            self.heartbeat_again(node, guard.heartbeat)
            raise GatewayError(102, f"node {node} is guarded by {owner}: one guarding master")
        self.guards[node] = guard
        self.fix(node, 0.0)  # (its replies are no heartbeats)
        guard.host = self.network.attach(guard, on_event=guard.on_event)
        guard.host.run(guard.start)

    def unguard(self, node: int) -> None:
        """Stop guarding ``node`` (nothing if it is not)."""
        guard = self.guards.get(node)
        if guard is not None:
            guard.stop()

    def heartbeat_again(self, node: int, timeout: float | None) -> None:
        """Guarding of ``node`` stopped: watch its heartbeat again, with the time a client
        gave before (None: the period learned)."""
        if timeout is not None:
            self.fix(node, timeout)
        else:
            self.fixed.pop(node, None)

    def owe(self, node: int, count: int) -> None:
        """The gateway sent ``count`` remote requests for ``node``: their echoes are its."""
        if count:
            self._owed[node] = self._owed.get(node, 0) + count

    def on_nmt(self, frame: Frame, now: float) -> None:
        """An NMT command on the bus (the gateway's, a master's): the state a guarded node
        should report from now on."""
        data = frame.data
        if frame.rtr or len(data) != 2 or data[0] not in _COMMANDED:
            return
        for node, guard in self.guards.items():
            if data[1] in (0, node):
                guard.expected = _COMMANDED[data[0]]

    def on_frame(self, frame: Frame, now: float) -> None:
        node = frame.cob_id - ERROR_CONTROL_BASE
        if self.host is None or node == self.own:
            return
        guard = self.guards.get(node)
        if frame.rtr:
            owed = self._owed.get(node, 0)
            if owed:
                self._owed[node] = owed - 1  # (the network hands back the requests it sends)
                return
            self._foreign[node] = now
            if guard is not None:
                guard.stop(
                    f"a remote request for node {node} the gateway did not send: another "
                    "master guards it"
                )
            return
        self._seen[node] = now
        if guard is not None and guard.host is not None:
            guard.host.feed(frame, now)
            if frame.data != b"\x00":
                return  # (a guarding reply; a boot-up is the heartbeat watch's too)
        elif frame.data != b"\x00":
            asked = self._foreign.get(node)
            if (
                asked is not None and now - asked < _FOREIGN_RTR_WINDOW
            ) or self.network.guarding_owner(node) is not None:
                return  # (another master guards it: a reply, no heartbeat)
        if len(frame.data) != 1:
            return
        state = frame.data[0] & 0x7F
        last = self._last.get(node)
        if state == 0 or self.monitor.is_lost(node):  # (boot-up, a loss: learn anew)
            self._intervals.pop(node, None)
            last = None
        self._last[node] = now
        if last is not None and now > last and node not in self.fixed:
            seen = self._intervals.setdefault(node, [])
            seen.append(now - last)
            del seen[:-3]
            if len(seen) >= 2:
                period = sorted(seen)[len(seen) // 2]
                timeout = max(0.05, _LOST_AFTER * period)
                if abs(self.monitor.timeout(node) - timeout) > 0.2 * timeout:
                    self.monitor.watch(node, timeout, now)
        self.host.feed(frame, now)

    def fix(self, node: int, timeout: float) -> None:
        """Watch ``node`` with ``timeout`` seconds from now on (0: not at all)."""
        self.fixed[node] = timeout
        self._intervals.pop(node, None)
        self.monitor.watch(node, timeout, self._now())
        if self.host is not None:
            self.host.apply(NOTHING)  # (its deadline armed)

    def _now(self) -> float:
        return self._core.networks[self._net].time()

    def on_event(self, event: Event) -> None:
        tell, net = self._core._tell, self._net
        if isinstance(event, BootupReceived):
            self._last.pop(event.node_id, None)
            tell("boot_up", f"{net} {event.node_id} BOOT_UP")
        elif isinstance(event, HeartbeatTimeout):
            self._last.pop(event.node_id, None)
            word = _STATE_WORDS.get(self.monitor.state(event.node_id), "ERROR")  # type: ignore[arg-type]
            tell("error_control", f"{net} {event.node_id} {word} 203 (Heartbeat lost)")
        elif isinstance(event, HeartbeatResumed):
            word = _STATE_WORDS.get(event.state, "ERROR")
            tell("error_control", f"{net} {event.node_id} {word} 202 (Heartbeat started)")
        elif isinstance(event, RemoteStateChanged) and event.new is not NmtState.INITIALISING:
            word = _STATE_WORDS.get(event.new, "ERROR")
            if event.old in (None, NmtState.INITIALISING):
                tell("error_control", f"{net} {event.node_id} {word} 202 (Heartbeat started)")
            else:
                tell("error_control", f"{net} {event.node_id} {word}")


def _version() -> tuple[int, int]:
    parts = [int(p) if p.isdigit() else 0 for p in cobus.__version__.split(".")[:2]]
    major, minor = [*parts, 0, 0][:2]
    return major, minor


def _device_dictionary() -> ObjectDictionary:
    """The objects of the gateway's own device (``set id``): CiA 301's communication
    objects, no PDOs (the gateway's PDOs are ``set rpdo``'s), its version as the revision."""
    major, minor = _version()
    return minimal_od(
        revision=major << 16 | minor,
        device_name="cobus CiA 309-3 gateway",
        software_version=f"cobus {cobus.__version__}",
        rpdos=0,
        tpdos=0,
    )


def _version_line() -> str:
    """``info version`` as Lely answers it: the gateway's identity (cobus has none of its
    own: vendor, product and serial 0, its version as the revision), gateway class 3 (it
    sends NMT commands), CiA 309-1 version 2.0, the implementation's version."""
    major, minor = _version()
    return f"0 0 {major}.{minor} 0 3 2.0 {major}.{minor}"


def version_fields() -> dict[str, str]:
    """``info version`` as gocanopen's HTTP gateway answers it (the same facts as
    :func:`_version_line`)."""
    major, minor = _version()
    return {
        "VendorId": "0x0",
        "ProductCode": "0x0",
        "RevisionNumber": f"0x{(major << 16) | minor:x}",
        "SerialNumber": "0x0",
        "GatewayClass": "3",
        "ProtocolVersion": "02.00",
        "ImplementationClass": f"{major:02d}.{minor:02d}",
    }


def _number_or_none(word: str) -> int | None:
    try:
        return parse_number(word)
    except GatewayError:
        return None
