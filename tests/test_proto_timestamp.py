from datetime import UTC, datetime, timedelta, timezone

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cobus.proto import NOTHING, Frame, Machine
from cobus.proto.timestamp import (
    EPOCH,
    MalformedTime,
    TimeCobId,
    TimeConsumer,
    TimeError,
    TimeProducer,
    TimeStampReceived,
    decode_time_of_day,
    encode_time_of_day,
)


def deadline(machine: Machine) -> float | None:
    return machine.deadline


def test_epoch_and_layout():
    assert encode_time_of_day(EPOCH) == bytes(6)
    # one day and one ms after the epoch
    assert encode_time_of_day(EPOCH + timedelta(days=1, milliseconds=1)) == bytes(
        [1, 0, 0, 0, 1, 0]
    )
    when = datetime(2024, 3, 1, 12, 30, 15, 250_000, tzinfo=UTC)
    data = encode_time_of_day(when)
    ms = int.from_bytes(data[:4], "little")
    days = int.from_bytes(data[4:], "little")
    assert ms == ((12 * 60 + 30) * 60 + 15) * 1000 + 250
    assert days == (when.date() - EPOCH.date()).days == 14670
    assert decode_time_of_day(data) == when


def test_sub_millisecond_parts_are_dropped_and_zones_converted():
    when = datetime(2000, 1, 1, 0, 0, 0, 999, tzinfo=UTC)
    assert decode_time_of_day(encode_time_of_day(when)) == when.replace(microsecond=0)
    cet = timezone(timedelta(hours=1))
    local = datetime(2000, 1, 1, 1, 0, tzinfo=cet)
    assert decode_time_of_day(encode_time_of_day(local)) == datetime(2000, 1, 1, tzinfo=UTC)


def test_reserved_bits_are_ignored_on_decode():
    data = bytes([0x10, 0, 0, 0xF0, 2, 0])
    assert decode_time_of_day(data) == EPOCH + timedelta(days=2, milliseconds=16)


@given(
    st.datetimes(
        min_value=datetime(1984, 1, 1),
        max_value=datetime(2163, 1, 1),
        timezones=st.just(UTC),
    )
)
def test_round_trip(when):
    when = when.replace(microsecond=when.microsecond // 1000 * 1000)
    assert decode_time_of_day(encode_time_of_day(when)) == when


def test_encode_errors():
    with pytest.raises(TimeError, match="no time zone"):
        encode_time_of_day(datetime(2020, 1, 1))
    with pytest.raises(TimeError, match="outside"):
        encode_time_of_day(datetime(1983, 12, 31, 23, 59, tzinfo=UTC))
    with pytest.raises(TimeError, match="outside"):
        encode_time_of_day(datetime(2170, 1, 1, tzinfo=UTC))


def test_decode_errors():
    with pytest.raises(TimeError, match="6 bytes, not 5"):
        decode_time_of_day(bytes(5))
    with pytest.raises(TimeError, match="86400000"):
        decode_time_of_day((86_400_000).to_bytes(4, "little") + bytes(2))


def test_cob_id_codec():
    assert TimeCobId.from_u32(0x100) == TimeCobId(0x100, False, False, False)
    assert TimeCobId.from_u32(0xC0000100) == TimeCobId(0x100, True, True, False)
    assert TimeCobId.from_u32(0x20000100) == TimeCobId(0x100, False, False, True)
    assert TimeCobId(0x100, True, False).to_u32() == 0x80000100
    assert TimeCobId(0x123, False, True, True).to_u32() == 0x60000123
    with pytest.raises(TimeError, match="needs bit 29"):
        TimeCobId.from_u32(0x1000)
    with pytest.raises(TimeError, match="UNSIGNED32"):
        TimeCobId.from_u32(-1)


def test_producer_on_demand():
    p = TimeProducer()
    when = datetime(2024, 1, 1, tzinfo=UTC)
    (frame,) = p.send(when).frames
    assert frame.cob_id == 0x100 and frame.data == encode_time_of_day(when)
    assert deadline(p) is None and p.on_timer(10.0) is NOTHING
    assert p.on_frame(frame, 0.0) is NOTHING
    with pytest.raises(TimeError, match="11-bit"):
        TimeProducer(0x800)


def test_producer_periodic_derives_the_wall_time_from_now():
    p = TimeProducer(0x1234, extended=True)
    wall = datetime(2024, 5, 6, 7, 8, 9, tzinfo=UTC)
    out = p.set_interval(1.0, 100.0, wall)
    assert out.frames == (Frame(0x1234, encode_time_of_day(wall), extended=True),)
    assert deadline(p) == 101.0
    assert p.on_timer(100.5) is NOTHING
    (frame,) = p.on_timer(101.0).frames
    assert decode_time_of_day(frame.data) == wall + timedelta(seconds=1)
    (frame,) = p.on_timer(105.25).frames  # late: stamp of the actual time, no burst
    assert decode_time_of_day(frame.data) == wall + timedelta(seconds=5.25)
    assert deadline(p) == 106.25
    assert p.set_interval(0, 107.0) is NOTHING
    assert deadline(p) is None


def test_producer_interval_errors():
    p = TimeProducer()
    with pytest.raises(TimeError, match="wall time"):
        p.set_interval(1.0, 0.0)
    with pytest.raises(TimeError, match=">= 0"):
        p.set_interval(-1.0, 0.0, EPOCH)


def test_consumer():
    c = TimeConsumer()
    when = datetime(2030, 6, 1, 8, 0, tzinfo=UTC)
    out = c.on_frame(Frame(0x100, encode_time_of_day(when)), 0.0)
    assert out.events == (TimeStampReceived(when),)
    assert c.on_frame(Frame(0x101, bytes(6)), 0.0) is NOTHING
    assert c.on_frame(Frame(0x100, bytes(6), extended=True), 0.0) is NOTHING
    (event,) = c.on_frame(Frame(0x100, bytes(4)), 0.0).events
    assert isinstance(event, MalformedTime) and "6 bytes, not 4" in event.reason
    (event,) = c.on_frame(Frame(0x100, rtr=True), 0.0).events
    assert isinstance(event, MalformedTime) and "remote" in event.reason
    assert deadline(c) is None and c.on_timer(1.0) is NOTHING
    with pytest.raises(TimeError):
        TimeConsumer(-1)
