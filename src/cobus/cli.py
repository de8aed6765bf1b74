"""The ``cobus`` command line.

Each area of the package contributes its sub-commands through a ``register(subparsers)``
function in a private ``_cli`` module; this file only assembles them: :data:`COMMANDS` names
each command's module and help, and only the module of the command run is imported.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Sequence
from typing import Any

from cobus import __version__

#: Every command: the module whose ``register(subparsers)`` adds it, and its one-line help, in
#: the order ``cobus --help`` lists them. Only the module of the command run is imported, so
#: that ``--help``, ``--version`` and every command start fast; a test checks that each help
#: here is the one its module gives.
COMMANDS: dict[str, tuple[str, str]] = {
    "eds": ("cobus.od._cli", "check, show or document an EDS/DCF file (CiA 306)"),
    "config": ("cobus.master._cli", "check a network description (YAML) or write its DCFs"),
    "run": (
        "cobus.apps._run_cli",
        "boot and supervise a network with the cobus master (and its operator panel)",
    ),
    "sim": ("cobus.sim._cli", "run simulated devices (a rig file) on a CAN bus until Ctrl-C"),
    "ec": (
        "cobus.profiles._cli",
        "read and write the EC motor (seed 002) over its own SDO dialect",
    ),
    "params": (
        "cobus.blocks._cli",
        "compare, apply and capture a node's parameters (parameter manager)",
    ),
    "alarms": ("cobus.blocks._alarms_cli", "read an alarm history file (show, export as CSV)"),
    "netvars": (
        "cobus.blocks._netvars_cli",
        "network variables over UDP with CODESYS controllers (.gvl): watch, send, export",
    ),
    "decode": (
        "cobus.trace._cli",
        "decode a trace file into CANopen records (NMT, SDO, PDO, EMCY...)",
    ),
    "record": (
        "cobus.trace._cli",
        "record the bus into a trace file (any format python-can writes)",
    ),
    "replay": ("cobus.trace._cli", "send a recording back onto a bus with its timing"),
    "monitor": ("cobus.trace.monitor", "the live bus decoded, with a node table and the bus load"),
    "plot": (
        "cobus.trace.plot",
        "PDO signals over time from a trace file, to a PNG (matplotlib)",
    ),
    "scan": (
        "cobus.trace.scan",
        "find the nodes on the bus: device type, identity, names, error history",
    ),
    "sdo": ("cobus.apps._node_cli", "read and write objects of a node by SDO"),
    "nmt": ("cobus.apps._node_cli", "send an NMT command to a node or to all"),
    "send": ("cobus.apps._node_cli", "send raw CAN frames: ID#DATA as cansend writes them"),
    "pdo": ("cobus.apps._pdo_cli", "read a node's PDOs, or map one anew, checked against its EDS"),
    "sync": ("cobus.apps._node_cli", "produce SYNC"),
    "lss": (
        "cobus.apps._lss_cli",
        "LSS (CiA 305): give devices node-IDs, find them, change the bit rate",
    ),
    "gateway": (
        "cobus.apps._gateway_cli",
        "the CiA 309-3 ASCII gateway: the bus from any program over TCP",
    ),
    "gw": (
        "cobus.apps._gw_cli",
        "send requests to a CiA 309-3 gateway and print the replies as data",
    ),
    "demo": (
        "cobus.apps.demo",
        "run the simulated thesis rig, booted and supervised by the cobus master",
    ),
}


class _Only:
    """The sub-command parsers as one module's ``register`` sees them: only the command
    wanted is added; the module's other commands go to parsers nobody uses."""

    def __init__(self, sub: Any, wanted: str | None) -> None:
        self.sub = sub
        self.wanted = wanted

    def add_parser(self, name: str, **options: Any) -> argparse.ArgumentParser:
        if self.wanted is None or name == self.wanted:
            parser: argparse.ArgumentParser = self.sub.add_parser(name, **options)
            return parser
        return argparse.ArgumentParser(prog=f"cobus {name}", add_help=False)


def build_parser(command: str | None = "*") -> argparse.ArgumentParser:
    """The ``cobus`` parser: with every command's own (``"*"``), with ``command``'s only
    (the others listed by name and help), or with none (``None``: for ``--help``)."""
    parser = argparse.ArgumentParser(
        prog="cobus",
        description="CANopen master, device, simulators and tools.",
        epilog="Exit codes, the same in every command: 0 done, 1 the bus, a node or a file "
        "failed (one line on stderr says which and why), 2 bad usage or a bad input file, "
        "3 differences found (params diff), 130 interrupted (Ctrl-C).",
    )
    parser.add_argument("--version", action="version", version=f"cobus {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    done: set[str] = set()
    for name, (module_name, help_text) in COMMANDS.items():
        if command != "*" and name != command:
            sub.add_parser(name, help=help_text, add_help=False)
            continue
        if module_name in done:
            continue
        done.add(module_name)
        module = importlib.import_module(module_name)
        module.register(_Only(sub, None if command == "*" else command))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    command = next((w for w in words if not w.startswith("-")), None)
    try:  # (Ctrl-C while the command's module loads: nothing was done yet)
        parser = build_parser(command if command in COMMANDS else None)
        args = parser.parse_args(words)
    except KeyboardInterrupt:
        print(f"cobus{' ' + command if command in COMMANDS else ''}: interrupted", file=sys.stderr)
        return 130
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
