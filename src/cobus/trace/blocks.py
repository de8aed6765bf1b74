"""Frames of a trace in blocks of arrays (numpy), for what runs over a whole trace at once.

A :class:`FrameBlock` holds up to :data:`BLOCK` frames column by column: times, identifiers,
flags, DLCs and the data bytes (zero-padded to 8). :func:`blocks` reads a trace file in
blocks of constant size (memory stays bounded whatever the trace's length): BLF and candump
.log files with :mod:`cobus.trace.fastread`, every other format python-can reads with its
reader; :func:`frame_bits` gives each frame's length on the wire,
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
    """python-can messages (anything with their attributes) in blocks of ``size``. Where
    reading fails (a damaged file), the frames read before come first, then the error."""
    times: list[float] = []
    ids: list[int] = []
    flags: list[int] = []
    dlcs: list[int] = []
    data = bytearray()
    reading = iter(messages)
    while True:
        try:
            msg = next(reading)
        except StopIteration:
            break
        except Exception:
            if times:  # (what came before the damage is kept)
                yield _block(times, ids, flags, dlcs, data)
            raise
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
    """The frames of trace file ``path`` in blocks: a BLF file and a candump .log through
    :mod:`cobus.trace.fastread` (python-can's frames, read a container or a few megabytes
    at a time), the other formats through python-can's reader
    (:func:`cobus.trace.files.open_trace`)."""
    from cobus.trace.files import open_trace

    suffix = Path(path).suffix.lower()
    if suffix in (".blf", ".log"):
        from cobus.trace.fastread import blf_blocks, log_blocks

        yield from (blf_blocks if suffix == ".blf" else log_blocks)(path, size)
        return

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


def _crc_table() -> npt.NDArray[np.int64]:
    """CRC-15/CAN of each byte value, most significant bit first: a byte at a time."""
    table = np.zeros(256, dtype=np.int64)
    for value in range(256):
        crc = value << 7
        for _ in range(8):
            crc = ((crc << 1) ^ _CRC_POLY if crc & 0x4000 else crc << 1) & 0x7FFF
        table[value] = crc
    return table


def _stuff_tables() -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """For each state (the last bit and how many equal bits end the stream, 1..4: state
    last * 4 + run - 1) and the top ``k`` bits of a byte (k = 1..8): the state after them
    and the stuff bits they need. Indexed [k, state, byte]."""
    states = np.zeros((9, 8, 256), dtype=np.int64)
    counts = np.zeros((9, 8, 256), dtype=np.int64)
    for k in range(1, 9):
        for state in range(8):
            for value in range(256):
                last, run, stuffed = state >> 2, (state & 3) + 1, 0
                for i in range(k):
                    bit = (value >> (7 - i)) & 1
                    if bit == last:
                        run += 1
                        if run == 5:
                            stuffed += 1
                            last, run = 1 - bit, 1
                    else:
                        last, run = bit, 1
                states[k, state, value] = last * 4 + run - 1
                counts[k, state, value] = stuffed
    return states, counts


_TABLES: list[Any] = []  # (built at first use: crc, stuff states, stuff counts)


def frame_bits(block: FrameBlock) -> npt.NDArray[np.int64]:
    """Each frame's bits on a classic CAN bus: start of frame to intermission, with the
    stuff bits its identifier, data and CRC really need (computed, not estimated). Error
    and FD frames count 0 (their length depends on what the bus did).

    Frames go in groups of one layout (base or extended identifier, data length). A group's
    frames are walked a chunk of up to 8 bits at a time, all frames at once: the header
    (start of frame to DLC) as one number, then each data byte, then the CRC; each chunk
    moves the CRC (a byte table) and the stuffing state (tables of the state after the
    chunk and the stuff bits it needs)."""
    if not _TABLES:
        states, counts = _stuff_tables()
        _TABLES.extend((_crc_table(), states.reshape(9, -1), counts.reshape(9, -1)))
    crc_table, stuff_states, stuff_counts = _TABLES
    n = len(block)
    out = np.zeros(n, dtype=np.int64)
    if n == 0:
        return out
    flags = block.flags
    ext = (flags & EXTENDED) != 0
    rtr = (flags & REMOTE) != 0
    skip = (flags & (ERROR | FD)) != 0
    nbytes = np.where(rtr, 0, np.minimum(block.dlc, 8)).astype(np.int64)
    layout = np.where(skip, -1, ext * 16 + nbytes)
    cob = block.cob_id.astype(np.int64)
    # the header's bits as a number: start of frame (0), identifier, RTR, IDE, r0 (and SRR,
    # IDE, r1 in an extended one), DLC
    head_bits = (rtr.astype(np.int64) << 6) | np.minimum(block.dlc, 15).astype(np.int64)
    for group in np.unique(layout).tolist():
        if group < 0:
            continue
        rows = np.flatnonzero(layout == group)
        extended, size = bool(group >> 4), group & 15
        ident = cob[rows]
        if extended:
            head = 39
            number = (
                ((ident >> 18) & 0x7FF) << 27 | 3 << 25 | (ident & 0x3FFFF) << 7 | head_bits[rows]
            )
        else:
            head = 19
            number = (ident & 0x7FF) << 7 | head_bits[rows]
        crc = np.zeros(len(rows), dtype=np.int64)
        state = np.full(len(rows), 4, dtype=np.int64)  # (the idle bus before: recessive)
        stuffed = np.zeros(len(rows), dtype=np.int64)

        def chunk(value: Any, k: int) -> None:
            """``k`` bits, the top ones of the byte ``value``, through the stuffing."""
            nonlocal state, stuffed
            at = state * 256 + value
            stuffed = stuffed + stuff_counts[k][at]
            state = stuff_states[k][at]

        def crc_byte(value: Any) -> None:
            nonlocal crc
            crc = ((crc << 8) & 0x7FFF) ^ crc_table[((crc >> 7) ^ value) & 0xFF]

        first = head % 8  # (the header's odd bits come first, then whole bytes)
        chunk((number >> (head - first)) << (8 - first), first)
        crc_byte(number >> (head - first))  # (zeros in front change no CRC: it starts at 0)
        for shift in range(head - first - 8, -1, -8):
            value = (number >> shift) & 0xFF
            chunk(value, 8)
            crc_byte(value)
        for column in range(size):
            value = block.data[rows, column].astype(np.int64)
            chunk(value, 8)
            crc_byte(value)
        chunk(crc >> 7, 8)
        chunk((crc & 0x7F) << 1, 7)
        out[rows] = head + 8 * size + 15 + stuffed + _TAIL
    return out
