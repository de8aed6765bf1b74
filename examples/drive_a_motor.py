"""Drive a CiA 402 motor: enable it, home it, move it back and forth, and switch it off
again, with the time each step took; a fault shows its code, its text and the last EMCY.

    python examples/drive_a_motor.py --simulated
    python examples/drive_a_motor.py -i socketcan -c can0 -b 500000 --node 2 --home 35 \\
        --scale 4096 --unit rev --positions 1 -1 0 --velocity 5
"""

from __future__ import annotations

import argparse
import sys

from _bench import add_bus_arguments, open_network
from cobus.profiles import Drive402, DriveError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_bus_arguments(parser)
    parser.add_argument("--node", type=int, default=10, help="the drive's node-ID (default 10)")
    parser.add_argument("--home", type=int, help="home first with this method (6098h)")
    parser.add_argument("--scale", type=float, default=1.0, help="increments per user unit")
    parser.add_argument("--unit", default="inc", help="the user unit's name (default inc)")
    parser.add_argument(
        "--positions",
        type=float,
        nargs="+",
        default=[50_000, -50_000, 0],
        help="positions to move to, in user units",
    )
    parser.add_argument("--velocity", type=float, default=100_000, help="user units per second")
    parser.add_argument(
        "--acceleration", type=float, default=500_000, help="user units per second²"
    )
    args = parser.parse_args(argv)
    with open_network(args) as net:
        drive = Drive402(net.add_remote(args.node), scale=args.scale, unit=args.unit)
        try:
            print(f"node {args.node}: {drive.read_statusword()}")
            began = net.time()
            drive.enable()
            print(f"  enabled in {(net.time() - began) * 1000:.0f} ms: {drive.status}")
            if args.home is not None:
                began = net.time()
                drive.home(args.home)
                print(f"  homed (method {args.home}) in {net.time() - began:.2f} s")
            for position in args.positions:
                began = net.time()
                drive.move_to(position, args.velocity, args.acceleration, args.acceleration)
                print(
                    f"  at {drive.read_position():g} {args.unit} (asked {position:g}) after "
                    f"{net.time() - began:.3f} s"
                )
            drive.disable()
            print(f"  switched off: {drive.status}")
        except DriveError as exc:
            print(f"the drive stopped the sequence: {exc}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
