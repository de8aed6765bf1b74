"""pcap and pcapng trace files with the SocketCAN link type, as Wireshark and tcpdump write them.

python-can reads and writes many trace formats but not pcap; these classes add it the way
python-can's own plugins do (entry points ``can.io.message_writer`` / ``can.io.message_reader``,
declared in cobus's ``pyproject.toml``), so once cobus is installed ``can.Logger("x.pcap")``,
``can.LogReader("x.pcapng")`` and every ``cobus`` command that takes a trace file handle them::

    cobus record bench.pcapng --duration 10         # then open it in Wireshark, or:
    tshark -r bench.pcapng -d can.subdissector,canopen   # CAN payloads as CANopen

The container is dpkt's (pcap and pcapng); each packet is one ``struct can_frame`` /
``struct canfd_frame`` of Linux in the layout of LINKTYPE_CAN_SOCKETCAN (227): the identifier
with its EFF/RTR/ERR flags in network byte order, the payload length, the CAN FD flags, two
reserved bytes, then the payload (8 bytes for classic CAN, 64 for CAN FD, zero-padded).
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Iterator
from decimal import Decimal
from typing import Any, BinaryIO

import can
import dpkt
from can.io.generic import BinaryIOMessageReader, BinaryIOMessageWriter

__all__ = [
    "LINKTYPE_CAN_SOCKETCAN",
    "PcapReader",
    "PcapWriter",
    "PcapngWriter",
    "frame_bytes",
    "message_from_bytes",
]

LINKTYPE_CAN_SOCKETCAN = 227

_EFF = 0x8000_0000  # extended (29-bit) identifier
_RTR = 0x4000_0000  # remote transmission request
_ERR = 0x2000_0000  # error frame: the identifier holds the error classes
_FDF = 0x04  # CAN FD frame (set by Linux since 5.14; older captures tell FD by length only)
_BRS = 0x01
_ESI = 0x02
_HEADER = struct.Struct(">IBBBB")
_CAN_MTU = 16
_CANFD_MTU = 72
_SNAPLEN = 0xFFFF


def frame_bytes(msg: can.Message) -> bytes:
    """The SocketCAN bytes of ``msg``: what Linux hands to a packet socket on a CAN interface."""
    data = bytes(msg.data or b"")
    if msg.is_error_frame:
        ident = _ERR | (msg.arbitration_id & 0x1FFF_FFFF)
        return _HEADER.pack(ident, 8, 0, 0, 0) + data[:8].ljust(8, b"\x00")
    ident = msg.arbitration_id & (0x1FFF_FFFF if msg.is_extended_id else 0x7FF)
    if msg.is_extended_id:
        ident |= _EFF
    if msg.is_fd:
        flags = (
            _FDF | (_BRS if msg.bitrate_switch else 0) | (_ESI if msg.error_state_indicator else 0)
        )
        return _HEADER.pack(ident, len(data), flags, 0, 0) + data.ljust(64, b"\x00")
    if msg.is_remote_frame:
        return _HEADER.pack(ident | _RTR, min(msg.dlc, 8), 0, 0, 0) + bytes(8)
    return _HEADER.pack(ident, len(data), 0, 0, 0) + data.ljust(8, b"\x00")


def message_from_bytes(buf: bytes, timestamp: float = 0.0) -> can.Message:
    """The message of one SocketCAN packet; ``ValueError`` says what is wrong with a bad one."""
    if len(buf) < 8:
        raise ValueError(f"{len(buf)} bytes: too short for a SocketCAN frame (8-byte header)")
    ident, length, flags, _res0, _res1 = _HEADER.unpack_from(buf)
    payload = buf[8:]
    fd = bool(flags & _FDF) or len(buf) == _CANFD_MTU
    if ident & _ERR:
        return can.Message(
            timestamp=timestamp,
            arbitration_id=ident & 0x1FFF_FFFF,
            is_error_frame=True,
            dlc=8,
            data=payload[:8].ljust(8, b"\x00"),
        )
    extended = bool(ident & _EFF)
    arbitration_id = ident & (0x1FFF_FFFF if extended else 0x7FF)
    if fd:
        if length > 64 or length > len(payload):
            raise ValueError(f"CAN FD frame of {length} bytes with {len(payload)} bytes of payload")
        return can.Message(
            timestamp=timestamp,
            arbitration_id=arbitration_id,
            is_extended_id=extended,
            is_fd=True,
            bitrate_switch=bool(flags & _BRS),
            error_state_indicator=bool(flags & _ESI),
            data=payload[:length],
        )
    if length > 8:
        raise ValueError(f"classic CAN frame of length {length}: at most 8")
    if ident & _RTR:
        return can.Message(
            timestamp=timestamp,
            arbitration_id=arbitration_id,
            is_extended_id=extended,
            is_remote_frame=True,
            dlc=length,
        )
    if length > len(payload):
        raise ValueError(f"frame of {length} bytes with only {len(payload)} bytes of payload")
    return can.Message(
        timestamp=timestamp,
        arbitration_id=arbitration_id,
        is_extended_id=extended,
        data=payload[:length],
    )


class _Writer(BinaryIOMessageWriter):
    """Common part of the pcap and pcapng writers."""

    _ng = False

    def __init__(self, file: Any, append: bool = False, **kwargs: Any) -> None:
        if append:
            raise ValueError("pcap files cannot be appended to here: write a new file")
        super().__init__(file, mode="wb")
        self._out: Any
        if self._ng:
            self._out = dpkt.pcapng.Writer(
                self.file, snaplen=_SNAPLEN, linktype=LINKTYPE_CAN_SOCKETCAN
            )
        else:
            self._out = dpkt.pcap.Writer(
                self.file, snaplen=_SNAPLEN, linktype=LINKTYPE_CAN_SOCKETCAN, nano=True
            )

    def on_message_received(self, msg: can.Message) -> None:
        self._out.writepkt(frame_bytes(msg), ts=msg.timestamp)


class PcapWriter(_Writer):
    """Messages into a pcap file (nanosecond time stamps, LINKTYPE_CAN_SOCKETCAN)."""


class PcapngWriter(_Writer):
    """Messages into a pcapng file (one SocketCAN interface)."""

    _ng = True


class _Capped(io.RawIOBase):
    """A file that never hands out more than it holds, whatever length a damaged block claims.

    dpkt reads a block by the length written in it; without this a 4 GB length in a 1 kB file
    would ask for a 4 GB buffer before finding the file short.
    """

    def __init__(self, inner: BinaryIO, size: int | None) -> None:
        super().__init__()
        self._inner = inner
        self._left = size
        self.short = False  # a read ended inside a block: the file is truncated

    def readable(self) -> bool:
        return True

    def read(self, n: int | None = -1) -> bytes:
        if n is None or n < 0:
            data = self._inner.read() if self._left is None else self._inner.read(self._left)
        elif self._left is None:
            data = self._inner.read(n)
        else:
            data = self._inner.read(min(n, self._left))
        if self._left is not None:
            self._left -= len(data)
        if n is not None and 0 < len(data) < n:
            self.short = True
        return bytes(data)

    def seek(self, offset: int, whence: int = 0) -> int:
        if offset != 0 or whence != 0:
            raise io.UnsupportedOperation("only a seek to the start")
        position = self._inner.seek(0)
        self._left = _size(self._inner)
        return position


def _size(file: BinaryIO) -> int | None:
    try:
        return os.fstat(file.fileno()).st_size - file.tell()
    except (OSError, AttributeError, ValueError):
        return None


class PcapReader(BinaryIOMessageReader):
    """Messages from a pcap or pcapng file with the SocketCAN link type.

    A damaged, truncated or foreign file raises ``ValueError`` naming the file, the packet
    and what is wrong; frames before the damage have been yielded.
    """

    def __init__(self, file: Any, **kwargs: Any) -> None:
        super().__init__(file, mode="rb")
        self._name = str(getattr(self.file, "name", file))
        self._capped = capped = _Capped(self.file, _size(self.file))  # type: ignore[arg-type]
        try:
            self._pcap: Any = dpkt.pcap.UniversalReader(capped)
        except (ValueError, dpkt.Error, struct.error) as exc:
            raise ValueError(f"{self._name}: not a pcap or pcapng file ({exc})") from None
        linktype = self._pcap.datalink()
        if linktype != LINKTYPE_CAN_SOCKETCAN:
            raise ValueError(
                f"{self._name}: link type {linktype}, not SocketCAN CAN frames "
                f"({LINKTYPE_CAN_SOCKETCAN}); capture on the CAN interface itself, "
                "e.g. tcpdump -i can0 -w trace.pcap"
            )

    def __iter__(self) -> Iterator[can.Message]:
        number = 0
        packets = iter(self._pcap)
        while True:
            number += 1
            try:
                item = next(packets)
            except StopIteration:
                break
            except (ValueError, dpkt.Error, struct.error) as exc:
                raise ValueError(
                    f"{self._name}: packet {number} is damaged or the file is truncated ({exc})"
                ) from None
            ts, buf = item
            if self._capped.short:
                raise ValueError(
                    f"{self._name}: packet {number} is cut short: the file is truncated"
                )
            stamp = float(ts) if isinstance(ts, Decimal | int | float) else 0.0
            try:
                yield message_from_bytes(bytes(buf), stamp)
            except ValueError as exc:
                raise ValueError(f"{self._name}: packet {number}: {exc}") from None
