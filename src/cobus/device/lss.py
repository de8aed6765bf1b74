"""The device's LSS slave (CiA 305): found, named, given a node-ID and a bit rate by an LSS
master on 7E5h/7E4h, whatever its NMT state.

The identity is the device's 1018h (vendor, product, revision, serial: all four needed). A
node-ID the master configures is *pending*: the device takes it at its next reset of the
communication (or reset node); a device that had none (FFh, it answers LSS only) takes it
at once when the master switches it back to waiting, and boots. ``store configuration``
keeps the pending node-ID and bit timing in the device's storage
(:meth:`~cobus.device.storage.StorageService.store_lss`), from which the device starts
next time; a store that cannot be written answers "storage media access error". An
activated bit timing is switched to one switch delay after the command
(:class:`~cobus.device.events.BitRateSwitched`; a simulated bus has no bit rate, so the
device's frames go on being heard).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TYPE_CHECKING

from cobus.device._core import Core
from cobus.device.errors import DeviceConfigError
from cobus.device.events import (
    BitRateSwitched,
    ConfigurationProblem,
    LssBitTimingConfigured,
    LssConfigurationStored,
    LssNodeIdConfigured,
    LssStoreFailed,
)
from cobus.device.storage import StorageService
from cobus.proto import Event
from cobus.proto.connection_set import LSS_MASTER_COB_ID
from cobus.proto.lss import (
    BIT_RATES,
    UNCONFIGURED,
    BitTimingActivated,
    BitTimingConfigured,
    ConfigurationStored,
    LssIdentity,
    LssSlave,
    NodeIdAssigned,
    NodeIdConfigured,
    StoreFailed,
)

if TYPE_CHECKING:
    from cobus.runtime.network import MachineHost

__all__ = ["LssService"]

_IDENTITY = 0x1018


class LssService:
    """The LSS slave of one device, its stored configuration and its bit-rate switch."""

    def __init__(
        self,
        core: Core,
        storage: StorageService,
        *,
        on_assigned: Callable[[int], None],
    ) -> None:
        self._core = core
        self._storage = storage
        self._on_assigned = on_assigned
        missing = [s for s in range(1, 5) if (_IDENTITY << 8 | s) not in core.entries]
        if missing:
            raise DeviceConfigError(
                f"LSS finds a device by 1018h sub 1-4 (vendor, product, revision, serial); "
                f"this dictionary lacks sub {', '.join(map(str, missing))}: add them"
            )
        #: The LSS slave machine: its ``answer_delay`` and ``bit_rates`` may be set.
        self.slave = LssSlave(self.identity(), core.node_id, store=self._store)
        #: The table-0 index of the bit timing the device runs at (None: as it was started).
        self.bit_timing: int | None = None
        self._host: MachineHost | None = None
        self._switch: asyncio.TimerHandle | None = None

    def identity(self) -> LssIdentity:
        """The device's identity as 1018h holds it now."""
        fields = []
        for sub in range(1, 5):
            entry = self._core.entries[_IDENTITY << 8 | sub]
            value = entry.value if entry.value is not None else entry.var.value
            fields.append(value if isinstance(value, int) else 0)  # (before the power-on)
        return LssIdentity(*fields)

    def power_on(self, node_id: int, bit_timing: int | None) -> None:
        """The device starts with ``node_id`` and ``bit_timing`` (stored or given)."""
        slave = self.slave
        slave.identity = self.identity()
        slave.active_node_id = slave.pending_node_id = node_id
        slave.pending_bit_timing = None
        if bit_timing is not None:
            self.bit_timing = bit_timing

    def open(self) -> None:
        """Answer LSS on the network."""
        if self._host is None:
            self.slave.identity = self.identity()
            network = self._core.network
            self._host = network.attach(self.slave, (LSS_MASTER_COB_ID,), self._on_event)

    def close(self) -> None:
        """Stop answering LSS (the device is closed or powered off)."""
        if self._host is not None:
            self._host.close()
            self._host = None
        if self._switch is not None:
            self._switch.cancel()
            self._switch = None

    def node_id_changed(self, node_id: int) -> None:
        """The application gave the device ``node_id``: LSS reports it, nothing is pending."""
        self.slave.active_node_id = self.slave.pending_node_id = node_id

    def take_pending(self) -> int | None:
        """At a reset of the communication: the node-ID a master configured since, now the
        active one; None when it is the one the device has."""
        slave = self.slave
        pending = slave.pending_node_id
        if pending == slave.active_node_id:
            return None
        if type(pending) is not int or not (1 <= pending <= 127 or pending == UNCONFIGURED):
            core = self._core
            core.emit(
                ConfigurationProblem(
                    core.node_id, f"pending LSS node-ID {pending!r} is not 1..127 or FFh: ignored"
                )
            )
            slave.pending_node_id = slave.active_node_id
            return None
        slave.node_id_active()
        return slave.active_node_id

    def keep_pending(self, active: int, pending: int) -> None:
        """The device could not take ``pending`` and goes on with ``active``."""
        self.slave.active_node_id = active
        self.slave.pending_node_id = pending

    def unassign(self) -> None:
        """The node-ID the slave reported as assigned could not be taken: none again."""
        self.slave.active_node_id = self.slave.pending_node_id = UNCONFIGURED

    # ---------------------------------------------------------------- the machine's events

    def _store(self, node_id: int, bit_timing: int | None) -> int:
        self._storage.store_lss(node_id, bit_timing)  # StorageError: a media access error
        return 0

    def _on_event(self, event: Event) -> None:
        core = self._core
        if isinstance(event, NodeIdConfigured):
            core.emit(LssNodeIdConfigured(core.node_id, event.node_id))
        elif isinstance(event, NodeIdAssigned):
            self._on_assigned(event.node_id)
        elif isinstance(event, BitTimingConfigured):
            core.emit(LssBitTimingConfigured(core.node_id, event.index, event.kbits))
        elif isinstance(event, BitTimingActivated):
            self._activate(event.delay, event.index)
        elif isinstance(event, ConfigurationStored):
            core.emit(LssConfigurationStored(core.node_id, event.node_id, event.bit_timing))
        elif isinstance(event, StoreFailed):
            core.emit(LssStoreFailed(core.node_id, event.error, event.reason))

    def _activate(self, delay: float, index: int) -> None:
        if self._switch is not None:
            self._switch.cancel()
        self._switch = self._core.network.loop.call_later(delay, self._switched, index)

    def _switched(self, index: int) -> None:
        self._switch = None
        self.bit_timing = index
        core = self._core
        core.emit(BitRateSwitched(core.node_id, index, BIT_RATES.get(index)))
