"""``cobus demo``: the thesis rig booted and run by the master, on both clocks."""

import io

import pytest

from cobus.apps.demo import Demo, render, run_demo
from cobus.cli import main
from tests.util import simulate


def test_demo_boots_the_rig_and_runs_the_drives_on_the_simulated_clock(tmp_path):
    out = io.StringIO()
    seen: list[list[dict[str, str]]] = []

    def on_tick(demo: Demo) -> None:
        seen.append(demo.rows())

    demo = simulate(
        run_demo(duration=8.0, refresh=1.0, out=out, clear=False, workdir=tmp_path, on_tick=on_tick)
    )
    last = {row["node"]: row for row in seen[-1]}
    # the master booted and supervises the CiA 301 nodes
    assert last["9"]["master"] == "5 operational"
    assert last["10"]["master"] == "5 operational"
    assert last["10"]["note"] == "operation enabled"
    assert last["9"]["heartbeat"].endswith("ms ago")
    # the servo and the ZAPI inverter follow the potentiometer, which has moved up
    assert int(last["10"]["speed"].split()[0]) > 10_000
    assert float(last["8"]["speed"].split()[0]) > 10.0
    assert last["8"]["nmt"] == "operational"
    assert last["8"]["master"] == "5 operational"  # started by the master, after SYNC
    assert last["8"]["note"] == ""  # the handshake holds: no alarm
    assert demo.zapi_cycles > 300  # answered every 20 ms SYNC cycle
    assert all(row["emcy"] == "0" for row in seen[-1])
    # the table was printed at each refresh
    assert out.getvalue().count("NODE  NAME") == len(seen) == 8


def test_render_aligns_columns():
    rows = [
        {
            "node": "9",
            "name": "io",
            "kind": "cia401_io",
            "nmt": "operational",
            "master": "5 operational",
            "heartbeat": "5 ms ago",
            "emcy": "0",
            "speed": "",
            "note": "",
        }
    ]
    text = render(rows, 1.5)
    lines = text.splitlines()
    assert lines[0].startswith("cobus demo — t =    1.50 s")
    assert lines[2].split() == [
        "NODE",
        "NAME",
        "KIND",
        "NMT",
        "MASTER",
        "HEARTBEAT",
        "EMCY",
        "SPEED",
        "NOTE",
    ]
    assert lines[4].split()[:4] == ["9", "io", "cia401_io", "operational"]


def test_demo_in_real_time_from_the_command_line(capsys):
    assert main(["demo", "--duration", "1.5", "--refresh", "0.5", "--no-clear"]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    assert out.count("NODE  NAME") >= 2
    assert "5 operational" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["demo", "--simulated"], "--simulated needs --duration"),
        (["demo", "--refresh", "0", "--duration", "1"], "--refresh must be a positive"),
    ],
)
def test_demo_argument_errors(argv, message, capsys):
    assert main(argv) == 2
    assert message in capsys.readouterr().err
