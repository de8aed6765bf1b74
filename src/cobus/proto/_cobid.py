"""The part all COB-ID objects share (1005h, 1012h, 1014h, 1400h/1800h sub 1): an UNSIGNED32
whose low 29 bits are the identifier and whose bit 29 says the frame uses a 29-bit one."""

from __future__ import annotations

EXTENDED_BIT = 1 << 29


def split_cob_id(value: object, what: str, error: type[Exception]) -> tuple[int, bool]:
    """``(can_id, extended)`` of a COB-ID value; ``error`` (naming ``what``) if it is no
    UNSIGNED32, or if an 11-bit identifier is wanted but the value does not fit 11 bits."""
    if not isinstance(value, int) or not 0 <= value <= 0xFFFFFFFF:
        raise error(f"{what} {value!r} is not an UNSIGNED32")
    extended = bool(value & EXTENDED_BIT)
    can_id = value & 0x1FFFFFFF
    if not extended and can_id > 0x7FF:
        raise error(
            f"{what} 0x{value:08X}: identifier 0x{can_id:X} needs bit 29 "
            "(29-bit frame) or must fit 11 bits"
        )
    return can_id, extended
