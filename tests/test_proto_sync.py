import pytest

from cobus.proto import NOTHING, Frame, Machine
from cobus.proto.sync import (
    SyncCobId,
    SyncConfigError,
    SyncConsumer,
    SyncProducer,
    SyncReceived,
    SyncResumed,
    SyncTimedOut,
    UnexpectedSyncLength,
    check_overflow,
)
from tests.golden import case


def deadline(machine: Machine) -> float | None:
    return machine.deadline


def run(p: SyncProducer, count: int) -> list[Frame]:
    frames: list[Frame] = []
    for _ in range(count):
        due = deadline(p)
        assert due is not None
        frames += p.on_timer(due).frames
    return frames


# --- COB-ID and overflow ----------------------------------------------------------------------


def test_cob_id_codec():
    assert SyncCobId.from_u32(0x80) == SyncCobId(0x80, False, False)
    assert SyncCobId.from_u32(0x40000080) == SyncCobId(0x80, True, False)
    assert SyncCobId.from_u32(0xA0012345) == SyncCobId(0x12345, False, True)
    assert SyncCobId(0x81, True).to_u32() == 0x40000081
    assert SyncCobId(0x12345, False, True).to_u32() == 0x20012345
    with pytest.raises(SyncConfigError, match="needs bit 29"):
        SyncCobId.from_u32(0x800)
    with pytest.raises(SyncConfigError, match="UNSIGNED32"):
        SyncCobId.from_u32(1 << 32)


@pytest.mark.parametrize("value", [0, 2, 100, 240])
def test_valid_overflow_values(value):
    assert check_overflow(value) == value


@pytest.mark.parametrize("value", [1, 241, 255, -1])
def test_invalid_overflow_values(value):
    with pytest.raises(SyncConfigError, match=r"0 \(no counter\) or 2\.\.240"):
        check_overflow(value)


# --- producer ---------------------------------------------------------------------------------


def test_producer_without_counter_matches_the_zapi_vector():
    sync = case("thesis-zapi", "SYNC 20 ms").steps[0].frame
    p = SyncProducer()
    assert deadline(p) is None and p.on_timer(5.0) is NOTHING
    p.set_period(20_000, 0.0)
    assert deadline(p) == pytest.approx(0.02)
    assert p.on_timer(0.01) is NOTHING
    assert run(p, 3) == [sync] * 3
    assert p.counter is None
    assert p.on_frame(sync, 1.0) is NOTHING


def test_producer_counter_wraps_at_overflow():
    p = SyncProducer(overflow=3)
    p.set_period(10_000, 0.0)
    assert p.counter == 1
    counters = [f.data[0] for f in run(p, 7)]
    assert counters == [1, 2, 3, 1, 2, 3, 1]


def test_producer_counter_restarts_when_production_starts():
    p = SyncProducer(overflow=5)
    p.set_period(10_000, 0.0)
    run(p, 2)
    p.set_period(0, 1.0)
    assert deadline(p) is None
    p.set_period(10_000, 2.0)
    assert [f.data[0] for f in run(p, 2)] == [1, 2]


def test_producer_on_demand_and_stall():
    p = SyncProducer(overflow=2)
    assert p.send(0.0).frames == (Frame(0x80, b"\x01"),)
    assert p.send(0.0).frames == (Frame(0x80, b"\x02"),)
    assert p.send(0.0).frames == (Frame(0x80, b"\x01"),)
    p.set_period(1000, 0.0)
    p.on_timer(0.0015)  # half a period late: the next SYNC stays on the grid
    assert deadline(p) == pytest.approx(0.002)
    assert p.late_max == pytest.approx(0.0005) and p.skipped == 0
    p.on_timer(3.0)  # late: skip the missed SYNCs, and count them
    assert deadline(p) == pytest.approx(3.001)
    assert p.skipped == 2998 and p.late_max == pytest.approx(2.998)


def test_overflow_changes_only_while_the_period_is_zero():
    p = SyncProducer()
    p.set_overflow(4)
    assert p.counter == 1
    p.set_period(10_000, 0.0)
    with pytest.raises(SyncConfigError, match="write 1006h = 0 first"):
        p.set_overflow(0)
    with pytest.raises(SyncConfigError):
        p.set_overflow(1)
    with pytest.raises(SyncConfigError, match="4294967295"):
        p.set_period(-1, 0.0)


def test_producer_cob_id_rules():
    p = SyncProducer(0x80)
    p.set_period(10_000, 0.0)
    with pytest.raises(SyncConfigError, match="bit 30"):
        p.set_cob_id(0x40000081, 0.0)
    p.set_cob_id(0x00000080, 0.0)  # stop generating
    assert deadline(p) is None
    p.set_cob_id(0x00000081, 0.0)
    p.set_cob_id(0x40000081, 1.0)  # generate again on the new identifier
    assert deadline(p) == pytest.approx(1.01)
    assert run(p, 1) == [Frame(0x81)]
    p.set_cob_id(0x00000081, 2.0)
    p.set_cob_id(0x60001234, 2.0)  # bit 30 and a 29-bit identifier
    assert run(p, 1) == [Frame(0x1234, extended=True)]


def test_producer_not_generating():
    p = SyncProducer(generate=False)
    p.set_period(10_000, 0.0)
    assert deadline(p) is None
    with pytest.raises(SyncConfigError, match="11-bit"):
        SyncProducer(0x800)
    with pytest.raises(SyncConfigError, match=r"2\.\.240"):
        SyncProducer(overflow=1)


# --- consumer ---------------------------------------------------------------------------------


def test_consumer_reports_sync_with_and_without_counter():
    c = SyncConsumer()
    assert c.on_frame(Frame(0x80), 1.0).events == (SyncReceived(None),)
    assert (c.counter, c.last_sync) == (None, 1.0)
    assert c.on_frame(Frame(0x80, b"\x07"), 2.0).events == (SyncReceived(7),)
    assert (c.counter, c.last_sync) == (7, 2.0)
    assert c.on_timer(100.0) is NOTHING and deadline(c) is None


def test_consumer_checks_the_length_against_1019h():
    c = SyncConsumer(overflow=0)
    assert c.on_frame(Frame(0x80, b"\x01"), 0.0).events == (UnexpectedSyncLength(0, 1),)
    assert c.last_sync is None
    c.set_overflow(10)
    assert c.on_frame(Frame(0x80), 0.0).events == (UnexpectedSyncLength(1, 0),)
    assert c.on_frame(Frame(0x80, b"\x03"), 0.0).events == (SyncReceived(3),)
    c.set_overflow(None)
    assert c.on_frame(Frame(0x80, b"\x01\x02"), 0.0).events == (UnexpectedSyncLength(None, 2),)
    with pytest.raises(SyncConfigError):
        c.set_overflow(241)


def test_consumer_ignores_other_frames():
    c = SyncConsumer()
    assert c.on_frame(Frame(0x81), 0.0) is NOTHING
    assert c.on_frame(Frame(0x80, rtr=True), 0.0) is NOTHING
    assert c.on_frame(Frame(0x80, extended=True), 0.0) is NOTHING
    c.set_cob_id(0x20000080)
    assert c.on_frame(Frame(0x80, extended=True), 0.0).events == (SyncReceived(None),)
    assert c.on_frame(Frame(0x80), 0.0) is NOTHING


def test_sync_loss_and_resume():
    c = SyncConsumer()
    c.set_period(20_000, 0.0)
    assert deadline(c) is None  # armed by the first SYNC
    c.on_frame(Frame(0x80), 1.0)
    assert deadline(c) == pytest.approx(1.03)  # 1.5 x 20 ms
    c.on_frame(Frame(0x80), 1.02)
    assert c.on_timer(1.04) is NOTHING
    assert c.on_timer(1.05).events == (SyncTimedOut(),)
    assert (c.lost, deadline(c), c.on_timer(2.0)) == (True, None, NOTHING)
    out = c.on_frame(Frame(0x80, b"\x05"), 3.0)
    assert out.events == (SyncResumed(), SyncReceived(5))
    assert c.lost is False
    c.on_timer(3.03)
    assert c.on_frame(Frame(0x80), 4.0).events == (SyncResumed(), SyncReceived(None))


def test_sync_period_changes():
    c = SyncConsumer(loss_factor=2.0)
    c.set_period(10_000, 0.0)
    c.on_frame(Frame(0x80), 0.0)
    c.set_period(50_000, 0.01)  # running: restarts from now
    assert deadline(c) == pytest.approx(0.11)
    c.on_timer(0.11)
    c.set_period(0, 0.2)  # off: no loss pending, no supervision
    assert deadline(c) is None and not c.lost
    c.on_frame(Frame(0x80), 0.3)
    assert deadline(c) is None
    with pytest.raises(SyncConfigError, match=">= 1 period"):
        SyncConsumer(loss_factor=0.5)


def test_synchronous_window():
    c = SyncConsumer()
    assert not c.in_window(0.0)  # no SYNC yet
    c.on_frame(Frame(0x80), 1.0)
    assert c.in_window(50.0)  # window 0: not used
    c.set_window(5_000)
    assert c.in_window(1.004) and c.in_window(1.005)
    assert not c.in_window(1.006)
    c.on_frame(Frame(0x80), 2.0)
    assert c.in_window(2.001)
    with pytest.raises(SyncConfigError, match="1007h"):
        c.set_window(-5)
