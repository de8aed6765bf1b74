"""cobus plot: PDO signals of a recorded trace to a PNG; choosing signals; clear errors."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import pytest

from cobus.cli import main
from cobus.device import export_eds
from cobus.proto import Frame
from cobus.runtime import Network
from cobus.sim import Rig, start_rig
from cobus.trace.plot import SignalError, collect, pick
from tests.test_trace_cli import RIG, listening


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A servo speeding up to 20,000 inc/s, its TPDOs sent on SYNC, recorded to .asc."""
    from cobus.profiles import Drive402

    folder = tmp_path_factory.mktemp("plot")
    trace, eds = folder / "run.asc", folder / "servo.eds"
    channel = f"plot-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        eds.write_text(export_eds(rig.aio.devices[10].od))
        node = net.add_remote(10)
        result: list[int] = []
        recorder = threading.Thread(
            target=lambda: result.append(
                main(["record", str(trace), "--duration", "1.0", "-i", "virtual", "-c", channel])
            )
        )
        recorder.start()
        listening(channel, 2)
        drive = Drive402(node)
        drive.enable()
        node.nmt.start()
        drive.set_velocity(20_000)
        for _ in range(25):
            net.send(Frame(0x080, b""))
            net.sleep(0.02)
        recorder.join()
    assert result == [0]
    return trace, eds


def test_plot_draws_the_named_signals_into_a_png(
    recording: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace, eds = recording
    assert main(["plot", str(trace), "--list", "--json", "--eds", f"10={eds}"]) == 0
    listed = {s["name"]: s for s in json.loads(capsys.readouterr().out)}
    assert {"Position actual value", "Velocity actual value", "Statusword"} <= set(listed)
    assert listed["Velocity actual value"]["max"] == 20_000
    png = tmp_path / "run.png"
    args = ["plot", str(trace), "velocity actual value", "10:Position actual value"]
    assert main([*args, "--eds", f"10={eds}", "-o", str(png), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["output"] == str(png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    position = summary["signals"][1]
    assert position["node"] == 10 and position["samples"] >= 10
    assert position["max"] > position["min"]  # the motor turned
    # A window of the trace: --from/--to (seconds from the first frame).
    assert main([*args, "--eds", f"10={eds}", "-o", str(png), "--from", "0.3", "--to", "0.6"]) == 0
    assert "2 signal(s) plotted to" in capsys.readouterr().err
    # Case, blanks and underscores do not matter, as everywhere in cobus.
    assert main(["plot", str(trace), "10:position_actual_value", "--eds", f"10={eds}"]) == 0
    # The default output is the trace's name with .png.
    assert main(["plot", str(trace), "Statusword", "--eds", f"10={eds}"]) == 0
    assert trace.with_suffix(".png").is_file()


def test_plot_says_what_is_wrong(
    recording: tuple[Path, Path],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    trace, eds = recording
    assert main(["plot", str(trace), "velocity", "--eds", f"10={eds}"]) == 1
    assert "did you mean 10:Velocity actual value?" in capsys.readouterr().err
    assert main(["plot", str(trace), "Statusword"]) == 1  # no EDS, no mapping seen on the bus
    assert "give the nodes' EDS (--eds NODE=FILE" in capsys.readouterr().err
    assert main(["plot", str(trace), "--list"]) == 0
    assert "no PDO signal could be named" in capsys.readouterr().err
    assert main(["plot", str(trace)]) == 2
    assert "name the signals to plot" in capsys.readouterr().err
    assert main(["plot", str(trace), "x", "--from", "2", "--to", "1"]) == 2
    assert main(["plot", str(trace.with_name("none.asc")), "x"]) == 1
    assert "no such file" in capsys.readouterr().err
    assert main(["plot", str(trace), "--list", "--eds", f"10={eds}"]) == 0
    assert "Velocity actual value" in capsys.readouterr().out


def _sdo_write(node: int, index: int, sub: int, value: int) -> Frame:
    body = bytes([0x23]) + index.to_bytes(2, "little") + bytes([sub]) + value.to_bytes(4, "little")
    return Frame(0x600 + node, body)


def _sdo_ok(node: int, index: int, sub: int) -> Frame:
    return Frame(
        0x580 + node, bytes([0x60]) + index.to_bytes(2, "little") + bytes([sub, 0, 0, 0, 0])
    )


def test_signals_of_a_mapping_learnt_from_the_bus_and_of_two_nodes() -> None:
    frames: list[tuple[float, Frame]] = []
    t = 0.0
    for node in (5, 6):  # both map 6064h:00 (32 bits) into TPDO1, written over SDO
        for index, sub, value in (
            (0x1800, 1, 0x180 + node),
            (0x1A00, 0, 0),
            (0x1A00, 1, 0x6064_0020),
            (0x1A00, 0, 1),
        ):
            frames += [(t, _sdo_write(node, index, sub, value)), (t, _sdo_ok(node, index, sub))]
    for n in range(5):
        t += 0.01
        frames.append((t, Frame(0x185, (100 * n).to_bytes(4, "little"))))
        frames.append((t, Frame(0x186, (-5 * n).to_bytes(4, "little", signed=True))))
    found = collect(frames)
    (five,) = pick(found, ["5:6064h:00"])
    assert five.values == [0.0, 100.0, 200.0, 300.0, 400.0] and five.times[0] == pytest.approx(0.01)
    with pytest.raises(SignalError, match="several nodes: write 5:6064h:00 or 6:6064h:00"):
        pick(found, ["6064h:00"])
    (six,) = pick(found, ["6:6064H:00"])  # any case
    assert six.values[-1] == float(0xFFFF_FFEC)  # no EDS: an unsigned 32-bit guess


def test_decode_and_plot_take_the_signals_of_a_network_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tests.test_trace_cli import write_trace

    network = str(Path(__file__).parent.parent / "examples/networks/line.yml")
    trace = tmp_path / "line.log"
    frames = [Frame(0x183, b"\x37\x06" + (500 * n).to_bytes(4, "little")) for n in range(20)]
    write_trace(trace, frames)
    assert main(["decode", str(trace), "--network", network, "--filter", "pdo"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1].endswith("node 3 TPDO1 drive1.statusword=1591, drive1.position=9.5 mm")
    png = tmp_path / "line.png"
    args = ["plot", str(trace), "drive1.position", "--network", network, "-o", str(png)]
    assert main([*args, "--json"]) == 0
    (signal,) = json.loads(capsys.readouterr().out)["signals"]
    assert signal["name"] == "drive1.position" and signal["max"] == pytest.approx(9.5)
    assert main(["decode", str(trace), "--network", str(tmp_path / "none.yml")]) == 2
    assert "none.yml" in capsys.readouterr().err


def test_a_window_holds_values_and_bad_files_or_windows_are_clear(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cobus.trace.plot import Series, window
    from tests.test_trace_cli import write_trace

    s = Series(3, "x", [1.0, 5.0], [567.0, 1591.0])
    held = window(s, 2.0, 4.0)
    assert (held.times, held.values) == ([2.0], [567.0])  # the value known since 1 s
    assert window(s, 0.0, 0.5).times == []
    network = str(Path(__file__).parent.parent / "examples/networks/line.yml")
    trace = tmp_path / "line.log"  # one position every millisecond for 20 ms
    write_trace(
        trace, [Frame(0x183, b"\x37\x06" + (500 * n).to_bytes(4, "little")) for n in range(20)]
    )
    base = ["plot", str(trace), "drive1.position", "--network", network]
    assert (
        main([*base, "--from", "0", "--to", "0.0105", "-o", str(tmp_path / "noext"), "--json"]) == 0
    )
    result = json.loads(capsys.readouterr().out)
    assert result["output"] == str(tmp_path / "noext.png") and (tmp_path / "noext.png").is_file()
    assert result["signals"][0]["samples"] == 11 and result["signals"][0]["max"] == pytest.approx(
        5.0
    )
    assert main([*base, "--from", "100"]) == 1
    assert "the trace's last PDO came at 0.019 s" in capsys.readouterr().err
    junk = tmp_path / "junk.blf"
    junk.write_bytes(bytes(range(256)) * 12)
    assert main(["plot", str(junk), "x"]) == 1
    assert main(["decode", str(junk)]) == 1
    err = capsys.readouterr().err
    assert "cannot read" in err and "Traceback" not in err
