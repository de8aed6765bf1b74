"""SDO block upload and download (CiA 301) frame by frame, on both sides."""

from __future__ import annotations

from binascii import crc_hqx

import pytest

from cobus.proto import NOTHING, Frame, Out
from cobus.proto.sdo import (
    DictBackend,
    DownloadDone,
    SdoAbortCode,
    SdoClient,
    SdoProtocolError,
    SdoServer,
    ServerAborted,
    ServerDownloaded,
    ServerUploaded,
    TransferFailed,
    UploadDone,
)
from tests.test_sdo_helpers import RX, TX, abort_frame, c2s, pair, s2c

IDX = 0x2000
LO, HI = 0x00, 0x20


def data_of(size: int) -> bytes:
    return bytes((i * 37 + 11) & 0xFF for i in range(size))


def segments(cob_id: int, data: bytes, first: int = 0, count: int = 127) -> tuple[Frame, ...]:
    """The block segments of ``data`` from segment ``first`` (0-based), sequence from 1."""
    out = []
    total = max(1, -(-len(data) // 7))
    for seq, n in enumerate(range(first, min(total, first + count)), start=1):
        chunk = data[7 * n : 7 * n + 7]
        last = 0x80 if n == total - 1 else 0
        out.append(Frame(cob_id, bytes((last | seq,)) + chunk + bytes(7 - len(chunk))))
    return tuple(out)


def end_byte(size: int) -> int:
    unused = (7 - size % 7) % 7 if size else 7
    return 0xC1 | unused << 2


def crc_bytes(data: bytes) -> tuple[int, int]:
    crc = crc_hqx(data, 0)
    return crc & 0xFF, crc >> 8


def protocol_abort(out: Out, cob_id: int, code: int) -> None:
    assert out.frames == (abort_frame(cob_id, IDX, 0, code),)
    if cob_id == RX:  # the client aborted
        (event,) = out.events
        assert isinstance(event, TransferFailed)
        assert isinstance(event.error, SdoProtocolError) and event.error.code == code
    else:
        assert out.events == (ServerAborted(IDX, 0, code, by_peer=False),)


# -- client: block upload ----------------------------------------------------------------------


@pytest.mark.parametrize("crc", [True, False])
@pytest.mark.parametrize("size", [0, 1, 7, 8, 20, 889, 890])
def test_client_block_upload(size: int, crc: bool) -> None:
    data = data_of(size)
    c = SdoClient(RX, TX, crc=crc)
    out = c.start_upload(IDX, 0, 0.0, block=True)
    assert out.frames == (c2s(0xA4 if crc else 0xA0, LO, HI, 0, 127, 0),)
    out = c.on_frame(s2c(0xC6, LO, HI, 0, *size.to_bytes(4, "little")), 0.1)
    assert out.frames == (c2s(0xA3),)
    for start in range(0, max(1, len(data)), 7 * 127):
        block = segments(TX, data, start // 7)
        for frame in block[:-1]:
            assert c.on_frame(frame, 0.2) is NOTHING
        out = c.on_frame(block[-1], 0.2)
        assert out.frames == (c2s(0xA2, len(block), 127),)
    out = c.on_frame(s2c(end_byte(size), *crc_bytes(data)), 0.3)
    assert out == Out((c2s(0xA1),), (UploadDone(IDX, 0, data),))
    assert not c.busy


def test_client_block_upload_without_size_and_without_server_crc() -> None:
    c = SdoClient(RX, TX)
    c.start_upload(IDX, 0, 0.0, block=True)
    c.on_frame(s2c(0xC0, LO, HI, 0), 0.1)  # sc = 0, s = 0
    c.on_frame(s2c(0x01, 1, 2, 3, 4, 5, 6, 7), 0.2)
    assert c.on_frame(s2c(0x82, 8, 9), 0.2).frames == (c2s(0xA2, 2, 127),)
    out = c.on_frame(s2c(0xC1 | 5 << 2, 0xDE, 0xAD), 0.3)  # CRC field ignored: not agreed
    assert out.events == (UploadDone(IDX, 0, bytes(range(1, 10))),)


def test_client_block_upload_accepts_short_segments() -> None:
    c = SdoClient(RX, TX)
    c.start_upload(IDX, 0, 0.0, block=True)
    c.on_frame(s2c(0xC6, LO, HI, 0, 2), 0.1)
    assert c.on_frame(Frame(TX, b"\x81\x05\x06"), 0.2).frames == (c2s(0xA2, 1, 127),)
    out = c.on_frame(s2c(0xC1 | 5 << 2, *crc_bytes(b"\x05\x06")), 0.3)
    assert out.events == (UploadDone(IDX, 0, b"\x05\x06"),)


@pytest.mark.parametrize("block_size", range(1, 128))
def test_client_proposes_each_block_size(block_size: int) -> None:
    data = data_of(7 * block_size + 3)  # one full sub-block and a short one
    c = SdoClient(RX, TX, block_size=block_size)
    assert c.start_upload(IDX, 0, 0.0, block=True).frames == (c2s(0xA4, LO, HI, 0, block_size, 0),)
    c.on_frame(s2c(0xC6, LO, HI, 0, *len(data).to_bytes(4, "little")), 0.0)
    segs = segments(TX, data, 0, block_size)
    for frame in segs[:-1]:
        assert c.on_frame(frame, 0.0) is NOTHING
    assert c.on_frame(segs[-1], 0.0).frames == (c2s(0xA2, block_size, block_size),)
    (last,) = segments(TX, data, block_size)
    assert c.on_frame(last, 0.0).frames == (c2s(0xA2, 1, block_size),)
    out = c.on_frame(s2c(end_byte(len(data)), *crc_bytes(data)), 0.0)
    assert out.events == (UploadDone(IDX, 0, data),)


def test_client_acknowledges_the_last_segment_in_sequence_after_a_loss() -> None:
    data = data_of(70)  # 10 segments
    c = SdoClient(RX, TX, block_size=5)
    c.start_upload(IDX, 0, 0.0, block=True)
    c.on_frame(s2c(0xC6, LO, HI, 0, 70), 0.0)
    first = segments(TX, data, 0, 5)
    c.on_frame(first[0], 0.1)
    c.on_frame(first[1], 0.1)
    # segment 3 is lost; 4 is dropped; 5 ends the sub-block
    assert c.on_frame(first[3], 0.2) is NOTHING
    assert c.deadline == pytest.approx(1.2)
    assert c.on_frame(first[4], 0.2).frames == (c2s(0xA2, 2, 5),)
    # the server resends from segment 3 (0-based 2), numbered from 1 again
    again = segments(TX, data, 2, 5)
    for frame in again[:-1]:
        assert c.on_frame(frame, 0.3) is NOTHING
    assert c.on_frame(again[-1], 0.3).frames == (c2s(0xA2, 5, 5),)
    rest = segments(TX, data, 7, 5)
    assert rest[0] == s2c(0x01, *data[49:56])
    c.on_frame(rest[0], 0.4)
    assert c.on_frame(rest[1], 0.4) is NOTHING  # a duplicate is harmless...
    c.on_frame(rest[1], 0.4)
    # ...and so is an old one, while the last segment ends the transfer
    assert c.on_frame(rest[0], 0.4) is NOTHING
    assert c.on_frame(rest[2], 0.4).frames == (c2s(0xA2, 3, 5),)
    out = c.on_frame(s2c(end_byte(70), *crc_bytes(data)), 0.5)
    assert out.events == (UploadDone(IDX, 0, data),)


def test_client_acknowledges_before_a_lost_segment_when_the_last_one_arrives() -> None:
    c = SdoClient(RX, TX)
    c.start_upload(IDX, 0, 0.0, block=True)
    c.on_frame(s2c(0xC6, LO, HI, 0, 10), 0.0)
    data = data_of(10)
    segs = segments(TX, data)
    assert c.on_frame(segs[1], 0.1).frames == (c2s(0xA2, 0, 127),)  # segment 1 lost
    again = segments(TX, data)
    c.on_frame(again[0], 0.2)
    assert c.on_frame(again[1], 0.2).frames == (c2s(0xA2, 2, 127),)


@pytest.mark.parametrize("seq", [0x00, 0x06, 0x86])
def test_client_refuses_sequence_numbers_outside_the_block(seq: int) -> None:
    c = SdoClient(RX, TX, block_size=5)
    c.start_upload(IDX, 0, 0.0, block=True)
    c.on_frame(s2c(0xC6, LO, HI, 0, 100), 0.0)
    protocol_abort(c.on_frame(s2c(seq, 1, 2, 3), 0.1), RX, SdoAbortCode.SEQUENCE_NUMBER)


def _client_at_block_upload_end(size: int, announced: int | None = None) -> SdoClient:
    c = SdoClient(RX, TX)
    c.start_upload(IDX, 0, 0.0, block=True)
    c.on_frame(s2c(0xC6, LO, HI, 0, announced if announced is not None else size), 0.0)
    for frame in segments(TX, data_of(size)):
        c.on_frame(frame, 0.1)
    return c


def test_client_refuses_more_segments_than_the_size_needs_at_once() -> None:
    c = SdoClient(RX, TX)
    c.start_upload(IDX, 0, 0.0, block=True)
    c.on_frame(s2c(0xC6, LO, HI, 0, 8), 0.0)  # two segments
    c.on_frame(s2c(0x01, *range(7)), 0.1)
    c.on_frame(s2c(0x02, *range(7)), 0.1)
    protocol_abort(c.on_frame(s2c(0x03, *range(7)), 0.1), RX, SdoAbortCode.LENGTH_TOO_HIGH)


def test_client_block_upload_crc_error_aborts_05040004() -> None:
    c = _client_at_block_upload_end(10)
    lo, hi = crc_bytes(data_of(10))
    out = c.on_frame(s2c(end_byte(10), lo ^ 1, hi), 0.2)
    protocol_abort(out, RX, SdoAbortCode.CRC)


@pytest.mark.parametrize(
    ("announced", "code"), [(9, SdoAbortCode.LENGTH_TOO_HIGH), (11, SdoAbortCode.LENGTH_TOO_LOW)]
)
def test_client_block_upload_size_mismatch(announced: int, code: int) -> None:
    c = _client_at_block_upload_end(10, announced)
    protocol_abort(c.on_frame(s2c(end_byte(10), *crc_bytes(data_of(10))), 0.2), RX, code)


def test_client_block_upload_end_without_its_crc_is_a_protocol_error() -> None:
    c = _client_at_block_upload_end(10)
    out = c.on_frame(Frame(TX, bytes((end_byte(10), 0x12))), 0.2)
    protocol_abort(out, RX, SdoAbortCode.INVALID_COMMAND)


def test_client_block_upload_response_without_its_size_is_a_protocol_error() -> None:
    c = SdoClient(RX, TX)
    c.start_upload(IDX, 0, 0.0, block=True)
    out = c.on_frame(Frame(TX, bytes((0xC6, LO, HI, 0, 9))), 0.1)
    protocol_abort(out, RX, SdoAbortCode.INVALID_COMMAND)


def test_protocol_switch_to_expedited() -> None:
    c = SdoClient(RX, TX, pst=4)
    assert c.start_upload(IDX, 0, 0.0, block=True).frames == (c2s(0xA4, LO, HI, 0, 127, 4),)
    out = c.on_frame(s2c(0x4B, LO, HI, 0, 0x34, 0x12), 0.1)
    assert out == Out((), (UploadDone(IDX, 0, b"\x34\x12"),))


def test_protocol_switch_to_segmented() -> None:
    c = SdoClient(RX, TX, pst=20)
    c.start_upload(IDX, 0, 0.0, block=True)
    assert c.on_frame(s2c(0x41, LO, HI, 0, 9), 0.1).frames == (c2s(0x60),)
    assert c.on_frame(s2c(0x00, *range(7)), 0.2).frames == (c2s(0x70),)
    out = c.on_frame(s2c(0x1B, 7, 8), 0.3)
    assert out.events == (UploadDone(IDX, 0, bytes(range(9))),)


# -- client: block download --------------------------------------------------------------------


@pytest.mark.parametrize("crc", [True, False])
@pytest.mark.parametrize("size", [0, 1, 6, 7, 8, 889, 890])
def test_client_block_download(size: int, crc: bool) -> None:
    data = data_of(size)
    c = SdoClient(RX, TX, crc=crc)
    out = c.start_download(IDX, 0, data, 0.0, block=True)
    cmd = 0xC6 if crc else 0xC2
    assert out.frames == (c2s(cmd, LO, HI, 0, *size.to_bytes(4, "little")),)
    out = c.on_frame(s2c(0xA4, LO, HI, 0, 127), 0.1)
    sent = 0
    while True:
        expected = segments(RX, data, sent)
        assert out.frames == expected
        sent += len(expected)
        out = c.on_frame(s2c(0xA2, len(expected), 127), 0.2)
        if sent * 7 >= size:
            break
    crc_lo, crc_hi = crc_bytes(data) if crc else (0, 0)
    assert out.frames == (c2s(end_byte(size), crc_lo, crc_hi),)
    assert c.on_frame(s2c(0xA1), 0.3) == Out((), (DownloadDone(IDX, 0),))


def test_client_block_download_without_server_crc_and_size() -> None:
    c = SdoClient(RX, TX)
    out = c.start_download(IDX, 0, b"abc", 0.0, block=True, size_indicated=False)
    assert out.frames == (c2s(0xC4, LO, HI, 0),)
    assert c.on_frame(s2c(0xA0, LO, HI, 0, 4), 0.1).frames == (c2s(0x81, *b"abc"),)
    assert c.on_frame(s2c(0xA2, 1, 4), 0.2).frames == (c2s(0xC1 | 4 << 2),)


@pytest.mark.parametrize("block_size", range(1, 128))
def test_client_follows_each_block_size_of_the_server(block_size: int) -> None:
    data = data_of(7 * block_size + 1)
    c = SdoClient(RX, TX)
    c.start_download(IDX, 0, data, 0.0, block=True)
    out = c.on_frame(s2c(0xA4, LO, HI, 0, block_size), 0.0)
    assert out.frames == segments(RX, data, 0, block_size)
    out = c.on_frame(s2c(0xA2, block_size, block_size), 0.0)
    assert out.frames == segments(RX, data, block_size, block_size)
    assert len(out.frames) == 1


def test_client_resends_from_the_acknowledged_segment() -> None:
    data = data_of(70)
    c = SdoClient(RX, TX)
    c.start_download(IDX, 0, data, 0.0, block=True)
    assert c.on_frame(s2c(0xA4, LO, HI, 0, 4), 0.1).frames == segments(RX, data, 0, 4)
    # the server got 1 and 2 only; it also shrinks the block size to 3
    assert c.on_frame(s2c(0xA2, 2, 3), 0.2).frames == segments(RX, data, 2, 3)
    assert c.on_frame(s2c(0xA2, 3, 3), 0.3).frames == segments(RX, data, 5, 3)
    out = c.on_frame(s2c(0xA2, 3, 3), 0.4)
    assert out.frames == segments(RX, data, 8, 3)  # segments 9 and 10, the last flagged
    assert out.frames[-1].data[0] == 0x82
    assert c.on_frame(s2c(0xA2, 0, 3), 0.5).frames == segments(RX, data, 8, 3)  # all lost
    out = c.on_frame(s2c(0xA2, 2, 3), 0.6)
    assert out.frames == (c2s(end_byte(70), *crc_bytes(data)),)


def test_client_block_download_errors() -> None:
    def started(response: Frame) -> Out:
        c = SdoClient(RX, TX)
        c.start_download(IDX, 0, data_of(30), 0.0, block=True)
        return c.on_frame(response, 0.1)

    protocol_abort(started(s2c(0xA4, LO, HI, 0, 0)), RX, SdoAbortCode.BLOCK_SIZE)
    protocol_abort(started(s2c(0xA4, LO, HI, 0, 128)), RX, SdoAbortCode.BLOCK_SIZE)
    protocol_abort(started(Frame(TX, bytes((0xA4, LO, HI, 0)))), RX, 0x05040001)

    def acked(ack: Frame) -> Out:
        c = SdoClient(RX, TX)
        c.start_download(IDX, 0, data_of(30), 0.0, block=True)
        c.on_frame(s2c(0xA4, LO, HI, 0, 3), 0.1)
        return c.on_frame(ack, 0.2)

    protocol_abort(acked(s2c(0xA2, 4, 3)), RX, SdoAbortCode.SEQUENCE_NUMBER)
    protocol_abort(acked(s2c(0xA2, 3, 0)), RX, SdoAbortCode.BLOCK_SIZE)
    protocol_abort(acked(s2c(0xA2, 3, 128)), RX, SdoAbortCode.BLOCK_SIZE)
    protocol_abort(acked(Frame(TX, b"\xa2\x03")), RX, SdoAbortCode.INVALID_COMMAND)


# -- server: block upload ----------------------------------------------------------------------


def server(value: bytes = b"", **kwargs: object) -> SdoServer:
    return SdoServer(RX, TX, DictBackend({(IDX, 0): value}), **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("client_crc", [True, False])
@pytest.mark.parametrize("server_crc", [True, False])
@pytest.mark.parametrize("size", [0, 5, 7, 889, 890])
def test_server_block_upload(size: int, client_crc: bool, server_crc: bool) -> None:
    data = data_of(size)
    s = server(data, crc=server_crc)
    out = s.on_frame(c2s(0xA4 if client_crc else 0xA0, LO, HI, 0, 127, 0), 0.0)
    cmd = 0xC6 if server_crc else 0xC2
    assert out.frames == (s2c(cmd, LO, HI, 0, *size.to_bytes(4, "little")),)
    out = s.on_frame(c2s(0xA3), 0.1)
    sent = 0
    while True:
        expected = segments(TX, data, sent)
        assert out.frames == expected
        sent += len(expected)
        out = s.on_frame(c2s(0xA2, len(expected), 127), 0.2)
        if sent * 7 >= size:
            break
    crc = crc_bytes(data) if client_crc and server_crc else (0, 0)
    assert out.frames == (s2c(end_byte(size), *crc),)
    assert s.on_frame(c2s(0xA1), 0.3) == Out((), (ServerUploaded(IDX, 0, size),))
    assert not s.busy


@pytest.mark.parametrize("block_size", range(1, 128))
def test_server_sends_sub_blocks_of_each_size(block_size: int) -> None:
    data = data_of(7 * block_size + 2)
    s = server(data)
    s.on_frame(c2s(0xA4, LO, HI, 0, block_size, 0), 0.0)
    assert s.on_frame(c2s(0xA3), 0.0).frames == segments(TX, data, 0, block_size)
    out = s.on_frame(c2s(0xA2, block_size, block_size), 0.0)
    assert out.frames == segments(TX, data, block_size, block_size)


def test_server_resends_from_the_acknowledged_segment() -> None:
    data = data_of(40)  # 6 segments
    s = server(data)
    s.on_frame(c2s(0xA4, LO, HI, 0, 4, 0), 0.0)
    assert s.on_frame(c2s(0xA3), 0.1).frames == segments(TX, data, 0, 4)
    assert s.on_frame(c2s(0xA2, 1, 4), 0.2).frames == segments(TX, data, 1, 4)
    out = s.on_frame(c2s(0xA2, 4, 2), 0.3)  # the client also shrinks its block size
    assert out.frames == segments(TX, data, 5, 2)
    assert s.on_frame(c2s(0xA2, 1, 2), 0.4).frames == (s2c(end_byte(40), *crc_bytes(data)),)


@pytest.mark.parametrize("pst", [4, 5, 200])
def test_server_switches_to_a_normal_upload_up_to_pst(pst: int) -> None:
    s = server(b"\x01\x02\x03\x04")
    out = s.on_frame(c2s(0xA4, LO, HI, 0, 127, pst), 0.0)
    assert out.frames == (s2c(0x43, LO, HI, 0, 1, 2, 3, 4),)
    s = server(bytes(range(10)))
    out = s.on_frame(c2s(0xA4, LO, HI, 0, 127, pst), 0.0)
    if pst >= 10:
        assert out.frames == (s2c(0x41, LO, HI, 0, 10),)
        assert s.on_frame(c2s(0x60), 0.1).frames == (s2c(0x00, *range(7)),)
    else:
        assert out.frames == (s2c(0xC6, LO, HI, 0, 10),)


def test_server_without_pst_does_not_switch_even_for_nothing() -> None:
    s = server(b"")
    assert s.on_frame(c2s(0xA4, LO, HI, 0, 127, 0), 0.0).frames == (s2c(0xC6, LO, HI, 0, 0),)
    assert s.on_frame(c2s(0xA3), 0.1).frames == (s2c(0x81),)


@pytest.mark.parametrize("block_size", [0, 128, 255])
def test_server_refuses_block_upload_sizes_outside_1_to_127(block_size: int) -> None:
    s = server(b"12345678")
    out = s.on_frame(c2s(0xA4, LO, HI, 0, block_size, 0), 0.0)
    protocol_abort(out, TX, SdoAbortCode.BLOCK_SIZE)


def test_server_block_upload_ack_errors() -> None:
    def acked(ack: Frame) -> Out:
        s = server(data_of(50))
        s.on_frame(c2s(0xA4, LO, HI, 0, 3, 0), 0.0)
        s.on_frame(c2s(0xA3), 0.0)
        return s.on_frame(ack, 0.1)

    protocol_abort(acked(c2s(0xA2, 4, 3)), TX, SdoAbortCode.SEQUENCE_NUMBER)
    protocol_abort(acked(c2s(0xA2, 3, 0)), TX, SdoAbortCode.BLOCK_SIZE)
    protocol_abort(acked(c2s(0xA2, 3, 128)), TX, SdoAbortCode.BLOCK_SIZE)
    protocol_abort(acked(Frame(RX, b"\xa2\x03")), TX, SdoAbortCode.INVALID_COMMAND)


# -- server: block download --------------------------------------------------------------------


def _download(s: SdoServer, data: bytes, *, crc: bool = True, block_size: int = 127) -> Out:
    """Initiate a block download of ``data`` and send all its segments; the last answer."""
    cmd = 0xC6 if crc else 0xC2
    out = s.on_frame(c2s(cmd, LO, HI, 0, *len(data).to_bytes(4, "little")), 0.0)
    assert out.frames == (s2c(0xA4 if s._crc else 0xA0, LO, HI, 0, block_size),)
    for frame in segments(RX, data, 0, block_size):  # one sub-block
        out = s.on_frame(frame, 0.1)
    return out


@pytest.mark.parametrize("client_crc", [True, False])
@pytest.mark.parametrize("server_crc", [True, False])
@pytest.mark.parametrize("size", [0, 1, 7, 8, 889, 890])
def test_server_block_download(size: int, client_crc: bool, server_crc: bool) -> None:
    data = data_of(size)
    backend = DictBackend({(IDX, 0): b""})
    s = SdoServer(RX, TX, backend, crc=server_crc)
    cmd = 0xC6 if client_crc else 0xC2
    out = s.on_frame(c2s(cmd, LO, HI, 0, *size.to_bytes(4, "little")), 0.0)
    assert out.frames == (s2c(0xA4 if server_crc else 0xA0, LO, HI, 0, 127),)
    for start in range(0, max(1, len(data)), 7 * 127):
        block = segments(RX, data, start // 7)
        for frame in block[:-1]:
            assert s.on_frame(frame, 0.1) is NOTHING
        assert s.on_frame(block[-1], 0.1).frames == (s2c(0xA2, len(block), 127),)
    crc = crc_bytes(data) if client_crc and server_crc else (0xBA, 0xD0)  # ignored when unused
    out = s.on_frame(c2s(end_byte(size), *crc), 0.2)
    assert out == Out((s2c(0xA1),), (ServerDownloaded(IDX, 0, size),))
    assert backend.entries[(IDX, 0)] == data


def test_server_block_download_without_size() -> None:
    backend = DictBackend({(IDX, 0): b""})
    s = SdoServer(RX, TX, backend)
    assert s.on_frame(c2s(0xC4, LO, HI, 0), 0.0).frames == (s2c(0xA4, LO, HI, 0, 127),)
    s.on_frame(c2s(0x01, *b"abcdefg"), 0.1)
    assert s.on_frame(c2s(0x82, *b"h"), 0.1).frames == (s2c(0xA2, 2, 127),)
    assert s.on_frame(c2s(0xC1 | 6 << 2, *crc_bytes(b"abcdefgh")), 0.2).frames == (s2c(0xA1),)
    assert backend.entries[(IDX, 0)] == b"abcdefgh"


def test_server_block_download_accepts_short_segments() -> None:
    backend = DictBackend({(IDX, 0): b""})
    s = SdoServer(RX, TX, backend)
    s.on_frame(c2s(0xC6, LO, HI, 0, 2), 0.0)
    assert s.on_frame(Frame(RX, b"\x81\x05\x06"), 0.1).frames == (s2c(0xA2, 1, 127),)
    s.on_frame(c2s(0xC1 | 5 << 2, *crc_bytes(b"\x05\x06")), 0.2)
    assert backend.entries[(IDX, 0)] == b"\x05\x06"


@pytest.mark.parametrize("block_size", range(1, 128))
def test_server_asks_for_each_block_size(block_size: int) -> None:
    data = data_of(7 * block_size + 4)
    s = server(block_size=block_size)
    s.on_frame(c2s(0xC6, LO, HI, 0, *len(data).to_bytes(4, "little")), 0.0)
    segs = segments(RX, data, 0, block_size)
    for frame in segs[:-1]:
        assert s.on_frame(frame, 0.0) is NOTHING
    assert s.on_frame(segs[-1], 0.0).frames == (s2c(0xA2, block_size, block_size),)
    (last,) = segments(RX, data, block_size, block_size)
    assert s.on_frame(last, 0.0).frames == (s2c(0xA2, 1, block_size),)
    out = s.on_frame(c2s(end_byte(len(data)), *crc_bytes(data)), 0.0)
    assert out.events == (ServerDownloaded(IDX, 0, len(data)),)


def test_server_acknowledges_the_last_segment_in_sequence_after_a_loss() -> None:
    data = data_of(50)  # 8 segments
    backend = DictBackend({(IDX, 0): b""})
    s = SdoServer(RX, TX, backend, block_size=4)
    s.on_frame(c2s(0xC6, LO, HI, 0, 50), 0.0)
    first = segments(RX, data, 0, 4)
    s.on_frame(first[0], 0.1)
    assert s.on_frame(first[2], 0.1) is NOTHING  # segment 2 lost, 3 dropped
    assert s.deadline == pytest.approx(1.1)
    assert s.on_frame(first[3], 0.1).frames == (s2c(0xA2, 1, 4),)
    again = segments(RX, data, 1, 4)
    for frame in again[:-1]:
        s.on_frame(frame, 0.2)
    assert s.on_frame(again[-1], 0.2).frames == (s2c(0xA2, 4, 4),)
    rest = segments(RX, data, 5, 4)  # 3 segments, the last flagged
    s.on_frame(rest[0], 0.3)
    assert s.on_frame(rest[2], 0.3).frames == (s2c(0xA2, 1, 4),)  # 2 lost, last arrived
    final = segments(RX, data, 6, 4)
    s.on_frame(final[0], 0.4)
    s.on_frame(final[0], 0.4)  # a duplicate is dropped
    assert s.on_frame(final[1], 0.4).frames == (s2c(0xA2, 2, 4),)
    out = s.on_frame(c2s(end_byte(50), *crc_bytes(data)), 0.5)
    assert out.events == (ServerDownloaded(IDX, 0, 50),)
    assert backend.entries[(IDX, 0)] == data


@pytest.mark.parametrize("seq", [0x00, 0x05, 0x85, 0xFF])
def test_server_refuses_sequence_numbers_outside_the_block(seq: int) -> None:
    s = server(block_size=4)
    s.on_frame(c2s(0xC6, LO, HI, 0, 50), 0.0)
    protocol_abort(s.on_frame(c2s(seq, 1, 2), 0.1), TX, SdoAbortCode.SEQUENCE_NUMBER)


def test_server_refuses_more_segments_than_the_size_needs() -> None:
    s = server()
    s.on_frame(c2s(0xC6, LO, HI, 0, 8), 0.0)  # two segments
    s.on_frame(c2s(0x01, *range(7)), 0.1)
    s.on_frame(c2s(0x02, *range(7)), 0.1)
    protocol_abort(s.on_frame(c2s(0x03, *range(7)), 0.1), TX, SdoAbortCode.LENGTH_TOO_HIGH)


@pytest.mark.parametrize(
    ("unused", "code"), [(4, SdoAbortCode.LENGTH_TOO_HIGH), (6, SdoAbortCode.LENGTH_TOO_LOW)]
)
def test_server_block_download_end_with_wrong_size(unused: int, code: int) -> None:
    s = server()
    _download(s, data_of(9))  # 9 bytes: the last segment has 5 unused
    protocol_abort(s.on_frame(c2s(0xC1 | unused << 2, *crc_bytes(data_of(9))), 0.2), TX, code)


def test_server_block_download_crc_error_aborts_05040004() -> None:
    s = server()
    _download(s, data_of(30))
    lo, hi = crc_bytes(data_of(30))
    out = s.on_frame(c2s(end_byte(30), lo, hi ^ 0x80), 0.2)
    protocol_abort(out, TX, SdoAbortCode.CRC)


def test_server_block_download_end_without_its_crc_aborts_05040001() -> None:
    s = server()
    _download(s, data_of(30))
    out = s.on_frame(Frame(RX, bytes((end_byte(30), 0x00))), 0.2)
    protocol_abort(out, TX, SdoAbortCode.INVALID_COMMAND)


def test_server_block_download_refused_by_the_back_end_at_the_end() -> None:
    s = SdoServer(RX, TX, DictBackend({(IDX, 0): b""}), crc=False)
    _download(s, data_of(3))
    s._backend.read_only.add((IDX, 0))  # type: ignore[attr-defined]
    out = s.on_frame(c2s(end_byte(3)), 0.2)
    protocol_abort(out, TX, SdoAbortCode.WRITE_READ_ONLY)


# -- both sides together -----------------------------------------------------------------------


@pytest.mark.parametrize("upload", [True, False])
def test_lost_segments_are_recovered_end_to_end(upload: bool) -> None:
    data = data_of(2000)
    backend = DictBackend({(IDX, 0): data if upload else b""})
    s = SdoServer(RX, TX, backend, block_size=16)
    c = SdoClient(RX, TX, block_size=16)
    lost = {3, 17, 40}  # every 3rd, 17th and 40th segment of a batch, once
    dropped: list[int] = []

    def drop(frame: Frame, position: int, size: int) -> bool:
        # Only segments that do not end their sub-block can be lost and recovered.
        if size > 1 and position < size - 1 and frame.data[0] & 0x7F in lost and len(dropped) < 8:
            dropped.append(position)
            return True
        return False

    start = c.start_upload(IDX, 0, 0.0, block=True) if upload else None
    if start is None:
        start = c.start_download(IDX, 0, data, 0.0, block=True)
    events = pair(c, s, start, drop=drop)
    assert dropped
    if upload:
        assert UploadDone(IDX, 0, data) in events
    else:
        assert DownloadDone(IDX, 0) in events
        assert backend.entries[(IDX, 0)] == data
