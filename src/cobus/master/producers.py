"""The master's own producers, in one place beside each other: SYNC (the network's
:class:`~cobus.runtime.NetworkSync`, timed by the loop or by the CAN interface), TIME, and
the master's heartbeat (CiA 302-2: the master produces what its nodes consume).

:meth:`MasterProducers.start_sync` comes first in the master's start, so that an interface
that cannot time SYNC leaves nothing started; :meth:`MasterProducers.start_heartbeat_and_time`
once the master listens to the bus; :meth:`MasterProducers.stop` ends all three.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import TYPE_CHECKING

from cobus.master.errors import MasterError
from cobus.proto import NOTHING
from cobus.proto.heartbeat import HeartbeatProducer
from cobus.proto.nmt import NmtState
from cobus.proto.timestamp import TimeProducer
from cobus.runtime import InterfaceTimingError

if TYPE_CHECKING:
    from cobus.master.config import MasterConfig
    from cobus.runtime import AsyncNetwork, MachineHost

__all__ = ["MasterProducers"]


class MasterProducers:
    """SYNC, TIME and the heartbeat the master produces on ``network`` (each start per the
    master's configuration as it is then)."""

    def __init__(self, network: AsyncNetwork) -> None:
        self._network = network
        self._hosts: list[MachineHost] = []
        #: Whether the master started the network's SYNC (and stops it).
        self.own_sync = False

    def start_sync(self, cfg: MasterConfig) -> None:
        """SYNC, when the master produces it; :class:`MasterError` if the interface was to
        time it and cannot."""
        net = self._network
        if not cfg.sync_period:
            return
        try:
            net.sync.start(
                cfg.sync_period,
                overflow=cfg.sync_overflow,
                cob_id=cfg.sync_cob_id,
                # (the simulated clock has no interface: its loop times SYNC)
                by_interface=cfg.sync_by_interface and not net.simulated,
            )
        except InterfaceTimingError as exc:
            raise MasterError(f"master.sync_by_interface: {exc} (set it to false)") from exc
        self.own_sync = True

    def start_heartbeat_and_time(self, cfg: MasterConfig, now: float) -> None:
        """The master's heartbeat (operational) and TIME, when configured."""
        net = self._network
        if cfg.heartbeat_time and cfg.node_id is not None:
            producer = HeartbeatProducer(cfg.node_id, state=NmtState.OPERATIONAL)
            producer.set_period(cfg.heartbeat_time, now)
            host = net.attach(producer)
            host.apply(NOTHING)
            self._hosts.append(host)
        if cfg.time_period:
            stamp = TimeProducer(cfg.time_cob_id)
            host = net.attach(stamp)
            host.apply(stamp.set_interval(cfg.time_period, now, datetime.now(UTC)))
            self._hosts.append(host)

    def stop(self) -> None:
        """End every producer the master started."""
        for host in self._hosts:
            host.close()
        self._hosts.clear()
        if self.own_sync:
            self._network.sync.stop()
            self.own_sync = False
