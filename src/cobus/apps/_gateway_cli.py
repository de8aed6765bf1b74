"""``cobus gateway``: the CiA 309-3 ASCII gateway on one bus or several, over TCP or a Unix
socket.

Any program that can open a socket reads and writes objects and sends NMT commands, several
at once: ``printf '[1] 5 r 0x1018 1 u32\\n' | nc 127.0.0.1 PORT``. Each client has its own
defaults (``set node 5``); requests to one node run in turn, to different nodes side by
side. ``help`` lists the commands.

Net 1 is the bus of -i/-c/-b (or python-can's configuration); ``--net 2=socketcan:can1``
adds more, addressed as ``[seq] 2 5 r 0x1000 0`` or after ``set network 2``. With a node's
EDS (``--eds 5=drive.eds``, ``--eds 2:7=io.eds`` for net 2) its objects go by name and
type: ``[1] 5 r "Device name"``, ``[2] 5 w "Producer heartbeat time" 500``. With
``--node-id 64`` the gateway is node 64 of net 1 too, a device a master can guard.

The gateway serves only this host (127.0.0.1) unless ``--listen`` names another address;
then clients must give a token (``auth TOKEN``) before they write, send NMT commands or use
LSS: ``--token``, or ``COBUS_GATEWAY_TOKEN``, or a random one it prints; five wrong tokens
and a client must connect again. A Unix socket (``--unix PATH``) is this user's only and
its clients need no token.

Exit codes: 0 ended by Ctrl-C, 1 a bus or the address could not be opened, 2 bad usage.
"""

from __future__ import annotations

import argparse
import asyncio
import re
import sys
from functools import partial
from typing import Any

from cobus._args import add_bus_options, bus_options, host_port, load_eds

__all__ = ["register"]

_EXIT_OK, _EXIT_OPEN, _EXIT_USAGE = 0, 1, 2


def _net_spec(text: str) -> tuple[int, dict[str, Any]]:
    """``N=INTERFACE:CHANNEL[@BITRATE]`` as an argparse type."""
    usage = f"{text!r}: give N=INTERFACE:CHANNEL[@BITRATE], e.g. 2=socketcan:can1"
    number, sep, bus = text.partition("=")
    interface, colon, channel = bus.partition(":")
    if not sep or not colon or not re.fullmatch("[0-9]+", number) or not interface or not channel:
        raise argparse.ArgumentTypeError(usage)
    if not 2 <= int(number) <= 127:
        raise argparse.ArgumentTypeError(
            f"{text!r}: --net numbers the other buses 2..127 (net 1 is -i/-c/-b)"
        )
    options: dict[str, Any] = {"interface": interface, "channel": channel}
    head, at, rate = channel.rpartition("@")
    if at and re.fullmatch("[0-9]+", rate) and head:
        if int(rate) == 0:
            raise argparse.ArgumentTypeError(f"{text!r}: a bit rate of 0")
        options.update(channel=head, bitrate=int(rate))
    return int(number), options


def _eds_spec(text: str) -> tuple[int, int, str]:
    """``[NET:]NODE=FILE`` as an argparse type."""
    where, sep, path = text.partition("=")
    net, colon, node = where.rpartition(":")
    numbers = [net or "1", node]
    if not sep or not path or not all(re.fullmatch("[0-9]+", n) for n in numbers):
        raise argparse.ArgumentTypeError(f"{text!r}: give [NET:]NODE=FILE, e.g. 5=drive.eds")
    del colon
    if not 1 <= int(numbers[0]) <= 127 or not 1 <= int(node) <= 127:
        raise argparse.ArgumentTypeError(f"{text!r}: nets and nodes are numbered 1..127")
    return int(numbers[0]), int(node), path


#: How long the gateway listens before it takes its --node-id (s): a node beating on the bus
#: within that time is seen (heartbeats come every second or faster).
_HEAR_FIRST = 1.5


def _node_id_spec(text: str) -> tuple[int, int]:
    """``[NET:]NODE`` as an argparse type."""
    net, _colon, node = text.rpartition(":")
    numbers = [net or "1", node]
    if not all(re.fullmatch("[0-9]+", n) for n in numbers):
        raise argparse.ArgumentTypeError(f"{text!r}: give [NET:]NODE, e.g. 64 or 2:64")
    if not 1 <= int(numbers[0]) <= 127 or not 1 <= int(node) <= 127:
        raise argparse.ArgumentTypeError(f"{text!r}: nets and nodes are numbered 1..127")
    return int(numbers[0]), int(node)


def register(sub: Any) -> None:
    """Add ``cobus gateway``."""
    p = sub.add_parser(
        "gateway",
        help="the CiA 309-3 ASCII gateway: the bus from any program over TCP",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--listen",
        type=partial(host_port, listening=True),
        metavar="HOST:PORT",
        help="where to listen (default 127.0.0.1:5000 unless --unix or --http is given; "
        "another host than this one needs a token)",
    )
    p.add_argument("--unix", metavar="PATH", help="listen on this Unix socket (this user's only)")
    p.add_argument(
        "--http",
        type=partial(host_port, listening=True),
        metavar="HOST:PORT",
        help="serve HTTP in gocanopen's CiA 309-5 URLs (/cia309-5/1.0/SEQ/NET/NODE/"
        "r/INDEX/SUB...) and a WebSocket of events; beyond this host writes need "
        "Authorization: Bearer TOKEN",
    )
    p.add_argument(
        "--token",
        help="the token clients give (auth TOKEN) before they write, send NMT or use LSS "
        "(default: COBUS_GATEWAY_TOKEN, else none on this host, a random one beyond it)",
    )
    p.add_argument(
        "--net",
        type=_net_spec,
        action="append",
        default=[],
        metavar="N=INTERFACE:CHANNEL[@BITRATE]",
        help="one more bus, as net N (net 1 is the bus of -i/-c/-b)",
    )
    p.add_argument(
        "--eds",
        type=_eds_spec,
        action="append",
        default=[],
        metavar="[NET:]NODE=FILE",
        help="a node's EDS or DCF: its objects by name and type (net 1 unless NET: is given)",
    )
    p.add_argument(
        "--node-id",
        type=_node_id_spec,
        action="append",
        default=[],
        metavar="[NET:]NODE",
        help="the gateway is this node of the net too, a CANopen device of its own "
        "(heartbeat, guarding, SDO server; net 1 unless NET: is given); clients: set id N",
    )
    p.add_argument(
        "--dialect",
        choices=("canopennode", "lely"),
        default="canopennode",
        help="how replies are written: CANopenNode's (decimal, ERROR:101 #text, the default) "
        "or Lely's (unsigned in hex, ERROR: 101 (text))",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help='JSON lines instead of CiA 309-3 text: {"seq": 1, "node": 5, "command": "r", '
        '"args": ["0x1018", 1, "u32"]} (or {"line": "..."}) in, {"seq": 1, "ok": true, '
        '"value": "..."} or {"event": "..."} out',
    )
    p.add_argument(
        "--idle-timeout",
        type=float,
        default=600.0,
        metavar="SECONDS",
        help="close a client's connection after this long without a request (600; 0: never)",
    )
    add_bus_options(p)
    p.set_defaults(handler=_run)


def _fail(message: str, code: int) -> int:
    print(f"cobus gateway: {message}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    from cobus.apps._serving import gateway_token
    from cobus.errors import CobusError

    nets: dict[int, dict[str, Any]] = {1: bus_options(args)}
    for number, options in args.net:
        if number in nets:
            return _fail(f"--net {number}: net {number} is given twice", _EXIT_USAGE)
        nets[number] = options
    if args.listen is None and args.unix is None and args.http is None:
        args.listen = ("127.0.0.1", 5000)
    hosts = [a[0] for a in (args.listen, args.http) if a is not None]
    try:
        token, drawn = gateway_token(args.token, hosts)
    except ValueError as exc:
        return _fail(f"the token: {exc}", _EXIT_USAGE)
    if drawn:
        print(f"cobus gateway: clients write after: auth {token}", flush=True)
    dictionaries: dict[tuple[int, int], Any] = {}
    for net, node, path in args.eds:
        if net not in nets:
            return _fail(f"--eds {net}:{node}={path}: there is no net {net}", _EXIT_USAGE)
        try:
            dictionaries[(net, node)] = load_eds(path, "gateway", node_id=node)
        except OSError as exc:
            return _fail(f"--eds {path}: {exc.strerror or exc}", _EXIT_USAGE)
        except (ValueError, CobusError) as exc:  # (the error names the file)
            return _fail(f"--eds: {exc}", _EXIT_USAGE)
    args.dictionaries = dictionaries
    given: set[int] = set()
    for net, node in args.node_id:
        if net not in nets:
            return _fail(f"--node-id {net}:{node}: there is no net {net}", _EXIT_USAGE)
        if net in given:
            return _fail(f"--node-id: net {net} is given a node-ID twice", _EXIT_USAGE)
        given.add(net)
    served: list[str] = []
    try:
        return asyncio.run(_serve(args, nets, token, served))
    except KeyboardInterrupt:
        where = f" after serving on {' and '.join(served)}" if served else ""
        print(f"cobus gateway: stopped by Ctrl-C{where}", file=sys.stderr)
        return _EXIT_OK


async def _serve(
    args: argparse.Namespace, nets: dict[int, dict[str, Any]], token: str | None, served: list[str]
) -> int:
    from cobus.apps.gateway import GatewayCore, GatewayError, GatewayServer
    from cobus.apps.gateway.http import GatewayHttp
    from cobus.errors import CobusError
    from cobus.runtime import AsyncNetwork

    networks: dict[int, AsyncNetwork] = {}
    servers: list[GatewayServer | GatewayHttp] = []
    core: GatewayCore | None = None
    try:
        for number, options in sorted(nets.items()):
            network = AsyncNetwork(**options)
            try:
                await network.connect()
            except (CobusError, OSError, ValueError) as exc:
                which = "" if len(nets) == 1 else f" of net {number}"
                return _fail(f"cannot open the bus{which}: {exc}", _EXIT_OPEN)
            networks[number] = network
        idle = args.idle_timeout if args.idle_timeout > 0 else None
        core = GatewayCore(
            networks, dialect=args.dialect, token=token, dictionaries=args.dictionaries
        )
        if args.node_id:  # (first hear what beats on the buses: a node-ID in use is refused)
            core.listen()
            await asyncio.sleep(_HEAR_FIRST)
        for net, node in args.node_id:
            try:
                core.set_node_id(net, node)
            except GatewayError as exc:
                return _fail(f"--node-id {net}:{node}: {exc.text}", _EXIT_USAGE)
        if args.listen is not None:
            host, port = args.listen
            servers.append(GatewayServer(core, host, port, idle_timeout=idle, json_lines=args.json))
        if args.unix is not None:
            servers.append(
                GatewayServer(core, unix=args.unix, idle_timeout=idle, json_lines=args.json)
            )
        if args.http is not None:
            servers.append(GatewayHttp(core, *args.http))
        for server in servers:
            try:
                await server.start()
            except OSError as exc:
                where = getattr(server, "unix", None) or f"{server.host}:{server.requested_port}"
                return _fail(f"cannot listen on {where}: {exc.strerror or exc}", _EXIT_OPEN)
            served.append(server.address)
        which = ", ".join(str(n) for n in networks)
        print(
            f"cobus gateway: serving net{'s' if len(networks) > 1 else ''} {which} on "
            f"{' and '.join(served)}",
            flush=True,
        )
        await asyncio.Event().wait()
        return _EXIT_OK
    finally:
        for server in servers:
            await server.stop()
        if core is not None:
            core.close()
        for network in networks.values():
            await network.disconnect()
