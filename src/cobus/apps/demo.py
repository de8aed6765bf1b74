"""``cobus demo``: the simulated rig with the master booting it.

The simulation rig (simulated devices) and the operator panel are not built yet; until then the
command says so plainly instead of pretending.
"""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    parser: argparse.ArgumentParser = sub.add_parser(
        "demo", help="run the simulated rig with the master and the operator panel"
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    print(
        "cobus demo: the simulation rig and the operator panel are not built yet.\n"
        "What works today: 'cobus eds check|show|doc FILE' on any EDS/DCF, and the library API\n"
        "(cobus.od, cobus.proto, cobus.runtime). See README.md."
    )
    return 0
