"""LSS in the master's boot (CiA 302-2 with CiA 305, issue 42): a node the network file names
by its LSS address (``lss: true`` with its identity) gets its node-ID from the master before
the node's boot - a device that had none boots under it at once, one that had another takes
it at the master's reset - then boots as any node; what LSS could not do is said."""

from __future__ import annotations

import re
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from cobus.device import UNCONFIGURED, export_eds
from cobus.master import (
    BootTimeoutError,
    LssAssigned,
    LssNotAssigned,
    Master,
    MasterEvent,
    NetworkConfigError,
    NodeState,
    loads_network,
)
from cobus.od import ObjectDictionary
from cobus.proto.lss import LssState
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork
from cobus.sim import Rig
from cobus.sim.generic import CanopenSimDevice
from tests.util import simulate

VENDOR, PRODUCT, REVISION = 0x00C0B005, 0x191, 1
Scenario = Callable[[AsyncNetwork, Rig, Master], Awaitable[None]]


def node_entry(
    name: str,
    node_id: int,
    serial: int,
    *,
    revision: bool = True,
    extra: str = "",
    mandatory: bool = True,
) -> str:
    rev = f", revision_number: {REVISION}" if revision else ""
    must = "true" if mandatory else "false"
    return (
        f"  {name}: {{node_id: {node_id}, eds: io.eds, mandatory: {must}, heartbeat_time: 100, "
        f"lss: true, vendor_id: 0x{VENDOR:X}, product_code: 0x{PRODUCT:X}{rev}, "
        f"serial_number: 0x{serial:X}{extra}}}\n"
    )


def canopen(rig: Rig, node: int | str) -> CanopenSimDevice:
    device = rig.device(node)
    assert isinstance(device, CanopenSimDevice)
    return device


def io_od(rig: Rig) -> ObjectDictionary:
    """The dictionary of the rig's first device (an I/O module), for its EDS."""
    return canopen(rig, next(iter(rig.devices))).od


def state_of(master: Master, node_id: int) -> NodeState:
    return master.nodes[node_id].state


def run(
    folder: Path,
    rig_text: str,
    nodes: str,
    scenario: Scenario,
    reset: str = "node",
    eds_revision: int | None = None,
) -> list[MasterEvent]:
    """``scenario(net, rig, master)`` on the rig with a master of ``nodes``; its events.
    ``eds_revision``: the revision the EDS gives (1018h sub 3) instead of the device's."""
    rig = Rig.loads(rig_text)
    events: list[MasterEvent] = []

    async def main() -> None:
        async with AsyncNetwork() as net:
            await rig.start(net)
            eds = export_eds(io_od(rig))
            if eds_revision is not None:
                head, tail = eds.split("[1018sub3]")
                tail = re.sub(
                    r"DefaultValue=\S+", f"DefaultValue=0x{eds_revision:X}", tail, count=1
                )
                eds = head + "[1018sub3]" + tail
            (folder / "io.eds").write_text(eds)
            text = f"master: {{node_id: 1, reset: {reset}}}\nnodes:\n{nodes}"
            config = loads_network(text, base_dir=folder, path=str(folder / "net.yml"))
            master = Master(net, config)
            master.add_listener(events.append)
            await scenario(net, rig, master)
            await master.stop()
            await rig.stop()

    simulate(main())
    return events


@pytest.mark.parametrize("reset", ["node", "broadcast"])
def test_a_device_without_node_id_gets_the_files_and_boots_under_it(
    tmp_path: Path, reset: str
) -> None:
    rig = "devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1234}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        await master.boot(timeout=5)
        assert state_of(master, 5) is NodeState.OPERATIONAL
        device = canopen(rig, 5)
        assert device.node_id == 5 and device.device.state is NmtState.OPERATIONAL
        # not stored: at the next power-on it waits for a node-ID again
        device.inject("power_loss")
        device.inject("power_return")
        await net.sleep(0.1)
        assert device.device.node_id == UNCONFIGURED

    events = run(tmp_path, rig, node_entry("io", 5, 0x1234), scenario, reset)
    assigned = [e for e in events if isinstance(e, LssAssigned)]
    assert assigned == [LssAssigned(5, VENDOR, PRODUCT, REVISION, 0x1234, 0xFF, False)]
    assert (
        str(assigned[0])
        == "node 5: LSS gave the device with serial 0x00001234 its node-ID (it had none)"
    )


def test_lss_store_keeps_the_node_id_through_a_power_cycle(tmp_path: Path) -> None:
    rig = "devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1234}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        await master.boot(timeout=5)
        device = canopen(rig, 5)
        device.inject("power_loss")
        device.inject("power_return")
        await net.sleep(0.1)
        assert device.device.node_id == 5
        assert device.device.state is NmtState.PRE_OPERATIONAL

    events = run(tmp_path, rig, node_entry("io", 5, 0x1234, extra=", lss_store: true"), scenario)
    assert [e.stored for e in events if isinstance(e, LssAssigned)] == [True]


@pytest.mark.parametrize("reset", ["node", "broadcast"])
def test_a_device_with_another_node_id_takes_the_files_at_the_masters_reset(
    tmp_path: Path, reset: str
) -> None:
    rig = "devices:\n  - {node: 9, kind: cia401_io, serial: 0x5678, options: {lss: true}}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        await master.boot(timeout=5)
        assert state_of(master, 5) is NodeState.OPERATIONAL
        device = canopen(rig, 5)
        assert device.device.node_id == 5 and device.device.state is NmtState.OPERATIONAL

    events = run(tmp_path, rig, node_entry("io", 5, 0x5678), scenario, reset)
    (assigned,) = [e for e in events if isinstance(e, LssAssigned)]
    assert assigned.previous == 9
    assert "(it had 9)" in str(assigned)


@pytest.mark.parametrize("eds_revision", [REVISION, 7])
def test_a_revision_the_file_does_not_give_is_the_eds_one_or_searched_for(
    tmp_path: Path, eds_revision: int | None
) -> None:
    rig = (
        "devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1234}\n"
        "  - {node: unconfigured, kind: cia401_io, serial: 0x4321}\n"
    )

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        await master.boot(timeout=30)
        assert state_of(master, 5) is NodeState.OPERATIONAL
        assert state_of(master, 6) is NodeState.OPERATIONAL
        serial = canopen(rig, 6).od.get_variable(0x1018, 4)
        assert serial is not None and serial.value == 0x4321

    nodes = node_entry("a", 5, 0x1234, revision=False) + node_entry("b", 6, 0x4321, revision=False)
    events = run(tmp_path, rig, nodes, scenario, eds_revision=eds_revision)
    assert sorted((e.node_id, e.revision) for e in events if isinstance(e, LssAssigned)) == [
        (5, REVISION),
        (6, REVISION),
    ]


def test_a_device_nobody_finds_is_said_and_the_node_boots_as_it_is(tmp_path: Path) -> None:
    rig = "devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1234}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        with pytest.raises(BootTimeoutError) as caught:
            await master.boot(timeout=3)
        text = str(caught.value)
        assert "node 5 'io'" in text
        assert "LSS: no device answers to vendor 0x00C0B005" in text
        assert master.nodes[5].boot.lss_note is not None

    events = run(tmp_path, rig, node_entry("io", 5, 0x9999), scenario)
    (missed,) = [e for e in events if isinstance(e, LssNotAssigned)]
    assert missed.node_id == 5 and "serial 0x00009999" in missed.reason
    assert str(missed).startswith("node 5: no node-ID by LSS: no device answers")


def test_stopping_the_master_during_lss_ends_it_quietly(tmp_path: Path) -> None:
    rig = "devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0x1234}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        master.start()
        await net.sleep(0.01)
        await master.stop()
        await net.sleep(1.0)
        assert state_of(master, 5) is NodeState.UNDEFINED
        assert master.nodes[5].boot_task is None

    run(tmp_path, rig, node_entry("io", 5, 0x1234, revision=False), scenario)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        (
            "  io: {node_id: 5, eds: io.eds, lss: true, vendor_id: 1, product_code: 2}\n",
            "the master finds the device by its LSS address: give serial_number",
        ),
        (
            "  io: {node_id: 5, eds: io.eds, lss_store: true}\n",
            "stores the node-ID LSS gives: set lss: true too",
        ),
        (
            node_entry("io", 5, 0x1234, extra=", do_not_initialise: true, sdo_server: false"),
            "a node with do_not_initialise: true gets nothing from the master",
        ),
        (
            node_entry("a", 5, 0x1234) + node_entry("b", 6, 0x1234),
            "node 'a' has the same LSS address",
        ),
        (
            node_entry("a", 5, 0x1234) + node_entry("b", 6, 0x1234, revision=False),
            "node 'a' has the same LSS address (vendor, product, serial; a revision_number "
            "left out matches any)",
        ),
        (
            "defaults: {lss: true}\nnodes:\n  io: {node_id: 5, eds: io.eds}\n",
            "(lss: true comes from defaults: set lss: false on this node)",
        ),
    ],
)
def test_what_lss_needs_in_the_network_file(tmp_path: Path, entry: str, message: str) -> None:
    rig = Rig.loads("devices:\n  - {node: 9, kind: cia401_io}\n")

    async def main() -> None:
        async with AsyncNetwork() as net:
            await rig.start(net)
            (tmp_path / "io.eds").write_text(export_eds(io_od(rig)))
            await rig.stop()

    simulate(main())
    with pytest.raises(NetworkConfigError) as caught:
        text = entry if entry.startswith("defaults") else f"nodes:\n{entry}"
        loads_network(text, base_dir=tmp_path, path=str(tmp_path / "net.yml"))
    assert message in str(caught.value)


def test_four_devices_with_random_serials_found_then_named_and_booted_by_the_master(
    tmp_path: Path,
) -> None:
    """The whole path of issue 42: a fastscan finds four unconfigured devices whose serials
    nobody knew; their serials go into the network file; after a power cycle (nothing
    stored: they wait for a node-ID again) the master names them by LSS and boots them."""
    rig = Rig.loads("devices:\n" + "  - {node: unconfigured, kind: cia401_io}\n" * 4)

    async def main() -> None:
        async with AsyncNetwork() as net:
            await rig.start(net)
            (tmp_path / "io.eds").write_text(export_eds(io_od(rig)))
            t0 = net.time()
            serials = []
            # each found device gets a node-ID for now (not stored), so that the next
            # fastscan finds the next one, as `cobus lss assign-all` does
            while (found := await net.lss.fastscan()) is not None and len(serials) < 5:
                serials.append(found.serial)
                await net.lss.configure_node_id(20 + len(serials))
                net.lss.switch_global(LssState.WAITING)
            scanned = net.time() - t0
            assert len(set(serials)) == 4, serials
            for device in list(rig.devices.values()):  # a power cycle: unconfigured again
                device.inject("power_loss")
                device.inject("power_return")
            await net.sleep(0.1)
            assert await net.lss.identify_unconfigured()
            nodes = "".join(
                node_entry(f"io{i}", 10 + i, serial, revision=False)
                for i, serial in enumerate(serials)
            )
            text = f"master: {{node_id: 1}}\nnodes:\n{nodes}"
            config = loads_network(text, base_dir=tmp_path, path=str(tmp_path / "net.yml"))
            master = Master(net, config)
            t1 = net.time()
            await master.boot(timeout=60)
            print(f"found in {scanned:.2f} s, named and booted in {net.time() - t1:.2f} s")
            for i, serial in enumerate(serials):
                device = canopen(rig, 10 + i)
                assert device.device.state is NmtState.OPERATIONAL
                found_serial = device.od.get_variable(0x1018, 4)
                assert found_serial is not None and found_serial.value == serial
            await master.stop()
            await rig.stop()

    simulate(main())


def lss_state(rig: Rig) -> dict[int, tuple[int, str]]:
    """serial -> (node-ID, LSS state) of every rig device."""
    out = {}
    for device in rig.devices.values():
        assert isinstance(device, CanopenSimDevice)
        slave = device.device.lss
        serial = device.od.get_variable(0x1018, 4)
        assert slave is not None and serial is not None
        out[serial.value] = (device.device.node_id, slave.state.name)
    return out


@pytest.mark.parametrize("delay", [0.0, 0.001, 0.003])
def test_a_master_stopped_during_lss_leaves_every_device_waiting_and_starts_again_right(
    tmp_path: Path, delay: float
) -> None:
    rig = (
        "devices:\n  - {node: 9, kind: cia401_io, serial: 0xA, options: {lss: true}}\n"
        "  - {node: 8, kind: cia401_io, serial: 0xB, options: {lss: true}}\n"
    )

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        master.start()
        await net.sleep(delay)
        await master.stop()
        await net.sleep(0.3)
        assert all(state == "WAITING" for _, state in lss_state(rig).values())
        await master.boot(timeout=5)
        assert lss_state(rig) == {0xA: (5, "WAITING"), 0xB: (6, "WAITING")}

    run(tmp_path, rig, node_entry("a", 5, 0xA) + node_entry("b", 6, 0xB), scenario)


def test_a_store_that_fails_keeps_the_node_id_and_says_it_is_not_kept(tmp_path: Path) -> None:
    rig = "devices:\n  - {node: 9, kind: cia401_io, serial: 0xA, options: {lss: true}}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        for device in rig.devices.values():
            assert isinstance(device, CanopenSimDevice) and device.device.lss is not None
            device.device.lss.store = lambda node_id, timing: False
        await master.boot(timeout=5)
        assert state_of(master, 5) is NodeState.OPERATIONAL

    events = run(tmp_path, rig, node_entry("a", 5, 0xA, extra=", lss_store: true"), scenario)
    (assigned,) = [e for e in events if isinstance(e, LssAssigned)]
    assert not assigned.stored and "media access error" in assigned.problem
    assert "(it had 9; the device did not store it: store configuration" in str(assigned)
    assert not [e for e in events if isinstance(e, LssNotAssigned)]


def test_a_device_that_does_not_say_its_node_id_is_moved_by_a_reset_communication(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import cobus.proto.lss.slave as slave_module
    from cobus.proto import Out
    from cobus.proto.lss._wire import INQUIRE_NODE_ID

    configure = slave_module.LssSlave._configure

    def no_inquire(self: slave_module.LssSlave, cs: int, data: bytes, now: float) -> Out:
        if cs == INQUIRE_NODE_ID:  # (optional in CiA 305)
            return Out(())
        return configure(self, cs, data, now)

    monkeypatch.setattr(slave_module.LssSlave, "_configure", no_inquire)
    rig = "devices:\n  - {node: 9, kind: cia401_io, serial: 0xA, options: {lss: true}}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        await master.boot(timeout=5)
        assert lss_state(rig) == {0xA: (5, "WAITING")}

    events = run(tmp_path, rig, node_entry("a", 5, 0xA), scenario)
    (assigned,) = [e for e in events if isinstance(e, LssAssigned)]
    assert assigned.previous == -1 and "did not say which it had" in str(assigned)


def test_a_device_that_has_its_node_id_already_is_not_asked_to_store_it_again(
    tmp_path: Path,
) -> None:
    rig = "devices:\n  - {node: 5, kind: cia401_io, serial: 0xA, options: {lss: true}}\n"
    stores: list[int] = []

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        for device in rig.devices.values():
            assert isinstance(device, CanopenSimDevice) and device.device.lss is not None
            store = device.device.lss.store
            assert store is not None

            def counted(node_id: int, timing: int | None, store: Any = store) -> bool:
                stores.append(node_id)
                return bool(store(node_id, timing))

            device.device.lss.store = counted
        for _ in range(2):
            await master.boot(timeout=5)
            assert state_of(master, 5) is NodeState.OPERATIONAL
            await master.stop()

    events = run(tmp_path, rig, node_entry("a", 5, 0xA, extra=", lss_store: true"), scenario)
    assert stores == []
    said = [str(e) for e in events if isinstance(e, LssAssigned)]
    assert len(said) == 2 and all(text.endswith("(it had it already)") for text in said)


def test_a_boot_that_times_out_during_lss_says_so(tmp_path: Path) -> None:
    rig = "devices:\n  - {node: unconfigured, kind: cia401_io, serial: 0xA}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        with pytest.raises(BootTimeoutError) as caught:
            await master.boot(timeout=1)
        assert "the LSS step (node-IDs before any reset) is still running: 0 of 2 nodes" in str(
            caught.value
        )

    nodes = node_entry("a", 5, 0xA, revision=False) + node_entry("b", 6, 0xB, revision=False)
    run(tmp_path, rig, nodes, scenario, eds_revision=7)


def test_a_network_closed_during_lss_is_said_and_a_new_start_runs(tmp_path: Path) -> None:
    rig = "devices:\n  - {node: 9, kind: cia401_io, serial: 0xA, options: {lss: true}}\n"

    async def scenario(net: AsyncNetwork, rig: Rig, master: Master) -> None:
        master.start()
        await net.sleep(1.0)  # (searching a revision)
        await net.disconnect()
        await net.sleep(0.5)
        await net.connect()
        with pytest.raises(BootTimeoutError) as caught:
            await master.boot(timeout=1)
        said = str(caught.value)
        assert "the network closed during the master's LSS step: stop() and start()" in said
        await master.stop()
        await master.boot(timeout=10)  # (started again: it runs)
        assert state_of(master, 5) is NodeState.OPERATIONAL

    nodes = node_entry("a", 5, 0xA, revision=False) + node_entry(
        "b", 6, 0xB, revision=False, mandatory=False
    )
    run(tmp_path, rig, nodes, scenario, eds_revision=7)
