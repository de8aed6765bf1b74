"""cobus lss against LSS slaves on python-can's virtual bus (real time)."""

from __future__ import annotations

import json
import os

import pytest

from cobus.cli import main
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
        assert all(not s.configured for s in slaves)  # scan names nobody

        assert main(["lss", "set-id", "12", "--identity", "0x360:0x1234:0x10000:42", "--store",
                     *bus]) == 0  # fmt: skip
        assert "serial 0x0000002A: node-ID 12 (stored)" in capsys.readouterr().out
        assert slaves[0].active_node_id == 12 and stored == [(12, None)]

        net.run(_beating(net.aio, 12))  # node 12 booted: its heartbeat says 12 is taken
        assert main(["lss", "assign-all", "--first", "12", "--json", *bus]) == 0
        rows = json.loads(capsys.readouterr().out)
        assert [(r["serial"], r["node_id"]) for r in rows] == [(0x07, 13)]
        assert slaves[1].active_node_id == 13
        assert [e.node_id for e in events if isinstance(e, NodeIdAssigned)] == [12, 13]

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
