"""Argument types the command line shares."""

from __future__ import annotations

import argparse
import math
from typing import Any

__all__ = [
    "add_bus_options",
    "bus_options",
    "load_eds",
    "node_id",
    "seconds",
    "seconds_or_zero",
]


def node_id(text: str) -> int:
    """A node-ID, 1-127."""
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a node-ID 1-127") from None
    if not 1 <= value <= 127:
        raise argparse.ArgumentTypeError(f"{text!r}: a node-ID 1-127")
    return value


def add_bus_options(parser: argparse.ArgumentParser) -> None:
    """``-i/--interface``, ``-c/--channel``, ``-b/--bitrate`` as python-can's own tools have
    them; what is not given comes from python-can's configuration (``CAN_INTERFACE``...)."""
    group = parser.add_argument_group(
        "bus (default: python-can's configuration)",
        "Other options of the interface (udp_multicast's port...) come from python-can's "
        """configuration too: CAN_CONFIG='{"port": 43114}' or ~/.canrc. udp_multicast """
        "without -c uses a group that never leaves this host; python-can listens on every "
        "interface, so whoever can send to its group and port writes to the bus: name a "
        "wider group only on a trusted network (off Linux, firewall the port 43113).",
    )
    group.add_argument("--interface", "-i", help="python-can interface (socketcan, pcan...)")
    group.add_argument("--channel", "-c", help="python-can channel (can0, PCAN_USBBUS1...)")
    group.add_argument("--bitrate", "-b", type=int, help="bit rate in bit/s")


def bus_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments for :class:`cobus.runtime.Network` from :func:`add_bus_options`."""
    options: dict[str, Any] = {"interface": args.interface, "channel": args.channel}
    if args.bitrate:
        options["bitrate"] = args.bitrate
    return options


def load_eds(path: Any, command: str, *, node_id: int | None = None) -> Any:
    """An EDS/DCF a command was given: a file with no object in it is refused (EdsError);
    one with errors is used as far as it goes, and the command says so once on stderr (the
    first error with its file and line, and how many there are)."""
    import sys

    from cobus.od import EdsError, Severity, load

    od = load(path, node_id=node_id)
    errors = [f for f in od.findings if f.severity is Severity.ERROR]
    if next(iter(od), None) is None:
        last = errors[-1] if errors else None
        reason = last.reason if last is not None else "the file defines no objects"
        raise EdsError(str(path), None, None, reason)
    if errors:
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        print(
            f"cobus {command}: {path} has errors, the rest of it is used - {errors[0]}{more} "
            f"(cobus eds check {path} lists every problem)",
            file=sys.stderr,
        )
    return od


def other_device(node: Any, od: Any) -> str | None:
    """Why ``od`` (an EDS given on the command line) is not the dictionary of ``node``: the
    device profile its 1000h names is not the one the node reports (None: it is, or either
    says nothing - an EDS with 0, a node that does not answer)."""
    var = od.get_variable(0x1000, 0) if od is not None else None
    expected = var.value if var is not None else None
    if not isinstance(expected, int) or not expected & 0xFFFF:
        return None
    try:
        data = node.sdo.upload(0x1000, 0)
    except Exception:  # (no answer, a refusal: what comes next says so)
        return None
    got = int.from_bytes(bytes(data[:4]).ljust(4, b"\0"), "little")
    if got & 0xFFFF == expected & 0xFFFF:
        return None
    return (
        f"node {node.node_id} reports device type 0x{got:08X} (profile {got & 0xFFFF}), the EDS "
        f"0x{expected:08X} (profile {expected & 0xFFFF}): the EDS is another device's"
    )


def seconds(text: str) -> float:
    """A number of seconds above 0 (``nan``, ``inf`` and negatives refused)."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: a number of seconds above 0")
    return value


def seconds_or_zero(text: str) -> float:
    """A number of seconds, 0 or above (0 usually means "never")."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: a number of seconds, 0 or above")
    return value


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: a finite number of seconds")
    return value


def host_port(text: str, *, listening: bool = False) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:5000`` for IPv6) as an argparse type; ``listening``: the host
    may be left out (127.0.0.1) and port 0 means any free one."""
    import argparse

    host, sep, port = text.rpartition(":")
    low = 0 if listening else 1
    if not sep or not port.isdigit() or not low <= int(port) <= 65535 or not (host or listening):
        raise argparse.ArgumentTypeError(f"{text!r}: give HOST:PORT, e.g. 127.0.0.1:5000")
    return (host.strip("[]") or "127.0.0.1"), int(port)
