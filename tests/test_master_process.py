"""The process image: inputs from the nodes' TPDOs and outputs to their RPDOs, by name, scaled,
sent on SYNC or on change, and blocked while a node is not operational; and the blocking
master for scripts."""

from __future__ import annotations

import itertools
import time

import pytest

from cobus.device import add_device
from cobus.master import (
    BlockingMaster,
    Diagnostic,
    MasterState,
    NodeState,
    SignalError,
    SignalValueError,
)
from cobus.proto.nmt import NmtCommand, NmtState
from cobus.proto.pdo import Kind
from cobus.runtime import Network
from tests.test_master_support import (
    Rig,
    diagnostic,
    io_od,
    master_state,
    network,
    nmt,
    rig_test,
    state,
)

TEXT = """
master: {{node_id: 127, heartbeat_time: 100, sync_period: 10}}
nodes:
  a:
    node_id: 5
    eds: io.eds
    heartbeat_time: 100
    tpdo1: {{mapping: [counter, ready], transmission_type: 255, event_timer: 50}}
    tpdo2: {{mapping: [temperature], transmission_type: 1}}
    rpdo1: {{mapping: [setpoint, flags], transmission_type: {rpdo1}}}
    signals:
      count: {{object: counter, scale: 0.5, offset: 1, unit: pieces}}
      target: {{object: setpoint, scale: 0.1}}
"""


def config(tmp_path, rpdo1: str = "255"):
    return network(tmp_path, TEXT.format(rpdo1=rpdo1))


async def booted(rig: Rig) -> None:
    rig.add(5)
    await rig.master.boot(timeout=5)
    await rig.run(0.1)


def test_inputs_by_name_scaled_from_the_tpdos(tmp_path):
    async def scenario(rig: Rig) -> None:
        await booted(rig)
        device = rig.devices[5]
        inputs = rig.master.inputs
        device.set(0x2000, 0, 10)
        device.set(0x2004, 0, True)
        device.set(0x2003, 0, 21.5)
        await rig.run(0.05)
        assert inputs["a.count"] == 6.0  # 10 x 0.5 + 1
        assert inputs["a.counter"] == 6.0  # the EDS name finds the aliased signal too
        assert inputs["a.ready"] is True
        assert inputs["a.temperature"] == 21.5  # TPDO 2, sent on every SYNC
        assert sorted(inputs) == ["a.count", "a.ready", "a.temperature"]
        assert "a.counter" in inputs and "a.nothing" not in inputs
        signal = inputs.signal("a.count")
        assert (signal.node_id, signal.pdo, signal.index, signal.unit) == (5, 1, 0x2000, "pieces")
        assert inputs.signal("a.temperature").kind is Kind.REAL32
        with pytest.raises(SignalError, match=r"close: a\.count") as err:
            inputs["a.cont"]
        assert isinstance(err.value, KeyError)

    rig_test(config(tmp_path), scenario)


def test_event_driven_outputs_go_out_on_change(tmp_path):
    async def scenario(rig: Rig) -> None:
        await booted(rig)
        device = rig.devices[5]
        before = len(rig.data(0x205))
        assert before == 1  # each RPDO is sent once when the node starts
        rig.master.outputs["a.target"] = -1.2  # raw -12
        rig.master.outputs["a.flags"] = 0x81
        await rig.settle()
        assert device.get(0x2001) == -12 and device.get(0x2002) == 0x81
        assert rig.data(0x205)[before:] == [b"\xf4\xff\x00", b"\xf4\xff\x81"]
        rig.master.outputs["a.flags"] = 0x81  # unchanged: nothing sent
        await rig.settle()
        assert len(rig.data(0x205)) == before + 2
        assert rig.master.outputs["a.target"] == -1.2
        assert rig.master.outputs["a.setpoint"] == -1.2
        assert rig.master.nodes[5].rpdo_sent[1] == 3
        assert rig.master.diagnostics.pdo_counters[(5, "rpdo", 1)] == 3

    rig_test(config(tmp_path), scenario)


def test_output_values_are_checked_before_they_are_kept(tmp_path):
    async def scenario(rig: Rig) -> None:
        await booted(rig)
        outputs = rig.master.outputs
        with pytest.raises(SignalValueError, match=r"limits -1000\.\.1000"):
            outputs["a.target"] = 500.0  # raw 5000: beyond the object's HighLimit
        with pytest.raises(SignalValueError, match=r"a\.flags cannot carry 300"):
            outputs["a.flags"] = 300
        with pytest.raises(SignalValueError):
            outputs["a.flags"] = "many"
        with pytest.raises(SignalError, match=r"no output signal 'a\.count'"):
            outputs["a.count"] = 1  # an input
        assert outputs["a.target"] == 0.0  # nothing was kept

    rig_test(config(tmp_path), scenario)


def test_synchronous_outputs_go_out_with_every_sync(tmp_path):
    async def scenario(rig: Rig) -> None:
        await booted(rig)
        device = rig.devices[5]
        rig.master.outputs["a.target"] = 2.5
        await rig.settle()
        assert device.get(0x2001) == 0  # type 1: applied at the next SYNC
        since = rig.master.network.time()
        await rig.run(0.1)
        assert device.get(0x2001) == 25
        sent = [t for t, f in rig.on(0x205) if t > since]
        syncs = [t for t, f in rig.on(0x080) if t > since]
        assert sent == syncs  # one RPDO right after each SYNC

    rig_test(config(tmp_path, "1"), scenario)


def test_acyclic_synchronous_outputs_go_out_at_the_sync_after_a_change(tmp_path):
    async def scenario(rig: Rig) -> None:
        await booted(rig)
        device = rig.devices[5]
        since = rig.master.network.time()
        await rig.run(0.1)
        assert [t for t, _ in rig.on(0x205) if t > since] == []  # nothing changed
        rig.master.outputs["a.target"] = 0.7
        rig.master.outputs["a.flags"] = 1
        await rig.run(0.1)
        assert len([t for t, _ in rig.on(0x205) if t > since]) == 1
        assert (device.get(0x2001), device.get(0x2002)) == (7, 1)

    rig_test(config(tmp_path, "0"), scenario)


def test_event_driven_outputs_with_an_event_timer_are_refreshed(tmp_path):
    text = TEXT.format(rpdo1="255").replace(
        "[setpoint, flags], transmission_type: 255",
        "[setpoint, flags], transmission_type: 255, event_timer: 100",
    )

    async def scenario(rig: Rig) -> None:
        await booted(rig)
        since = rig.master.network.time()
        await rig.run(0.5)
        times = [t for t, _ in rig.on(0x205) if t > since]
        assert len(times) >= 9  # every half of the node's event timer
        assert all(b - a == pytest.approx(0.05) for a, b in itertools.pairwise(times))
        assert nmt(rig.devices[5]) is NmtState.OPERATIONAL
        assert diagnostic(rig.master.nodes[5]) is Diagnostic.OK

    rig_test(network(tmp_path, text), scenario)


def test_process_data_is_blocked_while_the_node_is_not_operational(tmp_path):
    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        rig.master.start()
        rig.master.outputs["a.flags"] = 5  # kept until the node runs
        await rig.settle()
        assert rig.data(0x205) == []
        await rig.master.boot(timeout=5)
        await rig.settle()
        assert rig.data(0x205) == [b"\x00\x00\x05"]  # sent once at the start
        assert device.get(0x2002) == 5
        device.apply_nmt(NmtCommand.STOP)
        await rig.run(0.2)
        rig.master.outputs["a.flags"] = 6
        await rig.settle()
        assert rig.data(0x205) == [b"\x00\x00\x05"]  # nothing to a stopped node
        rig.send(0x185, b"\x10\x00\x01")  # a stray TPDO while stopped is not taken
        await rig.settle()
        assert rig.master.inputs["a.count"] == 0.0

    rig_test(config(tmp_path), scenario)


def test_blocking_master_for_scripts(tmp_path):
    cfg = config(tmp_path)
    with Network(simulated=True) as net:
        device = add_device(net, 5, io_od())
        master = BlockingMaster(net, cfg)
        seen: list[object] = []
        master.add_listener(seen.append)
        master.boot(timeout=5)
        assert master_state(master) is MasterState.RUNNING
        assert state(master.node("a")) is NodeState.OPERATIONAL
        assert diagnostic(master.nodes[5]) in (Diagnostic.OK, Diagnostic.TPDOS_PENDING)
        device.set(0x2000, 0, 4)
        master.sleep(0.1)
        assert master.inputs["a.count"] == 3.0
        master.outputs["a.target"] = 0.3
        master.sleep(0.01)
        assert device.get(0x2001) == 3 and master.outputs["a.target"] == 0.3
        assert master.bus_load > 0
        assert master.diagnostics.frames > 0
        assert len(seen) > 5
        master.stop(stop_nodes=True)
        master.sleep(0.01)
        assert nmt(device) is NmtState.STOPPED
        master.start()
        master.sleep(1.0)
        assert master_state(master) is MasterState.RUNNING
        master.restart_node(5)
        assert state(master.nodes[5]) is NodeState.OPERATIONAL


def test_blocking_master_in_real_time_on_a_virtual_bus(tmp_path):
    text = TEXT.format(rpdo1="255").replace("sync_period: 10}", "sync_period: 10, bootup_delay: 0}")
    cfg = network(tmp_path, text)
    with Network(interface="virtual", channel=f"master-rt-{id(cfg)}") as net:
        device = add_device(net, 5, io_od())
        master = BlockingMaster(net, cfg)
        master.boot(timeout=10)
        assert master_state(master) is MasterState.RUNNING
        device.set(0x2000, 0, 8)
        deadline = time.monotonic() + 5
        while master.inputs["a.count"] != 5.0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert master.inputs["a.count"] == 5.0
        master.outputs["a.flags"] = 3
        while device.get(0x2002) != 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert device.get(0x2002) == 3
        master.stop()


def test_an_object_in_several_pdos_is_one_signal(tmp_path):
    text = TEXT.format(rpdo1="255").replace(
        "    signals:",
        "    rpdo2: {mapping: [flags], transmission_type: 255}\n"
        "    tpdo3: {mapping: [counter], transmission_type: 255}\n"
        "    signals:",
    )

    async def scenario(rig: Rig) -> None:
        await booted(rig)
        device = rig.devices[5]
        rig.master.outputs["a.flags"] = 9  # carried by RPDO 1 and RPDO 2
        await rig.settle()
        assert rig.data(0x205)[-1] == b"\x00\x00\x09"
        assert rig.data(0x305)[-1] == b"\x09"
        assert device.get(0x2002) == 9
        device.set(0x2000, 0, 12)  # sent by TPDO 1 and TPDO 3
        await rig.settle()
        assert rig.master.inputs["a.count"] == 7.0
        rig.send(0x385, b"\x14\x00")  # TPDO 3 alone
        await rig.settle()
        assert rig.master.inputs["a.count"] == 11.0
        assert sorted(rig.master.outputs) == ["a.flags", "a.target"]

    rig_test(network(tmp_path, text), scenario)
