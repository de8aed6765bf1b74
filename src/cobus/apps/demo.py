"""``cobus demo``: the thesis bench, simulated, booted and run by the cobus master.

No hardware and nothing to configure: an embedded python-can virtual bus carries two networks,
one running the simulated rig (the ready rig ``thesis``: ZAPI ACE2 inverter, remote I/O with a
speed potentiometer, CiA 402 servo, EC motor, STÖBER MDS 5000), the other the cobus master and
a small application in the spirit of the thesis's PLC program:

- the master boots the CiA 301 nodes (I/O module and servo) the CiA 302 way, produces SYNC
  every 20 ms and supervises heartbeats and emergencies;
- the potentiometer sweeps slowly; the servo, run by :class:`cobus.profiles.AsyncDrive402`
  through the master's process image, is enabled and runs in profile velocity mode,
  backwards below the potentiometer's middle and forwards above, so it swings back and forth
  inside its limit switches;
- the ZAPI inverter, which has no boot-up and no heartbeat, is started by the master once
  SYNC runs; :class:`cobus.profiles.zapi.AsyncZapiDrive` answers each of its TPDO1 with the
  opposite handshake toggle and runs it clockwise at a speed that follows the potentiometer;
  when a cycle goes unanswered (a machine too busy), the inverter raises 248 CAN BUS KO and
  drops to pre-operational, the note says so, and the application acknowledges the alarm and
  has the master start it again (the note then counts the restarts).

At the end (``--duration``, Ctrl-C) it shuts down in order: the application, the drives
(switched off, their adapters closed), the master, the rig, the networks.

An alarm handler (:class:`cobus.blocks.AlarmHandler`, its history in the demo's working
folder) takes the master's and the ZAPI adapter's alarms.

The operator panel (:mod:`cobus.apps.panel`) serves the network, the alarms and the demo's
fault buttons on http://127.0.0.1:8047/ (another free port if that one is taken; a browser
opens where there is a display). A live table on the terminal shows each node too: NMT state,
the master's node state, heartbeat age (or why there is none), EMCY count and speed, and in
its note the drive's state, the newest error (alarm, EMCY with its text) or the master's last
event about the node.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import sys
import tempfile
from collections.abc import Awaitable, Callable, Mapping
from pathlib import Path
from typing import Any, TextIO

from cobus._args import seconds
from cobus.apps._run_cli import listen_address
from cobus.apps.panel.server import PanelError
from cobus.blocks.alarms import AlarmHandler
from cobus.blocks.param_manager import Parameterise
from cobus.device import export_eds
from cobus.errors import CobusError
from cobus.master import Master, loads_network
from cobus.master.events import (
    ErrorControlRestored,
    MasterEvent,
    NodeBooted,
    NodeEmergency,
    NodeEvent,
    NodeStateChanged,
    TpdoRestored,
)
from cobus.master.states import NodeState
from cobus.profiles import AsyncDrive402, DriveError
from cobus.profiles.zapi import AsyncZapiDrive, ZapiError
from cobus.proto.nmt import NmtState
from cobus.runtime import AsyncNetwork, SimulatedEventLoop
from cobus.runtime.emcy import Emergency
from cobus.runtime.remote import AsyncRemoteNode
from cobus.sim.rig import Rig, ready_rig

__all__ = ["DEMO_FAULTS", "Demo", "register", "run"]

IO, SERVO, ZAPI = 9, 10, 8
SYNC_PERIOD = 0.020
# The servo's speed follows the potentiometer around its middle: backwards below half,
# forwards above. The potentiometer sweeps symmetrically, so the servo swings back and forth:
# at most SERVO_MAX_SPEED * POT_PERIOD / 2 pi = 127 000 increments from its start, inside the
# rig's limit switches at +-200 000.
SERVO_MAX_SPEED = 40_000  # increments/s at either end of the potentiometer
ZAPI_MAX_HZ = 50.0  # the thesis's example speed: 50 Hz clockwise
POT_PERIOD = 20.0  # seconds for one sweep of the potentiometer


#: The faults the demo's panel offers (name -> what happens), so that a new user sees the
#: master's supervision and the alarm handling at work.
DEMO_FAULTS: Mapping[str, str] = {
    "unplug_io": "the I/O module loses its power: its heartbeat stops",
    "replug_io": "the I/O module's power returns: it boots and the master configures it again",
    "servo_fault": "the servo reports a drive fault (EMCY 7305h) and switches its power off",
    "servo_reset": "the servo's fault is reset and the servo enabled again: it moves",
    "zapi_handshake": "the application misses the ZAPI handshake for a moment: alarm 248",
    "bus_off": "the rig's CAN controller goes bus-off for 3 s: every node falls silent",
}

#: The panel's button for each of :data:`DEMO_FAULTS`.
FAULT_LABELS: Mapping[str, str] = {
    "unplug_io": "Unplug the I/O module",
    "replug_io": "Plug it back",
    "servo_fault": "Servo drive fault",
    "servo_reset": "Reset the servo and enable it",
    "zapi_handshake": "Break the ZAPI handshake",
    "bus_off": "Rig bus-off (3 s)",
}

#: The thesis bench's network file (also ``examples/networks/thesis.yml``); its EDS files are
#: exported from the simulated devices into the demo's working folder.
NETWORK_FILE = Path(__file__).with_name("thesis.yml")
#: The ZAPI inverter's parameters, brought to it at each boot as the thesis's parameter
#: manager did (it keeps them only when told "save" on 1010h sub 0).
ZAPI_PARAMETERS = """save: {subindex: 0}
parameters:
  main contactor voltage: 90   # % (20A8h)
"""


class Demo:
    """The demo's networks, rig, master and application; :meth:`run` drives it."""

    def __init__(self, workdir: Path, *, channel: str | None = None) -> None:
        self.workdir = workdir
        self.channel = channel or f"cobus-demo-{os.getpid()}-{id(self):x}"
        self.rig = Rig.load(ready_rig("thesis"))
        # (through the rig's FaultyBus: its controller can go bus-off)
        self.rig_net = self.rig.create_network(interface="virtual", channel=self.channel)
        self.master_net = AsyncNetwork(interface="virtual", channel=self.channel)
        self.master: Master | None = None
        #: Every rig node as the master's network sees it: heartbeats and emergencies.
        self.watch: dict[int, AsyncRemoteNode] = {}
        #: The text of the last master event about each node.
        self.events: dict[int, str] = {}
        self.started_at = 0.0
        #: The ZAPI inverter's adapter (it keeps the handshake), once the master runs.
        self.zapi: AsyncZapiDrive | None = None
        #: The servo's drive, once the application runs.
        self.servo: AsyncDrive402 | None = None
        #: Times the ZAPI handshake was lost (a cycle unanswered: a busy machine) and the
        #: application acknowledged the alarm and restarted the inverter.
        self.zapi_restarts = 0
        #: The alarms of the master and of the ZAPI adapter (history in ``workdir``).
        self.alarms: AlarmHandler | None = None
        #: The operator panel (:func:`run_demo` with ``panel``) and its address.
        self.panel: Any = None
        self.panel_url = ""
        #: For each drive the panel shows: whether the operator holds it (see ``_held``).
        self.panel_holds: dict[str, Callable[[], bool]] = {}
        self._tasks: list[asyncio.Task[None]] = []
        self._views: list[Any] = []  # the panel's drive views (closed with the drives)

    # -- life cycle
    async def start(self, before_boot: Callable[[Demo], Awaitable[None]] | None = None) -> None:
        """Connect both networks, start the rig, boot it with the master, start the
        application; ``before_boot`` runs once the master exists, before it boots (the panel
        attaches there)."""
        await self.rig_net.connect()
        await self.master_net.connect()
        await self.rig.start(self.rig_net)
        for node_id, name in ((IO, "io"), (SERVO, "servo"), (ZAPI, "zapi")):
            od = self.rig.devices[node_id].od  # type: ignore[attr-defined]
            (self.workdir / f"{name}.eds").write_text(export_eds(od))
        config = loads_network(NETWORK_FILE.read_text(), base_dir=self.workdir)
        self.watch = {n: self.master_net.add_remote(n) for n in self.rig.devices}
        self.started_at = self.master_net.time()
        self.master = Master(self.master_net, config)
        self.master.add_listener(self._on_master_event)
        self.alarms = AlarmHandler(self.workdir / "alarms.sqlite", clock=self.master_net.time)
        self.alarms.attach_master(self.master, emcy_tables={"servo": "cia402"})
        (self.workdir / "zapi-parameters.yml").write_text(ZAPI_PARAMETERS)
        self.master.add_boot_step("zapi", Parameterise(self.workdir / "zapi-parameters.yml"))
        if before_boot is not None:
            await before_boot(self)
        await self.master.boot(timeout=10)
        self.zapi = AsyncZapiDrive(self.master, "zapi")
        self.alarms.attach_zapi(self.zapi)
        self.servo = AsyncDrive402(self.master.node("servo"))  # RPDO4: controlword + velocity
        self._tasks = [
            asyncio.create_task(self._sweep_potentiometer()),
            asyncio.create_task(self._run_servo()),
            asyncio.create_task(self._run_zapi()),
        ]

    async def stop(self) -> None:
        """Shut down in order - the application, the drives (switched off, their adapters
        closed), the master, the rig, both networks - so that nothing runs into a network
        that is already closed."""
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks = []
        for view in self._views:
            view.close()
        if self.zapi is not None:
            self.zapi.release()  # set-point 0, power stage off, contactor open
            self.zapi.close()
        if self.servo is not None:
            # (best effort: a transfer cut short by the cancelled application may leave a
            # late answer behind that this one refuses; the rig stops next anyway)
            with contextlib.suppress(CobusError, TimeoutError):
                await self.servo.disable(timeout=1.0)
            self.servo.close()
        if self.master is not None:
            await self.master.stop()
        if self.alarms is not None:
            self.alarms.close()
        await self.rig.stop()
        await self.master_net.disconnect()
        await self.rig_net.disconnect()
        self.rig.close_bus()

    # -- the faults
    async def fault(self, name: str) -> str:
        """Inject one of :data:`DEMO_FAULTS`; what was done. ValueError for another name."""
        if name not in DEMO_FAULTS:
            raise ValueError(f"fault {name!r}: one of {', '.join(DEMO_FAULTS)}")
        if name == "unplug_io":
            self.rig.inject(IO, "power_loss")
        elif name == "replug_io":
            self.rig.inject(IO, "power_return")
        elif name == "servo_fault":
            self.rig.inject(SERVO, "drive_fault", code=0x7305)
        elif name == "servo_reset":
            if self.servo is None:
                raise ValueError("the servo's application has not started yet")
            if self._held("servo"):
                raise ValueError(
                    "the operator holds the servo: reset and enable it on its Drive page (or "
                    "give it back to the application first)"
                )
            await self.servo.fault_reset(timeout=2.0)
            await self.servo.enable(timeout=2.0)
        elif name == "zapi_handshake":
            if self.zapi is None:
                raise ValueError("the ZAPI adapter has not started yet")
            self.zapi.answering = False
            await asyncio.sleep(0.2)  # ten SYNC periods unanswered
            self.zapi.answering = True
        elif name == "bus_off":
            self.rig.inject(None, "bus_off", duration=3.0)
        return DEMO_FAULTS[name]

    # -- the application
    def _pot(self) -> float:
        """The potentiometer as the master reads it, 0.0 .. 1.0."""
        assert self.master is not None
        try:
            return max(0.0, min(1.0, float(self.master.inputs["io.pot"]) / 32767))
        except Exception:
            return 0.0

    async def _sweep_potentiometer(self) -> None:
        io = self.rig.devices[IO]
        t0 = self.rig_net.time()
        while True:
            phase = (self.rig_net.time() - t0) / POT_PERIOD
            io.set_potentiometer(0.5 - 0.5 * math.cos(2 * math.pi * phase))  # type: ignore[attr-defined]
            await asyncio.sleep(0.1)

    @property
    def zapi_cycles(self) -> int:
        """The ZAPI handshake cycles answered so far."""
        return self.zapi.cycles if self.zapi is not None else 0

    def _held(self, name: str) -> bool:
        """Whether the operator took the drive ``name`` over on the panel (the application
        then leaves it alone until it is given back)."""
        holds = self.panel_holds.get(name)
        return holds is not None and holds()

    async def _run_servo(self) -> None:
        servo = self.servo
        assert servo is not None
        await servo.enable()
        while True:
            if self._held("servo"):
                await asyncio.sleep(0.1)
                continue
            velocity = round((self._pot() - 0.5) * 2 * SERVO_MAX_SPEED)
            # a faulted drive stays so (the table shows its EMCY): no reset behind the user;
            # and the operator may have taken the servo over meanwhile: asked again right here
            if not self._held("servo"):
                with contextlib.suppress(DriveError):
                    await servo.set_velocity(velocity, wait=False)
            await asyncio.sleep(0.1)

    async def _run_zapi(self) -> None:
        """Run the inverter at the potentiometer's speed; when its handshake is lost (a cycle
        went unanswered: alarm 248 CAN BUS KO, the inverter drops to pre-operational and the
        master, with no heartbeat to tell it, still counts it operational) acknowledge the
        alarm and have the master start it again, as the thesis's program does."""
        zapi = self.zapi
        assert zapi is not None
        while True:
            if self._held("zapi"):
                await asyncio.sleep(0.1)
                continue
            if zapi.alarm or (zapi.cycles and not zapi.handshake_running):
                why = f"alarm {zapi.alarm} {zapi.alarm_text}" if zapi.alarm else "no TPDO1"
                self.events[ZAPI] = f"handshake lost ({why}): acknowledging, restarting"
                try:
                    await zapi.acknowledge(timeout=2.0)
                except ZapiError as exc:
                    self.events[ZAPI] = str(exc)
                    await asyncio.sleep(1.0)
                    continue
                self.zapi_restarts += 1
                self.events[ZAPI] = (
                    f"handshake lost {self.zapi_restarts}x, restarted at t = {self.elapsed():.1f} s"
                )
            if not self._held("zapi"):  # (the acknowledge above may take seconds)
                zapi.run(round(self._pot() * ZAPI_MAX_HZ, 2))
            await asyncio.sleep(0.1)

    def _on_master_event(self, event: MasterEvent) -> None:
        """Keep the master's last word on a node's problem until the problem is over."""
        if not isinstance(event, NodeEvent) or isinstance(event, NodeEmergency):
            return  # emergencies show from the node's own EMCY log
        over = isinstance(event, ErrorControlRestored | TpdoRestored) or (
            isinstance(event, NodeStateChanged) and event.new is NodeState.OPERATIONAL
        )
        if over:
            self.events.pop(event.node_id, None)
        elif not isinstance(event, NodeStateChanged) and not (
            isinstance(event, NodeBooted) and event.expected
        ):
            self.events[event.node_id] = str(event)

    # -- the table
    def elapsed(self) -> float:
        """Seconds since the demo started."""
        return self.master_net.time() - self.started_at

    def sync_status(self) -> str:
        """How well the master keeps SYNC: a busy host delays it, and the drives see it."""
        sync = self.master_net.sync
        head = f"SYNC every {SYNC_PERIOD * 1000:.0f} ms"
        worst = f"worst delay {sync.late_max * 1000:.1f} ms"
        if sync.skipped:
            return (
                f"{head}: {sync.skipped} period(s) without SYNC, {worst}: this machine was too "
                "busy to run the master in time"
            )
        return f"{head}: on time ({worst})"

    def rows(self) -> list[dict[str, str]]:
        """One row of text per rig node for the table (see the module docstring)."""
        now = self.master_net.time()
        managed = self.master.nodes if self.master is not None else {}
        rows = []
        for node_id, device in sorted(self.rig.devices.items()):
            status = device.status()
            node = managed.get(node_id)
            seen = self.watch[node_id]
            rows.append(
                {
                    "node": str(node_id),
                    "name": str(status.get("name", "")),
                    "kind": str(status.get("kind", "")),
                    "nmt": str(status.get("nmt") or status.get("state") or "-").replace("_", "-"),
                    "master": f"{int(node.state)} {node.state.text}" if node else "(not managed)",
                    "heartbeat": _heartbeat(seen, now),
                    "emcy": str(seen.emcy.count),
                    "speed": _speed(status),
                    "note": _note(status, seen.emcy.active, self.events.get(node_id)),
                }
            )
        return rows


def _heartbeat(node: AsyncRemoteNode, now: float) -> str:
    """How recent the node's heartbeat is, or why there is none to show."""
    nmt = node.nmt
    if nmt.last_heard is None:
        return "none heard"
    if nmt.state is NmtState.INITIALISING:
        return "boot-up only, no heartbeat"
    return f"{(now - nmt.last_heard) * 1000:.0f} ms ago"


_COLUMNS = ("node", "name", "kind", "nmt", "master", "heartbeat", "emcy", "speed", "note")


def _speed(status: dict[str, Any]) -> str:
    for key, unit in (("speed_hz", "Hz"), ("speed_rpm", "rpm"), ("velocity", "inc/s")):
        if key in status:
            return (
                f"{float(status[key]):.1f} {unit}" if unit != "inc/s" else f"{status[key]} {unit}"
            )
    if "potentiometer" in status:
        return f"pot {float(status['potentiometer']) * 100:.0f}%"
    return ""


def _note(status: dict[str, Any], active: list[Emergency], event: str | None) -> str:
    """What needs attention, most telling first: the device's own alarm text, the newest
    error it reported by EMCY (with the code's text), its fault code or event, the master's
    word on it; else the drive's state."""
    if status.get("alarm_text"):
        return str(status["alarm_text"])
    if active:
        return str(active[-1])
    if status.get("error_code"):
        return f"fault {status['error_code']}"
    if status.get("event_text") not in (None, "", "no event"):
        return str(status["event_text"])
    if event:
        return event
    if status.get("kind") == "cia402_drive":
        return str(status.get("state", ""))
    return ""


def render(
    rows: list[dict[str, str]], now: float, *, title: str = "cobus demo", status: str = ""
) -> str:
    """The node table as text, under a title line and a ``status`` line."""
    widths = {c: max([len(c)] + [len(r[c]) for r in rows]) for c in _COLUMNS}
    lines = [f"{title} — t = {now:7.2f} s   (Ctrl-C to stop)"]
    if status:
        lines.append(status)
    lines.append("")
    lines.append("  ".join(c.upper().ljust(widths[c]) for c in _COLUMNS).rstrip())
    lines.append("  ".join("-" * widths[c] for c in _COLUMNS))
    for row in rows:
        lines.append("  ".join(row[c].ljust(widths[c]) for c in _COLUMNS).rstrip())
    return "\n".join(lines)


async def start_panel(demo: Demo, host: str, port: int, out: TextIO, **options: Any) -> Any:
    """The operator panel for ``demo`` (its master, alarms and fault buttons), started on
    ``host``:``port``, or on any free port if that one is taken (``out`` is told);
    ``options`` go to :class:`~cobus.apps.panel.Panel` (``token``...)."""
    from cobus.apps.panel import (
        Panel,
        PanelError,
        serve_alarms,
        serve_master,
        serve_parameters,
        serve_trace,
    )

    assert demo.master is not None and demo.alarms is not None

    async def fault(message: Mapping[str, Any]) -> str:
        name = message.get("fault")
        if not isinstance(name, str):
            raise ValueError(f"fault: one of {', '.join(DEMO_FAULTS)}")
        return await demo.fault(name)

    master, alarms = demo.master, demo.alarms

    def build(port: int) -> tuple[Panel, list[Any]]:
        panel = Panel(
            host=host, port=port, clock=demo.master_net.time, title="cobus demo", **options
        )
        views = [
            serve_master(panel, master),
            serve_alarms(panel, alarms),
            serve_trace(panel, demo.master_net, master.config),
        ]
        serve_parameters(panel, master)
        panel.command("demo.fault", fault, writes=True, help="inject one of the demo's faults")
        panel.hub.info["faults"] = [
            {"name": name, "label": FAULT_LABELS[name], "text": text}
            for name, text in DEMO_FAULTS.items()
        ]
        return panel, views

    panel, views = build(port)
    try:
        await panel.start()
    except PanelError as exc:
        for view in views:
            view.close()
        if port == 0 or not _in_use(host, port):
            raise
        out.write(f"cobus demo: {exc}; the panel takes another port\n")
        panel, views = build(0)
        try:
            await panel.start()
        except PanelError:
            for view in views:
                view.close()
            raise
    demo._views.extend(views)
    return panel


def _in_use(host: str, port: int) -> bool:
    """Whether ``host``:``port`` cannot be bound because something else has it (and not
    because the address is not this machine's)."""
    import errno
    import socket

    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(family) as probe:
            probe.bind((host, port))
    except OSError as exc:
        return exc.errno == errno.EADDRINUSE
    return False


#: The servo's motor temperature: 2000h in 0.1 degC (the simulated drive's object).
SERVO_TEMPERATURE = (0x2000, 0, 0.1)


def attach_drives(demo: Demo, panel: Any) -> None:
    """The servo's and the ZAPI inverter's Drive pages; the application commands both until
    the operator takes one over there."""
    from cobus.apps.panel import serve_drive

    for name, drive, temperature in (
        ("servo", demo.servo, SERVO_TEMPERATURE),
        ("zapi", demo.zapi, None),
    ):
        if drive is None:
            continue
        view = serve_drive(panel, name, drive, holder="application", temperature=temperature)
        view.start()
        demo.panel_holds[name] = view.panel_holds
        demo._views.append(view)


def _display() -> bool:
    """Whether a browser can be opened here (a desktop session)."""
    return bool(
        os.environ.get("DISPLAY")
        or os.environ.get("WAYLAND_DISPLAY")
        or sys.platform in ("darwin", "win32")
    )


async def run_demo(
    *,
    duration: float | None,
    refresh: float,
    out: TextIO,
    clear: bool,
    workdir: Path,
    on_tick: Callable[[Demo], None] | None = None,
    panel: tuple[str, int] | None = None,
    open_browser: bool = False,
) -> Demo:
    """Run the demo until ``duration`` seconds have passed (None: until cancelled), with the
    operator panel on ``panel`` (host, port) if given (``demo.panel`` then)."""
    demo = Demo(workdir)
    served: list[Any] = []

    async def attach(d: Demo) -> None:
        assert panel is not None
        served.append(await start_panel(d, panel[0], panel[1], out))
        url = served[0].url
        demo.panel_url = url
        out.write(f"cobus demo: the operator panel is at {url}\n")
        if served[0].reads_need_token:
            out.write("cobus demo: reading it needs the token in that address\n")
        out.flush()
        if open_browser and _display():
            import webbrowser

            await asyncio.get_running_loop().run_in_executor(None, webbrowser.open, url)

    try:
        await demo.start(before_boot=attach if panel is not None else None)
        demo.panel = served[0] if served else None
        if served:
            attach_drives(demo, served[0])
        end = None if duration is None else demo.master_net.time() + duration - 1e-6
        while end is None or demo.master_net.time() < end:
            await asyncio.sleep(refresh)
            title = "cobus demo" + (f" — panel {demo.panel_url}" if demo.panel_url else "")
            text = render(demo.rows(), demo.elapsed(), title=title, status=demo.sync_status())
            out.write(("\x1b[H\x1b[2J" if clear else "\n") + text + "\n")
            out.flush()
            if on_tick is not None:
                on_tick(demo)
    finally:
        for server in served:
            await server.stop()
        await demo.stop()
    return demo


def register(sub: Any) -> None:
    """Add ``cobus demo`` to the command line's sub-commands."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "demo",
        help="run the simulated thesis rig, booted and supervised by the cobus master",
        description=(
            "The thesis bench with no hardware: an embedded python-can virtual bus runs the "
            "simulated rig (ZAPI ACE2 inverter, remote I/O with a speed potentiometer, CiA 402 "
            "servo, EC motor, STÖBER MDS 5000); the cobus master boots and supervises it, and a "
            "small application runs the servo and the ZAPI inverter at a speed that follows the "
            "potentiometer. The operator panel (http://127.0.0.1:8047/) shows the network and "
            "the alarms, with buttons that inject faults; a live table shows every node on the "
            "terminal too."
        ),
    )
    parser.add_argument("--duration", type=seconds, help="stop after this many seconds")
    parser.add_argument("--refresh", type=float, default=0.5, help="seconds between tables")
    parser.add_argument(
        "--simulated",
        action="store_true",
        help="run on the simulated clock (as fast as the machine goes; for tests)",
    )
    parser.add_argument("--no-clear", action="store_true", help="print tables one after the other")
    parser.add_argument(
        "--listen",
        type=listen_address,
        default=("127.0.0.1", 8047),
        metavar="HOST:PORT",
        help="where the operator panel listens (default 127.0.0.1:8047, another free port if "
        "taken; beyond 127.0.0.1, reading it and its buttons need the token its address "
        "carries)",
    )
    parser.add_argument("--no-panel", action="store_true", help="no operator panel")
    parser.add_argument(
        "--no-browser", action="store_true", help="do not open the panel in a browser"
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Run ``cobus demo`` with its parsed arguments; the exit status."""
    if args.refresh <= 0:
        print("cobus demo: --refresh must be a positive number of seconds", file=sys.stderr)
        return 2
    clear = not args.no_clear and sys.stdout.isatty()
    with tempfile.TemporaryDirectory(prefix="cobus-demo-") as tmp:
        coro = run_demo(
            duration=args.duration,
            refresh=args.refresh,
            out=sys.stdout,
            clear=clear,
            workdir=Path(tmp),
            # (on the simulated clock the panel would see time race: none there)
            panel=None if args.no_panel or args.simulated else args.listen,
            open_browser=not args.no_browser and sys.stdout.isatty(),
        )
        if args.simulated:
            if args.duration is None:
                print("cobus demo: --simulated needs --duration", file=sys.stderr)
                coro.close()
                return 2
            loop = SimulatedEventLoop()
            try:
                loop.run_until_complete(coro)
            finally:
                loop.close()
        else:
            try:
                asyncio.run(coro)
            except KeyboardInterrupt:
                print("\ncobus demo: stopped")
            except PanelError as exc:
                print(f"cobus demo: {exc} (--no-panel runs without it)", file=sys.stderr)
                return 2
    return 0
