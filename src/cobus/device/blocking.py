"""The blocking face of a :class:`~cobus.device.Device` (``add_device(network, ...)``).

It is generated from :class:`~cobus.device.Device` (see :mod:`cobus.runtime.twin`): every
method runs on the network's event loop and returns its result. Read and write callbacks
(``on_read``, ``on_write``) run on the loop itself, because the device needs their answer at
once: keep them short and thread-safe. Listeners (``add_listener``) run where the network runs
user callbacks (a callback thread in real time, inline on the simulated clock).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cobus.device.device import Device
from cobus.device.simulation import Simulation
from cobus.runtime.twin import BlockingTwin

if TYPE_CHECKING:
    from cobus.device.device import Key
    from cobus.od import ObjectDictionary
    from cobus.proto.emcy import ErrorRegister
    from cobus.proto.nmt import NmtState

__all__ = ["BlockingDevice", "BlockingSimulation"]


class BlockingDevice(BlockingTwin, twin_of=Device):
    """A device for blocking code; ``aio`` is the :class:`~cobus.device.Device` itself."""

    if TYPE_CHECKING:
        aio: Device
        node_id: int
        od: ObjectDictionary
        state: NmtState
        error_register: ErrorRegister
        simulation: BlockingSimulation

        def get(self, index: Key, subindex: Key = 0) -> Any: ...
        def set(self, index: Key, subindex: Key, value: Any) -> None: ...
        def on_read(self, index: Key, subindex: Key, fn: Callable[[], Any] | None) -> None: ...
        def on_write(
            self, index: Key, subindex: Key, fn: Callable[[Any], object] | None
        ) -> None: ...
        def to_eds(self) -> str: ...


class BlockingSimulation(BlockingTwin, twin_of=Simulation):
    """``device.simulation`` of a :class:`BlockingDevice`: its settings are read and changed
    on the network's loop."""

    if TYPE_CHECKING:
        aio: Simulation
        sdo_response_delay: float
        heartbeat_muted: bool
