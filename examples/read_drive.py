"""Read a drive as a commissioning engineer would: identity, PDO mappings, then its process
data, NMT state and emergencies for a while.

    python examples/read_drive.py --simulated
    python examples/read_drive.py -i socketcan -c can0 -b 500000 --node 2 --eds drive.eds
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from _bench import add_bus_arguments, open_network
from cobus.runtime import SdoError

HERE = Path(__file__).parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_bus_arguments(parser)
    parser.add_argument("--node", type=int, default=10, help="the drive's node-ID (default 10)")
    parser.add_argument(
        "--eds", default=str(HERE / "networks" / "servo.eds"), help="the drive's EDS file"
    )
    parser.add_argument(
        "--sync", type=float, default=0, help="produce SYNC every SYNC ms (default: none)"
    )
    args = parser.parse_args(argv)
    with open_network(args) as net:
        drive = net.add_remote(args.node, args.eds)
        try:
            identity = drive.sdo["Identity object"]
            print(f"node {args.node}: device type 0x{drive.sdo.read(0x1000):08X}")
            for sub in identity:
                print(f"  {sub.name}: {sub.read():#x}")
        except SdoError as exc:
            print(f"the drive does not answer: {exc}", file=sys.stderr)
            return 1

        for pdo in [*drive.tpdo.read(), *drive.rpdo.read()]:
            print(f"  {pdo}")

        drive.emcy.add_callback(lambda emcy: print(f"  EMCY {emcy}"))
        drive.nmt.add_callback(lambda event: print(f"  NMT {event}"))
        drive.sdo.write("Producer heartbeat time", 100)
        drive.nmt.watch_heartbeat(0.25)
        drive.nmt.start()
        if args.sync:
            net.sync.start(args.sync / 1000)
        net.sleep(args.duration)
        for pdo in drive.tpdo:
            values = ", ".join(f"{k} = {v}" for k, v in pdo.values.items())
            print(f"  TPDO {pdo.number}: {pdo.count} frames; last: {values if pdo.count else '-'}")
        print(f"node {args.node} is {drive.nmt.state}; {drive.emcy.count} emergencies")
    return 0


if __name__ == "__main__":
    sys.exit(main())
