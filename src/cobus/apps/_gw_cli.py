"""``cobus gw``: requests to a CiA 309-3 gateway, the replies as data.

    cobus gw 127.0.0.1:5000 '5 r 0x1018 1 u32' '5 r 0x1008 0 vs'
    cobus gw 127.0.0.1:5000 -f commands.txt --json
    printf 'set node 5\\nr 0x1017 0 u16\\n' | cobus gw 127.0.0.1:5000
    cobus gw /run/cobus-gw.sock '0 start'

Requests come from the arguments, else from the files of ``-f``, else from standard input,
one a line (``#`` comments and blank lines skipped); each is answered in turn, a value on a
line of its own (OK answers print nothing), or with ``--json`` one JSON object a request.
Every request is sent even after an error; the exit code is the first error's kind.
Unsolicited lines (after ``subscribe``) go to standard error, or as ``{"event": ...}``
objects with ``--json``. Options may come anywhere (``cobus gw H:P --json info``). A gateway
that wants a token for writes gets it from ``COBUS_GATEWAY_TOKEN`` (or ``--token``) when
it first asks; one that asks for none never sees it.

Exit codes: 0 all answered OK, 1 an SDO abort, 2 bad usage or a request the gateway calls a
syntax error, 3 no answer (time-out), 4 refused by the gateway (no default node, unknown
command...), 5 the gateway could not be reached or closed the connection.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from typing import Any

from cobus._args import host_port

__all__ = ["register"]

_EXIT = {"abort": 1, "syntax": 2, "timeout": 3, "refused": 4}
_EXIT_CONNECT = 5


def register(sub: Any) -> None:
    """Add ``cobus gw``."""
    p = sub.add_parser(
        "gw",
        help="send requests to a CiA 309-3 gateway and print the replies as data",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "address",
        type=_address,
        metavar="HOST:PORT",
        help="the gateway (a path with a / in it: its Unix socket)",
    )
    # (the words after HOST:PORT - requests and options mixed - are sorted by _options)
    p.add_argument("requests", nargs=argparse.REMAINDER, metavar="REQUEST", help="request lines")
    _add_options(p)
    p.set_defaults(handler=_run)


def _add_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "-f", "--file", action="append", default=[], metavar="FILE", help="a file of requests"
    )
    p.add_argument("--json", action="store_true", help="one JSON object a request")
    p.add_argument(
        "--token",
        help="the gateway's token, given when the gateway asks for it (default: "
        "COBUS_GATEWAY_TOKEN, if set)",
    )
    p.add_argument(
        "--timeout", type=float, default=30.0, help="seconds to wait for each reply (30)"
    )


def _options(args: argparse.Namespace) -> argparse.Namespace:
    """The options written among the requests (after HOST:PORT) taken out of them."""
    if not any(word.startswith("-") for word in args.requests):
        return args
    parser = argparse.ArgumentParser(prog="cobus gw", add_help=False)
    _add_options(parser)
    parser.add_argument("requests", nargs="*")
    parser.set_defaults(
        file=list(args.file), json=args.json, token=args.token, timeout=args.timeout
    )
    mixed = parser.parse_intermixed_args(args.requests)
    for name in ("file", "json", "token", "timeout", "requests"):
        setattr(args, name, getattr(mixed, name))
    return args


def _address(text: str) -> tuple[str, int]:
    """HOST:PORT, or a Unix socket's path (port 0)."""
    if "/" in text:
        return text, 0
    return host_port(text)


def _lines(args: argparse.Namespace) -> Iterator[str]:
    if args.requests:
        sources: list[Any] = [args.requests]
    elif args.file:
        sources = []
        for name in args.file:
            with open(name, encoding="utf-8") as f:
                sources.append(f.read().splitlines())
    else:
        sources = [sys.stdin]
    for source in sources:
        for line in source:
            text = line.strip()
            if text and not text.startswith("#"):
                yield text


def _run(args: argparse.Namespace) -> int:
    import os

    from cobus.apps.gateway.client import GatewayClient, TokenRefused, error_class

    args = _options(args)
    host, port = args.address
    where = host if port == 0 else f"{host}:{port}"
    token = args.token if args.token is not None else os.environ.get("COBUS_GATEWAY_TOKEN")
    try:
        lines = list(_lines(args))
    except OSError as exc:
        print(f"cobus gw: {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    first_error = 0
    done = 0
    try:
        unix = host if port == 0 else None
        with GatewayClient(host, port, args.timeout, unix=unix, token=token) as client:
            for line in lines:
                reply = client.request(line)
                done += 1
                for event in client.events:  # (unsolicited lines: not data of any reply)
                    if args.json:
                        print(json.dumps({"event": event}), flush=True)
                    else:
                        print(f"cobus gw: event: {event}", file=sys.stderr)
                client.events.clear()
                if args.json:
                    print(json.dumps(reply.as_dict()), flush=True)
                elif reply.ok:
                    for extra in reply.lines:
                        print(extra)
                    if reply.value is not None:
                        print(reply.value, flush=True)
                else:
                    code = reply.code or 0
                    shown = f"0x{code:08X}" if code > 0xFFFF else str(code)
                    print(f"cobus gw: {line}: error {shown}: {reply.text}", file=sys.stderr)
                if not reply.ok and not first_error:
                    first_error = _EXIT[error_class(reply.code)]
    except KeyboardInterrupt:
        print(f"cobus gw: stopped by Ctrl-C after {done} of {len(lines)} requests", file=sys.stderr)
        return 130
    except TimeoutError:
        print(
            f"cobus gw: no reply within {args.timeout:g} s (--timeout); the {len(lines) - done} "
            "requests from there on were not answered",
            file=sys.stderr,
        )
        return _EXIT["timeout"]
    except TokenRefused as exc:
        print(f"cobus gw: {where}: {exc}", file=sys.stderr)
        return _EXIT["refused"]
    except (OSError, ConnectionError) as exc:
        print(
            f"cobus gw: {where}: {getattr(exc, 'strerror', None) or exc} "
            f"(after {done} of {len(lines)} requests)",
            file=sys.stderr,
        )
        return _EXIT_CONNECT
    return first_error
