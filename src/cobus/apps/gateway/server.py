"""The gateway over TCP: each client a session of its own, one request a line (LF, CR LF or
CR); requests with a ``[seq]`` run side by side and are answered as they end, those without
in order (see :mod:`cobus.apps.gateway.core`).

Lines are bounded (:data:`MAX_LINE` bytes: a longer one is answered with a syntax error and
skipped, the connection stays), and so are a client's requests under way
(:data:`~cobus.apps.gateway.core.MAX_PENDING`); a client that disconnects in the middle of a
transfer holds back no other client but those asking the same node, and them only until its
transfer ends as it would (within its SDO timeout): no abort the client did not ask for
reaches the bus, and its requests still waiting for their turn are dropped once the
connection is known to be gone (reset, or a write to it failed). A client that only closes
its side (``printf ... | nc -N``) gets every answer: its requests all run.
The server binds 127.0.0.1 unless told otherwise; it serves another address only with a
token (the core's), which clients give (``auth TOKEN``) before they write, send NMT commands
or use LSS. A Unix socket (``unix``) is this user's only (mode 0600).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import socket
import time
from functools import partial

from cobus.apps._serving import free_unix_path, is_loopback
from cobus.apps.gateway.client import reply_of
from cobus.apps.gateway.core import MAX_PENDING, GatewayCore, Session
from cobus.apps.gateway.grammar import GatewayError

__all__ = ["MAX_LINE", "GatewayServer", "request_line"]

#: The longest request line taken (bytes, without its line end).
MAX_LINE = 4096


class GatewayServer:
    """Serves ``core`` on ``host``:``port`` (``port`` 0: a free one, see :attr:`port`), or
    on the Unix socket ``unix`` instead."""

    def __init__(
        self,
        core: GatewayCore,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        unix: str | None = None,
        idle_timeout: float | None = 600.0,
        json_lines: bool = False,
    ) -> None:
        if unix is None and not is_loopback(host) and core.token is None:
            raise ValueError(
                f"the gateway writes to the bus: to serve {host!r} (not only this host) give "
                "the core a token, GatewayCore(..., token=...), that clients give before "
                "they write"
            )
        self.core = core
        self._holding = False  # (it holds the core: start, stop)
        #: The Unix socket's path (None: TCP).
        self.unix = unix
        #: Whether requests and answers are JSON objects, one a line (see
        #: :func:`request_line`), instead of CiA 309-3 text.
        self.json_lines = json_lines
        self._peers = 0
        self._idle_timeout = idle_timeout
        self._idle_watches: set[_IdleWatch] = set()
        self.host = host
        self.requested_port = port
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.Task[None]] = set()
        #: How many clients are connected now.
        self.clients = 0

    @property
    def idle_timeout(self) -> float | None:
        """Seconds a client may send nothing (and be sent nothing) before its connection
        closes (None: never); a change applies to the clients connected too."""
        return self._idle_timeout

    @idle_timeout.setter
    def idle_timeout(self, seconds: float | None) -> None:
        self._idle_timeout = seconds
        for watch in list(self._idle_watches):
            watch.update()

    @property
    def port(self) -> int:
        """The port it listens on (once started)."""
        if self._server is None or not self._server.sockets:
            return self.requested_port
        return int(self._server.sockets[0].getsockname()[1])

    @property
    def address(self) -> str:
        """Where it listens: ``HOST:PORT`` or the Unix socket's path."""
        if self.unix is not None:
            return self.unix
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    async def start(self) -> None:
        """Listen (on the running loop: the networks' own); OSError when it cannot (the
        core then released again). The core watches the buses from now on (``set id``
        then knows the nodes that beat). Started already: nothing more."""
        if self._server is not None:
            return
        took = not self._holding
        if took:
            self.core.hold()
            self._holding = True
        try:
            self._server = await self._listen()
        except BaseException:
            if took:  # (a bind that failed leaves the core as it found it)
                self._holding = False
                self.core.release()
            raise

    async def _listen(self) -> asyncio.Server:
        if self.unix is None:
            return await asyncio.start_server(self._serve, self.host, self.requested_port)
        refused = free_unix_path(self.unix)
        if refused is not None:
            raise OSError(f"{self.unix}: {refused}")
        sock = socket.socket(socket.AF_UNIX)
        old = os.umask(0o177)  # (created 0600: this user's only, from the first moment)
        try:
            sock.bind(self.unix)
        except OSError:
            sock.close()
            raise
        finally:
            os.umask(old)
        return await asyncio.start_unix_server(self._serve, sock=sock)

    async def stop(self) -> None:
        """Stop listening and end every client's connection."""
        if self._server is not None:
            self._server.close()
            for task in list(self._clients):
                task.cancel()
            for task in list(self._clients):
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
            await self._server.wait_closed()
            self._server = None
            if self.unix is not None:
                with contextlib.suppress(OSError):
                    os.unlink(self.unix)
        if self._holding:  # (the core closes once no server serves it)
            self._holding = False
            self.core.release()

    #: Unsolicited lines dropped because their client did not read (summed over clients).
    dropped = 0

    def _notify(self, session: Session, writer: asyncio.StreamWriter, line: str) -> None:
        if writer.is_closing():
            return
        if writer.transport.get_write_buffer_size() > UNREAD_LIMIT:
            self.dropped += 1  # (a client that does not read holds back nobody)
            return
        if self.json_lines:
            line = json.dumps({"event": line}, ensure_ascii=False)
        writer.write(line.encode("utf-8") + b"\r\n")

    def _answer_json(
        self, session: Session, writer: asyncio.StreamWriter, request: str, reply: list[str]
    ) -> None:
        out = reply_of(request, reply).as_dict()
        match = _NUMBERED.match(request)
        if match:
            out = {"seq": int(match.group(1)), **out}
        self._answer(session, writer, [json.dumps(out, ensure_ascii=False)])

    def _answer(self, session: Session, writer: asyncio.StreamWriter, reply: list[str]) -> None:
        if writer.is_closing():
            self.core.abandon(session)  # (nobody reads: what waits for its turn goes)
            return
        if reply:
            writer.write(("\r\n".join(reply) + "\r\n").encode("utf-8", "replace"))
            if writer.is_closing():  # (that write found the client gone)
                self.core.abandon(session)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._clients.add(task)
        self.clients += 1
        session = self.core.session(trusted=self.unix is not None)
        session.notify = partial(self._notify, session, writer)
        peer = writer.get_extra_info("peername")
        if isinstance(peer, tuple):
            host = f"[{peer[0]}]" if ":" in str(peer[0]) else str(peer[0])
            session.peer = f"{host}:{peer[1]}"
        elif self.unix is not None:
            self._peers += 1
            session.peer = f"{self.unix}#{self._peers}"
        answer = partial(self._answer, session, writer)
        lines = _Lines(reader)
        idle = _IdleWatch(self, session, writer)
        self._idle_watches.add(idle)
        try:
            while True:
                line = await lines.next()
                if line is None:
                    break
                idle.update()
                if isinstance(line, int):
                    too_long = f"a line longer than {MAX_LINE} bytes"
                    if self.json_lines:
                        answer = partial(self._answer_json, session, writer, "")
                    self.core.refuse(session, 101, too_long, answer)
                elif self.json_lines:
                    text = request_line(line)
                    if isinstance(text, GatewayError):
                        refused = partial(self._answer_json, session, writer, "")
                        self.core.refuse(session, text.code, text.text, refused)
                    elif text:
                        replied = partial(self._answer_json, session, writer, text)
                        self.core.submit(session, text, replied)
                else:
                    self.core.submit(session, line, answer)
                await writer.drain()  # (a client that does not read its answers is not read)
                while len(session.pending) > 2 * MAX_PENDING:  # (nor one that floods us)
                    await asyncio.wait(list(session.pending), return_when=asyncio.FIRST_COMPLETED)
            # the client sent all it will: its requests are answered (a client that only
            # half-closed, as `printf ... | nc -N` does, gets every answer)
            await self.core.drain(session)
        except (ConnectionError, asyncio.IncompleteReadError):
            self.core.abandon(session)
            with contextlib.suppress(asyncio.CancelledError):
                await self.core.drain(session)
        except asyncio.CancelledError:
            pass  # (the server stops: the connection ends quietly)
        finally:
            idle.cancel()
            self._idle_watches.discard(idle)
            self.core.forget(session)
            self.clients -= 1
            self._clients.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()


_NUMBERED = re.compile(r"\s*\[\s*([0-9]+)\s*\]")
_NEEDS_QUOTES = re.compile(r'[\s"#]')


def request_line(text: str) -> str | GatewayError:
    """The CiA 309-3 line of one JSON request (the JSON lines framing): ``{"line": "[1] 5 r
    0x1018 1 u32"}`` as it is, or ``{"seq": 1, "net": 1, "node": 5, "command": "r", "args":
    ["0x1018", 1, "u32"]}`` (net, node, seq and args may be left out; an argument with a
    space, a quote or a # is quoted). A blank line is "" (nothing to do); what is no such
    object is the :class:`GatewayError` to answer."""
    if not text.strip():
        return ""
    try:
        request = json.loads(text)
    except ValueError as exc:
        return GatewayError(101, f"no JSON: {exc}")
    if not isinstance(request, dict):
        return GatewayError(101, 'a request is a JSON object: {"command": "r", ...}')
    unknown = set(request) - {"line", "seq", "net", "node", "command", "args"}
    if unknown:
        return GatewayError(101, f"no field {sorted(unknown)[0]!r} in a request")
    if "line" in request:
        line = request["line"]
        if set(request) != {"line"} or not isinstance(line, str) or "\n" in line:
            return GatewayError(101, '"line" is one line of text, alone in its request')
        return line
    command, args = request.get("command"), request.get("args", [])
    if not isinstance(command, str) or not command.strip() or " " in command.strip():
        return GatewayError(101, 'give the "command": "r", "w", "start", "set"...')
    if not isinstance(args, list) or not all(
        isinstance(a, str | int) and not isinstance(a, bool) for a in args
    ):
        return GatewayError(101, '"args" is a list of strings and numbers')
    words: list[str] = []
    for key in ("seq", "net", "node"):
        value = request.get(key)
        if value is None:
            continue
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            return GatewayError(101, f'"{key}" is a number')
        words.append(f"[{value}]" if key == "seq" else str(value))
    if "net" in request and "node" not in request:
        return GatewayError(101, '"net" needs "node" beside it (or the line form)')
    words.append(command.strip())
    for arg in args:
        word = str(arg)
        if "\n" in word or "\r" in word:
            return GatewayError(101, "an argument of one line: \\n for a line end in a string")
        if not word or _NEEDS_QUOTES.search(word):
            word = '"' + word.replace("\\", "\\\\").replace('"', '""') + '"'
        words.append(word)
    return " ".join(words)


class _IdleWatch:
    """Closes a client's connection once it has been idle for the server's idle timeout:
    no request and no answer for that long, none under way, no subscription. A timer, not
    a wait around each read (which would cost every line a task)."""

    def __init__(self, server: GatewayServer, session: Session, writer: asyncio.StreamWriter):
        self._server = server
        self._session = session
        self._writer = writer
        self._handle: asyncio.TimerHandle | None = None
        self._armed_for: float | None = None
        self.update()

    def update(self) -> None:
        """Follow a change of the server's idle timeout."""
        timeout = self._server.idle_timeout
        if timeout != self._armed_for:
            self.cancel()
            self._armed_for = timeout
            if timeout is not None:
                self._arm(timeout)

    def cancel(self) -> None:
        """The connection ends: no more checks."""
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None

    def _arm(self, delay: float) -> None:
        self._handle = asyncio.get_running_loop().call_later(delay, self._check)

    def _check(self) -> None:
        timeout, session, writer = self._armed_for, self._session, self._writer
        self._handle = None
        if timeout is None or writer.is_closing():
            return
        busy = session.subscribed or session.pending
        idle = 0.0 if busy else time.monotonic() - session.last
        if idle < timeout:
            self._arm(timeout - idle)
            return
        writer.write(f"# idle for {timeout:g} s: closed\r\n".encode())
        writer.close()  # (the read sees the end: the connection ends as any other)


#: Bytes a client may leave unread before its unsolicited lines are dropped (and counted).
UNREAD_LIMIT = 64 * 1024


class _Lines:
    """The lines of one client, ended by LF, CR LF or a CR alone, each at most
    :data:`MAX_LINE` bytes (a longer one comes as ``0`` and is skipped to its end)."""

    def __init__(self, reader: asyncio.StreamReader) -> None:
        self._reader = reader
        self._buffer = b""
        self._skipping = False  # (inside a line too long)
        self._after_cr = False  # (an LF right after a CR ends nothing)

    async def next(self) -> str | int | None:
        """The next line (None: the client sent no more)."""
        while True:
            if self._after_cr and self._buffer[:1] == b"\n":
                self._buffer = self._buffer[1:]
            if self._buffer:
                self._after_cr = False
            cut = _line_end(self._buffer)
            if cut is not None:
                raw, self._after_cr = self._buffer[:cut], self._buffer[cut : cut + 1] == b"\r"
                self._buffer = self._buffer[cut + 1 :]
                if self._skipping:
                    self._skipping = False
                    return 0
                if len(raw) > MAX_LINE:
                    return 0
                return raw.decode("utf-8", "replace")
            if len(self._buffer) > MAX_LINE:
                self._buffer = b""
                self._skipping = True
            chunk = await self._reader.read(MAX_LINE)
            if not chunk:
                if self._buffer and not self._skipping:  # (a last line without its end)
                    raw, self._buffer = self._buffer, b""
                    return raw.decode("utf-8", "replace")
                if self._skipping:  # (it ended in a line too long)
                    self._skipping = False
                    return 0
                return None
            self._buffer += chunk


def _line_end(data: bytes) -> int | None:
    """Where the first line of ``data`` ends (at a CR or an LF), None: it does not yet."""
    ends = [i for i in (data.find(b"\r"), data.find(b"\n")) if i >= 0]
    return min(ends) if ends else None
