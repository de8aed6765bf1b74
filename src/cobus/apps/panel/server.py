"""The panel's web server: aiohttp inside the running asyncio loop, one WebSocket per page.

:class:`Panel` serves the static pages (package data, no build step, no CDN: every response
says ``Content-Security-Policy: default-src 'self'``) and ``/ws``, over which a page gets

- ``{"type": "snapshot", "seq", "state", "events", "series", "info"}`` when it connects, after
  it fell behind, or when it asks (``{"cmd": "resync"}``, sent by a page that sees a gap in the
  event numbers);
- ``{"type": "delta", "values": {key: latest}}`` at most ``rate`` times a second;
- ``{"type": "event", "seq", "time", "kind", ...}`` for each event, numbered, never conflated;
- ``{"type": "ack", "id", "result"}`` or ``{"type": "error", "id", "code", "text"}`` for
  each command ``{"id": ..., "cmd": NAME, ...arguments, "token": ...}`` it sends.

A WebSocket message carries one of these, or a JSON array of several in the order they were
queued: what gathered since the last send goes out as one message, at most ``ROUNDS`` times
a second, so that a burst of events (an EMCY storm) costs the bus loop and the browser a few
messages rather than one each.

Safety: it binds 127.0.0.1 unless told otherwise. Bound anywhere else (or with ``token=``
given), every command that writes to the bus needs the token printed at start, and so does
reading the panel (``/ws?token=``, the CSV export: the state of the plant, its alarms, the
bus decoded) unless ``open_reads`` lets a view-only screen in without it. The static files
(no data in them) and the Unix socket (0600: this user only) need none. A request
whose ``Host`` is not a loopback name while bound to loopback (DNS rebinding) and a WebSocket
opened from another origin (another site in the same browser) are refused. Commands are
checked here, each failure answered with a typed error and a text; a malformed message never
ends the connection, and nothing a client does (or fails to do) reaches the bus uninvited:
each client has a bounded queue (:mod:`cobus.apps.panel.hub`) and one stuck for ``stall``
seconds is dropped.

It runs in the caller's loop (``await panel.start()``): no thread, no second loop, no signal
handlers of its own.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import secrets
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlsplit

from aiohttp import WSMsgType, web

from cobus._moved import renamed_names
from cobus.apps._serving import MIN_TOKEN, free_unix_path, is_loopback, token_is
from cobus.apps.panel.hub import Client, Hub, _clean
from cobus.errors import CobusError, clip

__all__ = ["CommandError", "Panel", "PanelCommand", "PanelError"]

log = logging.getLogger(__name__)

STATIC = Path(__file__).with_name("static")
#: The largest message a page may send (a command is a few hundred bytes).
MAX_MESSAGE = 64 * 1024
#: Commands of one page still running; more are answered "busy".
MAX_PENDING = 16
#: Replies a page has not taken before it counts as not reading (it is dropped).
MAX_REPLIES = 256
#: Messages to one page a second at most (each carries what gathered since the last).
ROUNDS = 50.0
#: Pages connected at once; more are refused (each costs the bus loop some work per tick).
MAX_CLIENTS = 32
CSP = (
    "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'; base-uri 'none'; "
    "form-action 'none'"
)


class PanelError(CobusError):
    """The panel cannot start (address in use, bad address...)."""


class CommandError(CobusError):
    """A command refused or failed: ``code`` for programs, the text for people."""

    def __init__(self, code: str, text: str) -> None:
        super().__init__(text)
        self.code = code
        self.text = text


Handler = Callable[[Mapping[str, Any]], Awaitable[Any]]


@dataclass(frozen=True)
class PanelCommand:
    """A command pages may send: its handler, and whether it writes to the bus."""

    name: str
    handler: Handler
    writes: bool
    help: str = ""


class Panel:
    """The operator panel's server (see the module text).

    ``port`` 0 takes a free port (:attr:`url` then tells which); ``unix`` also serves on a
    Unix socket at that path. ``token``: the token writes need (default: a random one, needed
    only when ``host`` is not loopback; given, it is always needed); reads need it too
    unless ``open_reads``. ``rate``: deltas per second at most. ``clock``: the time events
    carry (the network's, for a master)."""

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 8047,
        unix: str | None = None,
        token: str | None = None,
        rate: float = 10.0,
        stall: float = 5.0,
        max_events: int = 500,
        clock: Callable[[], float] | None = None,
        title: str = "cobus",
        open_reads: bool = False,
    ) -> None:
        if not 0 <= port <= 65535:
            raise PanelError(f"port {port}: give 0-65535 (0: any free port)")
        if not rate > 0:
            raise PanelError(f"rate {rate}: give a positive number of updates per second")
        self.host = host
        self.port = port
        self.unix = unix
        self.rate = rate
        if token is not None and len(token) < MIN_TOKEN:
            raise PanelError(f"a token of {MIN_TOKEN} characters at least (or none: a random one)")
        self.needs_token = token is not None or not is_loopback(host)
        self.token = token if token is not None else secrets.token_urlsafe(18)
        #: Whether reading the panel (its WebSocket, the CSV export) needs the token too.
        self.reads_need_token = self.needs_token and not open_reads
        self._clock = clock
        self.hub = Hub(self._now, max_events=max_events, stall=stall)
        self.hub.info.update({"title": title, "needs_token": self.needs_token})
        self.hub.before_snapshot = self._sample
        self.commands: dict[str, PanelCommand] = {}
        #: What the views keep on the panel (the drives' command router...), by name.
        self.views: dict[str, Any] = {}
        self._samplers: list[Callable[[], Mapping[str, Any]]] = []
        self._routes: list[tuple[str, str, Any]] = []
        self._runner: web.AppRunner | None = None
        self._ticker: asyncio.Task[None] | None = None
        #: The open WebSockets, each with what cuts its connection off.
        self._sockets: dict[web.WebSocketResponse, Callable[[], None]] = {}
        self.bound: tuple[str, int] | None = None

    def _now(self) -> float:
        if self._clock is not None:
            return self._clock()
        return asyncio.get_running_loop().time()

    # ------------------------------------------------------------------ extension
    def command(self, name: str, handler: Handler, *, writes: bool, help: str = "") -> None:
        """Let pages send ``{"cmd": name, ...}``; ``handler(message)`` answers it (its return
        value is the ack's result) or raises :class:`CommandError` / ``ValueError``."""
        if name in self.commands or name == "resync":
            raise ValueError(f"the panel already has a command {name!r}")
        self.commands[name] = PanelCommand(name, handler, writes, help)

    def route(
        self,
        method: str,
        path: str,
        handler: Callable[[web.Request], Awaitable[web.StreamResponse]],
    ) -> None:
        """Serve ``path`` (read-only things: a CSV export...) with ``handler``; before
        :meth:`start`. It gets the same Host check and headers as every page."""
        if self._runner is not None:
            raise PanelError(f"add {path} before the panel starts")
        self._routes.append((method, path, handler))

    def sample(self, sampler: Callable[[], Mapping[str, Any]]) -> None:
        """Call ``sampler`` ``rate`` times a second; the keys it returns update the state."""
        self._samplers.append(sampler)

    # ------------------------------------------------------------------ life cycle
    @property
    def url(self) -> str:
        """The page's address (with the token when writes need one)."""
        if self.bound is None:
            raise PanelError("the panel is not started")
        host, port = self.bound
        shown = f"[{host}]" if ":" in host else host
        query = f"?token={quote(self.token, safe='')}" if self.needs_token else ""
        return f"http://{shown}:{port}/{query}"

    def app(self) -> web.Application:
        """The aiohttp application (the server's routes; tests serve it themselves)."""
        app = web.Application(middlewares=[self._guard], client_max_size=MAX_MESSAGE)
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_static("/static/", STATIC, follow_symlinks=False)
        for method, path, handler in self._routes:
            app.router.add_route(method, path, handler)
        app.on_shutdown.append(self._close_sockets)
        return app

    async def start(self) -> None:
        """Serve in the running loop; :class:`PanelError` if the address cannot be bound."""
        if self.unix is not None:
            refused = free_unix_path(self.unix)
            if refused is not None:
                raise PanelError(f"cannot serve the panel on {self.unix}: {refused}")
        runner = web.AppRunner(self.app(), handle_signals=False, access_log=None)
        await runner.setup()
        where = f"{self.host}:{self.port}"
        try:
            site = web.TCPSite(runner, self.host, self.port)
            await site.start()
            if self.unix is not None:
                where = self.unix
                await web.UnixSite(runner, self.unix).start()
                os.chmod(self.unix, 0o600)  # this user's only: it needs no token
        except OSError as exc:
            await runner.cleanup()
            advice = (
                "give a path in a folder that exists and you may write to"
                if where == self.unix
                else "give another --listen address, or port 0 for any free one"
            )
            raise PanelError(
                f"cannot serve the panel on {where}: {exc.strerror or exc} ({advice})"
            ) from None
        port = next((a[1] for a in runner.addresses if isinstance(a, tuple)), self.port)
        self.bound = (self.host, int(port))
        self._runner = runner
        self._ticker = asyncio.create_task(self._tick(), name="cobus panel ticker")

    async def stop(self) -> None:
        """Close every page's connection and stop serving."""
        if self._ticker is not None:
            self._ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._ticker
            self._ticker = None
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
            if self.unix is not None:
                with contextlib.suppress(OSError):
                    os.unlink(self.unix)

    async def __aenter__(self) -> Panel:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    def refresh(self) -> None:
        """Take a sample now (the ticker does so ``rate`` times a second) and drop the
        clients that stalled."""
        self._sample()
        self.hub.check()

    def _sample(self) -> None:
        for sampler in self._samplers:
            try:
                values = sampler()
            except Exception:
                log.exception("a panel sampler failed")
                continue
            self.hub.update(values)

    async def _tick(self) -> None:
        while True:
            self.refresh()
            await asyncio.sleep(1.0 / self.rate)

    async def _close_sockets(self, _app: web.Application) -> None:
        async def close(ws: web.WebSocketResponse) -> None:
            try:
                await asyncio.wait_for(ws.close(code=1001, message=b"the panel stops"), 1.0)
            except Exception:  # (a page that does not read: cut it off)
                with contextlib.suppress(Exception):
                    self._sockets.get(ws, _nothing)()

        await asyncio.gather(*(close(ws) for ws in list(self._sockets)))

    # ------------------------------------------------------------------ HTTP
    @web.middleware
    async def _guard(
        self, request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
    ) -> web.StreamResponse:
        host = urlsplit("//" + request.host).hostname or ""
        unix = isinstance(request.transport and request.transport.get_extra_info("sockname"), str)
        if not unix and is_loopback(self.host) and not is_loopback(host):
            return _refused(
                421, f"this panel answers to 127.0.0.1 or localhost only, not {clip(host)}"
            )
        if (
            self.reads_need_token
            and not unix
            and request.path != "/"
            and not request.path.startswith("/static/")
            and not self._token_is(request.query.get("token"))
        ):
            return _refused(
                401,
                "this panel needs its token to be read: open the address it printed at start "
                "(with ?token=...)",
            )
        try:
            response = await handler(request)
        except web.HTTPException as exc:
            _secure(exc.headers)
            raise
        _secure(response.headers)
        return response

    async def _index(self, _request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html")

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc != request.host:
            return _refused(403, f"a page from {clip(origin)} may not use this panel")
        if len(self.hub.clients) >= MAX_CLIENTS:
            return _refused(503, f"{MAX_CLIENTS} pages are open on this panel already")
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=20.0)
        await ws.prepare(request)
        client = self.hub.connect()
        transport = request.transport
        client.abort = transport.abort if transport is not None else _nothing
        self._sockets[ws] = client.abort
        sender = asyncio.create_task(self._send(ws, client), name=f"cobus panel {client.name}")
        pending: set[asyncio.Task[None]] = set()
        try:
            async for msg in ws:
                if msg.type is WSMsgType.TEXT:
                    self._receive(client, msg.data, pending)
                elif msg.type is WSMsgType.BINARY:
                    client.reply(_error(None, "malformed", "send commands as JSON text"))
                if len(client.replies) > MAX_REPLIES:
                    client.close("it sends commands but does not read the answers")
                if client.closed:
                    break
        finally:
            client.close(client.closed or "disconnected")
            self._sockets.pop(ws, None)
            for task in pending:
                task.cancel()
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
            if not ws.closed:
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(ws.close(code=1008, message=client.closed.encode()), 1)
        return ws

    async def _send(self, ws: web.WebSocketResponse, client: Client) -> None:
        period = 1.0 / self.rate
        last_delta = -period
        loop = asyncio.get_running_loop()
        try:
            while True:
                await client.ready.wait()
                if client.closed:
                    break
                batch = client.messages()
                if client.values and loop.time() >= last_delta + period:
                    last_delta = loop.time()
                    batch.append(client.delta())
                if batch:
                    await self._put(ws, client, batch[0] if len(batch) == 1 else batch)
                    await asyncio.sleep(1.0 / ROUNDS)  # (what comes meanwhile goes together)
                elif client.values:
                    await asyncio.sleep(last_delta + period - loop.time())
        except (ConnectionError, RuntimeError):
            client.close("connection lost")

    async def _put(self, ws: web.WebSocketResponse, client: Client, message: Any) -> None:
        client.sending_since = self.hub.clock()
        try:
            await ws.send_str(_json(message))
        finally:
            client.sending_since = None

    def _token_is(self, given: Any) -> bool:
        """Whether ``given`` is the panel's token (compared in constant time)."""
        return token_is(given, self.token)

    # ------------------------------------------------------------------ commands
    def _receive(self, client: Client, text: str, pending: set[asyncio.Task[None]]) -> None:
        try:
            self._take(client, text, pending)
        except Exception as exc:  # (whatever a page sends, the connection stays)
            client.reply(_error(None, "malformed", f"cannot take that message: {clip(str(exc))}"))

    def _take(self, client: Client, text: str, pending: set[asyncio.Task[None]]) -> None:
        try:
            message = json.loads(text)
        except (ValueError, RecursionError) as exc:
            client.reply(_error(None, "malformed", f"not JSON: {clip(str(exc))}"))
            return
        if not isinstance(message, dict):
            client.reply(_error(None, "malformed", 'send a JSON object: {"id": 1, "cmd": ...}'))
            return
        ident = message.get("id")
        if ident is not None and not (
            isinstance(ident, int | str) and not isinstance(ident, bool) and len(str(ident)) <= 64
        ):
            client.reply(_error(None, "malformed", "id: a number or a text of up to 64 characters"))
            return
        name = message.get("cmd")
        if name == "resync":
            client.resync = True
            client.ready.set()
            return
        command = self.commands.get(name) if isinstance(name, str) else None
        if command is None:
            known = ", ".join(sorted([*self.commands, "resync"]))
            client.reply(
                _error(ident, "unknown-command", f"cmd {clip(repr(name))}: one of {known}")
            )
            return
        # (a view-only screen let in without the token watches: it asks nothing of the bus)
        asks = command.writes or not self.reads_need_token
        if asks and self.needs_token and not self._token_is(message.get("token")):
            client.reply(
                _error(
                    ident,
                    "token",
                    f"{name} {'writes to' if command.writes else 'asks'} the bus: send the "
                    'panel\'s token with it ("token": ...; the page does so when opened by '
                    "the address the panel printed)",
                )
            )
            return
        if len(pending) >= MAX_PENDING:
            client.reply(
                _error(ident, "busy", f"{MAX_PENDING} commands are still running: wait for one")
            )
            return
        task = asyncio.create_task(self._run(client, command, ident, message))
        pending.add(task)
        task.add_done_callback(pending.discard)

    async def _run(
        self, client: Client, command: PanelCommand, ident: Any, message: Mapping[str, Any]
    ) -> None:
        try:
            result = await command.handler(message)
        except CommandError as exc:
            reply = _error(ident, exc.code, exc.text)
        except (ValueError, OverflowError) as exc:
            reply = _error(ident, "bad-argument", f"{command.name}: {clip(str(exc))}")
        except CobusError as exc:
            reply = _error(ident, "failed", f"{command.name}: {exc}")
        except TimeoutError as exc:
            reply = _error(ident, "timeout", f"{command.name}: {exc or 'no answer in time'}")
        except Exception as exc:
            log.exception("panel command %s failed", command.name)
            reply = _error(ident, "internal", f"{command.name} failed: {type(exc).__name__}: {exc}")
        else:
            reply = {"type": "ack", "id": ident, "result": result}
        client.reply(reply)


def _json(message: Any) -> str:
    """``message`` as JSON text; NaN and infinities (which JSON has not) as null."""
    try:
        return json.dumps(message, separators=(",", ":"), default=str, allow_nan=False)
    except ValueError:
        return json.dumps(_clean(message), separators=(",", ":"), default=str, allow_nan=False)


def _nothing() -> None:
    pass


def _secure(headers: Any) -> None:
    """The headers every answer carries: nothing but this server's files (works offline),
    no framing, no sniffing, no referrer."""
    headers["Content-Security-Policy"] = CSP
    headers["X-Content-Type-Options"] = "nosniff"
    headers["Referrer-Policy"] = "no-referrer"
    headers["Cache-Control"] = "no-cache"


def _error(ident: Any, code: str, text: str) -> dict[str, Any]:
    return {"type": "error", "id": ident, "code": code, "text": text}


def _refused(status: int, text: str) -> web.Response:
    return web.Response(status=status, text=text + "\n")


# (renamed: cobus.profiles.Command is the CiA 402 controlword command)
__getattr__ = renamed_names(__name__, {"Command": ("PanelCommand", PanelCommand)})
