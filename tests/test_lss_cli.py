"""cobus lss against LSS slaves on python-can's virtual bus (real time)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

from cobus.apps._lss_plan import NetworkPlan, NetworkWriteError
from cobus.cli import main
from cobus.device import UNCONFIGURED, BitRateSwitched, add_device, minimal_od
from cobus.master.config import load_network
from cobus.od import load, resolve
from cobus.proto import Event
from cobus.proto.connection_set import LSS_MASTER_COB_ID
from cobus.proto.heartbeat import HeartbeatProducer
from cobus.proto.lss import LssIdentity, LssSlave, NodeIdAssigned
from cobus.runtime import AsyncNetwork, Network

A = LssIdentity(0x360, 0x1234, 0x1_0000, 0x2A)
B = LssIdentity(0x360, 0x1234, 0x1_0000, 0x07)


async def _attach(net: AsyncNetwork, slave: LssSlave, events: list[Event]) -> None:
    net.attach(slave, (LSS_MASTER_COB_ID,), events.append)


async def _beating(net: AsyncNetwork, node: int) -> None:
    """Node ``node``'s heartbeat every 100 ms: a node-ID in use."""
    producer = HeartbeatProducer(node)
    producer.set_period(100, net.time())
    net.attach(producer)


def test_scan_set_id_and_assign_all_from_the_shell(capsys: pytest.CaptureFixture[str]) -> None:
    channel = f"cli-lss-{os.getpid()}"
    bus = ["-i", "virtual", "-c", channel]
    stored: list[tuple[int, int | None]] = []
    slaves = [LssSlave(A, store=lambda n, b: stored.append((n, b)) or 0), LssSlave(B)]
    events: list[Event] = []
    with Network(interface="virtual", channel=channel) as net:
        for slave in slaves:
            net.run(_attach(net.aio, slave, events))
        assert main(["lss", "scan", "--vendor", "0x360", "--json", *bus]) == 0
        found = json.loads(capsys.readouterr().out)
        assert found["serial"] == 0x07 and found["node_id"] is None  # the lowest identity
        assert main(["lss", "scan", "--product", "0x1234", *bus]) == 0
        out, err = capsys.readouterr()
        assert "serial 0x00000007 (no node-ID; found in " in out
        assert "fastscan: a device answers; about " in err
        assert "  product  0x00001234 known, confirmed at " in err
        assert "  serial   0x00000007 found at " in err
        assert all(not s.configured for s in slaves)  # scan names nobody

        assert main(["lss", "set-id", "12", "--identity", "0x360:0x1234:0x10000:42", "--store",
                     *bus]) == 0  # fmt: skip
        assert "serial 0x0000002A: node-ID 12 (stored)" in capsys.readouterr().out
        assert slaves[0].active_node_id == 12 and stored == [(12, None)]

        net.run(_beating(net.aio, 12))  # node 12 booted: its heartbeat says 12 is taken
        # a bare LSS slave takes the node-ID but never boots: said, exit 1
        assert main(["lss", "assign-all", "--first", "12", "--json", *bus]) == 1
        out, err = capsys.readouterr()
        rows = json.loads(out)
        assert [(r["serial"], r["node_id"], r["booted"]) for r in rows] == [(0x07, 13, False)]
        assert "node(s) 13 took their node-ID but no boot-up came" in err
        assert slaves[1].active_node_id == 13
        assert [e.node_id for e in events if isinstance(e, NodeIdAssigned)] == [12, 13]

        find = ["lss", "find", "--vendor", "0x360", "--product", "0x1234", "--timeout", "0.02"]
        assert main([*find, "--revision", "0x10000", "--json", *bus]) == 0
        rows = json.loads(capsys.readouterr().out)
        assert [(r["serial"], r["node_id"]) for r in rows] == [(0x07, 13), (0x2A, 12)]
        assert main([*find[:-2], "--product", "0x4321", "--timeout", "0.02", *bus]) == 3
        assert "no device of vendor 0x00000360 and product 0x00004321" in capsys.readouterr().err
        assert main(["lss", "inquire", "--identity", "0x360:0x1234:0x10000:7", *bus]) == 0
        assert "serial 0x00000007: node-ID 13" in capsys.readouterr().out
        assert main(["lss", "store", "--identity", "0x360:0x1234:0x10000:42", "--json", *bus]) == 0
        assert json.loads(capsys.readouterr().out)["node_id"] == 12 and stored == [(12, None)] * 2
        assert main(["lss", "store", "--identity", "0x360:0x1234:0x10000:7", *bus]) == 1
        assert "storing is not supported" in capsys.readouterr().err
        assert main(["lss", "scan", *bus]) == 3
        err = capsys.readouterr().err
        assert "every device here has a node-ID" in err and "[12]" in err
        with pytest.raises(SystemExit) as usage:
            main(["lss", "set-id", "9", "--identity", "1:2:3", *bus])
        assert usage.value.code == 2
        assert "write VENDOR:PRODUCT:REVISION:SERIAL" in capsys.readouterr().err
        with pytest.raises(SystemExit):
            main(["lss", "scan", "--vendor", "acme", *bus])
        assert "'acme': a number 0 to 0xFFFFFFFF" in capsys.readouterr().err
        assert main(["lss", "set-id", "9", "--identity", "1:2:3:4", *bus]) == 1
        assert "no slave has that identity" in capsys.readouterr().err


EDS = Path(__file__).resolve().parent.parent / "examples" / "networks" / "devices"
NETWORK = """\
master:
  node_id: 127
nodes:
  io1:                       # known by vendor and product: its serial is written here
    node_id: 2
    eds: {eds}/cobus_io.eds
    vendor_id: 0x00000C0B
    product_code: 0x401
  io2:
    node_id: 4
    eds: {eds}/cobus_io.eds
    vendor_id: 0x00000C0B
    product_code: 0x401
    serial_number: 0x2222
  drive1:
    node_id: 3
    eds: {eds}/cobus_drive.eds
"""


def _io(serial: int) -> Any:
    od = load(EDS / "cobus_io.eds")
    resolve(od, 0x1018, 4).value = serial
    return od


def test_assign_all_by_the_network_file_writes_serials_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "line.yml"
    path.write_text(NETWORK.format(eds=EDS))
    channel = f"cli-lss-net-{os.getpid()}"
    bus = ["-i", "virtual", "-c", channel]
    with Network(interface="virtual", channel=channel) as net:
        other_vendor = minimal_od(vendor_id=0x999, serial=0x4444)
        for od in (_io(0x2222), _io(0x1111), minimal_od(vendor_id=0xC0B, serial=0x3333)):
            add_device(net, UNCONFIGURED, od)
        add_device(net, UNCONFIGURED, other_vendor)
        argv = ["lss", "assign-all", "--network", str(path), *bus]
        assert main([*argv, "--json"]) == 0
        rows = json.loads(capsys.readouterr().out)
        assert [(r["serial"], r["node_id"], r["network_node"], r["booted"]) for r in rows] == [
            (0x3333, 1, None, True),  # not in the file: a node-ID the file does not use
            (0x1111, 2, "io1", True),  # (the lowest identity first: product 0 above)
            (0x2222, 4, "io2", True),
            (0x4444, 5, None, True),  # another vendor than the file's: found by a whole scan
        ]
        assert all(r["seconds"] > 0 for r in rows)
        assert sorted(net.devices) == [1, 2, 4, 5]
    text = path.read_text()
    assert "    serial_number: 0x00001111   # by cobus lss assign-all\n" in text
    assert "# known by vendor and product" in text  # the rest as it was
    assert load_network(path).node("io1").serial_number == 0x1111


def test_a_node_on_one_line_is_not_rewritten_and_says_what_to_add(tmp_path: Path) -> None:
    path = tmp_path / "n.yml"
    path.write_text(
        f"master: {{node_id: 127}}\nnodes:\n  io1: {{node_id: 2, eds: {EDS}/cobus_io.eds, "
        "vendor_id: 0xC0B, product_code: 0x401}\n"
    )
    before = path.read_text()
    plan = NetworkPlan(path)
    planned = plan.choose(LssIdentity(0xC0B, 0x401, 0x10000, 5), set())
    assert planned is not None and planned.write and planned.node_id == 2
    with pytest.raises(NetworkWriteError, match="serial_number: 0x00000005"):
        plan.write_back({"io1": 5})
    assert path.read_text() == before


def _beating_device(net: Network, node: int, serial: int, **options: Any) -> Any:
    dev = add_device(net, node, minimal_od(vendor_id=0xC0B, serial=serial), lss=True, **options)
    dev.set(0x1017, 0, 100)  # heartbeat every 100 ms: heard
    return dev


def test_set_bitrate_moves_every_node_heard_or_none(capsys: pytest.CaptureFixture[str]) -> None:
    channel = f"cli-lss-rate-{os.getpid()}"
    bus = ["-i", "virtual", "-c", channel]
    with Network(interface="virtual", channel=channel) as net:
        devices = [_beating_device(net, n, 0x100 + n) for n in (2, 3, 4)]
        assert main(["lss", "set-bitrate", "250", "--json", *bus]) == 0
        assert json.loads(capsys.readouterr().out) == {"kbits": 250, "back": [2, 3, 4],
                                                       "missing": []}  # fmt: skip
        assert [d.bit_rate for d in devices] == [250, 250, 250]

        # one that cannot take the rate: nothing switches, it is named
        assert devices[1].lss is not None
        devices[1].lss.bit_rates = frozenset({0, 2, 3})  # 1000, 500, 250 only
        assert main(["lss", "set-bitrate", "125", *bus]) == 1
        err = capsys.readouterr().err
        assert "node 3: configure bit timing" in err and "not supported" in err
        assert "nothing switched: node(s) 3 cannot take 125 kbit/s" in err
        assert [d.bit_rate for d in devices] == [250, 250, 250]

        # one without LSS, named by --nodes
        plain = add_device(net, 9, minimal_od(serial=9))
        plain.set(0x1017, 0, 100)
        assert main(["lss", "set-bitrate", "500", "--nodes", "2,9", *bus]) == 1
        assert "node 9: it does not answer LSS" in capsys.readouterr().err
        plain.close()

        # one that switches but is not heard at the new rate (a wrong table): named
        def lost(event: object) -> None:
            if isinstance(event, BitRateSwitched):
                devices[2].aio.simulation.heartbeat_muted = True

        devices[2].add_listener(lost)
        assert main(["lss", "set-bitrate", "500", "--wait", "0.5", *bus]) == 1
        out, err = capsys.readouterr()
        assert "2 of 3 node(s) back at 500 kbit/s" in out
        assert "node(s) 4 not heard at 500 kbit/s within 0.5 s" in err
        with pytest.raises(SystemExit):
            main(["lss", "set-bitrate", "300", *bus])
        assert "one of CiA 305's rates" in capsys.readouterr().err


IO_NODE = """\
  {name}:
    node_id: {node_id}
    eds: {eds}/cobus_io.eds
    vendor_id: 0xC0B
    product_code: 0x401
"""


def _file(tmp_path: Path, *nodes: str, master: int = 127, end: str = "\n") -> Path:
    path = tmp_path / "net.yml"
    text = f"master:\n  node_id: {master}\nnodes:\n" + "".join(nodes)
    path.write_bytes(text.replace("\n", end).encode())
    return path


def _plan_of(path: Path, serial: int) -> NetworkPlan:
    plan = NetworkPlan(path)
    planned = plan.choose(LssIdentity(0xC0B, 0x401, 0x10000, serial), set())
    assert planned is not None and planned.write
    return plan


def test_the_network_file_keeps_its_form_when_serials_are_written(tmp_path: Path) -> None:
    # a placeholder serial is given its value, not a second key
    path = _file(
        tmp_path,
        IO_NODE.format(name="io1", node_id=2, eds=EDS) + "    serial_number: 0   # later\n",
    )
    _plan_of(path, 0x10).write_back({"io1": 0x10})
    assert "    serial_number: 0x00000010   # later\n" in path.read_text()
    assert load_network(path).node("io1").serial_number == 0x10
    # CRLF line ends, the mode and a link are kept
    path = _file(tmp_path, IO_NODE.format(name="io1", node_id=2, eds=EDS), end="\r\n")
    path.chmod(0o640)
    link = tmp_path / "link.yml"
    link.symlink_to(path)
    _plan_of(link, 0x11).write_back({"io1": 0x11})
    raw = path.read_bytes()
    assert raw.count(b"\r\n") == raw.count(b"\n") and b"serial_number: 0x00000011" in raw
    assert link.is_symlink() and (path.stat().st_mode & 0o777) == 0o640


@pytest.mark.parametrize(
    "entry",
    [
        "  io1: {{node_id: 2, eds: {eds}/cobus_io.eds,\n"
        "    vendor_id: 0xC0B, product_code: 0x401}}\n",
        "  io1:\n    node_id:\n      2\n    eds: {eds}/cobus_io.eds\n    vendor_id: 0xC0B\n"
        "    product_code: 0x401\n",
    ],
)
def test_a_node_not_written_one_key_per_line_is_left_alone(tmp_path: Path, entry: str) -> None:
    path = _file(tmp_path, entry.format(eds=EDS))
    before = path.read_bytes()
    plan = _plan_of(path, 5)
    with pytest.raises(NetworkWriteError, match="add by hand: io1: serial_number: 0x00000005"):
        plan.write_back({"io1": 5})
    assert path.read_bytes() == before


def test_a_file_changed_during_the_scan_is_left_alone(tmp_path: Path) -> None:
    path = _file(tmp_path, IO_NODE.format(name="io1", node_id=2, eds=EDS))
    plan = _plan_of(path, 5)
    path.write_text(path.read_text().replace("node_id: 2", "node_id: 5"))
    with pytest.raises(NetworkWriteError, match="changed while the scan ran"):
        plan.write_back({"io1": 5})


def test_the_masters_node_id_is_never_given_to_a_device(tmp_path: Path) -> None:
    path = _file(tmp_path, IO_NODE.format(name="io1", node_id=2, eds=EDS), master=1)
    assert {1, 2} <= NetworkPlan(path).used


def test_a_failure_midway_still_writes_what_was_done(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _file(
        tmp_path,
        IO_NODE.format(name="io1", node_id=2, eds=EDS),
        IO_NODE.format(name="io2", node_id=3, eds=EDS),
    )
    channel = f"cli-lss-midway-{os.getpid()}"
    bus = ["-i", "virtual", "-c", channel, "--listen", "0.3"]
    with Network(interface="virtual", channel=channel) as net:
        for serial in (0x10, 0x20, 0x20):  # two share one identity: the scan fails on them
            add_device(net, UNCONFIGURED, minimal_od(vendor_id=0xC0B, product_code=0x401,
                                                     serial=serial))  # fmt: skip
        argv = ["lss", "assign-all", "--network", str(path), "--json"]
        assert main([*argv, *bus]) == 1
        out, err = capsys.readouterr()
        assert [(r["serial"], r["node_id"]) for r in json.loads(out)] == [(0x10, 2)]
        assert "two devices share one identity" in err
    assert load_network(path).node("io1").serial_number == 0x10


def test_an_explicit_field_is_kept_and_only_the_named_nodes_switch(
    capsys: pytest.CaptureFixture[str],
) -> None:
    channel = f"cli-lss-kept-{os.getpid()}"
    bus = ["-i", "virtual", "-c", channel, "--listen", "0.3"]
    with Network(interface="virtual", channel=channel) as net:
        add_device(net, UNCONFIGURED, minimal_od(vendor_id=0x999, serial=1))
        assert main(["lss", "scan", "--vendor", "0x360", *bus]) == 3  # not the 0x999 one
        capsys.readouterr()
        named, other = _beating_device(net, 2, 0x102), _beating_device(net, 3, 0x103)
        assert main(["lss", "set-bitrate", "250", "--nodes", "2", *bus]) == 0
        assert (named.bit_rate, other.bit_rate) == (250, None)  # 3 was not asked: stays
        # a refusal puts back what the others accepted when the rate in use is given (-b)
        assert other.lss is not None
        other.lss.bit_rates = frozenset({0, 2})
        assert main(["lss", "set-bitrate", "125", "--nodes", "2,3", "-b", "250000", *bus]) == 1
        assert "node(s) 2 were given 250 kbit/s back" in capsys.readouterr().err
        assert named.lss is not None and named.lss.pending_bit_timing == 3
