"""cobus lss: give devices node-IDs, find them, change the bit rate (LSS, CiA 305).

    cobus lss scan                              # fastscan: the first device without a node-ID
    cobus lss set-id 12 --identity 0x360:0x1234:0x10000:42 --store
    cobus lss assign-all --first 20 --store     # every device without one, IDs from 20 up
    cobus lss assign-all --network line.yml     # the IDs the network file gives them
    cobus lss inquire --identity 0x360:0x1234:0x10000:42   # its node-ID (store: keep it)
    cobus lss set-bitrate 250                   # every node heard to 250 kbit/s, checked
    cobus lss find --vendor 0x360 --product 0x1234   # every such device, with its node-ID

A device without a node-ID (FFh) answers LSS only: no boot-up, no SDO. ``scan`` finds one by
fastscan (its identity, 1018h sub 1-4) and leaves it as it was. ``set-id`` gives a node-ID to
the device with that identity, ``assign-all`` to every device without one (node-IDs heard on
the bus are skipped); ``--store`` makes the device keep it over a power cycle. A device takes
its new node-ID when it is switched back to LSS waiting (one without one before: at once, it
boots; one that had one: at its next reset). Nothing but LSS is sent (``set-bitrate`` also
reads each node's identity, 1018h, by SDO): no NMT command, no SDO write.

``assign-all`` checks that each device boots under its new node-ID (its boot-up message). With
``--network FILE`` a device gets the node-ID of the file's node with its identity; one the
file knows by vendor and product only gets the first such node's ID and its serial is
written into that node's entry (``serial_number``), so that the master finds it by its
identity; a device the file does not know gets a node-ID the file does not use.

``find`` lists every device of a vendor and product, with a node-ID or without (identify
remote slave, halving ranges of serials and revisions): the identities ``set-id`` takes.

``set-bitrate`` moves every node heard (or ``--nodes``) to another bit rate as one step: each
is given the bit timing by its identity and must accept it, else nothing switches; then all
switch at once, the interface is opened again at the new rate and every node must be heard
again (the missing ones are named).

Exit codes: 0 done, 1 a device refused, did not answer or did not boot, or the bus cannot be
used, 2 bad usage or a network file with errors, 3 nothing found (no device without a
node-ID answered; find: no device of that product; set-bitrate: no node heard).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from typing import Any

from cobus._args import add_bus_options, bus_options, node_id, seconds

__all__ = ["register"]

_FIELDS = ("vendor", "product", "revision", "serial")
#: Seconds a device given a node-ID has to send its boot-up message.
_BOOT_WAIT = 1.0


def _identity(text: str) -> Any:
    from cobus.proto.lss import LssError, LssIdentity

    parts = text.split(":")
    try:
        if len(parts) != 4:
            raise ValueError
        return LssIdentity(*(int(p, 0) for p in parts))
    except (ValueError, LssError):
        raise argparse.ArgumentTypeError(
            f"{text!r}: write VENDOR:PRODUCT:REVISION:SERIAL, e.g. 0x360:0x1234:0x10000:42"
        ) from None


def _u32(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        value = -1
    if not 0 <= value <= 0xFFFF_FFFF:
        raise argparse.ArgumentTypeError(f"{text!r}: a number 0 to 0xFFFFFFFF (e.g. 0x360)")
    return value


def register(sub: Any) -> None:
    """Add ``cobus lss``."""
    lss = sub.add_parser(
        "lss",
        help="LSS (CiA 305): give devices node-IDs, find them, change the bit rate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = lss.add_subparsers(dest="action", metavar="ACTION", required=True)
    scan = actions.add_parser("scan", help="find a device without a node-ID (fastscan)")
    set_id = actions.add_parser("set-id", help="give the device with an identity a node-ID")
    inquire = actions.add_parser("inquire", help="the node-ID of the device with an identity")
    store = actions.add_parser("store", help="the device with an identity stores its node-ID")
    set_id.add_argument("node", type=node_id, help="the new node-ID, 1-127")
    for p in (set_id, inquire, store):
        p.add_argument(
            "--identity", type=_identity, required=True, help="VENDOR:PRODUCT:REVISION:SERIAL"
        )
    assign = actions.add_parser("assign-all", help="give every device without one a node-ID")
    assign.add_argument(
        "--first", type=node_id, default=1, help="the lowest node-ID to give (default 1)"
    )
    assign.add_argument(
        "--network",
        metavar="FILE",
        help="the network file: its nodes' node-IDs by identity; serials written back",
    )
    for p in (set_id, assign):
        p.add_argument("--store", action="store_true", help="the device stores its node-ID")
    for p in (scan, assign):
        for field in _FIELDS[:3]:
            p.add_argument(f"--{field}", type=_u32, help=f"the {field} if known (faster)")
        p.add_argument(
            "--ceiling", type=seconds, default=0.5, help="longest wait for an answer (0.5 s)"
        )
        p.add_argument(
            "--floor", type=seconds, default=0.01, help="shortest wait for an answer (0.01 s)"
        )
    find = actions.add_parser("find", help="every device of a vendor and product (by ranges)")
    find.add_argument("--vendor", type=_u32, required=True, help="the vendor-ID (1018h sub 1)")
    find.add_argument("--product", type=_u32, required=True, help="the product code (sub 2)")
    find.add_argument("--revision", type=_u32, help="the revision (sub 3), if known (faster)")
    find.add_argument("--timeout", type=seconds, default=0.1, help="the wait for an answer (0.1 s)")
    rate = actions.add_parser("set-bitrate", help="every node to another bit rate, checked")
    rate.add_argument("kbits", type=_kbits, help="the new rate in kbit/s (1000, 800, 500...)")
    rate.add_argument(
        "--nodes", type=_nodes, help="the nodes to move, e.g. 2,3,5 (default: those heard)"
    )
    rate.add_argument(
        "--delay", type=_switch_delay, default=0.1, help="the switch delay (default 0.1 s)"
    )
    rate.add_argument(
        "--wait", type=seconds, default=3.0, help="how long the nodes have to come back (3 s)"
    )
    rate.set_defaults(handler=_set_bitrate)
    for p in (scan, assign, rate):
        p.add_argument(
            "--listen",
            type=seconds,
            default=2.5,
            help="how long heartbeats are listened to for the node-IDs in use (2.5 s: give "
            "more than the slowest heartbeat period)",
        )
    for p in (scan, set_id, assign, inquire, store, find, rate):
        p.add_argument("--json", action="store_true", help="the result as JSON")
        p.epilog = (
            "Exit codes: 0 done, 1 refused / no answer / no boot-up / bus, 2 bad usage or "
            "network file, 3 none found."
        )
        add_bus_options(p)
        if p is not rate:
            p.set_defaults(handler=_run)


def _kbits(text: str) -> int:
    from cobus.proto.lss import BIT_RATES

    rates = sorted(BIT_RATES.values(), reverse=True)
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value not in rates:
        raise argparse.ArgumentTypeError(
            f"{text!r}: one of CiA 305's rates, in kbit/s: {', '.join(map(str, rates))}"
        )
    return value


def _switch_delay(text: str) -> float:
    value = seconds(text)
    if not value <= 65.535:
        raise argparse.ArgumentTypeError(f"{text!r}: the switch delay is 0 to 65.535 s")
    return value


def _nodes(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        try:
            out.append(node_id(part.strip()))
        except argparse.ArgumentTypeError:
            raise argparse.ArgumentTypeError(
                f"{text!r}: node-IDs 1-127 separated by commas, e.g. 2,3,5"
            ) from None
    return out


def _set_bitrate(args: argparse.Namespace) -> int:
    from cobus.apps._lss_bitrate import set_bitrate

    return set_bitrate(args)


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus: {message}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    from cobus.errors import CobusError
    from cobus.master.errors import NetworkConfigError

    done: list[dict[str, Any]] = []
    try:
        code = _session(args, done)
    except KeyboardInterrupt:
        what = ", ".join(f"serial {d['serial']} -> node {d['node_id']}" for d in done)
        print(f"cobus: interrupted; done so far: {what or 'nothing'}", file=sys.stderr)
        code = 130
    except NetworkConfigError as exc:  # (the --network file: input to mend, like usage)
        code = _fail(str(exc), 2)
    except CobusError as exc:
        code = _fail(str(exc))
    except Exception as exc:
        if not type(exc).__module__.startswith("can"):
            raise
        code = _fail(f"the bus cannot be used: {exc}")
    if done and (code == 0 or (args.json and args.action in ("assign-all", "find"))):
        _print(args, done)  # (what was done, also when a later step failed)
    return code


def _session(args: argparse.Namespace, done: list[dict[str, Any]]) -> int:
    """One ``cobus lss`` command on the bus; ``done`` gathers its rows."""
    from cobus.runtime import LssTimeoutError, Network

    with Network(**bus_options(args)) as net:
        if args.action == "set-id":
            net.lss.timeout = 0.2
            _set_id(net, args.identity, args.node, args.store)
            done.append(_row(args.identity, args.node, args.store))
        elif args.action in ("inquire", "store"):
            net.lss.timeout = 0.2
            done.append(_one(net, args.identity, args.action == "store"))
        elif args.action == "find":
            net.lss.timeout = args.timeout
            found = net.lss.identify_all(
                args.vendor,
                args.product,
                args.revision,
                on_found=None if args.json else _found_line,
            )
            if not found:
                return _fail(
                    f"no device of vendor 0x{args.vendor:08X} and product "
                    f"0x{args.product:08X} answered"
                    + ("" if args.revision is None else f" (revision 0x{args.revision:08X})"),
                    3,
                )
            for identity in found:
                try:
                    done.append(_one(net, identity, False))
                except LssTimeoutError:  # (it answered the ranges, not its identity)
                    done.append({**_row(identity, None, False), "node_id": "?"})
        else:
            return _scan(net, args, done)
    return 0


def _scan(net: Any, args: argparse.Namespace, done: list[dict[str, Any]]) -> int:
    from cobus.apps._lss_bitrate import heard_nodes
    from cobus.apps._lss_plan import NetworkPlan

    assign = args.action == "assign-all"
    plan = NetworkPlan(args.network) if assign and args.network else None
    known = {f: getattr(args, f) for f in _FIELDS[:3] if getattr(args, f) is not None}
    from_file = plan is not None and not known and plan.vendor is not None
    if from_file:
        assert plan is not None and plan.vendor is not None
        known = {"vendor": plan.vendor}  # (every node of the file has it: not scanned)
    heard = heard_nodes(net, args.listen)
    if not net.lss.identify_unconfigured():
        return _fail(_nothing_found(heard), 3)
    next_id = getattr(args, "first", 1)
    writes: dict[str, int] = {}
    try:
        return _assign(net, args, done, plan, known, from_file, heard, next_id, writes)
    finally:
        if plan is not None and writes:  # (also when a later device failed, or Ctrl-C)
            plan.write_back(writes)
            if not args.json:
                print(f"{plan.path}: serial_number written for {', '.join(writes)}")


def _assign(
    net: Any,
    args: argparse.Namespace,
    done: list[dict[str, Any]],
    plan: Any,
    known: dict[str, int],
    from_file: bool,
    heard: set[int],
    next_id: int,
    writes: dict[str, int],
) -> int:
    """Scan, and (assign-all) give each device found its node-ID; ``writes`` gathers the
    serials to write into the network file."""
    from cobus.proto.lss import LssState

    assign = args.action == "assign-all"
    while True:
        started = time.monotonic()
        found = net.lss.fastscan(
            known,
            floor=args.floor,
            ceiling=args.ceiling,
            on_event=None if args.json else _progress(started),
        )
        if found is None and from_file and net.lss.identify_unconfigured():
            known, from_file = {}, False  # one of another vendor than the file's: whole scan
            continue
        if found is None:
            break
        took = round(time.monotonic() - started, 3)
        if not assign:  # scan: report it, leave it as it was
            net.lss.switch_global(LssState.WAITING)
            done.append({**_row(found, None, False), "seconds": took})
            break
        planned = None if plan is None else plan.choose(found, heard)
        if planned is not None:
            target = planned.node_id
        else:
            taken = heard | {d["node_id"] for d in done} | (set() if plan is None else plan.used)
            while next_id in taken:
                next_id += 1
            if next_id > 127:
                net.lss.switch_global(LssState.WAITING)
                return _fail(f"no free node-ID left for {found} (heard: {sorted(heard)})")
            target = next_id
        booted = _configure(net, target, args.store)
        row = _row(found, target, args.store)
        row.update(
            seconds=took, booted=booted, network_node=None if planned is None else planned.name
        )
        done.append(row)
        if planned is not None and planned.write:
            writes[planned.name or ""] = found.serial
        if not args.json:
            print(_said(found, row, plan is not None))
    if not done:
        return _fail(_nothing_found(heard), 3)
    missing = [d["node_id"] for d in done if assign and not d["booted"]]
    if missing:
        return _fail(
            f"node(s) {', '.join(map(str, missing))} took their node-ID but no boot-up came "
            f"within {_BOOT_WAIT} s: check them (power, bit rate, a node-ID used twice)"
        )
    return 0


def _progress(started: float) -> Callable[[Any], None]:
    """Print the scan's estimate and each field as it is found (on stderr: the results go
    to stdout)."""
    from cobus.proto.lss import FastscanFieldFound, FastscanFieldRetried, FastscanStarted

    def show(event: Any) -> None:
        at = time.monotonic() - started
        if isinstance(event, FastscanStarted):
            text = f"fastscan: a device answers; about {event.estimate:.1f} s"
        elif isinstance(event, FastscanFieldFound):
            how = "known, confirmed" if event.known else "found"
            text = f"  {event.field:<8} 0x{event.value:08X} {how} at {at:.2f} s"
        elif isinstance(event, FastscanFieldRetried):
            text = f"  {event.field:<8} 0x{event.value:08X} not confirmed: scanned again"
        else:
            return
        print(text, file=sys.stderr, flush=True)

    return show


def _found_line(identity: Any) -> None:
    """The range search's progress: each device as it is found (stderr)."""
    print(f"find: {identity}", file=sys.stderr, flush=True)


def _said(found: Any, row: dict[str, Any], with_file: bool) -> str:
    text = f"{found}: node-ID {row['node_id']}"
    if row["network_node"] is not None:
        text += f" ({row['network_node']})"
    elif with_file:
        text += " (not in the network file: add it there to keep it)"
    if row["stored"]:
        text += ", stored"
    return text + (", booted" if row["booted"] else ", no boot-up")


def _set_id(net: Any, identity: Any, node: int, store: bool) -> None:
    net.lss.select(identity)
    _configure(net, node, store, wait=False)  # (it takes it at its next reset)


def _one(net: Any, identity: Any, store: bool) -> dict[str, Any]:
    """Select the device with ``identity``, ask its node-ID (and have it store it), and
    switch it back to waiting."""
    from cobus.proto.lss import UNCONFIGURED, LssState

    net.lss.select(identity)
    try:
        node = net.lss.inquire("node_id")
        if store:
            net.lss.store()
    finally:
        net.lss.switch_global(LssState.WAITING)
    return _row(identity, None if node == UNCONFIGURED else node, store)


def _configure(net: Any, node: int, store: bool, *, wait: bool = True) -> bool:
    """Give the device in configuration ``node`` (and have it store it), switch it back to
    waiting; whether its boot-up under ``node`` came within :data:`_BOOT_WAIT` seconds."""
    from cobus.proto.connection_set import ERROR_CONTROL_BASE
    from cobus.proto.lss import LssState

    booted: list[float] = []
    sub = net.subscribe(
        ERROR_CONTROL_BASE + node,
        lambda frame, now: booted.append(now) if frame.data == b"\x00" else None,
    )
    try:
        try:
            net.lss.configure_node_id(node)
            if store:
                net.lss.store()
        finally:
            net.lss.switch_global(LssState.WAITING)  # the device takes its node-ID now
        waited = 0.0
        while wait and not booted and waited < _BOOT_WAIT:
            net.sleep(0.01)
            waited += 0.01
    finally:
        sub.cancel()
    return bool(booted)


def _nothing_found(heard: set[int]) -> str:
    if heard:
        return (
            f"no device without a node-ID answered, but nodes {sorted(heard)} are heard: every "
            "device here has a node-ID; give one another with 'cobus lss set-id NODE "
            "--identity V:P:R:S' (their identities: 'cobus lss find --vendor V --product P')"
        )
    return (
        "no device without a node-ID answered, and no heartbeat is heard: check the bus "
        "(wiring, termination, bit rate: an LSS device listens at its own)"
    )


def _row(identity: Any, node: int | None, stored: bool) -> dict[str, Any]:
    row: dict[str, Any] = {f: getattr(identity, f) for f in _FIELDS}
    row.update(node_id=node, stored=stored)
    return row


def _print(args: argparse.Namespace, done: list[dict[str, Any]]) -> None:
    if args.json:
        print(json.dumps(done if args.action in ("assign-all", "find") else done[0]))
        return
    if args.action == "find":
        for row in done:
            node = "no node-ID" if row["node_id"] is None else f"node-ID {row['node_id']}"
            identity = ":".join(f"0x{row[f]:X}" for f in _FIELDS)
            print(f"{identity}  {node}")
        return
    if args.action == "scan":
        row = done[0]
        print(
            " ".join(f"{f} 0x{row[f]:08X}" for f in _FIELDS)
            + f" (no node-ID; found in {row['seconds']:.2f} s; 'cobus lss set-id' gives it one)"
        )
    elif args.action in ("inquire", "store"):
        row = done[0]
        node = "no node-ID" if row["node_id"] is None else f"node-ID {row['node_id']}"
        print(f"serial 0x{row['serial']:08X}: {node}" + (" (stored)" if row["stored"] else ""))
    elif args.action == "set-id":
        row = done[0]
        print(
            f"serial 0x{row['serial']:08X}: node-ID {row['node_id']}"
            + (" (stored)" if row["stored"] else "")
        )
    else:
        print(f"{len(done)} device(s) given a node-ID")
