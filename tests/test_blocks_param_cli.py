"""``cobus params diff|apply|snapshot`` against a simulated servo on python-can's virtual bus."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from cobus.cli import main
from cobus.device import export_eds
from cobus.runtime import Network
from cobus.sim import Rig, start_rig

RIG = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: servo}
"""


def test_diff_apply_snapshot_and_their_exit_codes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    channel = f"cli-params-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        eds = tmp_path / "servo.eds"
        eds.write_text(export_eds(rig.aio.devices[10].od))
        (tmp_path / "servo.yml").write_text(
            "parameters:\n  profile velocity: 20000\n  following error window: 500\n"
        )
        (tmp_path / "line.yml").write_text("nodes:\n  servo: {node_id: 10, eds: servo.eds}\n")
        bus = ["-i", "virtual", "-c", channel, "--eds", str(eds)]
        params = str(tmp_path / "servo.yml")

        assert main(["params", "diff", "10", params, *bus]) == 3
        out = capsys.readouterr().out
        assert "node 10: 2 of 2 parameters differ" in out
        assert "0x6081:00" in out and "50000" in out  # the set-point and what the node held

        assert main(["params", "apply", "10", params, *bus, "--json"]) == 0
        report = json.loads(capsys.readouterr().out)
        assert report["ok"] and report["saved"] and report["written"] == ["0x6081:00", "0x6065:00"]

        network = ["-i", "virtual", "-c", channel, "--network", str(tmp_path / "line.yml")]
        assert main(["params", "diff", "servo", params, *network]) == 0
        assert "node 10: up to date (2 parameters)" in capsys.readouterr().out

        snap = tmp_path / "snap.csv"
        assert main(["params", "snapshot", "10", str(snap), *bus, "--objects", "0x6081"]) == 0
        assert "1 parameters written" in capsys.readouterr().out
        assert "0x6081,0x00,20000,UNSIGNED32" in snap.read_text()

        (tmp_path / "bad.yml").write_text("parameters:\n  profile speed: 1\n")
        assert main(["params", "apply", "10", str(tmp_path / "bad.yml"), *bus]) == 2
        err = capsys.readouterr().err
        assert "bad.yml:2: profile speed: " in err and "did you mean" in err

        assert main(["params", "diff", "11", params, *bus, "--timeout", "0.1"]) == 1
        assert "[11] read 0x6081:00" in capsys.readouterr().out
        assert main(["params", "snapshot", "10", str(snap), "-i", "virtual", "-c", channel]) == 2
        assert "needs the node's EDS" in capsys.readouterr().err
