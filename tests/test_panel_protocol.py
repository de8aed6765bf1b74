"""The panel's server over a real WebSocket (aiohttp's client), against the simulated thesis
rig booted by the cobus master: snapshot, deltas, numbered events, resync, commands and their
errors, the token, the origin and host checks, a slow client, the vendored files."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import hashlib
import io
import itertools
import json
import os
import socket
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from cobus.apps.demo import IO, SERVO, Demo, attach_drives, start_panel
from cobus.apps.panel import CommandError, Panel, PanelError
from cobus.apps.panel.server import CSP, STATIC
from cobus.apps.panel.trace import TraceView


def run(coro: Awaitable[Any], timeout: float = 60.0) -> Any:
    async def bounded() -> Any:
        return await asyncio.wait_for(coro, timeout)

    return asyncio.run(bounded())


@contextlib.asynccontextmanager
async def served(workdir: Path, **options: Any) -> AsyncIterator[tuple[Demo, Panel]]:
    """The thesis rig booted by the master (the demo's, with its alarm handler and faults),
    with the demo's panel on a free port, attached before the boot."""
    demo = Demo(workdir)
    panels: list[Panel] = []

    async def attach(d: Demo) -> None:
        panels.append(await start_panel(d, "127.0.0.1", 0, io.StringIO(), **options))

    try:
        await demo.start(before_boot=attach)
        attach_drives(demo, panels[0])
        yield demo, panels[0]
    finally:
        for panel in panels:
            await panel.stop()
        await demo.stop()


@contextlib.asynccontextmanager
async def connected(
    workdir: Path, **options: Any
) -> AsyncIterator[tuple[Demo, Panel, aiohttp.ClientSession, Page]]:
    """:func:`served`, with an HTTP session and one page's WebSocket open on it."""
    async with (
        served(workdir, **options) as (demo, panel),
        aiohttp.ClientSession() as http,
        page(http, base(panel) + "/ws") as ws,
    ):
        yield demo, panel, http, ws


def base(panel: Panel) -> str:
    assert panel.bound is not None
    return f"http://127.0.0.1:{panel.bound[1]}"


class Page:
    """A WebSocket to the panel read by a task of its own into a queue (aiohttp's own receive
    must not be cut short by a timeout)."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.queue: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
        self.task = asyncio.create_task(self._read())

    async def _read(self) -> None:
        async for msg in self.ws:
            if msg.type is aiohttp.WSMsgType.TEXT:
                data = json.loads(msg.data)  # one message or several queued together
                for message in data if isinstance(data, list) else [data]:
                    self.queue.put_nowait(message)

    async def send(self, message: Any) -> None:
        if isinstance(message, str):
            await self.ws.send_str(message)
        elif isinstance(message, bytes):
            await self.ws.send_bytes(message)
        else:
            await self.ws.send_json(message)

    async def receive(self, timeout: float = 5.0) -> dict[str, Any]:
        return await asyncio.wait_for(self.queue.get(), timeout)

    async def until(
        self, check: Callable[[dict[str, Any]], bool], timeout: float = 10.0
    ) -> dict[str, Any]:
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while True:
            message = await self.receive(max(0.01, end - loop.time()))
            if check(message):
                return message

    async def reply(self) -> dict[str, Any]:
        return await self.until(lambda m: m["type"] in ("ack", "error"))


@contextlib.asynccontextmanager
async def page(http: aiohttp.ClientSession, url: str, **options: Any) -> AsyncIterator[Page]:
    async with http.ws_connect(url, **options) as ws:
        reader = Page(ws)
        try:
            yield reader
        finally:
            reader.task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reader.task


async def running(demo: Demo) -> None:
    """Wait until the rig's I/O module and servo took the master's start command."""
    for _ in range(200):
        if nmt_of(demo, IO) == nmt_of(demo, SERVO) == "OPERATIONAL":
            return
        await asyncio.sleep(0.01)
    raise AssertionError("the rig was never started")


def nmt_of(demo: Demo, node_id: int) -> str:
    return str(demo.rig.devices[node_id].status().get("nmt", "operational")).upper()


def test_a_page_gets_a_snapshot_then_deltas_then_numbered_events(tmp_path: Path) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (demo, _panel, _http, ws):
            snapshot = await ws.receive()
            assert snapshot["type"] == "snapshot"
            assert snapshot["info"]["title"] == "cobus demo"
            assert snapshot["info"]["needs_token"] is False
            assert {n["id"] for n in snapshot["info"]["nodes"]} == {8, IO, SERVO}
            node = snapshot["state"][f"node/{SERVO}"]
            assert node["nmt"] == "OPERATIONAL" and node["state"] == 5
            assert node["run_led"] == "on" and node["error_led"] == "off"
            assert snapshot["state"]["master"]["state"] == "RUNNING"
            assert isinstance(snapshot["state"][f"heard/{SERVO}"], float)
            assert "bus_load" in snapshot["series"]
            seq = snapshot["seq"]
            assert seq == len(snapshot["events"]) > 5  # the boot, as it happened
            assert [e["seq"] for e in snapshot["events"]] == list(range(1, seq + 1))
            # heartbeats keep arriving: deltas, at most 10 a second
            first = await ws.until(lambda m: m["type"] == "delta")
            await asyncio.sleep(1.0)
            deltas = [first]
            while True:
                try:
                    message = await ws.receive(0.05)
                except TimeoutError:
                    break
                if message["type"] == "delta":
                    deltas.append(message)
            assert 2 <= len(deltas) <= 13
            times = [d["time"] for d in deltas]
            assert all(b - a >= 0.09 for a, b in itertools.pairwise(times))
            # an event: the master's word on a node put to pre-operational
            demo.rig_net.nmt.send(0x80, IO)  # someone else on the bus
            event = await ws.until(lambda m: m["type"] == "event")
            events = [event]
            while not (event["kind"] == "master" and event["node"] == IO):
                event = await ws.until(lambda m: m["type"] == "event")
                events.append(event)
            assert [e["seq"] for e in events] == list(range(seq + 1, seq + 1 + len(events)))
            assert event["text"] and event["level"] == "problem"  # an unexpected state

    run(main())


def test_a_burst_of_events_goes_out_in_a_few_messages_in_order() -> None:
    async def main() -> None:
        async with (
            Panel(port=0) as panel,
            aiohttp.ClientSession() as http,
            http.ws_connect(base(panel) + "/ws") as ws,
        ):
            first = json.loads((await ws.receive(5)).data)
            assert first["type"] == "snapshot" and first["seq"] == 0
            for n in range(400):  # an EMCY storm: 400 events at once
                panel.hub.event("master", name="NodeEmergency", text=f"EMCY {n}")
            panel.hub.update({"load": 1})
            events: list[dict[str, Any]] = []
            frames = 0
            while len(events) < 400:
                data = json.loads((await ws.receive(5)).data)
                frames += 1
                for message in data if isinstance(data, list) else [data]:
                    assert message["type"] in ("event", "delta"), message
                    if message["type"] == "event":
                        events.append(message)
            assert [e["seq"] for e in events] == list(range(1, 401))
            assert [e["text"] for e in events[:2]] == ["EMCY 0", "EMCY 1"]
            assert frames <= 3  # (one, unless the sender woke in the middle of the burst)

    run(main())


def test_the_network_sample_builds_only_the_nodes_that_changed(tmp_path: Path) -> None:
    async def main() -> None:
        async with served(tmp_path) as (demo, panel):
            await running(demo)
            view = panel.views["network"]
            view.sample()
            again = view.sample()  # (nothing can change between the two: no await)
            assert not [k for k in again if k.startswith(("node/", "heard/"))]
            assert "master" in again and "bus_load" in again
            demo.rig_net.nmt.send(0x02, IO)  # someone stops the I/O module
            for _ in range(300):  # (its record may change for other reasons first)
                await asyncio.sleep(0.01)
                changed = view.sample()
                if changed.get(f"node/{IO}", {}).get("nmt") == "STOPPED":
                    break
            else:
                raise AssertionError("the stopped I/O module never came in a sample")

    run(main())


def test_nmt_buttons_reach_the_node_and_are_acknowledged(tmp_path: Path) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (demo, _panel, _http, ws):
            await ws.receive()
            await ws.send({"id": 7, "cmd": "nmt", "node": IO, "action": "stop"})
            ack = await ws.reply()
            assert ack == {"type": "ack", "id": 7, "result": {"node": IO, "action": "stop"}}
            await ws.until(
                lambda m: (
                    m["type"] == "delta"
                    and m["values"].get(f"node/{IO}", {}).get("nmt") == "STOPPED"
                ),
            )
            assert nmt_of(demo, IO) == "STOPPED"
            await ws.send({"id": "s", "cmd": "nmt", "node": "all", "action": "start"})
            ack = await ws.reply()
            assert ack["type"] == "ack" and ack["result"]["node"] == "all"

    run(main())


@pytest.mark.parametrize(
    ("message", "code", "text"),
    [
        ("{not json", "malformed", "not JSON"),
        ("[1, 2]", "malformed", "JSON object"),
        ('{"id": {"a": 1}, "cmd": "nmt"}', "malformed", "id"),
        ('{"id": 1, "cmd": "format_disk"}', "unknown-command", "alarm.ack, alarm.history"),
        ('{"id": 6, "cmd": "alarm.ack", "source": "emcy"}', "bad-argument", "code"),
        ('{"id": 6, "cmd": "alarm.ack", "source": "x", "node": 9, "code": 1}', "no-alarm", "x 1"),
        ('{"id": 6, "cmd": "alarm.ack", "all": true, "by": ""}', "bad-argument", "by"),
        ('{"id": 8, "cmd": "alarm.history", "limit": 0}', "bad-argument", "1-1000"),
        ('{"id": 8, "cmd": "alarm.history", "node": "9"}', "bad-argument", "node"),
        (
            '{"id": 8, "cmd": "alarm.history", "node": 1180591620717411303424}',
            "bad-argument",
            "0-127",
        ),
        (
            '{"id": 9, "cmd": "param.write", "node": 10, "index": 24707, "value": 1e999}',
            "bad-argument",
            "UNSIGNED32",
        ),
        ('{"id": 8, "cmd": "alarm.history", "since": "yesterday"}', "bad-argument", "1970"),
        ('{"id": 9, "cmd": "demo.fault", "fault": "meteor"}', "bad-argument", "unplug_io"),
        ('{"id": 10, "cmd": "nmt", "node": 9, "action": []}', "bad-argument", "action"),
        ('{"id": 11, "cmd": "drive", "drive": "servo", "action": {}}', "bad-argument", "action"),
        ('{"id": 12, "cmd": "drive", "drive": "pump", "action": "halt"}', "no-drive", "servo"),
        ("[" * 30000 + "]" * 30000, "malformed", ""),
        ('{"id": 2, "cmd": "nmt", "node": 9, "action": "explode"}', "bad-argument", "preop"),
        ('{"id": 3, "cmd": "nmt", "node": "9", "action": "stop"}', "bad-argument", "node-ID"),
        ('{"id": 4, "cmd": "nmt", "node": true, "action": "stop"}', "bad-argument", "node-ID"),
        ('{"id": 5, "cmd": "nmt", "node": 42, "action": "stop"}', "no-node", "8, 9, 10"),
    ],
)
def test_a_malformed_command_gets_a_typed_error_and_the_page_stays_connected(
    tmp_path: Path, message: str, code: str, text: str
) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (demo, _panel, _http, ws):
            await ws.receive()
            await running(demo)
            await ws.send(message)
            error = await ws.reply()
            assert error["type"] == "error" and error["code"] == code, error
            assert text in error["text"]
            states = {n: nmt_of(demo, n) for n in (IO, SERVO)}
            assert states == {IO: "OPERATIONAL", SERVO: "OPERATIONAL"}  # untouched
            # still connected: a good command works
            await ws.send({"id": 9, "cmd": "nmt", "node": IO, "action": "start"})
            ack = await ws.reply()
            assert ack["type"] == "ack" and ack["id"] == 9

    run(main())


def test_a_panel_with_a_token_refuses_readers_and_commands_without_it(tmp_path: Path) -> None:
    async def main() -> None:
        async with served(tmp_path, token="s3cret-token") as (demo, panel):
            assert panel.needs_token and panel.url.endswith("/?token=s3cret-token")
            assert panel.reads_need_token
            url = base(panel)
            async with aiohttp.ClientSession() as http:
                # the page itself carries no data: served without the token
                for path in ("/", "/static/panel.js"):
                    async with http.get(url + path) as r:
                        assert r.status == 200
                # its data is not: the WebSocket and the CSV export need the token
                for query in ("", "?token=wrong", "?token=s3cret-toke"):
                    with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                        async with http.ws_connect(url + "/ws" + query):
                            pass
                    assert refused.value.status == 401
                    async with http.get(url + "/alarms.csv" + query) as r:
                        assert r.status == 401 and "?token=" in await r.text()
                async with http.get(url + "/alarms.csv?token=s3cret-token") as r:
                    assert r.status == 200
            async with (
                aiohttp.ClientSession() as http,
                page(http, url + "/ws?token=s3cret-token") as ws,
            ):
                snapshot = await ws.receive()
                await running(demo)
                assert snapshot["info"]["needs_token"] is True
                for given in (None, "wrong", 12, "\ud800"):
                    command = {"id": 1, "cmd": "nmt", "node": IO, "action": "stop"}
                    if given is not None:
                        command["token"] = given
                    await ws.send(command)
                    error = await ws.reply()
                    assert error["code"] == "token" and "token" in error["text"]
                assert nmt_of(demo, IO) == "OPERATIONAL"
                await ws.send(
                    {"id": 2, "cmd": "nmt", "node": IO, "action": "stop", "token": "s3cret-token"}
                )
                ack = await ws.reply()
                assert ack["type"] == "ack"

    run(main())


def test_a_panel_bound_beyond_loopback_needs_a_token() -> None:
    panel = Panel(host="0.0.0.0", port=0)
    assert panel.needs_token and panel.reads_need_token and len(panel.token) >= 20
    assert not Panel(port=0).needs_token
    assert not Panel(host="::1", port=0).reads_need_token
    # a view-only screen: reads open, commands still need the token
    screen = Panel(host="0.0.0.0", port=0, open_reads=True)
    assert screen.needs_token and not screen.reads_need_token


def test_open_reads_let_a_screen_watch_but_not_command(tmp_path: Path) -> None:
    async def main() -> None:
        async with (
            connected(tmp_path, token="s3cret-token", open_reads=True) as (demo, _p, _h, ws),
        ):
            assert (await ws.receive())["type"] == "snapshot"
            await running(demo)
            await ws.send({"id": 1, "cmd": "nmt", "node": IO, "action": "stop"})
            assert (await ws.reply())["code"] == "token"
            assert nmt_of(demo, IO) == "OPERATIONAL"
            # nor does it ask the bus anything (an SDO read costs the master's channel)
            await ws.send({"id": 2, "cmd": "param.read", "node": IO, "index": 0x1008})
            refused = await ws.reply()
            assert refused["code"] == "token" and "param.read asks the bus" in refused["text"]

    run(main())


def test_a_gap_is_closed_by_a_resync(tmp_path: Path) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (_demo, panel, _http, ws):
            first = await ws.receive()
            panel.hub.event("test", text="one")
            await ws.until(lambda m: m["type"] == "event")
            await ws.send({"cmd": "resync"})
            again = await ws.until(lambda m: m["type"] == "snapshot")
            # numbered on from the first snapshot (the demo's own events may come in between
            # on a loaded machine), and holding the event the client may have missed
            assert again["seq"] > first["seq"]
            assert "one" in [e.get("text") for e in again["events"]]

    run(main())


def test_cross_origin_pages_and_foreign_host_names_are_refused(tmp_path: Path) -> None:
    async def main() -> None:
        async with served(tmp_path) as (_demo, panel), aiohttp.ClientSession() as http:
            url = base(panel)
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                await http.ws_connect(url + "/ws", origin="http://evil.example")
            assert refused.value.status == 403
            same = url.replace("http://", "")
            async with page(http, url + "/ws", origin=f"http://{same}") as ws:
                assert (await ws.receive())["type"] == "snapshot"
            # DNS rebinding: a name that resolves here but is not this machine's
            async with http.get(url + "/", headers={"Host": f"evil.example:{panel.bound[1]}"}) as r:  # type: ignore[index]
                assert r.status == 421
            for path in ("/", "/static/panel.js", "/static/vendor/uPlot.iife.min.js", "/nope"):
                async with http.get(url + path) as r:
                    assert r.headers["Content-Security-Policy"] == CSP, path
                    assert r.status == (404 if path == "/nope" else 200)
            async with http.get(url + "/static/../server.py") as r:
                assert r.status in (403, 404)

    run(main())


def test_a_stuck_browser_is_dropped_and_the_others_go_on() -> None:
    big = "x" * 300_000

    async def main() -> None:
        panel = Panel(port=0, stall=0.5, rate=20)
        ticks = {"n": 0}

        def sample() -> dict[str, Any]:
            ticks["n"] += 1
            return {"blob": f"{ticks['n']}{big}", "n": ticks["n"]}

        panel.sample(sample)
        await panel.start()
        assert panel.bound is not None
        port = panel.bound[1]
        # a client that opens the WebSocket and then never reads, with a tiny window
        stuck = socket.socket()
        stuck.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stuck.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        stuck.sendall(
            (
                f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                "Sec-WebSocket-Version: 13\r\n\r\n"
            ).encode()
        )
        try:
            async with (
                aiohttp.ClientSession() as http,
                page(http, f"http://127.0.0.1:{port}/ws", max_msg_size=0) as ws,
            ):
                loop = asyncio.get_running_loop()
                end = loop.time() + 30
                seen = 0
                while panel.hub.dropped == 0 and loop.time() < end:
                    message = await ws.receive()
                    seen += message["type"] == "delta"
                assert panel.hub.dropped == 1, "the stuck client was never dropped"
                assert len(panel.hub.clients) == 1  # the reading one stays
                # and its connection is cut, not left to the WebSocket heartbeat
                stuck.settimeout(0)
                cut = False
                for _ in range(200):
                    try:
                        while stuck.recv(1 << 20):
                            pass
                        cut = True
                    except BlockingIOError:
                        await asyncio.sleep(0.01)
                        continue
                    except ConnectionError:
                        cut = True
                    break
                assert cut, "the stalled connection stays open"
                before = seen
                for _ in range(5):
                    message = await ws.receive()
                    seen += message["type"] == "delta"
                assert seen > before
        finally:
            await asyncio.wait_for(panel.stop(), 5.0)  # a stuck page never holds the stop
            stuck.close()

    run(main())


def test_an_address_in_use_is_a_panel_error() -> None:
    async def main() -> None:
        async with Panel(port=0) as first:
            assert first.bound is not None
            second = Panel(port=first.bound[1])
            with pytest.raises(PanelError, match=r"cannot serve the panel .*port 0"):
                await second.start()

    run(main())


@pytest.mark.parametrize(("options", "text"), [({"port": 70000}, "port"), ({"rate": 0}, "rate")])
def test_bad_panel_options_are_refused(options: dict[str, Any], text: str) -> None:
    with pytest.raises(PanelError, match=text):
        Panel(**options)


def test_a_failing_command_is_answered_and_others_keep_working() -> None:
    async def main() -> None:
        panel = Panel(port=0)

        async def broken(_message: Any) -> None:
            raise RuntimeError("boom")

        async def refuses(_message: Any) -> None:
            raise CommandError("busy-drive", "the drive is homing")

        async def slow(_message: Any) -> str:
            await asyncio.sleep(0.3)
            return "done"

        panel.command("broken", broken, writes=False)
        panel.command("refuses", refuses, writes=False)
        panel.command("slow", slow, writes=False)
        with pytest.raises(ValueError, match="already"):
            panel.command("slow", slow, writes=False)
        async with panel, aiohttp.ClientSession() as http:
            assert panel.bound is not None
            async with page(http, f"http://127.0.0.1:{panel.bound[1]}/ws") as ws:
                await ws.receive()
                await ws.send({"id": 1, "cmd": "slow"})
                await ws.send({"id": 2, "cmd": "broken"})
                await ws.send({"id": 3, "cmd": "refuses"})
                await ws.send(b"\x00")
                replies = [await ws.until(lambda m: "id" in m) for _ in range(4)]
                by_id = {r["id"]: r for r in replies}
                assert by_id[2]["code"] == "internal" and "boom" in by_id[2]["text"]
                assert by_id[3]["code"] == "busy-drive"
                assert by_id[None]["code"] == "malformed"
                assert by_id[1] == {"type": "ack", "id": 1, "result": "done"}
                assert [r["id"] for r in replies][-1] == 1  # the slow one did not hold others

    run(main())


def test_the_vendored_files_are_the_pinned_ones() -> None:
    vendor = STATIC / "vendor"
    record = json.loads((vendor / "VENDOR.json").read_text())["uplot"]
    assert record["tarball"].startswith("https://registry.npmjs.org/uplot/-/uplot-")
    assert record["version"] in record["tarball"]
    for name, facts in record["files"].items():
        assert hashlib.sha256((vendor / name).read_bytes()).hexdigest() == facts["sha256"], name
    assert f"(v{record['version']})" in (vendor / "uPlot.iife.min.js").read_text()[:200]
    assert "MIT License" in (vendor / "uPlot.LICENSE").read_text()
    # every file the page loads is served from the package (no CDN)
    index = (STATIC / "index.html").read_text()
    assert "http" not in index.replace('lang="en"', "")


def test_a_fault_raises_an_alarm_that_is_acknowledged_cleared_and_kept(tmp_path: Path) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (_demo, panel, http, ws):
            snapshot = await ws.receive()
            assert snapshot["info"]["alarms"] == {"view_time": 3.0, "history": True}
            assert [f["name"] for f in snapshot["info"]["faults"]][:2] == ["unplug_io", "replug_io"]
            assert snapshot["state"]["alarms/current"] is None
            await ws.send({"id": 1, "cmd": "demo.fault", "fault": "unplug_io"})
            assert (await ws.reply())["result"].startswith("the I/O module loses its power")
            raised = await ws.until(
                lambda m: m["type"] == "event" and m["kind"] == "alarm" and m["node"] == IO
            )
            assert raised["action"] == "raised" and raised["level"] == "problem"
            alarm = raised["alarm"]
            assert alarm["source"] == "master" and alarm["acknowledged_by"] is None
            current = await ws.until(
                lambda m: m["type"] == "delta" and bool(m["values"].get("alarms/current"))
            )
            assert current["values"]["alarms/current"]["node"] == IO
            key = {k: alarm[k] for k in ("source", "node", "code")}
            await ws.send({"id": 2, "cmd": "alarm.ack", **key, "by": "Anna"})
            assert (await ws.reply()) == {"type": "ack", "id": 2, "result": {"acknowledged": 1}}
            await ws.until(lambda m: m["type"] == "event" and m.get("action") == "acknowledged")
            await ws.send({"id": 3, "cmd": "demo.fault", "fault": "replug_io"})
            await ws.reply()
            await ws.until(
                lambda m: (
                    m["type"] == "event"
                    and m.get("action") == "cleared"
                    and m["alarm"]["code"] == alarm["code"]
                ),
                timeout=15,
            )
            await ws.send({"id": 4, "cmd": "alarm.history", "node": IO, "source": "master"})
            rows = (await ws.reply())["result"]
            row = next(r for r in rows if r["code"] == alarm["code"])
            assert row["acknowledged_by"] == "Anna" and row["cleared_at"] is not None
            await ws.send({"id": 5, "cmd": "alarm.history", "active": True, "node": IO})
            assert all(r["cleared_at"] is None for r in (await ws.reply())["result"])
            async with http.get(base(panel) + f"/alarms.csv?node={IO}&source=master") as r:
                assert r.status == 200 and r.content_type == "text/csv"
                text = await r.text()
                assert "Anna" in text and text.count("\n") >= 2
            for query in ("node=nine", "node=0xfffffffffffffffffffffff", "since=soon"):
                async with http.get(base(panel) + f"/alarms.csv?{query}") as r:
                    assert r.status == 400, query

    run(main())


def test_a_page_that_stops_reading_never_holds_the_panel_stop() -> None:
    async def main() -> None:
        panel = Panel(port=0, stall=60)  # not dropped as stalled: the stop must cut it off
        panel.sample(lambda: {"blob": "x" * 200_000 + str(asyncio.get_running_loop().time())})
        await panel.start()
        assert panel.bound is not None
        stuck = socket.socket()
        stuck.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stuck.connect(("127.0.0.1", panel.bound[1]))
        key = base64.b64encode(os.urandom(16)).decode()
        stuck.sendall(
            (
                f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{panel.bound[1]}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                "Sec-WebSocket-Version: 13\r\n\r\n"
            ).encode()
        )
        await asyncio.sleep(1.5)
        assert len(panel.hub.clients) == 1
        await asyncio.wait_for(panel.stop(), 5.0)
        stuck.close()

    run(main())


def test_too_many_pages_are_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    from cobus.apps.panel import server

    monkeypatch.setattr(server, "MAX_CLIENTS", 2)

    async def main() -> None:
        async with Panel(port=0) as panel, aiohttp.ClientSession() as http:
            assert panel.bound is not None
            url = f"http://127.0.0.1:{panel.bound[1]}/ws"
            async with page(http, url) as one, page(http, url) as two:
                await one.receive()
                await two.receive()
                with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                    await http.ws_connect(url)
                assert refused.value.status == 503

    run(main())


def test_the_unix_socket_is_this_users_and_goes_with_the_panel(tmp_path: Path) -> None:
    path = str(tmp_path / "panel.sock")
    stale = socket.socket(socket.AF_UNIX)
    stale.bind(path)  # left behind by a server that is gone
    stale.close()

    async def main() -> None:
        async with Panel(port=0, unix=path) as panel:
            assert not panel.needs_token
            assert os.stat(path).st_mode & 0o777 == 0o600
            connector = aiohttp.UnixConnector(path=path)
            async with (
                aiohttp.ClientSession(connector=connector) as http,
                http.get("http://localhost/") as r,
            ):
                assert r.status == 200
            with pytest.raises(PanelError, match="another server listens there"):
                await Panel(port=0, unix=path).start()
        assert not os.path.exists(path)

    run(main())


def test_tokens_are_long_enough_and_quoted_in_the_address() -> None:
    with pytest.raises(PanelError, match="8 characters"):
        Panel(token="")
    panel = Panel(port=0, token="a+b&c#d%e")

    async def main() -> None:
        async with panel:
            assert panel.url.endswith("/?token=a%2Bb%26c%23d%25e")

    run(main())


def test_drive_commands_carry_the_safety_a_drive_needs(tmp_path: Path) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (demo, _panel, _http, ws):
            snapshot = await ws.receive()
            await running(demo)
            for _ in range(300):  # the application enables the servo
                if demo.servo.status.state.name == "OPERATION_ENABLED":  # type: ignore[union-attr]
                    break
                await asyncio.sleep(0.01)
            drives = {d["name"]: d for d in snapshot["info"]["drives"]}
            assert drives["servo"] == {
                "name": "servo",
                "kind": "cia402",
                "node": SERVO,
                "unit": "inc/s",
                "on_demand": False,
            }
            assert drives["zapi"]["kind"] == "zapi"
            servo = snapshot["state"]["drive/servo"]
            assert servo["holder"] == "application" and servo["kind"] == "cia402"

            async def drive(action: str, **args: Any) -> dict[str, Any]:
                await ws.send(
                    {"id": action, "cmd": "drive", "drive": "servo", "action": action, **args}
                )
                return await ws.reply()

            # while the application runs it: no set-point, no enable - but stopping, always
            refused = await drive("speed", value=100)
            assert (
                refused["code"] == "not-holder" and "stopping is always allowed" in refused["text"]
            )
            halted = await drive("halt")
            assert halted["type"] == "ack", halted
            # a stop lasts: the operator holds the drive now, the application leaves it be
            assert demo.panel_holds["servo"]()
            assert (await drive("take"))["result"] == {"holder": "panel"}
            assert demo.panel_holds["servo"]()
            assert (await drive("quick_stop"))["type"] == "ack"
            state = demo.servo.status.state.name  # type: ignore[union-attr]
            assert state in ("QUICK_STOP_ACTIVE", "SWITCH_ON_DISABLED")
            refused = await drive("speed", value=100)
            assert refused["code"] == "not-enabled"  # a set-point never enables a drive
            refused = await drive("enable")
            assert refused["code"] == "confirm" and "speed 0" in refused["text"]
            enabled = await drive("enable", confirm=True)
            assert enabled["type"] == "ack", enabled
            assert demo.servo.status.state.name == "OPERATION_ENABLED"  # type: ignore[union-attr]
            for value, text in (
                (1.5, "whole number"),
                ("fast", "signed speed"),
                (10**10, ".."),
                (10**400, ".."),
            ):
                refused = await drive("speed", value=value)
                assert refused["code"] == "bad-argument" and text in refused["text"], refused
            assert (await drive("speed", value=-5000))["result"] == {
                "action": "speed",
                "value": -5000,
            }
            # a faulted drive cannot move: a quick stop is answered at once
            await demo.fault("servo_fault")
            for _ in range(200):
                if (await demo.servo.read_statusword()).state.name == "FAULT":  # type: ignore[union-attr]
                    break
                await asyncio.sleep(0.01)
            stopped = await drive("quick_stop")
            assert stopped["result"] == {"action": "quick_stop", "state": "FAULT", "moving": False}
            assert (await drive("give"))["result"] == {"holder": "application"}
            assert not demo.panel_holds["servo"]()

            # the ZAPI inverter: the same rules
            await ws.send({"id": "z", "cmd": "drive", "drive": "zapi", "action": "take"})
            await ws.reply()
            await ws.send({"id": "z1", "cmd": "drive", "drive": "zapi", "action": "enable"})
            assert (await ws.reply())["code"] == "confirm"
            await ws.send(
                {"id": "z2", "cmd": "drive", "drive": "zapi", "action": "speed", "value": 500}
            )
            refused = await ws.reply()
            assert (refused["type"] == "error" and "327.67" in refused["text"]) or refused[
                "code"
            ] == "not-enabled"
            await ws.send({"id": "z3", "cmd": "drive", "drive": "zapi", "action": "release"})
            assert (await ws.reply())["type"] == "ack"
            assert demo.zapi is not None and demo.zapi.setpoint == 0.0

    run(main())


def test_parameters_are_listed_read_written_checked_and_diffed(tmp_path: Path) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (demo, _panel, _http, ws):
            snapshot = await ws.receive()
            await running(demo)
            nodes = snapshot["info"]["parameters"]["nodes"]
            assert {n["id"] for n in nodes} == {8, IO, SERVO}

            async def ask(cmd: str, **args: Any) -> dict[str, Any]:
                await ws.send({"id": cmd, "cmd": cmd, "node": SERVO, **args})
                return await ws.reply()

            found = (await ask("param.list", query="controlword"))["result"]["objects"]
            control = next(o for o in found if o["index"] == 0x6040)
            assert control["command"] and control["access"] == "rww"
            found = (await ask("param.list", query="0x1018:02"))["result"]["objects"]
            assert [(o["index"], o["subindex"]) for o in found] == [(0x1018, 2)]
            assert (await ask("param.list", query="1008h"))["result"]["objects"][0][
                "index"
            ] == 0x1008
            listing = (await ask("param.list", limit=3))["result"]
            assert len(listing["objects"]) == 3 and listing["more"] > 0

            name = (await ask("param.read", index=0x1008))["result"]
            assert name["value"] == "cobus CiA 402 drive" and name["type"] == "VISIBLE_STRING"

            refused = await ask("param.write", index=0x1000, value=1)
            assert refused["code"] == "read-only"
            refused = await ask("param.write", index=0x6040, value=0x0F)
            assert refused["code"] == "command" and "controlword" in refused["text"].lower()
            refused = await ask("param.write", index=0x6083, value="fast")
            assert refused["code"] == "bad-argument" and "UNSIGNED32" in refused["text"]
            refused = await ask("param.write", index=0x6083, value=-1)
            assert refused["code"] == "bad-argument"
            refused = await ask("param.write", index=0x7777, value=1)
            assert refused["code"] == "no-object"
            written = await ask("param.write", index=0x6083, value="0x3000")
            assert written["result"]["value"] == 0x3000, written
            assert (await ask("param.read", index=0x6083))["result"]["value"] == 0x3000

            diff = (await ask("param.diff"))["result"]
            mode = next(r for r in diff["rows"] if r["index"] == 0x6060)
            assert mode["file"] == 3 and mode["node"] == 3 and mode["same"] is True
            saved = await ask("param.save")
            assert saved["type"] == "ack", saved
            # nodes by name too; one the master leaves as it is has nothing to differ
            await ws.send({"id": "z", "cmd": "param.diff", "node": "zapi"})
            rows = (await ws.reply())["result"]["rows"]
            assert rows and all(r["same"] is None for r in rows)
            assert "do_not_initialise" in rows[0]["note"]
            await ws.send({"id": "p", "cmd": "param.diff", "node": "pump"})
            refused = await ws.reply()
            assert refused["code"] == "no-node" and "zapi (8)" in refused["text"], refused

    run(main())


def test_the_trace_comes_decoded_in_numbered_batches(tmp_path: Path) -> None:
    async def main() -> None:
        async with connected(tmp_path) as (_demo, panel, _http, ws):
            snapshot = await ws.receive()
            assert snapshot["info"]["trace"] == {"max_batch": 300, "watch": 6.0}
            view = next(v for v in _demo._views if isinstance(v, TraceView))

            def decoding() -> bool:
                return view.decoding

            assert not decoding()  # nobody watches: nothing decoded
            await ws.send({"id": 1, "cmd": "trace.watch"})
            assert (await ws.reply())["result"] == {"decoding": True, "for": 6.0}
            assert decoding()
            batches = []
            while len(batches) < 5:
                message = await ws.until(lambda m: m["type"] == "delta")
                if "trace/batch" in message["values"]:
                    batches.append(message["values"]["trace/batch"])
            records = [r for b in batches for r in b["records"]]
            numbers = [r["n"] for r in records]
            assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
            for batch in batches:  # each batch is a run of numbers, save for those skipped
                first = batch["records"][0]["n"]
                assert batch["first"] == first
                assert batch["records"][-1]["n"] == first + len(batch["records"]) - 1
            kinds = {r["kind"] for r in records}
            assert {"hb", "sync", "pdo"} <= kinds, kinds
            beat = next(r for r in records if r["kind"] == "hb" and r["node"] == IO)
            assert beat["cob_id"] == 0x700 + IO and "heartbeat" in beat["text"]
            assert all(isinstance(r["time"], float) for r in records)
            view._until = 0.0  # (as if the last watch was long ago)
            panel.refresh()
            assert not decoding()

    run(main())
