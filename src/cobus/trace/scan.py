"""Find the nodes on a bus and what they are: ``cobus scan``.

    cobus scan -i socketcan -c can0               # listen, then ask 1-127 for 1000h; a table
    cobus scan --nodes 1-32 --timeout 0.05 --json

First it listens (``--listen`` seconds) for boot-ups and heartbeats, then it reads 1000h
(device type) from every node-ID (16 at a time; a progress bar on a terminal), and of every
node that answers: the identity 1018h, the names 1008h-100Ah and the error history 1003h.
``--objects 0x2000-0x5FFF --nodes 8`` reads (never writes) every object of a range from one
node, with type guesses and values, and ``--eds-out draft.eds`` writes them as a draft EDS
to complete.
Exit codes: 0 done (also when none answered), 1 the bus cannot be used, 2 bad usage.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cobus._args import add_bus_options, bus_options, seconds
from cobus.proto.connection_set import ERROR_CONTROL_BASE, MAX_NODE_ID

__all__ = ["FoundNode", "FoundObject", "register", "scan", "scan_objects"]

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
    found: dict[int, FoundNode] | None = None,
) -> list[FoundNode]:
    """Scan ``nodes`` on an :class:`~cobus.runtime.AsyncNetwork`: listen ``listen`` seconds
    for boot-ups and heartbeats, read 1000h of each node (``timeout`` per answer, ``parallel``
    at once), then the identity, names and error history of those that answered (the
    remote nodes it makes for that are removed again; those the network had are used).
    ``progress(done, total)`` is called as node-IDs are asked. The nodes found, by node-ID;
    ``found``, a dict, is filled as they answer (a caller interrupted keeps what was found)."""
    from cobus.errors import CobusError
    from cobus.proto.sdo import SdoTimeoutError

    wanted = sorted(set(nodes))
    added: set[int] = set()
    found = {} if found is None else found
    heard: dict[int, str] = {}

    def on_frame(frame: Any, now: float) -> None:
        cob = frame.cob_id
        if (
            ERROR_CONTROL_BASE < cob <= ERROR_CONTROL_BASE + MAX_NODE_ID
            and len(frame.data) == 1
            and not frame.rtr
        ):
            heard[cob - ERROR_CONTROL_BASE] = _STATES.get(
                frame.data[0] & 0x7F, f"{frame.data[0]:02X}h"
            )

    sub = network.subscribe_all(on_frame)
    try:
        await asyncio.sleep(listen)
        gate = asyncio.Semaphore(max(1, parallel))
        done = 0

        async def probe(node_id: int) -> None:
            nonlocal done
            async with gate:
                node = _remote(network, node_id, timeout, added)
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
        _forget(network, added)
    for node_id, state in heard.items():
        if node_id in found:
            found[node_id].heard = state
        elif node_id in wanted:
            found[node_id] = FoundNode(node_id, heard=state)
    return [found[n] for n in sorted(found)]


def _remote(network: Any, node_id: int, timeout: float, added: set[int]) -> Any:
    """The network's remote node ``node_id``; one made for the scan is noted in ``added``
    (and removed again when the scan ends)."""
    existing = network.remotes.get(node_id)
    if existing is not None:
        return existing
    added.add(node_id)
    return network.add_remote(node_id, sdo_timeout=timeout)


def _forget(network: Any, added: set[int]) -> None:
    for node_id in added:
        network.remove_remote(node_id)


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


@dataclass(frozen=True)
class FoundObject:
    """A sub-index that answered an upload: its bytes and a guess of its type."""

    index: int
    subindex: int
    data: bytes

    @property
    def type_guess(self) -> str:
        """UNSIGNED8/16/32 by length, VISIBLE_STRING for printable text, else DOMAIN."""
        sizes = {1: "UNSIGNED8", 2: "UNSIGNED16", 3: "UNSIGNED24", 4: "UNSIGNED32"}
        if len(self.data) in sizes:
            return sizes[len(self.data)]
        if self.data and all(32 <= b < 127 for b in self.data.rstrip(b"\0")):
            return "VISIBLE_STRING"
        return "DOMAIN"


async def scan_objects(
    network: Any,
    node_id: int,
    indexes: Iterable[int],
    *,
    timeout: float = 0.1,
    progress: Callable[[int, int], object] | None = None,
) -> list[FoundObject]:
    """Which objects and sub-indexes of ``indexes`` node ``node_id`` answers (it only
    reads: sub-index 0 of each index, then 1..n when sub-index 0 is a count), in order."""
    from cobus.errors import CobusError

    added: set[int] = set()
    node = _remote(network, node_id, timeout, added)
    wanted = list(indexes)
    found: list[FoundObject] = []

    async def read(index: int, sub: int) -> bytes | None:
        try:
            data: bytes = await node.sdo.upload(index, sub)
            return data
        except CobusError:
            return None

    try:
        for done, index in enumerate(wanted, 1):
            data = await read(index, 0)
            if data is not None:
                found.append(FoundObject(index, 0, data))
                if len(data) == 1 and 0 < data[0] < 0xFF:  # a count: a record or an array
                    for sub in range(1, data[0] + 1):
                        value = await read(index, sub)
                        if value is not None:
                            found.append(FoundObject(index, sub, value))
            if progress is not None:
                progress(done, len(wanted))
    finally:
        _forget(network, added)
    return found


def draft_eds(node_id: int, objects: list[FoundObject]) -> str:
    """A draft EDS of what a node answered: every object read-only, types guessed from the
    answers, names to be completed (the file says so)."""
    from cobus.od import Access, DataType, ObjectDictionary, Record, Variable

    od = ObjectDictionary()
    by_index: dict[int, list[FoundObject]] = {}
    for obj in objects:
        by_index.setdefault(obj.index, []).append(obj)
    for index, subs in sorted(by_index.items()):
        if len(subs) == 1 and subs[0].subindex == 0:
            var = Variable(
                index, 0, f"Object {index:04X}h", DataType[subs[0].type_guess], Access.RO
            )
            od.add(var)
            continue
        record = Record(index, f"Object {index:04X}h")
        for obj in subs:
            name = "Highest sub-index supported" if obj.subindex == 0 else f"Sub {obj.subindex}"
            kind = DataType[obj.type_guess]
            record.add(Variable(index, obj.subindex, name, kind, Access.RO))
        od.add(record)
    head = (
        f"; draft EDS of node {node_id} from `cobus scan --objects`: every object the node\n"
        "; answered, read-only, with a type guessed from its answer's length. Complete the\n"
        "; names, access types, types and limits from the device's documents.\n"
    )
    return head + od.to_eds()


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
    p.add_argument(
        "--objects",
        metavar="RANGE",
        help="which objects ONE node answers, e.g. 0x2000-0x5FFF (give --nodes N)",
    )
    p.add_argument("--eds-out", type=Path, help="with --objects: write a draft EDS here")
    add_bus_options(p)
    p.set_defaults(handler=_run)


def _range(text: str) -> range:
    low, sep, high = text.partition("-")
    try:
        first, last = int(low, 16), int(high, 16) if sep else int(low, 16)
    except ValueError:
        raise ValueError(f"--objects {text!r}: a hex range like 0x2000-0x5FFF") from None
    if not 0x1000 <= first <= last <= 0xFFFF:
        raise ValueError(f"--objects {text!r}: indexes 1000h-FFFFh, low to high")
    return range(first, last + 1)


def _run_objects(args: argparse.Namespace) -> int:
    from cobus._console import print_table
    from cobus._console import table as new_table
    from cobus.runtime import Network

    if len(args.nodes) != 1:
        print("cobus scan: --objects scans one node: give --nodes N", file=sys.stderr)
        return 2
    try:
        indexes = _range(args.objects)
    except ValueError as exc:
        print(f"cobus scan: {exc}", file=sys.stderr)
        return 2
    node_id = args.nodes[0]
    try:
        with Network(**bus_options(args)) as net:
            found = net.run(scan_objects(net.aio, node_id, indexes, timeout=args.timeout))
    except Exception as exc:
        if type(exc).__module__.startswith(("can", "cobus")):
            print(f"cobus scan: cannot use the bus: {exc}", file=sys.stderr)
            return 1
        raise
    if args.eds_out is not None:
        args.eds_out.write_text(draft_eds(node_id, found), encoding="utf-8")
    if args.json:
        rows = [
            {"index": o.index, "subindex": o.subindex, "data": o.data.hex(), "type": o.type_guess}
            for o in found
        ]
        print(json.dumps(rows))
        return 0
    table = new_table(
        "object",
        "bytes",
        "type guess",
        "value",
        title=f"node {node_id}: {len(found)} sub-index(es) answered",
    )
    for o in found:
        value = str(int.from_bytes(o.data, "little")) if len(o.data) <= 4 else repr(o.data[:24])
        table.add_row(f"{o.index:04X}h:{o.subindex:02X}", str(len(o.data)), o.type_guess, value)
    print_table(table)
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.objects is not None:
        return _run_objects(args)
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    from cobus.runtime import Network

    quiet = args.json or not sys.stderr.isatty()
    found_so_far: dict[int, FoundNode] = {}
    asked = [0]
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
                asked[0] = done
                if bar is not None:
                    bar.update(task, completed=done)  # type: ignore[arg-type]

            found = net.run(
                scan(
                    net.aio,
                    args.nodes,
                    timeout=args.timeout,
                    listen=args.listen,
                    progress=progress,
                    found=found_so_far,
                )
            )
    except KeyboardInterrupt:
        if bar is not None:
            bar.stop()
            bar = None
        found = [found_so_far[n] for n in sorted(found_so_far)]
        print(
            f"cobus scan: interrupted after {asked[0]} of {len(args.nodes)} node-ID(s) asked; "
            f"{len(found)} found so far",
            file=sys.stderr,
        )
        _print_nodes(args, found)
        return 130
    except Exception as exc:
        if type(exc).__module__.startswith(("can", "cobus")):
            print(f"cobus scan: cannot use the bus: {exc}", file=sys.stderr)
            return 1
        raise
    finally:
        if bar is not None:
            bar.stop()
    _print_nodes(args, found)
    return 0


def _print_nodes(args: argparse.Namespace, found: list[FoundNode]) -> None:
    """The nodes found, as a table (or JSON)."""
    from rich.markup import escape

    from cobus._console import print_table
    from cobus._console import table as new_table

    if args.json:
        print(json.dumps([n.to_dict() for n in found]))
        return
    columns = ("node", "heard", "device type", "vendor", "product", "revision", "serial")
    table = new_table(*columns, "name", "hw", "sw", "errors", title=f"{len(found)} node(s) found")
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
    print_table(table)
