"""cobus lss: find devices without a node-ID and give them one (LSS, CiA 305).

    cobus lss scan                              # fastscan: the first device without a node-ID
    cobus lss set-id 12 --identity 0x360:0x1234:0x10000:42 --store
    cobus lss assign-all --first 20 --store     # every device without one, IDs from 20 up
    cobus lss inquire --identity 0x360:0x1234:0x10000:42   # its node-ID (store: keep it)

A device without a node-ID (FFh) answers LSS only: no boot-up, no SDO. ``scan`` finds one by
fastscan (its identity, 1018h sub 1-4) and leaves it as it was. ``set-id`` gives a node-ID to
the device with that identity, ``assign-all`` to every device without one (node-IDs heard on
the bus are skipped); ``--store`` makes the device keep it over a power cycle. A device takes
its new node-ID when it is switched back to LSS waiting (one without one before: at once, it
boots; one that had one: at its next reset). Nothing else is written: no NMT command, no SDO.

Exit codes: 0 done, 1 a device refused or did not answer, or the bus cannot be used, 2 bad
usage, 3 no device without a node-ID answered.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from cobus._args import add_bus_options, bus_options, node_id, seconds

__all__ = ["register"]

_FIELDS = ("vendor", "product", "revision", "serial")


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
        help="find devices without a node-ID and give them one (LSS, CiA 305)",
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
    for p in (scan, set_id, assign, inquire, store):
        p.add_argument("--json", action="store_true", help="the result as JSON")
        p.epilog = "Exit codes: 0 done, 1 refused / no answer / bus, 2 bad usage, 3 none found."
        add_bus_options(p)
        p.set_defaults(handler=_run)


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus: {message}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    from cobus.errors import CobusError
    from cobus.runtime import Network

    done: list[dict[str, Any]] = []
    try:
        with Network(**bus_options(args)) as net:
            if args.action == "set-id":
                net.lss.timeout = 0.2
                _set_id(net, args.identity, args.node, args.store)
                done.append(_row(args.identity, args.node, args.store))
            elif args.action in ("inquire", "store"):
                net.lss.timeout = 0.2
                done.append(_one(net, args.identity, args.action == "store"))
            else:
                code = _scan(net, args, done)
                if code:
                    return code
    except KeyboardInterrupt:
        what = ", ".join(f"serial {d['serial']} -> node {d['node_id']}" for d in done)
        print(f"cobus: interrupted; done so far: {what or 'nothing'}", file=sys.stderr)
        return 130
    except CobusError as exc:
        return _fail(str(exc))
    except Exception as exc:
        if type(exc).__module__.startswith("can"):
            return _fail(f"the bus cannot be used: {exc}")
        raise
    _print(args, done)
    return 0


def _scan(net: Any, args: argparse.Namespace, done: list[dict[str, Any]]) -> int:
    from cobus.proto.lss import LssState

    known = {f: getattr(args, f) for f in _FIELDS[:3] if getattr(args, f) is not None}
    heard = _heard(net)
    if not net.lss.identify_unconfigured():
        return _fail(_nothing_found(heard), 3)
    next_id = args.first if args.action == "assign-all" else None
    while True:
        found = net.lss.fastscan(known, floor=args.floor, ceiling=args.ceiling)
        if found is None:
            break
        if next_id is None:  # scan: report it, leave it as it was
            net.lss.switch_global(LssState.WAITING)
            done.append(_row(found, None, False))
            break
        while next_id in heard or next_id in {d["node_id"] for d in done}:
            next_id += 1
        if next_id > 127:
            net.lss.switch_global(LssState.WAITING)
            return _fail(f"no free node-ID left for {found} (heard: {sorted(heard)})")
        _configure(net, next_id, args.store)
        done.append(_row(found, next_id, args.store))
        if not args.json:
            print(f"{found}: node-ID {next_id}{' (stored)' if args.store else ''}")
    if not done:
        return _fail(_nothing_found(heard), 3)
    return 0


def _set_id(net: Any, identity: Any, node: int, store: bool) -> None:
    net.lss.select(identity)
    _configure(net, node, store)


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


def _configure(net: Any, node: int, store: bool) -> None:
    from cobus.proto.lss import LssState

    try:
        net.lss.configure_node_id(node)
        if store:
            net.lss.store()
    finally:
        net.lss.switch_global(LssState.WAITING)  # the device takes its node-ID now
        net.sleep(0.01)


def _heard(net: Any) -> set[int]:
    """The node-IDs whose heartbeat or boot-up comes within 1.1 s."""
    from cobus.proto.connection_set import ERROR_CONTROL_BASE, MAX_NODE_ID

    heard: set[int] = set()

    def beat(frame: Any, now: float) -> None:
        if len(frame.data) == 1:
            heard.add(frame.cob_id - ERROR_CONTROL_BASE)

    subs = [net.subscribe(ERROR_CONTROL_BASE + n, beat) for n in range(1, MAX_NODE_ID + 1)]
    net.sleep(1.1)
    for s in subs:
        s.cancel()
    return heard


def _nothing_found(heard: set[int]) -> str:
    if heard:
        return (
            f"no device without a node-ID answered, but nodes {sorted(heard)} are heard: every "
            "device here has a node-ID; give one another with 'cobus lss set-id NODE "
            "--identity V:P:R:S'"
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
        print(json.dumps(done if args.action == "assign-all" else done[0]))
        return
    if args.action == "scan":
        row = done[0]
        print(
            " ".join(f"{f} 0x{row[f]:08X}" for f in _FIELDS)
            + " (no node-ID; 'cobus lss set-id' gives it one)"
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
