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
from tests.util import ctrl_c_when, servo_bench

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


def test_a_snapshot_holds_no_commands_and_applying_it_leaves_a_disabled_drive_disabled(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38 (1): the snapshot of an enabled servo held its controlword and targets, and
    applying it to the disabled drive switched it back on (0x0231 → 0x0637)."""
    with servo_bench(tmp_path, "cli-params-commands") as (net, _rig, eds, bus):
        bus = [*bus, "--eds", str(eds)]
        servo = net.add_remote(10)
        for controlword in (0x06, 0x07, 0x0F):  # shutdown, switch on, enable operation
            servo.sdo.download(0x6040, 0, controlword.to_bytes(2, "little"))
        servo.sdo.download(0x60FF, 0, (1000).to_bytes(4, "little", signed=True))

        def statusword() -> int:
            return int.from_bytes(servo.sdo.upload(0x6041, 0), "little") & 0x6F

        assert statusword() == 0x27  # operation enabled

        snap = tmp_path / "s.yml"
        assert main(["params", "snapshot", "10", str(snap), *bus]) == 0
        out = capsys.readouterr().out
        text = snap.read_text()
        for index in ("0x6040", "0x6060", "0x607A", "0x60FF", "0x6071", "0x6081"):
            assert f'"{index}:00"' not in text, index
        assert '"0x6065:00"' in text  # the following error window: configuration
        assert "left out as commands or process data" in out
        assert "0x6040:00 Controlword: the CiA 402 controlword" in out
        named = tmp_path / "named.yml"
        assert main(["params", "snapshot", "10", str(named), *bus, "--objects", "0x6040"]) == 0
        capsys.readouterr()

        servo.sdo.download(0x6040, 0, (0x06).to_bytes(2, "little"))  # disable
        assert statusword() == 0x21  # ready to switch on
        assert main(["params", "apply", "10", str(snap), *bus]) == 0
        capsys.readouterr()
        assert statusword() == 0x21  # still disabled

        # named on its own, a command is read (while enabled); the set is then refused ...
        assert '"0x6040:00": {value: 15, type: UNSIGNED16}' in named.read_text()
        assert main(["params", "apply", "10", str(named), *bus]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1  # one line
        assert "0x6040:00 Controlword: the CiA 402 controlword" in err
        assert "--allow-commands" in err
        assert statusword() == 0x21  # nothing was written

        # ... unless the user asks for exactly that
        assert main(["params", "apply", "10", str(named), *bus, "--allow-commands"]) == 0
        assert "0x6040:00" in capsys.readouterr().out
        assert statusword() == 0x27

        # a range leaves commands out as the default does
        ranged = tmp_path / "ranged.csv"
        args = ["--objects", "0x6000-0x60FF", "--json"]
        assert main(["params", "snapshot", "10", str(ranged), *bus, *args]) == 0
        result = json.loads(capsys.readouterr().out)
        left = {entry["object"] for entry in result["not_parameters"]}
        assert {"0x6040:00", "0x6060:00", "0x607A:00", "0x60FF:00", "0x6071:00"} <= left
        assert "0x6040" not in ranged.read_text() and "0x6065" in ranged.read_text()
        args = ["--objects", "0x6040-0x6040"]
        assert main(["params", "snapshot", "10", str(ranged), *bus, *args]) == 2
        assert "all are commands or process data (0x6040:00 Controlword)" in (
            capsys.readouterr().err
        )


def test_ctrl_c_in_apply_says_what_was_written_and_what_was_cut_short(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38 (8): Ctrl-C in params apply exited 130 without a word of what it had
    already written."""
    with servo_bench(tmp_path, "cli-params-ctrl-c") as (net, rig, eds, bus):
        (tmp_path / "servo.yml").write_text(
            "parameters:\n  profile velocity: 20000\n  following error window: 500\n"
        )
        rig.devices[10].inject("sdo_delay", delay=0.3)
        # the download of the second parameter (6065h) is in flight when Ctrl-C comes
        ctrl_c_when(
            net.aio, lambda f: f.cob_id == 0x60A and f.data[:4] == bytes.fromhex("23656000")
        )
        bus = [*bus, "--eds", str(eds), "--timeout", "1"]
        assert main(["params", "apply", "10", str(tmp_path / "servo.yml"), *bus]) == 130
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("cobus params: interrupted (write); written before: ")
    assert "0x6081:00 Profile velocity = 20000" in err
    assert "not saved: the node loses them at its next power-up" in err
    assert "the write of 0x6065:00 Following error window = 500 was cut short" in err


def test_review_findings_on_params(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """What a review as a new user found: a snapshot of a silent node wiped a good file; a
    DCF's command was left out even with --allow-commands; refusals printed no JSON."""
    from cobus.od import load

    with servo_bench(tmp_path, "cli-params-review") as (_net, rig, eds, bus):
        bus = [*bus, "--eds", str(eds)]

        # a node that does not answer: one line, the file left as it was
        good = tmp_path / "good.yml"
        good.write_text("parameters: {}\n")
        args = ["params", "snapshot", "50", str(good), *bus, "--timeout", "0.05"]
        assert main(args) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "node 50 does not answer: the snapshot stopped" in err
        assert "good.yml left as it was" in err and good.read_text() == "parameters: {}\n"

        # a DCF's command: left out and said, applied with --allow-commands
        dcf = tmp_path / "servo.dcf"
        main(["eds", "convert", str(eds), str(dcf), "--node-id", "10"])
        dcf_od = load(dcf)
        mode = dcf_od.get_variable(0x6060, 0)
        assert mode is not None
        mode.parameter_value = 3
        dcf.write_text(dcf_od.to_dcf(10))
        capsys.readouterr()
        assert main(["params", "diff", "10", str(dcf), *bus, "--json"]) in (0, 3)
        report = json.loads(capsys.readouterr().out)
        assert report["left_out"] == [
            {
                "object": "0x6060:00",
                "name": "Modes of operation",
                "why": "the CiA 402 modes of operation: it changes how the drive moves",
            }
        ]
        assert main(["params", "apply", "10", str(dcf), *bus, "--allow-commands"]) == 0
        assert rig.devices[10].device.get(0x6060, 0) == 3
        capsys.readouterr()

        # a refusal with --json is a JSON object too; the hint is the option's
        named = tmp_path / "cw.yml"
        named.write_text('parameters:\n  "0x6040:00": 15\n')
        assert main(["params", "apply", "10", str(named), *bus, "--json"]) == 2
        out, err = capsys.readouterr()
        refused = json.loads(out)
        assert refused["ok"] is False and refused["exit"] == 2
        assert "(--allow-commands)" in err and "allow_commands=True" not in err


def test_an_eds_of_another_device_is_refused_for_apply_and_said_for_diff(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """With another device's EDS, names, types and commands would be misjudged."""
    examples = Path(__file__).resolve().parent.parent / "examples" / "networks"
    channel = f"cli-params-other-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        io_eds = ["--eds", str(examples / "io.eds")]
        bus = ["-i", "virtual", "-c", channel]
        (tmp_path / "set.yml").write_text('parameters:\n  "0x1017:00": 50\n')
        held = rig.devices[10].device.get(0x1017, 0)
        assert main(["params", "apply", "10", str(tmp_path / "set.yml"), *io_eds, *bus]) == 2
        err = capsys.readouterr().err
        assert "node 10 reports device type 0x00020192 (profile 402)" in err
        assert "the EDS is another device's; nothing written" in err
        assert rig.devices[10].device.get(0x1017, 0) == held
        main(["params", "diff", "10", str(tmp_path / "set.yml"), *io_eds, *bus])
        assert "the EDS is another device's" in capsys.readouterr().err
        assert main(["pdo", "show", "10", *io_eds, *bus]) == 0
        assert "the EDS is another device's" in capsys.readouterr().err
        assert main(["pdo", "map", "10", "tpdo1", "--disable", *io_eds, *bus]) == 2
