"""The device's public fault hooks (``device.simulation``), on the simulated clock: SDO answers
that come late (``sdo_response_delay``) and a heartbeat producer that falls silent
(``heartbeat_muted``)."""

from __future__ import annotations

import struct

import pytest

from cobus.device import DeviceConfigError
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbortCode
from tests.test_device_support import NODE, Bench, run_bench

RX, TX, HB = 0x600 + NODE, 0x580 + NODE, 0x700 + NODE


def upload_request(index: int, sub: int = 0) -> bytes:
    return struct.pack("<BHB4x", 0x40, index, sub)


def test_sdo_answers_come_late_by_the_delay():
    async def scenario(b: Bench):
        assert b.device.simulation.sdo_response_delay == 0.0
        t0 = b.net.time()
        assert await b.sdo.read(0x1000) == 0x191
        assert b.net.time() == t0  # no delay: answered at once
        b.device.simulation.sdo_response_delay = 0.2
        t0 = b.net.time()
        assert await b.sdo.read(0x1000) == 0x191
        assert b.net.time() - t0 == pytest.approx(0.2)
        t0 = b.net.time()
        # segmented (11 bytes: initiate and 2 segments), every answer late
        assert await b.sdo.read(0x1008) == "test device"
        assert b.net.time() - t0 == pytest.approx(0.2 * 3)
        await b.sdo.write(0x2002, 0, 7)  # writes too
        assert b.device.get(0x2002) == 7
        b.device.simulation.sdo_response_delay = 0
        t0 = b.net.time()
        assert await b.sdo.read(0x2002) == 7
        assert b.net.time() == t0

    run_bench(scenario)


def test_requests_keep_their_order_when_the_delay_shrinks():
    async def scenario(b: Bench):
        b.device.simulation.sdo_response_delay = 0.3
        t0 = b.net.time()
        b.send(RX, upload_request(0x1000))
        await b.net.sleep(0.01)
        b.device.simulation.sdo_response_delay = 0.05  # the next request would be due first
        b.send(RX, upload_request(0x1017))
        await b.net.sleep(0.1)
        assert b.on(TX) == []
        await b.net.sleep(0.25)
        answers = b.on(TX)
        assert [round(t - t0, 6) for t, _ in answers] == [0.3, 0.3]
        assert [f.data[1:3] for _, f in answers] == [b"\x00\x10", b"\x17\x10"]
        # with nothing waiting, the new delay applies
        t1 = b.net.time()
        b.send(RX, upload_request(0x1000))
        await b.net.sleep(0.1)
        assert [round(t - t1, 6) for t, _ in b.on(TX, since=t1)] == [0.05]

    run_bench(scenario)


def test_the_server_timeout_counts_from_when_the_request_is_taken_up():
    async def scenario(b: Bench):
        b.device.simulation.sdo_response_delay = 0.4
        t0 = b.net.time()
        b.send(RX, upload_request(0x1008))  # segmented: the server waits for segments
        await b.net.sleep(1.0)
        (initiate, abort) = b.on(TX)
        assert initiate[0] - t0 == pytest.approx(0.4) and initiate[1].data[0] == 0x41
        assert abort[1].data[0] == 0x80
        assert struct.unpack_from("<I", abort[1].data, 4)[0] == SdoAbortCode.TIMEOUT
        assert abort[0] - t0 == pytest.approx(0.4 + 0.5)  # the device's sdo_timeout

    run_bench(scenario, sdo_timeout=0.5)


def test_a_delay_set_during_a_transfer_makes_its_next_answers_late():
    """With no delay the channel serves without the gate; set mid-transfer, the delay puts it
    behind one: the transfer goes on, its answers late, and a stall still times out."""

    async def scenario(b: Bench):
        t0 = b.net.time()
        b.send(RX, upload_request(0x1008))  # segmented ("test device", 11 bytes)
        await b.net.sleep(0.01)
        assert [(round(t - t0, 6), f.data[0]) for t, f in b.on(TX)] == [(0.0, 0x41)]
        b.device.simulation.sdo_response_delay = 0.3
        t1 = b.net.time()
        b.send(RX, bytes([0x60]) + bytes(7))  # the first segment, asked for
        await b.net.sleep(0.2)
        assert b.on(TX, since=t1) == []
        await b.net.sleep(0.2)
        ((t, segment),) = b.on(TX, since=t1)
        assert t - t1 == pytest.approx(0.3) and segment.data[0] == 0x00
        assert segment.data[1:8] == b"test de"
        await b.net.sleep(1.0)  # no second segment asked for: the transfer times out
        ((t, abort),) = b.on(TX, since=t1 + 0.31)
        assert abort.data[0] == 0x80 and t - t1 == pytest.approx(0.3 + 0.5)
        assert struct.unpack_from("<I", abort.data, 4)[0] == SdoAbortCode.TIMEOUT
        b.device.simulation.sdo_response_delay = 0  # and back: at once again
        t2 = b.net.time()
        assert await b.sdo.read(0x1000) == 0x191
        assert b.net.time() == t2

    run_bench(scenario, sdo_timeout=0.5)


def test_a_delay_set_by_the_application_while_it_serves_a_request():
    """The read callback sets the delay while its request is served: that answer goes at
    once, the next comes late, and the transfer's timeout counts from when the gate took that
    request up (a request due at the same instant as the timeout goes first)."""

    async def scenario(b: Bench):
        def reader() -> str:
            b.device.simulation.sdo_response_delay = 0.25
            return "a string longer than four"

        b.device.on_read(0x2003, 0, reader)
        t0 = b.net.time()
        b.send(RX, upload_request(0x2003))  # segmented
        await b.net.sleep(0.25)
        b.send(RX, bytes([0x60]) + bytes(7))  # due at 0.5, as the timeout of the initiate
        await b.net.sleep(1.5)
        sent = [(round(t - t0, 6), f.data[0]) for t, f in b.on(TX)]
        assert sent == [(0.0, 0x41), (0.5, 0x00), (1.0, 0x80)]  # the last: timeout, 05040000
        assert struct.unpack_from("<I", b.on(TX)[-1][1].data, 4)[0] == SdoAbortCode.TIMEOUT

    run_bench(scenario, sdo_timeout=0.5)


def test_the_delay_holds_through_resets_and_waiting_requests_end_with_the_channels():
    async def scenario(b: Bench):
        b.device.simulation.sdo_response_delay = 0.2
        b.send(RX, upload_request(0x1000))
        await b.net.sleep(0.1)
        b.net.nmt.reset_communication(NODE)
        await b.net.sleep(0.3)
        assert b.on(TX) == []  # the request was dropped with the old channel
        assert b.device.state is NmtState.PRE_OPERATIONAL
        t0 = b.net.time()
        assert await b.sdo.read(0x1000) == 0x191
        assert b.net.time() - t0 == pytest.approx(0.2)
        b.device.set_node_id(NODE + 1)
        new = b.net.add_remote(NODE + 1)
        t0 = b.net.time()
        assert await new.sdo.upload(0x1000) == struct.pack("<I", 0x191)
        assert b.net.time() - t0 == pytest.approx(0.2)

    run_bench(scenario)


@pytest.mark.parametrize("bad", [-0.1, float("inf"), float("nan"), True, "0.2", None])
def test_a_delay_that_is_not_seconds_is_refused(bad):
    async def scenario(b: Bench):
        with pytest.raises(DeviceConfigError, match="seconds >= 0"):
            b.device.simulation.sdo_response_delay = bad
        assert b.device.simulation.sdo_response_delay == 0.0

    run_bench(scenario)


def test_a_muted_heartbeat_keeps_its_period_and_resumes_on_it():
    async def scenario(b: Bench):
        await b.net.sleep(0.01)  # after the boot-up
        b.device.set(0x1017, 0, 100)
        t0 = b.net.time()  # beats fall due at t0 + 0.1 k
        await b.net.sleep(0.25)
        assert b.times(HB, since=t0) == [round(t0 + 0.1, 6), round(t0 + 0.2, 6)]
        assert b.device.simulation.heartbeat_muted is False
        b.device.simulation.heartbeat_muted = True
        await b.net.sleep(0.3)
        assert b.times(HB, since=t0 + 0.25) == []
        assert await b.sdo.read(0x1017) == 100  # 1017h keeps its value, the node answers
        b.device.simulation.heartbeat_muted = (
            False  # at t0 + 0.55: the next beat is due at t0 + 0.6
        )
        await b.net.sleep(0.16)
        assert b.times(HB, since=t0 + 0.25) == [round(t0 + 0.6, 6), round(t0 + 0.7, 6)]

    run_bench(scenario)


def test_a_muted_heartbeat_stays_silent_through_writes_of_1017h_and_resets():
    async def scenario(b: Bench):
        await b.net.sleep(0.01)  # after the boot-up
        b.device.simulation.heartbeat_muted = True
        await b.sdo.write(0x1017, 0, 50)
        t0 = b.net.time()
        await b.net.sleep(0.2)
        assert b.on(HB, since=t0) == []
        b.net.nmt.reset_communication(NODE)  # 1017h back to its default 0
        await b.settle()
        b.device.set(0x1017, 0, 50)
        t1 = b.net.time()
        await b.net.sleep(0.2)
        assert b.data(HB, since=t0) == [b"\x00"]  # the boot-up only
        assert b.device.simulation.heartbeat_muted is True
        b.device.simulation.heartbeat_muted = False
        await b.net.sleep(0.06)
        assert b.times(HB, since=t0 + 0.001)[-1] == round(t1 + 0.25, 6)
        with pytest.raises(DeviceConfigError, match="True or False"):
            b.device.simulation.heartbeat_muted = 1  # type: ignore[assignment]

    run_bench(scenario)
