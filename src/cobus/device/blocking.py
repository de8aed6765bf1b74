"""The blocking face of a :class:`~cobus.device.Device` (``Network.add_device``).

Each call runs on the network's event loop and returns its result. Read and write callbacks
(:meth:`BlockingDevice.on_read`, :meth:`BlockingDevice.on_write`) run on the loop itself,
because the device needs their answer at once: keep them short and thread-safe. Listeners run
where the network runs user callbacks (a callback thread in real time, inline on the simulated
clock).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cobus.proto.emcy import ErrorRegister
from cobus.proto.nmt import NmtCommand, NmtState

if TYPE_CHECKING:
    from cobus.device.device import Device, Key, Listener
    from cobus.runtime.blocking import Runner

__all__ = ["BlockingDevice"]


class BlockingDevice:
    """A device for blocking code; ``aio`` is the :class:`~cobus.device.Device` itself."""

    def __init__(self, device: Device, runner: Runner) -> None:
        self.aio = device
        self._runner = runner

    def __repr__(self) -> str:
        return f"Blocking{self.aio!r}"

    @property
    def node_id(self) -> int:
        return self.aio.node_id

    @node_id.setter
    def node_id(self, node_id: int) -> None:
        self._runner.call(self.aio.set_node_id, node_id)

    @property
    def state(self) -> NmtState:
        return self.aio.state

    @property
    def error_register(self) -> ErrorRegister:
        return self._runner.call(lambda: self.aio.error_register)

    def get(self, index: Key, subindex: Key = 0) -> Any:
        return self._runner.call(self.aio.get, index, subindex)

    def set(self, index: Key, subindex: Key, value: Any) -> None:
        self._runner.call(self.aio.set, index, subindex, value)

    def on_read(self, index: Key, subindex: Key, fn: Callable[[], Any] | None) -> None:
        self._runner.call(self.aio.on_read, index, subindex, fn)

    def on_write(self, index: Key, subindex: Key, fn: Callable[[Any], object] | None) -> None:
        self._runner.call(self.aio.on_write, index, subindex, fn)

    def add_listener(self, listener: Listener) -> None:
        self._runner.call(self.aio.add_listener, self._runner.callback(listener))

    def send_emergency(
        self, code: int, register: int | None = None, manufacturer: bytes = b"", *, info: int = 0
    ) -> None:
        self._runner.call(lambda: self.aio.send_emergency(code, register, manufacturer, info=info))

    def clear_emergency(self, code: int | None = None) -> None:
        self._runner.call(self.aio.clear_emergency, code)

    def send_tpdo(self, number: int) -> None:
        self._runner.call(self.aio.send_tpdo, number)

    def apply_nmt(self, command: NmtCommand | int) -> None:
        self._runner.call(self.aio.apply_nmt, command)

    def store_parameters(self, subindex: int = 1) -> None:
        self._runner.call(self.aio.store_parameters, subindex)

    def restore_defaults(self, subindex: int = 1) -> None:
        self._runner.call(self.aio.restore_defaults, subindex)

    def to_eds(self) -> str:
        return self._runner.call(self.aio.to_eds)

    def save_eds(self, path: str | Path) -> None:
        self._runner.call(self.aio.save_eds, path)

    def close(self) -> None:
        self._runner.call(self.aio.close)
