"""Errors of the device layer: what the application asked for that the device cannot do."""

from __future__ import annotations

from cobus.errors import CobusError
from cobus.proto.sdo import SdoAbortCode, describe
from cobus.runtime.errors import NodeIdInUseError

__all__ = [
    "DeviceConfigError",
    "DeviceError",
    "EntryError",
    "EntryNotFoundError",
    "EntryRefusedError",
    "NodeIdInUseError",
    "StorageError",
]


class DeviceError(CobusError):
    """Base class of the errors :class:`~cobus.device.Device` raises."""


class DeviceConfigError(DeviceError, ValueError):
    """The object dictionary or an option cannot run as a device (says what to add or fix)."""


class EntryError(DeviceError):
    """An application read or write of an entry that the device refuses.

    ``code`` is the SDO abort code a master would get for the same request, so the cause is
    named the same way on both sides (e.g. 06090031 value too high, 06040043 mapping while
    the PDO is valid).
    """

    def __init__(self, index: int, subindex: int, code: int, reason: str | None = None) -> None:
        self.index = index
        self.subindex = subindex
        self.code: SdoAbortCode | int = code
        text = reason or describe(code)
        super().__init__(f"0x{index:04X}:{subindex:02X}: {text} (abort code 0x{code:08X})")

    def __str__(self) -> str:
        return str(self.args[0])


class EntryNotFoundError(EntryError, KeyError):
    """No such object or sub-index in the device's dictionary (06020000 / 06090011)."""


class EntryRefusedError(EntryError, ValueError):
    """A value or access the entry does not allow: wrong type, out of its limits, a
    communication parameter that cannot change in the current configuration."""


class StorageError(DeviceError, OSError):
    """Parameters could not be stored to or loaded from the storage file."""
