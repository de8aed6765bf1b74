"""Every fault injected and observed on the simulated clock: power loss (a heartbeat consumer
times out) and return (boot-up, stored parameters kept), a node-ID change (boot-up under the
new ID), a heartbeat that stops, late SDO answers (a client timeout when the delay exceeds
it), bus-off with its bus state events and recovery, frame loss and corruption at a seeded
rate, and a babbling node raising the bus traffic."""

from __future__ import annotations

import itertools
import struct

import can
import pytest

from cobus.device import HeartbeatLost, HeartbeatRestored
from cobus.device.device import SAVE_SIGNATURE
from cobus.proto import Frame
from cobus.proto.sdo import SdoTimeoutError
from cobus.runtime import AsyncNetwork, BusState, BusStateChanged, TxQueueFull, TxResumed
from cobus.sim.drive402 import SimulatedDrive402
from cobus.sim.faults import (
    BUS_FAULTS,
    Babbler,
    FaultConfigError,
    FaultyBus,
    fault_catalogue,
)
from cobus.sim.generic import DeviceOffError, FaultParameterError
from cobus.sim.io401 import SimulatedIo401
from tests.test_sim_support import SimBench, run_sim, simulate

NODE = 20
WATCHER = 21


def watched(make_extra=True):
    """An I/O module on NODE with a 50 ms heartbeat; another on WATCHER consuming it (150 ms)."""

    def make(net: AsyncNetwork) -> SimulatedIo401:
        if make_extra:
            watcher = SimulatedIo401(net, WATCHER, parameters={"0x1016:1": NODE << 16 | 150})
            watcher.start()
        return SimulatedIo401(net, NODE, heartbeat_ms=50)

    return make


def lost(b: SimBench, producer: int = NODE) -> list[HeartbeatLost]:
    return [e for e in b.of(HeartbeatLost) if e.node_id == WATCHER and e.producer == producer]


def test_power_loss_times_out_the_heartbeat_consumer_and_power_return_boots():
    async def scenario(b: SimBench):
        await b.sdo.write(0x6206, 1, 0x0F)
        await b.sdo.download(0x1010, 1, struct.pack("<I", SAVE_SIGNATURE))  # saved
        await b.sdo.write(0x6207, 1, 0x08)  # not saved
        await b.net.sleep(0.2)
        assert lost(b) == []
        b.sim.inject("power_loss")
        t_loss = b.net.time()
        assert b.sim.status()["nmt"] == "off" and "power_loss" in b.sim.status()["faults"]
        with pytest.raises(DeviceOffError, match="power_return"):
            _ = b.sim.device
        await b.net.sleep(0.3)
        assert len(lost(b)) == 1
        emcy = b.data(0x80 + WATCHER)
        assert emcy[-1][:2] == struct.pack("<H", 0x8130)  # the watcher reports it
        # the last heartbeat came at most 50 ms before the loss; the watcher waits 150 ms
        when = [t for t, f in b.on(0x80 + WATCHER)][-1]
        assert 0.1 <= when - t_loss <= 0.15 + 1e-9
        with pytest.raises(SdoTimeoutError):
            await b.sdo.read(0x1000)
        b.sim.inject("power_return")
        await b.settle()
        assert b.data(0x700 + NODE)[-1] == b"\x00"  # boot-up
        assert b.data(0x80 + WATCHER)[-1][:2] == b"\x00\x00"  # the watcher's error reset
        assert await b.sdo.read(0x6206, 1) == 0x0F
        assert await b.sdo.read(0x6207, 1) == 0x00

    run_sim(watched(), scenario, sdo_timeout=0.2)


def test_node_id_change_boots_under_the_new_id():
    async def scenario(b: SimBench):
        b.net.nmt.start(NODE)
        await b.settle()
        t0 = b.net.time()
        b.sim.inject("node_id_change", node_id=23)
        await b.settle()
        assert b.data(0x700 + 23, since=t0) == [b"\x00"]
        assert b.sim.node_id == 23 and b.sim.status()["node_id"] == 23
        new = b.net.add_remote(23, sdo_timeout=0.2)
        assert await new.sdo.upload(0x1000) == struct.pack("<I", 0x000F0191)
        with pytest.raises(SdoTimeoutError):
            await b.sdo.read(0x1000)
        await b.net.sleep(0.12)
        beats = [t for t, f in b.on(0x700 + 23, since=t0) if f.data == b"\x7f"]
        assert len(beats) >= 3  # heartbeats under the new ID, every 50 ms
        assert [round(y - x, 6) for x, y in itertools.pairwise(beats)] == [0.05] * (len(beats) - 1)
        assert b.data(0x700 + NODE, since=t0 + 0.001) == []
        # PDO COB-IDs that followed the node-ID follow the new one
        b.net.nmt.start(23)
        await b.settle()
        b.sim.set_digital_input(1, True)
        await b.settle()
        assert b.data(0x180 + 23) == [b"\x01\x00"]
        # it keeps the new ID through a power cycle
        b.sim.inject("power_loss")
        b.sim.inject("power_return")
        await b.settle()
        assert b.data(0x700 + 23)[-1] == b"\x00"
        with pytest.raises(FaultParameterError, match="needs the parameter"):
            b.sim.inject("node_id_change")
        with pytest.raises(FaultParameterError, match=r"is not 1\.\.127"):
            b.sim.inject("node_id_change", node_id=200)

    run_sim(watched(make_extra=False), scenario, sdo_timeout=0.2)


def test_a_node_id_taken_by_another_device_is_refused():
    async def scenario(b: SimBench):
        with pytest.raises(FaultParameterError, match="taken by another device"):
            b.sim.inject("node_id_change", node_id=WATCHER)

    run_sim(watched(), scenario)


def test_heartbeat_stop_is_seen_by_the_consumer_while_the_node_runs_on():
    async def scenario(b: SimBench):
        await b.net.sleep(0.2)
        b.sim.inject("heartbeat_stop")
        t0 = b.net.time()
        await b.net.sleep(0.3)
        assert b.data(0x700 + NODE, since=t0 + 0.001) == []
        assert len(lost(b)) == 1
        assert await b.sdo.read(0x1017) == 50  # configured as before, the node answers
        assert "heartbeat_stop" in b.sim.status()["faults"]
        # silent through a reset communication too (boot-up is sent)
        b.net.nmt.reset_communication(NODE)
        await b.net.sleep(0.22)  # resumed between two beats that fall due
        assert b.data(0x700 + NODE, since=t0 + 0.001) == [b"\x00"]
        b.sim.inject("heartbeat_resume")
        await b.net.sleep(0.11)
        (boot, *beats) = b.on(0x700 + NODE, since=t0 + 0.001)
        assert boot[1].data == b"\x00" and len(beats) == 2
        # the producer kept its period while silent: the beats resume on the boot's grid
        assert [round((t - boot[0]) / 0.05, 6) for t, _ in beats] == [5.0, 6.0]
        restored = [e for e in b.of(HeartbeatRestored) if e.producer == NODE]
        assert restored == [] or restored[0].node_id == WATCHER

    run_sim(watched(), scenario)


def test_late_sdo_answers_and_a_client_timeout_when_the_delay_exceeds_it():
    async def scenario(b: SimBench):
        b.sim.inject("sdo_delay", delay=0.3)
        t0 = b.net.time()
        assert await b.sdo.read(0x1000) == 0x000F0191
        assert b.net.time() - t0 == pytest.approx(0.3)
        t0 = b.net.time()
        # segmented (16 bytes: initiate and 3 segments): each answer late
        assert await b.sdo.read(0x1008) == "cobus I/O module"
        assert b.net.time() - t0 == pytest.approx(0.3 * 4)
        b.sim.inject("sdo_delay", delay=0.8)
        t0 = b.net.time()
        with pytest.raises(SdoTimeoutError):
            await b.sdo.read(0x1000)
        assert b.net.time() - t0 == pytest.approx(0.5)
        b.sim.inject("sdo_delay", delay=0)
        await b.net.sleep(1.0)  # the late answer and the client's abort pass
        t0 = b.net.time()
        assert await b.sdo.read(0x1018, 1) == 0x00C0B005
        assert b.net.time() == t0
        with pytest.raises(FaultParameterError, match="seconds"):
            b.sim.inject("sdo_delay", delay=-1)

    run_sim(watched(make_extra=False), scenario, sdo_timeout=0.5)


def test_bus_off_gives_bus_state_events_and_recovers_with_the_backlog():
    async def main():
        channel = "faults-bus-off"
        faulty = FaultyBus(can.Bus(interface="virtual", channel=channel))
        async with (
            AsyncNetwork(faulty) as net,
            AsyncNetwork(interface="virtual", channel=channel) as other,
        ):
            events = []
            net.add_listener(events.append)
            heard, got = [], []
            net.subscribe(0x222, lambda f, now: heard.append(f))
            other.subscribe(0x123, lambda f, now: got.append((now, f)))
            faulty.bus_off()
            await net.sleep(0.01)
            assert [e for e in events if isinstance(e, BusStateChanged)] == [
                BusStateChanged(BusState.ACTIVE, BusState.BUS_OFF, 255, 0)
            ]
            assert net.bus_state == BusState.BUS_OFF
            net.send(Frame(0x123, b"\x01"))
            other.send(Frame(0x222, b"\x02"))  # not heard while bus-off
            await net.sleep(0.05)
            assert got == [] and heard == []
            assert any(isinstance(e, TxQueueFull) for e in events)
            faulty.restart()
            t_restart = net.time()
            await net.sleep(0.01)
            assert net.bus_state.value == "error-active"  # (not narrowed by mypy)
            state_events = [e for e in events if isinstance(e, BusStateChanged | TxResumed)]
            assert state_events[-2:] == [
                BusStateChanged(BusState.BUS_OFF, BusState.ACTIVE, 0, 0),
                TxResumed(),  # the backlog went out
            ]
            assert [f for _, f in got] == [Frame(0x123, b"\x01")]
            assert got[0][0] >= t_restart
        faulty.shutdown()

    simulate(main())


def _send_and_count(loss=0.0, corruption=0.0, seed=None, direction="tx", n=2000):
    """``n`` frames from a network on a FaultyBus to a plain one: what arrived."""

    async def main():
        channel = f"faults-loss-{seed}-{direction}-{loss}-{corruption}"
        faulty = FaultyBus(
            can.Bus(interface="virtual", channel=channel),
            loss=loss,
            corruption=corruption,
            seed=seed,
            direction=direction,
        )
        async with (
            AsyncNetwork(faulty) as a,
            AsyncNetwork(interface="virtual", channel=channel) as b,
        ):
            got: list[Frame] = []
            if direction == "tx":
                b.subscribe(0x181, lambda f, now: got.append(f))
                sender = a
            else:
                a.subscribe(0x181, lambda f, now: got.append(f))
                sender = b
            for i in range(n):
                sender.send(Frame(0x181, struct.pack("<IxxxB", i, 0)))
                if i % 100 == 0:
                    await a.sleep(0.001)
            await a.sleep(0.01)
        faulty.shutdown()
        return got, faulty

    return simulate(main())


@pytest.mark.parametrize("direction", ["tx", "rx"])
def test_frame_loss_rate_is_measured_within_tolerance_and_repeats_with_the_seed(direction):
    got, faulty = _send_and_count(loss=0.1, seed=7, direction=direction)
    lost_count = 2000 - len(got)
    assert lost_count == faulty.lost
    sigma = (2000 * 0.1 * 0.9) ** 0.5
    assert abs(lost_count - 200) <= 3 * sigma
    indices = [struct.unpack("<IxxxB", f.data)[0] for f in got]
    assert indices == sorted(indices)  # losses never reorder
    again, _ = _send_and_count(loss=0.1, seed=7, direction=direction)
    assert [f.data for f in again] == [f.data for f in got]
    other, _ = _send_and_count(loss=0.1, seed=8, direction=direction)
    assert [f.data for f in other] != [f.data for f in got]


def test_frame_corruption_flips_one_bit_at_the_rate():
    got, faulty = _send_and_count(corruption=0.05, seed=3)
    assert len(got) == 2000
    bad = 0
    for i, frame in enumerate(got):
        diff = int.from_bytes(frame.data, "little") ^ int.from_bytes(
            struct.pack("<IxxxB", i, 0), "little"
        )
        if diff:
            bad += 1
            assert diff & (diff - 1) == 0  # exactly one bit
    assert bad == faulty.corrupted
    assert abs(bad - 100) <= 3 * (2000 * 0.05 * 0.95) ** 0.5


def test_a_corrupted_copy_keeps_what_tells_a_networks_own_messages():
    """The runtime drops its own messages handed back by the bus by their channel tag
    (udp_multicast) or is_rx mark (virtual with receive_own_messages): a corrupted copy
    keeps both, or its own frame would come back to a network as someone else's."""
    inner = can.Bus(interface="virtual", channel="faults-own-marks")
    try:
        faulty = FaultyBus(inner, corruption=1.0, seed=1)
        msg = can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False)
        msg.channel, msg.is_rx = "cobus-tag", False
        copy = faulty._fate(msg)
        assert copy is not None and copy.data != msg.data
        assert (copy.channel, copy.is_rx) == ("cobus-tag", False)
    finally:
        inner.shutdown()


def test_babbling_node_raises_the_bus_traffic():
    async def scenario(b: SimBench):
        counts: dict[int, int] = {}

        def count(frame: Frame, now: float) -> None:
            counts[frame.cob_id] = counts.get(frame.cob_id, 0) + 1

        b.net.subscribe_all(count)
        await b.net.sleep(0.5)
        quiet = sum(counts.values()) / 0.5
        babbler = Babbler(b.net, cob_id=0x001, period_us=100)
        babbler.start()
        counts.clear()
        await b.net.sleep(0.5)
        noisy = sum(counts.values()) / 0.5
        babbler.stop()
        assert quiet == pytest.approx(20, abs=2)  # the 50 ms heartbeat
        assert counts[0x001] == pytest.approx(5000, abs=1)
        assert noisy > 100 * quiet
        assert await b.sdo.read(0x1000) == 0x000F0191  # no arbitration on a virtual bus
        counts.clear()
        await b.net.sleep(0.1)
        assert 0x001 not in counts and not babbler.running

    run_sim(watched(make_extra=False), scenario)


def test_fault_settings_out_of_range_and_the_catalogue():
    inner = can.Bus(interface="virtual", channel="faults-config")
    try:
        with pytest.raises(FaultConfigError, match="probability"):
            FaultyBus(inner, loss=1.5)
        with pytest.raises(FaultConfigError, match="direction"):
            FaultyBus(inner, direction="up")
        faulty = FaultyBus(inner)
        with pytest.raises(FaultConfigError):
            faulty.corruption = -0.1
        faulty.loss = 0.5
        assert faulty.loss == 0.5
    finally:
        inner.shutdown()

    async def main():
        async with AsyncNetwork() as net:
            with pytest.raises(FaultConfigError, match="at least 1"):
                Babbler(net, period_us=0)
            with pytest.raises(FaultConfigError, match="babbling frame"):
                Babbler(net, cob_id=0x800)

    simulate(main())
    drive = fault_catalogue(SimulatedDrive402)
    assert {"power_loss", "power_return", "blocked_rotor", "sdo_delay"} <= set(drive)
    assert all(isinstance(text, str) and text for text in drive.values())
    assert fault_catalogue() == dict(BUS_FAULTS)
