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
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
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
_FD_SIZES = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def frame_bytes(msg: can.Message) -> bytes:
    """The SocketCAN bytes of ``msg``: what Linux hands to a packet socket on a CAN interface."""
    data = bytes(msg.data or b"")
    if msg.is_error_frame:
        ident = _ERR | (msg.arbitration_id & 0x1FFF_FFFF)
        return _HEADER.pack(ident, 8, 0, 0, 0) + data[:8].ljust(8, b"\x00")
    limit = 0x1FFF_FFFF if msg.is_extended_id else 0x7FF
    if not 0 <= msg.arbitration_id <= limit:
        raise ValueError(
            f"identifier 0x{msg.arbitration_id:X} does not fit {limit.bit_length()} bits"
        )
    ident = msg.arbitration_id | (_EFF if msg.is_extended_id else 0)
    if msg.is_fd:
        if len(data) > 64:
            raise ValueError(f"a CAN FD frame of {len(data)} bytes: at most 64")
        size = next(n for n in _FD_SIZES if n >= len(data))  # Linux pads to a DLC length
        flags = (
            _FDF | (_BRS if msg.bitrate_switch else 0) | (_ESI if msg.error_state_indicator else 0)
        )
        return _HEADER.pack(ident, size, flags, 0, 0) + data.ljust(64, b"\x00")
    if len(data) > 8:
        raise ValueError(f"a classic CAN frame of {len(data)} bytes: at most 8")
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
        stamp = float(msg.timestamp)
        if not math.isfinite(stamp) or stamp < 0:
            raise ValueError(f"time stamp {stamp}: pcap files hold times from 1970 on only")
        if not self._ng and round(stamp % 1 * 1e9) >= 1_000_000_000:
            stamp = math.floor(stamp) + 1.0  # (dpkt would write 1e9 ns into the fraction)
        self._out.writepkt(frame_bytes(msg), ts=stamp)


class PcapWriter(_Writer):
    """Messages into a pcap file (nanosecond time stamps, LINKTYPE_CAN_SOCKETCAN)."""


class PcapngWriter(_Writer):
    """Messages into a pcapng file (one SocketCAN interface, microsecond time stamps)."""

    _ng = True


class _Chunked(io.RawIOBase):
    """A file read in chunks of at most 1 MiB, whatever length a damaged block claims: a
    block claiming 4 GB costs only the bytes the file really has (plain or gzip alike).
    ``short`` tells that a read ended inside a block (the file is truncated)."""

    _CHUNK = 1 << 20

    def __init__(self, inner: BinaryIO) -> None:
        super().__init__()
        self._inner = inner
        self.short = False

    def readable(self) -> bool:
        return True

    def read(self, n: int | None = -1) -> bytes:
        if n is None or n < 0:
            return bytes(self._inner.read())
        parts: list[bytes] = []
        left = n
        while left > 0:
            got = self._inner.read(min(left, self._CHUNK))
            if not got:
                break
            parts.append(got)
            left -= len(got)
        data = b"".join(parts)
        if 0 < len(data) < n:
            self.short = True
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        return int(self._inner.seek(offset, whence))

    def tell(self) -> int:
        return int(self._inner.tell())


@dataclass
class _Interface:
    linktype: int
    divisor: float = 1e6
    offset: int = 0
    name: str | None = None


class PcapReader(BinaryIOMessageReader):
    """Messages from a pcap or pcapng file with the SocketCAN link type.

    In a pcapng file every interface keeps its own link type, time resolution and name (the
    message's ``channel``); packets of interfaces that are no SocketCAN interface (Ethernet
    beside CAN in one capture) are skipped and counted in ``skipped``. A damaged, truncated
    or foreign file raises ``ValueError`` naming the packet and what is wrong; frames before
    the damage have been yielded.
    """

    def __init__(self, file: Any, **kwargs: Any) -> None:
        super().__init__(file, mode="rb")
        try:
            self._name = Path(str(getattr(self.file, "name", file))).name
            self._in = _Chunked(self.file)  # type: ignore[arg-type]
            self.skipped = 0
            head = self._in.read(4)
            self._in.seek(0)
            ng = head == b"\x0a\x0d\x0d\x0a"
            self._packets: Iterator[tuple[float, bytes, str | None]] = (
                self._pcapng() if ng else self._pcap()
            )
            try:  # the header, the link type: a foreign file is refused here
                self._first = next(self._packets, None)
            except (ValueError, dpkt.Error, struct.error) as exc:
                raise self._damaged(1, exc) from None
        except BaseException:
            self.stop()
            raise

    def _damaged(self, number: int, exc: BaseException) -> ValueError:
        """The error for a file the reader cannot go on with at packet ``number``."""
        text = str(exc).removeprefix(f"{self._name}: ") or type(exc).__name__
        if text.startswith(("link type", "not a pcap")):
            return ValueError(f"{self._name}: {text}")
        return ValueError(
            f"{self._name}: packet {number} is damaged or the file is truncated ({text})"
        )

    def _pcap(self) -> Iterator[tuple[float, bytes, str | None]]:
        try:
            reader = dpkt.pcap.Reader(self._in)
        except (ValueError, dpkt.Error, struct.error) as exc:
            raise ValueError(f"{self._name}: not a pcap or pcapng file ({exc})") from None
        linktype = reader.datalink()
        if linktype != LINKTYPE_CAN_SOCKETCAN:
            raise ValueError(self._foreign(linktype))
        for ts, buf in reader:
            yield float(ts), bytes(buf), None

    def _foreign(self, linktype: int) -> str:
        return (
            f"{self._name}: link type {linktype}, not SocketCAN CAN frames "
            f"({LINKTYPE_CAN_SOCKETCAN}); capture on the CAN interface itself, "
            "e.g. tcpdump -i can0 -w trace.pcap"
        )

    def _pcapng(self) -> Iterator[tuple[float, bytes, str | None]]:
        """The packets of every section and interface (dpkt reads only the first)."""
        order = "<"
        interfaces: list[_Interface] = []
        seen_can = False
        while True:
            head = self._in.read(8)
            if not head:
                break
            if len(head) < 8:
                raise ValueError("the file ends inside a block header: it is truncated")
            kind = struct.unpack_from("<I", head)[0]
            if kind == dpkt.pcapng.PCAPNG_BT_SHB:  # a new section: its own byte order
                bom = self._in.read(4)
                if bom == struct.pack("<I", dpkt.pcapng.BYTE_ORDER_MAGIC):
                    order = "<"
                elif bom == struct.pack(">I", dpkt.pcapng.BYTE_ORDER_MAGIC):
                    order = ">"
                else:
                    raise ValueError("a section header with no valid byte-order mark")
                head += bom
                interfaces = []
            kind, length = struct.unpack(order + "II", head[:8])
            if length < 12 or length % 4:
                raise ValueError(f"a block of length {length}: damaged")
            body = self._in.read(length - len(head))
            if self._in.short or len(body) < length - len(head):
                raise ValueError("the file ends inside a block: it is truncated")
            block = head + body
            le = order == "<"
            if kind == dpkt.pcapng.PCAPNG_BT_IDB:
                cls = (
                    dpkt.pcapng.InterfaceDescriptionBlockLE
                    if le
                    else dpkt.pcapng.InterfaceDescriptionBlock
                )
                interfaces.append(_interface(cls(block), order))
                seen_can = seen_can or interfaces[-1].linktype == LINKTYPE_CAN_SOCKETCAN
            elif kind in (dpkt.pcapng.PCAPNG_BT_EPB, dpkt.pcapng.PCAPNG_BT_PB):
                if kind == dpkt.pcapng.PCAPNG_BT_EPB:
                    cls = (
                        dpkt.pcapng.EnhancedPacketBlockLE if le else dpkt.pcapng.EnhancedPacketBlock
                    )
                else:
                    cls = dpkt.pcapng.PacketBlockLE if le else dpkt.pcapng.PacketBlock
                packet = cls(block)
                if packet.iface_id >= len(interfaces):
                    raise ValueError(f"a packet of interface {packet.iface_id}, never described")
                iface = interfaces[packet.iface_id]
                if iface.linktype != LINKTYPE_CAN_SOCKETCAN:
                    self.skipped += 1
                    continue
                ts = iface.offset + ((packet.ts_high << 32) | packet.ts_low) / iface.divisor
                yield ts, bytes(packet.pkt_data), iface.name
            elif kind == dpkt.pcapng.PCAPNG_BT_SPB:
                # A simple packet block: no time stamp, interface 0.
                if interfaces and interfaces[0].linktype == LINKTYPE_CAN_SOCKETCAN:
                    size = struct.unpack_from(order + "I", block, 8)[0]
                    yield 0.0, bytes(block[12 : 12 + min(size, length - 16)]), interfaces[0].name
                else:
                    self.skipped += 1
        if not seen_can:
            kinds = sorted({i.linktype for i in interfaces})
            raise ValueError(self._foreign(kinds[0] if kinds else -1))

    def __iter__(self) -> Iterator[can.Message]:
        number = 0
        try:
            pending = [self._first] if self._first is not None else []
            packets = iter(self._packets)
            while True:
                number += 1
                try:
                    item = pending.pop() if pending else next(packets)
                except StopIteration:
                    break
                except (ValueError, dpkt.Error, struct.error) as exc:
                    raise self._damaged(number, exc) from None
                ts, buf, channel = item
                if self._in.short or not buf:
                    raise ValueError(
                        f"{self._name}: packet {number} is cut short: the file is truncated"
                    )
                try:
                    msg = message_from_bytes(buf, ts)
                except ValueError as exc:
                    raise ValueError(f"{self._name}: packet {number}: {exc}") from None
                if channel is not None:
                    msg.channel = channel
                yield msg
        finally:
            self.stop()


def _interface(idb: Any, order: str) -> _Interface:
    iface = _Interface(idb.linktype)
    for opt in idb.opts:
        if opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSRESOL and opt.data:
            value = opt.data[0]
            base = 2 if value & 0x80 else 10
            iface.divisor = float(base ** (value & 0x7F))
        elif opt.code == dpkt.pcapng.PCAPNG_OPT_IF_TSOFFSET and len(opt.data) >= 8:
            iface.offset = struct.unpack(order + "q", opt.data[:8])[0]
        elif opt.code == dpkt.pcapng.PCAPNG_OPT_IF_NAME and opt.data:
            iface.name = bytes(opt.data).rstrip(b"\0").decode("utf-8", "replace")
    return iface
