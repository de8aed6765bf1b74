"""The panel over a master with no application beside it, as ``cobus run`` has it: what a
Drive page reads of a CiA 402 drive and when, the position set-point with its safety, and
the parameter manager on the Parameters page - over a real WebSocket, a simulated drive and
the cobus master on python-can's virtual bus."""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
from collections import Counter
from collections.abc import AsyncIterator, Awaitable
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from cobus.apps.demo import IO, NETWORK_FILE, SERVO, ZAPI
from cobus.apps.panel import CommandError, Panel, serve_parameters, serve_zapi
from cobus.apps.panel.drives import DriveView, serve_cia402_drives
from cobus.blocks import Parameterise
from cobus.device import export_eds
from cobus.master import Master, loads_network
from cobus.runtime import AsyncNetwork
from cobus.sim import Rig
from cobus.sim.rig import ready_rig
from tests.test_apps_run_cli import RIG  # (the same single servo)

NETWORK = """
master: {node_id: 127, heartbeat_time: 100}
nodes:
  servo:
    node_id: 10
    eds: servo.eds
    mandatory: true
    heartbeat_time: 100
    tpdo4: {mapping: ["0x2000:00"], transmission_type: 255, event_timer: 100}
    signals:
      temperature: {object: "0x2000:00", scale: 0.1, unit: °C}
"""


def run(coro: Awaitable[Any], timeout: float = 60.0) -> Any:
    async def bounded() -> Any:
        return await asyncio.wait_for(coro, timeout)

    return asyncio.run(bounded())


class Reads:
    """The SDO uploads the drive is asked for, by object (index, subindex)."""

    def __init__(self) -> None:
        self.count: Counter[tuple[int, int]] = Counter()

    def __call__(self, frame: Any, _now: float) -> None:
        data = bytes(frame.data)
        if frame.cob_id == 0x60A and len(data) == 8 and data[0] == 0x40:
            self.count[(int.from_bytes(data[1:3], "little"), data[3])] += 1


@contextlib.asynccontextmanager
async def drive_page(
    tmp_path: Path, parameters: str | None = None
) -> AsyncIterator[tuple[Panel, DriveView, Reads, AsyncNetwork]]:
    """The servo booted by the master, a panel with its Drive page (not started: the test
    calls ``view.start()``) and its Parameters page, and the SDO reads counted.
    ``parameters``: a parameter file's text, brought to the servo at boot."""
    rig = Rig.loads(RIG)
    channel = f"panel-drives-{os.getpid()}-{id(tmp_path):x}"
    devices = AsyncNetwork(interface="virtual", channel=channel)
    net = AsyncNetwork(interface="virtual", channel=channel)
    await devices.connect()
    await net.connect()
    reads = Reads()
    subscription = devices.subscribe_all(reads)
    await rig.start(devices)
    (tmp_path / "servo.eds").write_text(export_eds(rig.devices[10].od))  # type: ignore[attr-defined]
    master = Master(net, loads_network(NETWORK, base_dir=tmp_path))
    if parameters is not None:
        (tmp_path / "servo.yml").write_text(parameters)
        master.add_boot_step(10, Parameterise(tmp_path / "servo.yml"))
    panel = Panel(port=0, clock=net.time)
    [view] = serve_cia402_drives(panel, master)
    serve_parameters(panel, master)
    try:
        await master.boot(timeout=10)
        await panel.start()
        yield panel, view, reads, net
    finally:
        view.close()
        await panel.stop()
        await master.stop()
        subscription.cancel()
        await rig.stop()
        await net.disconnect()
        await devices.disconnect()


async def until(check: Any, seconds: float = 5.0) -> None:
    for _ in range(int(seconds / 0.02)):
        if check():
            return
        await asyncio.sleep(0.02)
    raise AssertionError(f"not within {seconds} s: {check}")


def test_a_drive_page_nobody_watches_costs_a_statusword_a_second(tmp_path: Path) -> None:
    async def main() -> None:
        async with drive_page(tmp_path) as (_panel, view, reads, _net):
            view.start()
            # nobody watches: the statusword (the state is right without any application)
            await until(lambda: reads.count[(0x6041, 0)] >= 1)
            await asyncio.sleep(1.2)
            assert 2 <= reads.count[(0x6041, 0)] <= 3
            assert view.drive.status.state.name == "SWITCH_ON_DISABLED"
            assert view.read_error == ""
            assert reads.count[(0x606C, 0)] == reads.count[(0x6061, 0)] == 0
            assert view.sample()["drive/servo"]["actual"] == {}
            # a page shows it: the actual values, the mode, and the statusword 4 times a second
            assert view.watch() == {"drive": "servo", "watching": True, "for": 6.0}
            await until(lambda: view.actual.get("speed") is not None)
            await asyncio.sleep(1.0)
            assert 3 <= reads.count[(0x606C, 0)] <= 6
            assert reads.count[(0x6064, 0)] >= 3 and reads.count[(0x6061, 0)] >= 1
            record = view.sample()["drive/servo"]
            assert record["actual"]["position"] == 0.0 and record["mode_text"]
            # the temperature: the network file's signal, from its TPDO (never read by SDO)
            await until(lambda: view.actual.get("temperature") is not None)
            temperature = view.actual["temperature"]
            assert temperature is not None and 15.0 <= temperature <= 60.0  # (0.1 °C scaled)
            assert reads.count[(0x2000, 0)] == 0
            # the page went away: its values are no longer shown as current, nor read
            view._until = 0.0
            await until(lambda: view.actual.get("speed", 0) is None)
            asked = reads.count[(0x606C, 0)]
            await asyncio.sleep(1.2)
            assert reads.count[(0x606C, 0)] == asked
            assert view.sample()["drive/servo"]["actual"]["speed"] is None

    run(main())


def test_a_drive_that_stops_answering_is_said_so(tmp_path: Path) -> None:
    async def main() -> None:
        async with drive_page(tmp_path) as (_panel, view, _reads, net):
            view.start()
            await until(lambda: view.drive.status.state.name == "SWITCH_ON_DISABLED")
            net.nmt.send(0x02, 10)  # stopped: no SDO server answers
            await until(lambda: view.read_error != "", 8.0)
            assert view.sample()["drive/servo"]["read_error"] == view.read_error

    run(main())


def test_position_set_points_move_a_drive_only_as_asked(tmp_path: Path) -> None:
    async def main() -> None:
        async with drive_page(tmp_path) as (panel, view, _reads, _net):
            drive = view.drive
            await drive.write(0x607D, 1, -5000)  # software position limits
            await drive.write(0x607D, 2, 5000)
            view.start()
            await until(lambda: view.position_limits == (-5000, 5000))
            assert view.sample()["drive/servo"]["position_limits"] == [-5000.0, 5000.0]
            async with (
                aiohttp.ClientSession() as http,
                http.ws_connect(panel.url + "ws") as ws,
            ):
                replies: dict[str, dict[str, Any]] = {}

                async def reply(ident: str) -> dict[str, Any]:
                    while ident not in replies:
                        data = (await ws.receive_json(timeout=10)) or []
                        for message in data if isinstance(data, list) else [data]:
                            if message.get("id") is not None:
                                replies[message["id"]] = message
                    return replies.pop(ident)

                async def drive_command(action: str, **args: Any) -> dict[str, Any]:
                    await ws.send_json(
                        {"id": action, "cmd": "drive", "drive": "servo", "action": action, **args}
                    )
                    return await reply(action)

                for value, relative, text in (
                    (True, False, "signed position"),
                    ("far", False, "signed position"),
                    (math.inf, False, "finite"),
                    (1.5, False, "whole number"),
                    (2**31, False, "INTEGER32"),
                    (6000, False, "software position limits 607Dh"),
                    (100, "yes", "true or false"),
                ):
                    refused = await drive_command("position", value=value, relative=relative)
                    assert refused["code"] == "bad-argument" and text in refused["text"], refused
                await drive.set_mode(3)  # (the mode is the operator's choice, made elsewhere)
                refused = await drive_command("position", value=1000)
                assert refused["code"] == "mode", refused
                assert "never changes the mode" in refused["text"]
                assert int(await drive.read_mode()) == 3
                await drive.set_mode(1)
                refused = await drive_command("position", value=1000)
                assert refused["code"] == "not-enabled", refused
                assert (await drive_command("enable", confirm=True))["type"] == "ack"
                moved = await drive_command("position", value=1000)
                assert moved["result"] == {"action": "position", "value": 1000, "relative": False}
                assert await drive.read(0x607A) == 1000
                await drive.wait_for_target(10)
                assert abs(await drive.read(0x6064) - 1000) <= 10
                # relative: checked from where the drive is
                refused = await drive_command("position", value=4500, relative=True)
                assert " + 4500 inc: -5000..5000 inc" in refused["text"], refused
                moved = await drive_command("position", value=-500, relative=True)
                assert moved["result"]["relative"] is True
                await drive.wait_for_target(10)
                assert abs(await drive.read(0x6064) - 500) <= 10
                # commands to one drive run in the order they came: a set-point sent before
                # "give" reaches the drive before the application has it back
                for ident, action, args in (
                    ("p", "position", {"value": 0}),
                    ("g", "give", {}),
                ):
                    await ws.send_json(
                        {"id": ident, "cmd": "drive", "drive": "servo", "action": action, **args}
                    )
                order = []
                while len(order) < 2:
                    data = await ws.receive_json(timeout=10)
                    for message in data if isinstance(data, list) else [data]:
                        if message.get("id") in ("p", "g"):
                            assert message["type"] == "ack", message
                            order.append(message["id"])
                assert order == ["p", "g"]
                assert (await drive_command("take"))["type"] == "ack"
                # relative moves are checked from the last target too (the drive may still
                # be on its way there)
                assert (await drive_command("position", value=4000))["type"] == "ack"
                refused = await drive_command("position", value=3000, relative=True)
                assert "4000 + 3000 inc: -5000..5000 inc" in refused["text"], refused
                await drive.wait_for_target(10)
                # limits are read at each move: changed meanwhile, the new ones hold
                await drive.write(0x607D, 2, 3000)
                refused = await drive_command("position", value=3500)
                assert "-5000..3000 inc" in refused["text"], refused
                # the mode is never written: changed behind the panel's back, the move fails
                # instead of switching it back
                real_read_mode = drive.read_mode
                reads = 0

                async def mode_changes_after_the_check() -> Any:
                    nonlocal reads
                    reads += 1
                    if reads == 2:  # (move_to's own look, after the panel's check)
                        await drive.write(0x6060, 0, 3)
                        await asyncio.sleep(0.1)
                    return await real_read_mode()

                drive.read_mode = mode_changes_after_the_check
                failed = await drive_command("position", value=100)
                drive.read_mode = real_read_mode
                assert failed["code"] == "failed" and "6060h is not written" in failed["text"]
                assert await drive.read(0x6060) == 3  # (as the test set it: not switched back)
                await drive.set_mode(1)
                # a stop cuts short a move still under way (its controlwords never follow)
                held = asyncio.Event()

                async def waits_for_room(*_args: Any, **_options: Any) -> None:
                    held.set()
                    await asyncio.Event().wait()  # (as a drive with no room for a set-point)

                drive.move_to = waits_for_room
                await ws.send_json(
                    {"id": "m", "cmd": "drive", "drive": "servo", "action": "position", "value": 1}
                )
                await held.wait()
                await ws.send_json(  # (sent before the stop, waiting its turn)
                    {"id": "n", "cmd": "drive", "drive": "servo", "action": "position", "value": 2}
                )
                await asyncio.sleep(0.05)
                halted = await drive_command("halt")
                assert halted["type"] == "ack", halted
                cut = await reply("m")
                assert cut["code"] == "stopped" and "cut position short" in cut["text"], cut
                dropped = await reply("n")
                assert dropped["code"] == "stopped" and "not carried out" in dropped["text"]
                assert (await drive_command("quick_stop"))["type"] == "ack"

    run(main())


def test_the_parameters_page_shows_the_parameter_manager_and_diffs_against_its_file(
    tmp_path: Path,
) -> None:
    wanted = 'parameters:\n  "0x6083:00": 1234\n  "0x6084:00": 2345\n'

    async def main() -> None:
        async with (
            drive_page(tmp_path, parameters=wanted) as (panel, _view, _reads, _net),
            aiohttp.ClientSession() as http,
            http.ws_connect(panel.url + "ws") as ws,
        ):
            messages: list[dict[str, Any]] = []

            async def receive() -> dict[str, Any]:
                while not messages:
                    data = await ws.receive_json(timeout=10)
                    messages.extend(data if isinstance(data, list) else [data])
                return messages.pop(0)

            async def ask(**message: Any) -> dict[str, Any]:
                await ws.send_json({"id": 1, "node": 10, **message})
                while True:
                    got = await receive()
                    if got.get("id") == 1:
                        return got

            snapshot = await receive()
            [node] = snapshot["info"]["parameters"]["nodes"]
            assert node["set"] == "servo.yml"
            [status] = snapshot["state"]["parameters/status"]
            assert status["node"] == 10 and status["set"] == "servo.yml" and status["ok"] is True
            assert "re-parameterised, 2 of 2 written, saved and verified" in status["summary"]
            same = await ask(cmd="param.diff", against="parameters")
            result = same["result"]
            assert result["against"] == "parameters" and result["file"] == "servo.yml"
            assert result["differ"] == 0 and [r["same"] for r in result["rows"]] == [True, True]
            assert result["rows"][0]["name"] and result["rows"][0]["file"] == 1234
            # someone changes a parameter: the diff says which, and what each side holds
            written = await ask(cmd="param.write", index=0x6083, subindex=0, value=99)
            assert written["type"] == "ack", written
            differs = (await ask(cmd="param.diff", against="parameters"))["result"]
            assert differs["differ"] == 1
            assert (differs["rows"][0]["file"], differs["rows"][0]["node"]) == (1234, 99)
            network = (await ask(cmd="param.diff"))["result"]
            assert network["against"] == "network" and network["file"] is None
            refused = await ask(cmd="param.diff", against="yesterday")
            assert refused["code"] == "bad-argument" and "network or parameters" in refused["text"]

    run(main())


def test_a_node_without_a_parameter_file_says_how_to_give_one(tmp_path: Path) -> None:
    async def main() -> None:
        async with drive_page(tmp_path) as (panel, _view, _reads, _net):
            view = panel.views["parameters"]
            assert view.sample() == {"parameters/status": []}
            with pytest.raises(CommandError, match=r"--parameters servo=FILE"):
                await view._diff({"node": 10, "against": "parameters"})

    run(main())


@contextlib.asynccontextmanager
async def thesis_master(tmp_path: Path) -> AsyncIterator[tuple[Master, AsyncNetwork, Counter[int]]]:
    """The thesis rig booted by the master of the demo's network file, with no application
    (as ``cobus run thesis.yml`` has it); the frames the master sends, counted by COB-ID."""
    rig = Rig.load(ready_rig("thesis"))
    channel = f"panel-zapi-{os.getpid()}-{id(tmp_path):x}"
    devices = rig.create_network(interface="virtual", channel=channel)
    net = AsyncNetwork(interface="virtual", channel=channel)
    await devices.connect()
    await net.connect()
    sent: Counter[int] = Counter()

    def count(frame: Any, _now: float) -> None:
        sent[frame.cob_id] += 1

    subscription = devices.subscribe_all(count)
    await rig.start(devices)
    for node_id, name in ((IO, "io"), (SERVO, "servo"), (ZAPI, "zapi")):
        od = rig.devices[node_id].od  # type: ignore[attr-defined]
        (tmp_path / f"{name}.eds").write_text(export_eds(od))
    master = Master(net, loads_network(NETWORK_FILE.read_text(), base_dir=tmp_path))
    try:
        await master.boot(timeout=10)
        yield master, net, sent
    finally:
        await master.stop()
        subscription.cancel()
        await rig.stop()
        await net.disconnect()
        await devices.disconnect()


def adapter_of(view: DriveView) -> Any:
    """The view's adapter now (a function: mypy would keep an earlier narrowing)."""
    return view.drive


def test_a_zapi_handshake_starts_only_when_the_operator_starts_it(tmp_path: Path) -> None:
    async def main() -> None:
        async with thesis_master(tmp_path) as (master, net, sent):
            panel = Panel(port=0, clock=net.time)
            started: list[Any] = []
            view = serve_zapi(panel, master, "zapi", on_start=started.append)
            assert panel.hub.info["drives"] == [
                {"name": "zapi", "kind": "zapi", "node": ZAPI, "unit": "Hz", "on_demand": True}
            ]
            with pytest.raises(ValueError, match="already shows a drive 'zapi'"):
                serve_zapi(panel, master, ZAPI)
            with pytest.raises(KeyError, match="no node 'pump'"):
                serve_zapi(panel, master, "pump")

            async def drive(action: str, **args: Any) -> Any:
                handler = panel.commands["drive"].handler
                return await handler({"drive": "zapi", "action": action, **args})

            rpdo1 = 0x200 + ZAPI
            await asyncio.sleep(0.1)
            before = sent[rpdo1]  # (the master sends each RPDO once as it starts)
            await asyncio.sleep(0.3)
            assert sent[rpdo1] == before  # nothing answers the inverter until the operator asks
            record = view.sample()["drive/zapi"]
            assert record["state"] == "HANDSHAKE NOT STARTED" and record["handshake"] is False
            with pytest.raises(CommandError, match="start it first") as refused:
                await drive("enable", confirm=True)
            assert refused.value.code == "no-handshake"
            assert await drive("stop") == {"action": "stop", "handshake": False, "moving": False}
            # the operator starts it: an RPDO1 every cycle, released, at 0 Hz
            # (the inverter lost its handshake long ago - alarm 248, pre-operational - so it is
            # started again and acknowledged, the motor still off)
            assert await drive("handshake") == {
                "action": "handshake",
                "handshake": True,
                "started": True,
                "restarted": True,
            }
            assert view.drive.alarm == 0
            assert len(started) == 1 and started[0] is view.drive
            assert (await drive("handshake"))["started"] is False  # (once)
            await until(lambda: view.drive.cycles >= 10)
            assert sent[rpdo1] >= before + 10
            assert view.sample()["drive/zapi"]["handshake"] is True
            assert not view.drive.command and view.drive.setpoint == 0.0
            await drive("enable", confirm=True)
            assert (await drive("speed", value=12.5))["value"] == 12.5
            assert view.drive.setpoint == 12.5
            # ended from the page: released first, then no more answers
            adapter = view.drive
            assert await drive("end_handshake") == {"action": "end_handshake", "handshake": False}
            assert view.drive is None and adapter.setpoint == 0.0 and not adapter.command
            await asyncio.sleep(0.1)
            answered = sent[rpdo1]
            await asyncio.sleep(0.3)
            assert sent[rpdo1] == answered
            # started again, and ended by closing the view (the run's end)
            await drive("handshake")
            await until(lambda: adapter_of(view) is not None and adapter_of(view).cycles >= 3)
            view.close()
            assert adapter_of(view) is None

    run(main())
