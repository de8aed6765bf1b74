"""What a node may ask of its master: :class:`NodeContext`, the one port between
:class:`~cobus.master.node.ManagedNode` and :class:`~cobus.master.master.Master`.

A node (its CiA 302-2 boot, its supervision) sees its master only through this protocol:
the network and process image they share, the master's state, and the few things a node
makes the master do (emit an event, stop all, report a boot step's end, send the RPDOs,
pass on a TPDO, watch a heartbeat). The master hands each node a port that implements it;
neither side reaches into the other's private names (``tests/test_layout.py`` checks).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from cobus.master.config import NetworkConfig
    from cobus.master.diagnostics import MasterDiagnostics
    from cobus.master.events import MasterEvent
    from cobus.master.image import ProcessImage
    from cobus.master.master import Master
    from cobus.master.node import ManagedNode
    from cobus.master.states import MasterStatus
    from cobus.proto import Frame
    from cobus.runtime import AsyncNetwork, MachineHost, Subscription

__all__ = ["NodeContext"]


class NodeContext(Protocol):
    """What a managed node may ask of its master."""

    @property
    def master(self) -> Master:
        """The master itself, for the application's ports (``node.master``)."""
        ...

    @property
    def network(self) -> AsyncNetwork:
        """The network the master runs on."""
        ...

    @property
    def config(self) -> NetworkConfig:
        """The network's configuration."""
        ...

    @property
    def image(self) -> ProcessImage:
        """The process image (the node zeroes its inputs when it stops)."""
        ...

    @property
    def diagnostics(self) -> MasterDiagnostics:
        """The master's counters and the node's summary for the status display."""
        ...

    @property
    def status(self) -> MasterStatus:
        """The master's status (offline, reset, run, stop)."""
        ...

    @property
    def started(self) -> bool:
        """Whether the master's boot has started."""
        ...

    @property
    def running(self) -> bool:
        """Whether the network is operational (the master started it)."""
        ...

    def emit(self, event: MasterEvent) -> None:
        """Give ``event`` to the master's listeners."""
        ...

    def note_configuring(self) -> None:
        """A node began its configuration: the master is configuring."""
        ...

    def node_configured(self, node: ManagedNode) -> None:
        """``node`` finished its configuration: the master starts it when it runs."""
        ...

    def node_finished(self, node: ManagedNode) -> None:
        """``node`` ended its boot (configured or not): the master checks its own boot."""
        ...

    def stop_all(self, cause: ManagedNode, reason: str) -> None:
        """The network reaction to ``cause``'s fault: NMT stop to every node."""
        ...

    def send_all_rpdos(self, nodes: list[ManagedNode]) -> None:
        """Send every RPDO of ``nodes`` (outputs set while they were away reach them)."""
        ...

    def tpdo_taken(self, node_id: int, number: int, now: float) -> None:
        """A TPDO of ``node_id`` was taken into the process image: tell the listeners."""
        ...

    def send(self, frame: Frame) -> bool:
        """Send ``frame``; False when the network cannot take it (counted)."""
        ...

    def keep(self, subscription: Subscription) -> None:
        """Hold ``subscription`` until the master closes."""
        ...

    def keep_host(self, host: MachineHost) -> None:
        """Hold ``host`` until the master closes."""
        ...

    def watch_heartbeat(self, node_id: int, consumer_time: float, now: float) -> None:
        """Watch ``node_id``'s heartbeat with ``consumer_time`` seconds (0: stop watching)."""
        ...

    def heartbeat_frame(self, frame: Frame, now: float) -> None:
        """An error control frame for the master's heartbeat consumer."""
        ...
