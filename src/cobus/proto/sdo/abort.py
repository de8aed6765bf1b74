"""SDO abort codes of CiA 301 with their standard texts.

:class:`SdoAbortCode` lists every abort code CiA 301 defines; :func:`describe` gives a text for
any 32-bit value, including manufacturer-specific codes (optionally from a table such as
:data:`BECKHOFF_ABORT_TEXTS`) and values nobody defined.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import IntEnum
from types import MappingProxyType

__all__ = ["BECKHOFF_ABORT_TEXTS", "SdoAbortCode", "as_code", "describe"]


class SdoAbortCode(IntEnum):
    """The abort codes of CiA 301 (``.text`` is the standard's wording)."""

    TOGGLE_BIT = 0x05030000
    TIMEOUT = 0x05040000
    INVALID_COMMAND = 0x05040001
    BLOCK_SIZE = 0x05040002
    SEQUENCE_NUMBER = 0x05040003
    CRC = 0x05040004
    OUT_OF_MEMORY = 0x05040005
    UNSUPPORTED_ACCESS = 0x06010000
    READ_WRITE_ONLY = 0x06010001
    WRITE_READ_ONLY = 0x06010002
    NO_OBJECT = 0x06020000
    NOT_MAPPABLE = 0x06040041
    MAPPING_TOO_LONG = 0x06040042
    PARAMETER_INCOMPATIBLE = 0x06040043
    INTERNAL_INCOMPATIBLE = 0x06040047
    HARDWARE_ERROR = 0x06060000
    LENGTH_MISMATCH = 0x06070010
    LENGTH_TOO_HIGH = 0x06070012
    LENGTH_TOO_LOW = 0x06070013
    NO_SUBINDEX = 0x06090011
    INVALID_VALUE = 0x06090030
    VALUE_TOO_HIGH = 0x06090031
    VALUE_TOO_LOW = 0x06090032
    MAX_LESS_THAN_MIN = 0x06090036
    RESOURCE_NOT_AVAILABLE = 0x060A0023
    GENERAL_ERROR = 0x08000000
    CANNOT_STORE = 0x08000020
    LOCAL_CONTROL = 0x08000021
    DEVICE_STATE = 0x08000022
    NO_OBJECT_DICTIONARY = 0x08000023
    NO_DATA = 0x08000024

    @property
    def text(self) -> str:
        """The meaning of the code as CiA 301 words it (lower case, no full stop)."""
        return _TEXTS[self]

    def __str__(self) -> str:
        return f"0x{self.value:08X} {_TEXTS[self]}"


_TEXTS: Mapping[int, str] = MappingProxyType(
    {
        SdoAbortCode.TOGGLE_BIT: "toggle bit not alternated",
        SdoAbortCode.TIMEOUT: "SDO protocol timed out",
        SdoAbortCode.INVALID_COMMAND: "client/server command specifier not valid or unknown",
        SdoAbortCode.BLOCK_SIZE: "invalid block size (block mode only)",
        SdoAbortCode.SEQUENCE_NUMBER: "invalid sequence number (block mode only)",
        SdoAbortCode.CRC: "CRC error (block mode only)",
        SdoAbortCode.OUT_OF_MEMORY: "out of memory",
        SdoAbortCode.UNSUPPORTED_ACCESS: "unsupported access to an object",
        SdoAbortCode.READ_WRITE_ONLY: "attempt to read a write only object",
        SdoAbortCode.WRITE_READ_ONLY: "attempt to write a read only object",
        SdoAbortCode.NO_OBJECT: "object does not exist in the object dictionary",
        SdoAbortCode.NOT_MAPPABLE: "object cannot be mapped to the PDO",
        SdoAbortCode.MAPPING_TOO_LONG: (
            "the number and length of the objects to be mapped would exceed PDO length"
        ),
        SdoAbortCode.PARAMETER_INCOMPATIBLE: "general parameter incompatibility reason",
        SdoAbortCode.INTERNAL_INCOMPATIBLE: "general internal incompatibility in the device",
        SdoAbortCode.HARDWARE_ERROR: "access failed due to a hardware error",
        SdoAbortCode.LENGTH_MISMATCH: (
            "data type does not match, length of service parameter does not match"
        ),
        SdoAbortCode.LENGTH_TOO_HIGH: (
            "data type does not match, length of service parameter too high"
        ),
        SdoAbortCode.LENGTH_TOO_LOW: (
            "data type does not match, length of service parameter too low"
        ),
        SdoAbortCode.NO_SUBINDEX: "sub-index does not exist",
        SdoAbortCode.INVALID_VALUE: "invalid value for parameter (download only)",
        SdoAbortCode.VALUE_TOO_HIGH: "value of parameter written too high (download only)",
        SdoAbortCode.VALUE_TOO_LOW: "value of parameter written too low (download only)",
        SdoAbortCode.MAX_LESS_THAN_MIN: "maximum value is less than minimum value",
        SdoAbortCode.RESOURCE_NOT_AVAILABLE: "resource not available: SDO connection",
        SdoAbortCode.GENERAL_ERROR: "general error",
        SdoAbortCode.CANNOT_STORE: "data cannot be transferred or stored to the application",
        SdoAbortCode.LOCAL_CONTROL: (
            "data cannot be transferred or stored to the application because of local control"
        ),
        SdoAbortCode.DEVICE_STATE: (
            "data cannot be transferred or stored to the application because of the present "
            "device state"
        ),
        SdoAbortCode.NO_OBJECT_DICTIONARY: (
            "object dictionary dynamic generation fails or no object dictionary is present"
        ),
        SdoAbortCode.NO_DATA: "no data available",
    }
)

#: Manufacturer-specific abort codes of Beckhoff bus couplers, used by their register
#: communication (objects 4500h/4501h). Other manufacturers may give these values other meanings,
#: so :func:`describe` only uses them when asked to.
BECKHOFF_ABORT_TEXTS: Mapping[int, str] = MappingProxyType(
    {
        0x06020011: "invalid table: table or channel does not exist",
        0x06020010: "invalid register: table does not exist",
        0x06010022: "write protection still set",
        0x06070043: "wrong number of function arguments",
        0x06010021: "function still active, try again later",
        0x05040040: "general routing error",
        0x06060021: "error accessing the bus coupler table",
        0x06090010: "general error communicating with a terminal",
        0x05040047: "timeout communicating with a terminal",
    }
)

_CODES: Mapping[int, SdoAbortCode] = MappingProxyType({int(c): c for c in SdoAbortCode})


def as_code(code: int) -> SdoAbortCode | int:
    """``code`` as an :class:`SdoAbortCode` when CiA 301 defines it, else the plain int."""
    return _CODES.get(code, code)


def describe(code: int, manufacturer: Mapping[int, str] | None = None) -> str:
    """A text for any abort code: the CiA 301 text, else ``manufacturer``'s, else a fallback.

    ``manufacturer`` is a table of manufacturer-specific texts such as
    :data:`BECKHOFF_ABORT_TEXTS`; it never overrides a standard code.
    """
    known = _CODES.get(code)
    if known is not None:
        return _TEXTS[known]
    if manufacturer is not None:
        text = manufacturer.get(code)
        if text is not None:
            return f"{text} (manufacturer-specific)"
    if not 0 <= code <= 0xFFFFFFFF:
        return f"invalid abort code {code} (not a 32-bit value)"
    return "manufacturer-specific or unknown abort code (see the device's manual)"
