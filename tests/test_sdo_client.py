"""The SDO client frame by frame: expedited and segmented transfers, aborts, timeouts."""

from __future__ import annotations

import pytest

from cobus.errors import CobusError
from cobus.proto import NOTHING, Frame, Out
from cobus.proto.sdo import (
    DownloadDone,
    SdoAbortCode,
    SdoAbortedError,
    SdoBusyError,
    SdoClient,
    SdoParameterError,
    SdoProtocolError,
    SdoTimeoutError,
    TransferFailed,
    UploadDone,
)
from tests.test_sdo_helpers import RX, TX, abort_frame, c2s, running, s2c

IDX = 0x2000
LO, HI = 0x00, 0x20


def client(**kwargs: object) -> SdoClient:
    return SdoClient(RX, TX, **kwargs)  # type: ignore[arg-type]


def failed(out: Out) -> TransferFailed:
    assert len(out.events) == 1
    event = out.events[0]
    assert isinstance(event, TransferFailed)
    return event


def assert_protocol_abort(c: SdoClient, out: Out, code: int, sub: int = 0) -> SdoProtocolError:
    """``out`` is the client aborting with ``code``: abort frame, failure event, idle."""
    assert out.frames == (abort_frame(RX, IDX, sub, code),)
    event = failed(out)
    assert (event.index, event.subindex) == (IDX, sub)
    assert isinstance(event.error, SdoProtocolError)
    assert event.error.code == code
    assert not c.busy and c.deadline is None
    return event.error


# -- expedited ---------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [1, 2, 3, 4])
def test_expedited_upload_of_each_size(size: int) -> None:
    c = client()
    out = c.start_upload(IDX, 1, 0.0)
    assert out == Out((c2s(0x40, LO, HI, 1),))
    assert running(c) and c.deadline == 1.0
    cmd = {1: 0x4F, 2: 0x4B, 3: 0x47, 4: 0x43}[size]
    value = bytes(range(0xA1, 0xA1 + size))
    reply = s2c(cmd, LO, HI, 1, *value, *([0xEE] * (4 - size)))  # padding must be dropped
    out = c.on_frame(reply, 0.5)
    assert out == Out((), (UploadDone(IDX, 1, value),))
    assert not c.busy and c.deadline is None


def test_expedited_upload_without_size_gives_all_four_bytes() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    out = c.on_frame(s2c(0x42, LO, HI, 0, 1, 2, 3, 4), 0.1)
    assert out.events == (UploadDone(IDX, 0, b"\x01\x02\x03\x04"),)


def test_short_expedited_upload_without_size_gives_the_bytes_present() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    out = c.on_frame(Frame(TX, bytes((0x42, LO, HI, 0, 0x34, 0x12))), 0.1)
    assert out.events == (UploadDone(IDX, 0, b"\x34\x12"),)


def test_short_expedited_upload_with_size_keeps_the_data_it_needs() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    out = c.on_frame(Frame(TX, bytes((0x4B, LO, HI, 0, 0x34, 0x12))), 0.1)
    assert out.events == (UploadDone(IDX, 0, b"\x34\x12"),)


def test_expedited_upload_missing_its_data_bytes_is_a_protocol_error() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    out = c.on_frame(Frame(TX, bytes((0x4B, LO, HI, 0, 0x34))), 0.1)
    error = assert_protocol_abort(c, out, SdoAbortCode.INVALID_COMMAND)
    assert "too short" in str(error)


@pytest.mark.parametrize("size", [1, 2, 3, 4])
def test_expedited_download_of_each_size(size: int) -> None:
    c = client()
    value = bytes(range(1, size + 1))
    out = c.start_download(IDX, 2, value, 0.0)
    cmd = {1: 0x2F, 2: 0x2B, 3: 0x27, 4: 0x23}[size]
    assert out.frames == (c2s(cmd, LO, HI, 2, *value),)
    out = c.on_frame(s2c(0x60, LO, HI, 2), 0.2)
    assert out == Out((), (DownloadDone(IDX, 2),))
    assert not c.busy


def test_expedited_download_without_size_indication_uses_22h() -> None:
    c = client()
    out = c.start_download(IDX, 0, b"\x63", 0.0, size_indicated=False)
    assert out.frames == (c2s(0x22, LO, HI, 0, 0x63),)
    assert c.on_frame(s2c(0x60, LO, HI, 0), 0.1).events == (DownloadDone(IDX, 0),)


def test_download_response_of_four_bytes_is_accepted() -> None:
    # The EC motor dialect answers downloads with a 4-byte frame: its meaning is complete.
    c = client()
    c.start_download(IDX, 0, b"\x34\x12", 0.0)
    out = c.on_frame(Frame(TX, bytes((0x60, LO, HI, 0))), 0.1)
    assert out.events == (DownloadDone(IDX, 0),)


def test_download_response_without_its_index_is_a_protocol_error() -> None:
    c = client()
    c.start_download(IDX, 0, b"\x34\x12", 0.0)
    out = c.on_frame(Frame(TX, bytes((0x60, LO, HI))), 0.1)
    assert_protocol_abort(c, out, SdoAbortCode.INVALID_COMMAND)


def test_small_download_goes_segmented_when_asked() -> None:
    c = client()
    out = c.start_download(IDX, 0, b"\x01\x02", 0.0, expedited=False)
    assert out.frames == (c2s(0x21, LO, HI, 0, 2),)
    out = c.on_frame(s2c(0x60, LO, HI, 0), 0.1)
    assert out.frames == (c2s(0x0B, 1, 2),)
    assert c.on_frame(s2c(0x20), 0.2).events == (DownloadDone(IDX, 0),)


# -- segmented download ------------------------------------------------------------------------


def test_segmented_download_of_nothing_sends_one_empty_last_segment() -> None:
    c = client()
    assert c.start_download(IDX, 0, b"", 0.0).frames == (c2s(0x21, LO, HI, 0, 0),)
    assert c.on_frame(s2c(0x60, LO, HI, 0), 0.1).frames == (c2s(0x0F),)
    assert c.on_frame(s2c(0x20), 0.2).events == (DownloadDone(IDX, 0),)


def test_segmented_download_of_exactly_seven_bytes() -> None:
    c = client()
    data = bytes(range(1, 8))
    assert c.start_download(IDX, 0, data, 0.0).frames == (c2s(0x21, LO, HI, 0, 7),)
    assert c.on_frame(s2c(0x60, LO, HI, 0), 0.1).frames == (c2s(0x01, *data),)
    assert c.on_frame(s2c(0x20), 0.2).events == (DownloadDone(IDX, 0),)


def test_segmented_download_of_exactly_fourteen_bytes_toggles() -> None:
    c = client()
    data = bytes(range(1, 15))
    assert c.start_download(IDX, 0, data, 0.0).frames == (c2s(0x21, LO, HI, 0, 14),)
    assert c.on_frame(s2c(0x60, LO, HI, 0), 0.1).frames == (c2s(0x00, *data[:7]),)
    assert c.on_frame(s2c(0x20), 0.2).frames == (c2s(0x11, *data[7:]),)
    assert c.on_frame(s2c(0x30), 0.3).events == (DownloadDone(IDX, 0),)


def test_segmented_download_without_size_indication() -> None:
    c = client()
    data = bytes(range(1, 10))
    assert c.start_download(IDX, 0, data, 0.0, size_indicated=False).frames == (
        c2s(0x20, LO, HI, 0),
    )
    assert c.on_frame(s2c(0x60, LO, HI, 0), 0.1).frames == (c2s(0x00, *data[:7]),)
    assert c.on_frame(s2c(0x20), 0.2).frames == (c2s(0x1B, 8, 9),)
    assert c.on_frame(s2c(0x30), 0.3).events == (DownloadDone(IDX, 0),)


def test_download_segment_response_with_wrong_toggle_aborts_05030000() -> None:
    c = client()
    c.start_download(IDX, 0, bytes(10), 0.0)
    c.on_frame(s2c(0x60, LO, HI, 0), 0.1)
    out = c.on_frame(s2c(0x30), 0.2)
    error = assert_protocol_abort(c, out, SdoAbortCode.TOGGLE_BIT)
    assert "toggle bit 1, expected 0" in str(error)


# -- segmented upload --------------------------------------------------------------------------


def test_segmented_upload_of_nothing() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    assert c.on_frame(s2c(0x41, LO, HI, 0, 0), 0.1).frames == (c2s(0x60),)
    assert c.on_frame(s2c(0x0F), 0.2).events == (UploadDone(IDX, 0, b""),)


def test_segmented_upload_of_seven_and_fourteen_bytes() -> None:
    data = bytes(range(0x31, 0x3F))
    c = client()
    c.start_upload(IDX, 0, 0.0)
    assert c.on_frame(s2c(0x41, LO, HI, 0, 7), 0.1).frames == (c2s(0x60),)
    assert c.on_frame(s2c(0x01, *data[:7]), 0.2).events == (UploadDone(IDX, 0, data[:7]),)
    c.start_upload(IDX, 0, 1.0)
    assert c.on_frame(s2c(0x41, LO, HI, 0, 14), 1.1).frames == (c2s(0x60),)
    assert c.on_frame(s2c(0x00, *data[:7]), 1.2).frames == (c2s(0x70),)
    assert c.on_frame(s2c(0x11, *data[7:]), 1.3).events == (UploadDone(IDX, 0, data),)


def test_segmented_upload_without_size_takes_what_comes() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    assert c.on_frame(s2c(0x40, LO, HI, 0), 0.1).frames == (c2s(0x60),)
    assert c.on_frame(s2c(0x00, 1, 2, 3, 4, 5, 6, 7), 0.2).frames == (c2s(0x70),)
    out = c.on_frame(s2c(0x1D, 8), 0.3)  # n = 6, c = 1
    assert out.events == (UploadDone(IDX, 0, bytes(range(1, 9))),)


def test_upload_segment_with_wrong_toggle_aborts_05030000() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    c.on_frame(s2c(0x41, LO, HI, 0, 20), 0.1)
    out = c.on_frame(s2c(0x10, 1, 2, 3, 4, 5, 6, 7), 0.2)
    assert_protocol_abort(c, out, SdoAbortCode.TOGGLE_BIT)


def test_upload_longer_than_announced_aborts_06070012() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    c.on_frame(s2c(0x41, LO, HI, 0, 5), 0.1)
    out = c.on_frame(s2c(0x00, 1, 2, 3, 4, 5, 6, 7), 0.2)
    error = assert_protocol_abort(c, out, SdoAbortCode.LENGTH_TOO_HIGH)
    assert "more than the 5 bytes" in str(error)


def test_upload_shorter_than_announced_aborts_06070013() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    c.on_frame(s2c(0x41, LO, HI, 0, 9), 0.1)
    out = c.on_frame(s2c(0x03, 1, 2, 3, 4, 5, 6), 0.2)  # n = 1, last: 6 of 9 bytes
    assert_protocol_abort(c, out, SdoAbortCode.LENGTH_TOO_LOW)


def test_upload_segment_shorter_than_its_n_says_is_a_protocol_error() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    c.on_frame(s2c(0x41, LO, HI, 0, 9), 0.1)
    out = c.on_frame(Frame(TX, bytes((0x00, 1, 2, 3))), 0.2)
    assert_protocol_abort(c, out, SdoAbortCode.INVALID_COMMAND)


def test_segmented_upload_response_without_its_size_bytes_is_a_protocol_error() -> None:
    c = client()
    c.start_upload(IDX, 0, 0.0)
    out = c.on_frame(Frame(TX, bytes((0x41, LO, HI, 0, 9))), 0.1)
    assert_protocol_abort(c, out, SdoAbortCode.INVALID_COMMAND)


# -- unexpected answers ------------------------------------------------------------------------


def _in_state(state: str) -> SdoClient:
    """A client in one of its waiting states (block states are reached in test_sdo_block)."""
    c = client()
    if state == "upload initiate":
        c.start_upload(IDX, 0, 0.0)
    elif state == "upload segment":
        c.start_upload(IDX, 0, 0.0)
        c.on_frame(s2c(0x41, LO, HI, 0, 20), 0.0)
    elif state == "download initiate":
        c.start_download(IDX, 0, bytes(20), 0.0)
    elif state == "download segment":
        c.start_download(IDX, 0, bytes(20), 0.0)
        c.on_frame(s2c(0x60, LO, HI, 0), 0.0)
    elif state == "block upload initiate":
        c.start_upload(IDX, 0, 0.0, block=True)
    elif state == "block upload data":
        c.start_upload(IDX, 0, 0.0, block=True)
        c.on_frame(s2c(0xC6, LO, HI, 0, 20), 0.0)
    elif state == "block upload end":
        c.start_upload(IDX, 0, 0.0, block=True)
        c.on_frame(s2c(0xC6, LO, HI, 0, 3), 0.0)
        c.on_frame(s2c(0x81, 1, 2, 3), 0.0)
    elif state == "block download initiate":
        c.start_download(IDX, 0, bytes(20), 0.0, block=True)
    elif state == "block download ack":
        c.start_download(IDX, 0, bytes(20), 0.0, block=True)
        c.on_frame(s2c(0xA4, LO, HI, 0, 127), 0.0)
    elif state == "block download end":
        c.start_download(IDX, 0, bytes(20), 0.0, block=True)
        c.on_frame(s2c(0xA4, LO, HI, 0, 127), 0.0)
        c.on_frame(s2c(0xA2, 3, 127), 0.0)
    assert c.busy
    return c


STATES = [
    "upload initiate",
    "upload segment",
    "download initiate",
    "download segment",
    "block upload initiate",
    "block upload data",
    "block upload end",
    "block download initiate",
    "block download ack",
    "block download end",
]

# For each waiting state, an answer that is valid somewhere in SDO but not there.
WRONG = {
    "upload segment": s2c(0x20),
    "download segment": s2c(0x00, 1),
    "block upload end": s2c(0xA2, 1, 1),
    "block download ack": s2c(0x60, LO, HI, 0),
    "block download end": s2c(0xA2, 1, 1),
}
INITIATING = [
    "upload initiate",
    "download initiate",
    "block upload initiate",
    "block download initiate",
]


@pytest.mark.parametrize("state", sorted(WRONG))
def test_unexpected_command_aborts_05040001(state: str) -> None:
    c = _in_state(state)
    out = c.on_frame(WRONG[state], 0.5)
    error = assert_protocol_abort(c, out, SdoAbortCode.INVALID_COMMAND)
    assert f"{WRONG[state].data[0]:02X}h" in str(error)


@pytest.mark.parametrize("state", INITIATING)
def test_a_command_no_server_sends_aborts_05040001_while_initiating(state: str) -> None:
    c = _in_state(state)
    error = assert_protocol_abort(c, c.on_frame(s2c(0xE0, LO, HI, 0), 0.5), 0x05040001)
    assert "E0h" in str(error)


# A reply of another service, for another object, or an abort naming another object: what a
# server answering late (or a second client's server) sends while an initiate is pending.
STALE = [
    s2c(0x60, 0x17, 0x10, 0),  # download response, 1017h
    s2c(0x60, LO, HI, 0),  # download response, the same object
    s2c(0x43, 0x00, 0x10, 0, 0x91, 1, 0, 0),  # upload response, 1000h
    s2c(0x4F, LO, HI, 9, 1),  # upload response, another sub-index
    s2c(0x20),  # download segment response
    s2c(0x00, 1, 2, 3),  # upload segment
    s2c(0xA2, 1, 1),  # block acknowledge
    s2c(0xC6, 0x18, 0x10, 1, 4),  # block upload response, 1018h
    abort_frame(TX, 0x1017, 0, 0x05040000),  # an abort of an earlier transfer
]


@pytest.mark.parametrize("state", INITIATING)
def test_stale_replies_are_dropped_while_initiating_and_the_answer_is_taken(state: str) -> None:
    c = _in_state(state)
    answers = {
        "upload initiate": s2c(0x4F, LO, HI, 0, 7),
        "download initiate": s2c(0x60, LO, HI, 0),
        "block upload initiate": s2c(0x4F, LO, HI, 0, 7),  # (a protocol switch)
        "block download initiate": s2c(0xA4, LO, HI, 0, 127),
    }
    stale = [f for f in STALE if not (state == "download initiate" and f == answers[state])]
    for n, frame in enumerate(stale, 1):
        assert c.on_frame(frame, 0.1 * n) is NOTHING, frame
        assert c.busy and c.deadline == 1.0  # (still waiting for the answer in time)
    dropped = c.stale_replies
    assert dropped == len(stale)
    out = c.on_frame(answers[state], 0.95)
    assert out.events or out.frames  # the real answer goes on with the transfer
    assert not any(isinstance(e, TransferFailed) for e in out.events)
    assert c.stale_replies == dropped


def test_a_timeout_after_stale_replies_says_what_was_dropped() -> None:
    c = _in_state("upload initiate")
    c.on_frame(s2c(0x60, 0x17, 0x10, 0), 0.5)
    error = failed(c.on_timer(1.0)).error
    assert isinstance(error, SdoTimeoutError)
    assert error.stale is not None
    assert "1 stale reply dropped, the last command 60h for 0x1017:00" in str(error)
    c.start_upload(IDX, 0, 2.0)  # the count is per transfer
    error = failed(c.on_timer(3.0)).error
    assert isinstance(error, SdoTimeoutError) and error.stale is None
    assert c.stale_replies == 1


def test_initiate_response_shorter_than_its_index_is_a_protocol_error() -> None:
    c = _in_state("upload initiate")
    out = c.on_frame(Frame(TX, bytes((0x4F, LO))), 0.5)
    assert_protocol_abort(c, out, SdoAbortCode.INVALID_COMMAND)


# -- aborts ------------------------------------------------------------------------------------


@pytest.mark.parametrize("state", STATES)
def test_abort_from_the_server_ends_the_transfer_in_every_state(state: str) -> None:
    c = _in_state(state)
    out = c.on_frame(abort_frame(TX, IDX, 0, 0x06020000), 0.5)
    assert out.frames == ()
    error = failed(out).error
    assert isinstance(error, SdoAbortedError)
    assert error.code is SdoAbortCode.NO_OBJECT
    assert error.by_peer and (error.index, error.subindex, error.node) == (IDX, 0, 5)
    assert str(error).startswith(
        "SDO abort 0x06020000 on 0x2000:00 (node 5): object does not exist in the object dictionary"
    )
    assert not c.busy and c.deadline is None


def test_abort_naming_another_object_still_ends_the_transfer() -> None:
    c = _in_state("upload initiate")
    out = c.on_frame(abort_frame(TX, 0, 0, 0x08000000), 0.5)
    assert isinstance(failed(out).error, SdoAbortedError)


def test_short_abort_frame_reads_missing_code_bytes_as_zero() -> None:
    c = _in_state("upload initiate")
    out = c.on_frame(Frame(TX, bytes((0x80, LO, HI, 0, 0x22, 0x00))), 0.5)
    error = failed(out).error
    assert isinstance(error, SdoAbortedError)
    assert error.code == 0x22
    assert "manufacturer-specific or unknown" in str(error)


def test_manufacturer_abort_code_is_kept_as_int() -> None:
    c = _in_state("upload initiate")
    out = c.on_frame(abort_frame(TX, IDX, 0, 0x06020011), 0.5)
    error = failed(out).error
    assert isinstance(error, SdoAbortedError)
    assert error.code == 0x06020011 and not isinstance(error.code, SdoAbortCode)


@pytest.mark.parametrize("block_upload", [True, False])
def test_server_without_block_support_is_reported_as_its_abort(block_upload: bool) -> None:
    c = _in_state("block upload initiate" if block_upload else "block download initiate")
    out = c.on_frame(abort_frame(TX, IDX, 0, 0x05040001), 0.5)
    error = failed(out).error
    assert isinstance(error, SdoAbortedError)
    assert error.code is SdoAbortCode.INVALID_COMMAND
    assert "retry without block" in str(error)


def test_command_specifier_abort_outside_block_has_no_block_hint() -> None:
    c = _in_state("upload initiate")
    error = failed(c.on_frame(abort_frame(TX, IDX, 0, 0x05040001), 0.5)).error
    assert "block" not in str(error)


@pytest.mark.parametrize("state", STATES)
def test_abort_on_request_in_every_state(state: str) -> None:
    c = _in_state(state)
    out = c.abort(SdoAbortCode.GENERAL_ERROR, 0.5)
    assert out.frames == (abort_frame(RX, IDX, 0, 0x08000000),)
    error = failed(out).error
    assert isinstance(error, SdoAbortedError)
    assert not error.by_peer
    assert "sent by this side" in str(error)
    assert not c.busy


def test_abort_when_idle_does_nothing() -> None:
    assert client().abort(0x08000000, 0.0) is NOTHING


def test_abort_code_must_fit_32_bits() -> None:
    with pytest.raises(SdoParameterError, match="32 bits"):
        _in_state("upload initiate").abort(1 << 32, 0.0)


# -- timeouts ----------------------------------------------------------------------------------


@pytest.mark.parametrize("state", STATES)
def test_timeout_in_every_state_sends_05040000(state: str) -> None:
    c = _in_state(state)
    deadline = c.deadline
    assert deadline == 1.0
    assert c.on_timer(0.999) is NOTHING
    assert running(c)
    out = c.on_timer(1.0)
    assert out.frames == (abort_frame(RX, IDX, 0, 0x05040000),)
    error = failed(out).error
    assert isinstance(error, SdoTimeoutError)
    assert (error.index, error.subindex, error.timeout) == (IDX, 0, 1.0)
    assert "no answer within 1 s" in str(error) and "node 5" in str(error)
    assert not c.busy and c.deadline is None
    assert c.on_timer(5.0) is NOTHING


def test_every_answer_restarts_the_timeout() -> None:
    c = client(timeout=0.5)
    c.start_upload(IDX, 0, 10.0)
    assert c.deadline == 10.5
    c.on_frame(s2c(0x41, LO, HI, 0, 20), 10.4)
    assert c.deadline == pytest.approx(10.9)
    c.timeout = 2.0
    c.on_frame(s2c(0x00, 1, 2, 3, 4, 5, 6, 7), 10.8)
    assert c.deadline == pytest.approx(12.8)
    assert c.timeout == 2.0


# -- what the client ignores, and its arguments --------------------------------------------------


def test_frames_that_are_not_answers_are_ignored() -> None:
    c = _in_state("upload initiate")
    assert c.on_frame(Frame(0x586, bytes(8)), 0.1) is NOTHING
    assert c.on_frame(Frame(TX, rtr=True, dlc=8), 0.1) is NOTHING
    assert c.on_frame(Frame(TX, b""), 0.1) is NOTHING
    assert c.busy
    idle = client()
    assert idle.on_frame(s2c(0x43, LO, HI, 0), 0.1) is NOTHING
    assert idle.on_frame(abort_frame(TX, IDX, 0, 0x05040000), 0.1) is NOTHING


def test_one_transfer_at_a_time() -> None:
    c = _in_state("upload initiate")
    with pytest.raises(SdoBusyError, match="busy with the upload of 0x2000:00"):
        c.start_upload(0x1000, 0, 0.0)
    d = _in_state("download segment")
    with pytest.raises(SdoBusyError, match="busy with the download") as info:
        d.start_download(0x1000, 0, b"x", 0.0)
    assert isinstance(info.value, CobusError)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"timeout": 0}, "positive"),
        ({"block_size": 0}, "1..127"),
        ({"block_size": 128}, "1..127"),
        ({"pst": 256}, "byte"),
    ],
)
def test_settings_are_checked(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(SdoParameterError, match=match):
        client(**kwargs)


def test_cob_ids_are_checked() -> None:
    with pytest.raises(SdoParameterError, match="rx_cob_id"):
        SdoClient(0x20000000, TX)
    with pytest.raises(SdoParameterError, match="tx_cob_id"):
        SdoClient(RX, -1)


def test_timeout_setter_is_checked() -> None:
    with pytest.raises(SdoParameterError):
        client().timeout = -1.0


@pytest.mark.parametrize(("index", "subindex"), [(0x10000, 0), (-1, 0), (0x2000, 256)])
def test_object_address_is_checked(index: int, subindex: int) -> None:
    c = client()
    with pytest.raises(SdoParameterError, match="bits"):
        c.start_upload(index, subindex, 0.0)
    with pytest.raises(SdoParameterError, match="bits"):
        c.start_download(index, subindex, b"1", 0.0)
    assert not c.busy


def test_extended_cob_ids_and_unknown_node() -> None:
    c = SdoClient(0x1234567, 0x1234568)
    assert (c.rx_cob_id, c.tx_cob_id) == (0x1234567, 0x1234568)
    out = c.start_upload(IDX, 0, 0.0)
    assert out.frames[0].extended and out.frames[0].cob_id == 0x1234567
    error = failed(c.on_timer(1.0)).error
    assert error.node is None and c.node is None
    assert "(SDO 0x1234567/0x1234568)" in str(error)


def test_node_can_be_named() -> None:
    c = SdoClient(0x640, 0x5C0, node=64)
    assert c.node == 64 and client().node == 5
    c.start_upload(IDX, 0, 0.0)
    assert "node 64" in str(failed(c.on_timer(2.0)).error)


def test_an_abort_naming_another_sub_index_of_the_object_still_ends_the_transfer() -> None:
    c = _in_state("upload initiate")
    error = failed(c.on_frame(abort_frame(TX, IDX, 7, 0x06090011), 0.5)).error
    assert isinstance(error, SdoAbortedError) and error.code == 0x06090011
