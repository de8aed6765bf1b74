"""Operator panel soak: does a browser watching the panel disturb the master?

127 simulated nodes (119 I/O modules and 8 CiA 402 servo drives with their motor model) on
python-can's virtual bus, booted and supervised by the cobus master with SYNC every 20 ms;
the same run twice, in real time, ``--seconds`` each (60 by default; "minutes" with
``--seconds 300``):

- without the panel;
- with the panel read by a WebSocket client that draws nothing (the panel's own cost);
- with the panel and Debian's chromium (Playwright, headless) showing it: the Network page,
  then each Drive page in turn, at the panel's 10 updates a second.

Printed side by side: the master's SYNC timing (its worst delay and the periods it missed),
frames on the bus, the CPU this process used (the rig, the master and the panel: not the
browser's nor the reading client's), its resident memory and Python heap growth, and - with
the panel - the events it published, the deepest client queue seen, the clients dropped, the
browser's peak memory.
The browser runs through tests/browser.py's guard (this process capped, chromium watched).
No other CANopen tool has a web panel to compare with.

    python benchmarks/bench_panel.py --seconds 300
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import os
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from cobus.apps.panel import Panel, serve_alarms, serve_master  # noqa: E402
from cobus.apps.panel.drives import serve_cia402_drives  # noqa: E402
from cobus.blocks.alarms import AlarmHandler  # noqa: E402
from cobus.device import DictionaryBuilder, add_device, export_eds  # noqa: E402
from cobus.master import Master, loads_network  # noqa: E402
from cobus.od import DataType, ObjectDictionary  # noqa: E402
from cobus.runtime import AsyncNetwork  # noqa: E402
from cobus.sim import Rig  # noqa: E402

#: The runs side by side: no panel, the panel read by a client that draws nothing (its own
#: cost), the panel shown in chromium (with the browser's CPU on the same machine).
MODES = ("none", "socket", "browser")
IO_NODES = range(1, 120)
DRIVES = range(120, 128)
IO_NODE = """  io{n}:
    node_id: {n}
    eds: io.eds
    device_type: 0x191
    heartbeat_time: 500
    tpdo1: {{mapping: [counter, status], transmission_type: 255}}
"""
DRIVE_NODE = """  drive{n}:
    node_id: {n}
    eds: servo.eds
    device_type: 0x20192
    heartbeat_time: 100
"""


def _io_od() -> ObjectDictionary:
    b = DictionaryBuilder(device_name="bench io", vendor_id=0xC0B, device_type=0x191)
    b.variable(0x2000, "Counter", DataType.UNSIGNED16, access="ro", mappable=True)
    b.variable(0x2001, "Status", DataType.UNSIGNED8, access="ro", mappable=True)
    return b.build()


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


async def _run(folder: Path, seconds: float, mode: str) -> dict[str, Any]:
    """One run: ``mode`` "none" (no panel), "socket" (the panel, read by a WebSocket client
    that draws nothing: the panel's own cost) or "browser" (chromium showing it)."""
    with_panel = mode != "none"
    rig = Rig.loads(
        "bus: embedded\ndevices:\n"
        + "".join(f"  - {{node: {n}, kind: cia402_drive, name: drive{n}}}\n" for n in DRIVES)
    )
    channel = f"bench-panel-{os.getpid()}-{mode}"
    devices_net = AsyncNetwork(interface="virtual", channel=channel)
    master_net = AsyncNetwork(interface="virtual", channel=channel)
    await devices_net.connect()
    await master_net.connect()
    await rig.start(devices_net)
    (folder / "servo.eds").write_text(export_eds(rig.devices[DRIVES[0]].od))  # type: ignore[attr-defined]
    (folder / "io.eds").write_text(export_eds(_io_od()))
    ios = [add_device(devices_net, n, _io_od()) for n in IO_NODES]
    text = "master: {reset: broadcast, start: broadcast, sync_period: 20}\nnodes:\n"
    text += "".join(IO_NODE.format(n=n) for n in IO_NODES)
    text += "".join(DRIVE_NODE.format(n=n) for n in DRIVES)
    master = Master(master_net, loads_network(text, base_dir=folder))
    await master.boot(timeout=60)
    panel = None
    drives: list[Any] = []
    figures: dict[str, Any] = {}
    if with_panel:
        panel = Panel(port=0, clock=master_net.time)
        serve_master(panel, master)
        serve_alarms(panel, AlarmHandler(clock=master_net.time))
        drives = serve_cia402_drives(panel, master)
        for view in drives:
            view.start()
        await panel.start()
    gc.collect()
    tracemalloc.start()
    heap0 = tracemalloc.get_traced_memory()[0]
    rss0 = _rss_mb()
    sync = master_net.sync
    skipped0 = sync.skipped
    frames0 = master_net.frames_sent + master_net.frames_received
    deepest = 0
    browser_peak = 0.0
    events0 = panel.hub.seq if panel is not None else 0
    start = time.perf_counter()
    cpu0 = time.process_time()
    if mode == "browser":
        assert panel is not None
        deepest, browser_peak = await _browse(panel, seconds, [d.name for d in drives])
    elif mode == "socket":
        assert panel is not None
        deepest = await _read_socket(panel, seconds)
    else:
        await asyncio.sleep(seconds)
    elapsed = time.perf_counter() - start
    cpu = time.process_time() - cpu0
    heap1 = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    figures.update(
        sync_late_ms=sync.late_max * 1000,
        sync_missed=sync.skipped - skipped0,
        cpu_percent=100 * cpu / elapsed,
        frames_per_s=(master_net.frames_sent + master_net.frames_received - frames0) / elapsed,
        rss_growth_mb=_rss_mb() - rss0,
        heap_growth_mb=(heap1 - heap0) / 2**20,
        deepest_queue=deepest,
        dropped=panel.hub.dropped if panel is not None else 0,
        events=panel.hub.seq - events0 if panel is not None else 0,
        browser_mb=browser_peak,
    )
    if panel is not None:
        for view in drives:
            view.close()
        await panel.stop()
    await master.stop()
    for io in ios:
        io.close()
    await rig.stop()
    await master_net.disconnect()
    await devices_net.disconnect()
    return figures


_SOCKET = """
import asyncio, sys, aiohttp
url, seconds = {url!r}, {seconds!r}

async def main():
    loop = asyncio.get_running_loop()
    async with aiohttp.ClientSession() as http, http.ws_connect(url + "ws") as ws:
        print("ready", flush=True)
        end = loop.time() + seconds
        async for _msg in ws:
            if loop.time() > end:
                break

asyncio.run(main())
"""


async def _read_socket(panel: Panel, seconds: float) -> int:
    """A WebSocket client on the panel for ``seconds`` that reads everything and draws
    nothing, in a process of its own (its reading is not the panel's cost); the deepest
    client queue seen."""
    code = _SOCKET.format(url=panel.url, seconds=seconds)
    return await _watch_child(panel, [sys.executable, "-c", code])


async def _watch_child(panel: Panel, command: list[str]) -> int:
    """Run ``command`` (which prints a line once it reads the panel) to its end; the deepest
    client queue, sampled 10 times a second meanwhile."""
    deepest = 0
    child = await asyncio.create_subprocess_exec(*command, stdout=asyncio.subprocess.PIPE)
    assert child.stdout is not None
    try:
        await asyncio.wait_for(child.stdout.readline(), 120)
        while child.returncode is None:
            deepest = max([deepest, *(c.depth for c in panel.hub.clients)])
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(child.wait(), 0.1)
    finally:
        if child.returncode is None:
            child.kill()
            await child.wait()
    return deepest


_BROWSER = """
import sys, time
from pathlib import Path
from playwright.sync_api import sync_playwright
sys.path.insert(0, {root!r})
from tests.browser import CHROMIUM_ARGS, chromium_wrapper
url, seconds, hashes = {url!r}, {seconds!r}, {hashes!r}
with sync_playwright() as pw:
    browser = pw.chromium.launch(
        executable_path=chromium_wrapper(Path({folder!r})), headless=True, args=CHROMIUM_ARGS
    )
    page = browser.new_page(viewport={{"width": 1400, "height": 900}})
    page.goto(url)
    page.wait_for_selector("#link.up", timeout=60_000)
    print("ready", flush=True)
    end = time.monotonic() + seconds
    turn = 0
    while time.monotonic() < end:
        page.evaluate("h => {{ location.hash = h; }}", hashes[turn % len(hashes)])
        turn += 1
        page.wait_for_timeout(2000)
    browser.close()
"""


async def _browse(panel: Panel, seconds: float, drives: list[str]) -> tuple[int, float]:
    """Chromium on the panel for ``seconds`` (driven by Playwright in a process of its own,
    so that only the browser's requests reach this loop): the Network page, then each Drive
    page, two seconds each; the client queues sampled 10 times a second meanwhile."""
    from tests.browser import BrowserWatchdog, scratch

    hashes = ["#network", *(f"#drive-{d}" for d in drives)]
    with scratch() as folder, BrowserWatchdog(max_rss_mb=3000) as watchdog:
        code = _BROWSER.format(
            root=str(HERE.parent), url=panel.url, seconds=seconds, hashes=hashes, folder=folder
        )
        deepest = await _watch_child(panel, [sys.executable, "-c", code])
    return deepest, watchdog.peak_mb


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds per run")
    parser.add_argument(
        "--modes",
        default=",".join(MODES),
        help=f"the runs, comma-separated (default: {','.join(MODES)})",
    )
    args = parser.parse_args(argv if argv is not None else [])
    from tests.browser import CHROMIUM, capped

    print(f"\nOperator panel soak: 127 nodes (8 drives), SYNC 20 ms, {args.seconds:g} s per run")
    if not Path(CHROMIUM).exists():
        print("  (no chromium: apt install chromium; skipped)")
        return
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    wrong = [m for m in modes if m not in MODES]
    if wrong or not modes:
        parser.error(f"--modes {args.modes}: some of {', '.join(MODES)}")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for mode in modes:
            with capped(3000):  # (each run capped anew: 3 GB beyond what the last one left)
                runs.append(asyncio.run(_run(Path(tmp), args.seconds, mode)))
    rows = [
        ("SYNC: worst delay (with boot)", "sync_late_ms", "ms", ".1f"),
        ("SYNC: periods missed", "sync_missed", "", ".0f"),
        ("frames on the bus", "frames_per_s", "/s", ",.0f"),
        ("CPU of this process", "cpu_percent", "%", ".0f"),
        ("resident memory growth", "rss_growth_mb", "MB", ".1f"),
        ("Python heap growth", "heap_growth_mb", "MB", ".2f"),
        ("panel events", "events", "", ",.0f"),
        ("deepest client queue", "deepest_queue", "entries", ".0f"),
        ("clients dropped", "dropped", "", ".0f"),
        ("browser peak memory", "browser_mb", "MB", ".0f"),
    ]
    titles = {"none": "no panel", "socket": "panel + socket", "browser": "panel + chromium"}
    print(f"  {'':<30}" + "".join(f"{titles[m]:>18}" for m in modes))
    for label, key, unit, fmt in rows:
        cells = "".join(f"{run[key]:>18{fmt}}" for run in runs)
        print(f"  {label:<30}{cells} {unit}")


if __name__ == "__main__":
    main(sys.argv[1:])
