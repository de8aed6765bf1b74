"""CiA 301 basic data types: properties, exact codecs, and the errors of bad values."""

import datetime as dt
import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cobus.errors import CobusError
from cobus.od import (
    DataLengthError,
    DataType,
    DataTypeError,
    TimeDifference,
    TimeOfDay,
    ValueRangeError,
    codec,
    decode,
    encode,
    struct_unpacker,
)

D = DataType
INTEGERS = [d for d in D if d.is_integer]
FAST = settings(max_examples=60, deadline=None)


def test_enum_numbers_are_the_cia_301_indices():
    expected = {
        "BOOLEAN": 0x01,
        "INTEGER8": 0x02,
        "INTEGER16": 0x03,
        "INTEGER32": 0x04,
        "UNSIGNED8": 0x05,
        "UNSIGNED16": 0x06,
        "UNSIGNED32": 0x07,
        "REAL32": 0x08,
        "VISIBLE_STRING": 0x09,
        "OCTET_STRING": 0x0A,
        "UNICODE_STRING": 0x0B,
        "TIME_OF_DAY": 0x0C,
        "TIME_DIFFERENCE": 0x0D,
        "DOMAIN": 0x0F,
        "INTEGER24": 0x10,
        "REAL64": 0x11,
        "INTEGER40": 0x12,
        "INTEGER48": 0x13,
        "INTEGER56": 0x14,
        "INTEGER64": 0x15,
        "UNSIGNED24": 0x16,
        "UNSIGNED40": 0x18,
        "UNSIGNED48": 0x19,
        "UNSIGNED56": 0x1A,
        "UNSIGNED64": 0x1B,
    }
    assert {d.name: int(d) for d in D} == expected


def test_properties():
    assert D.BOOLEAN.bit_length == 1 and D.BOOLEAN.size == 1
    assert D.INTEGER24.bit_length == 24 and D.UNSIGNED56.bit_length == 56
    assert D.TIME_OF_DAY.bit_length == 48 and D.REAL64.bit_length == 64
    for d in (D.VISIBLE_STRING, D.OCTET_STRING, D.UNICODE_STRING, D.DOMAIN):
        assert d.bit_length is None and d.size is None
    assert len(INTEGERS) == 16
    assert not D.BOOLEAN.is_integer and not D.REAL32.is_integer
    assert {d for d in D if d.is_signed} == {d for d in INTEGERS if d.name.startswith("INT")}
    assert {d for d in D if d.is_string} == {D.VISIBLE_STRING, D.OCTET_STRING, D.UNICODE_STRING}
    assert D.REAL32.is_real and not D.INTEGER8.is_real
    assert D.INTEGER40.range == (-(2**39), 2**39 - 1)
    assert D.UNSIGNED48.range == (0, 2**48 - 1)
    assert D.DOMAIN.range is None


def _range(d: DataType) -> tuple[int, int]:
    r = d.range
    assert r is not None
    return r


@pytest.mark.parametrize("d", INTEGERS, ids=lambda d: d.name)
@FAST
@given(data=st.data())
def test_integer_round_trip(d, data):
    lo, hi = _range(d)
    value = data.draw(st.integers(lo, hi))
    raw = encode(d, value)
    assert len(raw) == d.bit_length // 8
    assert raw == value.to_bytes(len(raw), "little", signed=d.is_signed)
    assert decode(d, raw) == value


@pytest.mark.parametrize("d", INTEGERS, ids=lambda d: d.name)
@FAST
@given(data=st.data())
def test_integer_out_of_range_is_refused(d, data):
    lo, hi = _range(d)
    value = data.draw(st.one_of(st.integers(max_value=lo - 1), st.integers(min_value=hi + 1)))
    with pytest.raises(ValueRangeError) as info:
        encode(d, value)
    message = str(info.value)
    assert d.name in message and f"{lo}..{hi}" in message and str(value) in message


@pytest.mark.parametrize("d", INTEGERS, ids=lambda d: d.name)
def test_integer_wrong_type_and_length(d):
    with pytest.raises(ValueRangeError, match=f"{d.name} needs an integer"):
        encode(d, 1.5)
    with pytest.raises(ValueRangeError, match="needs an integer"):
        encode(d, "1")
    size = d.bit_length // 8
    with pytest.raises(DataLengthError, match=f"{d.name} takes {size} byte.*got {size + 1}"):
        decode(d, bytes(size + 1))


def test_integer_boundaries_and_sign():
    assert encode(D.INTEGER24, -1) == b"\xff\xff\xff"
    assert decode(D.INTEGER24, b"\x00\x00\x80") == -(2**23)
    assert decode(D.UNSIGNED40, b"\xff" * 5) == 2**40 - 1
    assert encode(D.INTEGER56, -(2**55)) == b"\x00" * 6 + b"\x80"
    assert encode(D.UNSIGNED16, True) == b"\x01\x00"  # bool is an int


class _Index:
    def __index__(self) -> int:
        return 7


def test_integer_accepts_index_types():
    assert encode(D.UNSIGNED8, _Index()) == b"\x07"
    assert encode(D.INTEGER24, _Index()) == b"\x07\x00\x00"


@FAST
@given(st.booleans())
def test_boolean_round_trip(value):
    assert decode(D.BOOLEAN, encode(D.BOOLEAN, value)) is value


def test_boolean_details():
    assert encode(D.BOOLEAN, 1) == b"\x01" and encode(D.BOOLEAN, 0) == b"\x00"
    assert decode(D.BOOLEAN, b"\xff") is True  # any non-zero byte is true
    with pytest.raises(ValueRangeError, match="BOOLEAN needs True/False"):
        encode(D.BOOLEAN, 2)
    with pytest.raises(DataLengthError, match="BOOLEAN takes 1 byte; got 2"):
        decode(D.BOOLEAN, b"\x00\x00")


@FAST
@given(st.floats(width=32))
def test_real32_round_trip(value):
    back = decode(D.REAL32, encode(D.REAL32, value))
    assert math.isnan(back) if math.isnan(value) else back == value


@FAST
@given(st.floats())
def test_real64_round_trip(value):
    raw = encode(D.REAL64, value)
    assert raw == struct.pack("<d", value)
    back = decode(D.REAL64, raw)
    assert math.isnan(back) if math.isnan(value) else back == value


def test_real_details():
    assert encode(D.REAL32, 1) == struct.pack("<f", 1.0)  # ints are accepted
    assert math.isinf(decode(D.REAL32, encode(D.REAL32, math.inf)))
    with pytest.raises(ValueRangeError, match="out of range for REAL32"):
        encode(D.REAL32, 1e39)
    with pytest.raises(ValueRangeError, match="out of range for REAL64"):
        encode(D.REAL64, 10**400)
    with pytest.raises(ValueRangeError, match="REAL32 needs a float"):
        encode(D.REAL32, "1.0")
    with pytest.raises(ValueRangeError, match="REAL64 needs a float"):
        encode(D.REAL64, True)
    with pytest.raises(DataLengthError, match="REAL64 takes 8 bytes; got 4"):
        decode(D.REAL64, b"\x00" * 4)


VISIBLE = st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E))


@FAST
@given(VISIBLE)
def test_visible_string_round_trip(value):
    raw = encode(D.VISIBLE_STRING, value)
    assert raw == value.encode("ascii")
    assert decode(D.VISIBLE_STRING, raw) == value


def test_visible_string_details():
    assert decode(D.VISIBLE_STRING, b"Gen4\x00\x00") == "Gen4"  # C padding is not the value
    with pytest.raises(ValueRangeError, match=r"visible ASCII .*'ä' \(U\+00E4\)"):
        encode(D.VISIBLE_STRING, "Gerät")
    with pytest.raises(ValueRangeError, match="VISIBLE_STRING needs a str"):
        encode(D.VISIBLE_STRING, b"abc")


UNICODE = st.text(alphabet=st.characters(blacklist_characters="\x00"))


@FAST
@given(UNICODE)
def test_unicode_string_round_trip(value):
    raw = encode(D.UNICODE_STRING, value)
    assert decode(D.UNICODE_STRING, raw) == value


def test_unicode_string_details():
    assert encode(D.UNICODE_STRING, "Aé") == b"A\x00\xe9\x00"
    assert decode(D.UNICODE_STRING, b"A\x00\x00\x00") == "A"
    with pytest.raises(ValueRangeError, match="cannot contain NUL"):
        encode(D.UNICODE_STRING, "a\x00b")
    with pytest.raises(DataLengthError, match="even number of bytes"):
        decode(D.UNICODE_STRING, b"A\x00B")


@pytest.mark.parametrize("d", [D.OCTET_STRING, D.DOMAIN], ids=lambda d: d.name)
@FAST
@given(value=st.binary(max_size=64))
def test_octets_round_trip(d, value):
    assert decode(d, encode(d, value)) == value
    assert encode(d, bytearray(value)) == value


def test_octets_refuse_text():
    with pytest.raises(ValueRangeError, match="OCTET_STRING needs bytes, got str"):
        encode(D.OCTET_STRING, "00ff")


@FAST
@given(st.integers(0, 0xFFFF), st.integers(0, 86_399_999))
def test_time_of_day_round_trip(days, ms):
    value = TimeOfDay(days, ms)
    raw = encode(D.TIME_OF_DAY, value)
    assert raw == ms.to_bytes(4, "little") + days.to_bytes(2, "little")
    assert decode(D.TIME_OF_DAY, raw) == value


@FAST
@given(st.integers(0, 0xFFFF), st.integers(0, 0x0FFFFFFF))
def test_time_difference_round_trip(days, ms):
    value = TimeDifference(days, ms)
    assert decode(D.TIME_DIFFERENCE, encode(D.TIME_DIFFERENCE, value)) == value


def test_time_details():
    noon = dt.datetime(1985, 1, 1, 12, 0, 0, 250_000)
    value = decode(D.TIME_OF_DAY, encode(D.TIME_OF_DAY, noon))
    assert value == TimeOfDay(366, 43_200_250) and value.to_datetime() == noon
    span = dt.timedelta(days=2, seconds=1)
    assert decode(D.TIME_DIFFERENCE, encode(D.TIME_DIFFERENCE, span)).to_timedelta() == span
    # The 4 reserved bits above the 28-bit milliseconds are ignored.
    assert decode(D.TIME_OF_DAY, b"\x00\x00\x00\xf0\x01\x00") == TimeOfDay(1, 0)
    with pytest.raises(ValueRangeError, match="milliseconds after midnight must be in"):
        encode(D.TIME_OF_DAY, TimeOfDay(0, 86_400_000))
    with pytest.raises(ValueRangeError, match=r"days must be in 0\.\.65535"):
        encode(D.TIME_DIFFERENCE, TimeDifference(70_000, 0))
    with pytest.raises(ValueRangeError, match="TIME_OF_DAY needs a TimeOfDay or datetime"):
        encode(D.TIME_OF_DAY, 5)
    with pytest.raises(DataLengthError, match="TIME_OF_DAY takes 6 bytes; got 4"):
        decode(D.TIME_OF_DAY, bytes(4))


def test_unknown_data_type():
    with pytest.raises(DataTypeError, match="0x0040 is not a CiA 301 basic data type"):
        encode(0x40, 1)
    with pytest.raises(DataTypeError, match="0x000E"):
        decode(0x0E, b"")
    assert encode(7, 1) == b"\x01\x00\x00\x00"  # plain ints work as data types


def test_errors_are_typed():
    for cls in (ValueRangeError, DataLengthError, DataTypeError):
        assert issubclass(cls, CobusError) and issubclass(cls, ValueError)


@pytest.mark.parametrize("data_type", list(D))
def test_codec_gives_what_encode_and_decode_call(data_type):
    enc, dec = codec(data_type)
    for value in (0, 1, True, 1.5, "ab", b"ab", TimeOfDay(1, 2), TimeDifference(3, 4)):
        try:
            expected = encode(data_type, value)
        except CobusError as exc:
            with pytest.raises(type(exc)):
                enc(value)
            continue
        assert enc(value) == expected
        assert dec(expected) == decode(data_type, expected)


_STRUCT_TYPES = {
    D.INTEGER8, D.INTEGER16, D.INTEGER32, D.INTEGER64,
    D.UNSIGNED8, D.UNSIGNED16, D.UNSIGNED32, D.UNSIGNED64,
    D.REAL32, D.REAL64,
}  # fmt: skip


@pytest.mark.parametrize("data_type", list(D))
def test_struct_unpacker_decodes_what_decode_decodes_and_only_where_nothing_can_fail(data_type):
    unpack = struct_unpacker(data_type)
    if data_type not in _STRUCT_TYPES:  # a decoder that checks more than the length
        assert unpack is None
        return
    assert unpack is not None
    size = data_type.size
    for data in (
        bytes(size),
        b"\xff" * size,
        bytes(range(1, size + 1)),
        b"\x00" * (size - 1) + b"\x80",
    ):
        (value,) = unpack(data)
        expected = decode(data_type, data)
        assert value == expected or (math.isnan(value) and math.isnan(expected))
        assert type(value) is type(expected)


def test_struct_unpacker_of_an_unknown_type_is_none():
    assert struct_unpacker(0x1234) is None


@pytest.mark.parametrize("unknown", [0x0020, 0x1234, -1])
def test_codec_of_an_unknown_type_is_refused_as_encode_refuses_it(unknown):
    with pytest.raises(DataTypeError) as by_codec:
        codec(unknown)
    with pytest.raises(DataTypeError) as by_encode:
        encode(unknown, 0)
    assert str(by_codec.value) == str(by_encode.value)
