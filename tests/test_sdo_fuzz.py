"""Random frames (0..8 data bytes) fed to the SDO server and client in every state.

Nothing may escape as an exception; every output is a well-formed SDO frame; every abort sent
comes with exactly one event and leaves the machine idle; and the first frame, whose meaning
in the state is known, gets the abort CiA 301 calls for (or none, when it is valid there).
"""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from cobus.proto import Frame, Out
from cobus.proto.sdo import (
    DownloadDone,
    SdoAbortCode,
    SdoAbortedError,
    SdoClient,
    SdoProtocolError,
    SdoServer,
    SdoTimeoutError,
    ServerAborted,
    ServerDownloaded,
    ServerUploaded,
    TransferFailed,
    UploadDone,
)
from tests.test_sdo_client import STATES as CLIENT_STATES
from tests.test_sdo_client import _in_state as client_in
from tests.test_sdo_helpers import RX, TX, make_server
from tests.test_sdo_server import SERVER_STATES
from tests.test_sdo_server import _server_in as server_in

ANY = -1  # the frame is valid here, or its outcome depends on more than the command byte
NONE = -2  # the frame must be ignored or taken without an abort


def frames_to(cob_id: int) -> st.SearchStrategy[Frame]:
    data = st.binary(max_size=8)
    return st.one_of(
        st.builds(lambda d: Frame(cob_id, d), data),
        st.builds(lambda d: Frame(cob_id, d), data),  # weighted: mostly on the channel
        st.builds(lambda d: Frame(cob_id + 1, d), data),
        st.just(Frame(cob_id, rtr=True, dlc=8)),
    )


def inputs(cob_id: int) -> st.SearchStrategy[list[Frame | float]]:
    """Frames to the machine, mixed with timer calls (a float: seconds since the last one)."""
    return st.lists(st.one_of(frames_to(cob_id), st.floats(0.0, 2.0)), min_size=1, max_size=8)


def _check_output(out: Out, cob_id: int) -> None:
    for frame in out.frames:
        assert frame.cob_id == cob_id and frame.dlc == 8 and not frame.rtr


# -- server ------------------------------------------------------------------------------------


def server_oracle(state: str, frame: Frame) -> int:
    """The abort code the server must send for ``frame`` in ``state`` (ANY / NONE)."""
    data = frame.data
    if frame.cob_id != RX or frame.rtr or not data:
        return NONE
    cmd = data[0]
    if state == "block download data":  # block size 127, segment 1 expected
        return SdoAbortCode.SEQUENCE_NUMBER if cmd & 0x7F == 0 and cmd != 0x80 else NONE
    if cmd == 0x80:
        return NONE
    ccs = cmd >> 5
    if ccs in (1, 2) or (ccs == 5 and cmd & 3 == 0) or (ccs == 6 and cmd & 1 == 0):
        return ANY  # an initiate: served or refused depending on its content
    if state == "download segment" and ccs == 0:
        return SdoAbortCode.TOGGLE_BIT if cmd & 0x10 else ANY
    if state == "upload segment" and ccs == 3:
        return SdoAbortCode.TOGGLE_BIT if cmd & 0x10 else NONE
    if state == "block upload start" and cmd & 0xE3 == 0xA3:
        return NONE
    if state == "block upload ack" and cmd & 0xE3 == 0xA2:
        if len(data) < 3:
            return SdoAbortCode.INVALID_COMMAND
        if data[1] > 43:  # the sub-block sent had 43 segments
            return SdoAbortCode.SEQUENCE_NUMBER
        return SdoAbortCode.BLOCK_SIZE if not 1 <= data[2] <= 127 else NONE
    if state == "block upload end" and cmd & 0xE3 == 0xA1:
        return NONE
    if state == "block download end" and cmd & 0xE1 == 0xC1:
        return ANY  # size and CRC decide
    return SdoAbortCode.INVALID_COMMAND


def _server_step(server: SdoServer, out: Out) -> None:
    _check_output(out, TX)
    aborts = [f for f in out.frames if f.data[0] == 0x80]
    own = [e for e in out.events if isinstance(e, ServerAborted) and not e.by_peer]
    assert len(aborts) == len(own) <= 1
    for frame, aborted in zip(aborts, own, strict=True):
        assert int.from_bytes(frame.data[4:], "little") == aborted.code
        assert frame.data[1:4] == bytes(
            (aborted.index & 0xFF, aborted.index >> 8, aborted.subindex)
        )
        assert not server.busy and server.deadline is None
    for event in out.events:
        assert isinstance(event, ServerAborted | ServerDownloaded | ServerUploaded)
    if server.busy:
        assert server.deadline is not None


@settings(max_examples=300, deadline=None)
@given(state=st.sampled_from(["idle", *SERVER_STATES]), feed=inputs(RX))
def test_server_survives_random_frames_and_aborts_correctly(
    state: str, feed: list[Frame | float]
) -> None:
    server = server_in(state) if state != "idle" else make_server({(0x2000, 0): bytes(300)})
    now = 0.0
    first = True
    for item in feed:
        if isinstance(item, float):
            now += item
            _server_step(server, server.on_timer(now))
            first = False
            continue
        out = server.on_frame(item, now)
        _server_step(server, out)
        if first:
            expected = server_oracle(state, item)
            sent = [int.from_bytes(f.data[4:], "little") for f in out.frames if f.data[0] == 0x80]
            if expected == NONE:
                assert sent == []
            elif expected != ANY:
                assert sent == [expected]
                if state == "idle":  # outside a transfer the abort names no object
                    assert out.frames[0].data[1:4] == bytes(3)
            first = False


# -- client ------------------------------------------------------------------------------------

VALID = {
    "upload initiate": lambda cmd: cmd & 0xE0 == 0x40,
    "upload segment": lambda cmd: cmd & 0xE0 == 0x00,
    "download initiate": lambda cmd: cmd & 0xE0 == 0x60,
    "download segment": lambda cmd: cmd & 0xE0 == 0x20,
    "block upload initiate": lambda cmd: cmd & 0xE0 == 0x40 or cmd & 0xE1 == 0xC0,
    "block upload end": lambda cmd: cmd & 0xE1 == 0xC1,
    "block download initiate": lambda cmd: cmd & 0xE3 == 0xA0,
    "block download ack": lambda cmd: cmd & 0xE3 == 0xA2,
    "block download end": lambda cmd: cmd & 0xE3 == 0xA1,
}


def client_oracle(state: str, frame: Frame) -> int:
    """The abort code the client must send for ``frame`` in ``state`` (ANY / NONE)."""
    data = frame.data
    if frame.cob_id != TX or frame.rtr or not data or data[0] == 0x80:
        return NONE
    cmd = data[0]
    if state == "block upload data":  # block size 127, segment 1 expected
        return SdoAbortCode.SEQUENCE_NUMBER if cmd & 0x7F == 0 else NONE
    if not VALID[state](cmd):
        if state.endswith("initiate") and cmd & 0xE0 not in (0x80, 0xE0):
            return NONE  # a reply of another service: stale, dropped
        return SdoAbortCode.INVALID_COMMAND
    if state in ("upload segment", "download segment") and cmd & 0x10:
        return SdoAbortCode.TOGGLE_BIT
    return ANY


def _client_step(client: SdoClient, out: Out, finished: list[object]) -> None:
    _check_output(out, RX)
    aborts = [f for f in out.frames if f.data[0] == 0x80]
    assert len(out.events) <= 1
    for event in out.events:
        assert isinstance(event, UploadDone | DownloadDone | TransferFailed)
        finished.append(event)
        assert not client.busy and client.deadline is None
    if aborts:
        (event,) = out.events
        assert isinstance(event, TransferFailed)
        assert isinstance(event.error, SdoProtocolError | SdoTimeoutError)
        code = int.from_bytes(aborts[0].data[4:], "little")
        if isinstance(event.error, SdoProtocolError):
            assert event.error.code == code
        else:
            assert code == SdoAbortCode.TIMEOUT
    elif out.events and isinstance(out.events[0], TransferFailed):
        assert isinstance(out.events[0].error, SdoAbortedError) and out.events[0].error.by_peer
    assert len(finished) <= 1, "one transfer, one completion event"
    if client.busy:
        assert client.deadline is not None


@settings(max_examples=300, deadline=None)
@given(state=st.sampled_from(CLIENT_STATES), feed=inputs(TX))
def test_client_survives_random_frames_and_aborts_correctly(
    state: str, feed: list[Frame | float]
) -> None:
    client = client_in(state)
    now = 0.0
    finished: list[object] = []
    first = True
    for item in feed:
        if isinstance(item, float):
            now += item
            _client_step(client, client.on_timer(now), finished)
            first = False
            continue
        out = client.on_frame(item, now)
        _client_step(client, out, finished)
        if first:
            expected = client_oracle(state, item)
            sent = [int.from_bytes(f.data[4:], "little") for f in out.frames if f.data[0] == 0x80]
            if expected == NONE:
                assert sent == []
            elif expected != ANY:
                assert sent == [expected]
            first = False
