"""An SDO server built with ``reports=False`` (what a device builds: nobody reads its events)
answers frame for frame, deadline for deadline, as one that reports, and builds no event.

Two servers over equal back ends are fed the same inputs: every kind of transfer run by our
client (with refusals, and frames lost on the way), and random sequences of valid and broken
requests mixed with timer calls, from idle and from every state a transfer passes through.
"""

from __future__ import annotations

from hypothesis import example, given, settings
from hypothesis import strategies as st

from cobus.proto import Frame, Out
from cobus.proto.sdo import DictBackend, SdoClient, SdoServer, ServerUploaded
from tests.test_sdo_fuzz import frames_to
from tests.test_sdo_helpers import RX, TX, c2s, make_server, pair
from tests.test_sdo_server import HI, IDX, LO, SERVER_STATES
from tests.test_sdo_server import _server_in as server_in

ENTRIES = {(IDX, 0): bytes(range(40)) * 3, (IDX, 1): b"\x11\x22", (IDX, 2): b""}


def _assert_reset(server: SdoServer) -> None:
    assert server.deadline is None and server._limit is None
    assert server._data == b"" and server._buf == bytearray()
    assert (server._index, server._subindex) == (-1, -1)


class Twins:
    """Both servers behind one machine's face: each input goes to both, their outputs and
    states are compared, and the reporting one's output is returned."""

    def __init__(self, loud: SdoServer, quiet: SdoServer) -> None:
        assert loud.reports and not quiet.reports
        self.loud, self.quiet = loud, quiet
        self.events = 0

    def _same(self, loud: Out, quiet: Out) -> Out:
        assert quiet.frames == loud.frames
        assert quiet.events == ()
        assert self.quiet.busy == self.loud.busy
        assert self.quiet.deadline == self.loud.deadline
        assert self.quiet.progress == self.loud.progress
        for server in (self.loud, self.quiet):
            if not server.busy:  # idle as a full reset leaves it (expedited transfers skip it)
                _assert_reset(server)
        self.events += len(loud.events)
        return loud

    def on_frame(self, frame: Frame, now: float) -> Out:
        return self._same(self.loud.on_frame(frame, now), self.quiet.on_frame(frame, now))

    def on_timer(self, now: float) -> Out:
        return self._same(self.loud.on_timer(now), self.quiet.on_timer(now))


def _twins(**kwargs: object) -> tuple[Twins, DictBackend, DictBackend]:
    loud = make_server(dict(ENTRIES), **kwargs)
    quiet = make_server(dict(ENTRIES), reports=False, **kwargs)
    twins = Twins(loud, quiet)
    return twins, loud._backend, quiet._backend  # type: ignore[return-value]


def test_reports_by_default_and_says_so() -> None:
    server = make_server(dict(ENTRIES))
    assert server.reports
    out = server.on_frame(c2s(0x40, LO, HI, 1), 0.0)
    assert out.events == (ServerUploaded(IDX, 1, 2),)
    quiet = make_server(dict(ENTRIES), reports=False)
    assert quiet.on_frame(c2s(0x40, LO, HI, 1), 0.0) == Out(out.frames)


_values = st.binary(max_size=300)


@settings(max_examples=150, deadline=None)
@given(
    value=_values,
    upload=st.booleans(),
    block=st.booleans(),
    expedited=st.booleans(),
    refused=st.booleans(),
    crc=st.booleans(),
    lost=st.integers(-1, 12),
)
def test_whole_transfers_answer_the_same(
    value: bytes, upload: bool, block: bool, expedited: bool, refused: bool, crc: bool, lost: int
) -> None:
    twins, loud_backend, quiet_backend = _twins(crc=crc, block_size=5)
    for backend in (loud_backend, quiet_backend):
        backend.entries[(IDX, 1)] = value
        if refused:
            backend.read_only.add((IDX, 1))
            backend.write_only.add((IDX, 1))
    client = SdoClient(RX, TX, block_size=7, pst=2)
    if upload:
        out = client.start_upload(IDX, 1, 0.0, block=block)
    else:
        out = client.start_download(IDX, 1, value, 0.0, block=block, expedited=expedited)
    seen = [0]

    def drop(frame: Frame, position: int, size: int) -> bool:
        seen[0] += 1
        return seen[0] == lost  # one frame lost on the way (-1: none)

    pair(client, twins, out, drop=drop)  # type: ignore[arg-type]
    twins.on_timer(10.0)  # a transfer a lost frame stalled times out alike
    assert quiet_backend.entries == loud_backend.entries
    assert twins.events >= 1 or lost == 1  # the loud one reported (unless it heard nothing)


_requests = st.sampled_from(
    [
        c2s(0x40, LO, HI, 0),  # upload, segmented
        c2s(0x40, LO, HI, 1),  # upload, expedited
        c2s(0x40, LO, HI, 9),  # no such sub-index
        c2s(0x60),  # upload segment, toggle 0
        c2s(0x70),  # upload segment, toggle 1
        c2s(0x23, LO, HI, 2, 1, 2, 3, 4),  # expedited download
        c2s(0x21, LO, HI, 2, 10),  # segmented download of 10 bytes
        c2s(0x00, 1, 2, 3, 4, 5, 6, 7),  # download segment, toggle 0
        c2s(0x10, 1, 2, 3, 4, 5, 6, 7),  # toggle 1
        c2s(0x07, 9, 9, 9),  # the last segment
        c2s(0xA4, LO, HI, 0, 5),  # block upload
        c2s(0xA4, LO, HI, 1, 5, 4),  # block upload, switched to a normal one
        c2s(0xA3),  # block upload start
        c2s(0xA2, 5, 5),  # its acknowledge
        c2s(0xA1),  # the end response
        c2s(0xC6, LO, HI, 2, 12),  # block download of 12 bytes
        c2s(0x01, 1, 2, 3, 4, 5, 6, 7),  # block segment 1
        c2s(0x82, 1, 2, 3, 4, 5, 6, 7),  # block segment 2, the last
        c2s(0xC5, 0, 0),  # block download end, 2 bytes unused in the last segment
        c2s(0x80, LO, HI, 0, 0, 0, 0, 8),  # abort from the client
    ]
)
_inputs = st.lists(
    st.one_of(_requests, _requests, frames_to(RX), st.floats(0.0, 2.0)), min_size=1, max_size=14
)


@settings(max_examples=400, deadline=None)
@given(state=st.sampled_from(["idle", "idle", "idle", *SERVER_STATES]), feed=_inputs)
@example(state="idle", feed=[c2s(0x40, LO, HI, 1), c2s(0x60)])  # an abort after a read names 0
@example(state="upload segment", feed=[c2s(0x40, LO, HI, 1), c2s(0x70)])
def test_any_sequence_of_requests_answers_the_same(state: str, feed: list[Frame | float]) -> None:
    if state == "idle":
        twins, _, _ = _twins()
    else:  # both brought into the state by the frames that bring one there
        loud, quiet = server_in(state), server_in(state)
        quiet.reports = False
        twins = Twins(loud, quiet)
    now = 0.0
    for item in feed:
        if isinstance(item, float):
            now += item
            twins.on_timer(now)
        else:
            twins.on_frame(item, now)
