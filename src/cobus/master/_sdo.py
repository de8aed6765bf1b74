"""The master's SDO client channel to one node.

Like :class:`cobus.runtime.SdoChannel`, transfers run one after the other; unlike it, a
transfer whose waiting task is cancelled (the node re-booted, the master stops) is aborted on
the bus at once, so the channel is free for the next configuration run.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Any

from cobus.od import ObjectDictionary, Variable
from cobus.proto import Event
from cobus.proto.connection_set import SDO_TX_BASE, sdo_cob_ids
from cobus.proto.sdo import DownloadDone, SdoAbortCode, SdoClient, TransferFailed, UploadDone

if TYPE_CHECKING:
    from collections.abc import Callable

    from cobus.proto import Out
    from cobus.runtime import AsyncNetwork

__all__ = ["SdoLink"]

#: The events that end a transfer (one union, not one made for each event).
_FINAL = UploadDone | DownloadDone | TransferFailed


class SdoLink:
    """SDO client of the master to node ``node_id`` (600h+id / 580h+id)."""

    def __init__(
        self, network: AsyncNetwork, node_id: int, od: ObjectDictionary, timeout: float
    ) -> None:
        self.node_id = node_id
        self.od = od
        self._network = network
        self.client = SdoClient(*sdo_cob_ids(node_id), timeout=timeout, node=node_id)
        self._host = network.attach(self.client, [SDO_TX_BASE + node_id], self._on_event)
        self._lock = asyncio.Lock()
        self._pending: asyncio.Future[Event] | None = None
        #: Transfers done and failed, for the diagnostics.
        self.transfers = 0
        self.failures = 0

    def _on_event(self, event: Event) -> None:
        if isinstance(event, _FINAL):
            pending = self._pending
            if pending is not None and not pending.done():
                pending.set_result(event)

    async def _transfer(self, start: Callable[[float], Out]) -> Event:
        async with self._lock:
            future: asyncio.Future[Event] = self._network.loop.create_future()
            self._pending = future
            try:
                self._host.run(start)
                event = await future
            except asyncio.CancelledError:
                self._abort_pending()
                raise
            finally:
                self._pending = None
            self.transfers += 1
            if isinstance(event, TransferFailed):
                self.failures += 1
                raise event.error
            return event

    async def upload(self, index: int, subindex: int = 0) -> bytes:
        """The raw bytes of ``index:subindex``."""
        client = self.client
        event = await self._transfer(lambda now: client.start_upload(index, subindex, now))
        assert isinstance(event, UploadDone)
        return event.data

    async def download(self, index: int, subindex: int, data: bytes) -> None:
        """Write raw bytes to ``index:subindex``."""
        client = self.client
        await self._transfer(lambda now: client.start_download(index, subindex, data, now))

    def variable(self, index: int | str, subindex: int | str = 0) -> Variable:
        obj = self.od[index]
        if isinstance(obj, Variable):
            return obj
        return obj[subindex]

    async def read(self, index: int | str, subindex: int | str = 0) -> Any:
        """Read an object and decode it with its type from the node's EDS."""
        var = self.variable(index, subindex)
        return var.decode(await self.upload(var.index, var.subindex))

    async def write(self, index: int | str, subindex: int | str, value: Any) -> None:
        """Encode ``value`` with the object's type from the node's EDS and write it."""
        var = self.variable(index, subindex)
        await self.download(var.index, var.subindex, var.encode(value))

    def _abort_pending(self) -> None:
        """Abort the transfer under way on the bus; with the network closed already there is
        no bus to tell: the client is only set free."""
        client = self.client
        if not client.busy:
            return
        if self._network.connected:
            self._host.run(lambda now: client.abort(SdoAbortCode.GENERAL_ERROR, now))
        else:
            client.abort(SdoAbortCode.GENERAL_ERROR, 0.0)  # (its frame goes nowhere)

    def close(self) -> None:
        self._abort_pending()
        self._host.close()
