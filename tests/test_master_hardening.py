"""The master heals what someone else or bad luck did to a node while it boots (issue 39): a
node stopped by another tool after its reset, late SDO replies taken for the next transfer's,
a protocol error that is not the node's verdict, a close while a boot is pending."""

from __future__ import annotations

import asyncio
import logging

import pytest

from cobus.master import (
    DeviceTypeMismatch,
    IdentityMismatch,
    Master,
    MasterEvent,
    NodeState,
    SdoUnanswered,
)
from cobus.od import ObjectDictionary, Variable
from cobus.proto import Frame
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork
from tests.test_master_support import Rig, io_od, network, nmt, rig_test, simulate, state

NODE = """
  {name}:
    node_id: {node_id}
    eds: io.eds
    heartbeat_time: 100
    device_type: 0x191
    vendor_id: 0x00C0B05
    mandatory: {mandatory}
{extra}"""


def net_text(node_id: int = 5, *, mandatory: bool = True, extra: str = "") -> str:
    return "master: {node_id: 127, heartbeat_time: 100}\nnodes:" + NODE.format(
        name="a", node_id=node_id, mandatory=str(mandatory).lower(), extra=extra
    )


def upload_requests(rig: Rig, index: int, since: float = -1.0) -> list[float]:
    key = bytes((0x40, index & 0xFF, index >> 8, 0))
    return [t for t, f in rig.on(0x605, since=since) if f.data[:4] == key]


def beating() -> ObjectDictionary:
    """The test device, producing its heartbeat from power-on (100 ms), as the thesis servo."""
    od = io_od()
    producer = od[0x1017]
    assert isinstance(producer, Variable)
    producer.default = 100
    return od


async def booted(rig: Rig) -> None:
    rig.add(5, beating())
    await rig.master.boot(timeout=5)
    await rig.run(0.2)


@pytest.mark.parametrize("mandatory", [True, False])
def test_a_node_reset_then_stopped_by_someone_else_is_brought_back(tmp_path, mandatory):
    """Another tool resets the node, then stops it: the master, reading 1000h after the
    boot-up, hears STOPPED in its heartbeat, sends enter pre-operational, configures it and
    starts it again - where it used to poll 1000h for ever (119 requests a minute)."""
    cfg = network(tmp_path, net_text(mandatory=mandatory))

    async def scenario(rig: Rig) -> None:
        await booted(rig)
        device = rig.devices[5]
        node = rig.master.nodes[5]
        since = rig.net.time()
        rig.send(0x000, bytes([0x81, 5]))  # someone else: reset node 5 ...
        await rig.run(0.01)
        rig.send(0x000, bytes([0x02, 5]))  # ... and stop it
        await rig.run(60.0)
        assert (state(node), nmt(device)) == (NodeState.OPERATIONAL, NmtState.OPERATIONAL)
        (event,) = rig.of(SdoUnanswered)
        assert event == SdoUnanswered(
            5,
            NmtState.STOPPED,
            "enter_preoperational",
            "reports STOPPED but does not answer SDO: enter pre-operational sent",
        )
        assert bytes([0x80, 5]) in rig.data(0x000, since=since)
        assert len(upload_requests(rig, 0x1000, since)) <= 3
        assert node.problem is None

    rig_test(cfg, scenario)


def test_a_node_kept_stopped_is_commanded_a_few_times_then_left_as_it_is(tmp_path):
    cfg = network(tmp_path, net_text())

    async def scenario(rig: Rig) -> None:
        await booted(rig)
        node = rig.master.nodes[5]
        since = rig.net.time()
        rig.send(0x000, bytes([0x81, 5]))
        await rig.run(0.01)
        rig.send(0x000, bytes([0x02, 5]))

        def stop_again(frame: Frame, now: float) -> None:  # a tool that insists
            if frame.data == bytes([0x80, 5]):
                asyncio.get_running_loop().call_soon(rig.send, 0x000, bytes([0x02, 5]))

        rig.net.subscribe(0x000, stop_again)
        await rig.run(30.0)
        commands = [d for d in rig.data(0x000, since=since) if d == bytes([0x80, 5])]
        assert len(commands) == 3  # the limit in 60 s
        events = rig.of(SdoUnanswered)
        assert [e.command for e in events] == ["enter_preoperational"] * 3 + [""]
        assert events[-1].reason == (
            "reports STOPPED but does not answer SDO after 3 NMT commands within 60 s: "
            "left as it is until it answers SDO or the application restarts it"
        )
        assert state(node) is NodeState.WAITING
        assert "left as it is" in (node.problem or "")
        await rig.run(120.0)  # past the window: still no more commands (not 3 a minute)
        commands = [d for d in rig.data(0x000, since=since) if d == bytes([0x80, 5])]
        assert len(commands) == 3 and len(rig.of(SdoUnanswered)) == 4

    rig_test(cfg, scenario)


def test_manual_restart_says_why_the_node_waits_and_sends_nothing(tmp_path):
    cfg = network(tmp_path, net_text(extra="    restart: manual\n"))

    async def scenario(rig: Rig) -> None:
        await booted(rig)
        since = rig.net.time()
        rig.send(0x000, bytes([0x81, 5]))
        await rig.run(0.01)
        rig.send(0x000, bytes([0x02, 5]))
        await rig.run(5.0)
        assert bytes([0x80, 5]) not in rig.data(0x000, since=since)
        (event,) = rig.of(SdoUnanswered)
        assert event.command == "" and "manual restart" in event.reason
        await rig.master.restart_node("a")
        assert state(rig.master.nodes[5]) is NodeState.OPERATIONAL

    rig_test(cfg, scenario)


def test_a_node_whose_sdo_server_stays_silent_is_reset_after_the_retries(tmp_path):
    """Heartbeat says PRE-OPERATIONAL, SDO says nothing (a hung server): after sdo_retries
    more timeouts the master resets it; a node with no heartbeat at all is only polled."""
    cfg = network(tmp_path, net_text(extra="    sdo_retries: 1\n"))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5, beating())
        device.simulation.sdo_response_delay = 3600.0  # hung until its next reset

        def reset(frame: Frame, now: float) -> None:
            if frame.data == bytes([0x81, 5]) and rig.of(SdoUnanswered):
                device.simulation.sdo_response_delay = 0.0

        rig.net.subscribe(0x000, reset)
        await rig.master.boot(timeout=10)
        (event,) = rig.of(SdoUnanswered)
        assert (event.reported, event.command) == (NmtState.PRE_OPERATIONAL, "reset_node")
        assert event.reason == "reports PRE_OPERATIONAL but does not answer SDO: reset node sent"
        assert state(rig.master.nodes[5]) is NodeState.OPERATIONAL
        # the reset came after the first read and sdo_retries (1) more, each timed out
        (sent,) = [t for t, f in rig.on(0x000) if f.data == bytes([0x81, 5]) and t > 0.5]
        assert len([t for t in upload_requests(rig, 0x1000) if t < sent]) == 2

    rig_test(cfg, scenario)


def test_no_heartbeat_no_command_the_node_is_only_polled(tmp_path):
    cfg = network(tmp_path, net_text())

    async def scenario(rig: Rig) -> None:
        rig.add(5).simulation.sdo_response_delay = 3600.0  # hung, and no heartbeat
        rig.master.start()
        await rig.run(10.0)
        assert not rig.of(SdoUnanswered)
        assert len(upload_requests(rig, 0x1000)) >= 5
        assert state(rig.master.nodes[5]) is NodeState.WAITING

    rig_test(cfg, scenario)


def test_a_node_answering_late_across_a_power_cycle_is_booted_once_it_is_prompt(tmp_path):
    """The servo answers 1.5 s late (timeout 1 s) across a power cycle: its late replies land
    inside later transfers and are dropped; once the delay is gone the node is booted (it
    used to stay WRONG_DEVICE for good)."""
    cfg = network(tmp_path, net_text())

    async def scenario(rig: Rig) -> None:
        await booted(rig)
        rig.devices[5].simulation.sdo_response_delay = 1.5
        await rig.run(1.0)
        rig.devices[5].close()
        await rig.run(0.5)
        fresh = rig.add(5, beating())
        fresh.simulation.sdo_response_delay = 1.5
        await rig.run(10.0)
        node = rig.master.nodes[5]
        assert state(node) is not NodeState.WRONG_DEVICE
        fresh.simulation.sdo_response_delay = 0.0
        await rig.run(30.0)
        assert state(node) is NodeState.OPERATIONAL
        assert nmt(fresh) is NmtState.OPERATIONAL
        assert not rig.of(DeviceTypeMismatch) and not rig.of(IdentityMismatch)

    rig_test(cfg, scenario)


def test_a_stale_reply_is_not_taken_for_the_device_type(tmp_path):
    """A late reply of an earlier transfer (a download response, 60h) lands inside the 1000h
    read: dropped as stale, the node's own answer is taken, no WRONG_DEVICE."""
    cfg = network(tmp_path, net_text())

    async def scenario(rig: Rig) -> None:
        def late_reply(frame: Frame, now: float) -> None:
            if frame.data[:4] == bytes((0x40, 0x00, 0x10, 0)):
                rig.send(0x585, bytes((0x60, 0x17, 0x10, 0, 0, 0, 0, 0)))
                rig.send(0x585, bytes((0x60, 0x00, 0x10, 0, 0, 0, 0, 0)))

        rig.net.subscribe(0x605, late_reply)
        await booted(rig)
        node = rig.master.nodes[5]
        assert state(node) is NodeState.OPERATIONAL
        assert not rig.of(DeviceTypeMismatch)
        assert node.sdo.client.stale_replies == 2

    rig_test(cfg, scenario)


@pytest.mark.parametrize("index", [0x1000, 0x1018])
def test_a_protocol_error_is_asked_again_before_it_is_a_wrong_device(tmp_path, index):
    """A reply that breaks the protocol once (a stale expedited reply for the same object
    without its data) ends that read; the master asks again before judging the device."""
    cfg = network(tmp_path, net_text())

    async def scenario(rig: Rig) -> None:
        sub = 1 if index == 0x1018 else 0
        request = bytes((0x40, index & 0xFF, index >> 8, sub))
        garbled = 0

        def garble(frame: Frame, now: float) -> None:
            nonlocal garbled
            if frame.data[:4] == request and not garbled:
                garbled += 1
                rig.send(0x585, bytes((0x4B, index & 0xFF, index >> 8, sub, 0x91)))

        rig.net.subscribe(0x605, garble)
        await booted(rig)
        assert garbled == 1
        assert state(rig.master.nodes[5]) is NodeState.OPERATIONAL
        assert not rig.of(DeviceTypeMismatch) and not rig.of(IdentityMismatch)

    rig_test(cfg, scenario)


def test_a_node_that_refuses_the_identity_read_is_a_wrong_device(tmp_path):
    """The refusal paths: an abort of 1018h sub 1 is no identity, whatever the retries."""
    cfg = network(tmp_path, net_text(mandatory=False, extra="    sdo_retries: 2\n"))

    async def scenario(rig: Rig) -> None:
        def refuse(frame: Frame, now: float) -> None:
            if frame.data[:4] == bytes((0x40, 0x18, 0x10, 1)):
                rig.send(0x585, bytes((0x80, 0x18, 0x10, 1, 0, 0, 2, 6)))

        rig.net.subscribe(0x605, refuse)
        rig.add(5)
        await rig.master.boot(timeout=5)
        node = rig.master.nodes[5]
        assert state(node) is NodeState.WRONG_DEVICE
        (event,) = rig.of(IdentityMismatch)
        assert (event.field, event.actual) == ("vendor_id", None)
        assert "1018h sub 1 (vendor_id) is refused" in (node.problem or "")

    rig_test(cfg, scenario)


def test_closing_the_network_while_a_boot_waits_for_sdo_is_quiet(tmp_path, caplog):
    """The network closes while a node's 1000h read is pending, then the master stops: no
    traceback (it was a CancelledError chained to NetworkClosedError)."""
    cfg = network(tmp_path, net_text())

    async def main() -> list[MasterEvent]:
        events: list[MasterEvent] = []
        net = AsyncNetwork()
        async with net:
            master = Master(net, cfg)
            master.add_listener(events.append)
            master.start()
            await asyncio.sleep(3.2)  # no device: the master polls 1000h
            assert master.nodes[5].sdo.client.busy
        await master.stop()
        await asyncio.sleep(1.0)
        return events

    with caplog.at_level(logging.DEBUG):
        events = simulate(main())
    assert not [r for r in caplog.records if r.exc_info or r.levelno >= logging.WARNING]
    assert events  # (the master did run)


def test_a_node_the_master_must_not_initialise_gets_no_command(tmp_path):
    cfg = network(tmp_path, net_text(extra="    do_not_initialise: true\n"))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5, beating())
        device.simulation.sdo_response_delay = 3600.0  # hung, heartbeat PRE-OPERATIONAL
        rig.master.start()
        await rig.run(20.0)
        assert [d for d in rig.data(0x000) if d[1:] == b"\x05"] == []
        assert not rig.of(SdoUnanswered)

    rig_test(cfg, scenario)


def test_the_masters_own_stop_is_not_undone_by_a_wake(tmp_path):
    """The application stops the node (through this process's NMT service) while the master
    reads its 1000h after a boot-up: STOPPED is what this process asked for."""
    cfg = network(tmp_path, net_text())

    async def scenario(rig: Rig) -> None:
        await booted(rig)
        since = rig.net.time()
        rig.send(0x000, bytes([0x81, 5]))  # someone else resets it ...
        await rig.run(0.01)
        rig.net.nmt.stop(5)  # ... and the application stops it
        await rig.run(20.0)
        assert bytes([0x80, 5]) not in rig.data(0x000, since=since)
        assert not rig.of(SdoUnanswered)
        assert nmt(rig.devices[5]) is NmtState.STOPPED

    rig_test(cfg, scenario)
