"""CiA 302-2 boot-up of a network by the master, against simulated devices on the simulated
clock: resets, boot-up, checks, configuration, error control set-up, start."""

from __future__ import annotations

import itertools

import pytest

from cobus.master import (
    BootTimeoutError,
    ConfigurationFailed,
    DeviceTypeMismatch,
    Diagnostic,
    IdentityMismatch,
    MasterState,
    MasterStatus,
    NodeBooted,
    NodeMissing,
    NodeNotFoundError,
    NodeState,
    NodeStateChanged,
)
from cobus.od import Access
from cobus.proto.nmt import NmtState
from cobus.proto.sdo import SdoAbortCode
from tests.test_master_support import (
    VENDOR,
    Rig,
    diagnostic,
    io_od,
    master_state,
    network,
    nmt,
    rig_test,
    state,
    status,
    write_eds,
)

IO = """
    eds: io.eds
    heartbeat_time: 100
    device_type: 0x191
    vendor_id: 0x00C0B05
    tpdo1: {mapping: [counter], transmission_type: 255, event_timer: 50}
    rpdo1: {mapping: [setpoint], transmission_type: 255}
"""


def node_block(name: str, node_id: int, extra: str = "") -> str:
    return f"  {name}:\n    node_id: {node_id}\n" + IO + extra


def sdo_requests(rig: Rig, node_id: int, index: int, sub: int = 0) -> list[float]:
    """When the master asked node ``node_id`` for ``index:sub`` (upload requests)."""
    key = bytes((0x40, index & 0xFF, index >> 8, sub))
    return [t for t, f in rig.on(0x600 + node_id) if f.data[:4] == key]


def test_127_nodes_boot_to_operational(tmp_path):
    nodes = "".join(node_block(f"n{i}", i) for i in range(1, 128))
    text = "master: {sync_period: 20, reset: broadcast, start: broadcast}\nnodes:\n" + nodes
    cfg = network(tmp_path, text)

    async def scenario(rig: Rig) -> None:
        for node_id in range(1, 128):
            rig.add(node_id)
        await rig.master.boot(timeout=30)  # (its wall time: benchmarks/bench_master.py)
        assert master_state(rig.master) is MasterState.RUNNING
        assert all(state(n) is NodeState.OPERATIONAL for n in rig.master.nodes.values())
        await rig.run(0.5)  # heartbeats flow, TPDOs arrive
        for node_id, device in rig.devices.items():
            assert nmt(device) is NmtState.OPERATIONAL, node_id
            assert device.get(0x1017) == 100
            assert device.get(0x1A00, 1) == 0x20000010
            assert diagnostic(rig.master.nodes[node_id]) is Diagnostic.OK, node_id
        # one broadcast reset and one broadcast start, nothing else on 000h
        assert rig.data(0x000) == [b"\x81\x00", b"\x01\x00"]

    rig_test(cfg, scenario)


def test_per_node_reset_and_start_with_the_whole_sequence(tmp_path):
    text = "master: {node_id: 127, heartbeat_time: 100, sync_period: 10}\nnodes:\n"
    cfg = network(tmp_path, text + node_block("a", 5) + node_block("b", 6))

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        rig.add(6)
        await rig.master.boot(timeout=5)
        assert rig.data(0x000) == [b"\x81\x05", b"\x81\x06", b"\x01\x05", b"\x01\x06"]
        node = rig.master.nodes[5]
        states = [e.new for e in rig.of(NodeStateChanged) if e.node_id == 5]
        assert states == [
            NodeState.RESETTING,
            NodeState.AWAITING_BOOTUP,
            NodeState.WAITING,
            NodeState.CONFIGURING,
            NodeState.CONFIGURED,
            NodeState.OPERATIONAL,
        ]
        assert node.device_type == 0x191 and node.identity == {"vendor_id": VENDOR}
        assert node.error_control == "heartbeat"
        assert [e.expected for e in rig.of(NodeBooted) if e.node_id == 5][-1] is True
        # 1000h is read after the boot-up delay (300 ms)
        booted = [t for t, f in rig.on(0x705) if f.data == b"\x00"][-1]
        (asked,) = sdo_requests(rig, 5, 0x1000)
        assert asked - booted == pytest.approx(0.3)
        device = rig.devices[5]
        assert device.get(0x1006) == 10_000  # the master's SYNC period
        await rig.run(0.2)
        assert rig.data(0x77F)[-1:] == [b"\x05"]  # the master's heartbeat: operational
        assert len(rig.data(0x080)) >= 50  # SYNC every 10 ms from the start
        assert status(rig.master) is MasterStatus.RUN

    rig_test(cfg, scenario)


def test_optional_node_missing_does_not_hold_the_network(tmp_path):
    text = "nodes:\n" + node_block("a", 5) + node_block("b", 6, "    boot_timeout: 500\n")
    cfg = network(tmp_path, text)

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        await rig.master.boot(timeout=5)
        absent = rig.master.nodes[6]
        assert state(absent) is NodeState.ABSENT
        assert diagnostic(absent) is Diagnostic.NOT_FOUND
        assert state(rig.master.nodes[5]) is NodeState.OPERATIONAL
        assert len(sdo_requests(rig, 6, 0x1000)) == 1  # an optional node is asked once
        (missing,) = rig.of(NodeMissing)
        assert (missing.node_id, missing.mandatory) == (6, False)
        # it comes later: its boot-up makes the master configure and start it
        late = rig.add(6)
        await rig.run(1.0)
        assert state(absent) is NodeState.OPERATIONAL
        assert nmt(late) is NmtState.OPERATIONAL and late.get(0x1017) == 100

    rig_test(cfg, scenario)


def test_mandatory_node_missing_holds_the_network_with_a_clear_diagnostic(tmp_path):
    text = (
        "nodes:\n"
        + node_block("a", 5)
        + node_block("drive", 6, "    mandatory: true\n    boot_timeout: 500\n")
    )
    cfg = network(tmp_path, text)

    async def scenario(rig: Rig) -> None:
        present = rig.add(5)
        with pytest.raises(BootTimeoutError) as err:
            await rig.master.boot(timeout=3)
        message = str(err.value)
        assert "node 6 'drive' (mandatory)" in message
        assert "no boot-up and no answer to the 1000h read" in message
        assert "diagnostic 2" in message
        assert master_state(rig.master) is MasterState.CONFIGURING
        assert diagnostic(rig.master.nodes[6]) is Diagnostic.NOT_FOUND
        # the others are configured but not started
        assert state(rig.master.nodes[5]) is NodeState.CONFIGURED
        assert nmt(present) is NmtState.PRE_OPERATIONAL
        # 1000h is asked again every 0.5 s (after each SDO timeout of 1 s here)
        asked = sdo_requests(rig, 6, 0x1000)
        assert len(asked) >= 2
        assert all(b - a == pytest.approx(1.0) for a, b in itertools.pairwise(asked))
        assert [e.mandatory for e in rig.of(NodeMissing)] == [True]  # reported once
        rig.add(6)
        await rig.master.boot(timeout=5)
        assert master_state(rig.master) is MasterState.RUNNING
        assert nmt(present) is NmtState.OPERATIONAL
        assert diagnostic(rig.master.nodes[6]) is not Diagnostic.NOT_FOUND

    rig_test(cfg, scenario)


def test_wrong_device_type_is_state_98_and_the_node_is_left_unconfigured(tmp_path):
    text = "nodes:\n" + node_block("a", 5) + node_block("b", 6)
    cfg = network(tmp_path, text)

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        wrong = rig.add(6, io_od(device_type=0x20192))
        await rig.master.boot(timeout=5)  # b is optional: the network runs without it
        node = rig.master.nodes[6]
        assert state(node) is NodeState.WRONG_DEVICE
        assert diagnostic(node) is Diagnostic.SDO_DATA_MISMATCH
        assert "device type 0x00020192, expected 0x00000191" in (node.problem or "")
        (event,) = rig.of(DeviceTypeMismatch)
        assert (event.node_id, event.expected, event.actual) == (6, 0x191, 0x20192)
        assert nmt(wrong) is NmtState.PRE_OPERATIONAL
        assert wrong.get(0x1A00, 0) == 0  # its PDOs stay as they were (not configured)
        assert not [f for _, f in rig.on(0x606) if f.data[0] >> 5 == 1]  # no download

    rig_test(cfg, scenario)


def test_device_type_low_16_bits_only_lenze_style(tmp_path):
    extra = "    device_type_low16: true\n"
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, extra).replace("0x191", "0x30191"))

    async def scenario(rig: Rig) -> None:
        rig.add(5, io_od(device_type=0x10191))
        await rig.master.boot(timeout=5)
        assert state(rig.master.nodes[5]) is NodeState.OPERATIONAL

    rig_test(cfg, scenario)


def test_identity_mismatch_names_the_field(tmp_path):
    extra = "    mandatory: true\n    product_code: 0x401\n    serial_number: 0x1234\n"
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, extra))

    async def scenario(rig: Rig) -> None:
        rig.add(5)
        with pytest.raises(BootTimeoutError, match="serial_number"):
            await rig.master.boot(timeout=3)
        node = rig.master.nodes[5]
        assert state(node) is NodeState.WRONG_DEVICE
        assert diagnostic(node) is Diagnostic.SDO_DATA_MISMATCH
        (event,) = rig.of(IdentityMismatch)
        assert (event.field, event.subindex, event.expected, event.actual) == (
            "serial_number",
            4,
            0x1234,
            0xABCD,
        )
        assert node.identity == {
            "vendor_id": VENDOR,
            "product_code": 0x401,
            "serial_number": 0xABCD,
        }

    rig_test(cfg, scenario)


def test_sdo_abort_during_configuration_stops_that_node(tmp_path):
    # the master's EDS has an object the device lacks (an older firmware, say)
    eds_od = io_od()
    from cobus.od import Access, DataType, Variable

    eds_od.add(Variable(0x2100, 0, "Brake delay", DataType.UNSIGNED16, Access.RW, default=0))
    write_eds(tmp_path, "newer.eds", eds_od)
    extra = (
        "    mandatory: true\n    stop_on_abort: true\n"
        "    sdo: [{object: brake delay, value: 40}]\n"
    )
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, extra).replace("io.eds", "newer.eds"))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        with pytest.raises(BootTimeoutError, match="0x2100:00"):
            await rig.master.boot(timeout=3)
        node = rig.master.nodes[5]
        (failure,) = rig.of(ConfigurationFailed)
        assert (failure.node_id, failure.index, failure.subindex) == (5, 0x2100, 0)
        assert failure.abort_code == SdoAbortCode.NO_OBJECT
        assert "object does not exist" in failure.reason
        assert node.config_errors == [failure]
        assert state(node) is NodeState.CONFIGURING
        assert diagnostic(node) is Diagnostic.SDO_SYNTAX_ERROR
        assert nmt(device) is NmtState.PRE_OPERATIONAL

    rig_test(cfg, scenario)


def test_sdo_abort_without_stop_on_abort_is_reported_and_the_node_runs(tmp_path):
    eds_od = io_od()
    from cobus.od import Access, DataType, Variable

    eds_od.add(Variable(0x2100, 0, "Brake delay", DataType.UNSIGNED16, Access.RW, default=0))
    write_eds(tmp_path, "newer.eds", eds_od)
    extra = "    sdo: [{object: brake delay, value: 40}, {object: parameter, value: 3}]\n"
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, extra).replace("io.eds", "newer.eds"))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        await rig.master.boot(timeout=3)
        (failure,) = rig.of(ConfigurationFailed)
        assert failure.index == 0x2100
        assert device.get(0x200A) == 3  # the list went on after the abort
        assert nmt(device) is NmtState.OPERATIONAL
        await rig.run(0.2)
        assert diagnostic(rig.master.nodes[5]) is Diagnostic.OK

    rig_test(cfg, scenario)


def test_restore_defaults_once_before_configuring(tmp_path):
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, "    restore_defaults: true\n"))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        device.set(0x200A, 0, 99)
        device.store_parameters(1)  # survives resets until restored
        await rig.master.boot(timeout=5)
        assert device.get(0x200A) == 7  # the EDS default again
        load = bytes((0x23, 0x11, 0x10, 0x01)) + b"load"
        assert [f.data for _, f in rig.on(0x605) if f.data == load] == [load]
        # reset, restore, reset again
        assert rig.data(0x000) == [b"\x81\x05", b"\x81\x05", b"\x01\x05"]

    rig_test(cfg, scenario)


def test_do_not_initialise_leaves_the_node_alone_but_starts_it(tmp_path):
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, "    do_not_initialise: true\n"))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        await rig.master.boot(timeout=5)
        assert rig.data(0x000) == [b"\x01\x05"]  # no reset
        downloads = [f for _, f in rig.on(0x605) if f.data[0] >> 5 == 1]
        assert downloads == []
        assert nmt(device) is NmtState.OPERATIONAL
        assert device.get(0x1A00, 0) == 0  # not configured

    rig_test(cfg, scenario)


def test_heartbeat_refused_falls_back_to_node_guarding(tmp_path):
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5))

    async def scenario(rig: Rig) -> None:
        od = io_od()
        od.remove(0x1017)  # a device without heartbeat producer
        device = rig.add(5, od)
        await rig.master.boot(timeout=5)
        node = rig.master.nodes[5]
        assert node.error_control == "guarding"
        assert device.get(0x100C) == 100 and device.get(0x100D) == 3
        since = rig.master.network.time()
        await rig.run(1.0)
        requests = [t for t, f in rig.on(0x705, since=since) if f.rtr and t > since]
        assert len(requests) == 10  # every guard time
        replies = [f.data[0] for t, f in rig.on(0x705, since=since) if not f.rtr and t > since]
        assert len(replies) == 10
        assert {r & 0x7F for r in replies} == {0x05}  # operational
        toggles = [r >> 7 for r in replies]
        assert all(a != b for a, b in itertools.pairwise(toggles))
        assert diagnostic(node) is Diagnostic.OK

    rig_test(cfg, scenario)


def test_master_stop_ends_supervision_and_can_start_again(tmp_path):
    master = "master: {sync_period: 10, node_id: 127, heartbeat_time: 100, time_period: 100}"
    cfg = network(tmp_path, master + "\nnodes:\n" + node_block("a", 5))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        await rig.master.boot(timeout=5)
        assert rig.data(0x77F) and rig.data(0x100)  # its heartbeat and TIME run
        await rig.master.stop(stop_nodes=True)
        assert status(rig.master) is MasterStatus.OFFLINE
        assert state(rig.master.nodes[5]) is NodeState.UNDEFINED
        await rig.settle()
        assert nmt(device) is NmtState.STOPPED
        produced = [len(rig.data(cob)) for cob in (0x080, 0x77F, 0x100)]
        await rig.run(1.0)
        # SYNC, the master's heartbeat and TIME stopped with the master
        assert [len(rig.data(cob)) for cob in (0x080, 0x77F, 0x100)] == produced
        await rig.master.boot(timeout=5)
        assert nmt(device) is NmtState.OPERATIONAL

    rig_test(cfg, scenario)


def test_master_producers_and_what_the_nodes_get_written(tmp_path):
    text = (
        "master: {node_id: 127, heartbeat_time: 100, sync_period: 10, sync_overflow: 4,"
        " time_period: 100}\nnodes:\n" + node_block("a", 5, "    watch_master: true\n")
    )
    cfg = network(tmp_path, text)

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        await rig.master.boot(timeout=5)
        assert device.get(0x1016, 1) == (127 << 16) | 150  # watches the master, 1.5 x 100 ms
        assert device.get(0x1019) == 4 and device.get(0x1006) == 10_000
        since = rig.master.network.time()
        await rig.run(0.5)
        counters = [f.data[0] for t, f in rig.on(0x080) if t > since]
        assert counters[:8] in (
            [1, 2, 3, 4, 1, 2, 3, 4],
            [2, 3, 4, 1, 2, 3, 4, 1],
            [3, 4, 1, 2, 3, 4, 1, 2],
            [4, 1, 2, 3, 4, 1, 2, 3],
        )
        stamps = [t for t, f in rig.on(0x100) if t > since]
        assert len(stamps) in (4, 5) and all(len(f.data) == 6 for _, f in rig.on(0x100))
        assert all(b - a == pytest.approx(0.1) for a, b in itertools.pairwise(stamps))
        beats = [t for t, f in rig.on(0x77F) if t > since]
        assert all(b - a == pytest.approx(0.1) for a, b in itertools.pairwise(beats))
        assert rig.master.summary()[0]["state"] == 5
        with pytest.raises(NodeNotFoundError, match="the nodes are: a \\(5\\)"):
            rig.master.node("b")

    rig_test(cfg, scenario)


def test_disabled_and_not_started_nodes_keep_the_broadcast_start_from_being_used(tmp_path):
    text = (
        "master: {start: broadcast}\nnodes:\n"
        + node_block("a", 5)
        + node_block("b", 6, "    auto_start: false\n")
        + node_block("c", 7, "    enabled: false\n")
    )
    cfg = network(tmp_path, text)

    async def scenario(rig: Rig) -> None:
        a, b, c = rig.add(5), rig.add(6), rig.add(7)
        await rig.master.boot(timeout=5)
        nodes = rig.master.nodes
        assert state(nodes[5]) is NodeState.OPERATIONAL
        assert state(nodes[6]) is NodeState.CONFIGURED  # configured, left for the application
        assert state(nodes[7]) is NodeState.UNDEFINED
        assert diagnostic(nodes[7]) is Diagnostic.DEACTIVATED
        starts = [d for d in rig.data(0x000) if d[0] == 0x01]
        assert starts == [b"\x01\x05"]  # per node: a broadcast would start b and c too
        assert (a.state, b.state, c.state) == (
            NmtState.OPERATIONAL,
            NmtState.PRE_OPERATIONAL,
            NmtState.PRE_OPERATIONAL,
        )
        assert not sdo_requests(rig, 7, 0x1000)

    rig_test(cfg, scenario)


def test_emergencies_on_a_configured_cob_id(tmp_path):
    extra = '    sdo: [{object: "0x1014", value: 0x80000085}, {object: "0x1014", value: 0x95}]\n'
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, extra))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)
        await rig.master.boot(timeout=5)
        assert device.get(0x1014) == 0x95
        device.send_emergency(0x5000)
        await rig.run(0.01)
        assert [f.cob_id for _, f in rig.frames if f.data[:2] == b"\x00\x50"] == [0x95]
        assert rig.master.nodes[5].emcy_count == 1

    rig_test(cfg, scenario)


def test_a_node_silent_during_configuration_is_retried_then_absent(tmp_path):
    cfg = network(tmp_path, "nodes:\n" + node_block("a", 5, "    sdo_retries: 2\n"))

    async def scenario(rig: Rig) -> None:
        device = rig.add(5)

        def unplug(event: object) -> None:
            if isinstance(event, NodeStateChanged) and event.new is NodeState.CONFIGURING:
                device.close()

        rig.master.add_listener(unplug)
        await rig.master.boot(timeout=10)
        node = rig.master.nodes[5]
        assert state(node) is NodeState.ABSENT
        assert "stopped answering SDO" in (node.problem or "")
        first = node.config.startup[0]
        key = bytes((first.index & 0xFF, first.index >> 8, first.subindex))
        tries = [t for t, f in rig.on(0x605) if f.data[0] >> 5 == 1 and f.data[1:4] == key]
        assert len(tries) == 3  # the first write and 2 retries, one SDO timeout apart
        assert tries[2] - tries[0] == pytest.approx(2.0)

    rig_test(cfg, scenario)


def test_a_node_that_refuses_every_error_control_is_not_ok(tmp_path):
    """A node refusing heartbeat (1017h) and node guarding (100Ch/100Dh) runs, but nothing
    would tell the master if it stopped: its diagnostic says so instead of OK."""
    text = "master: {node_id: 127}\nnodes:\n" + node_block("a", 5)
    cfg = network(tmp_path, text)

    async def scenario(rig: Rig) -> None:
        od = io_od()
        for index in (0x1017, 0x100C, 0x100D):
            var = od.get_variable(index, 0)
            if var is not None:
                var.access = Access.RO
        rig.add(5, od)
        await rig.master.boot(timeout=5)
        node = rig.master.nodes[5]
        assert node.error_control is None
        assert diagnostic(node) is Diagnostic.SDO_SYNTAX_ERROR
        assert node.problem is not None and "no error control" in node.problem

    rig_test(cfg, scenario)
