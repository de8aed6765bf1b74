"""``cobus gateway``: the CiA 309-3 ASCII gateway on a bus, over TCP.

Any program that can open a TCP socket reads and writes objects and sends NMT commands,
several at once: ``printf '[1] 5 r 0x1018 1 u32\\n' | nc 127.0.0.1 PORT``. Each client has
its own defaults (``set node 5``); requests to one node run in turn, to different nodes
side by side. ``help`` lists the commands. The gateway serves only this host (127.0.0.1).

Exit codes: 0 ended by Ctrl-C, 1 the bus or the port could not be opened, 2 bad usage.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from functools import partial
from typing import Any

from cobus._args import add_bus_options, bus_options, host_port

__all__ = ["register"]

_EXIT_OK, _EXIT_OPEN, _EXIT_USAGE = 0, 1, 2


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
        default=("127.0.0.1", 5000),
        metavar="HOST:PORT",
        help="where to listen (default 127.0.0.1:5000; only this host is served)",
    )
    p.add_argument(
        "--dialect",
        choices=("canopennode", "lely"),
        default="canopennode",
        help="how replies are written: CANopenNode's (decimal, ERROR:101 #text, the default) "
        "or Lely's (unsigned in hex, ERROR: 101 (text))",
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
    from cobus.apps.gateway import is_loopback

    host, _port = args.listen
    if not is_loopback(host):
        return _fail(
            f"--listen {host}: the gateway writes to the bus, so it serves only this host "
            "(127.0.0.1 or ::1) until tokens are built",
            _EXIT_USAGE,
        )
    served: list[str] = []
    try:
        return asyncio.run(_serve(args, served))
    except KeyboardInterrupt:
        print(
            "cobus gateway: stopped by Ctrl-C"
            + (f" after serving on {served[0]}" if served else ""),
            file=sys.stderr,
        )
        return _EXIT_OK


async def _serve(args: argparse.Namespace, served: list[str]) -> int:
    from cobus.apps.gateway import GatewayCore, GatewayServer
    from cobus.errors import CobusError
    from cobus.runtime import AsyncNetwork

    network = AsyncNetwork(**bus_options(args))
    try:
        await network.connect()
    except (CobusError, OSError, ValueError) as exc:
        return _fail(f"cannot open the bus: {exc}", _EXIT_OPEN)
    host, port = args.listen
    idle = args.idle_timeout if args.idle_timeout > 0 else None
    core = GatewayCore({1: network}, dialect=args.dialect)
    server = GatewayServer(core, host, port, idle_timeout=idle)
    try:
        try:
            await server.start()
        except OSError as exc:
            return _fail(f"cannot listen on {host}:{port}: {exc.strerror or exc}", _EXIT_OPEN)
        served.append(f"{host}:{server.port}")
        print(f"cobus gateway: serving net 1 on {host}:{server.port}", flush=True)
        await asyncio.Event().wait()
        return _EXIT_OK
    finally:
        await server.stop()
        await network.disconnect()
