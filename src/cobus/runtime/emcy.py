"""Emergencies of one remote node as its client sees them: ``node.emcy``.

Every emergency the node sends is kept (the last ``history`` ones) as an :class:`Emergency`
with the time it arrived and the CiA 301 text of its code; :attr:`AsyncRemoteEmcy.active` holds
the errors not yet cleared by an "error reset / no error" emergency (00xxh) of the node.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Final

from cobus._moved import renamed_names
from cobus.proto import Frame
from cobus.proto.emcy import EMCY_BASE, Emergency, MalformedEmcy, parse_emcy
from cobus.runtime._service import Callbacks, Waiters, removed_error
from cobus.runtime.errors import EmcyTimeoutError

if TYPE_CHECKING:
    from cobus.runtime.network import AsyncNetwork, Subscription

__all__ = ["AsyncRemoteEmcy", "EmcyTimeoutError", "Emergency", "error_still_shown"]


#: Error register bits (1001h) of the emergency code classes that have one.
_CLASS_BITS = {0x2: 0x02, 0x3: 0x04, 0x4: 0x08, 0x8: 0x10}


def _still_shown(emcy: Emergency, register: int) -> bool:
    """Whether ``register`` still shows the error ``emcy`` reported."""
    return error_still_shown(emcy.code, register)


def error_still_shown(code: int, register: int) -> bool:
    """Whether an error register (1001h) still shows an error of emergency ``code``: its
    class's bit (current, voltage, temperature, communication), else the generic bit."""
    bit = _CLASS_BITS.get(code >> 12, 0x01)
    return bool(register & bit)


class AsyncRemoteEmcy:
    """The emergencies of one remote node (see the module docstring)."""

    #: The node-ID.
    node_id: Final[int]
    #: The CAN identifier the node's emergencies arrive on (80h + node-ID unless changed).
    cob_id: int
    #: How many emergencies arrived in all (the log keeps only the last ``history``).
    count: int

    def __init__(self, network: AsyncNetwork, node_id: int, *, history: int = 64) -> None:
        self._network = network
        self._removed = False
        self.node_id = node_id
        self.cob_id = EMCY_BASE + node_id
        self.count = 0
        self._log: deque[Emergency] = deque(maxlen=history)
        self._active: list[Emergency] = []
        self._callbacks: Callbacks[Emergency] = Callbacks(network, f"EMCY of node {node_id}")
        self._waiters: Waiters[Emergency] = Waiters(network)
        self._subscription: Subscription | None = network.subscribe(self.cob_id, self._on_frame)

    def __repr__(self) -> str:
        return (
            f"<EMCY of node {self.node_id}: {len(self._log)} received, {len(self._active)} active>"
        )

    @property
    def log(self) -> list[Emergency]:
        """The emergencies received, oldest first (at most the last ``history``)."""
        return list(self._log)

    @property
    def active(self) -> list[Emergency]:
        """The errors the node reported and has not reset since, oldest first. An "error
        reset" emergency (00xxh) clears those whose class its error register no longer
        shows (current, voltage, temperature, communication; the others while the generic
        bit stays set), all of them when the register is 0."""
        return list(self._active)

    @property
    def last(self) -> Emergency | None:
        """The newest emergency (None: none yet)."""
        return self._log[-1] if self._log else None

    def clear(self) -> None:
        """Forget the emergencies received so far (and set the count back to 0)."""
        self.count = 0
        self._log.clear()
        self._active.clear()

    def set_cob_id(self, cob_id: int) -> None:
        """Receive the node's emergencies on ``cob_id`` (its 1014h) instead of 80h + id."""
        if self._removed:
            raise removed_error(self.node_id)
        if not isinstance(cob_id, int) or not 0x001 <= cob_id <= 0x7FF:
            raise ValueError(f"EMCY identifier {cob_id!r} is not an 11-bit identifier 1..7FFh")
        if self._subscription is not None:
            self._subscription.cancel()
        self.cob_id = cob_id
        self._subscription = self._network.subscribe(cob_id, self._on_frame)

    def add_callback(self, callback: Callable[[Emergency], object]) -> None:
        """Call ``callback(emergency)`` with each emergency of the node."""
        self._callbacks.add(callback)

    def remove_callback(self, callback: Callable[[Emergency], object]) -> None:
        """Stop calling ``callback`` (given to :meth:`add_callback`)."""
        self._callbacks.remove(callback)

    async def wait(self, timeout: float = 1.0) -> Emergency:
        """The node's next emergency; :class:`EmcyTimeoutError` after ``timeout`` seconds.

        It waits for one that arrives after the call: in real time, one the node sent just
        before may already be in :attr:`log` (a callback sees every one)."""
        if self._removed:
            raise removed_error(self.node_id)
        return await self._waiters.wait(
            timeout,
            lambda: EmcyTimeoutError(f"node {self.node_id} sent no emergency within {timeout:g} s"),
        )

    def _on_frame(self, frame: Frame, now: float) -> None:
        parsed = parse_emcy(frame, self.node_id)
        if isinstance(parsed, MalformedEmcy):
            self._network.emit(parsed)
            return
        emcy = Emergency.received(parsed, now)
        self._log.append(emcy)
        self.count += 1
        if emcy.is_reset:
            # what the error register still shows stays active (0: every error is gone)
            register = int(emcy.register)
            self._active = [e for e in self._active if register and _still_shown(e, register)]
        else:
            self._active = [e for e in self._active if e.code != emcy.code]
            self._active.append(emcy)
        self._waiters.resolve(emcy)
        self._callbacks(emcy)
        self._network.emit(parsed)

    def _close(self) -> None:
        self._removed = True
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        self._waiters.fail(removed_error(self.node_id))


#: The async classes are AsyncX, their blocking twins X (see :mod:`cobus`).
__getattr__ = renamed_names(__name__, {"RemoteEmcy": ("AsyncRemoteEmcy", AsyncRemoteEmcy)})
