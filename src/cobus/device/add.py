"""``add_device(network, node_id, od)``: a device attached to a network and started, in one
call, for the blocking :class:`~cobus.runtime.Network` and the :class:`~cobus.runtime.AsyncNetwork`.

The runtime knows no device: a device attaches itself to a network, claiming its node-ID in
``network.devices``. This is the convenience that used to be the network's own
``add_device`` method::

    dev = add_device(net, 5, od)         # was: dev = net.add_device(5, od)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, overload

from cobus.device.blocking import BlockingDevice
from cobus.device.device import Device
from cobus.device.errors import DeviceConfigError
from cobus.od import ObjectDictionary
from cobus.runtime import AsyncNetwork, Network
from cobus.runtime.remote import load_od

__all__ = ["add_device"]


@overload
def add_device(
    network: Network, node_id: int, od: ObjectDictionary | str | Path, **options: Any
) -> BlockingDevice: ...


@overload
def add_device(
    network: AsyncNetwork, node_id: int, od: ObjectDictionary | str | Path, **options: Any
) -> Device: ...


def add_device(
    network: Network | AsyncNetwork,
    node_id: int,
    od: ObjectDictionary | str | Path,
    **options: Any,
) -> Device | BlockingDevice:
    """A CANopen device (slave) with node-ID ``node_id`` on ``network``, serving ``od`` (an
    object dictionary, or an EDS/DCF path), started at once (boot-up message,
    pre-operational). On a blocking :class:`~cobus.runtime.Network` it is a
    :class:`BlockingDevice`. ``options`` are those of :class:`Device`; a node-ID another
    local device holds is a :class:`~cobus.device.NodeIdInUseError`."""
    if not isinstance(network, Network | AsyncNetwork):
        raise TypeError(
            f"add_device(network, node_id, od): {network!r} is not a cobus.runtime.Network or "
            "AsyncNetwork"
        )
    if od is None:
        raise DeviceConfigError(
            f"add_device: device {node_id} needs an object dictionary or an EDS/DCF path"
        )
    if isinstance(network, Network):
        blocking = network

        async def create() -> Device:
            return add_device(blocking.aio, node_id, od, **options)

        return BlockingDevice(network.run(create()), network._runner)
    dictionary = load_od(od, node_id)
    if dictionary is None:  # pragma: no cover - od was checked above
        raise DeviceConfigError(f"add_device: no object dictionary for device {node_id}")
    device = Device(network, node_id, dictionary, **options)
    try:
        device.start()
    except BaseException:
        device.close()
        raise
    return device
