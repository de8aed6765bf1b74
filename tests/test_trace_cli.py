"""cobus record and cobus decode: a simulated servo's traffic recorded from python-can's
virtual bus into trace files of several formats, and decoded back into records."""

from __future__ import annotations

import json
import os
import re
import threading
import time
from pathlib import Path

import can
import pytest

from cobus.cli import main
from cobus.device import export_eds
from cobus.proto import Frame
from cobus.runtime import Network
from cobus.sim import Rig, start_rig
from tests.util import Terminal

RIG = """
bus: embedded
devices:
  - {node: 10, kind: cia402_drive, name: servo}
"""


def listening(channel: str, buses: int) -> None:
    """Wait until ``buses`` python-can buses are open on the virtual ``channel``."""
    from can.interfaces import virtual

    deadline = time.monotonic() + 20
    while len(virtual.channels.get(channel, ())) < buses:
        assert time.monotonic() < deadline, "the command did not open its bus"
        time.sleep(0.01)


def write_trace(path: Path, frames: list[Frame]) -> None:
    with can.Logger(str(path)) as logger:
        for n, f in enumerate(frames):
            logger(
                can.Message(
                    timestamp=1000.0 + n * 0.001,
                    arbitration_id=f.cob_id,
                    data=f.data,
                    is_extended_id=False,
                    is_remote_frame=f.rtr,
                    dlc=f.dlc,
                )
            )


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".trc", ".csv"])
def test_decode_reads_every_format_python_can_writes(
    suffix: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / f"bench{suffix}"
    write_trace(
        trace,
        [
            Frame(0x000, b"\x01\x0a"),
            Frame(0x60A, bytes.fromhex("4017100000000000")),
            Frame(0x58A, bytes.fromhex("4b17100064000000")),
            Frame(0x08A, bytes.fromhex("2171010000000000")),
            Frame(0x70A, b"\x05"),
        ],
    )
    assert main(["decode", str(trace)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(None, 1)[1] for line in lines] == [
        "NMT start -> node 10",
        "node 10 read 1017h:00 Producer heartbeat time = 100 (2 bytes, expedited, 1.0 ms)",
        "node 10 EMCY 7121h Additional modules (7121h) (register 01h: generic)",
        "node 10 heartbeat OPERATIONAL",
    ]
    assert lines[0].split()[0] == "0.000000"
    assert main(["decode", str(trace), "--filter", "emcy", "--json"]) == 0
    (one,) = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert one["kind"] == "emcy" and one["code"] == 0x7121 and one["node"] == 10


def test_record_a_live_bus_and_decode_it_with_the_eds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    channel = f"trace-{os.getpid()}"
    trace = tmp_path / "live.asc"
    eds = tmp_path / "servo.eds"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        eds.write_text(export_eds(rig.aio.devices[10].od))
        node = net.add_remote(10)
        result: list[int] = []
        recorder = threading.Thread(
            target=lambda: result.append(
                main(["record", str(trace), "--duration", "1.5", "-i", "virtual", "-c", channel])
            )
        )
        recorder.start()
        listening(channel, 2)  # the rig's network and the recorder
        net.sleep(0.1)
        node.sdo.upload(0x1008, 0)
        node.sdo.download(0x1017, 0, (50).to_bytes(2, "little"))  # heartbeat every 50 ms
        recorder.join()
    assert result == [0]
    assert "frames written to" in capsys.readouterr().err
    assert main(["decode", str(trace), "--eds", f"10={eds}", "--node", "10"]) == 0
    out = capsys.readouterr().out
    assert "node 10 read 1008h:00 Manufacturer device name = " in out
    assert "node 10 write 1017h:00 Producer heartbeat time = 50 (2 bytes, expedited" in out
    assert "node 10 heartbeat PRE_OPERATIONAL" in out
    assert main(["decode", str(tmp_path / "none.asc")]) == 1
    with pytest.raises(SystemExit) as usage:
        main(["decode", str(trace), "--eds", "x=1"])
    assert usage.value.code == 2 and "write NODE=FILE" in capsys.readouterr().err


def test_monitor_decodes_the_live_bus_and_ends_with_the_node_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    channel = f"monitor-{os.getpid()}"
    eds = tmp_path / "servo.eds"
    with Network(interface="virtual", channel=channel) as net:
        rig = start_rig(net, Rig.loads(RIG))
        eds.write_text(export_eds(rig.aio.devices[10].od))
        node = net.add_remote(10)
        result: list[int] = []
        bus = ["-i", "virtual", "-c", channel, "-b", "500000"]
        monitor = threading.Thread(
            target=lambda: result.append(
                main(["monitor", "--duration", "1.5", "--eds", f"10={eds}", "--node", "10", *bus])
            )
        )
        monitor.start()
        listening(channel, 2)  # the rig's network and the monitor
        net.sleep(0.1)
        node.sdo.download(0x1017, 0, (50).to_bytes(2, "little"))
        node.nmt.send("start")
        net.sleep(0.3)
        net.send(Frame(0x000, bytes([0x80, 0])))  # to all nodes: --node 10 keeps it
        net.send(Frame(0x000, bytes([0x01, 11])))  # to another node: not shown
        monitor.join()
    assert result == [0]
    out = capsys.readouterr().out
    assert "NMT enter pre-operational -> all nodes" in out and "node 11" not in out
    assert "node 10 write 1017h:00 Producer heartbeat time = 50" in out
    assert "NMT start -> node 10" in out and "node 10 heartbeat OPERATIONAL" in out
    assert "frames/s, bus load" in out  # the node table at the end
    # piped, the node table is plain text with every value whole
    table = [line for line in out.splitlines() if line.startswith("10 ")]
    assert table and "OPERATIONAL " in table[0] and " 50 ms " in table[0]
    assert main(["monitor", "--duration", "0.1", "-i", "nosuchbus", "-c", "x"]) == 1
    assert "cannot open the bus" in capsys.readouterr().err


def test_monitor_on_a_terminal_fits_its_records_below_the_node_table(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On a terminal (a pseudo-terminal here) the live view never grows past the screen:
    the newest records that fit, below the node table."""

    monkeypatch.setenv("COLUMNS", "100")
    monkeypatch.setenv("LINES", "18")
    term = Terminal()
    screen = term.file
    channel = f"monitor-tty-{os.getpid()}"
    rig = RIG.replace("name: servo}", "name: servo, options: {heartbeat_ms: 10}}")
    monkeypatch.setattr("sys.stdout", screen)
    try:
        with Network(interface="virtual", channel=channel) as net:
            start_rig(net, Rig.loads(rig))
            node = net.add_remote(10)
            result: list[int] = []
            command = ["monitor", "--duration", "1.2", "--node", "10", "-i", "virtual"]
            monitor = threading.Thread(
                target=lambda: result.append(main([*command, "-c", channel]))
            )
            monitor.start()
            listening(channel, 2)
            net.sleep(0.2)
            node.nmt.send("start")
            net.sleep(0.2)
            net.send(Frame(0x000, bytes([0x80, 0])))  # pre-operational, to all nodes
            monitor.join()
    finally:
        monkeypatch.undo()
        term.close()
    assert result == [0]
    text = term.text()
    last = text.rsplit("nodes —", 1)[1]  # the last picture, from the table's title
    assert last.count("\n") <= 18
    assert "node 10 heartbeat" in last and "..." not in last


def test_decode_skips_a_can_fd_frame_and_reports_an_open_transfer(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "fd.log"
    trace.write_text(
        "(1000.000000) vcan0 70A#05\n"
        "(1000.001000) vcan0 123##0112233445566778899AA\n"
        "(1000.002000) vcan0 60A#4009100000000000\n"
        "(1000.003000) vcan0 70A#05\n"
    )
    assert main(["decode", str(trace)]) == 0
    captured = capsys.readouterr()
    assert "frame skipped" in captured.err
    lines = [line.split(None, 1)[1] for line in captured.out.splitlines()]
    assert lines == [
        "node 10 heartbeat OPERATIONAL",
        "node 10 heartbeat OPERATIONAL",
        "node 10 read 1009h:00 Manufacturer hardware version = (no data) "
        "(0 bytes, incomplete, 1.0 ms)",
    ]


def test_replay_sends_a_recording_with_its_timing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "short.log"
    trace.write_text(
        "(1000.000000) vcan0 000#010A\n"
        "(1000.200000) vcan0 70A#05\n"
        "(1000.400000) vcan0 60A#4009100000000000\n"
    )
    channel = f"replay-{os.getpid()}"
    got: list[tuple[float, Frame]] = []
    with Network(interface="virtual", channel=channel) as net:
        net.aio.subscribe_all(lambda f, now: got.append((time.monotonic(), f)))
        assert main(["replay", str(trace), "-i", "virtual", "-c", channel]) == 0
        net.sleep(0.1)
    assert "3 frames sent" in capsys.readouterr().err
    assert [f.cob_id for _, f in got] == [0x000, 0x70A, 0x60A]
    assert got[2][0] - got[0][0] >= 0.35  # its timing kept


def test_monitor_into_a_pipe_that_closes_ends_quietly(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 38 (9): ``cobus monitor ... | head`` reported "cannot open the bus: Broken pipe"."""
    import io

    class Head(io.StringIO):
        """A reader that takes two lines and goes away."""

        def write(self, text: str) -> int:
            if self.getvalue().count("\n") >= 2:
                raise BrokenPipeError(32, "Broken pipe")
            return super().write(text)

    channel = f"monitor-pipe-{os.getpid()}"
    head = Head()
    with Network(interface="virtual", channel=channel) as net:
        result: list[int] = []
        bus = ["-i", "virtual", "-c", channel]

        def run() -> None:
            import contextlib

            with contextlib.redirect_stdout(head):
                result.append(main(["monitor", "--duration", "5", *bus]))

        monitor = threading.Thread(target=run)
        monitor.start()
        listening(channel, 2)
        for _ in range(20):
            net.send(Frame(0x080, b""))  # SYNC
            net.sleep(0.01)
            if not monitor.is_alive():
                break
        monitor.join(5)
    assert result == [0]
    assert head.getvalue().count("\n") == 2
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("node", ["0", "128", "300", "x"])
def test_a_node_id_out_of_range_is_refused(
    node: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38 (9): `decode --node 300` was accepted and printed another node's transfer."""
    for argv in (["decode", str(tmp_path / "t.asc")], ["monitor", "--duration", "0.1"]):
        with pytest.raises(SystemExit) as usage:
            main([*argv, "--node", node])
        assert usage.value.code == 2 and "a node-ID 1-127" in capsys.readouterr().err


def _trace_at(path: Path, start: float, frames: list[Frame]) -> None:
    with can.Logger(str(path)) as logger:
        for n, f in enumerate(frames):
            logger(
                can.Message(
                    timestamp=start + n * 0.25,
                    arbitration_id=f.cob_id,
                    data=f.data,
                    is_extended_id=False,
                )
            )


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".csv"])
def test_decode_shows_absolute_times_when_asked(
    suffix: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 38: users asked for absolute timestamps in cobus decode."""
    import datetime as dt

    start = dt.datetime(2026, 11, 30, 14, 5, 7, 250000).timestamp()
    trace = tmp_path / f"bench{suffix}"
    _trace_at(trace, start, [Frame(0x000, b"\x01\x0a"), Frame(0x70A, b"\x05")])
    assert main(["decode", str(trace), "--absolute"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line[:26] for line in lines] == [
        "2026-11-30 14:05:07.250000",
        "2026-11-30 14:05:07.500000",
    ]
    assert lines[0].endswith("NMT start -> node 10")
    assert main(["decode", str(trace), "--absolute", "--json", "--node", "10"]) == 0
    records = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [r["datetime"][:26] for r in records] == [
        "2026-11-30 14:05:07.250000",
        "2026-11-30 14:05:07.500000",
    ]
    offset = records[0]["datetime"][26:]  # the local time's offset from UTC
    assert re.fullmatch(r"[+-]\d\d:\d\d", offset)


def test_decode_of_a_trace_without_a_date_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "bench.log"
    _trace_at(trace, 12.0, [Frame(0x000, b"\x01\x0a")])
    assert main(["decode", str(trace), "--absolute"]) == 0
    out, err = capsys.readouterr()
    assert out.split()[0] == "0.000000" and "carry no date: shown in seconds" in err


def test_an_open_transfer_at_the_end_honours_the_filters(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace = tmp_path / "bench.log"
    _trace_at(trace, 1000.0, [Frame(0x60A, bytes.fromhex("4017100000000000"))])
    assert main(["decode", str(trace), "--filter", "nmt"]) == 0
    assert capsys.readouterr().out == ""
    assert main(["decode", str(trace), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mode"] == "incomplete"


def test_monitor_raw_shows_the_bus_by_identifier(capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 38: users asked for a raw per-ID view in cobus monitor (count, period, last
    data - as python-can's viewer)."""
    channel = f"monitor-raw-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        result: list[int] = []
        bus = ["-i", "virtual", "-c", channel]
        monitor = threading.Thread(
            target=lambda: result.append(
                main(["monitor", "--raw", "--duration", "1.0", "--json", *bus])
            )
        )
        monitor.start()
        listening(channel, 2)
        for n in range(5):
            net.send(Frame(0x70A, b"\x05"))  # a heartbeat every 50 ms
            net.send(Frame(0x18A, bytes([n, 0x12])))  # a TPDO
            net.sleep(0.05)
        net.send(Frame(0x12345678, b"\x01", extended=True))
        monitor.join()
    assert result == [0]
    rows = {r["id"]: r for r in json.loads(capsys.readouterr().out)}
    assert list(rows) == ["0x18A", "0x70A", "0x12345678"]
    assert rows["0x70A"]["count"] == 5 and rows["0x70A"]["what"] == "heartbeat node 10"
    assert 30 < rows["0x70A"]["period_ms"] < 200
    assert rows["0x18A"]["data"] == "0412" and rows["0x18A"]["what"] == "TPDO1 node 10"
    assert rows["0x12345678"]["extended"] and rows["0x12345678"]["count"] == 1
    assert main(["monitor", "--raw", "--node", "10", *bus]) == 2
    assert "--filter and --node do not apply" in capsys.readouterr().err


def test_monitor_raw_piped_prints_the_table_at_the_end(
    capsys: pytest.CaptureFixture[str],
) -> None:
    channel = f"monitor-raw-table-{os.getpid()}"
    with Network(interface="virtual", channel=channel) as net:
        result: list[int] = []
        monitor = threading.Thread(
            target=lambda: result.append(
                main(["monitor", "--raw", "--duration", "0.6", "-i", "virtual", "-c", channel])
            )
        )
        monitor.start()
        listening(channel, 2)
        net.send(Frame(0x000, b"\x01\x00"))
        monitor.join()
    assert result == [0]
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("1 identifier(s), 1 frame(s) in ")
    assert lines[1].split() == ["id", "count", "period", "last", "gap", "dlc", "data", "what"]
    assert lines[2].split() == ["000", "1", "2", "01", "00", "NMT"]


def test_monitor_raw_on_a_terminal_updates_its_table(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "100")
    term = Terminal()
    channel = f"monitor-raw-tty-{os.getpid()}"
    monkeypatch.setattr("sys.stdout", term.file)
    try:
        with Network(interface="virtual", channel=channel) as net:
            result: list[int] = []
            command = ["monitor", "--raw", "--duration", "0.8", "-i", "virtual", "-c", channel]
            monitor = threading.Thread(target=lambda: result.append(main(command)))
            monitor.start()
            listening(channel, 2)
            for _ in range(3):
                net.send(Frame(0x70A, b"\x05"))
                net.sleep(0.1)
            monitor.join()
    finally:
        monkeypatch.undo()
        term.close()
    assert result == [0]
    last = term.text().rsplit("identifier(s)", 1)[1]  # the last picture
    assert "70A" in last and "heartbeat node 10" in last and "│" in last
