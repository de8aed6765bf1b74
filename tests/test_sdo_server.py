"""The SDO server frame by frame: expedited and segmented transfers, refusals, timeouts."""

from __future__ import annotations

import pytest

from cobus.proto import NOTHING, Frame, Out
from cobus.proto.sdo import (
    DictBackend,
    SdoAbort,
    SdoAbortCode,
    SdoParameterError,
    SdoServer,
    ServerAborted,
    ServerDownloaded,
    ServerUploaded,
)
from tests.test_sdo_helpers import RX, TX, abort_frame, c2s, make_server, s2c

IDX = 0x2000
LO, HI = 0x00, 0x20


def assert_abort(server: SdoServer, out: Out, code: int, index: int = IDX, sub: int = 0) -> None:
    """``out`` is the server aborting with ``code`` on ``index:sub`` and going idle."""
    assert out.frames == (abort_frame(TX, index, sub, code),)
    assert out.events == (ServerAborted(index, sub, code, by_peer=False),)
    assert not server.busy and server.deadline is None


# -- expedited ---------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [1, 2, 3, 4])
def test_expedited_upload_of_each_size(size: int) -> None:
    value = bytes(range(0xA1, 0xA1 + size))
    s = make_server({(IDX, 1): value})
    out = s.on_frame(c2s(0x40, LO, HI, 1), 0.0)
    cmd = {1: 0x4F, 2: 0x4B, 3: 0x47, 4: 0x43}[size]
    assert out == Out((s2c(cmd, LO, HI, 1, *value),), (ServerUploaded(IDX, 1, size),))
    assert not s.busy


@pytest.mark.parametrize("size", [1, 2, 3, 4])
def test_expedited_download_of_each_size(size: int) -> None:
    s = make_server({(IDX, 1): b""})
    value = bytes(range(1, size + 1))
    cmd = {1: 0x2F, 2: 0x2B, 3: 0x27, 4: 0x23}[size]
    out = s.on_frame(c2s(cmd, LO, HI, 1, *value, *([0xEE] * (4 - size))), 0.0)
    assert out == Out((s2c(0x60, LO, HI, 1),), (ServerDownloaded(IDX, 1, size),))
    assert s._backend.entries[(IDX, 1)] == value  # type: ignore[attr-defined]


def test_expedited_download_without_size_stores_four_bytes() -> None:
    backend = DictBackend({(IDX, 0): b""})
    s = SdoServer(RX, TX, backend)
    out = s.on_frame(c2s(0x22, LO, HI, 0, 0x63), 0.0)
    assert out.events == (ServerDownloaded(IDX, 0, 4),)
    assert backend.entries[(IDX, 0)] == b"\x63\x00\x00\x00"


def test_short_requests_are_served_when_complete() -> None:
    # Seen in the EC motor vectors: requests with DLC 4 and 6 (CiA 301 wants 8).
    backend = DictBackend({(0x2023, 1): b"\x67\x45\x23\x01", (0x2042, 0): b"", (0x2045, 1): b""})
    s = SdoServer(0x603, 0x583, backend)
    out = s.on_frame(Frame(0x603, bytes((0x40, 0x23, 0x20, 0x01))), 0.0)
    assert out.frames == (Frame(0x583, bytes((0x43, 0x23, 0x20, 0x01, 0x67, 0x45, 0x23, 0x01))),)
    out = s.on_frame(Frame(0x603, bytes((0x22, 0x42, 0x20, 0x00, 0x05, 0x00))), 0.0)
    assert out.events == (ServerDownloaded(0x2042, 0, 2),)
    assert backend.entries[(0x2042, 0)] == b"\x05\x00"
    out = s.on_frame(Frame(0x603, bytes((0x22, 0x45, 0x20, 0x01))), 0.0)
    assert out.events == (ServerDownloaded(0x2045, 1, 0),)
    out = s.on_frame(Frame(0x603, bytes((0x2B, 0x42, 0x20, 0x00, 0x07, 0x00))), 0.0)
    assert out.events == (ServerDownloaded(0x2042, 0, 2),)


@pytest.mark.parametrize(
    "data",
    [
        (0x40, LO, HI),  # upload without its sub-index
        (0x2B, LO, HI, 0, 0x07),  # two bytes indicated, one present
        (0x21, LO, HI, 0, 0x10, 0x00),  # segmented download without all size bytes
        (0xC6, LO, HI, 0, 0x10),  # block download without all size bytes
        (0xA4, LO, HI, 0, 0x7F),  # block upload without pst
        (0x20,),  # download initiate with nothing
    ],
)
def test_requests_missing_bytes_they_need_abort_05040001(data: tuple[int, ...]) -> None:
    s = make_server({(IDX, 0): bytes(20)})
    out = s.on_frame(Frame(RX, bytes(data)), 0.0)
    index = data[1] | data[2] << 8 if len(data) >= 3 else 0
    sub = data[3] if len(data) >= 4 else 0
    assert_abort(s, out, SdoAbortCode.INVALID_COMMAND, index, sub)


# -- refusals by the back end -----------------------------------------------------------------


ENTRIES = {(0x1000, 0): b"\x91\x01\x00\x00", (IDX, 0): b"\x01", (IDX, 1): b"\x02"}


@pytest.mark.parametrize(
    ("request_", "code"),
    [
        (c2s(0x40, 0x00, 0x30, 0), SdoAbortCode.NO_OBJECT),
        (c2s(0x40, LO, HI, 7), SdoAbortCode.NO_SUBINDEX),
        (c2s(0x40, LO, HI, 1), SdoAbortCode.READ_WRITE_ONLY),
        (c2s(0x2F, 0x00, 0x10, 0, 1), SdoAbortCode.WRITE_READ_ONLY),
        (c2s(0x2F, 0x00, 0x30, 0, 1), SdoAbortCode.NO_OBJECT),
        (c2s(0x21, 0x00, 0x10, 0, 9), SdoAbortCode.WRITE_READ_ONLY),  # refused at initiate
        (c2s(0xC6, 0x00, 0x10, 0, 9), SdoAbortCode.WRITE_READ_ONLY),
        (c2s(0xA4, 0x00, 0x30, 0, 127), SdoAbortCode.NO_OBJECT),
        (c2s(0xA4, LO, HI, 1, 127), SdoAbortCode.READ_WRITE_ONLY),
    ],
)
def test_back_end_refusals_become_aborts(request_: Frame, code: int) -> None:
    backend = DictBackend(ENTRIES, read_only=[(0x1000, 0)], write_only=[(IDX, 1)])
    s = SdoServer(RX, TX, backend)
    out = s.on_frame(request_, 0.0)
    data = request_.data
    assert_abort(s, out, code, data[1] | data[2] << 8, data[3])


class SizedBackend(DictBackend):
    """A back end whose entry 2000h:00 must have exactly 8 bytes."""

    def size_hint(self, index: int, subindex: int) -> int | None:
        super().size_hint(index, subindex)
        return 8


@pytest.mark.parametrize(
    ("size", "code"), [(9, SdoAbortCode.LENGTH_TOO_HIGH), (7, SdoAbortCode.LENGTH_TOO_LOW)]
)
@pytest.mark.parametrize("block", [False, True])
def test_size_hint_refuses_a_wrong_size_at_initiate(size: int, code: int, block: bool) -> None:
    s = SdoServer(RX, TX, SizedBackend({(IDX, 0): bytes(8)}))
    out = s.on_frame(c2s(0xC6 if block else 0x21, LO, HI, 0, size), 0.0)
    assert_abort(s, out, code)


def test_size_hint_accepts_the_right_size_and_unindicated_sizes() -> None:
    s = SdoServer(RX, TX, SizedBackend({(IDX, 0): bytes(8)}))
    assert s.on_frame(c2s(0x21, LO, HI, 0, 8), 0.0).frames == (s2c(0x60, LO, HI, 0),)
    s = SdoServer(RX, TX, SizedBackend({(IDX, 0): bytes(8)}))
    assert s.on_frame(c2s(0x20, LO, HI, 0), 0.0).frames == (s2c(0x60, LO, HI, 0),)


class RefusingStore(DictBackend):
    def download(self, index: int, subindex: int, data: bytes) -> None:
        raise SdoAbort(SdoAbortCode.VALUE_TOO_HIGH, "above 100 %")


def test_refusal_of_the_complete_value_aborts_instead_of_the_last_answer() -> None:
    s = SdoServer(RX, TX, RefusingStore({(IDX, 0): b""}))
    assert_abort(s, s.on_frame(c2s(0x2F, LO, HI, 0, 200), 0.0), SdoAbortCode.VALUE_TOO_HIGH)
    s.on_frame(c2s(0x21, LO, HI, 0, 2), 0.0)
    out = s.on_frame(c2s(0x0B, 1, 2), 0.1)
    assert_abort(s, out, SdoAbortCode.VALUE_TOO_HIGH)


class Broken:
    def upload(self, index: int, subindex: int) -> bytes:
        raise RuntimeError("disk on fire")

    def download(self, index: int, subindex: int, data: bytes) -> None:
        raise RuntimeError("disk on fire")


def test_other_back_end_exceptions_escape() -> None:
    s = SdoServer(RX, TX, Broken())
    with pytest.raises(RuntimeError, match="disk on fire"):
        s.on_frame(c2s(0x40, LO, HI, 0), 0.0)


def test_dict_backend_refuses_to_create_entries() -> None:
    backend = DictBackend()
    with pytest.raises(SdoAbort) as info:
        backend.download(1, 2, b"x")
    assert info.value.code is SdoAbortCode.NO_OBJECT
    assert backend.entries == {}


# -- segmented download ------------------------------------------------------------------------


def test_segmented_download_of_nothing() -> None:
    s = make_server({(IDX, 0): b"old"})
    assert s.on_frame(c2s(0x21, LO, HI, 0, 0), 0.0).frames == (s2c(0x60, LO, HI, 0),)
    assert s.busy and s.deadline == 1.0
    out = s.on_frame(c2s(0x0F), 0.1)
    assert out == Out((s2c(0x20),), (ServerDownloaded(IDX, 0, 0),))
    assert s._backend.entries[(IDX, 0)] == b""  # type: ignore[attr-defined]


def test_segmented_download_of_fourteen_bytes_without_size() -> None:
    s = make_server({(IDX, 0): b""})
    data = bytes(range(1, 15))
    assert s.on_frame(c2s(0x20, LO, HI, 0), 0.0).frames == (s2c(0x60, LO, HI, 0),)
    assert s.on_frame(c2s(0x00, *data[:7]), 0.1).frames == (s2c(0x20),)
    out = s.on_frame(c2s(0x11, *data[7:]), 0.2)
    assert out == Out((s2c(0x30),), (ServerDownloaded(IDX, 0, 14),))


def test_download_segment_with_wrong_toggle_aborts_05030000() -> None:
    s = make_server({(IDX, 0): b""})
    s.on_frame(c2s(0x21, LO, HI, 0, 20), 0.0)
    assert_abort(s, s.on_frame(c2s(0x10, *range(7)), 0.1), SdoAbortCode.TOGGLE_BIT)


def test_download_longer_than_indicated_aborts_06070012_at_once() -> None:
    s = make_server({(IDX, 0): b""})
    s.on_frame(c2s(0x21, LO, HI, 0, 5), 0.0)
    assert_abort(s, s.on_frame(c2s(0x00, *range(7)), 0.1), SdoAbortCode.LENGTH_TOO_HIGH)


def test_download_shorter_than_indicated_aborts_06070013() -> None:
    s = make_server({(IDX, 0): b""})
    s.on_frame(c2s(0x21, LO, HI, 0, 9), 0.0)
    assert_abort(s, s.on_frame(c2s(0x05, 1, 2, 3, 4, 5), 0.1), SdoAbortCode.LENGTH_TOO_LOW)


def test_download_segment_missing_bytes_its_n_promises_aborts_05040001() -> None:
    s = make_server({(IDX, 0): b""})
    s.on_frame(c2s(0x21, LO, HI, 0, 9), 0.0)
    out = s.on_frame(Frame(RX, bytes((0x00, 1, 2))), 0.1)
    assert_abort(s, out, SdoAbortCode.INVALID_COMMAND)


# -- segmented upload --------------------------------------------------------------------------


def test_segmented_upload_of_nothing_is_one_empty_segment() -> None:
    s = make_server({(IDX, 0): b""})
    assert s.on_frame(c2s(0x40, LO, HI, 0), 0.0).frames == (s2c(0x41, LO, HI, 0, 0),)
    out = s.on_frame(c2s(0x60), 0.1)
    assert out == Out((s2c(0x0F),), (ServerUploaded(IDX, 0, 0),))


@pytest.mark.parametrize("size", [5, 7, 8, 14, 15])
def test_segmented_upload_sizes(size: int) -> None:
    value = bytes(range(1, size + 1))
    s = make_server({(IDX, 0): value})
    assert s.on_frame(c2s(0x40, LO, HI, 0), 0.0).frames == (s2c(0x41, LO, HI, 0, size),)
    toggle = 0
    for pos in range(0, size, 7):
        chunk = value[pos : pos + 7]
        out = s.on_frame(c2s(0x60 | toggle), 0.1)
        last = pos + 7 >= size
        cmd = toggle | (7 - len(chunk)) << 1 | (1 if last else 0)
        assert out.frames == (s2c(cmd, *chunk),)
        assert out.events == ((ServerUploaded(IDX, 0, size),) if last else ())
        toggle ^= 0x10
    assert not s.busy


def test_upload_segment_request_with_wrong_toggle_aborts_05030000() -> None:
    s = make_server({(IDX, 0): bytes(20)})
    s.on_frame(c2s(0x40, LO, HI, 0), 0.0)
    s.on_frame(c2s(0x60), 0.1)
    assert_abort(s, s.on_frame(c2s(0x60), 0.2), SdoAbortCode.TOGGLE_BIT)


# -- malformed and out-of-place requests -------------------------------------------------------


@pytest.mark.parametrize("cmd", [0x00, 0x10, 0x60, 0x70, 0x81, 0xA1, 0xA2, 0xA3, 0xC1, 0xE0, 0xFF])
def test_requests_outside_a_transfer_abort_05040001_on_object_zero(cmd: int) -> None:
    s = make_server({(IDX, 0): b""})
    out = s.on_frame(c2s(cmd, LO, HI, 0), 0.0)
    assert_abort(s, out, SdoAbortCode.INVALID_COMMAND, 0, 0)


def _server_in(state: str) -> SdoServer:
    s = make_server({(IDX, 0): bytes(300)})
    if state == "download segment":
        s.on_frame(c2s(0x21, LO, HI, 0, 20), 0.0)
    elif state == "upload segment":
        s.on_frame(c2s(0x40, LO, HI, 0), 0.0)
    elif state == "block download data":
        s.on_frame(c2s(0xC6, LO, HI, 0, 20), 0.0)
    elif state == "block download end":
        s.on_frame(c2s(0xC6, LO, HI, 0, 5), 0.0)
        s.on_frame(c2s(0x81, 1, 2, 3, 4, 5), 0.0)
    elif state == "block upload start":
        s.on_frame(c2s(0xA4, LO, HI, 0, 127), 0.0)
    elif state == "block upload ack":
        s.on_frame(c2s(0xA4, LO, HI, 0, 127), 0.0)
        s.on_frame(c2s(0xA3), 0.0)
    elif state == "block upload end":
        s.on_frame(c2s(0xA4, LO, HI, 0, 127), 0.0)
        s.on_frame(c2s(0xA3), 0.0)
        s.on_frame(c2s(0xA2, 43, 127), 0.0)
    assert s.busy
    return s


SERVER_STATES = [
    "download segment",
    "upload segment",
    "block download data",
    "block download end",
    "block upload start",
    "block upload ack",
    "block upload end",
]

# For each state, a request that is valid somewhere in SDO but not there.
OUT_OF_PLACE = {
    "download segment": c2s(0x60),
    "upload segment": c2s(0x00, 1),
    "block download end": c2s(0xA2, 1, 1),
    "block upload start": c2s(0xA2, 1, 1),
    "block upload ack": c2s(0xA3),
    "block upload end": c2s(0xA3),
}


@pytest.mark.parametrize("state", sorted(OUT_OF_PLACE))
def test_out_of_place_request_aborts_05040001(state: str) -> None:
    s = _server_in(state)
    assert_abort(s, s.on_frame(OUT_OF_PLACE[state], 0.5), SdoAbortCode.INVALID_COMMAND)


@pytest.mark.parametrize("state", SERVER_STATES)
def test_abort_from_the_client_cancels_silently(state: str) -> None:
    s = _server_in(state)
    out = s.on_frame(abort_frame(RX, IDX, 0, 0x05040000), 0.5)
    assert out == Out((), (ServerAborted(IDX, 0, SdoAbortCode.TIMEOUT, by_peer=True),))
    assert not s.busy and s.deadline is None


def test_abort_outside_a_transfer_is_ignored() -> None:
    s = make_server()
    assert s.on_frame(abort_frame(RX, IDX, 0, 0x05040000), 0.0) is NOTHING
    assert s.on_frame(Frame(RX, b"\x80"), 0.0) is NOTHING


def test_short_abort_from_the_client_reads_missing_code_bytes_as_zero() -> None:
    s = _server_in("upload segment")
    out = s.on_frame(Frame(RX, b"\x80\x00\x20"), 0.5)
    assert out.events == (ServerAborted(IDX, 0, 0, by_peer=True),)


@pytest.mark.parametrize("state", [s for s in SERVER_STATES if s != "block download data"])
def test_new_initiate_supersedes_the_running_transfer(state: str) -> None:
    s = _server_in(state)
    s._backend.entries[(0x1000, 0)] = b"\x91\x01\x00\x00"  # type: ignore[attr-defined]
    out = s.on_frame(c2s(0x40, 0x00, 0x10, 0), 0.5)
    assert out.frames == (s2c(0x43, 0x00, 0x10, 0, 0x91, 0x01),)
    assert out.events == (
        ServerAborted(IDX, 0, SdoAbortCode.GENERAL_ERROR, by_peer=True),
        ServerUploaded(0x1000, 0, 4),
    )
    assert not s.busy


def test_initiate_during_block_download_data_is_a_segment() -> None:
    s = _server_in("block download data")  # block size 127: 40h is segment 64, out of sequence
    assert s.on_frame(c2s(0x40, 0x00, 0x10, 0), 0.5) is NOTHING
    s = SdoServer(RX, TX, DictBackend({(IDX, 0): b""}), block_size=10)
    s.on_frame(c2s(0xC6, LO, HI, 0, 20), 0.0)
    assert_abort(s, s.on_frame(c2s(0x40, 0x00, 0x10, 0), 0.5), SdoAbortCode.SEQUENCE_NUMBER)


# -- timeouts ----------------------------------------------------------------------------------


@pytest.mark.parametrize("state", SERVER_STATES)
def test_stalled_transfer_times_out_with_05040000(state: str) -> None:
    s = _server_in(state)
    assert s.deadline == 1.0
    assert s.on_timer(0.5) is NOTHING
    assert_abort(s, s.on_timer(1.0), SdoAbortCode.TIMEOUT)
    assert s.on_timer(9.0) is NOTHING


def test_each_request_restarts_the_timeout() -> None:
    s = make_server({(IDX, 0): bytes(30)}, timeout=0.25)
    s.on_frame(c2s(0x40, LO, HI, 0), 3.0)
    assert s.deadline == 3.25
    s.timeout = 0.5
    assert s.timeout == 0.5
    s.on_frame(c2s(0x60), 3.2)
    assert s.deadline == pytest.approx(3.7)


def test_idle_server_has_no_deadline() -> None:
    s = make_server({(IDX, 0): b"\x01"})
    assert s.deadline is None and s.on_timer(100.0) is NOTHING
    s.on_frame(c2s(0x40, LO, HI, 0), 0.0)  # expedited: nothing to wait for
    assert s.deadline is None


# -- what the server ignores, and its arguments ------------------------------------------------


def test_frames_that_are_not_requests_are_ignored() -> None:
    s = make_server({(IDX, 0): b"\x01"})
    assert s.on_frame(Frame(0x606, c2s(0x40, LO, HI, 0).data), 0.0) is NOTHING
    assert s.on_frame(Frame(RX, rtr=True, dlc=8), 0.0) is NOTHING
    assert s.on_frame(Frame(RX, b""), 0.0) is NOTHING


def test_extended_cob_ids_and_properties() -> None:
    s = SdoServer(0x1000605, 0x1000585, DictBackend({(IDX, 0): b"\x01"}))
    assert (s.rx_cob_id, s.tx_cob_id, s.node) == (0x1000605, 0x1000585, None)
    out = s.on_frame(Frame(0x1000605, c2s(0x40, LO, HI, 0).data, extended=True), 0.0)
    assert out.frames[0].extended and out.frames[0].cob_id == 0x1000585
    assert make_server().node == 5


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"timeout": 0.0}, "positive"), ({"block_size": 0}, "1..127"), ({"block_size": 200}, "1..")],
)
def test_settings_are_checked(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(SdoParameterError, match=match):
        SdoServer(RX, TX, DictBackend(), **kwargs)  # type: ignore[arg-type]
    with pytest.raises(SdoParameterError, match="tx_cob_id"):
        SdoServer(RX, 0x40000000, DictBackend())
    with pytest.raises(SdoParameterError, match="rx_cob_id"):
        SdoServer(-5, TX, DictBackend())
    with pytest.raises(SdoParameterError):
        make_server().timeout = 0


class _OneByte(DictBackend):
    """An object of a fixed size: one byte."""

    def size_hint(self, index: int, subindex: int) -> int | None:
        super().size_hint(index, subindex)
        return 1


@pytest.mark.parametrize("block", [False, True], ids=["segmented", "block"])
def test_a_download_without_size_stops_at_the_object_size_not_at_the_end(block: bool) -> None:
    """A hostile client sending 100 000 segments without a size indication into a 1-byte
    object is refused at the first segment that overflows it (it used to be buffered whole)."""
    s = SdoServer(RX, TX, _OneByte({(IDX, 0): b""}))
    if block:
        out = s.on_frame(c2s(0xC0, LO, HI, 0), 0.0)  # block download, no size
        assert out.frames[0].data[0] == 0xA4
        # block segments are whole: the first (7 bytes) may still end in the object
        assert s.on_frame(Frame(RX, bytes((1, 1, 2, 3, 4, 5, 6, 7))), 0.0) == NOTHING
        out = s.on_frame(Frame(RX, bytes((2, 1, 2, 3, 4, 5, 6, 7))), 0.0)
    else:
        s.on_frame(c2s(0x20, LO, HI, 0), 0.0)  # segmented, no size
        out = s.on_frame(c2s(0x00, 1, 2, 3, 4, 5, 6, 7), 0.0)
    assert_abort(s, out, SdoAbortCode.LENGTH_TOO_HIGH)


def test_a_domain_without_size_is_capped_by_max_download() -> None:
    s = SdoServer(RX, TX, DictBackend({(IDX, 0): b""}), max_download=20)
    s.on_frame(c2s(0x20, LO, HI, 0), 0.0)
    toggle = 0
    for _ in range(2):  # 14 bytes: taken
        assert s.on_frame(c2s(toggle, *range(7)), 0.0).frames[0].data[0] == 0x20 | toggle
        toggle ^= 0x10
    out = s.on_frame(c2s(toggle, *range(7)), 0.0)  # 21 bytes: one too many
    assert_abort(s, out, SdoAbortCode.LENGTH_TOO_HIGH)


@pytest.mark.parametrize("block", [False, True])
def test_an_announced_size_above_the_limit_is_refused_before_any_data(block: bool) -> None:
    """0xFFFFFFFF announced into a domain used to be buffered for as long as data came."""
    s = SdoServer(RX, TX, DictBackend({(IDX, 0): b""}), max_download=20)
    command = 0xC6 if block else 0x21  # (block: CRC and size; segmented: size)
    out = s.on_frame(c2s(command, LO, HI, 0, 0xFF, 0xFF, 0xFF, 0xFF), 0.0)
    assert_abort(s, out, SdoAbortCode.OUT_OF_MEMORY)
    assert s.on_frame(c2s(0x21, LO, HI, 0, 20, 0, 0, 0), 0.0).frames[0].data[0] == 0x60


class _Limited(DictBackend):
    def download_limit(self, index: int, subindex: int) -> int | None:
        return 8 if index == IDX else None


def test_a_back_end_sets_the_limit_per_object() -> None:
    s = SdoServer(RX, TX, _Limited({(IDX, 0): b"", (IDX + 1, 0): b""}), max_download=20)
    assert_abort(s, s.on_frame(c2s(0x21, LO, HI, 0, 9, 0, 0, 0), 0.0), SdoAbortCode.OUT_OF_MEMORY)
    s.on_frame(c2s(0x20, LO, HI, 0), 0.0)  # no size: capped at 8 bytes as they come
    s.on_frame(c2s(0x00, *range(7)), 0.0)
    assert_abort(s, s.on_frame(c2s(0x10, *range(7)), 0.0), SdoAbortCode.LENGTH_TOO_HIGH)
    other = bytes((0x21, (IDX + 1) & 0xFF, (IDX + 1) >> 8, 0, 20, 0, 0, 0))
    assert s.on_frame(Frame(RX, other), 0.0).frames[0].data[0] == 0x60  # the server's 20
