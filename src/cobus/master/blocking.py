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
from cobus.master.master import Master
from cobus.master.node import ManagedNode
from cobus.master.states import MasterState, MasterStatus
from cobus.runtime.twin import BlockingTwin, runner_of

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


class BlockingMaster(BlockingTwin, twin_of=Master):
    """:class:`Master` for blocking code: ``BlockingMaster(Network(...), "line.yml")``.

    Every method and property of :class:`Master` is here (generated from it): ``boot()``
    waits until the network runs, ``outputs["node.signal"] = value`` is sent by RPDO,
    listeners run in the network's callback thread (inline on the simulated clock)."""

    def __init__(self, network: Network, config: NetworkConfig | str | os.PathLike[str]) -> None:
        async def create() -> Master:
            return Master(network.aio, config)

        super().__init__(network.run(create()), runner_of(network))
        self._network = network
        self._outputs = _BlockingOutputs(self)
        self.aio: Master

    @property
    def network(self) -> Network:
        """The blocking network the master runs on."""
        return self._network

    @property
    def outputs(self) -> _BlockingOutputs:
        """The process image's outputs: setting one sends it (see :meth:`Master.set_output`)."""
        return self._outputs

    def sleep(self, seconds: float) -> None:
        """Let the network run (virtual seconds on the simulated clock)."""
        self._network.sleep(seconds)

    if TYPE_CHECKING:
        inputs: Mapping[str, Any]
        nodes: dict[int, ManagedNode]
        diagnostics: MasterDiagnostics
        state: MasterState
        status: MasterStatus
        bus_load: float

        def node(self, key: int | str) -> ManagedNode: ...
        def set_output(self, name: str, value: Any) -> None: ...
