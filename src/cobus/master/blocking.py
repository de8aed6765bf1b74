"""The master for blocking code (scripts, the REPL), on :class:`cobus.runtime.Network`.

Every call runs on the network's loop through ``Network.run()``: in real time the loop runs
in its background thread; on the simulated clock virtual time only moves while a call waits
(``master.sleep(5)`` lets the network run five virtual seconds).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Any

from cobus.master.config import NetworkConfig
from cobus.master.diagnostics import MasterDiagnostics
from cobus.master.master import Master, MasterListener
from cobus.master.node import ManagedNode
from cobus.master.states import MasterState, MasterStatus

if TYPE_CHECKING:
    from cobus.runtime import Network

__all__ = ["BlockingMaster"]


class _BlockingOutputs(Mapping[str, Any]):
    def __init__(self, master: BlockingMaster) -> None:
        self._master = master

    def __getitem__(self, key: str) -> Any:
        return self._master.aio.outputs[key]

    def __setitem__(self, key: str, value: Any) -> None:
        self._master.set_output(key, value)

    def __iter__(self) -> Iterator[str]:
        return iter(self._master.aio.outputs)

    def __len__(self) -> int:
        return len(self._master.aio.outputs)


class BlockingMaster:
    """:class:`Master` for blocking code: ``BlockingMaster(Network(...), "line.yml")``."""

    def __init__(self, network: Network, config: NetworkConfig | str | os.PathLike[str]) -> None:
        self.network = network

        async def create() -> Master:
            return Master(network.aio, config)

        self.aio: Master = network.run(create())
        self.outputs = _BlockingOutputs(self)

    def _call(self, fn: Any, *args: Any) -> Any:
        async def call() -> Any:
            return fn(*args)

        return self.network.run(call())

    def start(self) -> None:
        """Start the boot-up in the background (see :meth:`Master.start`)."""
        self._call(self.aio.start)

    def boot(self, timeout: float | None = None) -> None:
        """Boot and wait until the network runs (see :meth:`Master.boot`)."""
        self.network.run(self.aio.boot(timeout))

    def stop(self, *, stop_nodes: bool = False) -> None:
        self.network.run(self.aio.stop(stop_nodes=stop_nodes))

    def restart_node(self, key: int | str) -> None:
        self.network.run(self.aio.restart_node(key))

    def sleep(self, seconds: float) -> None:
        """Let the network run (virtual seconds on the simulated clock)."""
        self.network.sleep(seconds)

    def set_output(self, name: str, value: Any) -> None:
        self._call(self.aio.set_output, name, value)

    def add_listener(self, listener: MasterListener) -> None:
        self._call(self.aio.add_listener, listener)

    @property
    def inputs(self) -> Mapping[str, Any]:
        return self.aio.inputs

    @property
    def nodes(self) -> dict[int, ManagedNode]:
        return self.aio.nodes

    def node(self, key: int | str) -> ManagedNode:
        return self.aio.node(key)

    @property
    def state(self) -> MasterState:
        return self.aio.state

    @property
    def status(self) -> MasterStatus:
        return self.aio.status

    @property
    def diagnostics(self) -> MasterDiagnostics:
        return self.aio.diagnostics

    @property
    def bus_load(self) -> float:
        value: float = self._call(lambda: self.aio.bus_load)
        return value
