"""The node-IDs this process answers to on one network, and what answers to each.

A network holds one :class:`LocalNodes` (``network.devices``) and is its only owner: a local
device (a :class:`cobus.device.Device`, the device of a simulation) claims its node-ID when it
attaches itself to the network, moves it when its node-ID changes, and releases it when it
closes. Everyone else reads it as a mapping. The runtime does not know what a device is: it
only keeps two of them from answering to the same node-ID.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

from cobus.runtime.errors import NodeIdInUseError

__all__ = ["LocalNodes"]


class LocalNodes(Mapping[int, Any]):
    """Node-ID -> the local device answering to it (read-only as a mapping)."""

    __slots__ = ("_owners",)

    def __init__(self) -> None:
        self._owners: dict[int, Any] = {}

    def claim(self, node_id: int, owner: object) -> None:
        """``owner`` answers to ``node_id`` from now on; :class:`NodeIdInUseError` if another
        local device already does (claiming again what one holds is no error)."""
        holder = self._owners.get(node_id)
        if holder is not None and holder is not owner:
            raise NodeIdInUseError(
                f"node-ID {node_id} is used by another device of this network ({holder!r}); "
                "pick a free one"
            )
        self._owners[node_id] = owner

    def move(self, old: int, new: int, owner: object) -> None:
        """``owner`` answers to ``new`` instead of ``old`` (nothing changes if ``new`` is
        taken: :class:`NodeIdInUseError`)."""
        self.claim(new, owner)
        if old != new:
            self.release(old, owner)

    def release(self, node_id: int, owner: object) -> None:
        """``owner`` no longer answers to ``node_id`` (no effect if it did not)."""
        if self._owners.get(node_id) is owner:
            del self._owners[node_id]

    def __getitem__(self, node_id: int) -> Any:
        return self._owners[node_id]

    def __iter__(self) -> Iterator[int]:
        return iter(self._owners)

    def __len__(self) -> int:
        return len(self._owners)

    def __repr__(self) -> str:
        return f"LocalNodes({self._owners!r})"
