"""The ``cobus`` command line.

Each area of the package contributes its sub-commands through a ``register(subparsers)``
function in a private ``_cli`` module; this file only assembles them, so adding a command never
means editing the others.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Sequence

from cobus import __version__

# Modules with a ``register(subparsers)`` function, in the order their commands are listed.
_COMMAND_MODULES = (
    "cobus.od._cli",
    "cobus.master._cli",
    "cobus.sim._cli",
    "cobus.profiles._cli",
    "cobus.blocks._cli",
    "cobus.blocks._alarms_cli",
    "cobus.trace._cli",
    "cobus.trace.monitor",
    "cobus.trace.plot",
    "cobus.trace.scan",
    "cobus.apps._node_cli",
    "cobus.apps.demo",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cobus",
        description="CANopen master, device, simulators and tools.",
        epilog="Exit codes, the same in every command: 0 done, 1 the bus, a node or a file "
        "failed (one line on stderr says which and why), 2 bad usage or a bad input file, "
        "3 differences found (params diff), 130 interrupted (Ctrl-C).",
    )
    parser.add_argument("--version", action="version", version=f"cobus {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            # An area not built yet is skipped; a missing dependency inside one is an error.
            if exc.name is None or not name.startswith(exc.name):
                raise
            continue
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = getattr(args, "handler", None)
    if handler is None:
        parser.print_help()
        return 2
    try:
        result = handler(args)
    except KeyboardInterrupt:
        # (a command with something to say of what it had done says it, and returns 130)
        print(f"cobus {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader went away (`cobus monitor | head`): end quietly, and let the flush at
        # exit write to nowhere instead of reporting the broken pipe once more
        with contextlib.suppress(OSError, ValueError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        return 0
    except Exception as exc:
        # (imported here: the runtime is not loaded for --help and --version)
        from cobus.runtime.errors import BusOpenError

        if not isinstance(exc, BusOpenError):
            raise
        print(f"cobus {args.command}: {exc}", file=sys.stderr)
        return 1
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
