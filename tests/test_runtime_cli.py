"""cobus sdo / nmt / sync against a simulated servo on python-can's virtual bus."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from cobus.cli import main
from cobus.device import export_eds
from cobus.proto import Frame
from cobus.runtime import Network
from cobus.sim import Rig, start_rig
from tests.util import Terminal, ctrl_c_when, servo_bench

RIG = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: servo}
"""


def test_sdo_nmt_and_sync_from_the_shell(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    channel = f"cli-sdo-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        servo = rig.aio.devices[10]
        eds = tmp_path / "servo.eds"
        eds.write_text(export_eds(servo.od))
        seen: list[Frame] = []
        net.aio.subscribe_all(lambda f, now: seen.append(f))
        bus = ["-i", "virtual", "-c", channel]

        assert main(["sdo", "read", "10", "0x1008", "0", *bus]) == 0
        # no EDS: CiA 301 still names and types the communication objects
        assert "1008h:00 Manufacturer device name = cobus CiA 402 drive" in (
            capsys.readouterr().out
        )
        nowhere = tmp_path / "no" / "such" / "folder.eds"
        assert main(["sdo", "upload", "10", "0x1021", "0", str(nowhere), *bus]) == 2
        assert "there is no folder" in capsys.readouterr().err
        assert main(["sdo", "read", "10", "1008h", "0", "--eds", str(eds), *bus]) == 0
        assert "1008h:00 Manufacturer device name = cobus CiA 402 drive" in (
            capsys.readouterr().out
        )
        assert main(["sdo", "write", "10", "0x6081", "0", "20000", "--type", "u32", *bus]) == 0
        assert servo.device.get(0x6081, 0) == 20000
        assert main(["sdo", "write", "10", "0x6081", "0", "30000", "--eds", str(eds), *bus]) == 0
        assert servo.device.get(0x6081, 0) == 30000
        out = tmp_path / "servo-stored.eds"
        assert main(["sdo", "upload", "10", "0x1021", "0", str(out), "--block", *bus]) == 0
        assert out.read_bytes().startswith(b"[FileInfo]")
        capsys.readouterr()

        assert main(["sdo", "read", "10", "0x5555", "0", *bus]) == 1
        assert "object does not exist in the object dictionary" in capsys.readouterr().err
        assert main(["sdo", "read", "10", "0x1008", "0", "--eds", str(eds), "--json", *bus]) == 0
        read = json.loads(capsys.readouterr().out)
        assert read["value"] == "cobus CiA 402 drive" and read["ok"] is True
        assert read["name"] == "Manufacturer device name" and read["index"] == 0x1008
        assert main(["sdo", "read", "10", "0x1017", "0", "--json", *bus]) == 0
        assert isinstance(json.loads(capsys.readouterr().out)["value"], int)  # no EDS: a number
        assert main(["sdo", "read", "10", "0x5555", "0", "--json", *bus]) == 1
        failed = json.loads(capsys.readouterr().out)
        assert failed["ok"] is False and failed["abort_code"] == 0x06020000
        assert main(["sdo", "write", "10", "0x1008", "0", "x", "--type", "string", *bus]) == 1
        assert "read only" in capsys.readouterr().err
        assert main(["sdo", "read", "11", "0x1000", "0", "--timeout", "0.1", *bus]) == 1
        assert main(["sdo", "write", "10", "0x6081", "0", "5", *bus]) == 2
        assert "give --type" in capsys.readouterr().err

        # issue 38 (6): objects by name, the sub-index 0 by default, values by their type
        eds_ = ["--eds", str(eds)]
        assert main(["sdo", "read", "10", "Position actual value", *eds_, *bus]) == 0
        assert capsys.readouterr().out == "6064h:00 Position actual value = 0\n"
        assert main(["sdo", "write", "10", "profile velocity", "25000", *eds_, *bus]) == 0
        assert capsys.readouterr().out == "6081h:00 Profile velocity <- 25000\n"
        assert servo.device.get(0x6081, 0) == 25000
        assert main(["sdo", "write", "10", "profile velocity", "26000", "--json", *eds_, *bus]) == 0
        written = json.loads(capsys.readouterr().out)
        assert written["value"] == 26000 and written["data"] == "90650000"  # typed, as read
        assert main(["sdo", "read", "10", "Statusword", "--hex", *eds_, *bus]) == 0
        assert capsys.readouterr().out.startswith("6041h:00 Statusword = 0x0")
        assert main(["sdo", "read", "10", "Identity object.Vendor-ID", "--hex", *bus]) == 0
        assert capsys.readouterr().out == "1018h:01 Identity object.Vendor-ID = 0x00C0B005\n"
        assert main(["sdo", "read", "10", "0x1018", "1", *eds_, *bus]) == 0  # a record's sub
        assert capsys.readouterr().out == f"1018h:01 Identity object.Vendor-ID = {0xC0B005}\n"
        assert main(["sdo", "read", "10", "Identity object", "1", *bus]) == 0  # a record's name
        assert capsys.readouterr().out == f"1018h:01 Identity object.Vendor-ID = {0xC0B005}\n"
        assert main(["sdo", "read", "10", "Max position limit", *eds_, *bus]) == 0  # a sub's own
        assert capsys.readouterr().out.startswith("607Dh:02 Software position limit.Max")
        assert main(["sdo", "read", "10", "0x1018:01", *bus]) == 0  # sub-index in the address
        assert capsys.readouterr().out == f"1018h:01 Identity object.Vendor-ID = {0xC0B005}\n"
        assert main(["sdo", "read", "10", "Position actual valu", *eds_, *bus]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "did you mean 'Position actual value'" in err
        assert main(["sdo", "read", "10", "Position actual value", *bus]) == 2
        assert "give --eds" in capsys.readouterr().err
        assert main(["sdo", "read", "10", "1008", *bus]) == 2
        assert "write 0x1008 or 1008h" in capsys.readouterr().err
        assert main(["sdo", "read", "10", "0x1018:01", "2", *bus]) == 2
        assert "names sub-index 1" in capsys.readouterr().err
        assert main(["sdo", "write", "10", "0x6081", "0", "1", "2", *eds_, *bus]) == 2
        assert "too many arguments" in capsys.readouterr().err

        assert main(["nmt", "start", "10", *bus]) == 0
        net.sleep(0.1)
        assert servo.status()["nmt"] == "OPERATIONAL" or servo.device.state.name == "OPERATIONAL"
        assert main(["nmt", "preop", "all", *bus]) == 0
        assert main(["nmt", "reset", "200", *bus]) == 2
        seen.clear()
        capsys.readouterr()
        assert main(["sync", "--period", "0.01", "--count", "5", *bus]) == 0
        assert capsys.readouterr().out.startswith("5 SYNC sent, every 0.01 s")
        net.sleep(0.05)
        assert sum(1 for f in seen if f.cob_id == 0x80) == 5  # as many as asked
        seen.clear()
        assert main(["sync", "--period", "0.01", "--count", "4", "--overflow", "3", *bus]) == 0
        net.sleep(0.05)
        counters = [f.data for f in seen if f.cob_id == 0x80]
        assert counters == [b"\x01", b"\x02", b"\x03", b"\x01"]
        capsys.readouterr()
        # python-can's virtual bus would send from a thread whose frames its own bus never
        # hears: refused, with the reason and what to do
        assert main(["sync", "--by-interface", "--count", "1", *bus]) == 1
        err = capsys.readouterr().err
        assert "the virtual interface cannot send periodic frames by itself" in err
        assert "leave --by-interface out" in err
        for bad_args, why in (
            (["--overflow", "1"], "2 to 240"),
            (["--period", "5000"], "4294.967295 s"),
            (["--period", "1e-7"], "0.000001"),
        ):
            with pytest.raises(SystemExit) as bad:
                main(["sync", *bad_args, *bus])
            assert bad.value.code == 2 and why in capsys.readouterr().err


def test_sdo_upload_and_download_show_a_progress_bar_on_a_terminal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """stderr on a (pseudo-)terminal: a rich progress bar with bytes, gone once done;
    segmented (no --block) so the transfer takes many frames."""

    monkeypatch.setenv("COLUMNS", "120")
    term = Terminal()
    terminal = term.file
    channel = f"cli-progress-{os.getpid()}"
    out = tmp_path / "stored.eds"
    monkeypatch.setattr("sys.stderr", terminal)
    try:
        with Network(interface="virtual", channel=channel) as net:
            start_rig(net, Rig.loads(RIG))
            bus = ["-i", "virtual", "-c", channel]
            assert main(["sdo", "upload", "10", "0x1021", "0", str(out), *bus]) == 0
            assert main(["sdo", "read", "10", "0x1000", "0", *bus]) == 0  # (no bar)
            small = tmp_path / "name.bin"
            small.write_bytes(b"x" * 3000)
            assert main(["sdo", "download", "10", "0x1021", "0", str(small), *bus]) == 1
    finally:
        monkeypatch.undo()
        term.close()
    assert out.read_bytes().startswith(b"[FileInfo]")
    shown = term.text()
    assert "upload 1021h:00" in shown and "/" in shown and "kB" in shown
    assert "download 1021h:00" in shown  # the bar, then the refusal
    assert "node 10 1021h:00 Store EDS:" in shown


NO_BUS = ["-i", "cobus_no_such_interface", "-c", "can9"]


@pytest.mark.parametrize(
    "argv",
    [
        ["scan"],
        ["monitor"],
        ["record", "{tmp}/out.log"],
        ["sdo", "read", "10", "0x1000", "0"],
        ["sdo", "write", "10", "0x1017", "0", "100", "--type", "u16"],
        ["sdo", "upload", "10", "0x1008", "0", "{tmp}/out.bin"],
        ["nmt", "start", "10"],
        ["sync"],
        ["params", "diff", "10", "examples/parameters/servo.yml"],
        ["params", "apply", "10", "examples/parameters/servo.yml"],
        ["params", "snapshot", "10", "{tmp}/s.yml", "--eds", "examples/networks/servo.eds"],
        ["ec", "read", "3", "p_ven"],
        ["ec", "write", "3", "p_acc", "100"],
        ["ec", "mode", "3", "OFF"],
        ["ec", "status", "3"],
        ["sim", "thesis"],
    ],
    ids=lambda argv: " ".join(argv[:2]),
)
def test_a_bus_that_cannot_be_opened_is_one_line_and_exit_1(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38 (3): params and ec printed a 45-line traceback."""
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main([*args, *NO_BUS]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("cobus"), err
    assert "cobus_no_such_interface" in err and "Traceback" not in err


BROKEN_EDS = """[FileInfo]
FileName=broken.eds
[1000]
ParameterName=Device type
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=zz
[6040]
ParameterName=Controlword
DataType=0x0006
AccessType=rww
"""


@pytest.mark.parametrize(
    "argv",
    [
        ["sdo", "read", "10", "0x6040", "--eds", "{eds}"],
        ["params", "diff", "10", "examples/parameters/servo.yml", "--eds", "{eds}"],
        ["decode", "{tmp}/none.asc", "--eds", "10={eds}"],
        ["monitor", "--duration", "0.1", "--eds", "10={eds}"],
    ],
    ids=lambda argv: argv[0],
)
def test_an_empty_eds_is_refused_and_a_broken_one_said_once(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38 (5): sdo, params, decode and monitor used a broken or empty EDS silently."""
    empty = tmp_path / "empty.eds"
    empty.write_text("; nothing here\n")
    broken = tmp_path / "broken.eds"
    broken.write_text(BROKEN_EDS)

    def run(eds: Path) -> int:
        args = [a.replace("{eds}", str(eds)).replace("{tmp}", str(tmp_path)) for a in argv]
        return main(args if args[0] == "decode" else [*args, *NO_BUS])

    assert run(empty) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{empty}: the file defines no objects" in err
    run(broken)  # (goes on to the bus or the trace file, which are not there)
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if "has errors, the rest of it is used" in line]
    assert len(warnings) == 1 and f"{broken}:8: [1000] error: DefaultValue" in warnings[0]
    assert f"cobus eds check {broken}" in warnings[0] and "Traceback" not in err


def test_ctrl_c_in_an_sdo_transfer_says_it_was_aborted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38 (8): Ctrl-C in sdo exited 130 without a word."""
    channel = f"cli-sdo-ctrl-c-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        rig.devices[10].inject("sdo_delay", delay=0.5)
        again = ctrl_c_when(net.aio, lambda f: f.cob_id == 0x60A)
        bus = ["-i", "virtual", "-c", channel]
        assert main(["sdo", "write", "10", "0x1017", "100", "--type", "u16", *bus]) == 130
        err = capsys.readouterr().err
        assert err == (
            "cobus: interrupted: the write of 1017h:00 Producer heartbeat time was aborted: "
            "the node may or may not have taken the value\n"
        )
        again()
        assert main(["sdo", "read", "10", "0x1017", *bus]) == 130
        assert capsys.readouterr().err == (
            "cobus: interrupted: the read of 1017h:00 Producer heartbeat time was aborted\n"
        )


def test_ctrl_c_in_any_other_command_says_interrupted(capsys: pytest.CaptureFixture[str]) -> None:
    channel = f"cli-ec-ctrl-c-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        ctrl_c_when(net.aio, lambda f: True)
        argv = ["ec", "read", "3", "p_ven", "--timeout", "5", "-i", "virtual", "-c", channel]
        assert main(argv) == 130
    assert capsys.readouterr().err == "cobus ec: interrupted\n"


def test_each_command_s_help_in_the_table_is_its_module_s() -> None:
    """cobus --help lists the commands from cobus.cli.COMMANDS without importing them: what
    it says of each must be what the command's module says."""
    from cobus.cli import COMMANDS, build_parser

    parser = build_parser()  # every module registered
    actions = [a for a in parser._actions if a.dest == "command"]
    listed = {c.dest: c.help for c in actions[0]._choices_actions}  # type: ignore[attr-defined]
    assert listed == {name: help_text for name, (_module, help_text) in COMMANDS.items()}


def test_help_and_version_load_no_command_and_a_command_only_its_own() -> None:
    """Issue 38 (7): every command took about 1 s to start, importing all of cobus. (The
    times are in benchmarks/bench_startup.py; here, what is imported.)"""
    import subprocess
    import sys

    probe = (
        "import sys; from cobus.cli import main\n"
        "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
        "print(sorted(m for m in sys.modules if m.startswith('cobus.')), file=sys.stderr)"
    )

    def loaded(*argv: str) -> set[str]:
        done = subprocess.run(
            [sys.executable, "-c", probe, *argv], capture_output=True, text=True, check=False
        )
        last = done.stderr.strip().splitlines()[-1]
        return set(eval(last))

    heavy = {"cobus.runtime", "cobus.master", "cobus.od", "cobus.sim", "cobus.trace"}
    assert not loaded("--version") & heavy
    assert not loaded("--help") & heavy
    assert not loaded("sdo", "--help") & {"cobus.master", "cobus.sim", "cobus.trace"}
    assert "cobus.trace.scan" not in loaded("eds", "--help")


def test_send_puts_raw_frames_on_the_bus(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 38: users asked for `cobus send ID#DATA` (a raw frame, cansend's notation)."""
    channel = f"cli-send-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        seen: list[Frame] = []
        net.aio.subscribe_all(lambda f, now: seen.append(f))
        bus = ["-i", "virtual", "-c", channel]
        argv = ["send", "000#010A", "70A#R1", "12345678#DE.AD.BE.EF", *bus]
        assert main(argv) == 0
        assert capsys.readouterr().out == "sent 000#010A 70A#R1 12345678#DEADBEEF\n"
        net.sleep(0.1)
        assert rig.devices[10].device.state.name == "OPERATIONAL"  # the NMT start
        # (the servo's own frames on 70Ah - boot-up, its answer to the RTR - left out)
        sent = [f for f in seen if f.cob_id in (0x000, 0x12345678) or f.rtr]
        assert [(f.cob_id, f.data, f.rtr, f.extended) for f in sent] == [
            (0x000, b"\x01\x0a", False, False),
            (0x70A, b"", True, False),
            (0x12345678, bytes.fromhex("deadbeef"), False, True),
        ]
        seen.clear()
        assert main(["send", "080#", "--count", "3", "--period", "0.01", "--json", *bus]) == 0
        assert json.loads(capsys.readouterr().out) == {"sent": 3, "frames": ["080#"]}
        assert len([f for f in seen if f.cob_id == 0x080]) == 3
    for bad, why in (
        ("800#00", "does not fit an 11-bit identifier"),
        ("12#00", "3 hex digits (11-bit, 000-7FF) or 8 (29-bit)"),
        ("123#001", "each two hex digits"),
        ("123#R9", "DLC 9"),
        ("123", "write ID#DATA"),
        ("123##1DEAD", "a CAN FD frame"),
        ("123#GG", "each two hex digits"),
    ):
        with pytest.raises(SystemExit) as usage:
            main(["send", bad, *NO_BUS])
        assert usage.value.code == 2 and why in capsys.readouterr().err


def test_sdo_type_given_against_the_eds_or_the_answer(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A review found --type silently overriding the EDS and printing wrong values."""
    with servo_bench(tmp_path, "cli-sdo-type") as (_net, _rig, eds, bus):
        argv = ["sdo", "read", "10", "0x607F", "--type", "u8", "--eds", str(eds), *bus]
        assert main(argv) == 2
        assert "--type UNSIGNED8 differs from the EDS's UNSIGNED32" in capsys.readouterr().err
        assert main(["sdo", "read", "10", "0x1008", "--type", "u16", *bus]) == 0
        out = capsys.readouterr().out
        assert out.startswith("1008h:00 Manufacturer device name = 63 6f 62 75 73")
        assert out.rstrip().endswith("- 19 byte(s), not a UNSIGNED16")


def test_pdo_show_and_map_against_the_simulated_servo(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38: users asked for `cobus pdo show/map NODE` (read and remap PDOs from the
    shell, checked against the EDS)."""
    with servo_bench(tmp_path, "cli-pdo") as (net, _rig, eds, bus):
        eds_ = ["--eds", str(eds)]

        assert main(["pdo", "show", "10", *eds_, *bus]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert lines[0] == "node 10: 8 PDO(s)"
        assert lines[3].split() == [
            "TPDO2", "0x28A", "1", "(every", "SYNC)", "0", "ms", "0", "ms",
            "Statusword", "(16),", "Position", "actual", "value", "(32)",
        ]  # fmt: skip

        argv = ["pdo", "map", "10", "tpdo2", "Velocity actual value", "Statusword"]
        assert main([*argv, "--type", "2", "--json", *eds_, *bus]) == 0
        (tpdo2,) = json.loads(capsys.readouterr().out)["pdos"]
        assert tpdo2["transmission_type"] == 2 and tpdo2["enabled"]
        assert [o["object"] for o in tpdo2["objects"]] == ["0x606C:00", "0x6041:00"]
        # the node sends it so: every 2nd SYNC, 6 bytes
        seen: list[Frame] = []
        net.subscribe(0x28A, lambda f, now: seen.append(f))
        net.send(Frame(0x000, b"\x01\x0a"))
        for _ in range(4):
            net.sleep(0.02)
            net.send(Frame(0x080, b""))
        net.sleep(0.05)
        assert len(seen) == 2 and all(len(f.data) == 6 for f in seen)

        for bad, why in (
            (["rpdo1", "Statusword"], "is ro: an RPDO cannot write it"),
            (["tpdo2", *["Position actual value"] * 3], "at most 64"),
            (["tpdo2", "Nothing such"], "has no object named 'Nothing such'"),
        ):
            assert main(["pdo", "map", "10", *bad, *eds_, *bus]) == 2
            assert why in capsys.readouterr().err
        assert main(["pdo", "map", "10", "tpdo2", "Statusword", *bus]) == 2
        assert "give the node's --eds" in capsys.readouterr().err
        assert main(["pdo", "map", "10", "tpdo9", "Statusword", *eds_, *bus]) == 1
        assert "object does not exist" in capsys.readouterr().err
        with pytest.raises(SystemExit):
            main(["pdo", "map", "10", "xpdo1", *bus])
        assert "tpdo1..tpdo512 or rpdo1..rpdo512" in capsys.readouterr().err

        # what is not given stays as the node has it: off stays off (RPDO2 carries the
        # controlword: switching it on behind the user would let frames drive the servo)
        def rpdo2() -> dict[str, object]:
            assert main(["pdo", "show", "10", "--json", *eds_, *bus]) == 0
            pdos = json.loads(capsys.readouterr().out)["pdos"]
            found: dict[str, object] = next(p for p in pdos if p["pdo"] == "RPDO2")
            return found

        assert main(["pdo", "map", "10", "rpdo2", "--disable", *eds_, *bus]) == 0
        assert main(["pdo", "map", "10", "rpdo2", "--inhibit", "10", *eds_, *bus]) == 0
        capsys.readouterr()
        assert rpdo2()["enabled"] is False and rpdo2()["inhibit_100us"] == 10
        # refused before any write: the PDO as it was
        for bad, why in (
            (["rpdo2", "--type", "253"], "(on RTR) is for a TPDO"),
            (["rpdo2", "--type", "245"], "241-251 are reserved"),
            (["rpdo2"], "nothing to change"),
        ):
            assert main(["pdo", "map", "10", *bad, *eds_, *bus]) == 2
            assert why in capsys.readouterr().err
        assert rpdo2()["transmission_type"] == 255 and rpdo2()["enabled"] is False
        with pytest.raises(SystemExit):
            main(["pdo", "map", "10", "rpdo2", "--event-timer", "70000", *eds_, *bus])
        assert "0-65535" in capsys.readouterr().err
        assert main(["pdo", "map", "10", "rpdo2", "--enable", *eds_, *bus]) == 0
        capsys.readouterr()
        assert rpdo2()["enabled"] is True
        # a gap in a mapping
        argv = ["pdo", "map", "10", "tpdo3", "Statusword", "dummy16", "--json", *eds_, *bus]
        assert main(argv) == 0
        (tpdo3,) = json.loads(capsys.readouterr().out)["pdos"]
        assert [(o["name"], o["bits"]) for o in tpdo3["objects"]] == [
            ("Statusword", 16),
            ("dummy16", 16),
        ]


def test_send_period_needs_a_count(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["send", "080#", "--period", "0.1", *NO_BUS]) == 2
    assert "give --count too" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["send", "080#", "--count", "0", *NO_BUS])
    assert "1 to 1,000,000" in capsys.readouterr().err
