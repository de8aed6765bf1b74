"""pcap/pcapng with the SocketCAN link type: python-can plugins, ``cobus record``/``decode`` with
them, damaged files, and Debian's tshark reading a recording as CANopen frame by frame."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import threading
from pathlib import Path

import can
import dpkt
import pytest

from cobus.cli import main
from cobus.proto import Frame
from cobus.runtime import Network
from cobus.runtime.bus import message_to_frame
from cobus.sim import Rig, start_rig
from cobus.trace import frame_kind
from cobus.trace.pcap import (
    LINKTYPE_CAN_SOCKETCAN,
    PcapReader,
    frame_bytes,
    message_from_bytes,
)
from tests.test_trace_cli import RIG, listening
from tests.util import need

MESSAGES = [
    can.Message(timestamp=1.0, arbitration_id=0x000, is_extended_id=False, data=b"\x01\x05"),
    can.Message(timestamp=1.25, arbitration_id=0x080, is_extended_id=False, data=b""),
    can.Message(timestamp=1.5, arbitration_id=0x705, is_extended_id=False, is_remote_frame=True),
    can.Message(
        timestamp=1.75,
        arbitration_id=0x60A,
        is_extended_id=False,
        data=bytes.fromhex("4008100000000000"),
    ),
    can.Message(timestamp=2.0, arbitration_id=0x1ABCDE0F, is_extended_id=True, data=b"\x01"),
    can.Message(
        timestamp=2.5,
        arbitration_id=0x123,
        is_extended_id=False,
        is_fd=True,
        bitrate_switch=True,
        error_state_indicator=True,
        data=bytes(range(12)),
    ),
    can.Message(timestamp=3.0, arbitration_id=0x004, is_error_frame=True, data=bytes(8)),
    can.Message(timestamp=1e9 + 0.000123, arbitration_id=0x18A, is_extended_id=False, data=b"x"),
]


@pytest.mark.parametrize("suffix", [".pcap", ".pcapng"])
def test_python_can_writes_and_reads_every_kind_of_frame_through_the_plugin(
    suffix: str, tmp_path: Path
) -> None:
    path = tmp_path / f"t{suffix}"
    with can.Logger(str(path)) as logger:
        for msg in MESSAGES:
            logger(msg)
    with can.LogReader(str(path)) as reader:
        back = list(reader)
    assert len(back) == len(MESSAGES)
    for sent, read in zip(MESSAGES, back, strict=True):
        assert sent.equals(read, timestamp_delta=1e-6, check_channel=False), (sent, read)


def test_the_bytes_are_linux_socketcan_frames() -> None:
    assert frame_bytes(MESSAGES[0]) == bytes.fromhex("00000000 02 000000 0105000000000000")
    assert frame_bytes(MESSAGES[2])[:8] == bytes.fromhex("40000705 00 000000")
    assert frame_bytes(MESSAGES[4])[:4] == bytes.fromhex("9abcde0f")  # EFF flag
    fd = frame_bytes(MESSAGES[5])
    assert len(fd) == 72 and fd[4:6] == bytes([12, 0x07])  # FDF | BRS | ESI
    assert frame_bytes(MESSAGES[6])[:4] == bytes.fromhex("20000004")
    # A capture of an older Linux tells CAN FD by the length only (no FDF flag).
    old = bytearray(fd)
    old[5] = 0
    assert message_from_bytes(bytes(old)).is_fd
    with pytest.raises(ValueError, match="at most 8"):
        message_from_bytes(bytes.fromhex("00000123 09 000000") + bytes(8))
    with pytest.raises(ValueError, match="too short"):
        message_from_bytes(b"\x00\x01")


def test_cobus_decode_reads_a_pcap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    trace = tmp_path / "bench.pcapng"
    with can.Logger(str(trace)) as logger:
        for n, data in enumerate([b"\x01\x0a", bytes.fromhex("2171010000000000")]):
            cob = 0x000 if n == 0 else 0x08A
            logger(
                can.Message(timestamp=5.0 + n, arbitration_id=cob, is_extended_id=False, data=data)
            )
    assert main(["decode", str(trace)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(None, 1)[1] for line in lines] == [
        "NMT start -> node 10",
        "node 10 EMCY 7121h Additional modules (7121h) (register 01h: generic)",
    ]
    assert lines[1].split()[0] == "1.000000"


def _pcap_bytes(linktype: int = LINKTYPE_CAN_SOCKETCAN, packets: int = 3) -> bytes:
    path_like = _Buffer()
    writer = dpkt.pcap.Writer(path_like, snaplen=0xFFFF, linktype=linktype)
    for n in range(packets):
        writer.writepkt(frame_bytes(MESSAGES[0]), ts=float(n))
    return bytes(path_like.data)


class _Buffer:
    def __init__(self) -> None:
        self.data = bytearray()

    def write(self, b: bytes) -> None:
        self.data += b


def test_damaged_and_foreign_files_are_clear_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = _pcap_bytes()
    truncated = tmp_path / "cut.pcap"
    truncated.write_bytes(good[:-5])
    with pytest.raises(ValueError, match=r"cut.pcap: packet 3 is cut short: the file is truncated"):
        list(can.LogReader(str(truncated)))
    assert main(["decode", str(truncated)]) == 1
    captured = capsys.readouterr()
    assert captured.out.count("NMT start") == 2  # what came before the damage is kept
    assert "packet 3 is cut short" in captured.err

    # A packet header that claims 4 GB in a small file: refused without reading 4 GB.
    huge = bytearray(good)
    struct.pack_into("<II", huge, 24 + 8, 0xFFFF_FFF0, 0xFFFF_FFF0)
    bomb = tmp_path / "bomb.pcap"
    bomb.write_bytes(bytes(huge))
    with pytest.raises(ValueError, match="packet 1"):
        list(can.LogReader(str(bomb)))

    # The same for pcapng: a cut file and a block claiming 4 GB.
    ng = tmp_path / "good.pcapng"
    with can.Logger(str(ng)) as logger:
        for msg in MESSAGES[:3]:
            logger(msg)
    blob = ng.read_bytes()
    (tmp_path / "cut.pcapng").write_bytes(blob[:-10])
    with pytest.raises(ValueError, match=r"cut.pcapng: packet 3 is (damaged|cut short)"):
        list(can.LogReader(str(tmp_path / "cut.pcapng")))
    first_packet = blob.index(b"\x06\x00\x00\x00")  # an enhanced packet block's type
    huge = bytearray(blob)
    struct.pack_into("<I", huge, first_packet + 4, 0xFFFF_FFF0)
    (tmp_path / "bomb.pcapng").write_bytes(bytes(huge))
    with pytest.raises(ValueError, match="packet 1"):
        list(can.LogReader(str(tmp_path / "bomb.pcapng")))

    ethernet = tmp_path / "eth.pcap"
    ethernet.write_bytes(_pcap_bytes(linktype=1))
    with pytest.raises(ValueError, match=r"link type 1, not SocketCAN CAN frames"):
        can.LogReader(str(ethernet))
    assert main(["decode", str(ethernet)]) == 1
    assert "capture on the CAN interface itself" in capsys.readouterr().err

    text = tmp_path / "notes.pcap"
    text.write_text("not a capture at all\n")
    with pytest.raises(ValueError, match="not a pcap or pcapng file"):
        can.LogReader(str(text))
    short_packet = tmp_path / "short.pcap"
    out = _Buffer()
    writer = dpkt.pcap.Writer(out, snaplen=0xFFFF, linktype=LINKTYPE_CAN_SOCKETCAN)
    writer.writepkt(b"\x00\x00\x01", ts=1.0)
    short_packet.write_bytes(bytes(out.data))
    with pytest.raises(ValueError, match="packet 1: 3 bytes: too short"):
        list(can.LogReader(str(short_packet)))


def _tshark_kind(function_code: str, node: str) -> str:
    code = int(function_code, 16)
    if code == 0:
        return "nmt"
    if code == 1:
        return "emcy" if node and int(node, 16 if node.startswith("0x") else 10) else "sync"
    if code == 2:
        return "time"
    if 3 <= code <= 10:
        return "pdo"
    if code in (11, 12):
        return "sdo"
    if code == 14:
        return "hb"
    if code == 15:
        return "lss"
    return f"function code {code}"


def test_tshark_reads_a_cobus_recording_as_the_same_canopen_frames(tmp_path: Path) -> None:
    need(shutil.which("tshark"), "Debian's tshark is not installed")
    channel = f"pcap-{os.getpid()}"
    trace = tmp_path / "rig.pcapng"
    with Network(interface="virtual", channel=channel) as net:
        start_rig(net, Rig.loads(RIG))
        node = net.add_remote(10)
        result: list[int] = []
        recorder = threading.Thread(
            target=lambda: result.append(
                main(["record", str(trace), "--duration", "1.5", "-i", "virtual", "-c", channel])
            )
        )
        recorder.start()
        listening(channel, 2)
        net.sleep(0.05)
        node.sdo.upload(0x1008, 0)  # segmented
        node.sdo.download(0x1017, 0, (100).to_bytes(2, "little"))
        node.nmt.start()
        for _ in range(3):
            net.sleep(0.02)
            net.send(Frame(0x080, b""))
        net.send(Frame(0x08A, bytes.fromhex("1081110000000000")))  # an EMCY
        net.send(Frame(0x100, bytes.fromhex("00e1f50510270000")))  # TIME
        net.send(Frame(0x7E5, bytes.fromhex("0400000000000000")))  # LSS switch global
        recorder.join()
    assert result == [0]
    with can.LogReader(str(trace)) as reader:
        frames = [message_to_frame(m) for m in reader]
    assert len(frames) > 20
    fields = ["frame.number", "can.id", "canopen.function_code", "canopen.node_id"]
    out = subprocess.run(
        ["tshark", "-r", str(trace), "-d", "can.subdissector,canopen", "-T", "fields"]
        + [x for f in fields for x in ("-e", f)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    rows = [line.split("\t") for line in out.splitlines()]
    assert len(rows) == len(frames)
    seen = set()
    for frame, (number, can_id, function_code, node_id) in zip(frames, rows, strict=True):
        assert frame is not None
        assert int(can_id) == frame.cob_id, number
        ours = frame_kind(frame)
        seen.add(ours)
        if frame.rtr:  # Wireshark's CANopen dissector leaves remote frames to CAN
            assert function_code == "", number
            continue
        assert _tshark_kind(function_code, node_id) == ours, (number, hex(frame.cob_id))
        if node_id and ours not in ("nmt", "lss"):
            assert int(node_id, 0) == frame.cob_id & 0x7F, number
    assert {"nmt", "sync", "emcy", "time", "pdo", "sdo", "hb", "lss"} <= seen


def test_gzip_whole_seconds_and_bad_times(tmp_path: Path) -> None:
    """A .pcap.gz reads back whole (python-can (de)compresses); a time a hair below a whole
    second is not written as 1e9 ns; negative times are refused, not mangled."""
    for suffix in (".pcap.gz", ".pcapng.gz"):
        path = tmp_path / f"many{suffix}"
        with can.Logger(str(path)) as logger:
            for n in range(2000):
                logger(can.Message(timestamp=10.0 + n * 1e-3, arbitration_id=0x181, data=b"ab"))
        with can.LogReader(str(path)) as reader:
            assert sum(1 for _ in reader) == 2000
    near = sum([0.1] * 10)  # 0.9999999999999999
    path = tmp_path / "near.pcap"
    with can.Logger(str(path)) as logger:
        logger(can.Message(timestamp=near, arbitration_id=0x181))
    raw = path.read_bytes()
    sec, frac = struct.unpack_from("<II", raw, 24)
    assert (sec, frac) == (1, 0)
    for suffix in (".pcap", ".pcapng"):
        with (
            can.Logger(str(tmp_path / f"neg{suffix}")) as logger,
            pytest.raises(ValueError, match="from 1970 on only"),
        ):
            logger(can.Message(timestamp=-1.5, arbitration_id=0x181))
    with pytest.raises(ValueError, match="at most 8"):
        frame_bytes(can.Message(arbitration_id=1, data=bytes(9), check=False))
    with pytest.raises(ValueError, match="does not fit 11 bits"):
        frame_bytes(can.Message(arbitration_id=0x800, is_extended_id=False, check=False))
    padded = frame_bytes(can.Message(arbitration_id=1, is_fd=True, data=bytes(10)))
    assert padded[4] == 12


def test_a_pcapng_with_several_interfaces_keeps_each_ones_type_time_and_name(
    tmp_path: Path,
) -> None:
    """Ethernet beside two CAN interfaces (nanosecond and microsecond clocks, named): the
    Ethernet packets are skipped, the CAN frames keep their times and their channel."""
    ng = dpkt.pcapng
    tsresol_ns = ng.PcapngOptionLE(code=ng.PCAPNG_OPT_IF_TSRESOL, data=b"\x09")
    end = ng.PcapngOptionLE(code=ng.PCAPNG_OPT_ENDOFOPT)

    def named(name: bytes, *extra: object) -> list[object]:
        return [ng.PcapngOptionLE(code=ng.PCAPNG_OPT_IF_NAME, data=name), *extra, end]

    interfaces = [
        ng.InterfaceDescriptionBlockLE(linktype=1, snaplen=1500, opts=named(b"eth0")),
        ng.InterfaceDescriptionBlockLE(
            linktype=LINKTYPE_CAN_SOCKETCAN, snaplen=72, opts=named(b"can0", tsresol_ns)
        ),
        ng.InterfaceDescriptionBlockLE(
            linktype=LINKTYPE_CAN_SOCKETCAN, snaplen=72, opts=named(b"can1")
        ),
    ]
    out = _Buffer()
    writer = ng.Writer(out, idb=interfaces)
    frame_a = frame_bytes(MESSAGES[0])
    frame_b = frame_bytes(MESSAGES[1])
    for iface, ticks, body in (
        (0, 5, b"\xff" * 60),  # an Ethernet frame
        (1, 1_700_000_000_123_456_789, frame_a),  # nanoseconds
        (2, 1_700_000_000_123_457, frame_b),  # microseconds (the default)
    ):
        block = ng.EnhancedPacketBlockLE(
            iface_id=iface,
            ts_high=ticks >> 32,
            ts_low=ticks & 0xFFFF_FFFF,
            caplen=len(body),
            pkt_len=len(body),
            pkt_data=body,
        )
        writer.writepkt(block)
    path = tmp_path / "mixed.pcapng"
    path.write_bytes(bytes(out.data))
    reader = PcapReader(path)
    got = list(reader)
    assert [(m.arbitration_id, m.channel) for m in got] == [(0x000, "can0"), (0x080, "can1")]
    assert got[0].timestamp == pytest.approx(1_700_000_000.123456789, abs=1e-6)
    assert got[1].timestamp == pytest.approx(1_700_000_000.123457, abs=1e-6)
    assert reader.skipped == 1 and reader.file.closed  # closed once read to the end
