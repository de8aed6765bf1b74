"""What the example scripts share: the bus arguments, and the simulated bench for ``--simulated``.

On a real bus: ``-i socketcan -c can0 -b 500000`` (any python-can interface; without ``-i``,
python-can's configuration applies). ``--simulated`` runs the script against the simulated
thesis bench (``cobus sim thesis``: a CiA 402 servo on node 10, a CiA 401 I/O module on 9,
a ZAPI ACE2 inverter on 8) on the simulated clock: no hardware, and the same on every run.
"""

from __future__ import annotations

import argparse
from typing import Any

from cobus.runtime import Network
from cobus.sim import start_rig


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--interface", "-i", help="python-can interface (socketcan, pcan...)")
    parser.add_argument("--channel", "-c", help="python-can channel (can0...)")
    parser.add_argument("--bitrate", "-b", type=int, help="bit rate in bit/s")
    parser.add_argument(
        "--simulated",
        action="store_true",
        help="run against the simulated thesis bench on the simulated clock",
    )
    parser.add_argument("--duration", type=float, default=5.0, help="seconds to run (default 5)")


def open_network(args: argparse.Namespace) -> Network:
    """The network the arguments name; with ``--simulated``, the thesis bench runs on it."""
    if args.simulated:
        net = Network(simulated=True)
        start_rig(net, "thesis")
        return net
    options: dict[str, Any] = {"interface": args.interface, "channel": args.channel}
    if args.bitrate:
        options["bitrate"] = args.bitrate
    return Network(**options)
