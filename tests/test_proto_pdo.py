import math
import struct
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cobus.proto import NOTHING, Frame, Machine
from cobus.proto.pdo import (
    Kind,
    MappingEntry,
    PdoCobId,
    PdoError,
    PdoLengthError,
    PdoMap,
    RpdoResumed,
    RpdoTimeout,
    RpdoTooLong,
    RpdoTooShort,
    RpdoWatchdog,
    TpdoDue,
    TpdoReason,
    TpdoSample,
    TpdoTrigger,
    TransmissionType,
    is_restricted_can_id,
    rpdo_default_can_id,
    tpdo_default_can_id,
)


def deadline(machine: Machine | TpdoTrigger) -> float | None:
    return machine.deadline


def e(index: int, sub: int, bits: int) -> MappingEntry:
    return MappingEntry(index, sub, bits)


# --- mapping entries --------------------------------------------------------------------------


def test_mapping_entry_codec():
    entry = MappingEntry.from_u32(0x28080010)  # E08 n-Motor of the stober manual
    assert entry == MappingEntry(0x2808, 0, 16)
    assert entry.to_u32() == 0x28080010
    assert repr(entry) == "MappingEntry(2808h:00h, 16 bits)"
    assert not entry.is_dummy
    assert MappingEntry(0x0005, 0, 8).is_dummy and MappingEntry(0x0001, 0, 1).is_dummy
    assert not MappingEntry(0x0008, 0, 32).is_dummy


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((0x10000, 0, 8), "index"),
        ((0x2000, 256, 8), "sub-index"),
        ((0x2000, 0, 256), "bit length"),
    ],
)
def test_mapping_entry_validation(args, message):
    with pytest.raises(PdoError, match=message):
        MappingEntry(*args)


def test_mapping_entry_from_bad_u32():
    with pytest.raises(PdoError, match="UNSIGNED32"):
        MappingEntry.from_u32(1 << 32)


# --- PdoMap: byte-aligned fast path --------------------------------------------------------------


def test_aligned_map_uses_one_struct():
    m = PdoMap(
        [
            (e(0x6041, 0, 16), Kind.UNSIGNED),
            (e(0x6064, 0, 32), Kind.SIGNED),
            (e(0x0005, 0, 8), None),  # dummy UNSIGNED8
            (e(0x2000, 1, 8), Kind.BOOL),
        ]
    )
    assert m.byte_aligned and m.length == 8 and m.bit_length == 64 and m.value_count == 3
    data = m.pack([0x1234, -2, True])
    assert data == bytes.fromhex("3412FEFFFFFF0001")
    assert m.unpack(data) == (0x1234, -2, True)
    assert m.unpack(bytes.fromhex("3412FEFFFFFF7702")) == (0x1234, -2, True)  # dummy skipped


def test_aligned_reals_and_bytes():
    m = PdoMap([(e(0x2001, 0, 32), Kind.REAL32), (e(0x2002, 0, 24), Kind.BYTES)])
    assert m.byte_aligned and m.length == 7
    data = m.pack([1.5, b"abc"])
    assert data == struct.pack("<f", 1.5) + b"abc"
    assert m.unpack(data) == (1.5, b"abc")
    assert m.pack([0.0, b"a"])[4:] == b"a\x00\x00"  # shorter bytes are zero-filled
    d = PdoMap([(e(0x2003, 0, 64), Kind.REAL64)])
    assert d.unpack(d.pack([math.pi])) == (math.pi,)


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (0x10000, "not an unsigned 16-bit integer"),
        (-1, "not an unsigned 16-bit integer"),
        ("x", "not an unsigned 16-bit integer"),
    ],
)
def test_aligned_pack_names_the_bad_value(value, message):
    m = PdoMap([(e(0x6040, 0, 16), Kind.UNSIGNED), (e(0x2000, 0, 32), Kind.REAL32)])
    with pytest.raises(PdoError, match=message):
        m.pack([value, 1.0])


def test_aligned_pack_other_failures():
    m = PdoMap([(e(0x6040, 0, 16), Kind.UNSIGNED), (e(0x2000, 0, 32), Kind.REAL32)])
    with pytest.raises(PdoError, match="not a real32"):
        m.pack([1, "x"])
    with pytest.raises(PdoError, match="not a real32"):
        m.pack([1, 1e300])
    b = PdoMap([(e(0x2000, 0, 16), Kind.BYTES)])
    with pytest.raises(PdoError, match="bytes of at most 2"):
        b.pack([b"abc"])
    with pytest.raises(PdoError, match="bytes of at most 2"):
        b.pack(["ab"])


def test_aligned_pack_failure_no_field_explains():
    m = PdoMap([(e(0x2000, 0, 8), Kind.UNSIGNED)])
    m._struct = struct.Struct("<b")  # a struct stricter than the fields' own checks
    with pytest.raises(PdoError, match="cannot pack"):
        m.pack([200])


# --- PdoMap: odd bit layouts -------------------------------------------------------------------


def test_bit_layout_positions():
    m = PdoMap(
        [
            (e(0x2000, 1, 1), Kind.BOOL),
            (e(0x2000, 2, 3), Kind.UNSIGNED),
            (e(0x2000, 3, 12), Kind.SIGNED),
        ]
    )
    assert not m.byte_aligned and m.length == 2
    # bit 0 = 1, bits 1-3 = 101b, bits 4-15 = FFEh (-2)
    assert m.pack([True, 5, -2]) == bytes([0xEB, 0xFF])
    assert m.unpack(bytes([0xEB, 0xFF])) == (True, 5, -2)
    assert m.unpack(bytes([0x00, 0x80])) == (False, 0, -2048)


def test_24_and_40_bit_fields():
    m = PdoMap(
        [
            (e(0x2001, 0, 24), Kind.SIGNED),
            (e(0x2002, 0, 40), Kind.UNSIGNED),
        ]
    )
    assert not m.byte_aligned and m.length == 8
    data = m.pack([-1, 0x0102030405])
    assert data == bytes.fromhex("FFFFFF0504030201")
    assert m.unpack(data) == (-1, 0x0102030405)


def test_dummy_bits_are_zero_on_pack_and_skipped_on_unpack():
    m = PdoMap(
        [
            (e(0x2000, 1, 3), Kind.UNSIGNED),
            (e(0x0001, 0, 5), Kind.UNSIGNED),  # a kind on a dummy is ignored
            (e(0x2000, 2, 8), Kind.UNSIGNED),
        ]
    )
    assert m.value_count == 2 and not m.byte_aligned
    assert m.pack([7, 0xAA]) == bytes([0x07, 0xAA])
    assert m.unpack(bytes([0xFF, 0xAA])) == (7, 0xAA)


def test_unaligned_struct_kinds_go_the_bit_path():
    m = PdoMap(
        [
            (e(0x2000, 1, 4), Kind.UNSIGNED),
            (e(0x2000, 2, 32), Kind.REAL32),
            (e(0x2000, 3, 16), Kind.BYTES),
            (e(0x2000, 4, 4), Kind.BOOL),
        ]
    )
    assert not m.byte_aligned and m.length == 7
    values = (9, -0.25, b"\x01\x02", True)
    assert m.unpack(m.pack(values)) == values
    r64 = PdoMap([(e(0x2000, 1, 64), Kind.REAL64)])
    assert r64.byte_aligned and r64.unpack(r64.pack([2.5])) == (2.5,)


def test_bit_path_errors():
    m = PdoMap([(e(0x2000, 1, 4), Kind.SIGNED), (e(0x2000, 2, 4), Kind.UNSIGNED)])
    with pytest.raises(PdoError, match="signed 4-bit"):
        m.pack([8, 0])
    with pytest.raises(PdoError, match="signed 4-bit"):
        m.pack([-9, 0])
    with pytest.raises(PdoError, match="unsigned 4-bit"):
        m.pack([0, 16])
    b = PdoMap([(e(0x2000, 1, 4), Kind.UNSIGNED), (e(0x2000, 2, 16), Kind.BYTES)])
    with pytest.raises(PdoError, match="bytes of at most 2"):
        b.pack([0, b"abc"])


class Scaled:
    """A custom codec: a value in 0.1 units stored as unsigned raw bits."""

    def encode(self, value: float, bits: int) -> int:
        return round(value * 10)

    def decode(self, raw: int, bits: int) -> Any:
        return raw / 10


def test_custom_codec():
    m = PdoMap([(e(0x2000, 1, 8), Scaled()), (e(0x2000, 2, 8), Kind.UNSIGNED)])
    assert not m.byte_aligned  # custom codecs take the bit path
    assert m.pack([2.5, 1]) == bytes([25, 1])
    assert m.unpack(bytes([25, 1])) == (2.5, 1)
    with pytest.raises(PdoError, match="not 8 raw bits"):
        m.pack([30.0, 1])


def test_length_checks():
    m = PdoMap([(e(0x2000, 1, 16), Kind.UNSIGNED), (e(0x2000, 2, 4), Kind.UNSIGNED)])
    with pytest.raises(PdoLengthError, match="carries 2 bytes but its mapping needs 3") as info:
        m.unpack(b"\x01\x02")
    assert (info.value.expected, info.value.received) == (3, 2)
    assert m.unpack(b"\x01\x02\x03\xff\xff") == (0x0201, 3)  # longer: allowed
    a = PdoMap([(e(0x2000, 1, 16), Kind.UNSIGNED)])
    with pytest.raises(PdoLengthError):
        a.unpack(b"\x01")
    assert a.unpack(b"\x01\x02\x03") == (0x0201,)
    empty = PdoMap([])
    assert empty.length == 0 and empty.pack([]) == b"" and empty.unpack(b"") == ()


def test_mapping_limits():
    with pytest.raises(PdoError, match="65 bits but a PDO carries at most 64"):
        PdoMap([(e(0x2000, 1, 64), Kind.UNSIGNED), (e(0x2000, 2, 1), Kind.BOOL)])
    with pytest.raises(PdoError, match="at most 64 objects"):
        PdoMap([(e(0x2000, i, 1), Kind.BOOL) for i in range(65)])
    full = PdoMap([(e(0x2000, i, 1), Kind.BOOL) for i in range(64)])
    assert full.length == 8 and full.unpack(b"\xff" * 8) == (True,) * 64


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ([(e(0x2000, 1, 0), Kind.UNSIGNED)], "at least 1 bit"),
        ([(e(0x2000, 1, 8), None)], "needs a Kind or a codec"),
        ([(e(0x2000, 1, 16), Kind.REAL32)], "takes 32 bits"),
        ([(e(0x2000, 1, 32), Kind.REAL64)], "takes 64 bits"),
        ([(e(0x2000, 1, 12), Kind.BYTES)], "multiple of 8"),
    ],
)
def test_bad_fields(fields, message):
    with pytest.raises(PdoError, match=message):
        PdoMap(fields)


def test_value_count_must_match():
    m = PdoMap([(e(0x2000, 1, 8), Kind.UNSIGNED)])
    with pytest.raises(PdoError, match="1 values"):
        m.pack([1, 2])


# hypothesis: random layouts of any kinds and widths, round-tripped

_KINDS_BY_BITS = st.sampled_from(["u", "s", "b", "y", "f", "d", "x"])


@st.composite
def layouts(draw: st.DrawFn) -> tuple[PdoMap, list[Any]]:
    fields: list[tuple[MappingEntry, Kind | None]] = []
    values: list[Any] = []
    room = 64
    while room and len(fields) < 12 and draw(st.booleans()):
        kind = draw(_KINDS_BY_BITS)
        if kind == "f" and room >= 32:
            bits, k = 32, Kind.REAL32
            v: Any = draw(st.floats(width=32, allow_nan=False))
        elif kind == "d" and room >= 64:
            bits, k, v = 64, Kind.REAL64, draw(st.floats(allow_nan=False))
        elif kind == "y" and room >= 8:
            size = draw(st.integers(1, room // 8))
            bits, k, v = size * 8, Kind.BYTES, draw(st.binary(min_size=size, max_size=size))
        elif kind == "b":
            bits, k, v = draw(st.integers(1, min(8, room))), Kind.BOOL, draw(st.booleans())
        elif kind == "s":
            bits = draw(st.integers(1, room))
            k = Kind.SIGNED
            v = draw(st.integers(-(1 << (bits - 1)), (1 << (bits - 1)) - 1))
        elif kind == "x":
            bits = draw(st.integers(1, room))
            fields.append((e(draw(st.integers(1, 7)), 0, bits), None))
            room -= bits
            continue
        else:
            bits = draw(st.integers(1, room))
            k, v = Kind.UNSIGNED, draw(st.integers(0, (1 << bits) - 1))
        fields.append((e(0x2000, len(fields) + 1, bits), k))
        values.append(v)
        room -= bits
    return PdoMap(fields), values


@given(layouts())
def test_round_trip_of_random_layouts(layout):
    m, values = layout
    data = m.pack(values)
    assert len(data) == m.length
    assert list(m.unpack(data)) == values
    assert list(m.unpack(data + b"\xff" * (8 - len(data)))) == values


@given(st.lists(st.integers(1, 16), min_size=1, max_size=8).filter(lambda b: sum(b) <= 64))
def test_bit_path_matches_a_reference_bit_layout(widths):
    m = PdoMap([(e(0x2000, i + 1, w), Kind.UNSIGNED) for i, w in enumerate(widths)])
    values = [(1 << w) - 1 if i % 2 else 1 for i, w in enumerate(widths)]
    data = m.pack(values)
    # reference: write bit by bit, LSB first, from byte 0 upwards
    bits: list[int] = []
    for v, w in zip(values, widths, strict=True):
        bits += [(v >> i) & 1 for i in range(w)]
    ref = bytearray(m.length)
    for pos, bit in enumerate(bits):
        ref[pos // 8] |= bit << (pos % 8)
    assert data == bytes(ref)


# --- COB-IDs ----------------------------------------------------------------------------------


def test_pdo_cob_id_codec():
    assert PdoCobId.from_u32(0x181) == PdoCobId(0x181, True, True, False)
    assert PdoCobId.from_u32(0xC0000181) == PdoCobId(0x181, False, False, False)
    assert PdoCobId.from_u32(0x20012345) == PdoCobId(0x12345, True, True, True)
    assert PdoCobId(0x181, valid=False).to_u32() == 0x80000181
    assert PdoCobId(0x181, rtr_allowed=False).to_u32() == 0x40000181
    assert PdoCobId(0x12345, extended=True).to_u32() == 0x20012345
    assert str(PdoCobId(0x181)) == "181h (valid, RTR, 11-bit)"
    assert str(PdoCobId(0x12345, False, False, True)) == "00012345h (invalid, no RTR, 29-bit)"
    with pytest.raises(PdoError, match="needs bit 29"):
        PdoCobId.from_u32(0x1000)
    with pytest.raises(PdoError, match="UNSIGNED32"):
        PdoCobId.from_u32(-5)


@pytest.mark.parametrize(
    ("can_id", "restricted"),
    [
        (0x000, True),
        (0x07F, True),
        (0x080, False),
        (0x100, False),
        (0x101, True),
        (0x180, True),
        (0x181, False),
        (0x580, False),
        (0x581, True),
        (0x67F, True),
        (0x680, False),
        (0x6E0, True),
        (0x700, False),
        (0x701, True),
        (0x7FF, True),
    ],
)
def test_restricted_identifiers(can_id, restricted):
    assert is_restricted_can_id(can_id) is restricted


def test_default_identifiers():
    assert tpdo_default_can_id(1, 1) == 0x181 and tpdo_default_can_id(4, 127) == 0x4FF
    assert rpdo_default_can_id(1, 8) == 0x208 and rpdo_default_can_id(3, 1) == 0x401
    with pytest.raises(PdoError, match=r"PDO 1\.\.4"):
        tpdo_default_can_id(5, 1)
    with pytest.raises(PdoError, match=r"1\.\.127"):
        rpdo_default_can_id(1, 0)


# --- transmission types ---------------------------------------------------------------------


def test_transmission_type_predicates():
    t0, t3, t252, t253, t254, t255 = (TransmissionType(v) for v in (0, 3, 252, 253, 254, 255))
    assert t0.acyclic and t0.synchronous and not t0.cyclic and t0.every is None
    assert t3.cyclic and t3.every == 3 and t3.synchronous and not t3.acyclic
    assert t252.rtr_only and t252.synchronous and not t252.valid_for_rpdo
    assert t253.rtr_only and not t253.synchronous and not t253.event_driven
    assert t254.event_driven and t255.event_driven and t255.valid_for_rpdo
    assert TransmissionType(240).cyclic and TransmissionType(240).valid_for_rpdo


@pytest.mark.parametrize("value", [241, 245, 251])
def test_reserved_transmission_types(value):
    with pytest.raises(PdoError, match="reserved"):
        TransmissionType(value)


def test_transmission_type_range():
    with pytest.raises(PdoError, match=r"0\.\.255"):
        TransmissionType(256)


# --- TPDO trigger -------------------------------------------------------------------------------

SYNC_DUE = (TpdoDue(TpdoReason.SYNC),)


def syncs(t: TpdoTrigger, counters: list[int | None]) -> list[int]:
    """Indexes (1-based) of the SYNCs at which the TPDO was due."""
    return [i for i, c in enumerate(counters, 1) if t.on_sync(c, float(i)).events == SYNC_DUE]


def test_cyclic_every_third_sync():
    t = TpdoTrigger(3)
    t.start(0.0)
    assert syncs(t, [None] * 10) == [3, 6, 9]


def test_cyclic_with_sync_start_value():
    t = TpdoTrigger(3, sync_start_value=4)
    t.start(0.0)
    counters: list[int | None] = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 1, 2]
    # waits for counter 4, then every third SYNC
    assert syncs(t, counters) == [4, 7, 10]


def test_sync_start_value_without_counter_is_ignored():
    t = TpdoTrigger(2, sync_start_value=4)
    t.start(0.0)
    assert syncs(t, [None] * 5) == [2, 4]


def test_acyclic_sends_at_sync_only_if_changed():
    t = TpdoTrigger(0)
    t.start(0.0)
    assert t.on_sync(None, 1.0) is NOTHING
    assert t.on_change(1.5) is NOTHING
    assert t.on_change(1.6) is NOTHING
    assert t.on_sync(None, 2.0).events == SYNC_DUE
    assert t.on_sync(None, 3.0) is NOTHING


def test_rtr_only_types():
    t = TpdoTrigger(252)
    t.start(0.0)
    assert t.on_sync(1, 1.0).events == (TpdoSample(),)
    assert t.on_change(1.1) is NOTHING
    assert t.on_rtr(1.2).events == (TpdoDue(TpdoReason.RTR),)
    r = TpdoTrigger(253)
    r.start(0.0)
    assert r.on_sync(1, 1.0) is NOTHING and r.on_change(1.1) is NOTHING
    assert r.on_rtr(1.2).events == (TpdoDue(TpdoReason.RTR),)
    assert TpdoTrigger(5).on_rtr(0.0) is NOTHING  # not started
    c = TpdoTrigger(5)
    c.start(0.0)
    assert c.on_rtr(0.5).events == (TpdoDue(TpdoReason.RTR),)
    assert c.on_change(0.6) is NOTHING  # cyclic: changes do not trigger


def test_event_driven_sends_on_change_and_ignores_sync():
    t = TpdoTrigger(255)
    t.start(0.0)
    assert t.on_sync(1, 0.5) is NOTHING
    assert t.on_change(1.0).events == (TpdoDue(TpdoReason.EVENT),)
    assert t.on_change(1.0).events == (TpdoDue(TpdoReason.EVENT),)  # no inhibit time
    assert deadline(t) is None


def test_inhibit_time_throttles_a_fast_changing_value():
    t = TpdoTrigger(254, inhibit_time_100us=1250)  # 125 ms
    t.start(0.0)
    sent: list[tuple[float, TpdoReason]] = []
    now = 0.0
    for _ in range(40):  # a change every 10 ms for 400 ms
        for ev in t.on_change(now).events:
            assert isinstance(ev, TpdoDue)
            sent.append((now, ev.reason))
        due = deadline(t)
        now = round(now + 0.01, 6)
        while due is not None and due <= now:
            for ev in t.on_timer(due).events:
                assert isinstance(ev, TpdoDue)
                sent.append((due, ev.reason))
            due = deadline(t)
    # first change at once, then one send at the end of each inhibit period
    assert sent == [
        (0.0, TpdoReason.EVENT),
        (0.125, TpdoReason.EVENT),
        (0.25, TpdoReason.EVENT),
        (0.375, TpdoReason.EVENT),
    ]


def test_event_timer_fires_and_restarts_on_each_send():
    t = TpdoTrigger(255, event_timer_ms=500)
    assert deadline(t) is None
    t.start(0.0)
    assert deadline(t) == 0.5
    assert t.on_timer(0.25) is NOTHING
    assert t.on_timer(0.5).events == (TpdoDue(TpdoReason.TIMER),)
    assert deadline(t) == 1.0
    t.on_change(0.75)  # a send restarts the timer
    assert deadline(t) == 1.25
    assert t.on_timer(1.25).events == (TpdoDue(TpdoReason.TIMER),)


def test_event_timer_expiring_within_inhibit_waits_for_its_end():
    t = TpdoTrigger(254, inhibit_time_100us=5000, event_timer_ms=250)  # 500 ms inhibit
    t.start(0.0)
    t.on_change(0.125)
    assert deadline(t) == 0.375
    assert t.on_timer(0.375) is NOTHING  # timer expired inside the inhibit time
    assert deadline(t) == 0.625
    assert t.on_timer(0.625).events == (TpdoDue(TpdoReason.TIMER),)
    assert deadline(t) == 0.875


def test_pending_change_before_timer_keeps_its_reason():
    t = TpdoTrigger(254, inhibit_time_100us=2500, event_timer_ms=1000)
    t.start(0.0)
    t.on_change(0.0)
    assert t.on_change(0.125) is NOTHING  # within inhibit: pending
    assert t.on_rtr(0.15) is NOTHING  # still pending, one send only
    assert deadline(t) == 0.25
    assert t.on_timer(0.25).events == (TpdoDue(TpdoReason.EVENT),)
    assert deadline(t) == 1.25
    assert t.on_timer(1.0) is NOTHING


def test_stop_and_inactive_trigger():
    t = TpdoTrigger(254, event_timer_ms=100)
    assert t.on_change(0.0) is NOTHING and t.on_sync(1, 0.0) is NOTHING
    assert (t.on_timer(5.0), t.active) == (NOTHING, False)
    t.start(1.0)
    assert t.active is True
    assert deadline(t) == pytest.approx(1.1)
    t.stop()
    assert deadline(t) is None and t.on_timer(2.0) is NOTHING


def test_trigger_validation():
    with pytest.raises(PdoError, match="reserved"):
        TpdoTrigger(245)
    with pytest.raises(PdoError, match="inhibit"):
        TpdoTrigger(254, inhibit_time_100us=70000)
    with pytest.raises(PdoError, match="event timer"):
        TpdoTrigger(254, event_timer_ms=-1)
    with pytest.raises(PdoError, match="SYNC start value"):
        TpdoTrigger(3, sync_start_value=241)
    assert TpdoTrigger(TransmissionType(7)).transmission_type.every == 7


# --- RPDO watchdog ------------------------------------------------------------------------------


def test_rpdo_watchdog_times_out_once_and_resumes():
    w = RpdoWatchdog(0x201, 100)
    assert deadline(w) is None  # armed by the first RPDO
    assert w.on_frame(Frame(0x201, bytes(2)), 1.0) is NOTHING
    assert deadline(w) == pytest.approx(1.1)
    assert w.on_timer(1.05) is NOTHING
    assert w.on_timer(1.1).events == (RpdoTimeout(0x201),)
    assert (w.lost, deadline(w), w.on_timer(9.0)) == (True, None, NOTHING)
    assert w.on_frame(Frame(0x201, bytes(2)), 10.0).events == (RpdoResumed(0x201),)
    assert w.lost is False


def test_rpdo_length_checks():
    w = RpdoWatchdog(0x201, 100, length=4)
    out = w.on_frame(Frame(0x201, bytes(3)), 0.0)
    assert out.events == (RpdoTooShort(0x201, 4, 3),)
    assert deadline(w) is None  # not processed: not an arrival
    out = w.on_frame(Frame(0x201, bytes(6)), 0.0)
    assert out.events == (RpdoTooLong(0x201, 4, 6),)
    assert deadline(w) == pytest.approx(0.1)
    assert w.on_frame(Frame(0x201, bytes(4)), 0.05) is NOTHING
    assert w.on_timer(0.16).events == (RpdoTimeout(0x201),)
    out = w.on_frame(Frame(0x201, bytes(5)), 0.2)
    assert out.events == (RpdoResumed(0x201), RpdoTooLong(0x201, 4, 5))


def test_rpdo_watchdog_ignores_other_frames_and_reconfigures():
    w = RpdoWatchdog(0x1234, 0, extended=True)
    assert w.on_frame(Frame(0x1234, bytes(1), extended=True), 0.0) is NOTHING
    assert deadline(w) is None  # event timer 0: no watchdog
    assert w.on_frame(Frame(0x234, bytes(1)), 0.0) is NOTHING
    assert w.on_frame(Frame(0x1234, rtr=True, extended=True), 0.0) is NOTHING
    w.set_event_timer(50, 1.0)
    assert deadline(w) is None  # waits for the next RPDO
    w.on_frame(Frame(0x1234, bytes(1), extended=True), 2.0)
    w.set_event_timer(200, 2.1)  # running: restarts from now
    assert deadline(w) == pytest.approx(2.3)
    w.on_timer(2.3)
    w.set_event_timer(0, 3.0)
    assert (w.lost, deadline(w)) == (False, None)


def test_rpdo_watchdog_validation():
    with pytest.raises(PdoError, match="11-bit"):
        RpdoWatchdog(0x800)
    with pytest.raises(PdoError, match=r"0\.\.8 bytes"):
        RpdoWatchdog(0x201, length=9)
    with pytest.raises(PdoError, match="event timer"):
        RpdoWatchdog(0x201, 70000)


# ------------------------------------------------------------------ one rule, one order


def test_one_rule_says_which_kind_carries_a_data_type() -> None:
    from cobus.od import DataType
    from cobus.proto.pdo import kind_of_type

    assert kind_of_type(DataType.BOOLEAN) is Kind.BOOL
    assert kind_of_type(DataType.INTEGER24) is Kind.SIGNED
    assert kind_of_type(DataType.UNSIGNED64) is Kind.UNSIGNED
    assert kind_of_type(DataType.REAL32) is Kind.REAL32
    assert kind_of_type(DataType.REAL64) is Kind.REAL64
    assert kind_of_type(DataType.OCTET_STRING) is Kind.BYTES
    assert kind_of_type(DataType.DOMAIN) is Kind.BYTES
    for typed in (DataType.VISIBLE_STRING, DataType.TIME_OF_DAY, DataType.TIME_DIFFERENCE):
        assert kind_of_type(typed) is None  # (the caller's codec)


def test_writes_go_in_the_cia_301_order_whatever_order_they_are_made_in() -> None:
    from cobus.proto.pdo import REMAP_ORDER, RemapStep, in_remap_order

    assert REMAP_ORDER[0] is RemapStep.DISABLE and REMAP_ORDER[-1] is RemapStep.ENABLE
    made = [
        (RemapStep.DISABLE, "disable"),
        (RemapStep.COMMUNICATION, "type"),
        (RemapStep.COMMUNICATION, "timer"),
        (RemapStep.CLEAR_MAPPING, "clear"),
        (RemapStep.MAP, "entry 1"),
        (RemapStep.MAP, "entry 2"),
        (RemapStep.COUNT, "count"),
        (RemapStep.ENABLE, "enable"),
    ]
    assert in_remap_order(made) == [
        "disable", "clear", "entry 1", "entry 2", "count", "type", "timer", "enable"
    ]  # fmt: skip


def test_a_remote_pdo_is_saved_in_the_order_the_master_configures_one() -> None:
    from cobus.device import add_device
    from cobus.proto import Frame
    from cobus.runtime import Network
    from tests.test_master_support import io_od

    with Network(simulated=True) as net:
        add_device(net, 5, io_od())
        node = net.add_remote(5, io_od())
        written: list[tuple[int, int]] = []

        def request(frame: Frame, now: float) -> None:
            if frame.data[0] & 0xE0 == 0x20:  # download initiate
                written.append((int.from_bytes(frame.data[1:3], "little"), frame.data[3]))

        net.subscribe(0x605, request)
        tpdo = node.tpdo[1]
        tpdo.read()
        tpdo.clear()
        tpdo.add("Counter")
        tpdo.transmission_type = 1
        tpdo.event_timer = 50
        tpdo.save()
    assert written[:4] == [(0x1800, 1), (0x1A00, 0), (0x1A00, 1), (0x1A00, 0)]
    assert written[-1] == (0x1800, 1)
    assert {w for w in written[4:-1]} >= {(0x1800, 2), (0x1800, 5)}
    assert all(index == 0x1800 for index, _ in written[4:])
