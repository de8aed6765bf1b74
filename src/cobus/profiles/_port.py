"""The narrow port a drive profile talks through: SDO bytes, the newest TPDO value of an
object, RPDO outputs, the last emergency. One implementation per kind of node: a bare
:class:`~cobus.runtime.remote.AsyncRemoteNode`, or a node the :class:`~cobus.master.Master`
manages (its process image carries the PDOs)."""

from __future__ import annotations

import asyncio
import contextlib
import functools
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

from cobus.proto import Frame

if TYPE_CHECKING:
    from cobus.master.master import Master
    from cobus.master.node import ManagedNode
    from cobus.od import ObjectDictionary
    from cobus.runtime.emcy import Emergency
    from cobus.runtime.network import AsyncNetwork
    from cobus.runtime.pdo import PdoReceived
    from cobus.runtime.remote import AsyncRemoteNode

__all__ = ["DrivePort", "ManagedNodePort", "RemoteNodePort", "port_for"]

Key = tuple[int, int]


class DrivePort(Protocol):
    """What a drive profile needs from the node it runs."""

    node_id: int
    network: AsyncNetwork
    #: The node's dictionary (from its EDS), or None.
    od: ObjectDictionary | None

    async def upload(self, index: int, subindex: int) -> bytes: ...
    async def download(self, index: int, subindex: int, data: bytes) -> None: ...

    def input(self, index: int, subindex: int) -> tuple[Any, float] | None:
        """The raw value of an object as its last TPDO carried it, and when (None: no
        TPDO maps it, or none came yet)."""

    def add_input_callback(self, callback: Callable[[int, float], object]) -> None:
        """Call ``callback(tpdo_number, now)`` after each TPDO of the node was taken."""

    def remove_input_callback(self, callback: Callable[[int, float], object]) -> None: ...

    def set_outputs(self, values: Mapping[Key, int], *, always: bool = False) -> bool:
        """Put raw values into the RPDOs that map the objects and send each RPDO once as it
        is configured (``always``: even when no value changed). False when an object is in
        no RPDO the port sends (nothing is set), or while the RPDOs do not go out (the
        values are kept for when they do): the caller writes by SDO then."""

    def last_emergency(self) -> Emergency | None: ...

    def send_cyclic(self, values: Mapping[Key, int]) -> bool:
        """Send ``values`` by the RPDO that carries them (every object it maps is among
        them), now: a set-point of a cyclic mode. False when no such RPDO is configured."""

    def maps(self, index: int, subindex: int) -> bool:
        """Whether an RPDO the port sends maps the object."""

    async def settle(self, timeout: float) -> bool:
        """Wait until the values given to :meth:`set_outputs` reached the node and took
        effect (synchronous RPDOs: sent after the next SYNC, applied at the one after);
        False when no SYNC came within ``timeout``."""

    def close(self) -> None:
        """Stop listening to the node."""


class RemoteNodePort:
    """A bare remote node: SDO through its channel, inputs from the TPDOs whose mapping was
    read or loaded (``node.tpdo.read()``); outputs go by SDO (an RPDO of a bare node would
    send its other mapped objects too, with values the drive does not own)."""

    def __init__(self, node: AsyncRemoteNode) -> None:
        self.node = node
        self.node_id = node.node_id
        self.network = node.network
        self.od = node.od
        self._values: dict[Key, tuple[Any, float]] = {}
        self._callbacks: list[Callable[[int, float], object]] = []
        self._watched: set[int] = set()
        self._bound: dict[int, Callable[[PdoReceived], None]] = {}
        self._cyclic: dict[frozenset[Key], Any] = {}

    def _watch(self) -> None:
        for pdo in self.node.tpdo:
            if pdo.number in self._watched:
                continue
            self._watched.add(pdo.number)
            bound = self._bound[pdo.number] = functools.partial(self._taken, pdo)
            pdo.add_callback(bound)

    def _taken(self, pdo: Any, event: PdoReceived) -> None:
        for field in pdo.fields:
            if not field.dummy and field.name in event.values:
                key = (field.entry.index, field.entry.subindex)
                self._values[key] = (event.values[field.name], event.time)
        for callback in list(self._callbacks):
            callback(pdo.number, event.time)

    async def upload(self, index: int, subindex: int) -> bytes:
        return await self.node.sdo.upload(index, subindex)

    async def download(self, index: int, subindex: int, data: bytes) -> None:
        await self.node.sdo.download(index, subindex, data)

    def input(self, index: int, subindex: int) -> tuple[Any, float] | None:
        self._watch()
        return self._values.get((index, subindex))

    def add_input_callback(self, callback: Callable[[int, float], object]) -> None:
        self._watch()
        self._callbacks.append(callback)

    def remove_input_callback(self, callback: Callable[[int, float], object]) -> None:
        if callback in self._callbacks:
            self._callbacks.remove(callback)

    def set_outputs(self, values: Mapping[Key, int], *, always: bool = False) -> bool:
        return False

    def send_cyclic(self, values: Mapping[Key, int]) -> bool:
        keys = frozenset(values)
        pdo = self._cyclic.get(keys)
        if pdo is None:
            for candidate in self.node.rpdo:
                mapped = {
                    (f.entry.index, f.entry.subindex) for f in candidate.fields if not f.dummy
                }
                if candidate.enabled and mapped and mapped <= keys and next(iter(values)) in mapped:
                    pdo = self._cyclic[keys] = candidate
                    break
            else:
                return False
        for key in values:
            if key in pdo:
                pdo[key] = values[key]
        pdo.transmit()
        return True

    def maps(self, index: int, subindex: int) -> bool:
        return any(
            pdo.enabled and (index, subindex) in pdo for pdo in self.node.rpdo if pdo.configured
        )

    async def settle(self, timeout: float) -> bool:
        return True

    def close(self) -> None:
        for pdo in self.node.tpdo:
            if pdo.number in self._watched:
                with contextlib.suppress(ValueError, KeyError):
                    pdo.remove_callback(self._bound[pdo.number])
        self._watched.clear()
        self._callbacks.clear()

    def last_emergency(self) -> Emergency | None:
        return self.node.emcy.last


class ManagedNodePort:
    """A node the master manages: inputs and outputs through its process image (raw values:
    a signal's scale and offset are undone), SDO through the master's link to it."""

    def __init__(self, node: ManagedNode) -> None:
        self.managed = node
        self.master: Master = node.master
        self.node_id = node.node_id
        self.network = self.master.network
        self.od: ObjectDictionary | None = node.config.od
        self._sync_pending = False
        self._callbacks: list[Callable[[int, float], object]] = []
        self._times: dict[int, float] = {}
        self.master.add_tpdo_listener(self._taken)

    def _taken(self, node_id: int, number: int, now: float) -> None:
        if node_id != self.node_id:
            return
        self._times[number] = now
        for callback in list(self._callbacks):
            callback(number, now)

    def _signal(self, table: dict[str, Any], index: int, subindex: int) -> Any:
        for sig in table.values():
            if sig.node_id == self.node_id and (sig.index, sig.subindex) == (index, subindex):
                return sig
        return None

    async def upload(self, index: int, subindex: int) -> bytes:
        return await self.managed.sdo.upload(index, subindex)

    async def download(self, index: int, subindex: int, data: bytes) -> None:
        await self.managed.sdo.download(index, subindex, data)

    def input(self, index: int, subindex: int) -> tuple[Any, float] | None:
        image = self.master.image
        sig = self._signal(image.inputs_by_name, index, subindex)
        if sig is None or sig.pdo not in self._times:
            return None
        value = image.read_input(sig.name)
        if sig.scale is not None or sig.offset:
            value = round((value - sig.offset) / (sig.scale or 1.0))
        return value, self._times[sig.pdo]

    def add_input_callback(self, callback: Callable[[int, float], object]) -> None:
        self._callbacks.append(callback)

    def remove_input_callback(self, callback: Callable[[int, float], object]) -> None:
        if callback in self._callbacks:
            self._callbacks.remove(callback)

    def set_outputs(self, values: Mapping[Key, int], *, always: bool = False) -> bool:
        shown: dict[str, Any] = {}
        for (index, subindex), value in values.items():
            sig = self._signal(self.master.image.outputs_by_name, index, subindex)
            if sig is None:
                return False
            scaled: Any = value
            if sig.scale is not None or sig.offset:
                scaled = value * (sig.scale or 1.0) + sig.offset
            shown[sig.name] = scaled
        self.master.set_outputs(shown, always=always)
        sending = self.managed.operational and self.master.running
        if sending and any(
            self.master.rpdos.layouts[(self.node_id, sig.pdo)].transmission_type <= 240
            for sig in (self._signal(self.master.image.outputs_by_name, *key) for key in values)
            if sig is not None
        ):
            self._sync_pending = True
        return sending

    def maps(self, index: int, subindex: int) -> bool:
        return self._signal(self.master.image.outputs_by_name, index, subindex) is not None

    async def settle(self, timeout: float) -> bool:
        if not self._sync_pending:
            return True
        self._sync_pending = False
        loop = self.network.loop
        seen: list[float] = []
        done: asyncio.Future[None] = loop.create_future()

        def on_sync(frame: Frame, now: float) -> None:
            seen.append(now)
            if len(seen) >= 2 and not done.done():  # sent after one, applied at the next
                done.set_result(None)

        subscription = self.network.subscribe(self.master.config.master.sync_cob_id, on_sync)
        try:
            await asyncio.wait_for(done, timeout)
        except TimeoutError:
            return False
        finally:
            subscription.cancel()
        return True

    def send_cyclic(self, values: Mapping[Key, int]) -> bool:
        first = next(iter(values))
        if self._signal(self.master.image.outputs_by_name, *first) is None:
            return False
        known = {
            key: value
            for key, value in values.items()
            if self._signal(self.master.image.outputs_by_name, *key) is not None
        }
        return self.set_outputs(known, always=True)

    def last_emergency(self) -> Emergency | None:
        history = self.managed.emcy_history
        return history[0] if history else None

    def close(self) -> None:
        self.master.remove_tpdo_listener(self._taken)


def port_for(node: Any) -> DrivePort:
    """The port to a node: a :class:`AsyncRemoteNode`, a master's :class:`ManagedNode`, or the
    blocking twin of either (its async object is used)."""
    from cobus.master.node import ManagedNode
    from cobus.runtime.remote import AsyncRemoteNode

    aio = getattr(node, "aio", node)
    if isinstance(aio, AsyncRemoteNode):
        return RemoteNodePort(aio)
    if isinstance(aio, ManagedNode):
        return ManagedNodePort(aio)
    raise TypeError(
        f"a drive runs on a RemoteNode (net.add_remote(...)) or a node the master manages "
        f"(AsyncDrive402(master.node('name')) in async code, Drive402(master, 'name') with a "
        f"BlockingMaster), not on {type(node).__name__}"
    )
