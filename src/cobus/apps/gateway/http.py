"""The gateway over HTTP, CiA 309-5 style, in the URL scheme gocanopen's HTTP gateway and
client use, plus a WebSocket of the unsolicited lines.

``/cia309-5/1.0/SEQ/NET/NODE/COMMAND...`` (NET and NODE decimal, ``0x`` hex, or
``default``/``none`` for the gateway's defaults, ``all`` for every node of an NMT command):

- ``r/INDEX/SUB`` (GET) → ``{"sequence": "1", "response": "OK", "data": "0x5432",
  "length": 2}``: the bytes, most significant first, as gocanopen answers; with
  ``?datatype=u16`` (or ``"datatype"`` in a JSON body) ``"value"`` holds it as that type.
- ``w/INDEX/SUB`` (PUT) with ``{"value": "0x5432", "datatype": "i16"}``.
- ``start``, ``stop``, ``preop``, ``reset/node``, ``reset/comm`` (PUT); ``set/network``,
  ``set/node``, ``set/sdo-timeout`` with ``{"value": ...}``; ``info/version`` (GET).
- Any other request of the command language as ``/cia309-5/1.0/SEQ/NET/NODE/COMMAND/ARG...``
  (``lss_get_node``, ``r/p/1``...).

Every answer is HTTP 200 with a JSON body (gocanopen's client reads only the body);
``"response"`` is ``OK`` or ``ERROR:<code>`` (an SDO abort as ``ERROR:0x<8 hex>``, where
gocanopen's own gateway says 102), with ``"text"`` saying why. ``/cia309-5/1.0/events`` is
a WebSocket that sends ``{"event": "1 5 BOOT_UP"}`` for every unsolicited line.

Like the TCP server it binds 127.0.0.1 unless told otherwise; with a token (the core's),
writes, NMT, LSS and every ``set`` need ``Authorization: Bearer TOKEN``. Each request runs
in a session of its own; ``set/network``, ``set/node``, ``set/sdo-timeout`` and
``set/sdo_block`` change the defaults of every later HTTP request. A web page cannot use
it: GET only reads, a request from another Origin (or, on loopback, another Host) is
refused.
"""

from __future__ import annotations

import asyncio
import json
import re
from typing import Any

from aiohttp import WSMsgType, web

from cobus.apps._serving import is_loopback, token_is
from cobus.apps.gateway.client import reply_of
from cobus.apps.gateway.core import NODE_COMMANDS, GatewayCore, Session, version_fields

__all__ = ["GatewayHttp"]

_PATH = re.compile(
    r"/cia309-5/(?P<api>[^/]+)/(?P<seq>[0-9]{1,10})/(?P<net>[^/]+)/(?P<node>[^/]+)/(?P<cmd>.+)\Z"
)
_NUMBER = re.compile(r"(0x[0-9a-fA-F]{1,8}|[0-9]{1,10})\Z")
#: What a wrong Authorization costs (seconds; one at a time for the whole server).
_WRONG_TOKEN_WAIT = 1.0
#: Event lines a WebSocket may have waiting to be sent before more are dropped.
_UNSENT_LIMIT = 256


class GatewayHttp:
    """Serves ``core`` over HTTP on ``host``:``port`` (0: a free one, see :attr:`port`)."""

    def __init__(self, core: GatewayCore, host: str = "127.0.0.1", port: int = 0) -> None:
        if not is_loopback(host) and core.token is None:
            raise ValueError(
                f"the gateway writes to the bus: to serve {host!r} over HTTP (not only this "
                "host) give the core a token"
            )
        self.core = core
        self._holding = False  # (it holds the core: start, stop)
        self.host = host
        self.requested_port = port
        self._runner: web.AppRunner | None = None
        self._bound: int | None = None
        #: The defaults of every HTTP request (set network, set node, set sdo-timeout).
        self.defaults = Session(net=core.default_net)
        self._sockets: set[web.WebSocketResponse] = set()
        self._guessing = asyncio.Lock()

    @property
    def port(self) -> int:
        """The port it listens on (once started)."""
        return self._bound if self._bound is not None else self.requested_port

    @property
    def address(self) -> str:
        """``http://HOST:PORT``."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    async def start(self) -> None:
        """Listen on the running loop; OSError when the address cannot be bound (the core
        then released again). The core watches the buses from now on. Started already:
        nothing more."""
        if self._runner is not None:
            return
        took = not self._holding
        if took:
            self.core.hold()
            self._holding = True
        try:
            await self._serve_http()
        except BaseException:
            if took:  # (a bind that failed leaves the core as it found it)
                self._holding = False
                self.core.release()
            raise

    async def _serve_http(self) -> None:
        app = web.Application(client_max_size=64 * 1024)
        app.router.add_route("GET", "/cia309-5/{api}/events", self._events)
        app.router.add_route("*", "/{tail:.*}", self._handle)
        runner = web.AppRunner(app, handle_signals=False, access_log=None)
        await runner.setup()
        try:
            await web.TCPSite(runner, self.host, self.requested_port).start()
        except OSError:
            await runner.cleanup()
            raise
        self._bound = next(
            (int(a[1]) for a in runner.addresses if isinstance(a, tuple)), self.requested_port
        )
        self._runner = runner

    async def stop(self) -> None:
        """Close the WebSockets and stop serving."""
        for ws in list(self._sockets):
            await ws.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        if self._holding:  # (the core closes once no server serves it)
            self._holding = False
            self.core.release()

    # ------------------------------------------------------------------ requests

    def _authorised(self, request: web.Request) -> bool:
        if self.core.token is None:
            return True
        given = request.headers.get("Authorization", "")
        scheme, _, token = given.partition(" ")
        return scheme.lower() == "bearer" and token_is(token.strip(), self.core.token)

    async def _checked(self, request: web.Request) -> bool:
        """Whether the request is authorised; a wrong token costs a second, one wrong
        token at a time for the whole server (guessing gets nowhere, requests side by
        side or not)."""
        if self._authorised(request):
            return True
        if request.headers.get("Authorization"):
            async with self._guessing:
                await asyncio.sleep(_WRONG_TOKEN_WAIT)
        return False

    def _foreign(self, request: web.Request) -> str | None:
        """Why a request that a web page may have sent is refused (None: it is not): an
        Origin other than this server, or, served on this host only, a Host header that
        names another (DNS rebinding)."""
        host = request.host
        origin = request.headers.get("Origin")
        if origin is not None and origin not in (f"http://{host}", f"https://{host}"):
            return f"a request from the web page of {origin} is refused"
        if is_loopback(self.host):
            try:
                name, port = request.url.host or "", request.url.port
            except ValueError:
                name, port = "", None
            if not is_loopback(name) or (port is not None and port != self.port):
                return f"Host {host}: this gateway serves {self.address} only"
        return None

    async def _handle(self, request: web.Request) -> web.Response:
        try:
            return await self._answer(request)
        except Exception as exc:  # (never a 500 page: the client reads JSON)
            seq = _PATH.match(request.path)
            return _answer(seq.group("seq") if seq else "0", "ERROR:102", f"internal: {exc!r}")

    async def _answer(self, request: web.Request) -> web.Response:
        match = _PATH.match(request.path)
        seq = match.group("seq") if match else "0"
        if match is None:
            return _answer(seq, "ERROR:101", "give /cia309-5/1.0/SEQ/NET/NODE/COMMAND")
        if match.group("api") != "1.0":
            return _answer(seq, "ERROR:100", f"API version {match.group('api')}: 1.0 only")
        foreign = self._foreign(request)
        if foreign is not None:
            return _answer(seq, "ERROR:102", foreign)
        words = match.group("cmd").strip("/").split("/")
        words[0] = words[0].lower()
        reading = words[0] in ("r", "read", "info") and words[1:2] not in (["p"], ["pdo"])
        # (a web page can send GET and a form's POST to any site: they change nothing here)
        json_post = request.method == "POST" and request.content_type == "application/json"
        if not (request.method == "PUT" or json_post or (reading and request.method == "GET")):
            return _answer(
                seq, "ERROR:100", f"{request.method}: GET reads, PUT (or a JSON POST) the rest"
            )
        try:
            raw = await request.read()
            body: Any = json.loads(raw) if raw.strip() else {}
        except ValueError:
            return _answer(seq, "ERROR:101", "the body is no JSON")
        if not isinstance(body, dict):
            return _answer(seq, "ERROR:101", 'the body is a JSON object: {"value": ...}')
        try:
            line, type_name = self._line(
                seq,
                match.group("net"),
                match.group("node"),
                words,
                body,
                request.query.get("datatype"),
            )
        except ValueError as exc:
            return _answer(seq, "ERROR:101", str(exc))
        if line is None:  # (info version)
            return web.json_response({"sequence": seq, "response": "OK", **version_fields()})
        authorised = await self._checked(request)
        if words[0] == "set" and not authorised:
            return _answer(seq, "ERROR:102", "set changes every HTTP client's defaults: it "
                           "needs Authorization: Bearer TOKEN")  # fmt: skip
        session = self.core.session(trusted=authorised)
        session.net, session.node = self.defaults.net, self.defaults.node
        session.sdo_timeout, session.peer = self.defaults.sdo_timeout, "http"
        session.sdo_block = self.defaults.sdo_block
        try:
            lines = await self.core.execute(session, line)
        finally:
            self.core.forget(session)
        reply = reply_of(line, lines)
        if not reply.ok:
            code = reply.code or 0
            shown = f"0x{code:08X}" if code > 0xFFFF else str(code)
            return _answer(seq, f"ERROR:{shown}", reply.text)
        if words[0] == "set":
            self.defaults.net, self.defaults.node = session.net, session.node
            self.defaults.sdo_timeout = session.sdo_timeout
            self.defaults.sdo_block = session.sdo_block
        out: dict[str, Any] = {"sequence": seq, "response": "OK"}
        if words[0] in ("r", "read") and words[1:2] not in (["p"], ["pdo"]):
            if type_name is None:
                data = bytes.fromhex("".join((reply.value or "").split()))
                out["data"] = "0x" + data[::-1].hex() if data else "0x"
                if data:
                    out["length"] = len(data)
            else:
                out["value"] = reply.value
        elif reply.value is not None:
            out["data"] = reply.value
        if reply.lines:
            out["lines"] = reply.lines
        return web.json_response(out)

    def _line(
        self,
        seq: str,
        net: str,
        node: str,
        words: list[str],
        body: dict[str, Any],
        query_type: str | None = None,
    ) -> tuple[str | None, str | None]:
        """The CiA 309-3 line of one HTTP request, and the data type a read asked for."""
        command = words[0].lower()
        value = body.get("value")
        if value is not None and not isinstance(value, str | int | float):
            raise ValueError('"value" is a string or a number')
        if command == "info" and words[1:] == ["version"]:
            return None, None
        if node.lower() == "all":
            node = "0"
        numbers: list[int | None] = []
        for part, what, default in (
            (net, "net", self.defaults.net),
            (node, "node", self.defaults.node),
        ):
            if part.lower() in ("default", "none"):
                numbers.append(default)
            elif _NUMBER.match(part):
                numbers.append(int(part, 0))
            else:
                raise ValueError(f"{what} {part!r}: a number, default, none or all")
        net_number, node_number = numbers
        head = [f"[{seq}]"]
        pdo = words[1:2] in (["p"], ["pdo"])
        if command in NODE_COMMANDS and not pdo:  # ([seq] net node command)
            if node_number is None:
                raise ValueError("no node in the path and no default node: set/node first")
            head += [str(net_number), str(node_number)]
        elif net_number is not None:  # (a whole net's request: [seq] net command)
            head.append(str(net_number))
        type_name: str | None = None
        if command in ("r", "read") and len(words) in (2, 3) and words[1] not in ("p", "pdo"):
            type_name = body.get("datatype") or query_type or None
            if type_name is not None and not isinstance(type_name, str):
                raise ValueError('"datatype" is a type mnemonic: "u16"')
            where = words[1:] if len(words) == 3 else [_quote(words[1])]  # (a name)
            return " ".join([*head, "r", *where, type_name or "hex"]), type_name
        if command in ("w", "write") and len(words) == 3:
            datatype = body.get("datatype")
            if not isinstance(datatype, str) or value is None:
                raise ValueError('a write takes {"value": ..., "datatype": "u16"}')
            text = str(value)
            if datatype.lower() == "vs" or any(c.isspace() for c in text):
                text = _quote(text)
            return " ".join([*head, "w", words[1], words[2], datatype, text]), None
        if command == "set" and len(words) == 2:  # (the gateway's: the path's net, node unused)
            name = {"sdo-timeout": "sdo_timeout"}.get(words[1].lower(), words[1].lower())
            if value is None:
                raise ValueError(f'set/{words[1]} takes {{"value": ...}}')
            number = str(value)
            return f"[{seq}] set {name} {int(number, 0) if _NUMBER.match(number) else number}", None
        if command in ("set", "r", "read", "w", "write") and len(words) == 1:
            raise ValueError(f"{command}: give what to {command}")
        if value is not None:
            words = [*words, str(value)]
        return " ".join([*head, *words]), None

    # ------------------------------------------------------------------ events

    async def _events(self, request: web.Request) -> web.WebSocketResponse:
        foreign = self._foreign(request)
        if foreign is not None:
            raise web.HTTPForbidden(text=foreign + "\n")
        ws = web.WebSocketResponse(heartbeat=30.0)
        await ws.prepare(request)
        session = self.core.session(trusted=self._authorised(request))
        session.peer = "http events"
        self._sockets.add(ws)

        sending: set[asyncio.Task[None]] = set()

        def notify(line: str) -> None:
            if ws.closed or len(sending) > _UNSENT_LIMIT:
                return  # (a socket that does not keep up loses lines, not memory)
            task = asyncio.get_running_loop().create_task(ws.send_str(json.dumps({"event": line})))
            sending.add(task)
            task.add_done_callback(_sent)
            task.add_done_callback(sending.discard)

        session.notify = notify
        await self.core.execute(session, "subscribe all")
        try:
            async for message in ws:
                if message.type in (WSMsgType.ERROR, WSMsgType.CLOSE):
                    break
        finally:
            self._sockets.discard(ws)
            self.core.forget(session)
        return ws


def _quote(text: str) -> str:
    """``text`` as one quoted word of a request line (quotes doubled, backslashes too)."""
    return '"' + text.replace("\\", "\\\\").replace('"', '""') + '"'


def _sent(task: asyncio.Task[None]) -> None:
    if not task.cancelled():
        task.exception()  # (a socket gone: its lines are lost, nothing to log)


def _answer(seq: str, response: str, text: str = "") -> web.Response:
    out = {"sequence": seq, "response": response}
    if text:
        out["text"] = text
    return web.json_response(out)
