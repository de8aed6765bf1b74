"""The one SDO client transport per server COB-ID pair of a network.

Every client of a network that talks SDO to a server — a remote node's ``sdo``, a master's
node, the blocking facade, a gateway — takes the transport for that server's COB-ID pair from
:meth:`AsyncNetwork.sdo_transport <cobus.runtime.network.AsyncNetwork.sdo_transport>`. Two
SDO clients on one COB-ID pair would each take the other's answers (and abort); one transport
runs the transfers of all of them one after the other, in the order they were asked for.

A transfer is a ``start(now)`` call of the :class:`~cobus.proto.sdo.SdoClient` machine
(:meth:`SdoTransport.upload_call`, :meth:`SdoTransport.download_call`), awaited with
:meth:`SdoTransport.transfer`, or begun at once by blocking code that holds the loop's
protocol lock with :meth:`SdoTransport.begin`. Each transfer carries its asker's timeout.
The final event is handed back as is: :func:`uploaded`, :func:`downloaded` and
:func:`refused_block` read it.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections import deque
from functools import partial
from typing import TYPE_CHECKING, Final

from cobus.proto.sdo import (
    DownloadDone,
    SdoAbortCode,
    SdoAbortedError,
    SdoClient,
    TransferFailed,
    UploadDone,
)
from cobus.runtime.errors import NetworkClosedError

if TYPE_CHECKING:
    from collections.abc import Callable

    from cobus.proto import Event, Out
    from cobus.runtime.network import AsyncNetwork, MachineHost

    _Finish = Callable[[Event | BaseException], None] | asyncio.Future[Event]

__all__ = ["SdoTransport", "downloaded", "refused_block", "uploaded"]

#: The events that end a transfer (one union, not one made for each event).
_FINAL = UploadDone | DownloadDone | TransferFailed


class SdoTransport:
    """The SDO client of one network to one server COB-ID pair, shared by every asker.

    Transfers run one at a time, in request order, whoever asks; ``transfers`` and
    ``failures`` count them for diagnostics. Made and shared by
    :meth:`AsyncNetwork.sdo_transport <cobus.runtime.network.AsyncNetwork.sdo_transport>`;
    each taker calls :meth:`release` once when done with it.
    """

    #: The node-ID of the server, named in errors (None: a channel of other COB-IDs).
    node_id: Final[int | None]
    #: The protocol machine (its ``busy``, ``progress`` and ``stale_replies`` are read here).
    client: Final[SdoClient]

    def __init__(self, network: AsyncNetwork, rx_cob_id: int, tx_cob_id: int) -> None:
        self._network = network
        self.client = SdoClient(rx_cob_id, tx_cob_id)
        self.node_id = self.client.node
        self._host: MachineHost = network.attach(
            self.client, [tx_cob_id], on_event=self._on_event, extended=tx_cob_id > 0x7FF
        )
        #: Transfers that ended with an answer (done or failed) and those that failed.
        self.transfers = 0
        self.failures = 0
        self._users = 0
        # The transport is held by one transfer at a time; the others wait here, in order.
        self._busy = False
        self._waiters: deque[tuple[asyncio.Future[None], object]] = deque()
        # a disconnect voids every turn given before it (their tasks may never run again)
        self._generation = 0
        # how the transfer under way ends: its waiting future (transfer) or a callback (begin)
        self._finish: _Finish | None = None
        self._owner: object = None  # who asked for the transfer under way
        self._emit = True  # whether the network hears the events of the latest transfer
        network.on_disconnect(self._on_disconnect)

    def __repr__(self) -> str:
        return (
            f"<SdoTransport 0x{self.client.rx_cob_id:X}/0x{self.client.tx_cob_id:X}, "
            f"{self._users} user(s), {self.transfers} transfer(s)>"
        )

    @property
    def owner(self) -> object:
        """Who asked for the transfer under way (None between transfers)."""
        return self._owner

    # -- sharing
    def take(self) -> SdoTransport:
        """One more user (see :meth:`release`)."""
        self._users += 1
        return self

    def release(self) -> None:
        """One user fewer; the last one detaches the client from the network."""
        if self._users <= 0:
            return
        self._users -= 1
        if self._users > 0:
            return
        key = (self.client.rx_cob_id, self.client.tx_cob_id)
        if self._network._sdo_transports.get(key) is self:
            del self._network._sdo_transports[key]
        self._host.close()
        self._network._forget(self._on_disconnect)

    # -- the machine's events
    def _on_event(self, event: Event) -> None:
        if isinstance(event, _FINAL) and self._finish is not None:
            self.transfers += 1
            if isinstance(event, TransferFailed):
                self.failures += 1
            self._end(event)
        if self._emit:
            self._network.emit(event)

    def _end(self, outcome: Event | BaseException) -> None:
        finish = self._finish
        if finish is not None:
            self._finish = None
            self._owner = None
            if type(finish) is not asyncio.Future:
                finish(outcome)  # type: ignore[operator]
            elif finish.done():
                pass
            elif isinstance(outcome, BaseException):
                finish.set_exception(outcome)
            else:
                finish.set_result(outcome)

    def interrupt(self, owner: object, error: BaseException, queued: BaseException) -> None:
        """End ``owner``'s transfer under way, if any, with ``error`` (the server is told),
        and fail its transfers still waiting for their turn with ``queued``."""
        if self._finish is not None and self._owner is owner:
            self._end(error)
            self._cancel()  # after: the abort's own event must not end the transfer first
        for entry in [e for e in self._waiters if e[1] is owner]:
            self._waiters.remove(entry)
            if not entry[0].done():
                entry[0].set_exception(queued)

    def _on_disconnect(self) -> None:
        node = "" if self.node_id is None else f" with node {self.node_id}"
        error = NetworkClosedError(f"the network was disconnected during an SDO transfer{node}")
        self._end(error)
        self._cancel()
        # every turn, waiting or given and not yet taken, is void: the transport starts free
        self._generation += 1
        waiters, self._waiters = self._waiters, deque()
        for turn, _ in waiters:
            if not turn.done():
                turn.set_exception(error)
        self._busy = False

    # -- one transfer at a time: awaited in order, or begun at once by blocking code
    async def _acquire(self, owner: object) -> None:
        turn: asyncio.Future[None] = self._network.loop.create_future()
        entry = (turn, owner)
        self._waiters.append(entry)
        generation = self._generation
        try:
            await turn  # _release hands the transport over by resolving it
        except BaseException:
            handed = turn.done() and not turn.cancelled() and turn.exception() is None
            if handed and generation == self._generation:
                self._release()  # handed over, but cancelled before it could run: pass on
            else:
                with contextlib.suppress(ValueError):
                    self._waiters.remove(entry)
            raise

    def _release(self) -> None:
        while self._waiters:
            turn, _ = self._waiters.popleft()
            if not turn.done():
                turn.set_result(None)  # the transport stays busy: it is that waiter's now
                return
        self._busy = False

    def _start(
        self,
        start: Callable[[float], Out],
        finish: _Finish,
        timeout: float,
        emit: bool,
        owner: object,
    ) -> None:
        """Start a transfer on the held transport; ``finish`` gets its final event or error."""
        client = self.client
        if client.timeout != timeout:
            client.timeout = timeout
        self._finish = finish
        self._owner = owner
        self._emit = emit
        try:
            self._host.run(start)
        except BaseException:
            self._finish = None
            self._owner = None
            self._cancel()
            raise

    def _cancel(self) -> None:
        """End the transfer under way (cancelled, failed to start): the transport is free, and
        the server is told where it still can be."""
        if self.client.busy:
            network = self._network
            out = self.client.abort(
                SdoAbortCode.GENERAL_ERROR, network.time() if network.connected else 0.0
            )
            if network.connected:
                self._host.apply(out)

    def set_timeout(self, owner: object, seconds: float) -> None:
        """``owner``'s transfer under way waits ``seconds`` for each answer from now on."""
        if self._owner is owner:
            self.client.timeout = seconds

    def begin(
        self,
        start: Callable[[float], Out],
        finish: Callable[[Event | BaseException], None],
        *,
        timeout: float,
        emit: bool = True,
        owner: object = None,
    ) -> Callable[[], None] | None:
        """Start a transfer now if the transport is free, for blocking code that holds the
        loop's protocol lock (it then waits in its own thread, with no hop through the loop).

        ``start(now)`` is the client machine's call; ``finish`` is called once, under the lock,
        with the final event or the error that ended the transfer. Returns a function that
        cancels the transfer (to call under the lock), or None when the transport is busy
        and nothing was started (await :meth:`transfer` instead).
        """
        if self._busy or self._waiters:
            return None
        self._busy = True

        ended = False

        def finished(outcome: Event | BaseException) -> None:
            nonlocal ended
            ended = True
            self._release()
            finish(outcome)

        try:
            self._start(start, finished, timeout, emit, owner)
        except BaseException:
            if not ended:  # (a transfer that ended as it started has freed the transport)
                self._release()
            raise

        def cancel() -> None:
            if self._finish is finished:
                self._end(asyncio.CancelledError())
                self._cancel()  # after: the abort's own event is no outcome (nor a failure)

        return cancel

    async def transfer(
        self,
        start: Callable[[float], Out],
        *,
        timeout: float | Callable[[], float],
        emit: bool = True,
        owner: object = None,
        check: Callable[[], None] | None = None,
    ) -> Event:
        """Run a transfer in its turn and return its final event (a
        :class:`~cobus.proto.sdo.TransferFailed` is returned, not raised). ``timeout`` may be
        a function, asked when the turn comes (the asker may change it while waiting);
        ``check()`` runs when the turn comes after a wait (it raises to give the turn up:
        the asker is gone); a cancelled transfer is aborted on the bus."""
        generation = self._generation
        if self._busy or self._waiters:
            await self._acquire(owner)
            if generation != self._generation:  # given before a disconnect: void
                node = "" if self.node_id is None else f" with node {self.node_id}"
                raise NetworkClosedError(
                    f"the network was disconnected while an SDO transfer{node} waited"
                )
            waited = True
        else:  # _acquire() without a coroutine: every transfer on a free transport
            self._busy = True
            waited = False
        try:
            if waited:
                if check is not None:
                    check()
                # the asker may have changed its timeout while it waited: read it now
                changed = getattr(owner, "timeout", None)
                if isinstance(changed, float | int) and not isinstance(changed, bool):
                    timeout = changed
            if not isinstance(timeout, float | int):
                timeout = timeout()
            done: asyncio.Future[Event] = self._network.loop.create_future()
            self._start(start, done, timeout, emit, owner)  # (the future: no closure to call)
            try:
                return await done
            except BaseException:
                if self._finish is done:  # cancelled (wait_for, Ctrl-C): end the transfer
                    self._finish = None
                    self._owner = None
                    self._cancel()
                raise
        finally:
            if generation == self._generation:  # (a disconnect freed the transport itself)
                self._release()

    # ``start(now)`` of a transfer: a partial is called in C, a lambda would be one more
    # Python call on every blocking transfer's way to the bus
    def upload_call(self, index: int, subindex: int, block: bool) -> Callable[[float], Out]:
        """The ``start(now)`` of an upload of ``index:subindex``."""
        return partial(self.client.start_upload, index, subindex, block=block)

    def download_call(
        self, index: int, subindex: int, data: bytes, block: bool, size_indicated: bool
    ) -> Callable[[float], Out]:
        """The ``start(now)`` of a download of ``data`` to ``index:subindex``."""
        return partial(
            self.client.start_download,
            index,
            subindex,
            bytes(data),
            block=block,
            size_indicated=size_indicated,
        )


def uploaded(event: Event) -> bytes:
    """The bytes of a finished upload, or its error raised."""
    if isinstance(event, TransferFailed):
        raise event.error
    assert isinstance(event, UploadDone)
    return event.data


def downloaded(event: Event) -> None:
    """Nothing for a finished download, or its error raised."""
    if isinstance(event, TransferFailed):
        raise event.error


def refused_block(event: Event) -> bool:
    """Whether the server refused a block transfer (try segmented)."""
    if not isinstance(event, TransferFailed):
        return False
    error = event.error
    return isinstance(error, SdoAbortedError) and error.code in (
        SdoAbortCode.INVALID_COMMAND,
        SdoAbortCode.UNSUPPORTED_ACCESS,
    )
