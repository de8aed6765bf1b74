"""Errors of SDO transfers, and :class:`SdoAbort`, the refusal an SDO server back end raises.

Every transfer error names the object (index and sub-index) and the node or SDO channel, and
says what the abort code means, so the message alone tells a person where to look.
"""

from __future__ import annotations

from cobus.errors import CobusError
from cobus.proto.sdo.abort import SdoAbortCode, as_code, describe

__all__ = [
    "SdoAbort",
    "SdoAbortedError",
    "SdoBusyError",
    "SdoError",
    "SdoParameterError",
    "SdoProtocolError",
    "SdoTimeoutError",
]

_HINTS: dict[int, str] = {
    SdoAbortCode.NO_OBJECT: "check the index against the device's EDS",
    SdoAbortCode.NO_SUBINDEX: "check the sub-index against the device's EDS",
    SdoAbortCode.WRITE_READ_ONLY: "the entry can only be read",
    SdoAbortCode.READ_WRITE_ONLY: "the entry can only be written",
    SdoAbortCode.LENGTH_MISMATCH: "send exactly as many bytes as the entry's data type has",
    SdoAbortCode.LENGTH_TOO_HIGH: "send fewer bytes: the entry's data type is shorter",
    SdoAbortCode.LENGTH_TOO_LOW: "send more bytes: the entry's data type is longer",
    SdoAbortCode.INVALID_VALUE: "write a value the entry accepts",
    SdoAbortCode.VALUE_TOO_HIGH: "write a smaller value",
    SdoAbortCode.VALUE_TOO_LOW: "write a larger value",
    SdoAbortCode.DEVICE_STATE: "bring the device into a state that allows this access first",
}


def where(index: int | None, subindex: int | None, node: int | None, channel: str) -> str:
    """``0x2000:00 (node 5)``, or the channel's COB-IDs when the node is not known."""
    obj = "" if index is None else f"0x{index:04X}:{subindex or 0:02X} "
    peer = f"node {node}" if node is not None else f"SDO {channel}"
    return f"{obj}({peer})"


class SdoError(CobusError):
    """Base class of every SDO error; ``index``/``subindex`` name the object when known."""

    def __init__(
        self,
        message: str,
        *,
        index: int | None = None,
        subindex: int | None = None,
        node: int | None = None,
    ) -> None:
        super().__init__(message)
        self.index = index
        self.subindex = subindex
        self.node = node


class SdoParameterError(SdoError, ValueError):
    """An argument an SDO machine cannot work with (a COB-ID, index, size or setting)."""


class SdoBusyError(SdoError):
    """A transfer was started on an SDO channel that is still busy with another one."""


class SdoAbortedError(SdoError):
    """A transfer ended with an abort: sent by the peer (``by_peer``) or on our own request."""

    def __init__(
        self,
        code: int,
        *,
        index: int | None,
        subindex: int | None,
        node: int | None = None,
        channel: str = "",
        by_peer: bool = True,
        hint: str | None = None,
    ) -> None:
        self.code: SdoAbortCode | int = as_code(code)
        self.by_peer = by_peer
        text = describe(code)
        tip = hint if hint is not None else _HINTS.get(code)
        origin = "" if by_peer else " sent by this side"
        message = (
            f"SDO abort 0x{code:08X} on {where(index, subindex, node, channel)}{origin}: {text}"
        )
        if tip:
            message += f" ({tip})"
        super().__init__(message, index=index, subindex=subindex, node=node)


class SdoTimeoutError(SdoError, TimeoutError):
    """The peer did not answer within the SDO timeout (the client then sent abort 05040000)."""

    def __init__(
        self,
        *,
        index: int | None,
        subindex: int | None,
        timeout: float,
        node: int | None = None,
        channel: str = "",
        stale: str | None = None,
    ) -> None:
        self.timeout = timeout
        #: What the client dropped as stale while it waited (None: nothing).
        self.stale = stale
        message = f"SDO timeout on {where(index, subindex, node, channel)}: no answer within "
        if stale is not None:
            message += f"{timeout:g} s ({stale}; a longer timeout may help)"
        else:
            message += (
                f"{timeout:g} s (check that the node is powered, connected at the same bit "
                "rate, not in NMT stopped state, and that the SDO COB-IDs are right; slow "
                "devices may need a longer timeout)"
            )
        super().__init__(message, index=index, subindex=subindex, node=node)


class SdoProtocolError(SdoError):
    """The peer broke CiA 301, so this side aborted the transfer with ``code``."""

    def __init__(
        self,
        code: int,
        reason: str,
        *,
        index: int | None,
        subindex: int | None,
        node: int | None = None,
        channel: str = "",
    ) -> None:
        self.code: SdoAbortCode | int = as_code(code)
        self.reason = reason
        message = (
            f"SDO protocol error on {where(index, subindex, node, channel)}: {reason}; "
            f"aborted with 0x{code:08X} ({describe(code)}). The peer does not follow CiA 301 "
            "here: look for a vendor quirk or a second client on the same SDO channel"
        )
        super().__init__(message, index=index, subindex=subindex, node=node)


class SdoAbort(Exception):
    """Raised by an SDO server back end to refuse a request with the abort ``code``.

    A refusal the back end hands to the server, which turns it into an abort frame; it is not
    an error of cobus, so it does not derive from :class:`~cobus.errors.CobusError`.
    """

    def __init__(self, code: int, reason: str | None = None) -> None:
        if not 0 <= code <= 0xFFFFFFFF:
            raise SdoParameterError(f"SDO abort code {code} does not fit 32 bits")
        self.code: SdoAbortCode | int = as_code(code)
        self.reason = reason
        text = reason if reason is not None else describe(code)
        super().__init__(f"0x{code:08X}: {text}")
