"""The block reader of BLF files (issue 45): frame for frame what python-can's reader gives,
whatever the frames (base and extended, remote, every length, error frames, CAN FD), the
containers (objects split across them, stored or deflated) and the block size; bombs
refused as the file check refuses them; what it does not expect left to python-can."""

from __future__ import annotations

import random
from pathlib import Path

import can
import numpy as np
import pytest

from cobus.trace.blocks import FrameBlock, blocks, message_blocks
from cobus.trace.fastread import blf_blocks, log_blocks
from cobus.trace.files import TraceFileError
from tests.test_hostile_inputs import blf_bomb


def _same(got: list[FrameBlock], want: list[FrameBlock]) -> None:
    assert [len(b) for b in got] == [len(b) for b in want]
    for a, b in zip(got, want, strict=True):
        for column in ("time", "cob_id", "flags", "dlc", "data"):
            assert np.array_equal(getattr(a, column), getattr(b, column)), column


def _python_can(path: Path, size: int) -> list[FrameBlock]:
    reader = can.LogReader(str(path))
    try:
        return list(message_blocks(reader, size))
    finally:
        reader.stop()


def _messages(count: int, seed: int = 45) -> list[can.Message]:
    rng = random.Random(seed)
    out = []
    t = 1_700_000_000.0
    for n in range(count):
        t += rng.choice((0.0001, 0.00037, 0.01))
        kind = rng.randrange(20)
        ext = kind == 1
        cob = rng.randrange(1 << 29) if ext else rng.randrange(1 << 11)
        if kind == 2:
            out.append(can.Message(timestamp=t, is_error_frame=True, arbitration_id=cob))
        elif kind == 3:
            size = rng.choice((0, 8, 12, 64))
            data = bytes(rng.randrange(256) for _ in range(size))
            out.append(
                can.Message(
                    timestamp=t, arbitration_id=cob, is_extended_id=ext, is_fd=True, data=data
                )
            )
        elif kind == 4:
            out.append(
                can.Message(
                    timestamp=t,
                    arbitration_id=cob,
                    is_remote_frame=True,
                    dlc=rng.randrange(9),
                    is_extended_id=ext,
                )
            )
        else:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
            out.append(can.Message(timestamp=t, arbitration_id=cob, is_extended_id=ext, data=data))
        if n == 10:
            out.append(can.Message(timestamp=t, arbitration_id=0x123, data=bytes(8)))
    return out


@pytest.mark.parametrize(
    ("container", "level"), [(128 * 1024, -1), (1000, -1), (333, 0), (4096, 9)]
)
def test_the_same_frames_as_python_cans_reader(tmp_path: Path, container: int, level: int) -> None:
    """Small containers split objects between them; level 0 stores them uncompressed."""
    path = tmp_path / "mixed.blf"
    with can.BLFWriter(str(path), max_container_size=container, compression_level=level) as w:
        for msg in _messages(5000):
            w.on_message_received(msg)
    for size in (1, 7, 65_536):
        _same(list(blf_blocks(path, size)), _python_can(path, size))
    _same(list(blocks(path)), _python_can(path, 65_536))


def test_a_frame_python_can_reads_its_own_way_is_left_to_it(tmp_path: Path) -> None:
    """A time stamp float64 cannot hold exactly (a frame 120 days in): python-can's reader
    takes over from that frame on, the frames before are not read twice."""
    path = tmp_path / "long.blf"
    with can.BLFWriter(str(path)) as writer:
        for n in range(300):
            writer.on_message_received(can.Message(timestamp=n * 0.01, arbitration_id=0x181))
        writer.on_message_received(can.Message(timestamp=120 * 86400.0, arbitration_id=0x182))
        writer.on_message_received(can.Message(timestamp=120 * 86400.5, arbitration_id=0x183))
    for size in (7, 1000):
        _same(list(blf_blocks(path, size)), _python_can(path, size))


def test_a_bomb_is_refused_without_inflating_it(tmp_path: Path) -> None:
    path = tmp_path / "bomb.blf"
    blf_bomb(path, 64 << 20, 128 * 1024)
    with pytest.raises(TraceFileError, match="inflates to more than the 131,072 bytes"):
        for _ in blf_blocks(path):
            pass
    blf_bomb(path, 1 << 20, 1 << 30)
    with pytest.raises(TraceFileError, match="announces 1,073,741,824 bytes"):
        for _ in blf_blocks(path):
            pass


def test_what_is_no_blf_file(tmp_path: Path) -> None:
    path = tmp_path / "no.blf"
    path.write_bytes(b"LOGX" + bytes(200))
    with pytest.raises(TraceFileError, match="does not start with LOGG"):
        list(blf_blocks(path))
    path.write_bytes(b"LOGG")
    with pytest.raises(TraceFileError, match="too short"):
        list(blf_blocks(path))


def test_a_candump_log_gives_the_same_frames_as_python_cans_reader(tmp_path: Path) -> None:
    """python-can's writer (an R or T after each frame) and candump's own lines (none),
    remote frames with and without a DLC, CAN FD, error frames, blank lines, CR LF."""
    path = tmp_path / "mixed.log"
    with can.Logger(str(path)) as logger:
        for msg in _messages(5000):
            logger(msg)
    for size in (1, 7, 65_536):
        _same(list(log_blocks(path, size)), _python_can(path, size))
    _same(list(blocks(path)), _python_can(path, 65_536))
    candump = tmp_path / "candump.log"
    candump.write_bytes(
        b"(1436509052.249713) vcan0 044#2A366C2BBA\n"
        b"(1436509052.449847) vcan0 0F6#BC\n\n"
        b"(1436509052.650004) vcan0 12345678#R\r\n"
        b"(1436509052.850118) can1 1A2#R5\n"
        b"(1436509053.050327) vcan0 123##1DEADBEEF00112233445566778899\n"
        b"(1436509053.250511) vcan0 20000080#0000000000000000\n"
        b"(1436509053.450687) vcan0 7FF#\n"
        b"(1436509053.650900) vcan0 181#1122334455667788AABB\n"
        b"(1436509053.851000) vcan0 181#123\n"
    )
    for size in (1, 3, 100):
        _same(list(log_blocks(candump, size)), _python_can(candump, size))


def test_a_log_line_of_another_form_is_left_to_python_can(tmp_path: Path) -> None:
    """A line the block reader does not parse: python-can's reader from that frame on (its
    own error for a line it cannot read either)."""
    path = tmp_path / "odd.log"
    lines = [f"({1.0 + n / 100:.6f}) can0 181#{n:02X}\n" for n in range(50)]
    lines.insert(30, "(1.295000) can0 181#R1x\n")  # (python-can: invalid literal for int)
    path.write_text("".join(lines))
    with pytest.raises(ValueError):
        list(log_blocks(path, 7))
    lines[30] = "(1.295000) can\t0 181#01\n"  # (a tab: python-can's split finds 4 fields)
    path.write_text("".join(lines))
    with pytest.raises(ValueError):
        list(log_blocks(path, 7))
    lines[30] = "(1.295000)  can0   181#01   \n"  # (spaces python-can's split takes)
    path.write_text("".join(lines))
    _same(list(log_blocks(path, 7)), _python_can(path, 7))


def test_a_bomb_behind_what_python_can_reads_is_still_refused(tmp_path: Path) -> None:
    """An object the block reader leaves to python-can's reader (CAN FD 64), then a bomb:
    the file is checked before python-can's reader inflates anything."""
    import zlib

    from can.io import blf

    path = tmp_path / "fd64.blf"
    with can.BLFWriter(str(path)) as writer:
        for n in range(5):
            writer.on_message_received(can.Message(arbitration_id=0x181, data=[n], timestamp=n))
    fd64 = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 32, 1, 32 + 40, 101) + bytes(16 + 40)
    body = blf.LOG_CONTAINER_STRUCT.pack(blf.ZLIB_DEFLATE, len(fd64)) + zlib.compress(fd64)
    size = blf.OBJ_HEADER_BASE_STRUCT.size + len(body)
    head = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, blf.LOG_CONTAINER)
    with path.open("ab") as f:
        f.write(head + body + bytes(size % 4))
    _same(list(blf_blocks(path, 3)), _python_can(path, 3))  # (handed over, the same)
    inflated = 64 << 20
    deflate = zlib.compressobj()
    bomb = deflate.compress(bytes(inflated)) + deflate.flush()
    body = blf.LOG_CONTAINER_STRUCT.pack(blf.ZLIB_DEFLATE, 128 * 1024) + bomb
    size = blf.OBJ_HEADER_BASE_STRUCT.size + len(body)
    head = blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, size, blf.LOG_CONTAINER)
    with path.open("ab") as f:
        f.write(head + body + bytes(size % 4))
    with pytest.raises(TraceFileError, match="inflates to more than"):
        list(blf_blocks(path))
