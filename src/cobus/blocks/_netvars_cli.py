"""cobus netvars: network variables over UDP with CODESYS controllers (.gvl files).

    cobus netvars watch plant.gvl --udp --bind 0.0.0.0        # each list received, by name
    cobus netvars watch plant.gvl io.gvl --udp --json --count 10
    cobus netvars send plant.gvl --udp --bind 0.0.0.0 --to 192.168.1.20:1202 speed=1.5
    cobus netvars gvl netvars.yml line_status.gvl             # cobus's lists for CODESYS

A .gvl file is what CODESYS exports of a network variable list; user STRUCT and ENUM
types go beside it as ST text (--types). watch listens on 127.0.0.1 unless --bind says
otherwise (0.0.0.0: telegrams from other hosts); send writes one transmission of a list to
--to (else to the address and port in the file; a broadcast address needs --broadcast).
Values not given to send go as 0 (FALSE, empty text), and a line says which.

Exit codes: 0 done, 1 the network failed, 2 bad usage or a file cobus cannot use,
130 interrupted (Ctrl-C; watch says what it received).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import datetime as dt
import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any

__all__ = ["register"]

_HELP = "network variables over UDP with CODESYS controllers (.gvl): watch, send, export"


def _endpoint(text: str) -> tuple[str, int]:
    host, colon, port = text.rpartition(":")
    if (
        not colon
        or not host
        or not (port.isascii() and port.isdigit())
        or not 0 < int(port) < 65_536
    ):
        raise argparse.ArgumentTypeError(f"{text!r}: give HOST:PORT, e.g. 192.168.1.20:1202")
    return host.strip("[]"), int(port)


def _port(text: str) -> int:
    if not (text.isascii() and text.isdigit()) or not 0 <= int(text) < 65_536:
        raise argparse.ArgumentTypeError(f"{text!r}: a UDP port, 0..65535")
    return int(text)


class _AnyOrder(argparse.ArgumentParser):
    """A parser of one action that takes its options and its positionals in any order
    (``NAME=VALUE`` after ``--to HOST:PORT``)."""

    _inside = False

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        if self._inside:  # (parse_known_intermixed_args calls back here)
            return super().parse_known_args(args, namespace)
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


def register(sub: Any) -> None:
    """Add ``cobus netvars ...`` to the top-level sub-command parser."""
    netvars: argparse.ArgumentParser = sub.add_parser(
        "netvars",
        help=_HELP,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = netvars.add_subparsers(
        dest="action", metavar="ACTION", required=True, parser_class=_AnyOrder
    )
    watch = actions.add_parser(
        "watch", help="print each list received", description="print each list received"
    )
    send = actions.add_parser(
        "send", help="send a list once", description="send one transmission of a list"
    )
    for p in (watch, send):
        p.add_argument(
            "--udp",
            action="store_true",
            help="over UDP: the form .gvl files give, the only one here (for clarity)",
        )
        p.add_argument(
            "--types",
            type=Path,
            action="append",
            default=[],
            metavar="FILE",
            help="ST text of user STRUCT/ENUM types (TYPE ... END_TYPE); again for more",
        )
        p.add_argument("--json", action="store_true", help="print JSON lines")
    watch.add_argument("gvl", type=Path, nargs="+", help="the lists' .gvl files")
    watch.add_argument("--bind", default="127.0.0.1", help="listen here (default 127.0.0.1)")
    watch.add_argument("--port", type=_port, default=1202, help="UDP port (default 1202)")
    watch.add_argument(
        "--share-port",
        action="store_true",
        help="share the port with another program on this host (a CODESYS runtime)",
    )
    watch.add_argument("--count", type=int, help="stop after this many lists received")
    watch.add_argument("--seconds", type=float, help="stop after this many seconds")
    watch.set_defaults(handler=_watch)
    send.add_argument("gvl", type=Path, help="the list's .gvl file")
    send.add_argument("values", nargs="*", metavar="NAME=VALUE", help="values by name")
    send.add_argument("--to", type=_endpoint, help="HOST:PORT (default: the file's address)")
    send.add_argument("--bind", default="127.0.0.1", help="send from here (default 127.0.0.1)")
    send.add_argument("--broadcast", action="store_true", help="allow a broadcast address")
    send.set_defaults(handler=_send)
    gvl = actions.add_parser(
        "gvl",
        help="write cobus's lists (YAML) as .gvl files for CODESYS",
        description="write cobus's lists (a network variable YAML file) as .gvl files "
        "CODESYS imports ('Import from file'): one list to OUT, several into the folder OUT",
    )
    gvl.add_argument("netvars", type=Path, help="cobus's network variable definition (YAML)")
    gvl.add_argument("out", help="the .gvl file (one list) or a folder (several; or OUT/)")
    gvl.add_argument("--list", action="append", dest="lists", help="only this list; again")
    gvl.add_argument(
        "--address", default="255.255.255.255", help="the address the file gives (broadcast)"
    )
    gvl.add_argument("--port", type=_port, default=1202, help="UDP port (default 1202)")
    gvl.add_argument("--json", action="store_true", help="print the files written as JSON")
    gvl.set_defaults(handler=_gvl)


def _fail(action: str, text: str, code: int) -> int:
    print(f"cobus netvars {action}: {text}", file=sys.stderr)
    return code


def _lists(args: argparse.Namespace, paths: list[Path]) -> Any:
    """The lists of the .gvl files (or the exit code of what cannot be read)."""
    from cobus.blocks.gvl import GvlError, StTypes, load_gvl, parse_st_types
    from cobus.blocks.netvar_udp import UdpDefinition

    types: StTypes | None = None
    try:
        if args.types:
            merged = StTypes({}, {}, {})
            for path in args.types:
                try:
                    text = path.read_text(encoding="utf-8-sig")
                except OSError as exc:
                    raise GvlError(f"{path}: {exc.strerror or exc}") from None
                found = parse_st_types(text, str(path))
                again = set(found.spelled) & set(merged.spelled)
                if again:
                    twice = ", ".join(sorted(found.spelled[n] for n in again))
                    raise GvlError(f"{path}: {twice} defined in another --types file too")
                merged.structs.update(found.structs)
                merged.enums.update(found.enums)
                merged.aliases.update(found.aliases)
                merged.spelled.update(found.spelled)
            types = merged
        return UdpDefinition.of(load_gvl(p, types=types) for p in paths)
    except (GvlError, ValueError) as exc:
        return _fail(args.action, str(exc), 2)


def _why(exc: Exception) -> str:
    """An error's text (a KeyError's without the quotes ``str`` adds)."""
    if isinstance(exc, KeyError) and exc.args:
        return str(exc.args[0])
    return str(exc)


def _plain(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def _watch(args: argparse.Namespace) -> int:
    from cobus.blocks.netvars import (
        AsyncUdpNetworkVariables,
        ListIncomplete,
        ListMalformed,
        ListReceived,
        NetVarEvent,
    )

    definition = _lists(args, args.gvl)
    if isinstance(definition, int):
        return definition
    if args.count is not None and args.count < 1:
        return _fail("watch", "--count: 1 or more", 2)
    if args.seconds is not None and not args.seconds > 0:
        return _fail("watch", "--seconds: a time above 0", 2)
    try:
        lists = AsyncUdpNetworkVariables(
            definition, bind=args.bind, port=args.port, share_port=args.share_port
        )
    except (KeyError, ValueError) as exc:
        return _fail("watch", _why(exc), 2)
    received = 0
    broken = False
    stopped_by: list[int] = []

    def show(event: NetVarEvent) -> None:
        nonlocal broken
        try:
            shown(event)
        except BrokenPipeError:  # (the reader went away: `| head`)
            broken = True
            done.set()

    def shown(event: NetVarEvent) -> None:
        nonlocal received
        when = dt.datetime.now().isoformat(timespec="milliseconds")
        if isinstance(event, ListReceived):
            received += 1
            if args.json:
                values = {k: _plain(v) for k, v in event.values.items()}
                line = {"time": when, "list": event.list, "counter": event.counter}
                print(json.dumps({**line, "values": values}), flush=True)
            else:
                shown = "  ".join(f"{k}={v!r}" for k, v in event.values.items())
                print(f"{when}  {event.list} #{event.counter}  {shown}", flush=True)
            if args.count is not None and received >= args.count:
                done.set()
        elif isinstance(event, ListIncomplete | ListMalformed):
            if args.json:
                kind = "incomplete" if isinstance(event, ListIncomplete) else "malformed"
                print(json.dumps({"time": when, "list": event.list, kind: str(event)}), flush=True)
            else:
                print(f"{when}  # {event}", flush=True)

    done = asyncio.Event()

    async def run() -> None:
        await lists.open()
        with contextlib.suppress(NotImplementedError, AttributeError, ValueError, RuntimeError):
            # SIGTERM as Ctrl-C: the summary, then 143 (where the loop takes signals)
            def terminated() -> None:
                stopped_by.append(143)
                done.set()

            asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, terminated)
        try:
            lists.add_listener(show)
            host, port = lists.address
            print(
                f"# listening on {host}:{port} for {', '.join(definition.lists)}",
                file=sys.stderr,
                flush=True,
            )
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(done.wait(), args.seconds)
        finally:
            lists.close()

    interrupted = False
    try:
        asyncio.run(run())
    except KeyboardInterrupt:
        interrupted = True
    except OSError as exc:
        return _fail("watch", str(exc.strerror or exc), 1)
    finally:
        lists.close()
    if broken:
        raise BrokenPipeError  # (cobus's main ends quietly)
    stats = lists.statistics()
    dropped = lists.dropped()
    counts = ", ".join(f"{name} {s['received']}" for name, s in stats.items())
    lost = [
        f"{n} {what}"
        for what, n in (
            ("no telegrams", dropped["not_telegrams"]),
            ("of other lists", dropped["foreign"]),
            ("incomplete", sum(s["incomplete"] for s in stats.values())),
            ("malformed", sum(s["malformed"] for s in stats.values())),
            ("late or repeated telegrams", sum(s.get("late", 0) for s in stats.values())),
            ("with flags", sum(s.get("flagged", 0) for s in stats.values())),
            ("of lists it sends", dropped["of_own_lists"]),
        )
        if n
    ]
    summary = f"{received} list(s) received ({counts})" + (
        f"; dropped: {', '.join(lost)}" if lost else ""
    )
    if interrupted:
        return _fail("watch", f"interrupted: {summary}", 130)
    if stopped_by:
        return _fail("watch", f"terminated: {summary}", 143)
    print(f"# {summary}", file=sys.stderr)
    return 0


def _value(var: Any, text: str) -> Any:
    """A value for a variable from the command line, as its type takes it."""
    from cobus.blocks.gvl import iec_time

    kind = var.type
    if kind.code in "sw":
        return text
    if kind.name == "BOOL":
        lowered = text.strip().lower()
        if lowered in ("true", "1"):
            return True
        if lowered in ("false", "0"):
            return False
        raise ValueError(f"{var.name}: BOOL takes TRUE or FALSE")
    if kind.code in "fd":
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"{var.name}: {kind.name} takes a number, not {text!r}") from None
    if kind.name == "TIME" and "#" in text:
        return round(iec_time(text) * 1000)
    word = text.strip().replace("_", "")
    try:
        if "#" in word:  # (16#FF, 2#1010)
            base, _, digits = word.partition("#")
            return int(digits, int(base))
        return int(word, 0)
    except ValueError:
        raise ValueError(f"{var.name}: {kind.name} takes a whole number, not {text!r}") from None


def _send(args: argparse.Namespace) -> int:
    from cobus.blocks.netvars import AsyncUdpNetworkVariables, ListSendFailed, NetVarEvent

    definition = _lists(args, [args.gvl])
    if isinstance(definition, int):
        return definition
    (lst,) = definition.lists.values()
    values: dict[str, Any] = {}
    try:
        for given in args.values:
            name, eq, text = given.partition("=")
            if not eq:
                raise ValueError(f"{given!r}: give NAME=VALUE")
            var = lst.variable(name.strip())
            values[var.name] = var.decode(var.encode(_value(var, text)))
    except (KeyError, ValueError) as exc:
        return _fail("send", _why(exc), 2)
    try:
        lists = AsyncUdpNetworkVariables(
            definition,
            send=[lst.name],
            bind=args.bind,
            port=0,
            to=args.to,
            broadcast=args.broadcast,
            # (each run a counter of its own: a receiver drops a repeat of the last one)
            first_counter=time.time_ns() // 1_000_000,
        )
    except (KeyError, ValueError) as exc:
        return _fail("send", _why(exc), 2)
    failed: list[str] = []

    def on(event: NetVarEvent) -> None:
        if isinstance(event, ListSendFailed):
            failed.append(event.reason)

    async def run() -> None:
        lists.add_listener(on)
        lists.set(lst.name, values)  # (before open: one transmission, this one)
        await lists.open()
        try:
            if not lists.statistics()[lst.name]["sent"] and not failed:
                lists.send(lst.name)
        finally:
            lists.close()

    try:
        asyncio.run(run())
    except OSError as exc:
        return _fail("send", str(exc.strerror or exc), 1)
    finally:
        lists.close()
    if failed:
        return _fail("send", failed[0], 1)
    where = args.to or (lst.address, lst.port)
    left = [v.name for v in lst.variables if v.name not in values]
    if left:
        shown = ", ".join(left[:10]) + (f" and {len(left) - 10} more" if len(left) > 10 else "")
        print(f"# not given, sent as 0 or empty: {shown}", file=sys.stderr)
    telegrams = lst.frames
    if args.json:
        print(
            json.dumps(
                {
                    "list": lst.name,
                    "to": f"{where[0]}:{where[1]}",
                    "telegrams": telegrams,
                    "values": {k: _plain(v) for k, v in lists.values(lst.name).items()},
                }
            )
        )
    else:
        print(f"{lst.name}: sent to {where[0]}:{where[1]} ({telegrams} telegram(s))")
    return 0


def _gvl(args: argparse.Namespace) -> int:
    from cobus.blocks.gvl import dumps_gvl
    from cobus.blocks.netvar_lists import NetVarConfigError, load_netvars
    from cobus.blocks.netvar_udp import udp_list

    try:
        definition = load_netvars(args.netvars)
    except NetVarConfigError as exc:
        return _fail("gvl", str(exc), 2)
    except OSError as exc:
        return _fail("gvl", f"{args.netvars}: {exc.strerror or exc}", 2)
    names = args.lists or list(definition.lists)
    try:
        chosen = [definition[name] for name in names]
        texts = {
            lst.name: dumps_gvl(udp_list(lst, address=args.address, port=args.port))
            for lst in chosen
        }
    except (KeyError, ValueError) as exc:
        return _fail("gvl", _why(exc), 2)
    out = Path(args.out)
    folder = out.is_dir() or args.out.endswith(("/", "\\"))
    if len(texts) == 1 and not folder:
        targets = {out: next(iter(texts.values()))}
    else:
        if out.exists() and not out.is_dir():
            return _fail("gvl", f"{out}: {len(texts)} lists go into a folder, not a file", 2)
        targets = {out / f"{name}.gvl": text for name, text in texts.items()}
    try:
        if out not in targets:
            out.mkdir(parents=True, exist_ok=True)
        for path, text in targets.items():
            path.write_text(text, encoding="utf-8")
    except OSError as exc:
        return _fail("gvl", f"cannot write {exc.filename}: {exc.strerror or exc}", 1)
    if args.json:
        print(json.dumps({name: str(path) for name, path in zip(texts, targets, strict=True)}))
    else:
        for path in targets:
            print(path)
    return 0
