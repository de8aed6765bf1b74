"""SYNC sent by the CAN interface itself (``net.sync.start(..., by_interface=True)``).

SocketCAN's kernel (its broadcast manager) is the interface this is for; this kernel has no
SocketCAN, so python-can's ``udp_multicast``, whose python-can thread sends and whose
multicast loopback hands the frames back, stands in for it: the same path through cobus (a
sequence of frames handed to the interface, heard back from the bus).
"""

from __future__ import annotations

import asyncio
import random
import time

import can
import pytest

from cobus.proto import Frame
from cobus.proto.sync import SyncConfigError
from cobus.runtime import AsyncNetwork, HandlerFailed, Network
from cobus.runtime.periodic import InterfaceTimer, InterfaceTimingError, interface_timing
from cobus.runtime.remote import NetworkSync
from tests.test_runtime_fd_read import _multicast_or_skip, _until
from tests.test_runtime_fd_read import _on_real_time_loop as _real_time


def _group_or_skip() -> tuple[str, int]:
    """A multicast group and a port of this test's own (skips where multicast is not)."""
    from can.interfaces.udp_multicast import UdpMulticastBus

    group, port = UdpMulticastBus.DEFAULT_GROUP_IPv6, random.randrange(20000, 40000)
    _multicast_or_skip(group, port)
    return group, port


def _state(sync: NetworkSync) -> tuple[bool, bool, float | None]:
    """running, by_interface, period (read through a call: mypy would keep an earlier
    assert's narrowing of the properties)"""
    return sync.running, sync.by_interface, sync.period


def test_the_interface_sends_sync_with_its_counter_and_both_networks_hear_it():
    """The producing network hears its own SYNC from the bus (its synchronous PDOs and a
    device on it need it), once; the other network hears the same sequence."""
    group, port = _group_or_skip()

    async def main() -> None:
        async with (
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as master,
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as field,
        ):
            mine: list[bytes] = []
            theirs: list[bytes] = []
            master.subscribe(0x80, lambda f, now: mine.append(f.data))
            field.subscribe(0x80, lambda f, now: theirs.append(f.data))
            master.sync.start(0.002, overflow=3, by_interface=True)
            assert _state(master.sync) == (True, True, 0.002)
            await _until(lambda: len(mine) >= 7 and len(theirs) >= 7)
            master.sync.stop()
            assert _state(master.sync) == (False, False, None)
            await asyncio.sleep(0.02)  # (the last one sent on its way back)
            heard = len(mine)
            await asyncio.sleep(0.05)
            assert len(mine) == heard  # stopped: nothing is sent once stop() returns
            assert mine == theirs  # each SYNC once, in order, on both sides
            first = mine.index(b"\x01")
            assert first < 3
            assert mine[first : first + 6] == [b"\x01", b"\x02", b"\x03"] * 2
            assert master.sync.late_max == 0.0 and master.sync.skipped == 0

    _real_time(main)


def test_the_blocking_network_hands_sync_without_counter_to_the_interface():
    group, port = _group_or_skip()
    with (
        Network(interface="udp_multicast", channel=group, port=port) as master,
        Network(interface="udp_multicast", channel=group, port=port) as field,
    ):
        heard: list[Frame] = []
        field.subscribe(0x80, lambda f, now: heard.append(f))
        master.sync.start(0.005, by_interface=True)
        deadline = time.monotonic() + 3.0
        while len(heard) < 10:
            assert time.monotonic() < deadline, "timed out"
            time.sleep(0.005)
        assert master.sync.by_interface
        master.sync.send()  # without a counter, one SYNC in between is fine
        master.sync.stop()
        assert set(heard) == {Frame(0x80)}


def test_a_sync_in_between_would_break_the_interfaces_count():
    group, port = _group_or_skip()

    async def main() -> None:
        async with AsyncNetwork(interface="udp_multicast", channel=group, port=port) as net:
            net.sync.start(0.01, overflow=4, by_interface=True)
            with pytest.raises(SyncConfigError, match="break its count"):
                net.sync.send()
            net.sync.start(0.01, overflow=4)  # the loop's producer replaces it
            assert _state(net.sync)[:2] == (True, False)
            net.sync.send()
            net.sync.stop()

    _real_time(main)


def test_a_new_start_replaces_the_interfaces_sync_without_overlap():
    """The old sequence is stopped before the new one starts: with a COB-ID of its own for
    each start, the identifiers heard never go back."""
    group, port = _group_or_skip()

    async def main() -> None:
        async with (
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as master,
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as field,
        ):
            heard: list[int] = []
            field.subscribe_all(lambda f, now: heard.append(f.cob_id))
            ids = range(0x700, 0x728)
            for cob_id in ids:
                master.sync.start(0.001, overflow=3, cob_id=cob_id, by_interface=True)
                await asyncio.sleep(0.003)
            master.sync.stop()
            await asyncio.sleep(0.05)
            syncs = [cob_id for cob_id in heard if cob_id in ids]
            assert len(set(syncs)) > 10
            assert syncs == sorted(syncs)

    _real_time(main)


def test_a_network_not_connected_or_on_the_simulated_clock_refuses(tmp_path):
    """python-can would send all the same: from a network not connected, or in wall-clock
    time under a simulated clock."""
    from cobus.runtime import NetworkClosedError, SimulatedEventLoop

    group, port = _group_or_skip()
    bus = can.Bus(interface="udp_multicast", channel=group, port=port)
    try:
        net = AsyncNetwork(bus)
        with pytest.raises(NetworkClosedError):
            net.sync.start(0.001, by_interface=True)

        async def main() -> None:
            async with AsyncNetwork(bus) as sim:
                with pytest.raises(InterfaceTimingError, match="simulated clock"):
                    sim.sync.start(0.001, by_interface=True)
                assert not sim.sync.running

        loop = SimulatedEventLoop()
        try:
            loop.run_until_complete(main())
        finally:
            loop.close()
    finally:
        bus.shutdown()


def test_disconnecting_stops_the_interface_sending_on_a_bus_the_user_keeps():
    group, port = _group_or_skip()
    bus = can.Bus(interface="udp_multicast", channel=group, port=port)
    listener = can.Bus(interface="udp_multicast", channel=group, port=port)
    try:

        async def main() -> None:
            async with AsyncNetwork(bus) as net:
                net.sync.start(0.002, by_interface=True)
                await asyncio.sleep(0.05)
            assert net.sync.running  # (it resumes when the network connects again)

        _real_time(main)
        time.sleep(0.05)  # (one the thread was sending as it stopped)
        while listener.recv(0) is not None:
            pass
        assert listener.recv(0.1) is None  # the user's bus is open, and silent
    finally:
        listener.shutdown()
        bus.shutdown()


def test_a_failing_send_is_reported_and_sending_goes_on(caplog):
    group, port = _group_or_skip()
    bus = can.Bus(interface="udp_multicast", channel=group, port=port)
    send = bus.send
    failures = iter(range(3))

    def flaky(msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == 0x80 and next(failures, None) is not None:
            raise can.CanOperationError("No buffer space available [Error Code 105]")
        send(msg, timeout)

    bus.send = flaky  # type: ignore[method-assign]
    try:

        async def main() -> None:
            async with AsyncNetwork(bus) as net:
                events: list[object] = []
                heard: list[Frame] = []
                net.add_listener(events.append)
                net.subscribe(0x80, lambda f, now: heard.append(f))
                net.sync.start(0.002, by_interface=True)
                await _until(lambda: len(heard) >= 5)
                net.sync.stop()
                assert net.sync.send_errors == 3
                failed = [e for e in events if isinstance(e, HandlerFailed)]
                assert len(failed) == 1  # the 1st of a run is reported, then the 10th...
                assert "0x80" in failed[0].where and "No buffer space" in failed[0].error

        _real_time(main)
    finally:
        bus.shutdown()


def test_an_interface_whose_periodic_frames_nobody_here_would_hear_is_refused():
    """python-can's virtual bus sends periodic frames from a thread, which its own bus object
    never hears: the network's listeners would miss every SYNC."""

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel="periodic-refused") as net:
            assert interface_timing(net.bus) is None
            with pytest.raises(InterfaceTimingError, match="the virtual interface cannot"):
                net.sync.start(0.001, by_interface=True)
            assert not net.sync.running
            net.sync.start(0.01)  # the loop's producer
            with pytest.raises(InterfaceTimingError):  # a failed start keeps what runs
                net.sync.start(0.001, by_interface=True)
            assert _state(net.sync)[:2] == (True, False)
            net.sync.stop()

    _real_time(main)


def test_bad_sequences_and_periods_are_refused_before_anything_is_sent():
    group, port = _group_or_skip()

    async def main() -> None:
        async with AsyncNetwork(interface="udp_multicast", channel=group, port=port) as net:
            for frames, period in (
                ([], 0.01),
                ([Frame(0x80)] * 257, 0.01),
                ([Frame(0x80)], 0.0),
                ([Frame(0x80)], float("nan")),
            ):
                with pytest.raises(InterfaceTimingError):
                    InterfaceTimer(net, frames, period)
            with pytest.raises(SyncConfigError, match="overflow"):
                net.sync.start(0.01, overflow=241, by_interface=True)
            with pytest.raises(ValueError, match="out of range"):
                net.sync.start(0.0, by_interface=True)
            assert not net.sync.running

    _real_time(main)


def test_socketcan_would_be_timed_by_the_kernel():
    """No SocketCAN here: python-can's own class, never opened, decides."""
    from can.interfaces.socketcan import SocketcanBus

    assert interface_timing(SocketcanBus.__new__(SocketcanBus)) == "kernel"


def test_a_master_whose_interface_times_sync_boots_on_the_sync_it_hears_back(tmp_path):
    """The master starts its nodes once its first SYNC is out: with the interface sending
    it, the master learns that from the bus."""
    from cobus.master import Master
    from cobus.runtime import run
    from tests.test_master_support import io_od, network

    group, port = _group_or_skip()
    text = (
        "master: {sync_period: 5, sync_overflow: 4, sync_by_interface: true}\n"
        "nodes:\n  io:\n    node_id: 5\n    eds: io.eds\n"
    )
    cfg = network(tmp_path, text)
    assert cfg.master.sync_by_interface

    async def main() -> list[bytes]:
        from cobus.device import add_device

        async with (
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as net,
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as field,
        ):
            device = add_device(field, 5, io_od())
            heard: list[bytes] = []
            field.subscribe(0x80, lambda f, now: heard.append(f.data))
            master = Master(net, cfg)
            try:
                await master.boot(timeout=10)
                assert net.sync.by_interface
                assert device.state.name == "OPERATIONAL"
            finally:
                await master.stop()
            assert not net.sync.running  # stopped with the master
            return heard

    heard = run(main())
    assert {b"\x01", b"\x02", b"\x03", b"\x04"} <= set(heard)


def test_a_master_on_an_interface_that_cannot_time_sync_refuses_to_start(tmp_path):
    from cobus.master import Master, MasterError
    from tests.test_master_support import network

    text = (
        "master: {sync_period: 10, sync_by_interface: true}\n"
        "nodes:\n  io:\n    node_id: 5\n    eds: io.eds\n"
    )
    cfg = network(tmp_path, text)

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel="periodic-master") as net:
            master = Master(net, cfg)
            with pytest.raises(MasterError, match=r"master\.sync_by_interface: .*set it to false"):
                master.start()
            assert not master.started and not net.sync.running
            master.config.master.sync_by_interface = False  # the loop's producer, then
            master.start()
            assert _state(net.sync)[:2] == (True, False)
            await master.stop()

    _real_time(main)


def test_sync_by_interface_must_be_true_or_false(tmp_path):
    from cobus.master import NetworkConfigError
    from tests.test_master_support import network

    with pytest.raises(NetworkConfigError, match=r"sync_by_interface.*not true or false"):
        network(tmp_path, "master: {sync_period: 10, sync_by_interface: 1}\nnodes: {}\n")
    text = "master: {sync_by_interface: true}\nnodes:\n  io:\n    node_id: 5\n    eds: io.eds\n"
    warnings = [str(w) for w in network(tmp_path, text).warnings]
    assert any(
        "master.sync_by_interface: warning: the master sends no SYNC without a sync_period" in w
        for w in warnings
    ), warnings


def test_a_bus_shut_down_under_the_interfaces_sync_ends_it():
    """Not a flood of failures at 1 kHz: the bus is gone for good."""
    group, port = _group_or_skip()
    bus = can.Bus(interface="udp_multicast", channel=group, port=port)

    async def main() -> None:
        net = AsyncNetwork(bus, read_on_loop=False)
        await net.connect()
        try:
            net.sync.start(0.001, by_interface=True)
            await asyncio.sleep(0.01)
            bus.shutdown()
            await _until(lambda: not _state(net.sync)[0])
            assert net.sync.send_errors == 0  # (not counted as failed sends)
        finally:
            await net.disconnect()

    try:
        _real_time(main)
    finally:
        bus.shutdown()


def test_a_device_that_produces_sync_can_have_the_interface_time_it():
    """A cobus device told by 1005h to produce SYNC: by the interface, with its counter from
    1; silent while stopped or with 1006h at 0, from 1 again after; it hears its own SYNC
    from the bus (a TPDO on every SYNC follows); closing it ends the SYNC."""
    from cobus.device import DictionaryBuilder, add_device
    from cobus.od import DataType

    group, port = _group_or_skip()
    b = DictionaryBuilder(device_name="producer")
    b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
    b.tpdo(1, [(0x2000, 0)], transmission_type=1)  # every SYNC

    async def main() -> None:
        async with (
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as field,
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as master,
        ):
            device = add_device(field, 5, b.build(), sync_by_interface=True)
            heard: list[tuple[int, bytes]] = []
            master.subscribe(0x80, lambda f, now: heard.append((0x80, f.data)))
            master.subscribe(0x185, lambda f, now: heard.append((0x185, f.data)))
            master.nmt.start(5)
            device.set(0x1019, 0, 3)
            device.set(0x1005, 0, 0x40000080)
            device.set(0x1006, 0, 2000)  # 2 ms
            await _until(lambda: sum(1 for c, _ in heard if c == 0x80) >= 6)
            syncs = [d for c, d in heard if c == 0x80]
            assert syncs[:6] == [b"\x01", b"\x02", b"\x03"] * 2
            await _until(lambda: any(c == 0x185 for c, _ in heard))  # its TPDO on SYNC
            master.nmt.stop(5)
            await _until(lambda: device.state.name == "STOPPED")
            await asyncio.sleep(0.02)
            count = len(heard)
            await asyncio.sleep(0.03)
            assert len(heard) == count  # silent while stopped
            master.nmt.send("enter_preoperational", 5)
            await _until(lambda: len(heard) > count)
            assert heard[count] == (0x80, b"\x01")  # the counter starts again
            device.set(0x1006, 0, 0)
            await asyncio.sleep(0.02)
            count = len(heard)
            await asyncio.sleep(0.03)
            assert len(heard) == count  # no period, no SYNC
            device.set(0x1006, 0, 1000)
            await _until(lambda: len(heard) > count)
            assert heard[count] == (0x80, b"\x01")
            device.close()
            await asyncio.sleep(0.02)
            count = len(heard)
            await asyncio.sleep(0.03)
            assert len(heard) == count

    _real_time(main)


def test_a_device_on_an_interface_that_cannot_time_sync_is_refused():
    from cobus.device import add_device, minimal_od

    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel="periodic-device") as net:
            with pytest.raises(InterfaceTimingError, match="the virtual interface cannot"):
                add_device(net, 5, minimal_od(), sync_by_interface=True)
            assert 5 not in net.devices
            add_device(net, 5, minimal_od())  # the node-ID is free

    _real_time(main)


def test_the_interfaces_sync_resumes_when_the_network_connects_again():
    """As the loop's producer does: a network, and a device producing SYNC on one."""
    from cobus.device import add_device, minimal_od

    group, port = _group_or_skip()

    async def main() -> None:
        async with (
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as net,
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as field,
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as listener,
        ):
            heard: list[int] = []
            listener.subscribe_all(lambda f, now: heard.append(f.cob_id))
            net.sync.start(0.002, overflow=3, by_interface=True)
            device = add_device(field, 5, minimal_od(), sync_by_interface=True)
            device.set(0x1005, 0, 0x40000081)  # the device's SYNC on 81h
            device.set(0x1006, 0, 2000)
            await _until(lambda: {0x80, 0x81} <= set(heard))
            await net.disconnect()
            await field.disconnect()
            assert _state(net.sync) == (True, True, 0.002)  # (resumes on connect)
            await asyncio.sleep(0.02)
            count = len(heard)
            await asyncio.sleep(0.03)
            assert len(heard) == count  # both silent
            await net.connect()
            await field.connect()
            assert _state(net.sync) == (True, True, 0.002)
            await _until(lambda: {0x80, 0x81} <= set(heard[count:]))
            net.sync.stop()
            device.close()
            assert not field._on_connect  # (the closed device is forgotten)

    _real_time(main)


def test_a_master_on_the_simulated_clock_has_its_loop_time_sync(tmp_path):
    """The same network description runs on a simulated bench: no interface there."""
    from tests.test_master_support import Rig, network, rig_test

    text = (
        "master: {sync_period: 10, sync_by_interface: true}\n"
        "nodes:\n  io:\n    node_id: 5\n    eds: io.eds\n"
    )

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        await rig.master.boot(timeout=5)
        assert rig.net.sync.running and not rig.net.sync.by_interface
        await rig.run(0.1)
        assert len(rig.data(0x80)) >= 9

    rig_test(network(tmp_path, text), scenario)


def test_a_period_that_is_no_number_is_out_of_range():
    async def main() -> None:
        async with AsyncNetwork(interface="virtual", channel="periodic-nan") as net:
            for period in (float("nan"), float("inf")):
                with pytest.raises(ValueError, match="out of range"):
                    net.sync.start(period)

    _real_time(main)


def test_the_shell_sends_as_many_syncs_as_asked_by_the_interface(monkeypatch, capsys):
    """``cobus sync --count N --by-interface``: N SYNCs, with the counter; the port of
    udp_multicast comes from python-can's configuration."""
    import json

    from cobus.cli import main

    group, port = _group_or_skip()
    monkeypatch.setenv("CAN_CONFIG", json.dumps({"port": port}))
    listener = can.Bus(interface="udp_multicast", channel=group, port=port)
    try:
        args = ["--period", "0.002", "--count", "7", "--overflow", "3", "--by-interface"]
        assert main(["sync", *args, "-i", "udp_multicast", "-c", group]) == 0
        out = capsys.readouterr().out
        got = []
        while (msg := listener.recv(0.2)) is not None:
            if msg.arbitration_id == 0x80:
                got.append(bytes(msg.data))
        # the 8th may be on its way when the 7th comes back: what went out is printed
        assert got[:7] == [b"\x01", b"\x02", b"\x03"] * 2 + [b"\x01"] and len(got) <= 8
        assert out.startswith(f"{len(got)} SYNC sent by the interface, every 0.002 s")
    finally:
        listener.shutdown()


def test_a_device_sends_its_interface_timed_sync_after_its_boot_up_and_keeps_the_phase():
    """A device whose dictionary makes it a producer: its first SYNC one period after its
    boot-up (the interface would send at once), none while initialising after a reset from
    stopped; writing the same 1005h or 1006h again keeps the SYNC's phase."""
    from cobus.device import add_device, minimal_od

    group, port = _group_or_skip()
    od = minimal_od()
    for index, default in ((0x1005, 0x40000080), (0x1006, 5000)):  # SYNC every 5 ms
        variable = od.get_variable(index, 0)
        assert variable is not None
        variable.default = default

    async def main() -> None:
        async with (
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as field,
            AsyncNetwork(interface="udp_multicast", channel=group, port=port) as master,
        ):
            heard: list[tuple[float, int]] = []
            master.subscribe_all(lambda f, now: heard.append((now, f.cob_id)))
            device = add_device(field, 5, od, sync_by_interface=True)
            await _until(lambda: sum(1 for _, c in heard if c == 0x80) >= 3)
            assert heard[0][1] == 0x705  # the boot-up first
            boot, first = heard[0][0], next(t for t, c in heard if c == 0x80)
            assert first - boot > 0.003  # one period after it, not at once
            master.nmt.stop(5)
            await _until(lambda: device.state.name == "STOPPED")
            await asyncio.sleep(0.02)
            heard.clear()
            master.nmt.reset_node(5)
            await _until(lambda: sum(1 for _, c in heard if c == 0x80) >= 2)
            cobs = [c for _, c in heard]
            assert cobs.index(0x705) < cobs.index(0x80)  # no SYNC while initialising
            await asyncio.sleep(0.012)
            timer = device._sync._timer
            assert timer is not None and timer.running
            count = sum(1 for _, c in heard if c == 0x80)
            device.set(0x1005, 0, 0x40000080)  # the same values again, as a
            device.set(0x1006, 0, 5000)  # configuration download writes them
            await _until(lambda: sum(1 for _, c in heard if c == 0x80) >= count + 3)
            # the same sequence goes on: not stopped and started again (python-can's thread
            # catches up after a late send, so the intervals heard cannot tell)
            assert device._sync._timer is timer and timer.running
            device.close()

    _real_time(main)


def test_the_shell_gives_up_when_no_sync_goes_out(monkeypatch, capsys):
    """A bus that takes no frame: the SYNCs wait in the backlog, none is heard, and
    ``cobus sync --count`` says so instead of waiting for ever."""
    from can.interfaces.virtual import VirtualBus

    from cobus.cli import main

    def refuse(self: VirtualBus, msg: can.Message, timeout: float | None = None) -> None:
        raise can.CanOperationError("No buffer space available [Error Code 105]")

    monkeypatch.setattr(VirtualBus, "send", refuse)
    args = ["sync", "--period", "0.01", "--count", "3", "-i", "virtual", "-c", "no-sync"]
    assert main(args) == 1  # (it gives up: waiting for ever would hit the suite's timeout)
    assert "only 0 of 3 SYNC went out" in capsys.readouterr().err
