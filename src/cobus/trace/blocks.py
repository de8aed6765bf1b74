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

    Frames go in groups of one layout (base or extended identifier, data length): each
    group's bits are laid out in columns, its CRC computed a byte at a time and its stuff
    bits counted a byte at a time with tables, for all its frames at once."""
    if not _TABLES:
        _TABLES.extend((_crc_table(), *_stuff_tables()))
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
    dlc_field = np.minimum(block.dlc, 15).astype(np.int64)
    for group in np.unique(layout).tolist():
        if group < 0:
            continue
        rows = np.flatnonzero(layout == group)
        extended, size = bool(group >> 4), group & 15
        head = 39 if extended else 19
        body = head + 8 * size  # (the bits the CRC covers)
        bits = np.zeros((len(rows), body + 15), dtype=np.uint8)
        ident = cob[rows]
        base = (ident >> 18 if extended else ident) & 0x7FF
        for i in range(11):
            bits[:, 1 + i] = (base >> (10 - i)) & 1
        if extended:
            bits[:, 12] = 1  # (SRR)
            bits[:, 13] = 1  # (IDE)
            low = ident & 0x3FFFF
            for i in range(18):
                bits[:, 14 + i] = (low >> (17 - i)) & 1
            bits[:, 32] = rtr[rows]
        else:
            bits[:, 12] = rtr[rows]
        dlc = dlc_field[rows]
        for i in range(4):
            bits[:, head - 4 + i] = (dlc >> (3 - i)) & 1
        if size:
            bits[:, head:body] = np.unpackbits(block.data[rows, :size], axis=1)
        # the CRC: zeros before the bits change nothing (it starts at 0), so the bits are
        # padded in front to whole bytes and taken a byte at a time
        pad = -body % 8
        packed = np.packbits(
            np.concatenate((np.zeros((len(rows), pad), dtype=np.uint8), bits[:, :body]), axis=1),
            axis=1,
        ).astype(np.int64)
        crc = np.zeros(len(rows), dtype=np.int64)
        for column in range(packed.shape[1]):
            crc = ((crc << 8) & 0x7FFF) ^ crc_table[((crc >> 7) ^ packed[:, column]) & 0xFF]
        for i in range(15):
            bits[:, body + i] = (crc >> (14 - i)) & 1
        # the stuff bits, a byte at a time from the start of frame to the end of the CRC
        stream = np.packbits(bits, axis=1).astype(np.int64)
        total = body + 15
        state = np.full(len(rows), 4, dtype=np.int64)  # (the idle bus before: recessive)
        stuffed = np.zeros(len(rows), dtype=np.int64)
        for column in range(stream.shape[1]):
            k = min(8, total - 8 * column)
            value = stream[:, column]
            stuffed += stuff_counts[k, state, value]
            state = stuff_states[k, state, value]
        out[rows] = total + stuffed + _TAIL
    return out
