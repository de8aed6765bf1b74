"""The master's RPDOs: when the outputs of the process image go to the nodes.

CiA 301's transmission types, from the master's side: a synchronous RPDO (1..240) goes with
every SYNC the master sees, an acyclic synchronous one (0) with the next SYNC after one of
its values changed, an event-driven one (254, 255) at once when a value changes and, with an
event timer, at least every half of it (the node's deadline monitoring expects it). Every
RPDO goes once when its node is started; none goes to a node that is not operational (the
node's :meth:`~cobus.master.node.ManagedNode.send_rpdo` checks), and none the master does
not send (a linked RPDO: another node's TPDO feeds it).
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from cobus.master.errors import MasterValueError

if TYPE_CHECKING:
    from cobus.master.config import PdoLayout
    from cobus.master.image import ProcessImage
    from cobus.master.node import ManagedNode
    from cobus.runtime import AsyncNetwork

__all__ = ["MasterRpdos"]


class MasterRpdos:
    """Sends the RPDOs of ``nodes`` from the process image ``image`` (``master.rpdos``)."""

    def __init__(
        self, network: AsyncNetwork, image: ProcessImage, nodes: Mapping[int, ManagedNode]
    ) -> None:
        self.network = network
        self.image = image
        self.nodes = nodes
        #: Every RPDO the network file gives, by (node-ID, number).
        self.layouts: dict[tuple[int, int], PdoLayout] = {
            (node_id, layout.number): layout
            for node_id, node in nodes.items()
            for layout in node.config.rpdos
        }
        self._timers: dict[tuple[int, int], asyncio.TimerHandle] = {}
        self._dirty: set[tuple[int, int]] = set()  # acyclic RPDOs changed since the SYNC

    def start(self) -> None:
        """The master starts: event-driven RPDOs with an event timer begin their refresh."""
        for (node_id, _number), layout in self.layouts.items():
            if layout.transmission_type >= 254 and layout.event_timer and not layout.linked:
                self._refresh(self.nodes[node_id], layout)

    def stop(self) -> None:
        """The master stops: no more refreshes."""
        for handle in self._timers.values():
            handle.cancel()
        self._timers.clear()

    def send_all(self, nodes: list[ManagedNode]) -> None:
        """Send every RPDO of ``nodes`` once (they were just started)."""
        for node in nodes:
            for layout in node.config.rpdos:
                node.send_rpdo(layout)

    def on_sync(self) -> None:
        """A SYNC while the network runs: the synchronous RPDOs go (acyclic ones if changed)."""
        dirty = self._dirty
        for (node_id, number), layout in self.layouts.items():
            if layout.transmission_type > 240 or layout.linked:
                continue
            node = self.nodes[node_id]
            if not node.operational:
                continue
            if layout.transmission_type == 0:
                if (node_id, number) not in dirty:
                    continue
                dirty.discard((node_id, number))
            node.send_rpdo(layout)

    def set_outputs(self, values: Mapping[str, Any], *, always: bool = False) -> None:
        """Set output signals; see :meth:`cobus.master.Master.set_outputs`."""
        touched: dict[tuple[int, int], bool] = {}
        for name, value in values.items():
            for node_id, number, changed in self.image.set_output(name, value):
                touched[(node_id, number)] = touched.get((node_id, number), False) or changed
        for key, changed in touched.items():
            layout = self.layouts[key]
            if layout.transmission_type >= 254:
                if changed or always:
                    self.nodes[key[0]].send_rpdo(layout)
            elif layout.transmission_type == 0 and changed:
                self._dirty.add(key)

    def send(self, node: ManagedNode, number: int) -> bool:
        """Send RPDO ``number`` of ``node`` now; see :meth:`cobus.master.Master.send_rpdo`."""
        layout = self.layouts.get((node.node_id, number))
        if layout is None or layout.linked:
            numbers = ", ".join(
                str(n)
                for (nid, n), lay in self.layouts.items()
                if nid == node.node_id and not lay.linked
            )
            raise MasterValueError(
                f"node {node.node_id} {node.name!r} has no RPDO {number} the master sends "
                f"(its RPDOs: {numbers or 'none'})"
            )
        return node.send_rpdo(layout)

    def _refresh(self, node: ManagedNode, layout: PdoLayout) -> None:
        """Event-driven RPDOs with an event timer: send at least every half of it (the
        node's deadline monitoring expects them)."""
        period = layout.event_timer / 2000.0
        key = (node.node_id, layout.number)

        def tick() -> None:
            self._timers[key] = self.network.loop.call_later(period, tick)
            node.send_rpdo(layout)

        self._timers[key] = self.network.loop.call_later(period, tick)
