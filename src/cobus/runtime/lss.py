"""LSS (CiA 305) from this network's side: ``net.lss`` finds devices without a node-ID, gives
them one, sets bit rates, stores, inquires (the master's services of
:mod:`cobus.proto.lss` on the bus).

Requests go one at a time (a second caller waits its turn). A request nobody answers raises
:class:`LssTimeoutError` saying what that means; an answer with an error
:class:`LssRefusedError` with the standard's text. An answer nobody waits for is reported to
the network's listeners as :class:`~cobus.proto.lss.LssStrayAnswer`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TYPE_CHECKING

from cobus.proto import Event, Out
from cobus.proto.connection_set import LSS_SLAVE_COB_ID
from cobus.proto.lss import (
    Fastscan,
    FastscanFailed,
    FastscanFound,
    FastscanNothingFound,
    LssConfirmed,
    LssIdentified,
    LssIdentity,
    LssInquired,
    LssMaster,
    LssNoAnswer,
    LssSelected,
    LssState,
    LssStrayAnswer,
    bit_timing_index,
)
from cobus.runtime.errors import LssRefusedError, LssScanError, LssTimeoutError

if TYPE_CHECKING:
    from cobus.runtime.network import AsyncNetwork, MachineHost

__all__ = ["AsyncNetworkLss"]

_NO_ANSWER = {
    "switch state selective": "no slave has that identity (or it is not in waiting state)",
    "identify remote slave": "",
    "identify non-configured slave": "",
}


class AsyncNetworkLss:
    """The LSS master of a network (``net.lss``)."""

    def __init__(self, network: AsyncNetwork, timeout: float = 0.1) -> None:
        self._network = network
        self._machine = LssMaster(timeout)
        self._host: MachineHost | None = None
        self._waiter: asyncio.Future[Event] | None = None
        self._lock: asyncio.Lock | None = None
        self._scan: MachineHost | None = None

    @property
    def timeout(self) -> float:
        """Seconds an answered request waits for its answer (default 0.1)."""
        return self._machine.timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        self._machine.timeout = LssMaster(value).timeout  # (checked there)

    # ---------------------------------------------------------------- services

    def switch_global(self, state: LssState | int) -> None:
        """Every slave to waiting (0) or configuration (1); no answer."""
        self._host_of().run(lambda now: self._machine.switch_global(state))

    async def select(self, identity: LssIdentity) -> None:
        """The slave with ``identity`` to configuration state."""
        await self._ask(lambda now: self._machine.switch_selective(identity, now))

    async def configure_node_id(self, node_id: int) -> None:
        """The slave in configuration takes ``node_id`` (1..127, or 0xFF to remove it); it
        uses it after its next reset (at once, for a device that had none, when switched
        back to waiting)."""
        self._confirmed(await self._ask(lambda now: self._machine.configure_node_id(node_id, now)))

    async def configure_bit_rate(self, kbits: int) -> None:
        """The slaves in configuration take ``kbits`` (1000, 800, 500, 250, 125, 50, 20, 10)."""
        index = bit_timing_index(kbits)
        self._confirmed(await self._ask(lambda now: self._machine.configure_bit_timing(index, now)))

    def activate_bit_rate(self, delay: float) -> None:
        """The slaves in configuration switch to the configured bit rate: silent for
        ``delay`` seconds, switch, silent for ``delay`` again; no answer."""
        self._host_of().run(lambda now: self._machine.activate_bit_timing(delay))

    async def store(self) -> None:
        """The slave in configuration stores its node-ID and bit rate."""
        self._confirmed(await self._ask(self._machine.store))

    async def inquire(self, what: str) -> int:
        """The slave in configuration's vendor, product, revision, serial or node_id."""
        event = await self._ask(lambda now: self._machine.inquire(what, now))
        assert isinstance(event, LssInquired)
        return event.value

    async def inquire_identity(self) -> LssIdentity:
        """The whole identity of the slave in configuration."""
        values = [await self.inquire(what) for what in ("vendor", "product", "revision", "serial")]
        return LssIdentity(*values)

    async def identify_unconfigured(self) -> bool:
        """Whether any slave without a node-ID is on the bus."""
        return await self._identified(self._machine.identify_unconfigured)

    async def identify_remote(
        self, vendor: int, product: int, revisions: tuple[int, int], serials: tuple[int, int]
    ) -> bool:
        """Whether a slave of ``vendor`` and ``product`` has a revision and a serial in the
        ranges (bounds included)."""
        return await self._identified(
            lambda now: self._machine.identify_remote(vendor, product, revisions, serials, now)
        )

    async def fastscan(
        self,
        known: dict[str, int] | None = None,
        *,
        floor: float = 0.01,
        ceiling: float = 0.5,
        on_event: Callable[[Event], object] | None = None,
    ) -> LssIdentity | None:
        """Find one slave without a node-ID and put it into configuration state: its
        identity, or None when no unconfigured slave answered. ``known`` fields are confirmed,
        not scanned; ``on_event`` sees the scan's progress (estimate, each field found)."""
        scan = Fastscan(known, floor=floor, ceiling=ceiling)
        done: asyncio.Future[Event] = self._network.loop.create_future()

        def seen(event: Event) -> None:
            if on_event is not None:
                on_event(event)
            final = isinstance(event, FastscanFound | FastscanNothingFound | FastscanFailed)
            if final and not done.done():
                done.set_result(event)

        async with self._turn():
            host = self._network.attach(scan, (LSS_SLAVE_COB_ID,), seen)
            try:
                host.run(scan.start)
                event = await done
            finally:
                host.close()
        if isinstance(event, FastscanFailed):
            raise LssScanError(f"fastscan: the {event.field} could not be settled: {event.reason}")
        if isinstance(event, FastscanNothingFound):
            return None
        assert isinstance(event, FastscanFound)
        if event.answers > 1:
            raise LssScanError(
                f"fastscan: {event.answers} devices answer as {event.identity}: two devices "
                "share one identity; give them their node-IDs another way"
            )
        return event.identity

    # ---------------------------------------------------------------- plumbing

    def _host_of(self) -> MachineHost:
        if self._host is None:
            self._host = self._network.attach(self._machine, (LSS_SLAVE_COB_ID,), self._on_event)
        return self._host

    def _turn(self) -> asyncio.Lock:
        if self._lock is None:
            self._lock = asyncio.Lock()
        return self._lock

    def _on_event(self, event: Event) -> None:
        if isinstance(event, LssStrayAnswer):
            self._network.emit(event)
            return
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(event)

    async def _ask(self, call: Callable[[float], Out]) -> Event:
        async with self._turn():
            host = self._host_of()
            self._waiter = self._network.loop.create_future()
            try:
                host.run(call)
                event = await self._waiter
            finally:
                self._waiter = None
                self._machine.cancel()
        if isinstance(event, LssNoAnswer):
            why = _NO_ANSWER.get(event.service) or "no slave is in configuration state"
            raise LssTimeoutError(
                f"{event.service}: no answer within {event.timeout * 1000:.0f} ms: {why}"
            )
        return event

    async def _identified(self, call: Callable[[float], Out]) -> bool:
        try:
            event = await self._ask(call)
        except LssTimeoutError:
            return False
        return isinstance(event, LssIdentified)

    @staticmethod
    def _confirmed(event: Event) -> None:
        assert isinstance(event, LssConfirmed)
        if not event.ok:
            raise LssRefusedError(event.service, event.error, event.spec, event.text)


__all__ += ["LssSelected"]  # (the event of select, for listeners)
