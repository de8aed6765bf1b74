"""Frame layouts of CiA 301 SDO shared by the client and the server (private).

Byte 0 of every SDO frame is the command specifier; bits 7..5 name the service (``ccs`` from
the client, ``scs`` from the server). Multi-byte fields are little-endian.
"""

from __future__ import annotations

import struct

from cobus.proto.connection_set import SDO_RX_BASE, SDO_TX_BASE
from cobus.proto.frame import Frame
from cobus.proto.sdo.errors import SdoParameterError

# Command bytes and masks (CiA 301 7.2.4.3).
ABORT = 0x80
SERVICE_MASK = 0xE0  # bits 7..5: the command specifier
TOGGLE = 0x10  # bit 4 of segment frames
LAST = 0x01  # bit 0 'c' of segment frames
EXPEDITED = 0x02  # 'e' of initiate frames
SIZE = 0x01  # 's' of initiate frames (0x02 in block initiate frames)
BLOCK_SIZE_FLAG = 0x02  # 's' of block initiate frames
BLOCK_CRC = 0x04  # 'cc' / 'sc' of block initiate frames
LAST_SEGMENT = 0x80  # 'c' of block segments; bits 6..0 are the sequence number

# Client command specifiers (ccs << 5).
CCS_DOWNLOAD_SEGMENT = 0x00
CCS_INITIATE_DOWNLOAD = 0x20
CCS_INITIATE_UPLOAD = 0x40
CCS_UPLOAD_SEGMENT = 0x60
CCS_BLOCK_UPLOAD = 0xA0
CCS_BLOCK_DOWNLOAD = 0xC0

# Server command specifiers (scs << 5).
SCS_UPLOAD_SEGMENT = 0x00
SCS_DOWNLOAD_SEGMENT = 0x20
SCS_INITIATE_UPLOAD = 0x40
SCS_INITIATE_DOWNLOAD = 0x60
SCS_BLOCK_DOWNLOAD = 0xA0
SCS_BLOCK_UPLOAD = 0xC0

# Sub-commands of the block services: ccs/scs 5 use bits 1..0, ccs/scs 6 use bit 0.
BLOCK5_MASK = 0xE3
BLOCK6_MASK = 0xE1
BLOCK_UPLOAD_START = 0xA3  # client: start the first sub-block
BLOCK_ACK = 0xA2  # receiver of a sub-block: acknowledge it
BLOCK5_END = 0xA1  # block upload end response (client) / block download end response (server)
BLOCK6_END = 0xC1  # block download end request (client) / block upload end (server), n in 4..2

MAX_BLOCK_SIZE = 127

# Frame layouts: command, index, sub-index, then the rest.
MUX = struct.Struct("<BHB")
WITH_U32 = struct.Struct("<BHBI")  # initiate with size / abort with code
WITH_4S = struct.Struct("<BHB4s")  # expedited with data (padded with zeros)
BLOCK_INIT_RESPONSE = struct.Struct("<BHBB3x")  # block download initiate response: blksize
BLOCK_UPLOAD_INIT = struct.Struct("<BHBBB2x")  # block upload initiate: blksize, pst
SEGMENT = struct.Struct("<B7s")  # command or sequence byte and up to 7 data bytes
ACK = struct.Struct("<BBB5x")  # block acknowledge: ackseq, blksize
END_CRC = struct.Struct("<BH5x")  # block end with CRC
U32 = struct.Struct("<I")
U16 = struct.Struct("<H")
CODE_ONLY = struct.Struct("<B7x")  # a bare command byte (segment responses, start, end)

PAD8 = bytes(8)


def padded(data: bytes) -> bytes:
    """``data`` extended with zero bytes to 8 (for peers that send frames shorter than 8)."""
    return data + PAD8[len(data) :] if len(data) < 8 else data


def check_cob_id(name: str, cob_id: int) -> bool:
    """Validate an SDO COB-ID; ``True`` when it needs the 29-bit (extended) format."""
    if not 0 <= cob_id <= 0x1FFFFFFF:
        raise SdoParameterError(f"{name} 0x{cob_id:X} is not a CAN identifier (0 to 1FFFFFFFh)")
    return cob_id > 0x7FF


def check_timeout(timeout: float) -> float:
    if not timeout > 0:
        raise SdoParameterError(f"SDO timeout must be a positive number of seconds, not {timeout}")
    return float(timeout)


def check_block_size(block_size: int) -> int:
    if not 1 <= block_size <= MAX_BLOCK_SIZE:
        raise SdoParameterError(
            f"SDO block size {block_size} is outside 1..{MAX_BLOCK_SIZE} segments (CiA 301)"
        )
    return block_size


def check_object(index: int, subindex: int) -> None:
    if not 0 <= index <= 0xFFFF:
        raise SdoParameterError(f"object index 0x{index:X} does not fit 16 bits (0000h..FFFFh)")
    if not 0 <= subindex <= 0xFF:
        raise SdoParameterError(f"sub-index {subindex} of 0x{index:04X} does not fit 8 bits")


def node_of(rx_cob_id: int, tx_cob_id: int) -> int | None:
    """The node-ID of the default SDO channel (600h+id / 580h+id), else ``None``."""
    node = rx_cob_id - SDO_RX_BASE
    if 1 <= node <= 127 and tx_cob_id == SDO_TX_BASE + node:
        return node
    return None


UNLIMITED = 1 << 62


def block_room(size: int | None) -> int:
    """The bytes the block segments of an indicated ``size`` carry (whole segments, at least
    one); more is data beyond the size. No size indicated: no limit."""
    return 7 * max(1, -(-size // 7)) if size is not None else UNLIMITED


def unused_in_last(size: int) -> int:
    """Bytes of the last 7-byte segment that carry no data (7 for an empty transfer)."""
    return (7 - size % 7) % 7 if size else 7


def subblock(
    cob_id: int, extended: bool, data: bytes, pos: int, blksize: int
) -> tuple[tuple[Frame, ...], int, bool]:
    """The block segments of ``data`` from byte ``pos``: at most ``blksize`` frames.

    Returns the frames, how many there are, and whether the last one ends the data (it then
    carries the 'c' flag; an empty ``data`` makes one segment of padding).
    """
    total = len(data)
    pack = SEGMENT.pack
    frames: list[Frame] = []
    append = frames.append
    for seq in range(1, blksize + 1):
        end = pos + 7
        if end >= total:
            append(Frame(cob_id, pack(LAST_SEGMENT | seq, data[pos:end]), extended=extended))
            return tuple(frames), seq, True
        append(Frame(cob_id, pack(seq, data[pos:end]), extended=extended))
        pos = end
    return tuple(frames), blksize, False
