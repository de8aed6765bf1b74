"""A BLF reader that hands frames over in blocks of arrays (numpy), for whole traces.

python-can's BLF reader builds one ``can.Message`` per frame in Python; this one inflates
each log container (zlib), then takes the runs of CAN messages that follow each other in
it - what a BLF file of a CAN bus is made of - as one numpy record array each, and only
the other objects (error frames, CAN FD frames, markers) one by one. It gives what
python-can's reader gives, frame for frame (a test holds it to that on every trace), and
refuses what :func:`cobus.trace.files.check_blf` refuses (a container that announces or
inflates to more than :data:`~cobus.trace.files.MAX_CONTAINER`), without inflating twice.
What it does not expect of a file it leaves to python-can's reader, from the frame it had
come to (the file checked first): the blocks go on as python-can reads them.

:func:`log_blocks` does the same for candump ``.log`` files, a few megabytes of lines at a
time.
"""

from __future__ import annotations

import re
import struct
import zlib
from collections.abc import Callable, Generator, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import numpy.typing as npt

from cobus.trace.blocks import BLOCK, ERROR, EXTENDED, FD, REMOTE, FrameBlock, message_blocks
from cobus.trace.files import _SLACK, MAX_CONTAINER, TraceFileError, check_blf

__all__ = ["blf_blocks", "log_blocks"]

_CAN_MESSAGE, _CAN_MESSAGE2, _CAN_ERROR_EXT = 1, 86, 73
_CAN_FD_MESSAGE, _CAN_FD_MESSAGE_64, _LOG_CONTAINER = 100, 101, 10
_CAN_MSG_EXT = 0x80000000
_CAN_FD_LEN = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)

#: A CAN message object with a version 1 header: base header, object header, message.
_MESSAGE = [
    ("signature", "S4"),
    ("header_size", "<u2"),
    ("header_version", "<u2"),
    ("size", "<u4"),
    ("type", "<u4"),
    ("time_flags", "<u4"),
    ("client", "<u2"),
    ("version", "<u2"),
    ("time", "<u8"),
    ("channel", "<u2"),
    ("flags", "u1"),
    ("dlc", "u1"),
    ("can_id", "<u4"),
    ("data", "u1", (8,)),
]
_RECORDS = {48: np.dtype(_MESSAGE), 56: np.dtype([*_MESSAGE, ("extra", "V8")])}


class _Unexpected(Exception):
    """Something of the file this reader leaves to python-can's."""


class _Columns:
    """Frames gathered column by column until a block is full."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.parts: list[tuple[Any, ...]] = []
        self.count = 0

    def add(
        self,
        time: npt.NDArray[np.float64],
        cob_id: npt.NDArray[Any],
        flags: npt.NDArray[Any],
        dlc: npt.NDArray[Any],
        data: npt.NDArray[np.uint8],
    ) -> Iterator[FrameBlock]:
        self.parts.append((time, cob_id, flags, dlc, data))
        self.count += len(time)
        while self.count >= self.size:
            yield self._take(self.size)

    def _take(self, count: int) -> FrameBlock:
        columns = [np.concatenate(c) for c in zip(*self.parts, strict=True)]
        head = [c[:count] for c in columns]
        rest = [c[count:] for c in columns]
        self.parts = [tuple(rest)] if len(rest[0]) else []
        self.count -= count
        return FrameBlock(
            head[0].astype(np.float64),
            head[1].astype(np.uint32),
            head[2].astype(np.uint8),
            head[3].astype(np.uint8),
            np.ascontiguousarray(head[4], dtype=np.uint8).reshape(-1, 8),
        )

    def rest(self) -> Iterator[FrameBlock]:
        if self.count:
            yield self._take(self.count)


def _then_python_can(
    fast: Iterator[FrameBlock],
    reader: Callable[[], Any],
    size: int,
    where: Callable[[int, Exception], Exception] | None = None,
) -> Iterator[FrameBlock]:
    """``fast``'s blocks; once it meets what it leaves to python-can (:class:`_Unexpected`),
    the messages of python-can's ``reader()`` from the frame it had come to (frames gathered
    but not handed over yet are read again). When python-can's reader fails, ``where(n,
    error)`` (n: the messages it gave before) makes the error that says where."""
    done = 0
    try:
        for block in fast:
            done += len(block)
            yield block
        return
    except _Unexpected:
        pass
    source = reader()
    given = 0

    def counted() -> Iterator[Any]:
        nonlocal given
        for message in source:
            given += 1
            yield message

    try:
        messages = counted()
        for _ in range(done):
            next(messages)
        yield from message_blocks(messages, size)
    except (ValueError, IndexError, TypeError) as exc:  # (python-can's, on a line it cannot read)
        if where is None:
            raise
        raise where(given, exc) from exc
    finally:
        source.stop()


def blf_blocks(path: str | Path, size: int = BLOCK) -> Iterator[FrameBlock]:
    """The frames of BLF file ``path`` in blocks of ``size``, as python-can reads them."""
    import can

    def fast() -> Iterator[FrameBlock]:
        from can.io import blf

        with open(path, "rb") as f:
            head = f.read(blf.FILE_HEADER_STRUCT.size)
            if len(head) < blf.FILE_HEADER_STRUCT.size:
                raise TraceFileError(f"{Path(path).name}: too short for a BLF file")
            header = blf.FILE_HEADER_STRUCT.unpack(head)
            if header[0] != b"LOGG":
                raise TraceFileError(
                    f"{Path(path).name}: no BLF file (it does not start with LOGG)"
                )
            start = blf.systemtime_to_timestamp(header[14:22])
            f.seek(header[1])
            columns = _Columns(size)
            try:
                yield from _read(path, f, start, columns)
            except TraceFileError:  # (a container it refuses: the frames before it first)
                yield from columns.rest()
                raise
            yield from columns.rest()

    def python_can() -> Any:
        check_blf(path)  # (its containers checked as cobus decode checks them)
        return can.io.BLFReader(str(path))

    yield from _then_python_can(fast(), python_can, size)


def _read(path: str | Path, f: BinaryIO, start: float, columns: _Columns) -> Iterator[FrameBlock]:
    from can.io import blf

    base = blf.OBJ_HEADER_BASE_STRUCT
    tail = b""
    offset = f.tell()
    while True:
        raw = f.read(base.size)
        if not raw:
            return
        if len(raw) < base.size:
            raise _Unexpected
        signature, _, _, obj_size, obj_type = base.unpack(raw)
        if signature != b"LOBJ" or obj_size < base.size:
            raise _Unexpected
        if obj_type == _LOG_CONTAINER and obj_size - base.size > MAX_CONTAINER + _SLACK:
            raise TraceFileError(
                f"{Path(path).name}: the log container at byte {offset:,} holds "
                f"{obj_size - base.size:,} bytes, more than the {MAX_CONTAINER:,} cobus reads "
                "in one (real traces hold 128 KiB a container): a damaged or hostile file; "
                "not read"
            )
        body = f.read(obj_size - base.size)
        f.read(obj_size % 4)
        if obj_type == _LOG_CONTAINER:
            data = _inflate(path, offset, body)
            if data is not None:
                data = tail + data if tail else data
                used = yield from _objects(data, start, columns)
                tail = data[used:]
        offset = f.tell()


def _inflate(path: str | Path, offset: int, body: bytes) -> bytes | None:
    from can.io import blf

    if len(body) < blf.LOG_CONTAINER_STRUCT.size:
        raise _Unexpected
    method, announced = blf.LOG_CONTAINER_STRUCT.unpack_from(body)
    packed = body[blf.LOG_CONTAINER_STRUCT.size :]
    if method == blf.NO_COMPRESSION:
        return packed
    if method != blf.ZLIB_DEFLATE:
        return None  # (python-can skips it too, with a warning)
    where = f"{Path(path).name}: the log container at byte {offset:,}"
    if announced > MAX_CONTAINER:
        raise TraceFileError(
            f"{where} announces {announced:,} bytes uncompressed, more than the "
            f"{MAX_CONTAINER:,} cobus inflates (real traces hold 128 KiB a container): a "
            "damaged or hostile file; not read"
        )
    inflater = zlib.decompressobj()
    try:
        out = inflater.decompress(packed, announced + 1)
    except zlib.error:
        raise _Unexpected from None
    if len(out) > announced:
        raise TraceFileError(
            f"{where} inflates to more than the {announced:,} bytes it announces (a zip "
            "bomb?): a damaged or hostile file; not read"
        )
    return out


def _objects(data: bytes, start: float, columns: _Columns) -> Generator[FrameBlock, None, int]:
    """The frames of the objects in ``data``; returns how many bytes whole objects took
    (the rest continues in the next container)."""
    from can.io import blf

    base = blf.OBJ_HEADER_BASE_STRUCT
    end = len(data)
    pos = 0
    view = np.frombuffer(data, dtype=np.uint8)
    while True:
        found = data.find(b"LOBJ", pos, pos + 8)
        if found < 0:
            if pos + 8 > end:
                return pos
            raise _Unexpected
        pos = found
        if pos + base.size > end:
            return pos
        _, header_size, header_version, obj_size, obj_type = base.unpack_from(data, pos)
        if pos + obj_size > end:
            return pos
        record = _RECORDS.get(obj_size)
        if (
            obj_type in (_CAN_MESSAGE, _CAN_MESSAGE2)
            and header_version == 1
            and record is not None
            and header_size == 32
        ):
            count = (end - pos) // obj_size
            rows = view[pos : pos + count * obj_size].view(record)
            same = (
                (rows["signature"] == b"LOBJ")
                & (rows["size"] == obj_size)
                & (rows["type"] == obj_type)
                & (rows["header_version"] == 1)
                & (rows["header_size"] == 32)
            )
            run = count if same.all() else int(np.argmin(same))
            yield from _messages(rows[:run], start, columns)
            pos += run * obj_size
            continue
        try:
            frame = _one(data, pos, header_version, obj_size, obj_type, start)
        except struct.error:
            raise _Unexpected from None  # (a short object: python-can's reader decides)
        if frame is not None:
            yield from columns.add(*frame)
        pos += obj_size


def _times(raw: npt.NDArray[Any], flags: npt.NDArray[Any], start: float) -> npt.NDArray[Any]:
    if int(raw.max(initial=0)) >= 1 << 53:
        raise _Unexpected  # (float64 would round it: python-can's Decimal does not)
    scale = np.where(flags == 1, 1e5, 1e9)
    return raw.astype(np.float64) / scale + start


def _messages(rows: npt.NDArray[Any], start: float, columns: _Columns) -> Iterator[FrameBlock]:
    if not len(rows):
        return
    can_id = rows["can_id"].astype(np.int64)
    rtr = (rows["flags"] & 0x80) != 0
    flags = np.where(can_id & _CAN_MSG_EXT, EXTENDED, 0) | np.where(rtr, REMOTE, 0)
    dlc = rows["dlc"]
    data = rows["data"].copy()
    keep = np.minimum(dlc, 8)
    data[np.arange(8)[None, :] >= keep[:, None]] = 0  # (python-can keeps data[:dlc])
    data[rtr] = 0
    length = np.where(rtr, dlc, keep)
    yield from columns.add(
        _times(rows["time"], rows["time_flags"], start),
        can_id & 0x1FFFFFFF,
        flags,
        length,
        data,
    )


def _one(
    data: bytes, pos: int, header_version: int, obj_size: int, obj_type: int, start: float
) -> tuple[Any, ...] | None:
    """An object that is no run of CAN messages: one frame's columns, or None."""
    from can.io import blf

    if obj_type not in (_CAN_MESSAGE, _CAN_MESSAGE2, _CAN_ERROR_EXT, _CAN_FD_MESSAGE):
        if obj_type == _CAN_FD_MESSAGE_64:
            raise _Unexpected  # (rare: python-can's reader takes it from here)
        return None  # (python-can skips what is not a frame)
    at = pos + blf.OBJ_HEADER_BASE_STRUCT.size
    if header_version == 1:
        time_flags, _, _, stamp = blf.OBJ_HEADER_V1_STRUCT.unpack_from(data, at)
        at += blf.OBJ_HEADER_V1_STRUCT.size
    elif header_version == 2:
        time_flags, _, _, stamp = blf.OBJ_HEADER_V2_STRUCT.unpack_from(data, at)
        at += blf.OBJ_HEADER_V2_STRUCT.size
    else:
        return None  # (python-can skips it, with a warning)
    if obj_type in (_CAN_MESSAGE, _CAN_MESSAGE2):
        _channel, msg_flags, dlc, can_id, payload = blf.CAN_MSG_STRUCT.unpack_from(data, at)
        rtr = bool(msg_flags & 0x80)
        flag = (EXTENDED if can_id & _CAN_MSG_EXT else 0) | (REMOTE if rtr else 0)
        body = b"" if rtr else payload[:dlc]
        length = dlc if rtr else len(body)
    elif obj_type == _CAN_ERROR_EXT:
        members = blf.CAN_ERROR_EXT_STRUCT.unpack_from(data, at)
        dlc, can_id, payload = members[5], members[7], members[9]
        flag = ERROR | (EXTENDED if can_id & _CAN_MSG_EXT else 0)
        body = payload[:dlc]
        length = len(body)
    else:
        members = blf.CAN_FD_MSG_STRUCT.unpack_from(data, at)
        _channel, msg_flags, dlc, can_id, _, _, fd_flags, valid, payload = members
        rtr = bool(msg_flags & 0x80)
        flag = (EXTENDED if can_id & _CAN_MSG_EXT else 0) | (REMOTE if rtr else 0)
        flag |= FD if fd_flags & 1 else 0
        body = b"" if rtr else payload[:valid]
        length = (_CAN_FD_LEN[dlc] if dlc <= 15 else 64) if rtr else len(body)
    row = np.frombuffer(body[:8].ljust(8, b"\0"), dtype=np.uint8).reshape(1, 8)
    return (
        _times(np.array([stamp], dtype=np.uint64), np.array([time_flags]), start),
        np.array([can_id & 0x1FFFFFFF]),
        np.array([flag]),
        np.array([min(length, 255)]),
        row,
    )


# ------------------------------------------------------------------ candump .log

#: One frame of a candump ``-L`` log (what python-can's CanutilsLogReader reads): the time,
#: the channel, the identifier in hex, ``#`` and the rest (data in hex, ``R`` and a DLC for
#: a remote frame, ``#`` and flags for CAN FD), an ``R``/``T`` python-can's writer adds.
_LOG_LINE = re.compile(
    rb"^[ \t]*\(([0-9][0-9.]*)\)[ \t]+\S+[ \t]+([0-9A-Fa-f]+)#(\S*)(?:[ \t]+[RrTt])?[ \t\r]*$",
    re.M,
)
_NON_BLANK = re.compile(rb"^[ \t\r]*[^ \t\r\n]", re.M)
_CAN_ERR_FLAG, _CAN_ERR_BUSERROR = 0x20000000, 0x80
_CHUNK = 8 << 20  # bytes of the file parsed at once

#: Each byte's value as a hex digit (255: none).
_NIBBLE = np.full(256, 255, dtype=np.uint8)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _NIBBLE[_c] = _i
    _NIBBLE[bytes([_c]).lower()[0]] = _i


def log_blocks(path: str | Path, size: int = BLOCK) -> Iterator[FrameBlock]:
    """The frames of candump log ``path`` in blocks of ``size``, as python-can reads them:
    the lines parsed a few megabytes at a time, column by column with numpy (a chunk with
    a line of another layout: with one regular expression); a line it does not know is
    left to python-can's reader, from the frame it had come to."""
    import can

    def fast() -> Iterator[FrameBlock]:
        columns = _Columns(size)
        yield from _log(path, columns)
        yield from columns.rest()

    def where(given: int, exc: Exception) -> Exception:
        """The line python-can stopped at: it gives a message for each line not blank."""
        with open(path, "rb") as f:
            for number, line in enumerate(f, 1):
                if line.strip():
                    if given == 0:
                        text = line.strip().decode("utf-8", "replace")
                        shown = text if len(text) <= 60 else text[:57] + "..."
                        why = str(exc) or type(exc).__name__
                        return TraceFileError(
                            f"line {number}: {shown!r} is no candump line "
                            f"(python-can's reader says: {why})"
                        )
                    given -= 1
        return exc

    yield from _then_python_can(fast(), lambda: can.io.CanutilsLogReader(str(path)), size, where)


def _log(path: str | Path, columns: _Columns) -> Iterator[FrameBlock]:
    with open(path, "rb") as f:
        carry = b""
        while True:
            piece = f.read(_CHUNK)
            text = carry + piece
            if piece:
                cut = text.rfind(b"\n") + 1
                text, carry = text[:cut], text[cut:]
            else:
                carry = b""
            if text:
                frames = _lines_by_layout(text)
                if frames is None:  # (a line of another layout: the regular expression)
                    yield from _lines(text, columns)
                else:
                    yield from columns.add(*frames)
            if not piece:
                return


def _first_after(positions: npt.NDArray[np.int64], after: npt.NDArray[np.int64]) -> Any:
    """For each of ``after``, the first of ``positions`` at or past it (len: none)."""
    at = np.searchsorted(positions, after)
    return np.append(positions, np.iinfo(np.int64).max)[at]


def _lines_by_layout(text: bytes) -> tuple[Any, ...] | None:
    """The frames of ``text`` (whole lines) found column by column, when every line has
    candump's layout: ``(SECONDS.FRACTION) CHANNEL ID#DATA`` and maybe `` R`` or `` T``;
    None when a line has another (blank, other spacing): the regular expression's turn."""
    padded = np.frombuffer(text + bytes(_WINDOW), dtype=np.uint8)
    buf = padded[: len(text)]
    # the _WINDOW characters from each place in the text, for rows of characters at a time
    windows = np.lib.stride_tricks.sliding_window_view(padded, _WINDOW)
    if not len(buf) or buf[-1] != 10 or buf.max() >= 128:  # (beyond ASCII)
        return None
    # every character the layout turns on is below "0": one pass finds them all
    marks = np.flatnonzero(buf < 48)
    kind = buf[marks]
    ends = marks[kind == 10]
    odd = kind < 32  # (control bytes)
    if odd.sum() != len(ends):
        lone = marks[odd & (kind != 10)]
        if (buf[lone] != 13).any() or (buf[np.minimum(lone + 1, len(buf) - 1)] != 10).any():
            return None  # (a tab, a CR inside a line...: python-can's split decides)
    starts = np.concatenate(([0], ends[:-1] + 1))
    stop = ends - (buf[np.maximum(ends - 1, 0)] == 13)  # (before a CR)
    if (buf[starts] != 40).any():  # (
        return None
    close = _first_after(marks[kind == 41], starts)  # )
    spaces = marks[kind == 32]
    if not (close < stop).all() or (buf[close + 1] != 32).any():
        return None
    channel_end = _first_after(spaces, close + 2)
    hashes = _first_after(marks[kind == 35], channel_end)
    if not ((channel_end > close + 2) & (hashes < stop)).all():
        return None
    data_end = _first_after(spaces, hashes)
    suffix = data_end < stop
    if suffix.any():  # (python-can's writer: " R" or " T" after the frame)
        at = data_end[suffix]
        mark = buf[np.minimum(at + 1, len(buf) - 1)] | 0x20
        if ((at + 2 != stop[suffix]) | ((mark != 114) & (mark != 116))).any():
            return None
    data_end = np.where(suffix, data_end, stop)
    # the identifier: the digits between the channel and #, 1 to 8 of them
    id_len = hashes - channel_end - 1
    if ((id_len < 1) | (id_len > 8)).any():  # (a space in it: no hex digit, refused below)
        return None
    # the time: digits and one point between the parentheses, exact as python-can's float()
    last = len(buf) - 1
    tlen = close - starts - 1
    fixed = _fixed_times(windows, starts, tlen)
    if fixed is not None:  # (the usual: every time of one width, its point in one place)
        value, count, places, points, bad = fixed
    else:
        value, count, places, points, bad = _times_by_column(buf, starts, tlen, last)
    if bad is None:
        return None
    if bad.any() or (points > 1).any() or (count == 0).any() or (value >= 1 << 53).any():
        return None  # (another form, or more digits than float64 holds exactly)
    times = value / (10.0**places)
    # the identifier and the data in hex
    cob = _hex_number(windows, channel_end + 1, id_len)
    if cob is None:
        return None
    data_len = data_end - hashes - 1
    nibbles = _NIBBLE[windows[hashes + 1, :16]]
    inside = data_len[:, None] > _SIXTEEN
    plain = (data_len <= 16) & (data_len % 2 == 0) & ~(inside & (nibbles == 255)).any(axis=1)
    pairs = nibbles[:, 0::2].astype(np.uint16) * 16 + nibbles[:, 1::2]
    data = np.where(inside[:, 0::2] & plain[:, None], pairs, 0).astype(np.uint8)
    nbytes = np.where(plain, data_len // 2, 0)
    error = ((cob & _CAN_ERR_FLAG) != 0) & ((cob & _CAN_ERR_BUSERROR) != 0)
    flags = np.where(id_len > 3, EXTENDED, 0)
    dlc = nbytes.copy()
    cob = np.where(error, 0, cob & 0x1FFFFFFF)
    for i in np.flatnonzero(~plain | error).tolist():
        rest = text[int(hashes[i]) + 1 : int(data_end[i])]
        flags[i], dlc[i], data[i] = _special(rest, bool(error[i]), int(id_len[i]) > 3)
    return times, cob, flags, dlc, data


_SIXTEEN = np.arange(16)
_WINDOW = 20  # (the widest run of characters read at once: a time of 19)


def _fixed_times(windows: Any, starts: Any, tlen: Any) -> tuple[Any, ...] | None:
    """The times of lines whose times are all of one width with the point in one column,
    digit columns at once; None otherwise (:func:`_times_by_column` reads them)."""
    width = int(tlen[0])
    if not 2 <= width <= 19 or (tlen != width).any():
        return None
    chars = windows[starts + 1, :width]
    point = np.flatnonzero(chars[0] == 46)
    if len(point) != 1:
        return None
    p = int(point[0])
    digits = chars - np.uint8(48)  # (anything but a digit wraps past 9)
    if (chars[:, p] != 46).any() or (np.delete(digits, p, axis=1) > 9).any():
        return None
    value = np.zeros(len(starts), dtype=np.int64)
    for column in range(width):  # (a column at a time: quicker than a product of matrices)
        if column != p:
            value = value * 10 + digits[:, column]
    n = len(starts)
    count = np.full(n, width - 1, dtype=np.int64)
    places = np.full(n, width - 1 - p, dtype=np.int64)
    return value, count, places, np.ones(n, dtype=np.int64), np.zeros(n, dtype=bool)


def _times_by_column(buf: Any, starts: Any, tlen: Any, last: int) -> tuple[Any, ...]:
    """The times of lines of any width, a character column at a time (``bad`` None: more
    digits than the reader takes)."""
    n = len(starts)
    value = np.zeros(n, dtype=np.int64)
    count = np.zeros(n, dtype=np.int64)
    places = np.zeros(n, dtype=np.int64)
    points = np.zeros(n, dtype=np.int64)
    bad = tlen < 1
    for j in range(int(tlen.max(initial=0))):
        c = buf[np.minimum(starts + 1 + j, last)].astype(np.int64)
        inside = j < tlen
        digit = inside & (c >= 48) & (c <= 57)
        point = inside & (c == 46)
        bad |= inside & ~digit & ~point
        value = np.where(digit, value * 10 + (c - 48), value)
        count += digit
        places += digit & (points > 0)
        points += point
        if (count > 18).any():
            return value, count, places, points, None
    return value, count, places, points, bad


def _hex_number(windows: Any, at: Any, length: Any) -> Any:
    """The hex numbers of ``length`` (1..8) digits at ``at``; None where one is no hex."""
    width = int(length.max(initial=1))
    nibbles = _NIBBLE[windows[at, :width]].astype(np.int64)
    inside = np.arange(width) < length[:, None]
    if (inside & (nibbles == 255)).any():
        return None
    if (length == width).all():
        return nibbles @ (16 ** np.arange(width - 1, -1, -1, dtype=np.int64))
    number = np.zeros(len(at), dtype=np.int64)
    for j in range(width):
        number = np.where(inside[:, j], number * 16 + nibbles[:, j], number)
    return number


def _lines(text: bytes, columns: _Columns) -> Iterator[FrameBlock]:
    found = _LOG_LINE.findall(text)
    lines = text.count(b"\n") + (not text.endswith(b"\n"))
    if len(found) != lines and len(found) != len(_NON_BLANK.findall(text)):
        raise _Unexpected  # (a line of another form: python-can's reader says what it is)
    if not found:
        return
    stamps, idents, rests = zip(*found, strict=True)
    try:
        times = np.array(stamps, dtype="S40").astype(np.float64)
    except ValueError:
        raise _Unexpected from None
    ids, id_len = _hex_columns(idents, 8)
    if int(id_len.max()) > 8:
        raise _Unexpected  # (python-can takes it; a CAN identifier has 8 digits at most)
    shift = 4 * (id_len[:, None] - 1 - np.arange(8)[None, :])
    inside = np.arange(8)[None, :] < id_len[:, None]
    cob = np.where(inside, ids.astype(np.int64) << np.maximum(shift, 0), 0).sum(axis=1)
    if (ids[inside] == 255).any():
        raise _Unexpected
    raw, rest_len = _hex_columns(rests, 16)
    plain = (rest_len % 2 == 0) & ~(
        (raw == 255) & (np.arange(16)[None, :] < rest_len[:, None])
    ).any(axis=1)
    nbytes = rest_len // 2
    data = (raw[:, 0::2].astype(np.uint16) * 16 + raw[:, 1::2]).astype(np.uint8)
    data[np.arange(8)[None, :] >= nbytes[:, None]] = 0
    error = ((cob & _CAN_ERR_FLAG) != 0) & ((cob & _CAN_ERR_BUSERROR) != 0)
    flags = np.where(id_len > 3, EXTENDED, 0) | np.where(error, ERROR, 0)
    dlc = nbytes.copy()
    cob = np.where(error, 0, cob & 0x1FFFFFFF)
    flags = np.where(error, ERROR, flags)
    for i in np.flatnonzero(~plain | error).tolist():
        flags[i], dlc[i], data[i] = _special(rests[i], bool(error[i]), int(id_len[i]) > 3)
    yield from columns.add(times, cob, flags, dlc, data)


def _hex_columns(
    words: tuple[bytes, ...], width: int
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.int64]]:
    """Each word's first ``width`` characters as hex digit values (255: none) and each
    word's length."""
    packed = np.array(words, dtype=f"S{width + 1}")  # (one more: a longer word shows)
    chars = packed.view(np.uint8).reshape(len(words), width + 1)
    lengths = (chars != 0).sum(axis=1)  # (no hex digit or letter is a zero byte)
    long = lengths > width
    if long.any():  # (the true lengths, for what the caller refuses or reads its own way)
        lengths[long] = [len(words[i]) for i in np.flatnonzero(long).tolist()]
    return _NIBBLE[chars[:, :width]], lengths


def _special(rest: bytes, error: bool, extended: bool) -> tuple[int, int, npt.NDArray[np.uint8]]:
    """Flags, length and data of a frame that is no classic data frame of up to 8 bytes
    (remote, CAN FD, an error frame, more than 8 bytes, an odd number of digits), as
    python-can reads it."""
    try:
        text = rest.decode("ascii")
    except UnicodeDecodeError:
        raise _Unexpected from None
    flags = EXTENDED if extended else 0
    fd = False
    if text[:1] == "#":
        fd = True
        if len(text) < 2 or not text[1].isdigit():
            raise _Unexpected
        text = text[2:]
    if text[:1].lower() == "r" and not error:
        tail = text[1:]
        if tail and not tail.isdigit():
            raise _Unexpected
        flags |= REMOTE | (FD if fd else 0)
        return flags, int(tail) if tail else 0, np.zeros(8, dtype=np.uint8)
    try:
        body = bytes(int(text[i : i + 2], 16) for i in range(0, len(text), 2))
    except ValueError:
        raise _Unexpected from None
    if error:  # (python-can keeps neither identifier nor data; its default: extended)
        return ERROR | EXTENDED, 0, np.zeros(8, dtype=np.uint8)
    flags |= FD if fd else 0
    row = np.frombuffer(body[:8].ljust(8, b"\0"), dtype=np.uint8).copy()
    return flags, min(len(body), 255), row
