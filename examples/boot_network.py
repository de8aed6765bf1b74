"""Boot a network the CiA 302 way from its network file, and watch it: the master resets,
checks and configures every node, starts them, then supervises heartbeats and emergencies.

    python examples/boot_network.py --simulated                 # the thesis bench
    python examples/boot_network.py examples/networks/line.yml -i socketcan -c can0

On the thesis bench the ZAPI inverter soon reports "TPDO 1 missing": it waits for the
application's answer to each TPDO 1 (a toggle handshake), which this script does not give;
`cobus demo` does.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from _bench import add_bus_arguments, open_network
from cobus.master import BlockingMaster, NetworkConfigError

HERE = Path(__file__).parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "network",
        nargs="?",
        default=str(HERE / "networks" / "thesis.yml"),
        help="the network file (default: the thesis bench's)",
    )
    add_bus_arguments(parser)
    args = parser.parse_args(argv)
    with open_network(args) as net:
        try:
            master = BlockingMaster(net, args.network)
        except NetworkConfigError as exc:
            print(exc, file=sys.stderr)
            return 2
        master.add_listener(lambda event: print(f"  {event}"))
        master.boot(timeout=10)
        print(f"the network runs: master {master.state}, bus load {master.bus_load:.1f} %")
        master.sleep(args.duration)
        for node in master.nodes.values():
            print(
                f"  node {node.node_id} {node.name}: {node.state.text}, NMT "
                f"{node.nmt_state.name if node.nmt_state is not None else '-'}, "
                f"{node.emcy_count} emergencies"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
