"""``cobus sim`` in one process, python-canopen as the master in this one, both on a
python-can-remote server on 127.0.0.1: SDO (expedited and segmented), heartbeat, NMT, SYNC
and a synchronous TPDO cross the process boundary."""

from __future__ import annotations

import signal
import struct
import subprocess
import sys
import textwrap
import threading
import time

import can
import canopen
import pytest

pytestmark = pytest.mark.interop

RIG = """
    bus: embedded
    devices:
      - node: 10
        kind: cia402_drive
        name: servo
        options: {heartbeat_ms: 100}
      - node: 20
        kind: cia401_io
        options: {heartbeat_ms: 100, potentiometer: {channel: 1, position: 0.5}}
"""


@pytest.fixture
def bus_url(remote_bus_url: str) -> str:
    """The python-can-remote server of tests/conftest.py."""
    return remote_bus_url


def test_python_canopen_masters_a_rig_run_by_cobus_sim_in_another_process(tmp_path, bus_url):
    rig = tmp_path / "rig.yaml"
    rig.write_text(textwrap.dedent(RIG), encoding="utf-8")
    command = [sys.executable, "-m", "cobus.cli", "sim", str(rig), "--status-every", "0"]
    child = subprocess.Popen(
        [*command, "--interface", "remote", "--channel", bus_url],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    master = canopen.Network()
    try:
        assert child.stdout is not None
        first = child.stdout.readline()
        assert first.startswith("cobus sim: running 2 device(s) on remote ws://"), first
        master.connect(interface="remote", channel=bus_url)
        drive = canopen.RemoteNode(10, canopen.ObjectDictionary())
        io = canopen.RemoteNode(20, canopen.ObjectDictionary())
        master.add_node(drive)
        master.add_node(io)
        for node in (drive, io):
            node.sdo.RESPONSE_TIMEOUT = 2.0
        assert drive.sdo.upload(0x1000, 0) == struct.pack("<I", 0x00020192)
        assert io.sdo.upload(0x1008, 0) == b"cobus I/O module"  # segmented
        assert io.sdo.upload(0x6401, 1) == struct.pack("<h", 16384)  # the potentiometer
        assert drive.nmt.wait_for_heartbeat(timeout=2) == "PRE-OPERATIONAL"

        got: list[bytes] = []
        arrived = threading.Event()

        def on_tpdo2(can_id: int, data: bytearray, timestamp: float) -> None:
            got.append(bytes(data))
            arrived.set()

        master.subscribe(0x280 + 10, on_tpdo2)
        drive.nmt.state = "OPERATIONAL"
        assert drive.nmt.wait_for_heartbeat(timeout=2) == "OPERATIONAL"
        master.sync.transmit()  # TPDO2 (statusword, position) is synchronous
        assert arrived.wait(3), "no TPDO2 after SYNC"
        statusword, position = struct.unpack("<Hi", got[0])
        assert statusword == 0x0240 and position == 0
    finally:
        master.disconnect()
        child.send_signal(signal.SIGTERM)
        out, err = child.communicate(timeout=15)
    assert child.returncode == 0, err
    assert out.rstrip().endswith("cobus sim: stopped")


def test_a_newcomer_watches_cobus_sim_thesis_boot_with_cobus_monitor(bus_url):
    """Two processes as two terminals: `cobus monitor` first, then `cobus sim thesis`; the
    monitor shows the rig's nodes booting, decoded."""
    cobus = [sys.executable, "-m", "cobus.cli"]
    bus = ["-i", "remote", "-c", bus_url]
    monitor = subprocess.Popen(
        [*cobus, "monitor", "--duration", "15", *bus],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []
    assert monitor.stdout is not None
    reader = threading.Thread(target=lambda: lines.extend(monitor.stdout or ()), daemon=True)
    reader.start()
    # It listens once it shows a probe (node 127's boot-up) sent from here: then the sim.
    probe = can.Bus(interface="remote", channel=bus_url)
    try:
        until_listening = time.monotonic() + 30
        while not any("node 127 boot-up" in line for line in lines):
            assert time.monotonic() < until_listening, "the monitor never showed the probe"
            probe.send(can.Message(arbitration_id=0x77F, data=b"\x00", is_extended_id=False))
            time.sleep(0.2)
    finally:
        probe.shutdown()
    sim = subprocess.Popen(
        [*cobus, "sim", "thesis", "--status-every", "0", "--duration", "3", *bus],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        monitor.wait(timeout=60)
        reader.join(10)
        err = monitor.stderr.read() if monitor.stderr is not None else ""
        out = "".join(lines)
    finally:
        for child in (sim, monitor):
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
                child.wait(10)
    assert monitor.returncode == 0, err
    assert "node 10 boot-up" in out and "node 9 boot-up" in out
    assert "heartbeat PRE_OPERATIONAL" in out
    assert "frames/s" in out  # the node table at the end


def test_faults_are_injected_into_a_running_cobus_sim_from_another_shell(tmp_path, bus_url, capsys):
    """Issue 38: users asked to inject faults into a running `cobus sim` from another shell
    (`cobus sim inject 10 drive_fault code=0x7305`), over its control socket."""
    import json
    import stat

    from cobus.cli import main
    from cobus.runtime import Network

    rig = tmp_path / "rig.yaml"
    rig.write_text(textwrap.dedent(RIG), encoding="utf-8")
    sock = tmp_path / "sim.sock"
    command = [sys.executable, "-m", "cobus.cli", "sim", str(rig), "--status-every", "0"]
    child = subprocess.Popen(
        [*command, "--interface", "remote", "--channel", bus_url, "--control", str(sock)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    control = ["--control", str(sock)]
    try:
        assert child.stdout is not None
        assert child.stdout.readline().startswith("cobus sim: running 2 device(s)")
        assert f"cobus sim inject --control {sock}" in child.stdout.readline()
        assert stat.S_IMODE(sock.stat().st_mode) == 0o600  # its owner's only
        with Network(interface="remote", channel=bus_url) as net:
            seen: list[bytes] = []
            net.subscribe(0x08A, lambda frame, now: seen.append(frame.data))
            net.sleep(0.2)
            assert main(["sim", "inject", "10", "drive_fault", "code=0x7305", *control]) == 0
            assert capsys.readouterr().out == "drive_fault injected into node 10\n"
            deadline = time.monotonic() + 5
            while not seen and time.monotonic() < deadline:
                net.sleep(0.05)
        assert seen and seen[0][:2] == bytes([0x05, 0x73])  # its EMCY, on the bus
        assert main(["sim", "status", "--json", *control]) == 0
        status = json.loads(capsys.readouterr().out)
        servo = next(d for d in status["devices"] if d["node_id"] == 10)
        assert servo["state"] == "fault" and servo["error_code"] == "7305h"
        assert main(["sim", "faults", "20", *control]) == 0
        assert "heartbeat_stop" in capsys.readouterr().out
        assert main(["sim", "inject", "10", "nonsense", *control]) == 2  # a wrong request
        assert "cannot inject 'nonsense'" in capsys.readouterr().err
        assert main(["sim", "inject", "10", "drive_fault", "code", *control]) == 2
        assert "write KEY=VALUE" in capsys.readouterr().err
    finally:
        child.send_signal(signal.SIGINT)
        child.wait(10)
    assert not sock.exists()  # removed at the end
    assert main(["sim", "status", *control]) == 1
    assert "no cobus sim runs with the control socket" in capsys.readouterr().err
