"""The CRC of SDO block transfers (CiA 301): CRC-16-CCITT, polynomial 1021h, initial value 0.

Bits are processed most significant first, with no final XOR (the "XMODEM" variant); the check
value of the ASCII string ``123456789`` is 31C3h.

:func:`crc16` is what the SDO machines use. It runs in C through :func:`binascii.crc_hqx`,
which computes exactly this CRC. :func:`crc16_table` is the same CRC written out in Python with
a 256-entry table, so the definition is visible and the tests can hold the fast path to it.
"""

from __future__ import annotations

from binascii import crc_hqx

__all__ = ["CRC16_TABLE", "crc16", "crc16_table"]

_POLY = 0x1021


def _table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ _POLY) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        table.append(crc)
    return tuple(table)


#: ``CRC16_TABLE[b]`` is the CRC register after shifting the byte ``b`` through a zero register.
CRC16_TABLE: tuple[int, ...] = _table()


def crc16_table(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16-CCITT of ``data`` continuing from ``crc``, byte by byte through the table."""
    table = CRC16_TABLE
    for byte in bytes(data):
        crc = ((crc << 8) & 0xFF00) ^ table[(crc >> 8) ^ byte]
    return crc


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16-CCITT of ``data`` continuing from ``crc`` (0 to start), as block transfers use."""
    return crc_hqx(data, crc)
