"""The device's SDO server: access, type, length and limit checks with their abort codes,
application callbacks and notifications, extra SDO channels, and NMT gating."""

from __future__ import annotations

import asyncio
import math

import pytest

from cobus.device import (
    DeviceConfigError,
    DictionaryBuilder,
    EntryNotFoundError,
    EntryRefusedError,
    EntryWritten,
)
from cobus.od import Access, DataType, decode
from cobus.proto import Frame
from cobus.proto.sdo import SdoAbort, SdoAbortCode, SdoAbortedError, SdoTimeoutError
from cobus.runtime.remote import SdoChannel
from tests.test_device_support import NODE, Bench, run_bench, test_od


async def _abort(coro) -> int:
    with pytest.raises(SdoAbortedError) as err:
        await coro
    return int(err.value.code)


def test_reads_every_kind_of_entry_and_writes_take_effect():
    async def scenario(b: Bench):
        b.device.set(0x2006, 0, 21.5)
        assert await b.sdo.read(0x1000) == 0x191
        assert await b.sdo.read(0x1018, 0) == 4
        assert await b.sdo.read(0x1014) == 0x80 + NODE
        assert await b.sdo.read(0x1200, 1) == 0x600 + NODE
        assert await b.sdo.read(0x2003) == "pump"  # segmented
        assert await b.sdo.read(0x2005) == 42
        assert await b.sdo.read(0x2006) == 21.5
        await b.sdo.write(0x2001, 0, -12)
        await b.sdo.write(0x2003, 0, "a much longer pump name")
        await b.sdo.download(0x2008, 0, bytes(range(200)), block=True)
        await b.sdo.write(0x2007, 0, True)
        await b.sdo.write(0x6200, 2, 0xA5)
        assert b.device.get(0x2001) == -12
        assert b.device[0x2003].value == "a much longer pump name"
        assert b.device.get(0x2008) == bytes(range(200))
        assert b.device.get(0x2007) is True
        assert b.device[0x6200][2] == 0xA5
        assert b.device.get("Digital outputs", 2) == 0xA5
        assert await b.sdo.upload(0x2008, 0, block=True) == bytes(range(200))
        written = b.of(EntryWritten)
        assert [(e.index, e.subindex, e.value) for e in written] == [
            (0x2001, 0, -12),
            (0x2003, 0, "a much longer pump name"),
            (0x2008, 0, bytes(range(200))),
            (0x2007, 0, True),
            (0x6200, 2, 0xA5),
        ]
        assert all(e.node_id == NODE for e in written)

    run_bench(scenario)


_PLAIN = [
    DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER32, DataType.INTEGER64,
    DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32, DataType.UNSIGNED64,
    DataType.REAL32, DataType.REAL64, DataType.BOOLEAN, DataType.UNSIGNED24,
]  # fmt: skip


def test_a_download_of_each_type_stores_what_decode_gives_and_a_later_listener_hears_it():
    """Integers and reals without limits take the struct's unpacker, the rest the decoder:
    either way the value is what :func:`decode` gives; a network listener added after the
    device was built hears the write."""
    builder = DictionaryBuilder(device_name="types")
    for i, data_type in enumerate(_PLAIN):
        builder.variable(0x2100 + i, data_type.name, data_type)
    od = builder.build()

    async def scenario(b: Bench):
        heard: list[object] = []
        b.net.add_listener(heard.append)
        sent = {}
        for i, data_type in enumerate(_PLAIN):
            size = data_type.size or 0
            data = b"\x01" if data_type is DataType.BOOLEAN else bytes(range(0x81, 0x81 + size))
            await b.sdo.download(0x2100 + i, 0, data)  # expedited up to 4 bytes, else segmented
            sent[0x2100 + i] = decode(data_type, data)
        nan = b"\x00\x00\xc0\x7f"  # a REAL32 NaN: stored as it came
        await b.sdo.download(0x2108, 0, nan)
        assert math.isnan(b.device.get(0x2108))
        return sent, {e.index: e.value for e in heard if isinstance(e, EntryWritten)}, b

    sent, heard, b = run_bench(scenario, od)
    for index, value in sent.items():
        if index != 0x2108:
            assert b.device.get(index) == value
            assert type(b.device.get(index)) is type(value)
    assert set(heard) == set(sent)
    assert (
        heard[0x2103]
        == sent[0x2103]
        == int.from_bytes(bytes(range(0x81, 0x89)), "little", signed=True)
    )


def test_each_access_type_is_served_as_its_readable_and_writable_say():
    """The server tests access by identity (no property call per request): the same
    answers as Access.readable and Access.writable, for every access type."""
    builder = DictionaryBuilder(device_name="access")
    kinds = list(Access)
    for i, access in enumerate(kinds):
        builder.variable(0x2100 + i, access.name, DataType.UNSIGNED8, access=access.value)
    od = builder.build()

    async def scenario(b: Bench):
        for i, access in enumerate(kinds):
            index = 0x2100 + i
            if access.readable:
                assert await b.sdo.upload(index, 0) == b"\x00"
            else:
                assert await _abort(b.sdo.upload(index, 0)) == SdoAbortCode.READ_WRITE_ONLY
            if access.writable:
                await b.sdo.download(index, 0, b"\x07")
            else:
                assert await _abort(b.sdo.download(index, 0, b"\x07")) == (
                    SdoAbortCode.WRITE_READ_ONLY
                )

    run_bench(scenario, od)


def test_every_refusal_has_its_abort_code():
    async def scenario(b: Bench):
        sdo = b.sdo
        assert await _abort(sdo.upload(0x3000, 0)) == SdoAbortCode.NO_OBJECT
        assert await _abort(sdo.upload(0x1018, 9)) == SdoAbortCode.NO_SUBINDEX
        assert await _abort(sdo.download(0x2000, 1, b"\x00\x00")) == SdoAbortCode.NO_SUBINDEX
        assert await _abort(sdo.upload(0x2004, 0)) == SdoAbortCode.READ_WRITE_ONLY
        assert await _abort(sdo.download(0x2000, 0, b"\x01\x00")) == SdoAbortCode.WRITE_READ_ONLY
        assert await _abort(sdo.download(0x2005, 0, b"\x01\0\0\0")) == SdoAbortCode.WRITE_READ_ONLY
        assert await _abort(sdo.download(0x1000, 0, b"\x01\0\0\0")) == SdoAbortCode.WRITE_READ_ONLY
        # lengths: expedited and segmented
        assert await _abort(sdo.download(0x2001, 0, b"\x01")) == SdoAbortCode.LENGTH_TOO_LOW
        assert await _abort(sdo.download(0x2001, 0, b"\x01\0\0")) == SdoAbortCode.LENGTH_TOO_HIGH
        assert await _abort(sdo.download(0x2009, 0, bytes(9))) == SdoAbortCode.LENGTH_TOO_HIGH
        assert await _abort(sdo.download(0x2009, 0, bytes(5))) == SdoAbortCode.LENGTH_TOO_LOW
        # limits of 2001h: -1000..1000
        high = (1001).to_bytes(2, "little", signed=True)
        low = (-1001).to_bytes(2, "little", signed=True)
        assert await _abort(sdo.download(0x2001, 0, high)) == SdoAbortCode.VALUE_TOO_HIGH
        assert await _abort(sdo.download(0x2001, 0, low)) == SdoAbortCode.VALUE_TOO_LOW
        # a VISIBLE_STRING with a control character
        assert await _abort(sdo.download(0x2003, 0, b"bad\x07name")) == SdoAbortCode.INVALID_VALUE
        # nothing changed
        assert b.device.get(0x2001) == 0
        assert b.device.get(0x2003) == "pump"
        assert not b.of(EntryWritten)

    run_bench(scenario)


def test_application_callbacks_bind_values_and_may_refuse():
    async def scenario(b: Bench):
        device = b.device
        temperature = [20.0]
        device.on_read(0x2006, 0, lambda: temperature[0])
        received: list[int] = []

        def take(value: int) -> None:
            if value == 13:
                raise SdoAbort(SdoAbortCode.LOCAL_CONTROL, "13 is unlucky")
            received.append(value)

        device.on_write(0x2002, 0, take)
        assert await b.sdo.read(0x2006) == 20.0
        temperature[0] = 36.6
        assert await b.sdo.read(0x2006) == pytest.approx(36.6)
        assert device.get(0x2006) == pytest.approx(36.6)
        await b.sdo.write(0x2002, 0, 12)
        assert await _abort(b.sdo.write(0x2002, 0, 13)) == SdoAbortCode.LOCAL_CONTROL
        assert received == [12]
        assert device.get(0x2002) == 12
        # a failing callback is an abort 08000020, not a crash
        device.on_write(0x2002, 0, lambda v: 1 / 0)
        assert await _abort(b.sdo.write(0x2002, 0, 1)) == SdoAbortCode.CANNOT_STORE
        device.on_read(0x2006, 0, lambda: "not a float")
        assert await _abort(b.sdo.read(0x2006)) == SdoAbortCode.GENERAL_ERROR
        device.on_read(0x2006, 0, None)
        assert await b.sdo.read(0x2006) == 0.0
        with pytest.raises(DeviceConfigError):
            device.on_read(0x1017, 0, lambda: 5)

    run_bench(scenario)


def test_application_access_is_typed_and_checked():
    async def scenario(b: Bench):
        device = b.device
        with pytest.raises(EntryNotFoundError) as missing:
            device.get(0x3000)
        assert missing.value.code == SdoAbortCode.NO_OBJECT
        with pytest.raises(EntryNotFoundError) as missing:
            device.set(0x6000, 7, 1)
        assert missing.value.code == SdoAbortCode.NO_SUBINDEX
        with pytest.raises(EntryRefusedError) as refused:
            device.set(0x2001, 0, 5000)
        assert refused.value.code == SdoAbortCode.VALUE_TOO_HIGH
        with pytest.raises(EntryRefusedError) as refused:
            device.set(0x2002, 0, 256)
        assert refused.value.code == SdoAbortCode.VALUE_TOO_HIGH
        with pytest.raises(EntryRefusedError) as refused:
            device.set(0x2002, 0, "x")
        assert refused.value.code == SdoAbortCode.INVALID_VALUE
        with pytest.raises(EntryRefusedError) as refused:
            device.set(0x1001, 0, 1)
        assert refused.value.code == SdoAbortCode.UNSUPPORTED_ACCESS
        # the application owns its read-only entries
        device[0x2000][0] = 99
        assert await b.sdo.read(0x2000) == 99
        assert "0x2001:00" in str(EntryRefusedError(0x2001, 0, SdoAbortCode.VALUE_TOO_HIGH))

    run_bench(scenario)


def test_additional_sdo_channel_configured_by_sdo():
    async def scenario(b: Bench):
        sdo = b.sdo
        # 1201h: client->server 640h, server->client 5C0h; identifiers change only while invalid
        await sdo.write(0x1201, 1, 0x80000640)
        await sdo.write(0x1201, 2, 0x800005C0)
        await sdo.write(0x1201, 3, 0x10)
        await sdo.write(0x1201, 1, 0x640)
        await sdo.write(0x1201, 2, 0x5C0)
        assert await _abort(sdo.write(0x1201, 1, 0x641)) == SdoAbortCode.INVALID_VALUE
        assert await _abort(sdo.write(0x1201, 1, 0x20000641)) == SdoAbortCode.INVALID_VALUE
        assert await _abort(sdo.write(0x1200, 1, 0x601)) == SdoAbortCode.WRITE_READ_ONLY
        channel = SdoChannel(b.net, NODE, b.master.od, rx_cob_id=0x640, tx_cob_id=0x5C0)
        assert await channel.read(0x1018, 0) == 4
        await channel.write(0x2002, 0, 77)
        assert await sdo.read(0x2002) == 77
        # invalid again: the channel is gone
        await sdo.write(0x1201, 1, 0x80000640)
        fast = SdoChannel(b.net, NODE, b.master.od, rx_cob_id=0x640, tx_cob_id=0x5C0, timeout=0.1)
        with pytest.raises(SdoTimeoutError):
            await fast.read(0x1018, 0)

    run_bench(scenario, test_od(sdo_servers=2))


def test_sdo_is_silent_in_stopped_and_served_again_in_pre_operational():
    async def scenario(b: Bench):
        probe = SdoChannel(b.net, NODE, b.master.od, timeout=0.2)
        b.net.nmt.stop(NODE)
        await b.settle()
        start = b.net.time()
        with pytest.raises(SdoTimeoutError):
            await probe.read(0x1000)
        # nothing but the client's request and its abort went out on the SDO identifiers
        assert b.on(0x580 + NODE, since=start) == []
        b.net.nmt.enter_preoperational(NODE)
        await b.settle()
        assert await probe.read(0x1000) == 0x191

    run_bench(scenario)


def test_store_eds_is_readable_by_block_upload():
    async def scenario(b: Bench):
        assert await b.sdo.read(0x1022) == 0
        data = await b.sdo.upload(0x1021, 0, block=True)
        text = data.decode("utf-8")
        assert text.startswith("[FileInfo]\r\n")
        assert "[MandatoryObjects]" in text and "\r\n1=0x1000\r\n" in text
        assert "DefaultValue=$NODEID+0x80" in text
        assert await b.sdo.upload(0x1021, 0) == data  # segmented gives the same
        assert await _abort(b.sdo.download(0x1021, 0, b"x")) == SdoAbortCode.WRITE_READ_ONLY

    run_bench(scenario)


def test_an_access_changed_while_the_device_runs_applies_to_the_next_request():
    async def scenario(b: Bench):
        await b.sdo.write(0x2002, 0, 7)
        var = b.device.od.get_variable(0x2002, 0)
        assert var is not None
        var.access = Access.RO  # the application locks the parameter
        assert await _abort(b.sdo.write(0x2002, 0, 8)) == SdoAbortCode.WRITE_READ_ONLY
        var.access = Access.WO
        assert await _abort(b.sdo.read(0x2002)) == SdoAbortCode.READ_WRITE_ONLY
        var.access = Access.RW
        await b.sdo.write(0x2002, 0, 9)
        assert await b.sdo.read(0x2002) == 9

    run_bench(scenario)


def _listened(b: Bench) -> bool:
    return b.net.listened  # through a call, so that mypy does not narrow it across steps


def test_entry_written_reaches_whoever_listens_when_the_write_comes():
    """The event is built only when somebody would see it: nobody, the device's listeners,
    the network's, added and removed while the device runs."""

    async def scenario(b: Bench):
        b.net.remove_listener(b.events.append)
        assert not _listened(b)
        await b.sdo.write(0x2001, 0, 1)  # heard by nobody
        mine: list[object] = []
        b.device.add_listener(mine.append)
        await b.sdo.write(0x2001, 0, 2)
        b.device.remove_listener(mine.append)
        b.net.add_listener(b.events.append)
        assert _listened(b)
        await b.sdo.write(0x2001, 0, 3)
        assert [e for e in mine if isinstance(e, EntryWritten)] == [
            EntryWritten(NODE, 0x2001, 0, 2)
        ]
        assert b.of(EntryWritten) == [EntryWritten(NODE, 0x2001, 0, 3)]
        assert b.device.get(0x2001) == 3

    run_bench(scenario)


def test_a_download_announcing_more_than_the_limit_is_refused_at_once():
    """0xFFFFFFFF announced into a DOMAIN kept the device buffering (21 MB, no abort): now
    05040005 at the initiate; the limit is 1 MiB unless set per object."""

    async def scenario(b: Bench):
        huge = bytes((0x21, 0x08, 0x20, 0, 0xFF, 0xFF, 0xFF, 0xFF))  # segmented, size 4 GiB-1
        since = b.net.time()
        b.net.send(Frame(0x600 + NODE, huge))
        await asyncio.sleep(0.01)
        (answer,) = b.data(0x580 + NODE, since=since)
        assert answer == bytes((0x80, 0x08, 0x20, 0, 0x05, 0x00, 0x04, 0x05))
        await b.sdo.download(0x2008, 0, bytes(1 << 20))  # 1 MiB: taken
        b.device.limit_download("Blob", 0, 100)
        assert await _abort(b.sdo.download(0x2008, 0, bytes(101))) == SdoAbortCode.OUT_OF_MEMORY
        await b.sdo.download(0x2008, 0, bytes(100), block=True)
        assert b.device.get(0x2008) == bytes(100)
        with pytest.raises(ValueError, match="UNSIGNED32 of 4 bytes"):
            b.device.limit_download(0x200A, 0, 100)

    run_bench(scenario)


def test_a_device_wide_download_limit_takes_a_bigger_image():
    """A device taking program images (1F50h style) raises the limit for all its domains."""

    async def scenario(b: Bench):
        await b.sdo.download(0x2008, 0, bytes(3 << 20), block=True)  # 3 MiB, announced
        assert len(b.device.get(0x2008)) == 3 << 20
        assert await _abort(b.sdo.download(0x2008, 0, bytes((4 << 20) + 1))) == (
            SdoAbortCode.OUT_OF_MEMORY
        )

    run_bench(scenario, sdo_max_download=4 << 20)
    with pytest.raises(DeviceConfigError, match="sdo_max_download -1"):
        run_bench(scenario, sdo_max_download=-1)
