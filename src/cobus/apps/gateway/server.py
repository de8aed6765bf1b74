"""The gateway over TCP (or a Unix socket): each client a session of its own, one request a
line, the replies in its order.

Lines are bounded (:data:`MAX_LINE` bytes: a longer one is answered with a syntax error and
skipped, the connection stays); a client that disconnects in the middle of a transfer ends
only its own requests. The server binds 127.0.0.1 unless told otherwise; it serves another
address only to clients that give the token (not built yet: it refuses such an address).
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
from typing import TYPE_CHECKING

from cobus.apps.gateway.core import GatewayCore, Session
from cobus.apps.gateway.grammar import format_error

if TYPE_CHECKING:
    pass

__all__ = ["MAX_LINE", "GatewayServer", "is_loopback"]

#: The longest request line taken (bytes, without its line end).
MAX_LINE = 4096


class GatewayServer:
    """Serves ``core`` on ``host``:``port`` (``port`` 0: a free one, see :attr:`port`)."""

    def __init__(self, core: GatewayCore, host: str = "127.0.0.1", port: int = 0) -> None:
        if not is_loopback(host):
            raise ValueError(
                f"the gateway writes to the bus: it serves only 127.0.0.1 (or ::1) until "
                f"tokens are built, not {host!r}"
            )
        self.core = core
        self.host = host
        self.requested_port = port
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.Task[None]] = set()
        #: How many clients are connected now.
        self.clients = 0

    @property
    def port(self) -> int:
        """The port it listens on (once started)."""
        if self._server is None or not self._server.sockets:
            return self.requested_port
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        """Listen (on the running loop: the networks' own)."""
        self._server = await asyncio.start_server(
            self._serve, self.host, self.requested_port, limit=MAX_LINE + 2
        )

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

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._clients.add(task)
        self.clients += 1
        session = self.core.session()
        try:
            while True:
                line = await _read_line(reader)
                if line is None:
                    break
                if isinstance(line, int):
                    reply = [
                        format_error(
                            None, 101, f"a line longer than {MAX_LINE} bytes", self.core.dialect
                        )
                    ]
                else:
                    answered = await self._execute(reader, session, line)
                    if answered is None:
                        break  # (the client left while its request ran)
                    reply = answered
                if reply:
                    writer.write(("\r\n".join(reply) + "\r\n").encode("utf-8", "replace"))
                    await writer.drain()
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            session.close()
            self.clients -= 1
            self._clients.discard(task)
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    #: Seconds between looks whether a client whose request runs has left.
    LOOK = 0.1

    async def _execute(
        self, reader: asyncio.StreamReader, session: Session, line: str
    ) -> list[str] | None:
        """The reply to ``line``; None when the client left before it came (its request is
        cancelled: a transfer to a silent node does not outlive its asker)."""
        task = asyncio.ensure_future(self.core.execute(session, line))
        while True:
            done, _pending = await asyncio.wait({task}, timeout=self.LOOK)
            if done:
                return task.result()
            if reader.at_eof():
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
                return None


async def _read_line(reader: asyncio.StreamReader) -> str | int | None:
    """The next line (None: the client left; an int: a line too long, skipped)."""
    try:
        raw = await reader.readuntil(b"\n")
    except asyncio.IncompleteReadError as exc:
        if not exc.partial:
            return None
        raw = exc.partial
    except asyncio.LimitOverrunError:
        # skip to the end of the over-long line
        while True:
            try:
                await reader.readuntil(b"\n")
                return 0
            except asyncio.LimitOverrunError as exc:
                await reader.readexactly(exc.consumed)
            except asyncio.IncompleteReadError:
                return None
    return raw.decode("utf-8", "replace")


def is_loopback(host: str) -> bool:
    """Whether ``host`` is this host only (localhost, 127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
