"""cobus scan: the thesis rig's nodes found with their identity, names and errors."""

from __future__ import annotations

import json
import os

import pytest

from cobus.cli import main
from cobus.runtime import Network
from cobus.sim import start_rig
from cobus.trace.scan import scan


def test_scan_finds_the_thesis_rig_on_the_simulated_clock() -> None:
    with Network(simulated=True) as net:
        rig = start_rig(net, "thesis")
        rig.inject(10, "drive_fault", code=0x7121)  # an entry in 1003h
        seen: list[tuple[int, int]] = []
        found = net.run(scan(net.aio, progress=lambda d, t: seen.append((d, t))))
        assert net.aio.remotes == {}  # the scan's own remote nodes are gone again
    by_id = {n.node_id: n for n in found}
    assert set(by_id) >= {8, 9, 10}
    assert 3 not in by_id  # the EC motor speaks no CANopen SDO
    servo = by_id[10]
    assert servo.profile == 402 and servo.device_name and servo.identity["vendor_id"]
    assert servo.errors and servo.errors[0] & 0xFFFF == 0x7121
    assert by_id[9].profile == 401
    assert seen[-1] == (127, 127)


def test_the_scan_command(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv("COLUMNS", raising=False)  # piped: no terminal width to go by
    channel = f"scan-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        start_rig(net, "thesis")
        bus = ["-i", "virtual", "-c", channel, "--listen", "0.2", "--timeout", "0.05"]
        assert main(["scan", "--nodes", "8-10", "--json", *bus]) == 0
        found = json.loads(capsys.readouterr().out)
        assert [n["node_id"] for n in found] == [8, 9, 10]
        assert found[2]["profile"] == 402
        assert main(["scan", "--nodes", "9-10", *bus]) == 0
        out = capsys.readouterr().out
        # issue 38 (4): piped, the table fell back to 80 columns and every cell read 0x0…
        assert "…" not in out and "│" not in out and "\x1b" not in out
        lines = out.splitlines()
        assert lines[0] == "2 node(s) found"
        assert lines[1].split() == [
            "node", "heard", "device", "type", "vendor", "product", "revision", "serial",
            "name", "hw", "sw", "errors",
        ]  # fmt: skip
        assert lines[3].split()[:7] == [
            "10", "PRE_OPERATIONAL", "0x00020192", "0x00C0B005", "0x00000192", "0x00000001",
            "0x00000000",
        ]  # fmt: skip
        assert "cobus CiA 402 drive" in lines[3]
        assert all(line == line.rstrip() for line in lines)


def test_scan_objects_of_the_zapi_into_a_draft_eds(
    tmp_path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from cobus.od import load

    monkeypatch.delenv("COLUMNS", raising=False)
    channel = f"scan-objects-{os.getpid()}"
    draft = tmp_path / "zapi-draft.eds"
    with Network(interface="virtual", channel=channel) as net:
        start_rig(net, "thesis")
        bus = ["-i", "virtual", "-c", channel, "--timeout", "0.2"]
        args = ["scan", "--nodes", "8", "--objects", "0x2000-0x20FF", "--eds-out", str(draft)]
        assert main([*args, *bus]) == 0
        out = capsys.readouterr().out
        assert "20A8h:00" in out and "100" in out  # the main contactor voltage, 100 %
        assert main(["scan", "--objects", "0x2000-0x2001", *bus]) == 2
        assert "--objects scans one node" in capsys.readouterr().err
    od = load(draft)
    assert od.get_variable(0x20A8, 0) is not None
    assert draft.read_text().startswith("; draft EDS of node 8")


@pytest.mark.interop
def test_scan_finds_a_python_canopen_local_node(
    capsys: pytest.CaptureFixture[str], tmp_path
) -> None:
    import canopen

    from cobus.device import export_eds
    from cobus.runtime import AsyncNetwork
    from cobus.sim.drive402 import SimulatedDrive402
    from tests.util import simulate

    async def servo_eds() -> str:
        async with AsyncNetwork() as net:
            return export_eds(SimulatedDrive402(net, 5).od)

    eds = tmp_path / "servo.eds"
    eds.write_text(simulate(servo_eds()))
    channel = f"scan-peer-{os.getpid()}"
    peer = canopen.Network()
    peer.connect(interface="virtual", channel=channel)
    try:
        node = canopen.LocalNode(5, str(eds))
        peer.add_node(node)
        bus = ["-i", "virtual", "-c", channel, "--listen", "0.1", "--timeout", "0.2"]
        assert main(["scan", "--nodes", "1-8", "--json", *bus]) == 0
        found = json.loads(capsys.readouterr().out)
    finally:
        peer.disconnect()
    assert [n["node_id"] for n in found] == [5]
    assert found[0]["device_type"] == 0x00020192 and found[0]["profile"] == 402


def test_ctrl_c_in_a_scan_keeps_what_was_found(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 38 (8): Ctrl-C in scan exited 130 silently, its results lost."""
    from tests.util import ctrl_c_when

    channel = f"scan-ctrl-c-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        start_rig(net, "thesis")
        ctrl_c_when(net.aio, lambda f: f.cob_id == 0x600 + 40)  # asking node 40
        bus = ["-i", "virtual", "-c", channel, "--listen", "0.05", "--timeout", "0.2"]
        assert main(["scan", *bus]) == 130
    out, err = capsys.readouterr()
    assert err.startswith("cobus scan: interrupted after ") and " of 127 node-ID(s) asked; " in err
    assert err.rstrip().endswith("4 found so far")  # STÖBER 1, ZAPI 8, I/O 9, servo 10
    rows = [line.split()[0] for line in out.splitlines()[2:]]
    assert "10" in rows and "9" in rows
