"""Rigs: the YAML format and its errors, kinds resolved when the rig starts, devices and
faults driven through the rig (scheduled and injected, device and bus), the status table,
the ready thesis rig, the ``cobus sim`` command, and a rig run by the cobus master."""

from __future__ import annotations

import struct
import textwrap
from pathlib import Path

import pytest

from cobus.cli import main
from cobus.device import export_eds
from cobus.master import Master, loads_network
from cobus.proto import Frame
from cobus.runtime import AsyncNetwork, BusState, BusStateChanged
from cobus.sim import rig as rig_module
from cobus.sim._cli import format_table
from cobus.sim.drive402 import SimulatedDrive402
from cobus.sim.faults import BUS_FAULTS
from cobus.sim.io401 import SimulatedIo401
from cobus.sim.rig import DeviceSpec, KindUnavailableError, Rig, RigError, ready_rig
from tests.conftest import EDS_DIR
from tests.test_sim_support import simulate

MINE = textwrap.dedent(
    """
    bus: embedded
    devices:
      - node: 10
        kind: cia402_drive
        name: servo
        options: {heartbeat_ms: 100, positive_limit: 100000}
      - node: 20
        kind: cia401_io
        options: {heartbeat_ms: 50, potentiometer: 1}
      - node: 5
        kind: eds
        options: {eds: systec_iox1_16di_8do.eds}
    """
)


def write(folder: Path, text: str, name: str = "rig.yaml") -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def mine(tmp_path: Path, extra: str = "") -> Rig:
    """The test rig of this file's device kinds; the EDS next to the rig file."""
    (tmp_path / "systec_iox1_16di_8do.eds").write_bytes(
        (EDS_DIR / "systec_iox1_16di_8do.eds").read_bytes()
    )
    return Rig.load(write(tmp_path, MINE + textwrap.dedent(extra)))


def test_a_rig_file_starts_its_devices_on_a_network(tmp_path):
    rig = mine(tmp_path)

    async def main_():
        async with AsyncNetwork() as net:
            frames = []
            net.subscribe_all(lambda f, now: frames.append(f))
            await rig.start(net)
            await net.sleep(0.21)
            remote = net.add_remote(5)
            assert await remote.sdo.upload(0x1018, 1) == struct.pack("<I", 63)
            assert isinstance(rig.devices[10], SimulatedDrive402) and isinstance(
                rig.devices[20], SimulatedIo401
            )
            assert rig.device("servo") is rig.devices[10]
            rows = rig.status()
            assert [r["node_id"] for r in rows] == [10, 20, 5]
            assert rows[0]["state"] == "switch on disabled" and rows[0]["name"] == "servo"
            assert rows[2]["eds"] == "systec_iox1_16di_8do.eds"
            beats = [f for f in frames if f.cob_id == 0x714 and f.data == b"\x7f"]
            assert len(beats) == 4
            # the status table has one line per device and the common columns first
            table = format_table(rows).splitlines()
            assert table[0].split()[:4] == ["node", "name", "kind", "power"]
            assert len(table) == 4 and "potentiometer=0.0" in table[2]
            bus = rig.bus_status()
            assert bus["state"] == "error-active" and bus["frames"] >= 4
            await rig.stop()
            assert rig.devices == {} and net.devices == {}
            await rig.start(net)  # a stopped rig starts again
            await rig.stop()

    simulate(main_())


def test_faults_scheduled_in_the_file_and_injected_through_the_rig(tmp_path):
    rig = mine(
        tmp_path,
        """
        faults:
          - {at: 0.5, node: 20, fault: power_loss}
          - {at: 1.0, node: 20, fault: power_return}
          - {at: 1.2, node: 10, fault: overcurrent}
        """,
    )

    async def main_():
        async with AsyncNetwork() as net:
            seen = []
            net.subscribe_all(lambda f, now: seen.append((round(now, 3), f)))
            await rig.start(net)
            await net.sleep(1.3)
            beats = [t for t, f in seen if f.cob_id == 0x714 and f.data == b"\x7f"]
            assert beats[:10] == pytest.approx([0.05 * k for k in range(1, 11)])
            assert not [t for t in beats if 0.5 < t < 1.0]
            assert (1.0, Frame(0x714, b"\x00")) in seen  # boot-up at power return
            emcy = [f.data[:2] for t, f in seen if f.cob_id == 0x8A]
            assert emcy == [struct.pack("<H", 0x2310)]
            assert rig.faults(10)["blocked_rotor"]
            rig.inject("servo", "sdo_delay", delay=0.2)
            assert rig.devices[10].status()["faults"] == ["sdo_delay=0.2s"]
            with pytest.raises(RigError, match="no device 33"):
                rig.inject(33, "power_loss")
            with pytest.raises(RigError, match="is no bus fault"):
                rig.inject(None, "power_loss")
            with pytest.raises(RigError, match="needs the rig's network on a FaultyBus"):
                rig.inject(None, "bus_off")
            await rig.stop()

    simulate(main_())


def test_bus_faults_on_the_rigs_own_bus_seen_from_a_master_on_another_network(tmp_path):
    rig = mine(tmp_path)

    async def main_():
        async with (
            rig.running(interface="virtual", channel="rig-bus-faults") as net,
            AsyncNetwork(interface="virtual", channel="rig-bus-faults") as master,
        ):
            events = []
            net.add_listener(events.append)
            seen = []
            master.subscribe_all(lambda f, now: seen.append((now, f)))
            await net.sleep(0.5)
            rig.inject(None, "bus_off", duration=0.3)
            t_off = net.time()
            await net.sleep(0.6)
            changes = [(e.old, e.new) for e in events if isinstance(e, BusStateChanged)]
            assert changes == [
                (BusState.ACTIVE, BusState.BUS_OFF),
                (BusState.BUS_OFF, BusState.ACTIVE),
            ]
            quiet = [t for t, f in seen if f.cob_id == 0x714 and t_off < t < t_off + 0.3]
            assert quiet == []
            # each simulated CANopen node reports the recovery (8140h), then the reset
            for node in (10, 20, 5):
                emcy = [f.data[:2] for _, f in seen if f.cob_id == 0x80 + node]
                assert emcy == [b"\x40\x81", b"\x00\x00"], node
            # half the frames lost: the master hears about half of the heartbeats
            rig.inject(None, "frame_loss", rate=0.5, seed=11)
            t0 = net.time()
            await net.sleep(2.0)
            heard = len([1 for t, f in seen if f.cob_id == 0x714 and t > t0])
            assert 10 <= heard <= 30  # 40 sent, 20 expected; 3 sigma is 9.5
            assert rig.bus_status()["loss"] == 0.5
            rig.inject(None, "frame_loss", rate=0)
            rig.inject(None, "frame_corruption", rate=0.25, seed=2)
            assert rig.bus is not None and rig.bus.corruption == 0.25
            rig.inject(None, "frame_corruption", rate=0)
            with pytest.raises(ValueError, match="rate from 0 to 1"):
                rig.inject(None, "frame_loss", rate=2)
            # bus-off until restarted by hand
            rig.inject(None, "bus_off")
            await net.sleep(0.3)
            assert net.bus_state == BusState.BUS_OFF
            rig.inject(None, "bus_restart")
            await net.sleep(0.01)
            assert rig.bus_status()["state"] == "error-active"
            # a babbling node floods the bus
            rig.bus_status()
            rig.inject(20, "babbling", period_us=500)
            await net.sleep(0.2)
            status = rig.bus_status()
            assert status["babbling"] == "001h every 500 us"
            assert status["frames_per_s"] > 2000
            rig.inject(None, "babbling_stop")
            assert "babbling" not in rig.bus_status()

    simulate(main_())


def test_rig_run_by_the_cobus_master(tmp_path):
    """The thesis pattern: the master boots the nodes, the application reads the speed
    potentiometer and moves the servo to it by PDO."""
    rig = Rig(
        [
            DeviceSpec(10, "cia402_drive", "servo"),
            DeviceSpec(9, "cia401_io", "io", {"potentiometer": {"channel": 1, "position": 0.5}}),
        ]
    )
    network_yaml = """
        master: {node_id: 127, sync_period: 10}
        nodes:
          servo:
            node_id: 10
            eds: servo.eds
            heartbeat_time: 100
            device_type: 0x20192
            tpdo2: {mapping: [statusword, position_actual_value], transmission_type: 1}
            rpdo3: {mapping: [controlword, target_position], transmission_type: 255}
            signals:
              sw: {object: statusword}
              position: {object: position_actual_value}
              cw: {object: controlword}
              target: {object: target_position}
          io:
            node_id: 9
            eds: io.eds
            heartbeat_time: 100
            tpdo2: {mapping: ["0x6401:01"], transmission_type: 1}
            signals:
              pot: {object: "0x6401:01"}
    """

    async def main_():
        async with AsyncNetwork() as net:
            await rig.start(net)
            (tmp_path / "servo.eds").write_text(export_eds(rig.devices[10].od))  # type: ignore[attr-defined]
            (tmp_path / "io.eds").write_text(export_eds(rig.devices[9].od))  # type: ignore[attr-defined]
            config = loads_network(textwrap.dedent(network_yaml), base_dir=tmp_path)
            master = Master(net, config)
            try:
                await master.boot(timeout=5)
                await net.sleep(0.05)
                target = master.inputs["io.pot"]
                assert target == 16384
                for cw in (0x06, 0x07, 0x0F):
                    master.outputs["servo.cw"] = cw
                    await net.sleep(0.02)
                assert master.inputs["servo.sw"] & 0x6F == 0x27
                master.outputs["servo.target"] = target
                master.outputs["servo.cw"] = 0x1F
                await net.sleep(0.02)
                assert master.inputs["servo.sw"] & 0x1000  # set-point acknowledged
                master.outputs["servo.cw"] = 0x0F
                await net.sleep(1.0)
                assert master.inputs["servo.sw"] & 0x0400
                assert abs(master.inputs["servo.position"] - target) <= 20
            finally:
                await master.stop()
                await rig.stop()

    simulate(main_())


def test_the_ready_thesis_rig(tmp_path):
    rig = Rig.load(ready_rig("thesis"))
    kinds = {spec.node: spec.kind for spec in rig.specs}
    assert kinds == {
        8: "zapi_ace2",
        9: "cia401_io",
        10: "cia402_drive",
        3: "ec_motor",
        1: "stober_mds5000",
    }
    assert rig.bus_spec.embedded
    assert 1 <= next(s.node for s in rig.specs if s.kind == "ec_motor") <= 15
    # the devices of this engineer's kinds, from the thesis file, on a network
    mine_only = Rig([s for s in rig.specs if s.kind in ("cia401_io", "cia402_drive")])

    async def main_():
        async with AsyncNetwork() as net, mine_only.running(net):
            io = mine_only.device("remote I/O")
            assert isinstance(io, SimulatedIo401) and io.pot_channel == 1
            io.set_potentiometer(0.75)
            remote = net.add_remote(9)
            assert await remote.sdo.upload(0x6401, 1) == struct.pack("<h", 24575)
        assert mine_only.devices == {}

    simulate(main_())
    with pytest.raises(RigError, match="no ready rig 'nope'; cobus ships: thesis"):
        ready_rig("nope")


def test_a_missing_device_module_is_reported_when_the_rig_starts(tmp_path, monkeypatch):
    monkeypatch.setitem(rig_module.KINDS, "zapi_ace2", "cobus.sim.not_written_yet:ZapiAce2")
    rig = Rig.loads("devices: [{node: 8, kind: zapi_ace2}, {node: 9, kind: cia401_io}]")

    async def main_():
        async with AsyncNetwork() as net:
            with pytest.raises(KindUnavailableError, match="kind zapi_ace2 is not available"):
                await rig.start(net)
            assert net.devices == {}  # nothing was started
            custom = Rig.loads("devices: [{node: 9, kind: 'cobus.sim.io401:SimulatedIo401'}]")
            await custom.start(net)
            assert isinstance(custom.devices[9], SimulatedIo401)
            await custom.stop()
            other = Rig.loads("devices: [{node: 9, kind: 'cobus.sim.io401:ChannelError'}]")
            with pytest.raises(KindUnavailableError, match="is not a SimulatedDevice class"):
                await other.start(net)

    simulate(main_())


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("devices: []", "list of at least one device"),
        ("devices: [{node: 8, kind: robot}]", "kind 'robot' is unknown; known kinds: cia401_io"),
        ("devices: [{node: 0, kind: eds}]", "out of range"),
        ("devices: [{node: x, kind: eds}]", "must be a node-ID"),
        ("devices: [{node: 3, kind: eds, colour: red}]", "unknown key.*colour"),
        ("devices: [{node: 3, kind: eds}, {node: 3, kind: cia401_io}]", "node 3 is used twice"),
        ("bus: [1]\ndevices: [{node: 3, kind: eds}]", "bus: write 'embedded'"),
        ("bus: {interface: virtual, bitrate: fast}\ndevices: [{node: 3, kind: eds}]", "bitrate"),
        ("devices: [{node: 3, kind: eds}]\nfaults: [{fault: power_loss}]", "no bus fault"),
        ("devices: [{node: 3, kind: eds}]\nfaults: [{node: 4, fault: x}]", "no device with node 4"),
        ("devices: [{node: 3, kind: eds}]\nfaults: [{at: -1, fault: bus_off}]", "at -1"),
        ("devices: [{node: 3, kind: eds}]\nwires: 3", "unknown key.*wires"),
        ("devices: [{node: 3, kind: eds, quirks: {x: maybe}}]", "true or false"),
        ("devices: [{node: 3", "not valid YAML"),
        # Fault parameters are checked when the file loads, not when the fault fires:
        (
            "devices: [{node: 3, kind: cia402_drive}]\n"
            "faults: [{at: 60, node: 3, fault: overtemperature, temp: 90}]",
            r"faults\[0\]: overtemperature takes temperature \(number, optional\); not temp",
        ),
        (
            "devices: [{node: 3, kind: cia402_drive}]\n"
            "faults: [{at: 60, node: 3, fault: drive_fault, code: high}]",
            r"faults\[0\]: drive_fault: code 'high' must be an integer",
        ),
        (
            "devices: [{node: 3, kind: ec_motor}]\nfaults: [{at: 60, node: 3, fault: supply}]",
            "supply needs volts",
        ),
        (
            "devices: [{node: 3, kind: eds}]\nfaults: [{at: 9, fault: frame_loss, rate: 2}]",
            "frame_loss: rate 2 must be a rate from 0 to 1",
        ),
        (
            "devices: [{node: 3, kind: zapi_ace2}]\n"
            "faults: [{at: 1, node: 3, fault: battery, bdi: 50, colour: red}]",
            "battery takes bdi .*; not colour",
        ),
        (
            "devices: [{node: 3, kind: eds}]\n"
            "faults: [{at: 1, node: 3, fault: babbling, period_us: fast}]",
            "babbling: period_us 'fast' must be a number",
        ),
    ],
)
def test_rig_file_errors_say_where_and_what(text, message):
    with pytest.raises(RigError, match=message):
        Rig.loads(text, path="bench.yaml")


def test_an_optional_fault_parameter_may_be_null():
    Rig.loads(
        "devices: [{node: 3, kind: cia402_drive}]\nfaults:\n"
        "  - {at: 1, fault: frame_loss, rate: 0.1, seed: null}\n"
        "  - {at: 2, fault: bus_off, duration: ~}\n"
        "  - {at: 3, node: 3, fault: drive_fault, register: null}\n"
    )


def test_errors_found_when_the_rig_starts(tmp_path):
    bad_option = Rig.loads("devices: [{node: 9, kind: cia401_io, options: {colour: red}}]")
    bad_fault = Rig.loads(
        "devices: [{node: 9, kind: cia401_io}]\nfaults: [{node: 9, fault: blocked_rotor}]"
    )
    bad_value = Rig.loads("devices: [{node: 9, kind: cia401_io, options: {analog_inputs: -1}}]")

    async def main_():
        async with AsyncNetwork() as net:
            with pytest.raises(RigError, match=r"devices\[0\] \(cia401_io\): the options do not"):
                await bad_option.start(net)
            with pytest.raises(RigError, match="cia401_io cannot inject 'blocked_rotor'"):
                await bad_fault.start(net)
            with pytest.raises(RigError, match="analog_inputs -1"):
                await bad_value.start(net)
            assert net.devices == {}

    simulate(main_())
    assert set(BUS_FAULTS) == set(Rig.loads("devices: [{node: 1, kind: eds}]").faults())


def test_cobus_sim_command_lists_faults_and_reports_errors(tmp_path, capsys):
    path = mine(tmp_path).path
    assert main(["sim", str(path), "--list-faults"]) == 0
    out = capsys.readouterr().out
    assert "node 10 servo (cia402_drive):" in out and "blocked_rotor" in out
    assert "bus:" in out and "frame_loss" in out
    assert main(["sim", str(tmp_path / "missing.yaml")]) == 2
    assert "cannot read the rig file" in capsys.readouterr().err
    assert main(["sim", "nope"]) == 2
    assert "no ready rig 'nope'" in capsys.readouterr().err


def test_cobus_sim_runs_for_a_duration_and_prints_the_status(tmp_path, capsys):
    path = mine(tmp_path).path
    code = main(
        [
            "sim",
            str(path),
            "--interface",
            "virtual",
            "--channel",
            "cli-run",
            "--status-every",
            "0.2",
            "--duration",
            "0.5",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    assert out.startswith("cobus sim: running 3 device(s) on virtual cli-run")
    assert out.count("node  name") == 2 and "bus: state error-active" in out
    assert out.rstrip().endswith("cobus sim: stopped")


def test_the_control_socket_replaces_a_stale_one_and_refuses_to_take_a_live_one(tmp_path):
    import asyncio
    import socket

    from cobus.sim._control import ControlError, ask, serve

    class FakeRig:
        def status(self) -> list[dict[str, object]]:
            return [{"node_id": 1}]

        def bus_status(self) -> dict[str, object]:
            return {}

        def faults(self, node: object) -> dict[str, str]:
            return {"x": "y"}

        def inject(self, node: object, fault: str, **params: object) -> None:
            raise ValueError(f"no {fault}")

    path = tmp_path / "c.sock"
    stale = socket.socket(socket.AF_UNIX)
    stale.bind(str(path))
    stale.close()  # a socket file nobody listens on: a simulation that ended

    async def scenario() -> None:
        server = await serve(FakeRig(), path)
        try:
            got = await asyncio.to_thread(ask, path, {"op": "status"})
            assert got["devices"] == [{"node_id": 1}]
            with pytest.raises(ControlError, match="no zap"):
                await asyncio.to_thread(ask, path, {"op": "inject", "node": 1, "fault": "zap"})
            with pytest.raises(ControlError, match="op 'nope'"):
                await asyncio.to_thread(ask, path, {"op": "nope"})
            with pytest.raises(ControlError, match="another cobus sim listens"):
                await serve(FakeRig(), path)
        finally:
            server.close()
            await server.wait_closed()

    asyncio.run(scenario())
    (tmp_path / "file").write_text("x")
    with pytest.raises(ControlError, match="is no socket"):
        asyncio.run(serve(FakeRig(), tmp_path / "file"))


def test_without_an_interface_the_message_says_how_to_name_one(monkeypatch, capsys):
    monkeypatch.delenv("CAN_INTERFACE", raising=False)
    monkeypatch.setenv("HOME", "/nonexistent")  # (no ~/.canrc)
    assert main(["sim", "thesis", "--duration", "1", "--control", "/nonexistent/c.sock"]) == 1
    err = capsys.readouterr().err
    assert "no CAN interface given" in err and "-i/--interface" in err


def test_a_control_path_that_cannot_be_used_is_one_line(tmp_path, capsys):
    long = tmp_path / ("x" * 120 + ".sock")
    for path, why in (
        (tmp_path / "nowhere" / "c.sock", "there is no folder"),
        (long, "at most 107 bytes"),
    ):
        argv = ["sim", "thesis", "--duration", "1", "-i", "virtual", "--control", str(path)]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and why in err
        assert main(["sim", "status", "--control", str(path)]) in (1, 2)
        assert "Traceback" not in capsys.readouterr().err


def test_sim_runs_without_a_control_socket_when_told(tmp_path, capsys):
    sock = tmp_path / "c.sock"
    argv = ["sim", "thesis", "--duration", "0.3", "--status-every", "0", "-i", "virtual"]
    assert main([*argv, "-c", "ctl-on", "--control", str(sock)]) == 0
    assert f"cobus sim inject --control {sock}" in capsys.readouterr().out
    assert not sock.exists()  # removed at the end
    assert main([*argv, "-c", "ctl-off", "--no-control"]) == 0
    assert "another shell" not in capsys.readouterr().out
