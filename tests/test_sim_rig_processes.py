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

import canopen
import pytest

from tests.test_runtime_processes import _free_port, _wait_for_port

pytestmark = pytest.mark.interop

CAN_REMOTE = [sys.executable, "-m", "can_remote", "-i", "virtual"]
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
def bus_url():
    port = _free_port()
    server = subprocess.Popen(
        [*CAN_REMOTE, "-c", f"sim{port}", "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        _wait_for_port(port, time.monotonic() + 15)
        yield f"ws://127.0.0.1:{port}/"
    finally:
        server.terminate()
        server.wait(10)


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
        [*cobus, "monitor", "--duration", "6", *bus],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(2.0)  # (it connects)
    sim = subprocess.Popen(
        [*cobus, "sim", "thesis", "--status-every", "0", "--duration", "3", *bus],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        out, err = monitor.communicate(timeout=60)
    finally:
        for child in (sim, monitor):
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
                child.wait(10)
    assert monitor.returncode == 0, err
    assert "node 10 boot-up" in out and "node 9 boot-up" in out
    assert "heartbeat PRE_OPERATIONAL" in out
    assert "frames/s" in out  # the node table at the end
