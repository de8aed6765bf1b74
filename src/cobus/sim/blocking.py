"""Simulated benches for blocking code: :func:`start_rig` runs a rig on a blocking
:class:`~cobus.runtime.Network`, and gives it back as a :class:`BlockingRig`.

On the simulated clock the devices only run while the network does (``net.sleep()``, or any
blocking call waiting for an answer), exactly as the master side does.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from cobus.runtime.twin import BlockingTwin
from cobus.sim.base import SimulatedDevice
from cobus.sim.rig import Rig, ready_rig

if TYPE_CHECKING:
    from cobus.runtime import Network

__all__ = ["BlockingRig", "BlockingSimulatedDevice", "start_rig"]


class BlockingSimulatedDevice(BlockingTwin, twin_of=SimulatedDevice):
    """A simulated device for blocking code: power, status, faults and (forwarded) whatever
    its kind adds (``rig.device(9).set_potentiometer(0.5)``)."""


class BlockingRig(BlockingTwin, twin_of=Rig):
    """A running rig for blocking code (see :class:`cobus.sim.rig.Rig`): ``device(node)``,
    ``inject(node, fault)``, ``status()``, ``stop()``."""


def start_rig(network: Network, rig: Rig | str | Path) -> BlockingRig:
    """Start ``rig`` on ``network``: a :class:`Rig`, a rig file, or the name of a rig cobus
    ships (``"thesis"``). Its devices boot at once and run until ``stop()`` or the network
    closes."""
    if not isinstance(rig, Rig):
        path = Path(rig)
        rig = Rig.load(
            path if path.suffix in (".yaml", ".yml") or path.exists() else ready_rig(str(rig))
        )
    network.run(rig.start(network.aio))
    return BlockingRig(rig, network._runner)
