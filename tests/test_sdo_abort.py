"""SDO abort codes, their texts, the SDO errors and the block CRC."""

from __future__ import annotations

from binascii import crc_hqx

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cobus.errors import CobusError
from cobus.proto.sdo import (
    BECKHOFF_ABORT_TEXTS,
    SdoAbort,
    SdoAbortCode,
    SdoAbortedError,
    SdoBusyError,
    SdoError,
    SdoParameterError,
    SdoProtocolError,
    SdoTimeoutError,
    as_code,
    crc16,
    describe,
)
from cobus.proto.sdo.crc import CRC16_TABLE, crc16_table

# Every abort code of CiA 301 (the standard's table), value by value.
CIA301 = {
    0x05030000,
    0x05040000,
    0x05040001,
    0x05040002,
    0x05040003,
    0x05040004,
    0x05040005,
    0x06010000,
    0x06010001,
    0x06010002,
    0x06020000,
    0x06040041,
    0x06040042,
    0x06040043,
    0x06040047,
    0x06060000,
    0x06070010,
    0x06070012,
    0x06070013,
    0x06090011,
    0x06090030,
    0x06090031,
    0x06090032,
    0x06090036,
    0x060A0023,
    0x08000000,
    0x08000020,
    0x08000021,
    0x08000022,
    0x08000023,
    0x08000024,
}


def test_every_cia301_code_is_a_member_with_a_text() -> None:
    assert {int(code) for code in SdoAbortCode} == CIA301
    for code in SdoAbortCode:
        assert code.text and code.text == describe(code)
        assert str(code) == f"0x{int(code):08X} {code.text}"


@pytest.mark.parametrize(
    ("code", "text"),
    [
        (0x05030000, "toggle bit not alternated"),
        (0x05040000, "SDO protocol timed out"),
        (0x05040001, "client/server command specifier not valid or unknown"),
        (0x05040004, "CRC error (block mode only)"),
        (0x06020000, "object does not exist in the object dictionary"),
        (0x06090011, "sub-index does not exist"),
        (0x08000022, "data cannot be transferred or stored to the application because of the "
         "present device state"),
    ],
)  # fmt: skip
def test_standard_texts(code: int, text: str) -> None:
    assert describe(code) == text
    assert SdoAbortCode(code).text == text


def test_manufacturer_codes_are_described_only_from_a_table() -> None:
    assert set(BECKHOFF_ABORT_TEXTS) == {
        0x06020011,
        0x06020010,
        0x06010022,
        0x06070043,
        0x06010021,
        0x05040040,
        0x06060021,
        0x06090010,
        0x05040047,
    }
    assert describe(0x05040047) == (
        "manufacturer-specific or unknown abort code (see the device's manual)"
    )
    assert describe(0x05040047, BECKHOFF_ABORT_TEXTS) == (
        "timeout communicating with a terminal (manufacturer-specific)"
    )
    # a manufacturer table never hides a standard text
    assert describe(0x06020000, {0x06020000: "other"}) == SdoAbortCode.NO_OBJECT.text


@given(st.integers())
def test_any_int_has_a_text(code: int) -> None:
    text = describe(code)
    assert text
    if not 0 <= code <= 0xFFFFFFFF:
        assert "not a 32-bit value" in text


def test_as_code_keeps_unknown_values() -> None:
    assert as_code(0x06020000) is SdoAbortCode.NO_OBJECT
    assert as_code(0x12345678) == 0x12345678
    assert not isinstance(as_code(0x12345678), SdoAbortCode)


# -- errors ------------------------------------------------------------------------------------


def test_every_sdo_error_is_a_cobus_error() -> None:
    for cls in (
        SdoAbortedError,
        SdoBusyError,
        SdoParameterError,
        SdoProtocolError,
        SdoTimeoutError,
    ):
        assert issubclass(cls, SdoError)
        assert issubclass(cls, CobusError)
    assert issubclass(SdoParameterError, ValueError)


def test_aborted_error_message_names_code_object_node_and_text() -> None:
    error = SdoAbortedError(0x06020000, index=0x2000, subindex=0, node=5)
    assert str(error) == (
        "SDO abort 0x06020000 on 0x2000:00 (node 5): object does not exist in the object "
        "dictionary (check the index against the device's EDS)"
    )
    assert error.code is SdoAbortCode.NO_OBJECT
    assert (error.index, error.subindex, error.node, error.by_peer) == (0x2000, 0, 5, True)


def test_aborted_error_without_node_names_the_channel() -> None:
    error = SdoAbortedError(0x1234, index=0x1000, subindex=3, channel="0x620/0x5A0")
    assert str(error).startswith("SDO abort 0x00001234 on 0x1000:03 (SDO 0x620/0x5A0): ")
    assert error.code == 0x1234


def test_aborted_error_with_a_hint() -> None:
    error = SdoAbortedError(0x08000000, index=1, subindex=2, node=3, hint="try later")
    assert str(error).endswith("general error (try later)")


def test_protocol_error_says_why_and_which_abort_was_sent() -> None:
    error = SdoProtocolError(0x05030000, "segment with toggle 1", index=0x2000, subindex=1, node=9)
    text = str(error)
    assert text.startswith("SDO protocol error on 0x2000:01 (node 9): segment with toggle 1;")
    assert "aborted with 0x05030000 (toggle bit not alternated)" in text
    assert error.code is SdoAbortCode.TOGGLE_BIT and error.reason == "segment with toggle 1"


def test_timeout_error_says_what_to_check() -> None:
    error = SdoTimeoutError(index=0x1018, subindex=1, timeout=0.5, node=12)
    assert "0x1018:01 (node 12)" in str(error) and "0.5 s" in str(error)
    assert "bit rate" in str(error)


def test_sdo_abort_carries_the_code() -> None:
    refusal = SdoAbort(SdoAbortCode.VALUE_TOO_HIGH)
    assert refusal.code is SdoAbortCode.VALUE_TOO_HIGH
    assert str(refusal) == "0x06090031: value of parameter written too high (download only)"
    assert not isinstance(refusal, CobusError)
    assert str(SdoAbort(0x06090030, "must be even")) == "0x06090030: must be even"
    with pytest.raises(SdoParameterError, match="32 bits"):
        SdoAbort(-1)


# -- CRC ---------------------------------------------------------------------------------------


def test_crc_check_value() -> None:
    # CRC-16-CCITT with initial value 0 (XMODEM): the check value of "123456789" is 31C3h.
    assert crc16(b"123456789") == 0x31C3
    assert crc16_table(b"123456789") == 0x31C3
    assert crc16(b"") == 0 == crc16_table(b"")


def test_crc_table() -> None:
    assert len(CRC16_TABLE) == 256
    assert CRC16_TABLE[0] == 0 and CRC16_TABLE[1] == 0x1021 and CRC16_TABLE[0x80] == 0x9188


@given(st.binary(max_size=300), st.binary(max_size=50))
def test_fast_crc_is_the_table_crc_and_continues(first: bytes, second: bytes) -> None:
    assert crc16(first) == crc16_table(first) == crc_hqx(first, 0)
    assert crc16(second, crc16(first)) == crc16(first + second)
    assert crc16_table(second, crc16_table(first)) == crc16_table(first + second)
