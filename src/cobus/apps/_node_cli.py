"""cobus sdo / nmt / sync: talk to nodes from the shell (a program on the runtime's public API).

    cobus sdo read 10 0x1008                    # value, with the EDS's name and type (--eds)
    cobus sdo read 10 "Position actual value" --eds servo.eds
    cobus sdo read 10 0x1018 2 --hex            # sub-index 2 (default 0), unsigned in hex
    cobus sdo write 10 0x6081 20000 --type u32
    cobus sdo write 10 "Profile velocity" 20000 --eds servo.eds
    cobus sdo upload 10 0x1021 servo.eds --block
    cobus sdo download 10 0x1F50 1 firmware.bin --block
    cobus nmt start all                         # start | stop | preop | reset | reset-comm
    cobus send 000#010A 70A#R 12345678#DEADBEEF # raw frames (cansend's notation)
    cobus sync --period 0.01 --count 100
    cobus sync --period 0.001 --overflow 10 --by-interface -i socketcan -c can0

An object is an address (0x1018, 1018h, 0x1018:02) or, with ``--eds``, a name from the EDS
("Identity object.Vendor-ID", close names are suggested); without an EDS the CiA 301 names of
1000h-1FFFh work too. ``sdo write`` writes exactly the object named, a controlword or a
set-point too: the drive acts on it.

Exit codes: 0 done, 1 the node refused (abort code and its text) or did not answer, 2 bad
usage.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import threading
import time
from pathlib import Path
from typing import Any

from cobus._args import add_bus_options, bus_options, seconds

__all__ = ["register"]

_NMT = {
    "start": "start",
    "stop": "stop",
    "preop": "enter_preoperational",
    "reset": "reset_node",
    "reset-comm": "reset_communication",
}


def _node(text: str) -> int:
    try:
        value = int(text, 0) if text.lower().startswith("0x") else int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 127:
        raise argparse.ArgumentTypeError(f"{text!r}: a node-ID 1-127")
    return value


def register(sub: Any) -> None:
    """Add ``cobus sdo``, ``cobus nmt`` and ``cobus sync``."""
    sdo = sub.add_parser(
        "sdo",
        help="read and write objects of a node by SDO",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = sdo.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, help_text in (
        ("read", "read an object and show its value"),
        ("write", "write a value to an object"),
        ("upload", "read an object's bytes into a file"),
        ("download", "write a file's bytes to an object"),
    ):
        tail = {"read": "", "write": " VALUE", "upload": " FILE", "download": " FILE"}[name]
        p = actions.add_parser(
            name,
            help=help_text,
            description=help_text,
            epilog=_EXITS,
            usage=f"cobus sdo {name} NODE OBJECT [SUBINDEX]{tail} [options]",
        )
        p.add_argument("node", type=_node, help="node-ID 1-127")
        p.add_argument(
            "object",
            help="an address (0x1008, 1008h, 0x1018:02) or, with --eds, a name from the EDS",
        )
        if name == "read":
            p.add_argument("rest", nargs="?", metavar="SUBINDEX", help="sub-index (default 0)")
        elif name == "write":
            p.add_argument(
                "rest",
                nargs="+",
                metavar="[SUBINDEX] VALUE",
                help="sub-index (default 0) and the value (a number, text, or hex bytes)",
            )
        else:
            p.add_argument(
                "rest", nargs="+", metavar="[SUBINDEX] FILE", help="sub-index (default 0), file"
            )
        if name == "read":
            p.add_argument(
                "--hex", action="store_true", help="unsigned numbers of 16 bits and more in hex"
            )
        p.add_argument("--eds", type=Path, help="the node's EDS/DCF: names and types")
        p.add_argument("--type", help="the data type without an EDS (u8, u16, i32, real32...)")
        p.add_argument("--block", action="store_true", help="a block transfer")
        p.add_argument("--timeout", type=seconds, default=1.0, help="seconds per answer")
        p.add_argument("--json", action="store_true", help="the result (or the abort) as JSON")
        add_bus_options(p)
        p.set_defaults(handler=_sdo)
    nmt = sub.add_parser(
        "nmt",
        help="send an NMT command to a node or to all",
        epilog="Exit codes: 0 sent, 1 the bus cannot be used, 2 bad usage.",
    )
    nmt.add_argument("command", choices=sorted(_NMT), help="the command")
    nmt.add_argument("target", help="a node-ID 1-127, or all")
    add_bus_options(nmt)
    nmt.set_defaults(handler=_nmt)
    send = sub.add_parser(
        "send",
        help="send raw CAN frames: ID#DATA as cansend writes them",
        description="Send raw CAN frames, in the order given, as cansend writes them: "
        "123#DEADBEEF (11-bit identifier, 0-8 data bytes in hex, dots allowed: 123#DE.AD), "
        "12345678#... (29-bit: eight hex digits), 123#R or 123#R4 (a remote frame, with "
        "its DLC). The frames reach every node on the bus as they are: a controlword or a "
        "set-point in one is obeyed; nothing is checked beyond the CAN format.",
        epilog="Exit codes: 0 sent, 1 the bus cannot be used, 2 bad usage.",
    )
    send.add_argument("frames", nargs="+", metavar="ID#DATA", type=_frame, help="the frames")
    send.add_argument(
        "--count", type=_count, default=1, help="send the frames this many times (default 1)"
    )
    send.add_argument(
        "--period", type=seconds, default=None, help="seconds between rounds (with --count)"
    )
    send.add_argument("--json", action="store_true", help="what was sent, as JSON")
    add_bus_options(send)
    send.set_defaults(handler=_send)
    sync = sub.add_parser(
        "sync",
        help="produce SYNC",
        epilog="Exit codes: 0 done (or stopped with Ctrl-C), 1 the bus cannot be used.",
    )
    sync.add_argument("--period", type=_sync_period, default=0.01, help="seconds (default 0.01)")
    sync.add_argument(
        "--count",
        type=int,
        help="how many (default: until Ctrl-C); with --by-interface one more may go out at "
        "short periods (what went out is printed)",
    )
    sync.add_argument(
        "--overflow",
        type=_overflow,
        default=0,
        help="add the CiA 301 counter, 1 up to this (2-240; default 0: no counter)",
    )
    sync.add_argument(
        "--by-interface",
        action="store_true",
        help="the CAN interface times the SYNC (SocketCAN: the kernel; no pause of this "
        "program delays it)",
    )
    add_bus_options(sync)
    sync.set_defaults(handler=_sync)


_EXITS = (
    "Exit codes: 0 done, 1 the node refused (abort code and its text) or did not answer, "
    "or the bus cannot be used, 2 bad usage."
)


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus: {message}", file=sys.stderr)
    return code


def _open(args: argparse.Namespace) -> Any:
    from cobus.runtime import Network

    return Network(**bus_options(args))


def _sdo(args: argparse.Namespace) -> int:
    from cobus._args import load_eds
    from cobus.errors import CobusError
    from cobus.od import DataType, EdsError, data_type_named, decode, encode

    od = None
    if args.eds is not None:
        try:
            od = load_eds(args.eds, "sdo", node_id=args.node)
        except (OSError, EdsError) as exc:
            return _fail(str(exc), 2)
    try:
        args.index, args.subindex, var = _object(args, od)
    except ValueError as exc:
        return _fail(str(exc), 2)
    data_type: DataType | None = var.data_type if var is not None else None
    if args.type is not None:
        given = data_type_named(args.type)
        if given is None:
            return _fail(f"--type {args.type!r} is not a CiA 301 type", 2)
        if od is not None and var is not None and data_type is not None and given != data_type:
            return _fail(
                f"--type {given.name} differs from the EDS's {data_type.name} for "
                f"{var.index:04X}h:{var.subindex:02X}: leave --type out",
                2,
            )
        data_type = given
    label = "" if var is None else var.name
    if var is not None and var.parent is not None and "." not in label:
        label = f"{var.parent.name}.{label}"
    where = f"{args.index:04X}h:{args.subindex:02X}" + (f" {label}" if label else "")
    payload = b""
    if args.action == "write":
        if data_type is None:
            return _fail("give --type (or --eds) so the value can be encoded", 2)
        try:
            payload = _encode(args.value, data_type, encode)
        except (ValueError, TypeError) as exc:
            return _fail(f"{args.value!r} is not a valid {data_type.name}: {exc}", 2)
    elif args.action == "upload" and not args.file.parent.is_dir():
        return _fail(f"cannot write {args.file}: there is no folder {args.file.parent}", 2)
    elif args.action == "download":
        try:
            payload = args.file.read_bytes()
        except OSError as exc:
            return _fail(f"cannot read {args.file}: {exc.strerror}", 2)
    try:
        with _open(args) as net:
            node = net.add_remote(args.node, od, sdo_timeout=args.timeout)

            def job() -> Any:
                if args.action in ("read", "upload"):
                    return node.sdo.upload(args.index, args.subindex, block=args.block)
                node.sdo.download(args.index, args.subindex, payload, block=args.block)
                return b""

            if args.action in ("upload", "download"):
                data = _with_progress(job, node.sdo, f"{args.action} {where}")
            else:
                data = job()
    except KeyboardInterrupt:
        what = "read" if args.action in ("read", "upload") else "write"
        after = "" if what == "read" else ": the node may or may not have taken the value"
        return _fail(f"interrupted: the {what} of {where} was aborted{after}", 130)
    except (CobusError, TimeoutError) as exc:
        if args.json:
            code = getattr(exc, "code", None)
            print(
                json.dumps(
                    {
                        "node": args.node,
                        "index": args.index,
                        "subindex": args.subindex,
                        "ok": False,
                        "error": str(exc),
                        "abort_code": int(code) if isinstance(code, int) else None,
                    }
                )
            )
        return _fail(f"node {args.node} {where}: {exc}")
    except Exception as exc:
        if type(exc).__module__.startswith("can"):
            return _fail(f"cannot open the bus: {exc}")
        raise
    if args.json:
        result: dict[str, Any] = {
            "node": args.node,
            "index": args.index,
            "subindex": args.subindex,
            "name": var.name if var is not None else None,
            "ok": True,
        }
        if args.action == "read":
            result["value"] = _plain(_value(data, data_type, decode))
            result["data"] = data.hex()
        elif args.action == "upload":
            if not _save(args.file, data):
                return 1
            result.update(file=str(args.file), size=len(data))
        elif args.action == "write":
            result.update(value=_plain(_value(payload, data_type, decode)), data=payload.hex())
        else:
            result.update(file=str(args.file), size=len(payload))
        print(json.dumps(result))
        return 0
    if args.action == "read":
        print(f"{where} = {_show(data, data_type, decode, hex_numbers=args.hex)}")
    elif args.action == "upload":
        if not _save(args.file, data):
            return 1
        print(f"{where}: {len(data)} bytes written to {args.file}")
    elif args.action == "write":
        print(f"{where} <- {args.value}")
    else:
        print(f"{where} <- {len(payload)} bytes from {args.file}")
    return 0


def _object(args: argparse.Namespace, od: Any) -> tuple[int, int, Any]:
    """The index, sub-index and variable (None: unknown) the arguments name; the value or
    the file put into ``args``. A ValueError says what is wrong."""
    rest = [args.rest] if isinstance(args.rest, str) else list(args.rest or [])
    if args.action != "read":
        last = rest.pop()
        if args.action == "write":
            args.value = last
        else:
            args.file = Path(last)
    if len(rest) > 1:
        raise ValueError(f"too many arguments: {' '.join(rest)}")
    sub: int | None = None
    if rest:
        try:
            sub = int(rest[0], 0) if rest[0].lower().startswith("0x") else int(rest[0])
        except ValueError:
            sub = -1
        if not 0 <= sub <= 0xFF:
            raise ValueError(f"sub-index {rest[0]!r}: a number 0-255 (2, 0x0A)")
    var = None
    try:
        index, given = _address(args.object)
    except ValueError:
        if args.object.strip().isdigit():
            raise  # (a bare number: hex or decimal? said so)
        record = _record_named(args.object, od) if sub is not None else None
        if record is not None:  # "Identity object" 1
            index, given = record, None
        else:
            var = _by_name(args.object, od)
            index, given = var.index, var.subindex
    if given is not None and sub is not None and given != sub:
        raise ValueError(
            f"{args.object!r} names sub-index {given}; the sub-index {sub} given besides differs"
        )
    subindex = sub if sub is not None else (given or 0)
    if var is None or var.subindex != subindex:
        var = od.get_variable(index, subindex) if od is not None else None
        if var is None:
            from cobus.trace.decoder import standard_variable

            var = standard_variable(index, subindex)
    return index, subindex, var


# (as cobus.master.config has it for network files: not imported for an address, as the
# master package takes a tenth of a second to load)
_ADDRESS = re.compile(r"\s*(?:0x)?([0-9a-f]{1,4})h?\s*(?:(?::|sub)\s*(0x)?([0-9a-f]{1,2})h?)?\s*\Z")


def _address(text: str) -> tuple[int, int | None]:
    """(index, sub-index or None) of ``0x1018``, ``1018h``, ``0x1018:02``, ``1018sub2``."""
    lowered = text.strip().lower()
    match = _ADDRESS.match(lowered)
    head = lowered.partition(":")[0].partition("sub")[0].strip()
    if match is None or not (head.startswith("0x") or head.endswith("h")):
        bare = match is not None and head.isdigit()
        raise ValueError(
            f"{text!r}: an index is hexadecimal, write 0x{head.upper()} or {head.upper()}h"
            if bare
            else f"{text!r} is not an object: give an address (0x1008, 1008h, 0x1018:02), "
            "or --eds FILE to name objects by the EDS's names"
        )
    index = int(match.group(1), 16)
    if not 0 < index <= 0xFFFF:
        raise ValueError(f"{text!r}: an index 0001h-FFFFh")
    return index, int(match.group(3), 16) if match.group(3) is not None else None


def _record_named(text: str, od: Any) -> int | None:
    """The index of the record or array named ``text`` (None: none is)."""
    from cobus.od import NameLookupError, Variable, resolve_object

    if od is None:
        from cobus.trace.decoder import _cia301

        od = _cia301()
    try:
        obj = resolve_object(od, text, suggest=False)
    except NameLookupError:
        return None
    return None if isinstance(obj, Variable) else obj.index


def _by_name(text: str, od: Any) -> Any:
    """The variable ``text`` names in ``od`` (an EDS), or among the CiA 301 objects without
    one; ValueError: a name nobody has (with close names)."""
    from cobus.master.config import ObjectIndex

    if od is None:
        from cobus.trace.decoder import _cia301

        od, name = _cia301(), "CiA 301 (give --eds for the node's own names)"
    else:
        name = str(getattr(od, "path", None) or "the EDS")
    return ObjectIndex(od, name).resolve(text)


def _with_progress(job: Any, sdo: Any, what: str) -> Any:
    """Run the transfer ``job`` with a progress bar on a terminal (stderr): bytes, rate and
    the time left, from the SDO channel's progress read on the loop ten times a second."""
    import threading

    from rich.console import Console
    from rich.progress import (
        BarColumn,
        DownloadColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
        TransferSpeedColumn,
    )

    console = Console(stderr=True)
    if not console.is_terminal:
        return job()
    outcome: dict[str, Any] = {}

    def work() -> None:
        try:
            outcome["value"] = job()
        except BaseException as exc:  # handed to the caller's thread below
            outcome["error"] = exc

    worker = threading.Thread(target=work, name="cobus-sdo-transfer", daemon=True)
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        DownloadColumn(),
        TransferSpeedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console, transient=True) as bar:
        task = bar.add_task(what, total=None)
        worker.start()
        while worker.is_alive():
            worker.join(0.1)
            done, total = sdo.progress
            if worker.is_alive():  # (once done, the channel is idle: (0, None))
                bar.update(task, completed=done, total=total)
        if "error" not in outcome:
            finished = bar.tasks[0].total or bar.tasks[0].completed
            bar.update(task, completed=finished, total=finished)
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")


def _encode(text: str, data_type: Any, encode: Any) -> bytes:
    from cobus.od import DataType

    if data_type.is_integer:
        value: Any = int(text, 0)
    elif data_type.is_real:
        value = float(text)
    elif data_type is DataType.BOOLEAN:
        value = text.lower() in ("1", "true", "on", "yes")
    elif data_type in (DataType.OCTET_STRING, DataType.DOMAIN):
        return bytes.fromhex(text)
    else:
        value = text
    data: bytes = encode(data_type, value)
    return data


def _save(path: Path, data: bytes) -> bool:
    try:
        path.write_bytes(data)
    except OSError as exc:
        _fail(f"cannot write {path}: {exc.strerror or exc} ({len(data)} bytes read, not kept)")
        return False
    return True


def _fitting(data: bytes, data_type: Any) -> bytes | None:
    """``data`` as ``data_type`` takes it, or None when its length does not fit the type
    (an expedited answer without size has 4 bytes: the zero bytes beyond are dropped)."""
    size = data_type.size
    if not size or len(data) == size:
        return data
    if len(data) == 4 and size < 4 and not any(data[size:]):
        return data[:size]
    return None


def _value(data: bytes, data_type: Any, decode: Any) -> Any:
    """The value of ``data`` by its type; without one (or not fitting), a number for up to
    4 bytes."""
    if data_type is not None:
        fitting = _fitting(data, data_type)
        if fitting is not None:
            try:
                return decode(data_type, fitting)
            except ValueError:
                pass
    return int.from_bytes(data, "little") if 0 < len(data) <= 4 else None


def _plain(value: Any) -> Any:
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # (JSON has no NaN or infinity)
    if isinstance(value, int | float | str | bool) or value is None:
        return value
    return str(value)


def _show(data: bytes, data_type: Any, decode: Any, *, hex_numbers: bool = False) -> str:
    """The value by its type: numbers in decimal (unsigned of 16 bits and more in hex with
    ``hex_numbers``), text as text, bytes in hex; without a type, the bytes and a guess."""
    mismatch = ""
    if data_type is not None:
        size = data_type.size
        fitting = _fitting(data, data_type)
        try:
            if fitting is None:
                mismatch = f" - {len(data)} byte(s), not a {data_type.name}"
                raise ValueError(mismatch)
            value = decode(data_type, fitting)
        except ValueError:
            pass
        else:
            if isinstance(value, str):
                return value
            if isinstance(value, bytes | bytearray):
                return bytes(value).hex(" ") or "(no data)"
            unsigned = data_type.is_integer and not data_type.is_signed and (size or 0) >= 2
            if hex_numbers and unsigned and isinstance(value, int):
                return f"0x{value:0{size * 2}X}"
            return str(value)
    shown = data.hex(" ") or "(no data)"
    if 0 < len(data) <= 4:
        number = int.from_bytes(data, "little")
        shown += f" ({number}, 0x{number:X})"
    elif data and all(32 <= b < 127 for b in data):
        shown += f" ({data.decode('ascii')!r})"
    return shown + mismatch


def _nmt(args: argparse.Namespace) -> int:
    target = 0 if args.target == "all" else None
    if target is None:
        try:
            target = _node(args.target)
        except argparse.ArgumentTypeError as exc:
            return _fail(f"{exc} or all", 2)
    try:
        with _open(args) as net:
            net.nmt.send(_NMT[args.command], target)
            net.sleep(0.05)  # (the frame goes out before the bus is closed)
    except Exception as exc:
        if type(exc).__module__.startswith(("can", "cobus")):
            return _fail(f"cannot send: {exc}")
        raise
    print(f"NMT {args.command} -> {'all nodes' if target == 0 else f'node {target}'}")
    return 0


def _frame(text: str) -> Any:
    """A frame in cansend's notation; ArgumentTypeError says what is wrong."""
    from cobus.proto import Frame, FrameError

    head, sep, body = text.partition("#")
    if body.startswith("#"):
        raise argparse.ArgumentTypeError(
            f"{text!r}: a CAN FD frame (ID##...): CANopen (CiA 301) uses classic CAN frames"
        )
    if not sep or not head or not all(c in "0123456789abcdefABCDEF" for c in head):
        raise argparse.ArgumentTypeError(
            f"{text!r}: write ID#DATA, e.g. 000#010A, 12345678#DEADBEEF or 70A#R"
        )
    if len(head) not in (3, 8):
        raise argparse.ArgumentTypeError(
            f"{text!r}: the identifier is 3 hex digits (11-bit, 000-7FF) or 8 (29-bit)"
        )
    cob_id, extended = int(head, 16), len(head) == 8
    try:
        if body[:1] in ("R", "r"):
            dlc = int(body[1:]) if body[1:] else 0
            return Frame(cob_id, b"", rtr=True, extended=extended, dlc=dlc)
        digits = body.replace(".", "")
        if len(digits) % 2 or len(digits) > 16 or not all(c in _HEX for c in digits):
            raise ValueError("the data is 0-8 bytes, each two hex digits (DE.AD or DEAD)")
        return Frame(cob_id, bytes.fromhex(digits), extended=extended)
    except (ValueError, FrameError) as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None


_HEX = frozenset("0123456789abcdefABCDEF")


def _notation(frame: Any) -> str:
    head = f"{frame.cob_id:08X}" if frame.extended else f"{frame.cob_id:03X}"
    return f"{head}#R{frame.dlc or ''}" if frame.rtr else f"{head}#{frame.data.hex().upper()}"


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 1_000_000:
        raise argparse.ArgumentTypeError(f"{text!r}: 1 to 1,000,000")
    return value


def _send(args: argparse.Namespace) -> int:
    if args.period is not None and args.count == 1:
        return _fail("--period is the time between rounds: give --count too", 2)
    sent = 0
    try:
        with _open(args) as net:
            for round_ in range(args.count):
                if round_ and args.period:
                    net.sleep(args.period)
                for frame in args.frames:
                    net.send(frame)
                    sent += 1
            net.sleep(0.05)  # (the frames go out before the bus is closed)
    except KeyboardInterrupt:
        return _fail(f"interrupted: {sent} frame(s) sent", 130)
    except Exception as exc:
        if type(exc).__module__.startswith(("can", "cobus")):
            return _fail(f"cannot send: {exc}")
        raise
    shown = [_notation(f) for f in args.frames]
    if args.json:
        print(json.dumps({"sent": sent, "frames": shown}))
    else:
        times = f" x{args.count}" if args.count > 1 else ""
        print(f"sent {' '.join(shown)}{times}")
    return 0


def _sync(args: argparse.Namespace) -> int:
    from cobus.proto import Frame
    from cobus.runtime import InterfaceTimingError

    if args.count is not None and args.count < 1:
        return _fail("--count: 1 or more", 2)
    sent = 0
    done = threading.Event()
    try:
        with _open(args) as net:
            aio = net.aio

            def heard(frame: Frame, now: float) -> None:
                # every SYNC: the network's own as it sends it, the interface's from the bus
                nonlocal sent
                sent += 1
                if sent == args.count:
                    if aio.sync.by_interface:
                        aio.sync.stop()  # at once: the interface would send the next
                    else:  # (not from within the producer's own send)
                        aio.loop.call_soon(aio.sync.stop)
                    done.set()

            async def begin() -> None:
                aio.subscribe(0x80, heard)
                aio.sync.start(args.period, overflow=args.overflow, by_interface=args.by_interface)

            try:
                net.run(begin())
            except InterfaceTimingError as exc:
                return _fail(f"--by-interface: {exc}; leave --by-interface out", 1)
            began = time.monotonic()
            limit = math.inf  # until Ctrl-C
            if args.count is not None:  # (a bus that carries none must not hang the shell)
                limit = began + args.count * args.period + max(1.0, 10 * args.period)
            try:
                while not done.wait(0.1) and time.monotonic() < limit:
                    pass
            except KeyboardInterrupt:
                pass
            net.sync.stop()
            took = time.monotonic() - began
            net.sleep(0.05)  # what is still on its way back from the bus
    except Exception as exc:
        if type(exc).__module__.startswith(("can", "cobus")):
            return _fail(f"cannot send: {exc}")
        raise
    by = " by the interface" if args.by_interface else ""
    if args.count is not None and sent < args.count:
        return _fail(
            f"only {sent} of {args.count} SYNC went out{by} in {took:.2f} s: is the bus up, "
            "and does another node acknowledge frames?"
        )
    print(f"{sent} SYNC sent{by}, every {args.period:g} s, in {took:.2f} s")
    return 0


def _sync_period(text: str) -> float:
    value = seconds(text)
    if not 1e-6 <= value <= 4294.967295:
        raise argparse.ArgumentTypeError(f"{text!r}: 0.000001 to 4294.967295 s (1006h)")
    return value


def _overflow(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        value = -1
    if not (value == 0 or 2 <= value <= 240):
        raise argparse.ArgumentTypeError(f"{text!r}: 0 (no counter) or 2 to 240")
    return value
