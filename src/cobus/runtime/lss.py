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
    LssError,
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
from cobus.runtime.errors import (
    LssRefusedError,
    LssScanError,
    LssTimeoutError,
    NetworkClosedError,
)

if TYPE_CHECKING:
    from cobus.runtime.network import AsyncNetwork, MachineHost

__all__ = ["AsyncNetworkLss"]

_IDENTIFIED, _UNCONFIGURED_IDENTIFIED = 0x4F, 0x50  # (answers several slaves give)
_NO_ANSWER = {
    "switch state selective": "no slave has that identity (or it is not in waiting state)",
    "identify remote slave": "",
    "identify non-configured slave": "",
}


_U32 = 0xFFFF_FFFF


class AsyncNetworkLss:
    """The LSS master of a network (``net.lss``)."""

    def __init__(self, network: AsyncNetwork, timeout: float = 0.1) -> None:
        self._network = network
        self._machine = LssMaster(timeout)
        self._host: MachineHost | None = None
        self._waiter: asyncio.Future[Event] | None = None
        self._lock: asyncio.Lock | None = None
        self._scan: asyncio.Future[Event] | None = None  # the fastscan under way
        network.on_disconnect(self._disconnected)

    @property
    def timeout(self) -> float:
        """Seconds an answered request waits for its answer (default 0.1)."""
        return self._machine.timeout

    @timeout.setter
    def timeout(self, value: float) -> None:
        self._machine.timeout = LssMaster(value).timeout  # (checked there)

    @property
    def _settle(self) -> float:
        """Seconds the other answers to one request get to come in (a twentieth of the
        timeout, at least 2 ms)."""
        return max(0.002, self._machine.timeout / 20)

    # ---------------------------------------------------------------- services

    def switch_global(self, state: LssState | int) -> None:
        """Every slave to waiting (0) or configuration (1); no answer."""
        self._not_during_a_request("switch state global")
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
        self._not_during_a_request("activate bit timing")
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

    async def identify_all(
        self,
        vendor: int,
        product: int,
        revision: int | None = None,
        *,
        on_found: Callable[[LssIdentity], object] | None = None,
    ) -> list[LssIdentity]:
        """Every device of ``vendor`` and ``product`` (and ``revision``, if given), with a
        node-ID or without: their identities, found by halving ranges of serial numbers
        (then of revisions) with "identify remote slave". A range no device answers costs
        one timeout; each device about 64 requests per field searched, and each value found
        is asked once more after a quiet timeout (a late answer makes no phantom device)."""
        full = (0, _U32)
        revisions = full if revision is None else (revision, revision)
        found: list[LssIdentity] = []
        for serial in await self._halve(vendor, product, revisions, None):
            if revision is not None:
                revs = [revision]
            else:
                revs = await self._halve(vendor, product, None, (serial, serial))
            for rev in revs:
                identity = LssIdentity(vendor, product, rev, serial)
                found.append(identity)
                if on_found is not None:
                    on_found(identity)
        return found

    async def find_revisions(self, vendor: int, product: int, serial: int) -> list[int]:
        """The revisions of the devices of ``vendor`` and ``product`` with ``serial``, with
        a node-ID or without (one, unless two devices differ only in their revision), found
        by halving ranges with "identify remote slave": about 33 requests for one device."""
        return await self._halve(vendor, product, None, (serial, serial))

    async def slowscan(
        self, vendor: int, product: int, revisions: tuple[int, int], serials: tuple[int, int]
    ) -> LssIdentity | None:
        """The lowest identity of a device of ``vendor`` and ``product`` with a revision and
        a serial in the ranges (bounds included), found by halving them with "identify
        remote slave": the revision first, then the serial; None when no device answers.
        Several devices may answer one request: each answer is let settle before the next
        request, and the value found is asked once more after a quiet timeout."""

        async def ask(revs: tuple[int, int], sers: tuple[int, int]) -> bool:
            if await self.identify_remote(vendor, product, revs, sers):
                await asyncio.sleep(self._settle)
                return True
            return False

        async def lowest(field: str, span: tuple[int, int]) -> int | None:
            low, high = span
            while low < high:
                middle = (low + high) // 2
                half = (low, middle)
                if await (ask(half, serials) if field == "revision" else ask((rev, rev), half)):
                    high = middle
                else:
                    low = middle + 1
            await asyncio.sleep(self._machine.timeout)  # (a late answer passes first)
            one = (low, low)
            found = await (ask(one, serials) if field == "revision" else ask((rev, rev), one))
            return low if found else None

        rev = 0
        if not await ask(revisions, serials):
            return None
        revision = await lowest("revision", revisions)
        if revision is None:
            return None
        rev = revision
        serial = await lowest("serial", serials)
        return None if serial is None else LssIdentity(vendor, product, revision, serial)

    async def _halve(
        self,
        vendor: int,
        product: int,
        revisions: tuple[int, int] | None,
        serials: tuple[int, int] | None,
    ) -> list[int]:
        """The revisions (``revisions`` None) or serials (``serials`` None) some device of
        ``vendor`` and ``product`` answers for, the other field within its range."""
        out: list[int] = []
        todo = [(0, _U32)]
        while todo:
            span = todo.pop()
            asked = await self.identify_remote(
                vendor, product, revisions or span, span if serials is None else serials
            )
            if not asked:
                continue
            # several devices may answer one request: let the others' answers pass before
            # the next one, so that none is taken for its answer
            await asyncio.sleep(self._settle)
            low, high = span
            if low == high:
                # a late answer to the request before may have looked like this one's: ask
                # once more after a quiet timeout, and keep what answers again
                await asyncio.sleep(self._machine.timeout)
                if await self.identify_remote(
                    vendor, product, revisions or span, span if serials is None else serials
                ):
                    out.append(low)
                    await asyncio.sleep(self._settle)
                continue
            middle = (low + high) // 2
            todo += [(middle + 1, high), (low, middle)]
        return out

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
            final = isinstance(event, FastscanFound | FastscanNothingFound | FastscanFailed)
            if final and not done.done():
                done.set_result(event)
            if on_event is not None:
                try:
                    on_event(event)
                except Exception as exc:  # the caller's callback must not stop the scan
                    self._network.report_failure("fastscan on_event", exc)

        async with self._turn():
            self._check_connected()
            host = self._network.attach(scan, (LSS_SLAVE_COB_ID,), seen)
            self._scan = done
            try:
                host.run(scan.start)
                event = await done
            finally:
                self._scan = None
                host.close()
            if isinstance(event, FastscanFailed):
                raise LssScanError(
                    f"fastscan: the {event.field} could not be settled: {event.reason}"
                )
            if isinstance(event, FastscanNothingFound):
                return None
            assert isinstance(event, FastscanFound)
            identity = event.identity
            if event.answers > 1:
                self._machine_out(lambda now: self._machine.switch_global(LssState.WAITING))
                raise LssScanError(
                    f"fastscan: {event.answers} devices answer as {identity}: two devices "
                    "share one identity; give them their node-IDs another way"
                )
            # a late answer can make a wrong bit look confirmed: the selected slave says
            serial = await self._inquired("serial")
            if serial != identity.serial:
                self._machine_out(lambda now: self._machine.switch_global(LssState.WAITING))
                said = "no slave is in configuration" if serial is None else f"0x{serial:08X}"
                raise LssScanError(
                    f"fastscan found serial 0x{identity.serial:08X} but the selected slave "
                    f"says {said}: answers came later than the wait (raise the ceiling, now "
                    f"{ceiling} s)"
                )
        return identity

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
            # several slaves answer an identify request or a fastscan probe: not stray
            if event.data[0] not in (_IDENTIFIED, _UNCONFIGURED_IDENTIFIED):
                self._network.emit(event)
            return
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(event)

    def _not_during_a_request(self, service: str) -> None:
        """A request without an answer must not cut into one under way (a fastscan)."""
        if self._lock is not None and self._lock.locked():
            raise LssError(f"{service}: an LSS request is under way; await it first")
        self._check_connected()

    def _check_connected(self) -> None:
        if not self._network.connected:
            raise NetworkClosedError("the network is not connected: no LSS request can go out")

    def _disconnected(self) -> None:
        closed = NetworkClosedError("the network was disconnected during an LSS request")
        for waiting in (self._waiter, self._scan):
            if waiting is not None and not waiting.done():
                waiting.set_exception(closed)

    def _machine_out(self, call: Callable[[float], Out]) -> None:
        self._host_of().run(call)

    async def _inquired(self, what: str) -> int | None:
        """An inquiry inside a turn already held: the value, or None without an answer."""
        try:
            event = await self._exchange(lambda now: self._machine.inquire(what, now))
        except LssTimeoutError:
            return None
        assert isinstance(event, LssInquired)
        return event.value

    async def _ask(self, call: Callable[[float], Out]) -> Event:
        async with self._turn():
            return await self._exchange(call)

    async def _exchange(self, call: Callable[[float], Out]) -> Event:
        self._check_connected()
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
