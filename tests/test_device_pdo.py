"""PDOs driven by the device: every transmission type, inhibit time and event timer, RPDOs
applied at once or at the next SYNC, the arrival watchdog, length errors, and mapping changes
by SDO with their consistency aborts."""

from __future__ import annotations

import struct

import pytest

from cobus.device import (
    ConfigurationProblem,
    DeviceConfigError,
    DictionaryBuilder,
    RpdoLost,
    RpdoReceived,
    RpdoRestored,
    WrongLengthRpdoReceived,
    minimal_od,
)
from cobus.od import DataType, Variable
from cobus.proto.pdo import PdoMap
from cobus.proto.sdo import SdoAbort, SdoAbortCode, SdoAbortedError
from tests.test_device_support import NODE, Bench, run_bench

TPDO1 = 0x180 + NODE
TPDO2 = 0x280 + NODE
RPDO1 = 0x200 + NODE
EMCY = 0x80 + NODE


async def _abort(coro) -> int:
    with pytest.raises(SdoAbortedError) as err:
        await coro
    return int(err.value.code)


def _entry(index: int, sub: int, bits: int) -> int:
    return index << 16 | sub << 8 | bits


async def configure_tpdo(
    b: Bench,
    number: int,
    entries: list[int],
    tt: int,
    *,
    inhibit: int = 0,
    timer: int = 0,
    start: int = 0,
    cob_id: int | None = None,
) -> None:
    """The CiA 301 procedure: disable, clear the count, entries, count, parameters, enable."""
    comm, mapping = 0x1800 + number - 1, 0x1A00 + number - 1
    sdo = b.sdo
    current = await sdo.read(comm, 1)
    can_id = (current & 0x7FF) if cob_id is None else cob_id
    await sdo.write(comm, 1, can_id | 0x80000000)
    await sdo.write(mapping, 0, 0)
    for sub, value in enumerate(entries, 1):
        await sdo.write(mapping, sub, value)
    await sdo.write(mapping, 0, len(entries))
    await sdo.write(comm, 2, tt)
    await sdo.write(comm, 3, inhibit)
    await sdo.write(comm, 5, timer)
    await sdo.write(comm, 6, start)
    await sdo.write(comm, 1, can_id)


async def configure_rpdo(
    b: Bench, number: int, entries: list[int], tt: int, *, timer: int = 0
) -> None:
    comm, mapping = 0x1400 + number - 1, 0x1600 + number - 1
    sdo = b.sdo
    can_id = await sdo.read(comm, 1) & 0x7FF
    await sdo.write(comm, 1, can_id | 0x80000000)
    await sdo.write(mapping, 0, 0)
    for sub, value in enumerate(entries, 1):
        await sdo.write(mapping, sub, value)
    await sdo.write(mapping, 0, len(entries))
    await sdo.write(comm, 2, tt)
    await sdo.write(comm, 5, timer)
    await sdo.write(comm, 1, can_id)


COUNTER = _entry(0x2000, 0, 16)
INPUT1 = _entry(0x6000, 1, 8)
SETPOINT = _entry(0x2001, 0, 16)
OUTPUT2 = _entry(0x6200, 2, 8)


def test_cyclic_tpdo_every_third_sync():
    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [COUNTER, INPUT1], 3)
        await b.start()
        for n in range(1, 10):
            b.device.set(0x2000, 0, n)
            b.device.set(0x6000, 1, 0x10 + n)
            await b.sync()
        assert b.data(TPDO1) == [
            bytes.fromhex("0300 13"),
            bytes.fromhex("0600 16"),
            bytes.fromhex("0900 19"),
        ]

    run_bench(scenario)


def test_cyclic_tpdo_waits_for_its_sync_start_value():
    async def scenario(b: Bench):
        await b.sdo.write(0x1019, 0, 5)
        await configure_tpdo(b, 1, [INPUT1], 2, start=3)
        await b.start()
        sent_at = []
        for counter in (4, 5, 1, 2, 3, 4, 5, 1, 2, 3):
            before = len(b.data(TPDO1))
            await b.sync(counter)
            if len(b.data(TPDO1)) > before:
                sent_at.append(counter)
        assert sent_at == [3, 5, 2]
        # the start value cannot change while the PDO is valid
        assert await _abort(b.sdo.write(0x1800, 6, 1)) == SdoAbortCode.INVALID_VALUE

    run_bench(scenario)


def test_acyclic_synchronous_tpdo_only_after_a_change():
    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [COUNTER], 0)
        await b.start()
        await b.sync()
        b.device.set(0x2000, 0, 1)
        b.device.set(0x2000, 0, 2)
        assert b.data(TPDO1) == []  # not before the SYNC
        await b.sync()
        await b.sync()
        b.device.set(0x2000, 0, 2)  # the same value: no change
        await b.sync()
        b.device.set(0x2000, 0, 3)
        await b.sync()
        assert b.data(TPDO1) == [b"\x02\x00", b"\x03\x00"]

    run_bench(scenario)


def test_event_driven_tpdo_throttled_by_the_inhibit_time():
    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [COUNTER], 255, inhibit=100)  # 10 ms
        await b.start()
        await b.net.sleep(1.0)
        t0 = b.net.time()
        history = []
        for n in range(1, 26):  # a new value every millisecond for 25 ms
            b.device.set(0x2000, 0, n)
            history.append((b.net.time(), n))
            await b.net.sleep(0.0015 if n == 1 else 0.001)  # off the inhibit time's grid
        await b.net.sleep(0.05)
        sent = [(t, struct.unpack("<H", f.data)[0]) for t, f in b.on(TPDO1)]
        # first at once, then one per inhibit time, each with the newest value at that moment
        assert [round(t - t0, 6) for t, _ in sent] == [0.0, 0.01, 0.02, 0.03]
        for t, value in sent:
            assert value == max(n for when, n in history if when <= t)
        assert sent[-1][1] == 25

    run_bench(scenario)


def test_event_timer_sends_without_change_and_restarts_on_change():
    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [INPUT1], 254, timer=50)
        await b.start()
        t0 = b.net.time()
        await b.net.sleep(0.12)
        b.device.set(0x6000, 1, 7)
        await b.net.sleep(0.11)
        times = [round(t - t0, 6) for t in b.times(TPDO1)]
        assert times == [0.05, 0.1, 0.12, 0.17, 0.22]
        assert b.data(TPDO1) == [b"\x00", b"\x00", b"\x07", b"\x07", b"\x07"]
        # the event timer takes effect at once, also while the PDO is valid
        await b.sdo.write(0x1800, 5, 0)
        count = len(b.data(TPDO1))
        await b.net.sleep(0.5)
        assert len(b.data(TPDO1)) == count

    run_bench(scenario)


def test_rtr_only_tpdos():
    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [COUNTER], 253)
        await configure_tpdo(b, 2, [INPUT1], 252)
        await b.start()
        b.device.set(0x2000, 0, 0x1234)
        b.device.set(0x6000, 1, 1)
        await b.settle()
        assert b.data(TPDO1) == [] and b.data(TPDO2) == []
        b.send(TPDO1, rtr=True)
        await b.settle()
        assert b.data(TPDO1) == [b"\x34\x12"]
        await b.sync()  # type 252 samples at SYNC ...
        b.device.set(0x6000, 1, 2)
        b.send(TPDO2, rtr=True)  # ... and sends the sample on request
        await b.settle()
        assert b.data(TPDO2) == [b"\x01"]
        # bit 30: no RTR allowed
        await b.sdo.write(0x1800, 1, 0x80000000 | TPDO1)
        await b.sdo.write(0x1800, 1, 0x40000000 | TPDO1)
        b.send(TPDO1, rtr=True)
        await b.settle()
        assert len(b.data(TPDO1)) == 1

    run_bench(scenario)


def test_no_pdos_outside_operational():
    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [COUNTER], 255, timer=10)
        await configure_rpdo(b, 1, [SETPOINT], 255)
        b.device.set(0x2000, 0, 5)
        b.send(RPDO1, b"\x01\x00")
        await b.net.sleep(0.05)
        assert b.data(TPDO1) == [] and b.device.get(0x2001) == 0
        await b.start()
        await b.net.sleep(0.025)
        assert len(b.data(TPDO1)) == 2
        b.net.nmt.stop(NODE)
        await b.settle()
        b.send(RPDO1, b"\x02\x00")
        b.device.set(0x2000, 0, 6)
        await b.net.sleep(0.05)
        assert len(b.data(TPDO1)) == 2 and b.device.get(0x2001) == 0

    run_bench(scenario)


def test_rpdo_applied_at_once_and_notifies_the_application():
    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT, _entry(0x0005, 0, 8), OUTPUT2], 255)
        seen = []
        b.device.on_write(0x6200, 2, seen.append)
        await b.start()
        b.send(RPDO1, bytes.fromhex("f6ff 99 42"))
        await b.settle()
        assert b.device.get(0x2001) == -10
        assert b.device.get(0x6200, 2) == 0x42
        assert seen == [0x42]
        assert b.of(RpdoReceived) == [
            RpdoReceived(NODE, 1, ((0x2001, 0), (0x6200, 2)), (-10, 0x42))
        ]
        # a value outside the entry's limits is dropped, the others are applied
        b.send(RPDO1, bytes.fromhex("e803 00 43"))  # 1000 is allowed
        b.send(RPDO1, bytes.fromhex("e903 00 44"))  # 1001 is not
        await b.settle()
        assert b.device.get(0x2001) == 1000
        assert b.device.get(0x6200, 2) == 0x44

    run_bench(scenario)


def test_rpdo_values_apply_with_nobody_listening_and_a_later_listener_hears_them():
    """With no listener no RpdoReceived is built, yet every value is applied, and a TPDO
    mapping a written entry still sees the change; a listener added later hears the next."""

    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT, _entry(0x0005, 0, 8), OUTPUT2], 255)
        await configure_tpdo(b, 1, [SETPOINT], 255)  # event-driven: sent on each change
        await b.start()
        b.net.remove_listener(b.events.append)
        b.send(RPDO1, bytes.fromhex("f6ff 99 42"))
        await b.settle()
        assert b.device.get(0x2001) == -10
        assert b.device.get(0x6200, 2) == 0x42
        assert b.data(TPDO1)[-1] == bytes.fromhex("f6ff")
        assert not b.of(RpdoReceived)
        heard: list[object] = []
        b.net.add_listener(heard.append)
        b.send(RPDO1, bytes.fromhex("0500 00 43"))
        await b.settle()
        assert [e for e in heard if isinstance(e, RpdoReceived)] == [
            RpdoReceived(NODE, 1, ((0x2001, 0), (0x6200, 2)), (5, 0x43))
        ]
        assert b.data(TPDO1)[-1] == bytes.fromhex("0500")

    run_bench(scenario)


def test_a_listener_added_by_a_write_callback_hears_that_rpdo():
    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT], 255)
        await b.start()
        b.net.remove_listener(b.events.append)
        heard: list[object] = []
        b.device.on_write(0x2001, 0, lambda v: heard or b.device.add_listener(heard.append))
        b.send(RPDO1, b"\x05\x00")
        await b.settle()
        assert [e for e in heard if isinstance(e, RpdoReceived)] == [
            RpdoReceived(NODE, 1, ((0x2001, 0),), (5,))
        ]

    run_bench(scenario)


def test_an_rpdo_watchdog_turned_off_reports_nothing_more():
    """A watchdog switched off while armed (which rebuilds the RPDO) never reports the RPDO
    lost, and frames received afterwards, without an event timer, still apply."""

    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT], 255, timer=100)
        await b.start()
        b.send(RPDO1, b"\x01\x00")  # arms the watchdog
        await b.net.sleep(0.05)
        await b.sdo.write(0x1400, 5, 0)  # off while armed
        for n in range(3):
            b.send(RPDO1, bytes((n, 0)))
            await b.net.sleep(0.01)
        await b.net.sleep(0.5)
        assert b.of(RpdoLost) == []
        assert b.device.get(0x2001) == 2

    run_bench(scenario)


def test_synchronous_rpdo_applied_at_the_next_sync():
    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT], 1)
        await b.start()
        b.send(RPDO1, b"\x05\x00")
        b.send(RPDO1, b"\x06\x00")  # the newest one counts
        await b.settle()
        assert b.device.get(0x2001) == 0
        await b.sync()
        assert b.device.get(0x2001) == 6
        await b.sync()
        assert len(b.of(RpdoReceived)) == 1

    run_bench(scenario)


def test_rpdo_watchdog_emcy_and_recovery():
    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT], 255, timer=100)
        await b.start()
        await b.net.sleep(0.5)
        assert b.of(RpdoLost) == []  # armed by the first RPDO only
        for n in range(3):
            b.send(RPDO1, bytes((n, 0)))
            await b.net.sleep(0.05)
        t_last = b.net.time() - 0.05
        await b.net.sleep(0.1)
        assert b.of(RpdoLost) == [RpdoLost(NODE, 1, RPDO1)]
        emcy = b.on(EMCY)
        assert emcy[0][1].data[:3] == bytes.fromhex("5082 11")
        assert round(emcy[0][0] - t_last, 6) == 0.1
        b.send(RPDO1, b"\x09\x00")
        await b.settle()
        assert b.of(RpdoRestored) == [RpdoRestored(NODE, 1, RPDO1)]
        assert b.data(EMCY)[-1] == bytes(8)
        assert b.device.get(0x2001) == 9

    run_bench(scenario)


def test_rpdo_of_the_wrong_length():
    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT, OUTPUT2], 255)
        await b.start()
        b.send(RPDO1, b"\x05\x00")  # one byte short: not processed
        await b.settle()
        assert b.device.get(0x2001) == 0
        assert b.data(EMCY) == [bytes.fromhex("1082 11 0000000000")]
        assert b.of(WrongLengthRpdoReceived) == [WrongLengthRpdoReceived(NODE, 1, 3, 2)]
        assert b.device.error_register == 0  # a single event, no lasting error
        b.send(RPDO1, b"\x05\x00\x01\xff")  # one byte long: processed, reported
        await b.settle()
        assert b.device.get(0x2001) == 5 and b.device.get(0x6200, 2) == 1
        assert b.data(EMCY)[-1] == bytes.fromhex("2082 11 0000000000")

    run_bench(scenario)


def test_mapping_changes_by_sdo_and_their_consistency_aborts():
    async def scenario(b: Bench):
        sdo = b.sdo
        # mapping of a valid PDO: parameter incompatibility
        assert await _abort(sdo.write(0x1A00, 0, 0)) == SdoAbortCode.PARAMETER_INCOMPATIBLE
        assert await _abort(sdo.write(0x1A00, 1, COUNTER)) == SdoAbortCode.PARAMETER_INCOMPATIBLE
        # the identifier of a valid PDO cannot change; restricted identifiers are refused
        assert await _abort(sdo.write(0x1800, 1, 0x190)) == SdoAbortCode.INVALID_VALUE
        await sdo.write(0x1800, 1, 0x80000000 | TPDO1)
        assert await _abort(sdo.write(0x1800, 1, 0x605)) == SdoAbortCode.INVALID_VALUE
        assert await _abort(sdo.write(0x1800, 2, 245)) == SdoAbortCode.INVALID_VALUE
        assert await _abort(sdo.write(0x1400, 2, 252)) == SdoAbortCode.INVALID_VALUE
        # entries only while the count is 0
        await sdo.write(0x1A00, 0, 0)
        not_mappable = _entry(0x200A, 0, 32)
        assert await _abort(sdo.write(0x1A00, 1, not_mappable)) == SdoAbortCode.NOT_MAPPABLE
        wrong_length = _entry(0x2000, 0, 8)
        assert await _abort(sdo.write(0x1A00, 1, wrong_length)) == SdoAbortCode.NOT_MAPPABLE
        write_only = _entry(0x2004, 0, 32)
        assert await _abort(sdo.write(0x1A00, 1, write_only)) == SdoAbortCode.NOT_MAPPABLE
        missing = _entry(0x3000, 0, 8)
        assert await _abort(sdo.write(0x1A00, 1, missing)) == SdoAbortCode.NO_OBJECT
        # 3 x 32 bits: each entry is fine, the count is too long
        temp, wide = _entry(0x2006, 0, 32), _entry(0x2009, 0, 64)
        for sub, value in enumerate((temp, temp, temp), 1):
            await sdo.write(0x1A00, sub, value)
        assert await _abort(sdo.write(0x1A00, 0, 3)) == SdoAbortCode.MAPPING_TOO_LONG
        assert await _abort(sdo.write(0x1A00, 0, 9)) == SdoAbortCode.VALUE_TOO_HIGH
        await sdo.write(0x1A00, 0, 2)
        assert await _abort(sdo.write(0x1A00, 3, wide)) == SdoAbortCode.PARAMETER_INCOMPATIBLE
        await sdo.write(0x1800, 3, 0)  # inhibit time: allowed while invalid
        await sdo.write(0x1800, 1, TPDO1)
        assert await _abort(sdo.write(0x1800, 3, 10)) == SdoAbortCode.INVALID_VALUE
        # an RPDO cannot map a read-only object
        await sdo.write(0x1400, 1, 0x80000000 | RPDO1)
        await sdo.write(0x1600, 0, 0)
        assert await _abort(sdo.write(0x1600, 1, COUNTER)) == SdoAbortCode.NOT_MAPPABLE
        # the new mapping is in use
        await b.start()
        b.device.set(0x2006, 0, 1.5)
        await b.net.sleep(0.001)
        assert b.data(TPDO1)[-1] == struct.pack("<ff", 1.5, 1.5)

    run_bench(scenario)


def test_mixed_types_and_bit_sized_entries_in_one_pdo():
    async def scenario(b: Bench):
        enable, flags = _entry(0x2007, 0, 1), _entry(0x2002, 0, 8)
        await configure_tpdo(b, 1, [enable, _entry(0x0001, 0, 1), flags], 255)
        await configure_rpdo(b, 1, [enable, _entry(0x0001, 0, 1), flags], 255)
        await b.start()
        b.device.set(0x2002, 0, 0xFF)
        b.device.set(0x2007, 0, True)
        await b.net.sleep(0.001)
        # bit 0 enable, bit 1 dummy, bits 2-9 flags
        assert b.data(TPDO1) == [bytes([0xFC, 0x03]), bytes([0xFD, 0x03])]
        b.send(RPDO1, (0x5A << 2 | 0b10).to_bytes(2, "little"))
        await b.settle()
        assert b.device.get(0x2007) is False and b.device.get(0x2002) == 0x5A

    run_bench(scenario)


def test_default_mappings_from_the_builder_and_512_pdos():
    builder = DictionaryBuilder(rpdos=512, tpdos=512)
    builder.variable(0x2100, "In", DataType.UNSIGNED32, access="ro", mappable=True)
    builder.variable(0x2101, "Out", DataType.UNSIGNED32, access="rww", mappable=True)
    builder.tpdo(1, [(0x2100, 0)], transmission_type=1)
    od = builder.build()

    async def scenario(b: Bench):
        assert await b.sdo.read(0x1A00, 1) == _entry(0x2100, 0, 32)
        # the 512th PDOs, configured by SDO on free identifiers
        await configure_tpdo(b, 512, [_entry(0x2100, 0, 32)], 255, cob_id=0x3F0)
        await configure_rpdo_at(b, 512, 0x3F1, [_entry(0x2101, 0, 32)])
        await b.start()
        b.device.set(0x2100, 0, 0xCAFE)
        b.send(0x3F1, (0xBEEF).to_bytes(4, "little"))
        await b.sync()
        assert b.data(0x3F0) == [(0xCAFE).to_bytes(4, "little")]
        assert b.data(0x180 + NODE) == [(0xCAFE).to_bytes(4, "little")]
        assert b.device.get(0x2101) == 0xBEEF

    run_bench(scenario, od)


async def configure_rpdo_at(b: Bench, number: int, cob_id: int, entries: list[int]) -> None:
    comm, mapping = 0x1400 + number - 1, 0x1600 + number - 1
    await b.sdo.write(mapping, 0, 0)
    for sub, value in enumerate(entries, 1):
        await b.sdo.write(mapping, sub, value)
    await b.sdo.write(mapping, 0, len(entries))
    await b.sdo.write(comm, 1, cob_id)


def test_one_pack_per_tpdo_and_one_unpack_per_rpdo(monkeypatch):
    packs, unpacks = [], []
    pack, unpack = PdoMap.pack, PdoMap.unpack

    def counting_pack(self, values):
        packs.append(values)
        return pack(self, values)

    def counting_unpack(self, data):
        unpacks.append(data)
        return unpack(self, data)

    monkeypatch.setattr(PdoMap, "pack", counting_pack)
    monkeypatch.setattr(PdoMap, "unpack", counting_unpack)

    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [COUNTER, INPUT1], 1)
        await configure_rpdo(b, 1, [SETPOINT, OUTPUT2], 255)
        await b.start()
        packs.clear()
        for n in range(10):
            b.send(RPDO1, bytes((n, 0, n)))
            await b.sync()
        assert len(packs) == 10 and len(unpacks) == 10

    run_bench(scenario)


def test_pdo_defaults_of_minimal_od_follow_the_node_id():
    od = minimal_od(node_id=9, rpdos=5, tpdos=5)
    tpdo1, rpdo4, tpdo5 = (od.get_variable(i, 1) for i in (0x1800, 0x1403, 0x1804))
    assert tpdo1 is not None and rpdo4 is not None and tpdo5 is not None
    assert tpdo1.value == 0x189
    assert rpdo4.value == 0x509
    assert tpdo5.value == 0x80000000  # PDO 5 and above: not valid until configured
    assert tpdo1.relative and not tpdo5.relative


def test_a_default_mapping_the_device_cannot_use_is_reported():
    od = minimal_od()
    od.add(Variable(0x2000, 0, "Plain", DataType.UNSIGNED8, pdo_mappable=False))
    mapping = od.get_variable(0x1A00, 1)
    count = od.get_variable(0x1A00, 0)
    assert mapping is not None and count is not None
    mapping.default = 0x20000008
    count.default = 1

    async def scenario(b: Bench):
        problems = b.of(ConfigurationProblem)
        assert len(problems) == 1 and "TPDO 1" in problems[0].reason
        assert "not PDO-mappable" in problems[0].reason
        await b.start()
        b.device.set(0x2000, 0, 1)
        await b.net.sleep(0.01)
        assert b.data(TPDO1) == []
        # corrected by SDO, the PDO works
        await b.sdo.write(0x1800, 1, 0x80000000 | TPDO1)
        await b.sdo.write(0x1A00, 0, 0)
        await b.sdo.write(0x1A00, 1, 0x10010008)  # the error register
        await b.sdo.write(0x1A00, 0, 1)
        await b.sdo.write(0x1800, 1, TPDO1)
        b.device.send_emergency(0x4000)
        await b.settle()
        assert b.data(TPDO1) == [b"\x09"]

    run_bench(scenario, od)


def test_synchronous_rpdo_after_the_window_is_discarded():
    async def scenario(b: Bench):
        await configure_rpdo(b, 1, [SETPOINT], 0)
        await b.sdo.write(0x1007, 0, 5_000)  # 5 ms window
        await b.start()
        await b.sync()
        b.send(RPDO1, b"\x01\x00")  # inside the window
        await b.net.sleep(0.01)
        b.send(RPDO1, b"\x02\x00")  # after it: dropped
        await b.net.sleep(0.001)
        await b.sync()
        assert b.device.get(0x2001) == 1
        await b.sync()
        assert b.device.get(0x2001) == 1

    run_bench(scenario)


def test_application_events_and_bound_values_in_tpdos():
    async def scenario(b: Bench):
        await configure_tpdo(b, 1, [COUNTER], 254)
        await configure_rpdo(b, 1, [SETPOINT, OUTPUT2], 255)
        live = [0x0102]
        b.device.on_read(0x2000, 0, lambda: live[0])

        def refuse_odd(value: int) -> None:
            if value % 2:
                raise SdoAbort(SdoAbortCode.LOCAL_CONTROL)

        b.device.on_write(0x6200, 2, refuse_odd)
        await b.start()
        b.device.send_tpdo(1)  # an application event: the bound value is sampled
        live[0] = 0x0304
        b.device.send_tpdo(1)
        await b.settle()
        assert b.data(TPDO1) == [b"\x02\x01", b"\x04\x03"]
        with pytest.raises(DeviceConfigError):
            b.device.send_tpdo(9)  # no such TPDO
        b.send(RPDO1, b"\x07\x00\x03")  # the odd output is refused, the setpoint taken
        await b.settle()
        assert b.device.get(0x2001) == 7 and b.device.get(0x6200, 2) == 0
        assert b.of(RpdoReceived)[-1].entries == ((0x2001, 0),)

    run_bench(scenario)
