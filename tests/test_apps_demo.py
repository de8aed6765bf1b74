"""``cobus demo``: the thesis rig booted and run by the master, on both clocks."""

import asyncio
import io
from pathlib import Path
from typing import Any

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
    # nodes that send no heartbeat say so instead of showing an age that grows without end
    assert last["1"]["heartbeat"] == "boot-up only, no heartbeat"  # STÖBER: 1017h is 0
    assert last["3"]["heartbeat"] == "none heard"  # the EC motor has no heartbeat at all
    assert last["8"]["heartbeat"] == "none heard"  # nor has the ZAPI inverter
    # the table was printed at each refresh, its clock counting from the demo's start
    assert out.getvalue().count("NODE  NAME") == len(seen) == 8
    assert "SYNC every 20 ms: on time (worst delay 0.0 ms)" in out.getvalue()
    first = float(out.getvalue().split("t =", 1)[1].split()[0])
    assert 1.0 <= first < 1.5  # the first refresh, plus the boot-up before it


def test_the_servo_swings_within_its_travel_and_problems_show_their_text(tmp_path):
    """A whole potentiometer sweep: the servo runs backwards then forwards, never reaching
    its limit switches; an emergency shows with its text, the master's word on a lost node
    until the node is back."""
    positions: list[int] = []
    notes: list[dict[str, str]] = []

    def on_tick(demo: Demo) -> None:
        servo = demo.rig.devices[10]
        positions.append(servo.status()["position"])
        t = round(demo.elapsed())
        if t == 22:
            servo.inject("drive_fault", code=0x7305)
        if t == 24:
            demo.rig.devices[9].power_off()
        notes.append({row["node"]: row["note"] for row in demo.rows()})

    simulate(
        run_demo(
            duration=26.0,
            refresh=1.0,
            out=io.StringIO(),
            clear=False,
            workdir=tmp_path,
            on_tick=on_tick,
        )
    )
    assert min(positions) < -50_000 and max(positions) > 50_000, "it swings both ways"
    assert all(-200_000 < p < 200_000 for p in positions), "inside the limit switches"
    assert all(n["10"] == "operation enabled" for n in notes[:21])
    assert notes[23]["10"].startswith("0x7305 ")  # the drive's EMCY, with the code's text
    assert "heartbeat lost" in notes[-1]["9"]  # the master's event about the silent I/O


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


@pytest.mark.parametrize("duration", ["1.0", "1.5", "2.0"])
def test_demo_in_real_time_from_the_command_line(duration, capsys):
    """Run a few times: about one run in three ended in a traceback (issue 38)."""
    assert main(["demo", "--duration", duration, "--refresh", "0.5", "--no-clear"]) == 0
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err and "Exception in callback" not in out + err
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


def test_the_thesis_network_file_ships_in_examples_with_the_devices_eds():
    """``examples/networks/thesis.yml`` is the demo's own network file, and the EDS files
    beside it are those of the simulated rig's devices (exported again here: not stale)."""
    from pathlib import Path

    from cobus.apps.demo import NETWORK_FILE
    from cobus.device import export_eds
    from cobus.master import check_network
    from cobus.runtime import AsyncNetwork
    from cobus.sim.rig import Rig, ready_rig

    examples = Path(__file__).parent.parent / "examples" / "networks"
    assert (examples / "thesis.yml").resolve() == NETWORK_FILE.resolve()  # one file, linked
    config, problems = check_network(examples / "thesis.yml")
    assert config is not None, problems

    async def exported() -> dict[str, str]:
        async with AsyncNetwork() as net:
            rig = Rig.load(ready_rig("thesis"))
            await rig.start(net)
            try:
                return {
                    name: export_eds(rig.devices[node].od)  # type: ignore[attr-defined]
                    for node, name in ((9, "io"), (10, "servo"), (8, "zapi"))
                }
            finally:
                await rig.stop()

    def undated(text: str) -> list[str]:  # an export is stamped with the day it was made
        stamps = ("CreationDate=", "CreationTime=", "ModificationDate=", "ModificationTime=")
        return [line for line in text.splitlines() if not line.startswith(stamps)]

    for name, text in simulate(exported()).items():
        shipped = (examples / f"{name}.eds").read_text()
        assert undated(shipped) == undated(text), f"examples/networks/{name}.eds"


def test_the_demo_says_when_the_machine_was_too_busy_to_keep_sync():
    from types import SimpleNamespace

    busy = SimpleNamespace(
        master_net=SimpleNamespace(sync=SimpleNamespace(late_max=0.075, skipped=3))
    )
    text = Demo.sync_status(busy)  # type: ignore[arg-type]
    assert text == (
        "SYNC every 20 ms: 3 period(s) without SYNC, worst delay 75.0 ms: this machine was "
        "too busy to run the master in time"
    )
    lines = render([], 2.0, status=text).splitlines()
    assert lines[1] == text and lines[2] == ""


def test_a_lost_zapi_handshake_shows_and_the_application_restarts_the_inverter(tmp_path):
    """Issue 38 (2): a cycle left unanswered (a busy machine) made the inverter raise 248
    CAN BUS KO and drop to pre-operational for good, while the master still counted it
    operational."""
    rows: list[dict[str, dict[str, str]]] = []

    def on_tick(demo: Demo) -> None:
        assert demo.zapi is not None
        if len(rows) == 5:
            demo.zapi.answering = False  # the application misses the handshake's cycles
        if len(rows) == 6:
            demo.zapi.answering = True
        rows.append({row["node"]: row for row in demo.rows()})

    demo = simulate(
        run_demo(
            duration=9.0,
            refresh=0.5,
            out=io.StringIO(),
            clear=False,
            workdir=tmp_path,
            on_tick=on_tick,
        )
    )
    zapi = [r["8"] for r in rows]
    assert any(r["note"] == "CAN BUS KO" for r in zapi), "the handshake was lost"
    assert zapi[-1]["nmt"] == "operational" and zapi[-1]["master"] == "5 operational"
    assert zapi[-1]["note"].startswith("handshake lost 1x, restarted at t = ")
    assert float(zapi[-1]["speed"].split()[0]) > 1.0  # running again
    assert demo.zapi_restarts == 1


def test_the_demo_shuts_down_in_order_and_no_timer_fires_into_a_closed_network(tmp_path):
    """Issue 38 (2): about one run in three ended in a traceback: the ZAPI adapter's
    handshake watchdog fired after the networks were closed (NetworkClosedError)."""
    import asyncio

    errors: list[dict[str, object]] = []
    closed: list[tuple[bool, bool]] = []
    servo_states: list[str] = []
    servos: list[Any] = []

    async def main() -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(lambda _loop, context: errors.append(context))
        for n, duration in enumerate((1.0, 1.37, 2.21, 2.5, 3.03)):
            workdir = tmp_path / str(n)
            workdir.mkdir()
            demo = await run_demo(
                duration=duration,
                refresh=0.25,
                out=io.StringIO(),
                clear=False,
                workdir=workdir,
                on_tick=lambda d: servos.append(d.rig.devices[10]),
            )
            await asyncio.sleep(1.0)  # what the demo left armed would fire now
            closed.append((demo.master_net.connected, demo.rig_net.connected))
            servo_states.append(servos[-1].state.value)

    simulate(main())
    assert errors == []
    assert set(closed) == {(False, False)}  # both networks closed
    assert set(servo_states) == {"switch on disabled"}  # the servo was switched off first


def test_the_demo_serves_its_panel_and_takes_another_port_when_8047_is_taken(
    tmp_path: Path,
) -> None:
    import socket

    out = io.StringIO()
    seen: list[int] = []

    fetches: list[asyncio.Task[None]] = []

    async def fetch(url: str) -> None:
        import aiohttp

        async with aiohttp.ClientSession() as http, http.get(url) as r:
            seen.append(r.status)

    def on_tick(demo: Demo) -> None:  # (on the demo's loop: the page is fetched beside it)
        fetches.append(asyncio.create_task(fetch(demo.panel_url)))

    async def main() -> Demo:
        with socket.socket() as taken:
            taken.bind(("127.0.0.1", 0))
            taken.listen()
            port = taken.getsockname()[1]
            demo = await run_demo(
                duration=1.0,
                refresh=0.5,
                out=out,
                clear=False,
                workdir=tmp_path,
                on_tick=on_tick,
                panel=("127.0.0.1", port),
            )
            await asyncio.gather(*fetches, return_exceptions=True)
            return demo

    demo = asyncio.run(main())
    text = out.getvalue()
    assert "cannot serve the panel on 127.0.0.1:" in text and "takes another port" in text
    assert f"the operator panel is at {demo.panel_url}\n" in text
    assert f"cobus demo — panel {demo.panel_url}" in text
    assert seen and set(seen) == {200}
    assert demo.panel is not None and demo.panel.bound is not None  # stopped with the demo


def test_a_panel_address_that_is_not_this_machines_is_one_line_and_exit_2(capsys):
    code = main(["demo", "--listen", "192.0.2.1:8047", "--duration", "1", "--no-clear"])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("cobus demo: cannot serve the panel on 192.0.2.1:8047")
    assert "Traceback" not in err and "--no-panel" in err
