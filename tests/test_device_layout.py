"""Where things live (issue 19): each service of a device owns the objects it serves, the
runtime imports nothing above it and has no import cycle, and the registry of local
node-IDs belongs to the network alone."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from cobus.device import (
    BlockingDevice,
    Deviations,
    Device,
    DeviceConfigError,
    NodeIdInUseError,
    Simulation,
    add_device,
    minimal_od,
)
from cobus.device.blocking import BlockingSimulation
from cobus.runtime import AsyncNetwork, Network
from cobus.runtime.errors import NodeIdInUseError as RuntimeNodeIdInUseError
from cobus.runtime.local_nodes import LocalNodes
from tests.test_device_support import simulate, test_od

SRC = Path(__file__).resolve().parent.parent / "src" / "cobus"
ABOVE_RUNTIME = ("device", "master", "profiles", "sim", "blocks", "apps", "trace", "cli")

#: Object -> the module of the service that serves it.
OWNERS = {
    0x1001: "emcy",
    0x1003: "emcy",
    0x1005: "sync",
    0x1006: "sync",
    0x1007: "sync",
    0x100C: "guarding",
    0x100D: "guarding",
    0x1010: "storage",
    0x1011: "storage",
    0x1012: "timestamp",
    0x1014: "emcy",
    0x1015: "emcy",
    0x1016: "heartbeat",
    0x1017: "heartbeat",
    0x1019: "sync",
    0x1029: "nmt",
    0x1200: "sdo_server",
    0x1201: "sdo_server",
    0x1400: "pdo",
    0x1600: "pdo",
    0x1800: "pdo",
    0x1A00: "pdo",
}


def _imports(path: Path, *, typing_too: bool) -> set[str]:
    """The cobus modules ``path`` imports (at any depth, in functions too)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped: set[int] = set()
    if not typing_too:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                skipped.update(id(n) for n in ast.walk(node))
    found = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("cobus"):
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("cobus"))
    return found


def test_each_object_is_served_by_its_service():
    async def main() -> None:
        async with AsyncNetwork() as net:
            od = minimal_od(rpdos=1, tpdos=1, sdo_servers=2, heartbeat_consumers=1)
            device = Device(net, 5, od)
            handlers = device._core.handlers
            for index, module in OWNERS.items():
                handler = handlers[index]
                assert handler.__module__ == f"cobus.device.{module}", hex(index)
            unowned = sorted(hex(i) for i in handlers if i not in OWNERS and i < 0x2000)
            assert unowned == []
            device.close()

    simulate(main())


#: The objects a service owns as ranges (SDO server and PDO parameters come in series).
_SERIES = {
    0x1200: (0x1200, 0x127F),
    0x1400: (0x1400, 0x15FF),
    0x1600: (0x1600, 0x17FF),
    0x1800: (0x1800, 0x19FF),
    0x1A00: (0x1A00, 0x1BFF),
}


def _owner(value: int) -> str | None:
    for first, (low, high) in _SERIES.items():
        if low <= value <= high:
            return OWNERS[first]
    return OWNERS.get(value)


def test_each_object_index_is_written_in_its_service_only():
    """As ``grep 0x1005 src/cobus/device/`` finds SYNC's objects in sync.py only: no module
    of the device package but the owner's (``pdo.py`` and its ``_pdo_machines.py``) names an
    index the owner serves as a number in its code."""
    strays = []
    for path in sorted((SRC / "device").glob("*.py")):
        module = path.stem.lstrip("_").split("_")[0] if path.stem.startswith("_pdo") else path.stem
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and type(node.value) is int:
                owner = _owner(node.value)
                if owner is not None and owner != module:
                    strays.append(f"{path.name}:{node.lineno} 0x{node.value:04X} ({owner})")
    assert strays == []


def test_the_runtime_imports_nothing_above_it():
    offenders = []
    for path in sorted((SRC / "runtime").glob("*.py")):
        for name in _imports(path, typing_too=True):
            layer = name.split(".")[1] if "." in name else ""
            if layer in ABOVE_RUNTIME:
                offenders.append(f"{path.name}: {name}")
    assert offenders == []


def test_no_import_cycle_inside_the_runtime():
    modules = {p.stem: p for p in (SRC / "runtime").glob("*.py") if p.stem != "__init__"}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        inside = {
            m.split(".")[2]
            for m in _imports(path, typing_too=False)
            if m.startswith("cobus.runtime.")
        }
        graph[name] = (inside & set(modules)) - {name}
    seen: dict[str, int] = {}  # 1 on the path, 2 done

    def visit(name: str, path: list[str]) -> None:
        seen[name] = 1
        for other in sorted(graph[name]):
            if seen.get(other) == 1:
                raise AssertionError(" -> ".join([*path, name, other]))
            if other not in seen:
                visit(other, [*path, name])
        seen[name] = 2

    assert "remote" in graph["network"] and "pdo" in graph["remote"]  # the graph is read
    for name in sorted(graph):
        if name not in seen:
            visit(name, [])


def test_local_node_ids_are_claimed_moved_and_released():
    nodes = LocalNodes()
    a, b = object(), object()
    nodes.claim(5, a)
    nodes.claim(5, a)  # again: no error
    with pytest.raises(RuntimeNodeIdInUseError, match="node-ID 5 is used by another device"):
        nodes.claim(5, b)
    nodes.claim(6, b)
    with pytest.raises(RuntimeNodeIdInUseError):
        nodes.move(5, 6, a)
    assert dict(nodes) == {5: a, 6: b}  # a refused move changes nothing
    nodes.move(5, 7, a)
    assert dict(nodes) == {7: a, 6: b}
    nodes.release(6, a)  # not a's: no effect
    nodes.release(6, b)
    assert dict(nodes) == {7: a} and len(nodes) == 1 and 7 in nodes
    with pytest.raises(TypeError):
        nodes[8] = b  # type: ignore[index]


def test_a_device_holds_its_node_id_from_creation_to_close():
    async def main() -> None:
        async with AsyncNetwork() as net:
            first = Device(net, 5, test_od())
            assert net.devices == {5: first}  # attached, not started yet
            with pytest.raises(NodeIdInUseError, match="node-ID 5 is used by another device"):
                Device(net, 5, test_od())
            assert NodeIdInUseError is RuntimeNodeIdInUseError  # one class per idea
            first.start()
            first.node_id = 9
            assert net.devices == {9: first}
            first.close()
            assert net.devices == {}
            again = add_device(net, 5, test_od())  # the node-ID is free again
            assert net.devices == {5: again}

    simulate(main())


def test_a_device_that_fails_to_start_gives_its_node_id_back():
    class Broken:
        def load(self):
            raise RuntimeError("the store is on fire")

        def save(self, parameters):
            raise RuntimeError("the store is on fire")

    async def main() -> None:
        async with AsyncNetwork() as net:
            with pytest.raises(RuntimeError, match="on fire"):
                add_device(net, 5, test_od(), storage=Broken())
            assert net.devices == {}

    simulate(main())


def test_add_device_on_a_blocking_network_gives_a_blocking_device(tmp_path):
    eds = tmp_path / "valve.eds"
    with Network(simulated=True) as net:
        eds.write_text(add_device(net, 4, test_od()).to_eds(), encoding="utf-8")
        device = add_device(net, 5, eds)  # from an EDS file too
        assert isinstance(device, BlockingDevice) and device.node_id == 5
        assert set(net.devices) == {4, 5}
        assert isinstance(net.devices[5], BlockingDevice) and net.devices[5].aio is device.aio
        with pytest.raises(NodeIdInUseError):
            add_device(net, 5, test_od())


def test_the_simulation_settings_sit_behind_one_object():
    with Network(simulated=True) as net:
        device = add_device(net, 5, test_od(), deviations=Deviations(send_bootup=False))
        simulation = device.simulation
        assert isinstance(simulation, BlockingSimulation)
        assert isinstance(simulation.aio, Simulation) and simulation.aio is device.aio.simulation
        assert simulation.deviations == Deviations(send_bootup=False)
        assert (simulation.sdo_response_delay, simulation.heartbeat_muted) == (0.0, False)
        node = net.add_remote(5)
        node.nmt.start()  # (no boot-up) the channels are built, without a gate
        t0 = net.time()
        assert node.sdo.upload(0x1000) == bytes.fromhex("91010000")
        assert net.time() == t0
        simulation.sdo_response_delay = 0.25  # on the loop: the channels go behind their gates
        simulation.heartbeat_muted = True
        t0 = net.time()
        assert node.sdo.upload(0x1000) == bytes.fromhex("91010000")
        assert net.time() - t0 == pytest.approx(0.25)
        assert device.aio.simulation.sdo_response_delay == 0.25
        assert device.aio.simulation.heartbeat_muted is True
        with pytest.raises(DeviceConfigError, match="SDO response delay"):
            simulation.sdo_response_delay = -1
        with pytest.raises(DeviceConfigError, match="True or False"):
            simulation.heartbeat_muted = 1  # type: ignore[assignment]
        assert "sdo_response_delay=0.25" in repr(device.aio.simulation)
    with pytest.raises(DeviceConfigError, match=r"not a cobus\.device\.Deviations"):
        Simulation({"send_bootup": False})  # type: ignore[arg-type]


def test_moved_names_say_where_they_went():
    async def main() -> None:
        async with AsyncNetwork() as net:
            with pytest.raises(AttributeError, match=r"cobus\.device\.add_device\(network"):
                net.add_device(5, test_od())
            device = add_device(net, 5, test_od())
            for name in ("sdo_response_delay", "heartbeat_muted", "deviations"):
                with pytest.raises(AttributeError, match=rf"use device\.simulation\.{name}"):
                    getattr(device, name)
                with pytest.raises(AttributeError, match=rf"Device\.{name} has moved"):
                    setattr(device, name, 1)
            assert device.simulation.sdo_response_delay == 0.0  # nothing was set on the side

    simulate(main())
    with Network(simulated=True) as net:
        with pytest.raises(AttributeError, match=r"Network\.add_device has moved"):
            net.add_device(5, test_od())
        device = add_device(net, 5, test_od())
        with pytest.raises(AttributeError, match=r"use device\.simulation\.heartbeat_muted"):
            device.heartbeat_muted = True


def test_add_device_names_what_is_wrong_with_its_arguments():
    async def main() -> None:
        async with AsyncNetwork() as net:
            with pytest.raises(TypeError, match=r"not a cobus\.runtime\.Network or"):
                add_device(5, net, test_od())  # type: ignore[call-overload]
            with pytest.raises(DeviceConfigError, match="needs an object dictionary"):
                add_device(net, 5, None)  # type: ignore[call-overload]
            assert net.devices == {}

    simulate(main())


def test_a_closed_device_takes_no_new_node_id():
    async def main() -> None:
        async with AsyncNetwork() as net:
            device = add_device(net, 5, test_od())
            device.close()
            with pytest.raises(DeviceConfigError, match="was closed"):
                device.node_id = 9
            assert net.devices == {} and device.node_id == 5

    simulate(main())


def test_every_simulated_device_holds_its_node_id():
    from cobus.sim.ecmotor import EcMotor

    async def main() -> None:
        async with AsyncNetwork() as net:
            motor = EcMotor(net, 3)
            motor.start()
            assert net.devices == {3: motor}
            with pytest.raises(NodeIdInUseError):
                add_device(net, 3, test_od())  # it would answer on 603h/583h too
            motor.power_off()
            assert net.devices == {}
            add_device(net, 3, test_od())

    simulate(main())


def test_the_blocking_devices_are_the_same_twins_each_time():
    with Network(simulated=True) as net:
        device = add_device(net, 5, test_od())
        first = net.devices[5]
        assert net.devices[5] is first and first.aio is device.aio
        device.close()
        assert net.devices == {}
