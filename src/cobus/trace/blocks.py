"""Frames of a trace in blocks of arrays (numpy), for what runs over a whole trace at once.

A :class:`FrameBlock` holds up to :data:`BLOCK` frames column by column: times, identifiers,
flags, DLCs and the data bytes (zero-padded to 8). :func:`blocks` reads a trace file in
blocks of constant size (memory stays bounded whatever the trace's length), from python-can's
reader for every format it reads; :func:`frame_bits` gives each frame's length on the wire,
bit stuffing included, for bus load.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["BLOCK", "FrameBlock", "blocks", "frame_bits", "message_blocks"]

#: Frames a block holds at most.
BLOCK = 65_536

#: Flag bits of :attr:`FrameBlock.flags`.
EXTENDED, REMOTE, ERROR, FD = 1, 2, 4, 8


@dataclass(frozen=True)
class FrameBlock:
    """Frames column by column: ``time`` (s, the file's own), ``cob_id`` (the identifier),
    ``flags`` (:data:`EXTENDED`, :data:`REMOTE`, :data:`ERROR` frame, :data:`FD`), ``dlc``
    (data bytes for a data frame, the DLC field of a remote one) and ``data`` (n x 8 bytes,
    zero-padded; an FD frame keeps its first 8)."""

    time: npt.NDArray[np.float64]
    cob_id: npt.NDArray[np.uint32]
    flags: npt.NDArray[np.uint8]
    dlc: npt.NDArray[np.uint8]
    data: npt.NDArray[np.uint8]

    def __len__(self) -> int:
        return len(self.time)


def message_blocks(messages: Iterable[Any], size: int = BLOCK) -> Iterator[FrameBlock]:
    """python-can messages (anything with their attributes) in blocks of ``size``."""
    times: list[float] = []
    ids: list[int] = []
    flags: list[int] = []
    dlcs: list[int] = []
    data = bytearray()
    for msg in messages:
        times.append(float(msg.timestamp))
        ids.append(msg.arbitration_id)
        flag = 0
        if msg.is_extended_id:
            flag |= EXTENDED
        if msg.is_remote_frame:
            flag |= REMOTE
        if msg.is_error_frame:
            flag |= ERROR
        if msg.is_fd:
            flag |= FD
        flags.append(flag)
        payload = bytes(msg.data or b"")[:8]
        dlcs.append(msg.dlc if msg.is_remote_frame else len(msg.data or b""))
        data += payload.ljust(8, b"\0")
        if len(times) == size:
            yield _block(times, ids, flags, dlcs, data)
            times, ids, flags, dlcs, data = [], [], [], [], bytearray()
    if times:
        yield _block(times, ids, flags, dlcs, data)


def _block(
    times: list[float], ids: list[int], flags: list[int], dlcs: list[int], data: bytearray
) -> FrameBlock:
    return FrameBlock(
        np.array(times, dtype=np.float64),
        np.array(ids, dtype=np.uint32),
        np.array(flags, dtype=np.uint8),
        np.array(dlcs, dtype=np.uint8),
        np.frombuffer(bytes(data), dtype=np.uint8).reshape(-1, 8),
    )


def blocks(path: str | Path, size: int = BLOCK, **options: Any) -> Iterator[FrameBlock]:
    """The frames of trace file ``path`` in blocks (python-can's reader, a BLF file checked
    first: :func:`cobus.trace.files.open_trace`)."""
    from cobus.trace.files import open_trace

    reader = open_trace(path, **options)
    try:
        yield from message_blocks(reader, size)
    finally:
        stop = getattr(reader, "stop", None)
        if stop is not None:
            stop()


# ------------------------------------------------------------------ bits on the wire

#: Bits after the CRC sequence, never stuffed: CRC delimiter, ACK slot and delimiter, end of
#: frame (7), intermission (3).
_TAIL = 13
_CRC_POLY = 0x4599


def frame_bits(block: FrameBlock) -> npt.NDArray[np.int64]:
    """Each frame's bits on a classic CAN bus: start of frame to intermission, with the
    stuff bits its identifier, data and CRC really need (computed, not estimated). Error
    and FD frames count 0 (their length depends on what the bus did)."""
    n = len(block)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    ext = (block.flags & EXTENDED) != 0
    rtr = (block.flags & REMOTE) != 0
    skip = (block.flags & (ERROR | FD)) != 0
    nbytes = np.where(rtr, 0, np.minimum(block.dlc, 8)).astype(np.int64)
    dlc_field = np.minimum(block.dlc, 15).astype(np.int64)
    head = np.where(ext, 39, 19)  # bits before the data: SOF ... DLC
    body = head + 8 * nbytes  # the bits the CRC covers
    width = 39 + 64 + 15
    bits = np.zeros((n, width), dtype=np.uint8)
    cob = block.cob_id.astype(np.int64)
    rows = np.arange(n)
    # standard: SOF, ID10..0, RTR, IDE=0, r0, DLC3..0
    base = np.where(ext, cob >> 18, cob) & 0x7FF
    for i in range(11):
        bits[:, 1 + i] = (base >> (10 - i)) & 1
    # extended: SOF, ID28..18, SRR=1, IDE=1, ID17..0, RTR, r1, r0, DLC
    low = cob & 0x3FFFF
    std = ~ext
    bits[std, 12] = rtr[std]
    bits[ext, 12] = 1
    bits[ext, 13] = 1
    for i in range(18):
        bits[ext, 14 + i] = (low[ext] >> (17 - i)) & 1
    bits[ext, 32] = rtr[ext]
    dlc_at = np.where(ext, 35, 15)
    for i in range(4):
        bits[rows, dlc_at + i] = (dlc_field >> (3 - i)) & 1
    data_bits = np.unpackbits(block.data, axis=1)  # (n, 64), most significant bit first
    columns = head[:, None] + np.arange(64)[None, :]
    inside = np.arange(64)[None, :] < (8 * nbytes)[:, None]
    bits[np.broadcast_to(rows[:, None], columns.shape)[inside], columns[inside]] = data_bits[inside]
    crc = np.zeros(n, dtype=np.int64)
    for pos in range(39 + 64):
        live = pos < body
        if not live.any():
            break
        nxt = ((crc >> 14) & 1) ^ bits[:, pos]
        stepped = (crc << 1) & 0x7FFF
        stepped = np.where(nxt == 1, stepped ^ _CRC_POLY, stepped)
        crc = np.where(live, stepped, crc)
    for i in range(15):
        bits[rows, body + i] = (crc >> (14 - i)) & 1
    stuffed = body + 15
    last = np.zeros(n, dtype=np.uint8)  # (SOF is dominant: 0)
    run = np.zeros(n, dtype=np.int64)
    stuff = np.zeros(n, dtype=np.int64)
    for pos in range(int(stuffed.max())):
        live = pos < stuffed
        bit = bits[:, pos]
        same = bit == last
        run = np.where(live, np.where(same, run + 1, 1), run)
        last = np.where(live, bit, last)
        full = live & (run == 5)
        stuff += full
        last = np.where(full, 1 - bit, last)
        run = np.where(full, 1, run)
    total = stuffed + stuff + _TAIL
    return np.where(skip, 0, total).astype(np.int64)
