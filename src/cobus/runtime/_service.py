"""What the services of a remote node share: user callbacks, the error of a removed node,
and the checks of values and commands given by the user."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from cobus.proto.nmt import NmtCommand
from cobus.runtime.errors import NetworkClosedError

if TYPE_CHECKING:
    from cobus.od import Variable
    from cobus.runtime.network import AsyncNetwork

E = TypeVar("E")


class Callbacks(Generic[E]):
    """The user callbacks of one service, called in the order they were added; one that
    raises is reported (a :class:`~cobus.runtime.events.HandlerFailed` event) and the others
    still run."""

    __slots__ = ("_callbacks", "_network", "_where")

    def __init__(self, network: AsyncNetwork, where: str) -> None:
        self._network = network
        self._where = where
        self._callbacks: list[Callable[[E], object]] = []

    def add(self, callback: Callable[[E], object]) -> None:
        self._callbacks.append(callback)

    def remove(self, callback: Callable[[E], object]) -> None:
        if callback in self._callbacks:
            self._callbacks.remove(callback)

    def __len__(self) -> int:
        return len(self._callbacks)

    def __bool__(self) -> bool:
        return bool(self._callbacks)

    def __call__(self, event: E) -> None:
        for callback in list(self._callbacks):
            try:
                callback(event)
            except Exception as exc:
                self._network.report_failure(f"callback of {self._where}", exc)


class Waiters(Generic[E]):
    """The operations waiting for an event of a service (``wait_for_bootup()``...): each
    ends with the first event its test accepts, with the error ``on_timeout`` makes when the
    time is up, or with the service's end (:meth:`fail`)."""

    __slots__ = ("_items", "_network")

    def __init__(self, network: AsyncNetwork) -> None:
        self._network = network
        self._items: list[tuple[Callable[[E], bool], asyncio.Future[E]]] = []

    def __bool__(self) -> bool:
        """Whether any operation waits."""
        return bool(self._items)

    async def wait(
        self,
        timeout: float,
        on_timeout: Callable[[], Exception],
        match: Callable[[E], bool] = lambda event: True,
    ) -> E:
        future: asyncio.Future[E] = self._network.loop.create_future()
        item = (match, future)
        self._items.append(item)
        try:
            return await asyncio.wait_for(future, timeout)
        except TimeoutError:
            raise on_timeout() from None
        finally:
            if item in self._items:
                self._items.remove(item)

    def resolve(self, event: E) -> None:
        """End the waits whose test accepts ``event``."""
        if not self._items:  # the common case: asked for every heartbeat and TPDO
            return
        for match, future in list(self._items):
            if not future.done() and match(event):
                future.set_result(event)

    def fail(self, error: Exception) -> None:
        """End every wait with ``error``."""
        for _, future in self._items:
            if not future.done():
                future.set_exception(error)


def removed_error(node_id: int) -> NetworkClosedError:
    """The error of an operation on a node taken off the network with ``remove_remote``."""
    return NetworkClosedError(
        f"node {node_id} was removed from the network (remove_remote): add it again with "
        "add_remote()"
    )


def check_not_bool(var: Variable, value: Any) -> None:
    """Refuse True/False for an integer object: Python counts them as 1 and 0, a user who
    writes ``True`` into a mode of operation has most likely mistaken the object."""
    from cobus.od import ValueRangeError

    if isinstance(value, bool) and var.data_type.is_integer:
        raise ValueRangeError(
            f"{value!r} is a bool but the object is {var.data_type.name}: give a number"
        )


def parse_nmt_command(command: NmtCommand | int | str) -> NmtCommand | int:
    """An NMT command from its enum, number or name (``"start"``, ``"reset-node"``...)."""
    if not isinstance(command, str):
        return command
    try:
        return NmtCommand[command.upper().replace("-", "_").replace(" ", "_")]
    except KeyError:
        names = ", ".join(c.name.lower() for c in NmtCommand)
        raise ValueError(f"unknown NMT command {command!r}; use one of {names}") from None
