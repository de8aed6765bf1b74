"""NMT slave, error control (heartbeat, node and life guarding), EMCY, SYNC and TIME of the
device, on the simulated clock."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from cobus.device import (
    Booted,
    EmergencySent,
    HeartbeatLost,
    HeartbeatRestored,
    LifeGuardingLost,
    LifeGuardingRestored,
    NmtCommandReceived,
    StateChanged,
    SyncLost,
    SyncRestored,
    TimeReceived,
)
from cobus.proto.emcy import EmcyError
from cobus.proto.nmt import NmtCommand, NmtState
from cobus.proto.sdo import SdoAbortCode, SdoAbortedError
from cobus.proto.timestamp import encode_time_of_day
from tests.test_device_support import NODE, Bench, run_bench

EMCY = 0x80 + NODE
HB = 0x700 + NODE


async def _abort(coro) -> int:
    with pytest.raises(SdoAbortedError) as err:
        await coro
    return int(err.value.code)


def test_boots_pre_operational_and_follows_nmt_commands():
    async def scenario(b: Bench):
        assert b.data(HB) == [b"\x00"]
        assert b.state() is NmtState.PRE_OPERATIONAL
        assert b.of(Booted) == [Booted(NODE)]
        await b.start()
        assert b.state() is NmtState.OPERATIONAL
        b.net.nmt.stop(0)  # broadcast
        await b.settle()
        assert b.state() is NmtState.STOPPED
        b.net.nmt.start(NODE + 1)  # another node: ignored
        await b.settle()
        assert b.state() is NmtState.STOPPED
        b.net.nmt.enter_preoperational(NODE)
        await b.settle()
        assert [e.command for e in b.of(NmtCommandReceived)] == [
            NmtCommand.START,
            NmtCommand.STOP,
            NmtCommand.ENTER_PREOPERATIONAL,
        ]
        assert [(e.old, e.new) for e in b.of(StateChanged)] == [
            (NmtState.INITIALISING, NmtState.PRE_OPERATIONAL),
            (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL),
            (NmtState.OPERATIONAL, NmtState.STOPPED),
            (NmtState.STOPPED, NmtState.PRE_OPERATIONAL),
        ]
        b.device.apply_nmt(NmtCommand.START)
        assert b.state() is NmtState.OPERATIONAL

    run_bench(scenario)


def test_reset_node_restores_application_and_communication_then_boots():
    async def scenario(b: Bench):
        seen_before_reset: list[int] = []

        def listener(event):
            if isinstance(event, NmtCommandReceived) and event.command is NmtCommand.RESET_NODE:
                seen_before_reset.append(b.device.get(0x2002))

        b.device.add_listener(listener)
        await b.sdo.write(0x2002, 0, 9)
        await b.sdo.write(0x1017, 0, 50)
        await b.start()
        b.net.nmt.reset_node(NODE)
        await b.settle()
        assert seen_before_reset == [9]  # the indication comes before the reset
        assert b.device.get(0x2002) == 0
        assert b.device.get(0x1017) == 0
        assert b.state() is NmtState.PRE_OPERATIONAL
        assert b.data(HB) == [b"\x00", b"\x00"]  # a second boot-up
        assert len(b.of(Booted)) == 2

    run_bench(scenario)


def test_reset_communication_keeps_application_values():
    async def scenario(b: Bench):
        await b.sdo.write(0x2002, 0, 9)
        await b.sdo.write(0x1017, 0, 50)
        await b.sdo.write(0x1800, 2, 1)
        b.net.nmt.reset_communication(NODE)
        await b.settle()
        assert b.device.get(0x2002) == 9
        assert b.device.get(0x1017) == 0
        assert b.device.get(0x1800, 2) == 255
        assert b.data(HB) == [b"\x00", b"\x00"]
        await b.net.sleep(1.0)
        assert b.data(HB) == [b"\x00", b"\x00"]  # heartbeat off again

    run_bench(scenario)


def test_heartbeat_producer_period_takes_effect_at_once():
    async def scenario(b: Bench):
        await b.net.sleep(1.0)
        await b.sdo.write(0x1017, 0, 100)
        t0 = b.net.time()
        await b.net.sleep(0.25)
        await b.start()
        await b.net.sleep(0.2)
        await b.sdo.write(0x1017, 0, 30)  # shorter: counted from the write
        t1 = b.net.time()
        await b.net.sleep(0.1)
        await b.sdo.write(0x1017, 0, 0)
        await b.net.sleep(0.5)
        beats = [(round(t - t0, 3), f.data) for t, f in b.on(HB, since=t0)]
        assert beats == [
            (0.1, b"\x7f"),
            (0.2, b"\x7f"),
            (0.3, b"\x05"),
            (0.4, b"\x05"),
            (round(t1 - t0 + 0.03, 3), b"\x05"),
            (round(t1 - t0 + 0.06, 3), b"\x05"),
            (round(t1 - t0 + 0.09, 3), b"\x05"),
        ]

    run_bench(scenario)


def test_heartbeat_consumer_timeout_sends_emcy_and_falls_back():
    async def scenario(b: Bench):
        master = 0x10
        await b.sdo.write(0x1016, 1, master << 16 | 100)
        # the same producer twice is a parameter incompatibility; reserved bits are invalid
        dup = b.sdo.write(0x1016, 2, master << 16 | 200)
        assert await _abort(dup) == SdoAbortCode.PARAMETER_INCOMPATIBLE
        assert await _abort(b.sdo.write(0x1016, 2, 0x01000064)) == SdoAbortCode.INVALID_VALUE
        await b.start()
        for _ in range(3):
            b.send(0x700 + master, b"\x05")
            await b.net.sleep(0.08)
        assert not b.of(HeartbeatLost)
        t_last = b.net.time() - 0.08
        await b.net.sleep(0.1)
        assert b.of(HeartbeatLost) == [HeartbeatLost(NODE, master)]
        emcy = b.on(EMCY)
        assert [f.data for _, f in emcy] == [bytes.fromhex("3081 11 0000000000")]
        assert round(emcy[0][0] - t_last, 6) == 0.1
        assert b.device.error_register == 0x11
        assert await b.sdo.read(0x1001) == 0x11
        assert b.state() is NmtState.PRE_OPERATIONAL  # 1029h sub 1 = 0
        b.send(0x700 + master, b"\x05")
        await b.settle()
        assert b.of(HeartbeatRestored) == [HeartbeatRestored(NODE, master, NmtState.OPERATIONAL)]
        assert b.data(EMCY)[-1] == bytes(8)  # error reset, register 0
        assert b.device.error_register == 0

    run_bench(scenario)


def test_error_behaviour_no_change_keeps_the_state():
    async def scenario(b: Bench):
        await b.sdo.write(0x1029, 1, 1)
        assert await _abort(b.sdo.write(0x1029, 1, 5)) == SdoAbortCode.INVALID_VALUE
        await b.sdo.write(0x1016, 1, 0x20 << 16 | 50)
        await b.start()
        b.send(0x720, b"\x05")
        await b.net.sleep(0.2)
        assert b.of(HeartbeatLost)
        assert b.state() is NmtState.OPERATIONAL
        await b.sdo.write(0x1029, 1, 2)  # 2: stopped
        b.send(0x720, b"\x05")
        await b.net.sleep(0.2)
        assert len(b.of(HeartbeatLost)) == 2
        assert b.state() is NmtState.STOPPED

    run_bench(scenario)


def test_node_guarding_replies_toggle_and_life_guarding_expiry():
    async def scenario(b: Bench):
        await b.sdo.write(0x100C, 0, 100)
        await b.sdo.write(0x100D, 0, 3)
        b.send(HB, rtr=True)
        await b.settle()
        await b.start()
        for _ in range(3):
            await b.net.sleep(0.1)
            b.send(HB, rtr=True)
            await b.settle()
        replies = [f.data for _, f in b.on(HB) if not f.rtr][1:]  # after the boot-up
        assert replies == [b"\x7f", b"\x85", b"\x05", b"\x85"]
        t_last = b.net.time()
        await b.net.sleep(0.29)
        assert not b.of(LifeGuardingLost)
        await b.net.sleep(0.02)
        assert b.of(LifeGuardingLost) == [LifeGuardingLost(NODE)]
        assert b.on(EMCY)[0][1].data[:3] == bytes.fromhex("3081 11")
        assert round(b.on(EMCY)[0][0] - t_last, 6) == 0.3
        assert b.state() is NmtState.PRE_OPERATIONAL
        b.send(HB, rtr=True)
        await b.settle()
        assert b.of(LifeGuardingRestored) == [LifeGuardingRestored(NODE)]
        assert b.data(HB)[-1] == b"\x7f"

    run_bench(scenario)


def test_a_shorter_inhibit_time_releases_a_queued_emergency_sooner():
    async def scenario(b: Bench):
        device = b.device
        await b.sdo.write(0x1015, 0, 10_000)  # 1 s
        t0 = b.net.time()
        device.send_emergency(0x3110)
        device.send_emergency(0xFF01)  # queued behind the inhibit time
        await b.net.sleep(0.01)
        await b.sdo.write(0x1015, 0, 200)  # 20 ms, counted from the first EMCY
        await b.net.sleep(0.1)
        times = [round(t - t0, 6) for t in b.times(EMCY, since=t0)]
        assert times[0] == 0.0 and len(times) == 2
        assert times[1] <= 0.02 + 0.001  # not the old 1 s

    run_bench(scenario)


def test_the_old_manufacturer_keyword_works_for_a_release_with_a_warning():
    async def scenario(b: Bench):
        device = b.device
        with pytest.warns(DeprecationWarning, match="manufacturer_data"):
            device.send_emergency(0x4210, manufacturer=b"\x01\x02")
        await b.settle()
        assert b.data(EMCY) == [bytes.fromhex("1042 09 0102000000")]
        with pytest.raises(TypeError, match="give manufacturer_data only"):
            device.send_emergency(0x4210, manufacturer_data=b"\x01", manufacturer=b"\x02")
        with pytest.warns(DeprecationWarning, match="clear_emergency"):
            device.clear_emergency(manufacturer=b"\x07")
        await b.settle()
        assert b.data(EMCY)[-1] == bytes.fromhex("0000 00 0700000000")

    run_bench(scenario)


def test_emergencies_history_register_and_inhibit_time():
    async def scenario(b: Bench):
        device = b.device
        device.send_emergency(0x4210, manufacturer_data=b"\x01\x02")
        await b.settle()
        assert b.data(EMCY) == [bytes.fromhex("1042 09 0102000000")]
        assert device.error_register == 0x09
        assert await b.sdo.read(0x1001) == 0x09
        assert await b.sdo.read(0x1003, 0) == 1
        assert await b.sdo.read(0x1003, 1) == 0x4210
        assert await _abort(b.sdo.read(0x1003, 2)) == SdoAbortCode.NO_DATA
        # inhibit time 10 ms: the next emergency waits
        await b.sdo.write(0x1015, 0, 100)
        await b.net.sleep(1.0)
        t0 = b.net.time()
        device.send_emergency(0x3110, info=0x0101)
        device.send_emergency(0xFF01, register=0x80)
        await b.net.sleep(0.05)
        times = b.times(EMCY, since=t0)
        assert [round(t - t0, 6) for t in times] == [0.0, 0.01]
        assert b.data(EMCY, since=t0) == [
            bytes.fromhex("1031 0d 0000000000"),
            bytes.fromhex("01ff 8d 0000000000"),
        ]
        assert await b.sdo.read(0x1003, 0) == 3
        assert await b.sdo.read(0x1003, 1) == 0xFF01
        assert await b.sdo.read(0x1003, 2) == 0x01013110
        device.clear_emergency(0x3110)
        await b.net.sleep(0.05)
        assert b.data(EMCY)[-1] == bytes.fromhex("0000 89 0000000000")
        device.clear_emergency()
        await b.net.sleep(0.05)
        assert b.data(EMCY)[-1] == bytes(8)
        assert device.error_register == 0
        # 1003h sub 0: only 0 clears
        assert await _abort(b.sdo.write(0x1003, 0, 1)) == SdoAbortCode.INVALID_VALUE
        await b.sdo.write(0x1003, 0, 0)
        assert await b.sdo.read(0x1003, 0) == 0
        assert device.error_history == ()
        with pytest.raises(EmcyError):
            device.send_emergency(0x1000, manufacturer_data=b"123456")

    run_bench(scenario)


def test_emcy_cob_id_changes_only_while_invalid():
    async def scenario(b: Bench):
        assert await _abort(b.sdo.write(0x1014, 0, 0x90)) == SdoAbortCode.INVALID_VALUE
        assert await _abort(b.sdo.write(0x1014, 0, 0x40000085)) == SdoAbortCode.INVALID_VALUE
        await b.sdo.write(0x1014, 0, 0x80000085)
        b.device.send_emergency(0x1000)
        await b.settle()
        assert b.data(EMCY) == []  # not valid: nothing sent, still recorded
        assert b.device.error_history == (0x1000,)
        await b.sdo.write(0x1014, 0, 0x90)
        b.device.send_emergency(0x5000)
        await b.settle()
        assert b.data(0x90) == [bytes.fromhex("0050 01 0000000000")]

    run_bench(scenario)


def test_no_emergency_frames_in_stopped():
    async def scenario(b: Bench):
        b.net.nmt.stop(NODE)
        await b.settle()
        b.device.send_emergency(0x2310)
        await b.settle()
        assert b.data(EMCY) == []
        assert b.device.error_history == (0x2310,)
        assert b.device.error_register == 0x03
        assert b.of(EmergencySent)[-1].code == 0x2310

    run_bench(scenario)


def test_sync_loss_detection_counter_rules_and_wrong_length():
    async def scenario(b: Bench):
        # 1019h changes only while 1006h is 0; 1 is no valid overflow value
        assert await _abort(b.sdo.write(0x1019, 0, 1)) == SdoAbortCode.INVALID_VALUE
        await b.sdo.write(0x1019, 0, 4)
        await b.sdo.write(0x1006, 0, 10_000)
        assert await _abort(b.sdo.write(0x1019, 0, 8)) == SdoAbortCode.DEVICE_STATE
        for counter in (1, 2, 3):
            await b.sync(counter)
            await b.net.sleep(0.01)
        assert not b.of(SyncLost)
        await b.net.sleep(0.006)
        assert b.of(SyncLost) == [SyncLost(NODE)]
        assert b.data(EMCY)[-1][:3] == bytes.fromhex("0081 11")
        await b.sync(4)
        assert b.of(SyncRestored) == [SyncRestored(NODE)]
        assert b.device.error_register == 0
        # a SYNC without the counter 1019h asks for: EMCY 8240h, once
        await b.sync()
        assert b.data(EMCY)[-1][:3] == bytes.fromhex("4082 11")
        assert b.device.error_register == 0

    run_bench(scenario)


def test_device_produces_sync_when_1005h_says_so():
    async def scenario(b: Bench):
        await b.sdo.write(0x1019, 0, 3)
        await b.sdo.write(0x1005, 0, 0x40000080)
        t0 = b.net.time()
        await b.sdo.write(0x1006, 0, 20_000)
        await b.net.sleep(0.105)
        assert b.data(0x80) == [b"\x01", b"\x02", b"\x03", b"\x01", b"\x02"]
        assert [round(t - t0, 6) for t in b.times(0x80)] == [0.02, 0.04, 0.06, 0.08, 0.1]
        # the identifier cannot change while producing
        assert await _abort(b.sdo.write(0x1005, 0, 0x40000081)) == SdoAbortCode.INVALID_VALUE

    run_bench(scenario)


def test_no_sync_is_produced_in_stopped_and_the_counter_restarts_after():
    async def scenario(b: Bench):
        await b.sdo.write(0x1019, 0, 3)
        await b.sdo.write(0x1005, 0, 0x40000080)
        await b.sdo.write(0x1006, 0, 10_000)
        await b.net.sleep(0.025)
        assert b.data(0x80) == [b"\x01", b"\x02"]
        b.net.nmt.stop(NODE)
        await b.settle()
        await b.net.sleep(0.1)
        assert len(b.data(0x80)) == 2  # silent while stopped
        await b.start()
        await b.net.sleep(0.025)
        assert b.data(0x80)[2:] == [b"\x01", b"\x02"]

    run_bench(scenario)


def test_a_period_written_while_stopped_takes_effect_once_the_device_leaves_stopped():
    async def scenario(b: Bench):
        await b.sdo.write(0x1019, 0, 3)
        await b.sdo.write(0x1005, 0, 0x40000080)
        await b.sdo.write(0x1006, 0, 10_000)
        await b.net.sleep(0.015)
        b.net.nmt.stop(NODE)
        await b.settle()
        b.device.set(0x1006, 0, 5_000)  # by the application: no SDO in stopped
        await b.net.sleep(0.1)
        assert b.data(0x80) == [b"\x01"]  # still silent
        await b.start()
        t0 = b.net.time()
        await b.net.sleep(0.0125)
        assert b.data(0x80)[1:] == [b"\x01", b"\x02"]
        assert [round(t - t0, 4) for t in b.times(0x80)[1:]] == [0.005, 0.01]

    run_bench(scenario)


def test_time_stamps_are_consumed_per_1012h():
    async def scenario(b: Bench):
        when = datetime(2024, 5, 17, 8, 30, 15, 250_000, tzinfo=UTC)
        b.send(0x100, encode_time_of_day(when))
        await b.settle()
        assert b.of(TimeReceived) == [TimeReceived(NODE, when)]
        assert await _abort(b.sdo.write(0x1012, 0, 0xC0000100)) == SdoAbortCode.INVALID_VALUE
        await b.sdo.write(0x1012, 0, 0x00000100)  # consumer off
        b.send(0x100, encode_time_of_day(when))
        await b.settle()
        assert len(b.of(TimeReceived)) == 1
        await b.sdo.write(0x1012, 0, 0x80000123)
        b.send(0x123, encode_time_of_day(when))
        await b.settle()
        assert len(b.of(TimeReceived)) == 2
        b.net.nmt.stop(NODE)
        await b.settle()
        b.send(0x123, encode_time_of_day(when))
        await b.settle()
        assert len(b.of(TimeReceived)) == 2  # not received in stopped

    run_bench(scenario)


def test_heartbeat_consumer_watches_several_producers():
    async def scenario(b: Bench):
        await b.sdo.write(0x1016, 1, 0x10 << 16 | 100)
        await b.sdo.write(0x1016, 2, 0x11 << 16 | 100)
        await b.sdo.write(0x1016, 3, 0x12 << 16 | 100)
        for step in range(10):
            b.send(0x710, b"\x05")
            if step < 2:
                b.send(0x711, b"\x7f")
            b.send(0x712, b"\x05")
            await b.net.sleep(0.05)
        assert [e.producer for e in b.of(HeartbeatLost)] == [0x11]
        # clearing the entry of the lost producer ends its error
        assert b.device.error_register == 0x11
        await b.sdo.write(0x1016, 2, 0)
        assert b.device.error_register == 0
        await b.sdo.write(0x1016, 3, 0)
        await b.net.sleep(0.5)
        assert [e.producer for e in b.of(HeartbeatLost)] == [0x11, 0x10]

    run_bench(scenario)
