"""LSS (CiA 305) on the wire: command specifiers, the identity, the bit timing table, frames.

Every LSS frame is 8 bytes on a fixed identifier: the master asks on 7E5h, the slaves answer on
7E4h; byte 0 is the command specifier, numbers are little-endian.
"""

from __future__ import annotations

from dataclasses import dataclass

from cobus.errors import CobusError
from cobus.proto.connection_set import LSS_MASTER_COB_ID, LSS_SLAVE_COB_ID
from cobus.proto.frame import Frame

__all__ = [
    "AUTO_BIT_RATE",
    "BIT_RATES",
    "FIELDS",
    "UNCONFIGURED",
    "LssError",
    "LssIdentity",
    "bit_timing_index",
]

#: The node-ID of a device that has none yet: it takes part in LSS only.
UNCONFIGURED = 0xFF
#: The identity's four fields in fastscan order (LSSSub 0..3).
FIELDS = ("vendor", "product", "revision", "serial")
#: CiA 305's bit timing table 0: index -> kbit/s (5 is reserved; 9 is automatic detection).
BIT_RATES = {0: 1000, 1: 800, 2: 500, 3: 250, 4: 125, 6: 50, 7: 20, 8: 10}
AUTO_BIT_RATE = 9

# command specifiers
SWITCH_GLOBAL = 0x04
CONFIGURE_NODE_ID = 0x11
CONFIGURE_BIT_TIMING = 0x13
ACTIVATE_BIT_TIMING = 0x15
STORE = 0x17
SWITCH_SELECTIVE = (0x40, 0x41, 0x42, 0x43)
SELECTED = 0x44
IDENTIFY_REMOTE = (0x46, 0x47, 0x48, 0x49, 0x4A, 0x4B)  # vendor, product, rev low/high, serial
IDENTIFIED = 0x4F
IDENTIFY_UNCONFIGURED = 0x4C
UNCONFIGURED_IDENTIFIED = 0x50
FASTSCAN = 0x51
INQUIRE = (0x5A, 0x5B, 0x5C, 0x5D)  # vendor, product, revision, serial
INQUIRE_NODE_ID = 0x5E
#: Fastscan's BitChecked that resets every unconfigured slave's scan and asks who is there.
FASTSCAN_RESET = 0x80

MASTER = LSS_MASTER_COB_ID
SLAVE = LSS_SLAVE_COB_ID
_U32 = 0xFFFF_FFFF


class LssError(CobusError, ValueError):
    """An LSS request that cannot be made as given (a field, node-ID or bit rate out of range)."""


def u32(value: object, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= _U32:
        raise LssError(f"{what} {value!r} is no UNSIGNED32 (0..0xFFFFFFFF)")
    return value


@dataclass(frozen=True, slots=True)
class LssIdentity:
    """The LSS address of a device: its identity object 1018h sub 1..4."""

    vendor: int
    product: int
    revision: int
    serial: int

    def __post_init__(self) -> None:
        for name in FIELDS:
            u32(getattr(self, name), name)

    @property
    def fields(self) -> tuple[int, int, int, int]:
        """(vendor, product, revision, serial): LSSSub 0..3."""
        return (self.vendor, self.product, self.revision, self.serial)

    def __str__(self) -> str:
        return (
            f"vendor 0x{self.vendor:08X}, product 0x{self.product:08X}, "
            f"revision 0x{self.revision:08X}, serial 0x{self.serial:08X}"
        )


def check_node_id(node_id: object) -> int:
    """A node-ID LSS can give: 1..127, or FFh (none)."""
    if isinstance(node_id, bool) or not isinstance(node_id, int):
        raise LssError(f"node-ID {node_id!r}: give 1..127, or 0xFF for none")
    if not (1 <= node_id <= 127 or node_id == UNCONFIGURED):
        raise LssError(f"node-ID {node_id}: give 1..127, or 0xFF for none")
    return node_id


def bit_timing_index(kbits: int) -> int:
    """The table-0 index of a bit rate in kbit/s (``bit_timing_index(250) == 3``)."""
    for index, rate in BIT_RATES.items():
        if rate == kbits and not isinstance(kbits, bool):
            return index
    rates = ", ".join(str(r) for r in sorted(BIT_RATES.values(), reverse=True))
    raise LssError(f"{kbits!r} kbit/s is not in CiA 305's bit timing table ({rates})")


def frame(cob_id: int, cs: int, body: bytes = b"") -> Frame:
    return Frame(cob_id, bytes((cs,)) + body.ljust(7, b"\0"))


def request(cs: int, body: bytes = b"") -> Frame:
    """A master's request (7E5h), padded to 8 bytes."""
    return frame(MASTER, cs, body)


def answer(cs: int, body: bytes = b"") -> Frame:
    """A slave's answer (7E4h), padded to 8 bytes."""
    return frame(SLAVE, cs, body)


def le32(value: int) -> bytes:
    return value.to_bytes(4, "little")


def read_u32(data: bytes) -> int:
    return int.from_bytes(data[1:5], "little")
