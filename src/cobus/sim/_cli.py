"""``cobus sim RIG``: run a rig's simulated devices on a bus until Ctrl-C.

A master in another process (cobus, python-canopen, a PLC) talks to them over the bus: a real
interface, or python-can-remote on the loopback (``--interface remote --channel
ws://127.0.0.1:54701/``). RIG is a rig file or the name of a rig cobus ships (``thesis``).

From another shell, while it runs (its control socket, see ``cobus.sim._control``):

    cobus sim inject 10 drive_fault code=0x7305   # a device's fault, parameters as KEY=VALUE
    cobus sim inject bus frame_loss rate=0.1      # a bus fault
    cobus sim faults 10                           # what node 10 can be given
    cobus sim status --json                       # every device's state

Exit codes: 0 stopped by Ctrl-C or SIGTERM (inject, faults, status: done), 1 the bus cannot be
used (no simulation answers), 2 a bad rig file, a bad control path or bad usage (a fault or a
parameter the device does not know).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from cobus._args import seconds, seconds_or_zero
from cobus.errors import CobusError
from cobus.proto.lss import UNCONFIGURED
from cobus.runtime.errors import BusOpenError
from cobus.sim.faults import fault_catalogue
from cobus.sim.rig import Rig, ready_rig, ready_rigs, resolve_kind

__all__ = ["format_table", "register"]

_FIRST = ("node_id", "name", "kind", "powered", "nmt", "state", "faults")


def register(sub: Any) -> None:
    """Add ``cobus sim ...`` to the top-level sub-command parser."""
    sim: argparse.ArgumentParser = sub.add_parser(
        "sim",
        help="run simulated devices (a rig file) on a CAN bus until Ctrl-C",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sim.add_argument(
        "rig",
        help=f"rig YAML file, or a ready rig: {', '.join(ready_rigs()) or 'none'}; or inject, "
        "faults, status to talk to a running simulation",
    )
    sim.add_argument(
        "words",
        nargs="*",
        metavar="ARG",
        help="inject: NODE (or bus) FAULT [KEY=VALUE ...]; faults: [NODE]",
    )
    control = sim.add_mutually_exclusive_group()
    control.add_argument(
        "--control",
        type=Path,
        metavar="PATH",
        help="the control socket, a Unix socket only its owner can use (default: "
        "cobus-sim.sock in $XDG_RUNTIME_DIR or the temporary folder)",
    )
    control.add_argument(
        "--no-control",
        action="store_true",
        help="run without a control socket (no faults from another shell)",
    )
    sim.add_argument("--json", action="store_true", help="inject, faults, status: as JSON")
    sim.add_argument("--interface", "-i", help="python-can interface (overrides the rig file)")
    sim.add_argument("--channel", "-c", help="python-can channel (overrides the rig file)")
    sim.add_argument("--bitrate", "-b", type=int, help="bit rate in bit/s")
    sim.add_argument(
        "--status-every",
        type=seconds_or_zero,
        default=2.0,
        metavar="SECONDS",
        help="print the status table this often (0: never; default 2)",
    )
    sim.add_argument(
        "--duration", type=seconds, metavar="SECONDS", help="stop after this many seconds"
    )
    sim.add_argument(
        "--list-faults",
        action="store_true",
        help="list the faults each device and the bus can be given, and exit",
    )
    sim.set_defaults(handler=_run)


def _rig_path(name: str) -> Path:
    path = Path(name)
    if path.exists() or path.suffix or "/" in name or "\\" in name:
        return path
    return ready_rig(name)


_CONTROL = ("inject", "faults", "status")


def _run(args: argparse.Namespace) -> int:
    if args.rig in _CONTROL:
        return _control(args)
    if args.words:
        print(f"cobus sim: unexpected {' '.join(args.words)!r} after the rig", file=sys.stderr)
        return 2
    try:
        rig = Rig.load(_rig_path(args.rig))
        if args.list_faults:
            _list_faults(rig, sys.stdout)
            return 0
        return asyncio.run(_serve(rig, args))
    except BusOpenError as exc:
        print(f"cobus sim: {exc}", file=sys.stderr)
        return 1
    except CobusError as exc:
        print(f"cobus sim: {exc}", file=sys.stderr)
        return 2


def _list_faults(rig: Rig, out: TextIO) -> None:
    for spec in rig.specs:
        cls = resolve_kind(spec.kind)
        node = "unconfigured" if spec.node == UNCONFIGURED else f"node {spec.node}"
        print(f"{node} {spec.name or ''} ({spec.kind}):".replace("  ", " "), file=out)
        for name, text in fault_catalogue(cls).items():
            print(f"  {name:18} {text}", file=out)
    print("bus:", file=out)
    for name, text in fault_catalogue().items():
        print(f"  {name:18} {text}", file=out)


async def _serve(rig: Rig, args: argparse.Namespace) -> int:
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    where = " ".join(str(v) for v in (args.interface or rig.bus_spec.interface, args.channel) if v)
    async with (
        rig.running(interface=args.interface, channel=args.channel, bitrate=args.bitrate) as net,
        _controlled(rig, args) as control,
    ):
        bus = where or f"the configured bus ({net.bus.channel_info})"
        print(
            f"cobus sim: running {len(rig.devices)} device(s) on {bus}; Ctrl-C stops",
            flush=True,
        )
        if control is not None:
            option = "" if args.control is None else f" --control {control}"
            print(f"cobus sim: faults from another shell: cobus sim inject{option} ...", flush=True)
        started = loop.time()
        period = args.status_every if args.status_every and args.status_every > 0 else None
        end = None if args.duration is None else started + args.duration
        next_status = None if period is None else started + period
        while not stop.is_set():
            now = loop.time()
            if end is not None and now >= end:
                break
            if next_status is not None and now >= next_status:
                next_status += period or 0.0
                print(format_table(rig.status()), flush=True)
                bus_line = ", ".join(f"{k} {v}" for k, v in rig.bus_status().items())
                print(f"bus: {bus_line}", flush=True)
                continue
            wake = [t for t in (end, next_status) if t is not None]
            timeout = min(wake) - now if wake else None
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), timeout)
    print("cobus sim: stopped", flush=True)
    return 0


@contextlib.asynccontextmanager
async def _controlled(rig: Rig, args: argparse.Namespace) -> Any:
    """The control socket while the rig runs (None when the default one is another
    simulation's: this one runs without); removed at the end."""
    from cobus.sim._control import ControlError, default_path, serve

    if args.no_control:
        yield None
        return
    path = args.control or default_path()
    try:
        server = await serve(rig, path)
    except (ControlError, OSError) as exc:
        if args.control is not None:
            raise
        print(f"cobus sim: no control socket: {exc}", file=sys.stderr, flush=True)
        yield None
        return
    try:
        yield path
    finally:
        server.close()
        with contextlib.suppress(OSError):
            path.unlink()


def _control(args: argparse.Namespace) -> int:
    """``cobus sim inject|faults|status``: ask the running simulation."""
    import json

    from cobus.sim._control import ControlError, ask, default_path, parse_value

    path = args.control or default_path()
    words = list(args.words)
    request: dict[str, Any] = {"op": args.rig}
    if args.rig == "inject":
        if len(words) < 2:
            print("cobus sim inject: give NODE (or bus) and FAULT [KEY=VALUE ...]", file=sys.stderr)
            return 2
        node, fault, *pairs = words
        params: dict[str, Any] = {}
        for pair in pairs:
            key, sep, value = pair.partition("=")
            if not sep or not key:
                print(f"cobus sim inject: {pair!r}: write KEY=VALUE (code=0x7305)", file=sys.stderr)
                return 2
            params[key] = parse_value(value)
        request.update(node=_node_of(node), fault=fault, params=params)
    elif args.rig == "faults":
        if len(words) > 1:
            print("cobus sim faults: give at most a NODE (none: the bus)", file=sys.stderr)
            return 2
        request["node"] = _node_of(words[0]) if words else None
    elif words:
        print("cobus sim status: takes no arguments", file=sys.stderr)
        return 2
    try:
        answer = ask(path, request)
    except ControlError as exc:
        code = 2 if exc.refused else 1  # a wrong request, or no simulation to ask
        if args.json:
            print(json.dumps({"ok": False, "error": str(exc), "exit": code}))
        print(f"cobus sim {args.rig}: {exc}", file=sys.stderr)
        return code
    if args.json:
        print(json.dumps(answer, default=str))
    elif args.rig == "inject":
        print(answer["text"])
    elif args.rig == "faults":
        for name, text in answer["faults"].items():
            print(f"{name:18} {text}")
    else:
        print(format_table(answer["devices"]))
        print("bus: " + ", ".join(f"{k} {v}" for k, v in answer["bus"].items()))
    return 0


def _node_of(word: str) -> int | str | None:
    """A node-ID, a device's name, or None for ``bus``."""
    if word == "bus":
        return None
    try:
        return int(word, 0) if word.lower().startswith("0x") else int(word)
    except ValueError:
        return word


def _cell(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, list | tuple):
        return ",".join(str(v) for v in value) or "-"
    if value is None or value == "":
        return "-"
    return str(value)


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """A plain text table of status rows: the common columns, then the rest as key=value."""
    header = ["node", "name", "kind", "power", "nmt", "state", "faults", "values"]
    lines = [header]
    for row in rows:
        rest = " ".join(f"{k}={_cell(v)}" for k, v in row.items() if k not in _FIRST)
        lines.append([_cell(row.get(k)) for k in _FIRST] + [rest])
    widths = [max(len(line[i]) for line in lines) for i in range(len(header) - 1)]
    out = []
    for line in lines:
        cells = [c.ljust(w) for c, w in zip(line, widths, strict=False)]
        out.append("  ".join([*cells, line[-1]]).rstrip())
    return "\n".join(out)
