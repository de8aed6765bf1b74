"""cobus pdo: a node's PDOs from the shell - read them, or map one anew, checked against its EDS.

    cobus pdo show 10 --eds servo.eds              # every TPDO and RPDO: COB-ID, type, mapping
    cobus pdo show 10 --json
    cobus pdo map 10 tpdo2 "Position actual value" Statusword --type 1 --eds servo.eds
    cobus pdo map 10 rpdo1 Controlword "Target velocity" --eds servo.eds
    cobus pdo map 10 tpdo4 --disable --eds servo.eds    # (--enable: on again)
    cobus pdo map 8 tpdo2 "alarm code" dummy8 dummy16 "controller temperature" --eds zapi.eds

``map`` writes the PDO the CiA 301 way - disable it, write the transmission type and timers,
clear the mapping, write the entries, set their count, enable it again - then reads it back.
Each object is checked against the EDS first: it exists, may be mapped, can be sent (TPDO) or
written (RPDO), and the PDO stays within 64 bits; ``dummy8``, ``dummy16``, ``dummy32`` leave
a gap. What is not given stays as the node has it - its objects, type, timers, and whether
it is on (``--enable``/``--disable`` change that). Remapping changes what the node sends and
takes; it writes no value itself (an RPDO's objects take what the next frame carries).

Exit codes: 0 done, 1 the node refused or did not answer, or the bus cannot be used, 2 bad
usage (a bad object, a bad option).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

from cobus._args import add_bus_options, bus_options, node_id, other_device, seconds

__all__ = ["register"]

_PDO = re.compile(r"\s*([tr])pdo\s*(\d{1,3})\s*\Z", re.IGNORECASE)


def register(sub: Any) -> None:
    """Add ``cobus pdo show|map``."""
    pdo: argparse.ArgumentParser = sub.add_parser(
        "pdo",
        help="read a node's PDOs, or map one anew, checked against its EDS",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = pdo.add_subparsers(dest="action", metavar="ACTION", required=True)
    show = actions.add_parser("show", help="read every TPDO and RPDO of the node")
    show.add_argument("node", type=node_id, help="node-ID 1-127")
    mapping = actions.add_parser(
        "map",
        help="write one PDO: its objects, transmission type and timers",
        usage="cobus pdo map NODE PDO [OBJECT ...] [options]",
    )
    mapping.add_argument("node", type=node_id, help="node-ID 1-127")
    mapping.add_argument("pdo", type=_pdo_name, help="tpdo1..tpdo512 or rpdo1..rpdo512")
    mapping.add_argument(
        "objects", nargs="*", metavar="OBJECT", help="names from the EDS or addresses, in order"
    )
    mapping.add_argument(
        "--type",
        type=int,
        dest="transmission_type",
        help="transmission type: 0 acyclic sync, 1-240 every n-th SYNC, 254/255 event",
    )
    mapping.add_argument(
        "--event-timer", type=_u16, metavar="MS", help="event timer, ms (0-65535; 0: none)"
    )
    mapping.add_argument(
        "--inhibit", type=_u16, metavar="N", help="inhibit time, 100 us units (0-65535)"
    )
    on_off = mapping.add_mutually_exclusive_group()
    on_off.add_argument("--disable", action="store_true", help="switch the PDO off")
    on_off.add_argument("--enable", action="store_true", help="switch the PDO on")
    for p in (show, mapping):
        p.add_argument("--eds", type=Path, help="the node's EDS or DCF (names, checks)")
        p.add_argument("--timeout", type=seconds, default=1.0, help="seconds per SDO answer")
        p.add_argument("--json", action="store_true", help="the PDOs as JSON")
        add_bus_options(p)
        p.set_defaults(handler=_run)


def _u16(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        value = -1
    if not 0 <= value <= 0xFFFF:
        raise argparse.ArgumentTypeError(f"{text!r}: a whole number 0-65535")
    return value


_DUMMY = re.compile(r"\s*dummy\s*(8|16|32)\s*\Z", re.IGNORECASE)
_DUMMY_TYPES = {8: 0x0005, 16: 0x0006, 32: 0x0007}


def _pdo_name(text: str) -> tuple[bool, int]:
    match = _PDO.match(text)
    number = int(match.group(2)) if match else 0
    if match is None or not 1 <= number <= 512:
        raise argparse.ArgumentTypeError(f"{text!r}: tpdo1..tpdo512 or rpdo1..rpdo512")
    return match.group(1).lower() == "t", number


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus pdo: {message}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    from cobus._args import load_eds
    from cobus.errors import CobusError
    from cobus.od import EdsError
    from cobus.runtime import Network
    from cobus.runtime.errors import BusOpenError

    od = None
    if args.eds is not None:
        try:
            od = load_eds(args.eds, "pdo", node_id=args.node)
        except EdsError as exc:
            return _fail(str(exc), 2)
    if args.action == "map":
        if od is None:
            return _fail("give the node's --eds: the objects are checked against it", 2)
        given = (args.transmission_type, args.event_timer, args.inhibit)
        if not args.objects and all(v is None for v in given) and not (args.enable or args.disable):
            return _fail(
                "nothing to change: give objects, --type, --event-timer, --inhibit, --enable "
                "or --disable",
                2,
            )
        try:
            _check_type(args.pdo[0], args.transmission_type)
            entries = [_entry(text, od) for text in args.objects]
        except ValueError as exc:
            return _fail(str(exc), 2)
    try:
        with Network(**bus_options(args)) as net:
            node = net.add_remote(args.node, od, sdo_timeout=args.timeout)
            mismatch = other_device(node, od)
            if mismatch is not None:
                if args.action == "map":  # (the checks against the EDS would be wrong)
                    return _fail(f"{mismatch}; nothing written: give the node's own EDS", 2)
                print(f"cobus pdo: {mismatch}", file=sys.stderr)
            if args.action == "show":
                pdos = [*node.tpdo.read(), *node.rpdo.read()]
            else:
                pdos = [_map(node, args, entries)]
            described = [_describe(p) for p in pdos]  # (read while the network runs)
    except KeyboardInterrupt:
        what = "the PDO may be left disabled" if args.action == "map" else "nothing was written"
        return _fail(f"interrupted: {what}", 130)
    except ValueError as exc:  # a mapping the PDO cannot take (checked before any write)
        return _fail(str(exc), 2)
    except BusOpenError:
        raise  # (cobus.cli says it, as for every command)
    except CobusError as exc:
        return _fail(str(exc))
    _print(args, described)
    return 0


def _check_type(transmit: bool, tt: int | None) -> None:
    """ValueError for a transmission type the PDO cannot have (checked before any write)."""
    if tt is None:
        return
    if not 0 <= tt <= 255 or 241 <= tt <= 251:
        raise ValueError(f"--type {tt}: 0, 1-240, 252-255 (241-251 are reserved)")
    if not transmit and tt in (252, 253):
        raise ValueError(f"--type {tt} (on RTR) is for a TPDO: an RPDO takes 0-240, 254, 255")


def _entry(text: str, od: Any) -> tuple[int, int, int | None]:
    """(index, sub-index, bits: None for the object's own) of an object named or numbered in
    ``od``, or a dummy (``dummy8``); ValueError: none."""
    from cobus.master.config import ObjectIndex

    dummy = _DUMMY.match(text)
    if dummy is not None:
        bits = int(dummy.group(1))
        return _DUMMY_TYPES[bits], 0, bits
    var = ObjectIndex(od, str(getattr(od, "path", None) or "the EDS")).resolve(text)
    return var.index, var.subindex, None


def _map(node: Any, args: argparse.Namespace, entries: list[tuple[int, int, int | None]]) -> Any:
    transmit, number = args.pdo
    pdo = (node.tpdo if transmit else node.rpdo)[number]
    pdo.read()  # (what it has now: the options not given stay)
    if args.objects:
        pdo.clear()
        for index, sub, bits in entries:
            pdo.add(index, sub, bits)
    if args.transmission_type is not None:
        pdo.transmission_type = args.transmission_type
    if args.event_timer is not None:
        pdo.event_timer = args.event_timer
    if args.inhibit is not None:
        pdo.inhibit_time = args.inhibit
    if args.enable or args.disable:
        pdo.enabled = args.enable  # (else: on or off as the node has it)
    pdo.save()
    pdo.read()  # what the node holds now
    return pdo


def _describe(pdo: Any) -> dict[str, Any]:
    kind = "TPDO" if pdo.transmit_by_node else "RPDO"
    return {
        "pdo": f"{kind}{pdo.number}",
        "cob_id": f"0x{pdo.cob_id:X}",
        "enabled": pdo.enabled,
        "transmission_type": pdo.transmission_type,
        "inhibit_100us": pdo.inhibit_time,
        "event_timer": pdo.event_timer,
        "objects": [
            {
                "object": f"0x{f.entry.index:04X}:{f.entry.subindex:02X}",
                "name": f"dummy{f.entry.bit_length}" if f.dummy else f.name,
                "bits": f.entry.bit_length,
            }
            for f in pdo.fields
        ],
    }


def _type_text(tt: int) -> str:
    if tt == 0:
        return "0 (SYNC, on change)"
    if 1 <= tt <= 240:
        return f"{tt} (every {'' if tt == 1 else f'{tt}th '}SYNC)"
    return {252: "252 (SYNC, on RTR)", 253: "253 (on RTR)", 254: "254 (event)"}.get(
        tt, f"{tt} (event)"
    )


def _print(args: argparse.Namespace, described: list[dict[str, Any]]) -> None:
    if args.json:
        print(json.dumps({"node": args.node, "pdos": described}))
        return
    from cobus._console import print_table
    from cobus._console import table as new_table

    table = new_table(
        "pdo",
        "cob-id",
        "type",
        "inhibit",
        "event",
        "objects",
        title=f"node {args.node}: {len(described)} PDO(s)",
    )
    for d in described:
        objects = ", ".join(f"{o['name']} ({o['bits']})" for o in d["objects"]) or "(none)"
        inhibit, event = d["inhibit_100us"], d["event_timer"]
        table.add_row(
            d["pdo"],
            d["cob_id"] if d["enabled"] else f"{d['cob_id']} off",
            _type_text(d["transmission_type"]),
            "" if inhibit is None else f"{inhibit / 10:g} ms",
            "" if event is None else f"{event} ms",
            objects,
        )
    print_table(table)
