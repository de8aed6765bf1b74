"""Find the nodes on a bus and what they are: ``cobus scan``.

    cobus scan -i socketcan -c can0               # listen, then ask 1-127 for 1000h; a table
    cobus scan --nodes 1-32 --timeout 0.05 --json

First it listens (``--listen`` seconds) for boot-ups and heartbeats, then it reads 1000h
(device type) from every node-ID (16 at a time; a progress bar on a terminal), and of every
node that answers: the identity 1018h, the names 1008h-100Ah and the error history 1003h.
Exit codes: 0 done (also when none answered), 1 the bus cannot be used, 2 bad usage.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from cobus._args import add_bus_options, bus_options, seconds

__all__ = ["FoundNode", "register", "scan"]

_STATES = {0x00: "BOOTUP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE_OPERATIONAL"}
_IDENTITY = ("vendor_id", "product_code", "revision", "serial")
_NAMES = {0x1008: "device_name", 0x1009: "hardware_version", 0x100A: "software_version"}


@dataclass
class FoundNode:
    """A node the scan found: what it sent unasked and what it answered."""

    node_id: int
    #: The NMT state its heartbeat or boot-up said (None: it sent neither).
    heard: str | None = None
    device_type: int | None = None
    identity: dict[str, int] = field(default_factory=dict)
    device_name: str | None = None
    hardware_version: str | None = None
    software_version: str | None = None
    #: The pre-defined error field 1003h, newest first.
    errors: list[int] = field(default_factory=list)

    @property
    def profile(self) -> int | None:
        """The device profile number (CiA 402, 401...) from the device type."""
        return None if self.device_type is None else self.device_type & 0xFFFF

    def to_dict(self) -> dict[str, Any]:
        """Plain data (``--json``)."""
        return {
            "node_id": self.node_id,
            "heard": self.heard,
            "device_type": self.device_type,
            "profile": self.profile,
            "identity": dict(self.identity),
            "device_name": self.device_name,
            "hardware_version": self.hardware_version,
            "software_version": self.software_version,
            "errors": list(self.errors),
        }


async def scan(
    network: Any,
    nodes: Iterable[int] = range(1, 128),
    *,
    timeout: float = 0.1,
    listen: float = 0.5,
    parallel: int = 16,
    progress: Callable[[int, int], object] | None = None,
) -> list[FoundNode]:
    """Scan ``nodes`` on an :class:`~cobus.runtime.AsyncNetwork`: listen ``listen`` seconds
    for boot-ups and heartbeats, read 1000h of each node (``timeout`` per answer, ``parallel``
    at once), then the identity, names and error history of those that answered.
    ``progress(done, total)`` is called as node-IDs are asked. The nodes found, by node-ID."""
    from cobus.errors import CobusError
    from cobus.proto.sdo import SdoTimeoutError

    wanted = sorted(set(nodes))
    found: dict[int, FoundNode] = {}
    heard: dict[int, str] = {}

    def on_frame(frame: Any, now: float) -> None:
        cob = frame.cob_id
        if 0x701 <= cob <= 0x77F and len(frame.data) == 1 and not frame.rtr:
            heard[cob - 0x700] = _STATES.get(frame.data[0] & 0x7F, f"{frame.data[0]:02X}h")

    sub = network.subscribe_all(on_frame)
    try:
        await asyncio.sleep(listen)
        gate = asyncio.Semaphore(max(1, parallel))
        done = 0

        async def probe(node_id: int) -> None:
            nonlocal done
            async with gate:
                node = _remote(network, node_id, timeout)
                try:
                    data = await node.sdo.upload(0x1000, 0)
                except SdoTimeoutError:
                    data = None
                except CobusError:
                    data = b""  # it answered (refused): it is there
                finally:
                    done += 1
                    if progress is not None:
                        progress(done, len(wanted))
                if data is None:
                    if node_id in heard:
                        found[node_id] = FoundNode(node_id)
                    return
                info = found[node_id] = FoundNode(node_id)
                if data:
                    info.device_type = int.from_bytes(data[:4].ljust(4, b"\0"), "little")
                await _details(node, info)

        await asyncio.gather(*(probe(n) for n in wanted))
    finally:
        sub.cancel()
    for node_id, state in heard.items():
        if node_id in found:
            found[node_id].heard = state
        elif node_id in wanted:
            found[node_id] = FoundNode(node_id, heard=state)
    return [found[n] for n in sorted(found)]


def _remote(network: Any, node_id: int, timeout: float) -> Any:
    existing = network.remotes.get(node_id)
    if existing is not None:
        return existing
    return network.add_remote(node_id, sdo_timeout=timeout)


async def _details(node: Any, info: FoundNode) -> None:
    from cobus.errors import CobusError

    async def read(index: int, sub: int) -> bytes | None:
        try:
            data: bytes = await node.sdo.upload(index, sub)
            return data
        except CobusError:
            return None

    for sub, name in enumerate(_IDENTITY, 1):
        data = await read(0x1018, sub)
        if data:
            info.identity[name] = int.from_bytes(data[:4].ljust(4, b"\0"), "little")
    for index, name in _NAMES.items():
        data = await read(index, 0)
        if data is not None:
            setattr(info, name, data.split(b"\0", 1)[0].decode("latin-1").strip())
    count = await read(0x1003, 0)
    if count:
        for sub in range(1, min(count[0], 254) + 1):
            data = await read(0x1003, sub)
            if data:
                info.errors.append(int.from_bytes(data[:4].ljust(4, b"\0"), "little"))


# ------------------------------------------------------------------------------ command


def _nodes(text: str) -> list[int]:
    out: set[int] = set()
    for part in text.split(","):
        low, sep, high = part.partition("-")
        try:
            first, last = int(low, 0), int(high, 0) if sep else int(low, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: node-IDs as 1-127 or 2,5,10-12") from None
        if not 1 <= first <= last <= 127:
            raise argparse.ArgumentTypeError(f"{part!r}: node-IDs 1-127")
        out.update(range(first, last + 1))
    return sorted(out)


def register(sub: Any) -> None:
    """Add ``cobus scan``."""
    p = sub.add_parser(
        "scan",
        help="find the nodes on the bus: device type, identity, names, error history",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--nodes", type=_nodes, default=list(range(1, 128)), help="e.g. 1-32,64")
    p.add_argument("--timeout", type=seconds, default=0.1, help="seconds per answer (0.1)")
    p.add_argument("--listen", type=seconds, default=0.5, help="seconds to listen first (0.5)")
    p.add_argument("--json", action="store_true", help="print JSON")
    add_bus_options(p)
    p.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn
    from rich.table import Table

    from cobus.runtime import Network

    quiet = args.json or not sys.stderr.isatty()
    bar = None
    if not quiet:
        bar = Progress(
            TextColumn("scanning"),
            BarColumn(),
            MofNCompleteColumn(),
            console=Console(stderr=True),
            transient=True,
        )
    try:
        with Network(**bus_options(args)) as net:
            task = bar.add_task("scan", total=len(args.nodes)) if bar is not None else None
            if bar is not None:
                bar.start()

            def progress(done: int, total: int) -> None:
                if bar is not None:
                    bar.update(task, completed=done)  # type: ignore[arg-type]

            found = net.run(
                scan(
                    net.aio,
                    args.nodes,
                    timeout=args.timeout,
                    listen=args.listen,
                    progress=progress,
                )
            )
    except Exception as exc:
        if type(exc).__module__.startswith(("can", "cobus")):
            print(f"cobus scan: cannot use the bus: {exc}", file=sys.stderr)
            return 1
        raise
    finally:
        if bar is not None:
            bar.stop()
    if args.json:
        print(json.dumps([n.to_dict() for n in found]))
        return 0
    table = Table(title=f"{len(found)} node(s) found")
    columns = ("node", "heard", "device type", "vendor", "product", "revision", "serial")
    for column in (*columns, "name", "hw", "sw", "errors"):
        table.add_column(column)
    for n in found:
        ident = [n.identity.get(k) for k in _IDENTITY]
        table.add_row(
            str(n.node_id),
            n.heard or "",
            "" if n.device_type is None else f"0x{n.device_type:08X}",
            *("" if v is None else f"0x{v:08X}" for v in ident),
            escape(n.device_name or ""),
            escape(n.hardware_version or ""),
            escape(n.software_version or ""),
            " ".join(f"{e:08X}" for e in n.errors),
        )
    Console(highlight=False).print(table)
    return 0
