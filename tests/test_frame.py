import pytest

from cobus.proto import NOTHING, Frame, FrameError, Out
from tests.golden import load


def test_parse_and_repr_round_trip():
    f = Frame.parse("605 [8] 40 00 10 00 00 00 00 00")
    assert f.cob_id == 0x605 and f.dlc == 8 and not f.rtr
    assert f.data == bytes([0x40, 0, 0x10, 0, 0, 0, 0, 0])
    assert Frame.parse(repr(f)[6:-1]) == f


def test_remote_frame():
    f = Frame.parse("71B [0] RTR")
    assert f.rtr and f.dlc == 0 and f.data == b""
    assert f == Frame(0x71B, rtr=True)
    assert f != Frame(0x71B)


def test_extended_identifier():
    f = Frame(0x1234567, b"\x01", extended=True)
    assert f.extended and repr(f) == "Frame(01234567 [1] 01)"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"cob_id": 0x800}, "11-bit"),
        ({"cob_id": -1}, "11-bit"),
        ({"cob_id": 0x20000000, "extended": True}, "29-bit"),
        ({"cob_id": 1, "data": bytes(9)}, "0 to 8"),
        ({"cob_id": 1, "data": b"\x00", "rtr": True}, "cannot carry data"),
        ({"cob_id": 1, "data": b"\x00", "dlc": 2}, "differs"),
    ],
)
def test_invalid_frames_are_refused(kwargs, message):
    with pytest.raises(FrameError, match=message):
        Frame(**kwargs)


def test_out_concatenation():
    a = Out((Frame(1),), ())
    assert a + NOTHING is a
    assert NOTHING + a is a
    assert (a + a).frames == (Frame(1), Frame(1))


def test_every_vectors_file_parses():
    for name in ("beckhoff-cia301", "ec-motor", "stober-mds5000", "thesis-zapi"):
        cases = load(name)
        assert cases, name
        assert sum(len(c.steps) for c in cases) > 3, name
