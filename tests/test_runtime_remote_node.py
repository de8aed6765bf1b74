"""The remote node as python-canopen users use theirs: its PDO mapping read over SDO or taken from
the EDS, TPDOs received as named values, RPDOs sent, remapping with the CiA procedure, NMT state
followed from heartbeat and boot-up, heartbeat supervision, emergencies with their texts, and
names looked up the way people type them, against simulated devices on the simulated clock."""

from __future__ import annotations

import asyncio
import itertools
from pathlib import Path

import pytest

from cobus.device import DictionaryBuilder, add_device
from cobus.od import DataType, ValueRangeError
from cobus.proto import Frame
from cobus.proto.heartbeat import (
    BootupReceived,
    HeartbeatResumed,
    HeartbeatTimeout,
    RemoteStateChanged,
)
from cobus.proto.nmt import NmtCommand, NmtState
from cobus.proto.pdo import PdoError
from cobus.proto.sdo import SdoAbortedError
from cobus.runtime import (
    AsyncNetwork,
    Network,
    NetworkClosedError,
    ObjectAccessError,
    ObjectNotFoundError,
)
from cobus.runtime.emcy import EmcyTimeoutError
from cobus.runtime.nmt import NmtTimeoutError
from cobus.runtime.pdo import (
    PdoConfigurationError,
    PdoReceived,
    PdoRejected,
    PdoTimeoutError,
)
from cobus.sim.drive402 import SimulatedDrive402
from tests.test_sim_support import SimBench, run_sim
from tests.util import simulate

NODE = 10
EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "networks"


def drive_run(scenario):
    return run_sim(lambda net: SimulatedDrive402(net, NODE), scenario)


def test_a_drive_as_python_canopen_users_use_it():
    """Read the mapping, follow NMT, enable the drive by RPDO, receive TPDOs by name, see an
    EMCY with its text: the everyday tasks, against the simulated CiA 402 drive."""

    async def scenario(b: SimBench):
        node = b.master
        received: list[PdoReceived] = []
        states: list[object] = []
        node.nmt.add_callback(states.append)
        await node.sdo.write("Producer heartbeat time", 50)
        assert await node.nmt.wait_for_heartbeat() is NmtState.PRE_OPERATIONAL

        tpdos = await node.tpdo.read()
        await node.rpdo.read()
        assert [p.number for p in tpdos] == [1, 2, 3, 4]
        assert node.tpdo[1].names == ["Statusword"]
        assert node.tpdo[2].names == ["Statusword", "Position actual value"]
        assert node.tpdo[2].transmission_type == 1
        assert node.rpdo[1].names == ["Controlword"]
        node.tpdo[1].add_callback(received.append)

        node.nmt.start()
        assert await node.nmt.wait_for_state("operational") is NmtState.OPERATIONAL
        for cw in (0x06, 0x07, 0x0F):
            node.rpdo[1]["controlword"] = cw  # case does not matter
            node.rpdo[1].transmit()
            await b.settle()
        assert received, "the statusword TPDO arrives when the state changes"
        assert received[-1].values["Statusword"] & 0x6F == 0x27  # operation enabled
        assert node.tpdo[1]["Statusword"] == received[-1].values["Statusword"]

        b.net.sync.start(0.01)
        values = await node.tpdo[2].wait_for_reception()
        assert set(values) == {"Statusword", "Position actual value"}
        assert node.tpdo[2].timestamp == pytest.approx(b.net.time())

        b.sim.inject("drive_fault", code=0x7305)
        emcy = await node.emcy.wait()
        assert emcy.code == 0x7305
        assert str(emcy).startswith("0x7305 ")
        assert node.emcy.active == [emcy]
        assert [(e.old, e.new) for e in states if isinstance(e, RemoteStateChanged)] == [
            (None, NmtState.INITIALISING),  # its boot-up
            (NmtState.INITIALISING, NmtState.PRE_OPERATIONAL),  # its first heartbeat
            (NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL),
        ]

    drive_run(scenario)


def test_pdos_from_the_eds_match_those_read_from_the_node():
    async def scenario(b: SimBench):
        from_node = [
            (p.number, p.cob_id, p.transmission_type, p.names) for p in await b.master.tpdo.read()
        ]
        node = b.net.add_remote(NODE + 1, b.master.od)
        del node
        b.net.remove_remote(NODE + 1)
        loaded = b.master.tpdo.load_from_od()
        from_eds = [(p.number, p.cob_id, p.transmission_type, p.names) for p in loaded]
        assert from_eds == from_node

    drive_run(scenario)


def test_remapping_a_tpdo_with_the_cia_procedure():
    async def scenario(b: SimBench):
        node = b.master
        await node.tpdo.read()
        tpdo = node.tpdo[4]
        tpdo.clear()
        tpdo.add("Position actual value")
        tpdo.add(0x6041)
        tpdo.transmission_type = 1
        await tpdo.save()
        # the node now has the new mapping: read it back
        await node.tpdo.read()
        assert node.tpdo[4].names == ["Position actual value", "Statusword"]
        node.nmt.start()
        b.net.sync.start(0.01)
        values = await node.tpdo[4].wait_for_reception()
        assert list(values) == ["Position actual value", "Statusword"]

        # what the EDS forbids is refused before anything is sent
        with pytest.raises(PdoError, match="not PDO-mappable in the node's EDS"):
            tpdo.add("Producer heartbeat time")
        with pytest.raises(PdoError, match="maps with 16 bits, not 8"):
            tpdo.add("Statusword", bits=8)
        with pytest.raises(PdoError, match="an RPDO cannot write it"):
            node.rpdo[1].add("Statusword")

        # a mapping the node refuses (its EDS said otherwise) names the step, the node's
        # answer and what the node is left with
        assert node.od is not None
        node.od[0x1017].pdo_mappable = True  # type: ignore[union-attr]
        tpdo.clear()
        tpdo.add("Producer heartbeat time")
        tpdo.add(0x6041)
        with pytest.raises(
            PdoConfigurationError,
            match=r"TPDO 4 of node 10: writing mapping entry 1 .* the node now has <TPDO 4 "
            r"of node 10 disabled: no mapping>",
        ):
            await tpdo.save()
        assert not tpdo.enabled and tpdo.names == []

        # a PDO only looked at is not listed, nor saved
        assert node.tpdo[7].configured is False
        assert [p.number for p in node.tpdo] == [1, 2, 3, 4]

    drive_run(scenario)


def test_nmt_follows_bootup_and_heartbeat_loss():
    async def scenario(b: SimBench):
        node = b.master
        events: list[object] = []
        node.nmt.add_callback(events.append)

        def lost() -> bool:  # read afresh each time (a property, not a value)
            return node.nmt.lost

        await node.sdo.write(0x1017, 0, 20)
        await node.nmt.wait_for_heartbeat()
        node.nmt.watch_heartbeat(0.05)
        assert node.nmt.bootups == 1  # the boot-up when the simulated drive started
        node.nmt.reset_node()
        await node.nmt.wait_for_bootup()
        assert node.nmt.bootups == 2
        assert any(isinstance(e, BootupReceived) for e in events)
        # after the reset the node's heartbeat is off again (1017h back to its default 0)
        await node.sdo.write(0x1017, 0, 20)
        await node.nmt.wait_for_heartbeat()
        b.sim.power_off()
        await b.net.sleep(0.2)
        assert lost()
        assert any(isinstance(e, HeartbeatTimeout) for e in events)
        with pytest.raises(
            NmtTimeoutError, match="node 10 did not report state OPERATIONAL"
        ) as err:
            await node.nmt.wait_for_state(NmtState.OPERATIONAL, timeout=0.1)
        assert isinstance(err.value, TimeoutError)
        assert "last heard" in str(err.value)
        b.sim.power_on()
        await node.nmt.wait_for_bootup()
        assert not lost()  # a boot-up starts supervision over
        await node.sdo.write(0x1017, 0, 20)
        node.nmt.start()
        await node.nmt.wait_for_state("operational")
        # silent without a boot-up, then back in the same state: the wait hears it
        b.sim.inject("heartbeat_stop")
        await b.net.sleep(0.2)
        assert lost() and node.nmt.state is NmtState.OPERATIONAL
        b.sim.inject("heartbeat_resume")
        assert await node.nmt.wait_for_state("operational") is NmtState.OPERATIONAL
        assert isinstance(events[-1], HeartbeatResumed) and not lost()

    drive_run(scenario)


def _valve() -> DictionaryBuilder:
    b = DictionaryBuilder(device_name="valve block")
    b.variable(0x2000, "Setpoint", DataType.INTEGER16, access="rww", mappable=True)
    b.variable(0x2001, "Pressure", DataType.INTEGER16, access="ro", mappable=True)
    b.variable(0x2002, "Valve open", DataType.BOOLEAN, access="ro", mappable=True)
    b.tpdo(1, [(0x2001, 0), (0x2002, 0)], transmission_type=255)
    b.rpdo(1, [(0x2000, 0)])
    return b


def test_blocking_node_on_a_device_with_names_as_people_type_them():
    with Network(simulated=True) as net:
        dev = add_device(net, 5, _valve().build())
        from cobus.od import loads

        node = net.add_remote(5, loads(dev.to_eds(), node_id=5))
        # sdo["name"] access, names matched without regard to case or separators
        node.sdo["producer_heartbeat_time"].write(100)
        assert node.sdo["Producer heartbeat time"].read() == 100
        assert node.sdo["identity object"]["vendor-id"].read() == node.sdo.read(0x1018, 1)
        node.sdo.write(0x1017, 0)  # write(index, value) for sub-index 0
        assert node.sdo.read(0x1017) == 0
        node.sdo.write(0x1017, value=20)
        assert node.sdo["Producer heartbeat time"].raw == 20  # python-canopen's .raw
        node.sdo["Producer heartbeat time"].raw = 0
        assert node.sdo.read(0x1017) == 0
        node.sdo.timeout = 2.5
        assert node.sdo.aio.timeout == 2.5  # (the shared client takes it per transfer)
        with pytest.raises(ObjectNotFoundError, match="did you mean 'Producer heartbeat time'"):
            node.sdo["Producr heartbeat"]
        with pytest.raises(
            ValueRangeError, match=r"node 5, 'Producer heartbeat time' \(0x1017:00\)"
        ):
            node.sdo.write("Producer heartbeat time", 70000)

        node.sdo.write(0x1017, 10)  # heartbeat every 10 ms: the NMT state is followed
        node.tpdo.read()
        node.rpdo.read()
        seen: list[PdoReceived] = []
        node.tpdo[1].add_callback(seen.append)
        node.nmt.state = "OPERATIONAL"  # python-canopen's way: sends start
        assert node.nmt.commanded is NmtCommand.START
        assert node.nmt.wait_for_state("operational") is NmtState.OPERATIONAL
        with pytest.raises(ValueError, match="no NMT command leads to INITIALISING"):
            node.nmt.state = "initialising"
        dev.set(0x2001, 0, -321)  # the event-driven TPDO goes out
        net.sleep(0.001)
        assert node.tpdo[1].values == {"Pressure": -321, "Valve open": False}
        assert seen and seen[-1].values["Pressure"] == -321
        assert node.tpdo[1]["pressure"] == -321
        with pytest.raises(KeyError, match="did you mean 'Pressure'"):
            node.tpdo[1]["Presure"]

        node.rpdo[1]["Setpoint"] = 42
        node.rpdo[1].transmit()
        net.sleep(0.001)
        assert dev.get(0x2000, 0) == 42
        with pytest.raises(ValueRangeError, match="'Setpoint'"):
            node.rpdo[1]["Setpoint"] = 1 << 20
        with pytest.raises(ValueRangeError, match="True is a bool but the object is INTEGER16"):
            node.rpdo[1]["Setpoint"] = True
        with pytest.raises(ValueRangeError, match=r"node 5, 'Setpoint'.*a bool"):
            node.sdo.write("Setpoint", False)

        # periodic RPDO on the simulated clock
        writes: list[int] = []
        dev.on_write(0x2000, 0, lambda *a: writes.append(1))
        node.rpdo[1].start(0.01)
        net.sleep(0.095)
        node.rpdo[1].stop()
        net.sleep(0.05)
        assert len(writes) == 10  # one at once, then every 10 ms

        # re-adding a removed node works; adding twice says how
        with pytest.raises(ValueError, match="remove_remote"):
            net.add_remote(5)
        net.remove_remote(5)
        again = net.add_remote(5)
        assert again.sdo.read is not None


def test_tpdo_errors_short_frames_timeouts_and_rtr():
    async def main():
        async with AsyncNetwork() as net:
            node = net.add_remote(7)
            events: list[object] = []
            net.add_listener(events.append)
            tpdo = node.tpdo[1]
            tpdo.add(0x6041, 0, 16)
            tpdo.add(0x6064, 0, 32)
            assert tpdo.names == ["0x6041:00", "0x6064:00"]
            net.send(Frame(0x187, b"\x37\x02"))
            await asyncio.sleep(0)
            rejected = [e for e in events if isinstance(e, PdoRejected)]
            assert rejected and "needs 6" in rejected[0].reason
            with pytest.raises(PdoTimeoutError) as err:
                await tpdo.wait_for_reception(timeout=0.05)
            assert isinstance(err.value, TimeoutError)
            frames: list[Frame] = []
            net.subscribe(0x187, lambda f, now: frames.append(f))
            tpdo.request()
            await asyncio.sleep(0)
            assert frames[0].rtr and frames[0].dlc == 6
            with pytest.raises(PdoError, match="only a TPDO"):
                node.rpdo[1].request()
            with pytest.raises(PdoError, match="by number"):
                tpdo.add("Statusword")
            with pytest.raises(EmcyTimeoutError):
                await node.emcy.wait(timeout=0.01)

    simulate(main())


def test_emergencies_keep_their_history_and_active_errors():
    async def main():
        async with AsyncNetwork() as net:
            node = net.add_remote(3)
            seen = []
            node.emcy.add_callback(seen.append)
            for data in (
                b"\x10\x81\x11\x00\x00\x00\x00\x00",  # 8110h CAN overrun
                b"\x10\x42\x09\x00\x00\x00\x00\x00",  # 4210h temperature
                b"\x00\x00\x00\x00\x00\x00\x00\x00",  # reset
            ):
                net.send(Frame(0x83, data))
                await asyncio.sleep(0.01)
            assert [e.code for e in node.emcy.log] == [0x8110, 0x4210, 0x0000]
            assert node.emcy.active == []
            assert str(node.emcy.log[0]).startswith("0x8110 ")
            assert node.emcy.log[0].time == 0.0 and node.emcy.log[1].time == pytest.approx(0.01)
            assert seen == node.emcy.log
            net.send(Frame(0x83, b"\x10\x42\x09\x00\x00\x00\x00\x00"))
            await asyncio.sleep(0)
            assert [e.code for e in node.emcy.active] == [0x4210]
            assert node.emcy.count == 4

            node.emcy.clear()  # forgotten: the log, the active errors and the count
            assert (node.emcy.log, node.emcy.active, node.emcy.count) == ([], [], 0)
            assert node.emcy.last is None

            # the node's 1014h says 0x0A3: emergencies come on it, no longer on 83h
            node.emcy.set_cob_id(0x0A3)
            assert node.emcy.cob_id == 0x0A3
            net.send(Frame(0x83, b"\x10\x81\x11\x00\x00\x00\x00\x00"))
            net.send(Frame(0xA3, b"\x30\x81\x11\x00\x00\x00\x00\x00"))
            await asyncio.sleep(0)
            assert [e.code for e in node.emcy.log] == [0x8130]
            with pytest.raises(ValueError, match="11-bit identifier"):
                node.emcy.set_cob_id(0x800)
            net.remove_remote(3)
            with pytest.raises(NetworkClosedError, match="removed from the network"):
                node.emcy.set_cob_id(0x83)

    simulate(main())


def test_every_async_operation_has_its_blocking_twin():
    import cobus.sim.blocking
    from cobus.blocks import (
        AsyncNetworkVariables,
        AsyncParameterManager,
        NetworkVariables,
        ParameterManager,
    )
    from cobus.device import BlockingDevice, Device, Simulation
    from cobus.device.blocking import BlockingSimulation
    from cobus.master import BlockingMaster, Master
    from cobus.profiles import AsyncDrive402, Drive402
    from cobus.profiles.axes import AsyncAxes, Axes
    from cobus.profiles.ecmotor import AsyncEcMotorDrive, EcMotorDrive
    from cobus.profiles.io401 import AsyncIo401, Io401
    from cobus.profiles.stober import AsyncStoberDrive, StoberDrive
    from cobus.profiles.zapi import AsyncZapiDrive, ZapiDrive
    from cobus.runtime import blocking, emcy, nmt, pdo, remote
    from cobus.runtime import twin as twin_module
    from cobus.runtime.lss import AsyncNetworkLss
    from cobus.sim import Rig, SimulatedDevice

    expected = {
        remote.AsyncRemoteNode: blocking.RemoteNode,
        remote.SdoChannel: blocking.BlockingSdoChannel,
        remote.AsyncSdoVariable: blocking.SdoVariable,
        remote.AsyncSdoRecord: blocking.SdoRecord,
        nmt.AsyncRemoteNmt: blocking.RemoteNmt,
        emcy.AsyncRemoteEmcy: blocking.RemoteEmcy,
        pdo.AsyncRemotePdo: blocking.RemotePdo,
        pdo.AsyncPdoSet: blocking.PdoSet,
        Rig: cobus.sim.blocking.BlockingRig,
        SimulatedDevice: cobus.sim.blocking.BlockingSimulatedDevice,
        Master: BlockingMaster,
        Device: BlockingDevice,
        Simulation: BlockingSimulation,
        AsyncDrive402: Drive402,
        AsyncZapiDrive: ZapiDrive,
        AsyncStoberDrive: StoberDrive,
        AsyncEcMotorDrive: EcMotorDrive,
        AsyncIo401: Io401,
        AsyncAxes: Axes,
        AsyncParameterManager: ParameterManager,
        AsyncNetworkVariables: NetworkVariables,
    }
    # what a blocking face adds: letting the network run (async code awaits the network)
    added: dict[type, set[str]] = {
        BlockingMaster: {"sleep"},
        blocking.SdoVariable: {"raw"},  # python-canopen's habit; a property cannot await
    }
    expected[remote.NmtMaster] = blocking.BlockingNmtMaster
    expected[remote.NetworkSync] = blocking.BlockingNetworkSync
    expected[AsyncNetworkLss] = blocking.NetworkLss
    assert dict(twin_module._TWINS) == expected
    for async_cls, twin in expected.items():
        assert issubclass(twin, twin_module.BlockingTwin)
        assert twin._async_only <= twin_module.public_names(async_cls)
        missing = twin_module.public_names(async_cls) - twin_module.public_names(twin)
        missing -= twin._async_only  # the steps of a transfer: not for blocking code
        extra = twin_module.public_names(twin) - twin_module.public_names(async_cls)
        assert not missing and extra == added.get(twin, set()), (async_cls, missing, extra)
        assert twin.__doc__
        for name in twin_module.public_names(twin):
            if not name.startswith("_"):
                assert getattr(twin, name).__doc__, f"{twin.__name__}.{name} has no docstring"


def test_a_blocking_sdo_channel_keeps_the_steps_of_a_transfer_to_itself():
    with Network(simulated=True) as net:
        node = net.add_remote(5)
        assert node.sdo.transport.node_id == 5  # its statistics are for everyone
        for name in ("begin", "transfer", "client", "check_open"):
            with pytest.raises(AttributeError, match="is for async code"):
                getattr(node.sdo, name)


def test_a_blocking_rig_forwards_what_each_kind_of_device_adds():
    from cobus.sim import start_rig

    with Network(simulated=True) as net:
        rig = start_rig(net, "thesis")
        io = rig.device(9)
        io.set_potentiometer(0.5)  # an Io401 method, forwarded
        node = net.add_remote(9, EXAMPLES / "io.eds")
        assert abs(node.sdo.read(0x6401, 1) - 16383) <= 1
        rig.inject(9, "power_loss")
        with pytest.raises(TimeoutError):
            node.sdo.read(0x1000)
        assert rig.device(9).status()["powered"] is False
        rig.stop()


def test_errors_fit_pythons_hierarchy_and_import_from_the_runtime():
    import cobus.runtime as runtime
    from cobus.proto import sdo

    assert runtime.SdoTimeoutError is sdo.SdoTimeoutError
    assert runtime.SdoAbortedError is sdo.SdoAbortedError
    for error in (
        runtime.SdoTimeoutError,
        runtime.NmtTimeoutError,
        runtime.PdoTimeoutError,
        runtime.EmcyTimeoutError,
    ):
        assert issubclass(error, TimeoutError), error
    assert issubclass(runtime.ObjectNotFoundError, KeyError)
    assert issubclass(runtime.ValueRangeError, ValueError)


def test_python_dash_m_cobus_and_the_demo_help_read_whole():
    import subprocess
    import sys

    version = subprocess.run(
        [sys.executable, "-m", "cobus", "--version"], capture_output=True, text=True, check=True
    )
    assert version.stdout.startswith("cobus ")
    demo = subprocess.run(
        [sys.executable, "-m", "cobus", "demo", "--help"],
        capture_output=True,
        text=True,
        check=True,
    )
    description = demo.stdout.split("\n\n")[1]
    assert description.rstrip().endswith("."), description


def test_enums_print_by_name_and_codes_in_hex_with_their_text():
    from cobus.master.states import MasterState, NodeState
    from cobus.od import DataType
    from cobus.proto.emcy import EmcyCode
    from cobus.proto.sdo import SdoAbortCode

    assert str(NmtState.OPERATIONAL) == f"{NmtState.OPERATIONAL}" == "OPERATIONAL"
    assert f"{NmtState.OPERATIONAL:02X}" == "05" and int(NmtState.OPERATIONAL) == 5
    assert str(MasterState(5)) == MasterState(5).name
    assert str(NodeState.OPERATIONAL) == "OPERATIONAL"
    assert str(DataType.UNSIGNED16) == "UNSIGNED16"
    assert str(EmcyCode(0x8100)).startswith("0x8100 ")
    assert str(SdoAbortCode.TIMEOUT) == "0x05040000 SDO protocol timed out"


def test_every_public_class_and_method_has_a_docstring():
    """What ``help()`` shows a user: every class a public module exports, and its methods and
    properties (a protocol machine's deadline/on_frame/on_timer are documented once, on
    :class:`cobus.proto.Machine`)."""
    import importlib
    import inspect
    import pkgutil

    import cobus

    machine = {"deadline", "on_frame", "on_timer"}
    missing = []
    for info in pkgutil.walk_packages(cobus.__path__, "cobus."):
        if any(part.startswith("_") for part in info.name.split(".")[1:]):
            continue
        module = importlib.import_module(info.name)
        for name in getattr(module, "__all__", []):
            obj = getattr(module, name)
            if getattr(obj, "__module__", None) != module.__name__:
                continue
            if inspect.isfunction(obj) and not obj.__doc__:
                missing.append(f"{module.__name__}.{name}")
            if not inspect.isclass(obj):
                continue
            if not obj.__doc__:
                missing.append(f"{module.__name__}.{name}")
            is_machine = hasattr(obj, "on_frame") and hasattr(obj, "on_timer")
            for key, member in vars(obj).items():
                if key.startswith("_") or (is_machine and key in machine):
                    continue
                if (inspect.isfunction(member) or isinstance(member, property)) and not (
                    inspect.getdoc(member)
                ):
                    missing.append(f"{module.__name__}.{name}.{key}")
    assert missing == []


def test_blocking_waits_hear_what_the_call_before_them_caused():
    """``reset_node(); wait_for_bootup()`` and ``inject(fault); emcy.wait()`` work in blocking
    code as with ``await``; lists of PDOs come back as blocking PDOs."""
    from cobus.runtime.blocking import RemotePdo
    from cobus.sim import start_rig

    with Network(simulated=True) as net:
        rig = start_rig(net, "thesis")
        drive = net.add_remote(NODE, EXAMPLES / "servo.eds")
        pdos = drive.tpdo.read()
        assert all(isinstance(p, RemotePdo) for p in pdos)
        drive.nmt.reset_node()
        drive.nmt.wait_for_bootup(timeout=1)
        rig.inject(NODE, "drive_fault", code=0x7305)
        assert drive.emcy.wait(timeout=1).code == 0x7305
        drive.nmt.start()
        net.sync.start(0.01)
        assert set(pdos[1].wait_for_reception()) == {"Statusword", "Position actual value"}
        drive.sdo.write(0x1017, 50)
        drive.nmt.watch_heartbeat(0.1)
        drive.nmt.wait_for_heartbeat()
        rig.inject(NODE, "power_loss")
        net.sleep(0.3)
        assert "heartbeat lost" in repr(drive.nmt)


def test_blocking_handles_are_not_kept_and_callbacks_come_back():
    import gc

    with Network(simulated=True) as net:
        dev = add_device(net, 5, _valve().build())
        from cobus.od import loads

        node = net.add_remote(5, loads(dev.to_eds(), node_id=5))
        for _ in range(200):
            node.sdo["Setpoint"].write(1)
        gc.collect()
        assert len(node.sdo._children) == 0
        node.tpdo.read()

        def callback(event: PdoReceived) -> None:
            del event

        node.tpdo[1].add_callback(callback)
        gc.collect()  # the twin that took the callback is gone; another gives it back
        node.tpdo[1].remove_callback(callback)
        assert len(node.tpdo.aio[1]._callbacks) == 0


def test_sdo_objects_as_a_container_and_names_as_pdos_write_them():
    with Network(simulated=True) as net:
        dev = add_device(net, 5, _valve().build())
        from cobus.od import loads

        node = net.add_remote(5, loads(dev.to_eds(), node_id=5))
        sdo = node.sdo
        assert 0x1018 in sdo and "identity object" in sdo and 0x9999 not in sdo
        assert (0x1018, 1) in sdo and (0x1018, 9) not in sdo
        assert len(sdo) == len(list(sdo)) > 10
        assert "vendor id" in sdo[0x1018]
        vendor = sdo[0x1018, 1].read()
        assert sdo["Identity object.Vendor-ID"].read() == vendor == sdo.read((0x1018, 1))
        with pytest.raises(ObjectNotFoundError, match=r"0x1018 \('Identity object'\) has no sub"):
            sdo[0x1018][9]
        sent = net.frames_sent
        with pytest.raises(ObjectAccessError, match=r"'Device type' .* is ro .* nothing was sent"):
            sdo.write("Device type", 5)
        assert net.frames_sent == sent
        assert issubclass(ObjectAccessError, SdoAbortedError)
        net.remove_remote(5)
        with pytest.raises(NetworkClosedError, match="node 5 was removed"):
            sdo.read(0x1000)


def test_pdo_values_are_checked_when_set_and_a_removed_node_fails_at_once():
    async def main():
        async with AsyncNetwork() as net:
            node = net.add_remote(9)  # no dictionary: the mapping's bits are the limits
            rpdo = node.rpdo[1]
            rpdo.add(0x6200, 1, 8)
            with pytest.raises(PdoError, match=r"RPDO 1 of node 9, '0x6200:01'"):
                rpdo[(0x6200, 1)] = 0x1FF
            rpdo[(0x6200, 1)] = 0xFF
            tpdo = node.tpdo[5]  # beyond the pre-defined set: no identifier, disabled
            tpdo.add(0x6000, 1, 8)
            with pytest.raises(PdoError, match="is disabled"):
                await tpdo.wait_for_reception()
            net.remove_remote(9)
            for wait in (
                node.nmt.wait_for_bootup(),
                node.emcy.wait(),
                node.tpdo[1].wait_for_reception(),
            ):
                with pytest.raises(NetworkClosedError, match="node 9 was removed"):
                    await wait
            with pytest.raises(NetworkClosedError):
                rpdo.transmit()

    simulate(main())


def test_the_blocking_network_lists_its_nodes_and_takes_listeners_back():
    with Network(simulated=True) as net:
        dev = add_device(net, 5, _valve().build())
        node = net.add_remote(5)
        assert net.remotes == {5: node} and net.remotes[5] is node
        assert list(net.devices) == [5] and net.devices[5].aio is dev.aio
        seen: list[object] = []
        net.add_listener(seen.append)
        node.nmt.start()
        net.sleep(0.01)
        count = len(seen)
        assert count > 0  # the device's state change, at least
        net.remove_listener(seen.append)
        node.nmt.stop()
        net.sleep(0.01)
        assert len(seen) == count
        was_connected = net.connected
        assert str(net.bus_state) == "error-active" and net.tx_backlog == 0
    assert was_connected and not net.connected
    with pytest.raises(TypeError, match="SimulatedEventLoop"):
        AsyncNetwork(simulated=True)


def test_what_a_blocking_node_is_made_of_is_read_without_the_loop():
    """``node.sdo`` and the node's other ``Final`` attributes never change, so the blocking
    node reads them in the calling thread, once: ``node.sdo.upload(...)`` in a loop costs no
    trip to the network's loop for ``node.sdo``. They cannot be set; the rest still can."""
    from cobus.runtime import blocking
    from cobus.runtime.twin import _Fixed

    assert isinstance(vars(blocking.RemoteNode)["sdo"], _Fixed)
    assert isinstance(vars(blocking.RemotePdo)["number"], _Fixed)
    assert not isinstance(vars(blocking.RemotePdo)["transmission_type"], _Fixed)
    with Network(simulated=True) as net:
        add_device(net, 5, _valve().build())
        node = net.add_remote(5)
        tpdo = node.tpdo[1]
        runner = net._runner
        hops: list[object] = []
        call, run = runner.call, runner.run
        runner.call = lambda *a, **k: hops.append(a) or call(*a, **k)  # type: ignore[method-assign]
        runner.run = lambda *a, **k: hops.append(a) or run(*a, **k)  # type: ignore[method-assign]
        for _ in range(3):
            assert node.sdo is node.sdo and node.sdo.aio is node.aio.sdo
            assert node.nmt.aio is node.aio.nmt and node.emcy.aio is node.aio.emcy
            assert node.tpdo.aio is node.aio.tpdo and node.rpdo.aio is node.aio.rpdo
            assert (node.node_id, node.od, node.network) == (5, None, net.aio)
            assert (node.sdo.node_id, node.nmt.node_id, tpdo.number, tpdo.node_id) == (5, 5, 1, 5)
        assert hops == []
        assert node.sdo.upload(0x1000) == bytes([0x91, 1, 0, 0])  # device type 401
        for name in ("sdo", "node_id", "od"):
            with pytest.raises(AttributeError, match=f"'{name}' is fixed"):
                setattr(node, name, None)
        with pytest.raises(AttributeError, match="'number' is fixed"):
            tpdo.number = 2
        hops.clear()
        tpdo.transmission_type = 254  # not Final: set on the loop, as before
        assert tpdo.transmission_type == 254 and len(hops) == 2


def test_the_blocking_network_has_what_the_async_one_has():
    """Network is written by hand (it owns the loop); it has every operation of AsyncNetwork
    but the plumbing for code that runs on the loop, which blocking code does through
    ``run()`` and ``close()``."""
    from cobus.runtime import twin

    plumbing = {
        "attach",
        "claim_guarding",
        "connect",
        "disconnect",
        "emit",
        "guarding_owner",
        "listened",
        "loop",
        "on_connect",
        "on_disconnect",
        "release_guarding",
        "report_failure",
        "sdo_transport",
    }
    missing = twin.public_names(AsyncNetwork) - twin.public_names(Network)
    assert missing == plumbing
    assert twin.public_names(Network) - twin.public_names(AsyncNetwork) == {"close", "run"}
    with Network(simulated=True) as net:
        net.sync.start(0.01)
        assert net.sync is net.sync and net.sync.running and net.sync.period == 0.01
        net.nmt.start(5)
        net.sleep(0.1)
        assert net.frames_sent == 11 and net.bus is net.aio.bus


def test_review_findings_stay_fixed():
    """A PDO never read cannot wipe the node's mapping; out-of-range parameters are typed
    errors; guarding replies count as the node's state; waits running at removal fail with
    NetworkClosedError; a periodic RPDO does not burst after a stall; TPDOs on 29-bit
    identifiers and longer frames decode; a reset EMCY clears what the register no longer
    shows."""

    async def main():
        async with AsyncNetwork() as net:
            node = net.add_remote(7)
            with pytest.raises(PdoConfigurationError, match="nothing to save"):
                await node.tpdo[1].save()
            tpdo = node.tpdo[1]
            tpdo.add(0x6041, 0, 16)
            tpdo.inhibit_time = 70_000
            with pytest.raises(PdoConfigurationError, match="inhibit time 70000 is out of range"):
                await tpdo.save()

            # node guarding replies: toggle bit 7 set, state in bits 0-6
            events: list[object] = []
            node.nmt.add_callback(events.append)
            net.send(Frame(0x707, b"\x85"))
            await asyncio.sleep(0)
            assert node.nmt.state is NmtState.OPERATIONAL and node.nmt.last_heard == 0.0
            assert not [e for e in events if "Malformed" in type(e).__name__]

            # 29-bit TPDO, frame longer than the mapping
            tpdo.extended = True
            tpdo.cob_id = 0x1ABCDE07
            net.send(Frame(0x1ABCDE07, b"\x37\x02\xff\xff", extended=True))
            await asyncio.sleep(0)
            assert tpdo.values == {"0x6041:00": 0x0237} and tpdo.count == 1

            # periodic RPDO after a stall of the loop: no burst of the missed ones
            frames: list[float] = []
            rpdo = node.rpdo[1]
            rpdo.add(0x6040, 0, 16)
            net.subscribe(0x207, lambda f, now: frames.append(now))
            rpdo.start(0.01)
            await asyncio.sleep(0.05)
            net.loop.call_soon(net.loop._advance, 0.2)  # type: ignore[attr-defined]
            await asyncio.sleep(0.05)
            rpdo.stop()
            gaps = [b - a for a, b in itertools.pairwise(frames)]
            assert min(gaps) > 0.009, gaps

            # a reset EMCY keeps the errors its register still shows
            for data in (
                b"\x10\x42\x09\x00\x00\x00\x00\x00",  # 4210h temperature (bit 3)
                b"\x10\x81\x11\x00\x00\x00\x00\x00",  # 8110h communication (bit 4)
                b"\x00\x00\x09\x00\x00\x00\x00\x00",  # reset: temperature remains
            ):
                net.send(Frame(0x87, data))
                await asyncio.sleep(0)
            assert [e.code for e in node.emcy.active] == [0x4210]

            # waits running when the node is removed fail with NetworkClosedError
            waits = [
                asyncio.ensure_future(w)
                for w in (
                    node.nmt.wait_for_bootup(),
                    node.emcy.wait(),
                    tpdo.wait_for_reception(),
                    node.sdo.upload(0x1000),
                    node.sdo.upload(0x1001),  # waits for the channel
                )
            ]
            requests: list[bytes] = []
            net.subscribe(0x607, lambda f, now: requests.append(f.data))
            await asyncio.sleep(0)
            net.remove_remote(7)
            results = await asyncio.gather(*waits, return_exceptions=True)
            assert all(isinstance(r, NetworkClosedError) for r in results), results
            # the running upload is aborted towards the node; the queued one never went out
            assert [d[:4].hex() for d in requests] == ["40001000", "80001000"]

    simulate(main())


def test_sync_skips_are_counted_exactly():
    from cobus.proto.sync import SyncProducer

    for k in range(1, 400):
        p = SyncProducer()
        p.set_period(1000, 0.0)
        deadline = p.deadline
        assert deadline is not None
        p.on_timer(deadline + 3 * 0.001 + k * 1e-12)  # three whole periods late
        assert p.skipped == 3, k


def test_a_callback_failing_on_every_frame_does_not_flood_the_log(caplog):
    from cobus.runtime import HandlerFailed

    async def main():
        async with AsyncNetwork() as net:
            node = net.add_remote(7)
            tpdo = node.tpdo[1]
            tpdo.add(0x6041, 0, 16)

            def broken(event: PdoReceived) -> None:
                raise RuntimeError("a bug in the application")

            tpdo.add_callback(broken)
            failed: list[object] = []
            net.add_listener(lambda e: failed.append(e) if isinstance(e, HandlerFailed) else None)
            for _ in range(50):
                net.send(Frame(0x187, b"\x37\x02"))
                await asyncio.sleep(0.001)
            assert tpdo.count == 50 and len(failed) == 50  # every failure is an event

    with caplog.at_level("ERROR", logger="cobus.runtime.network"):
        simulate(main())
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 2, lines  # the first with its traceback, then the 10th
    assert "a bug in the application" in lines[0] and "10 times so far" in lines[1]


def test_a_received_tpdo_keeps_its_values_and_is_told_to_whoever_listens_then():
    """The event is built only when a callback, a waiter or a network listener is there;
    the values, the time and the count are kept either way, by the mapping's current names."""
    from tests.test_device_support import simulate

    async def main() -> None:
        async with AsyncNetwork() as net:
            tpdo = net.add_remote(5).tpdo[1]
            tpdo.add(0x6041, 0, 16)
            tpdo.add(0x0005, 0, 8)  # a dummy: takes a byte, has no name
            tpdo.add(0x6061, 0, 8)
            tpdo.cob_id = 0x185
            tpdo.enabled = True
            names = tpdo.names
            assert [f.name for f in tpdo.fields if not f.dummy] == names and len(names) == 2

            async def receive(data: bytes) -> None:
                net.send(Frame(0x185, data))  # handed to the network's own handlers
                await asyncio.sleep(0)

            await receive(bytes([1, 0, 0xEE, 7]))  # nobody listens
            assert list(tpdo.values.values()) == [1, 7] and tpdo.count == 1
            assert tpdo.timestamp == net.time()
            seen: list[PdoReceived] = []
            tpdo.add_callback(seen.append)
            await receive(bytes([2, 0, 0, 8]))
            tpdo.remove_callback(seen.append)
            heard: list[object] = []
            net.add_listener(heard.append)
            await receive(bytes([3, 0, 0, 9]))
            net.remove_listener(heard.append)
            waiting = asyncio.ensure_future(tpdo.wait_for_reception())
            await asyncio.sleep(0)
            await receive(bytes([4, 0, 0, 10]))
            assert list((await waiting).values()) == [4, 10]
            assert [list(e.values.values()) for e in seen] == [[2, 8]]
            assert [list(e.values.values()) for e in heard if isinstance(e, PdoReceived)] == [
                [3, 9]
            ]
            assert tpdo.count == 4 and len(tpdo.names) == 2
            tpdo.clear()
            tpdo.add(0x6061, 0, 8)
            tpdo.enabled = True
            await receive(bytes([11]))
            assert tpdo.names == names[1:] and tpdo.values == {names[1]: 11}

    simulate(main())


def test_a_tpdo_nobody_listens_to_is_decoded_only_when_its_values_are_asked_for():
    """A byte-aligned mapping keeps the last frame's bytes and decodes them when asked
    (a master watching many nodes decodes nothing it does not read); the values are those
    of the last good frame, of the mapping they were sent for."""
    from tests.test_device_support import simulate

    async def main() -> None:
        async with AsyncNetwork() as net:
            tpdo = net.add_remote(5).tpdo[1]
            tpdo.add(0x6041, 0, 16)
            tpdo.add(0x6064, 0, 32)
            tpdo.cob_id = 0x185
            tpdo.enabled = True
            status, position = tpdo.names
            rejected: list[PdoRejected] = []

            async def receive(data: bytes) -> None:
                net.send(Frame(0x185, data))
                await asyncio.sleep(0)

            for i in range(5):
                await receive(bytes([i, 0]) + (1000 * i).to_bytes(4, "little", signed=True))

            def undecoded() -> bool:
                return tpdo._raw is not None

            assert undecoded()  # the bytes kept, not decoded
            assert tpdo[status] == 4 and tpdo.values == {status: 4, position: 4000}
            assert not undecoded()
            await receive(bytes([9, 0, 1, 2, 3]))  # one byte short: refused, values kept
            await asyncio.sleep(0)
            assert tpdo.values == {status: 4, position: 4000} and tpdo.count == 5
            net.add_listener(lambda e: rejected.append(e) if isinstance(e, PdoRejected) else None)
            await receive(bytes([9, 0, 1, 2, 3]))
            assert len(rejected) == 1 and "carries 5 bytes" in rejected[0].reason
            await receive(bytes([7, 0, 0xFF, 0xFF, 0xFF, 0xFF]))
            tpdo[position] = 5  # written over the frame's values, which are decoded first
            assert tpdo.values == {status: 7, position: 5}
            await receive(bytes([8, 0, 1, 0, 0, 0]))
            tpdo.clear()  # a new mapping before the last frame was decoded:
            tpdo.add(0x6061, 0, 8)  # its bytes are not read with the new mapping
            assert tpdo.values == {tpdo.names[0]: 0}
            tpdo.clear()  # not byte-aligned: decoded as it comes, as before
            tpdo.add(0x0005, 0, 8)
            tpdo.add(0x6061, 0, 8)
            tpdo.add(0x0001, 0, 1)
            tpdo.add(0x0001, 0, 7)
            tpdo.enabled = True
            await receive(bytes([0xAA, 3, 0]))
            assert not undecoded() and tpdo.values == {tpdo.names[0]: 3}

    simulate(main())


def test_a_tpdo_value_its_type_refuses_leaves_the_last_values_time_and_count():
    """A mapping that is not byte-aligned decodes each frame as it comes: a value out of its
    type's range (TIME_OF_DAY past midnight) is reported and does not count."""
    from cobus.runtime import HandlerFailed

    b = DictionaryBuilder(device_name="clock")
    b.variable(0x2000, "Stamp", DataType.TIME_OF_DAY, access="ro", mappable=True)
    od = b.build()

    async def main() -> None:
        async with AsyncNetwork() as net:
            tpdo = net.add_remote(5, od).tpdo[1]
            tpdo.add(0x2000)
            tpdo.enabled = True
            failed: list[HandlerFailed] = []
            net.add_listener(lambda e: failed.append(e) if isinstance(e, HandlerFailed) else None)
            net.send(Frame(0x185, (100).to_bytes(4, "little") + bytes(2)))
            await asyncio.sleep(0.01)
            stamp, when = tpdo["Stamp"], tpdo.timestamp
            assert stamp.milliseconds == 100 and tpdo.count == 1
            net.send(Frame(0x185, (0x0FFFFFFF).to_bytes(4, "little") + bytes(2)))
            await asyncio.sleep(0.01)
            assert len(failed) == 1 and "86400000" in failed[0].error
            assert tpdo["Stamp"] == stamp and tpdo.count == 1 and tpdo.timestamp == when

    simulate(main())
