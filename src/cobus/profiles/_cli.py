"""cobus ec: read and write the EC motor of seed 002 over its own SDO dialect.

    cobus ec read 3 p_ven h_vel          # raw value and physical value with its unit
    cobus ec write 3 p_ven 2000
    cobus ec mode 3 VEL
    cobus ec status 3

The bus is python-can's (``-i/--interface``, ``-c/--channel``, ``-b/--bitrate``, else its
configuration). Exit codes: 0 done, 1 the motor refused or did not answer, or the bus cannot
be used, 2 bad usage.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add ``cobus ec ...`` to the top-level sub-command parser."""
    ec: argparse.ArgumentParser = sub.add_parser(
        "ec",
        help="read and write the EC motor (seed 002) over its own SDO dialect",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = ec.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, help_text in (
        ("read", "read objects by name (p_ven, h_vel, m_ssm...)"),
        ("write", "write an object: NAME VALUE (raw units)"),
        ("mode", "switch the working mode: OFF, PON, VEL, POZ..."),
        ("status", "the status poll: position, I/O bits, mode"),
    ):
        p = actions.add_parser(name, help=help_text)
        p.add_argument("address", type=int, help="the motor's address, 1-15")
        if name == "read":
            p.add_argument("objects", nargs="+", help="object names")
        elif name == "write":
            p.add_argument("object", help="object name")
            p.add_argument("value", type=int, help="raw value")
        elif name == "mode":
            p.add_argument("mode", help="mode name or number")
        p.add_argument("--interface", "-i", help="python-can interface")
        p.add_argument("--channel", "-c", help="python-can channel")
        p.add_argument("--bitrate", "-b", type=int, help="bit rate in bit/s")
        p.add_argument("--timeout", type=float, default=0.5, help="seconds per answer")
        p.set_defaults(handler=_run)


def _run(args: argparse.Namespace) -> int:
    from cobus.profiles.ecmotor import OBJECTS, UNITS, EcMotorDrive, EcMotorError
    from cobus.runtime import Network

    options: dict[str, Any] = {"interface": args.interface, "channel": args.channel}
    if args.bitrate:
        options["bitrate"] = args.bitrate
    try:
        with Network(**options) as net:
            motor = EcMotorDrive(net, args.address, timeout=args.timeout)
            if args.action == "read":
                for name in args.objects:
                    raw = motor.read(name)
                    obj = OBJECTS.get(name)
                    unit = UNITS.get(obj.unit) if obj is not None and obj.unit else None
                    shown = f" = {raw * unit[1]:g} {unit[2]}" if unit else ""
                    print(f"{name}: {raw}{shown}")
            elif args.action == "write":
                motor.write(args.object, args.value)
                print(f"{args.object} <- {args.value}")
            elif args.action == "mode":
                mode = int(args.mode) if args.mode.isdigit() else args.mode
                motor.set_mode(mode)
                print(f"mode {args.mode}")
            else:
                status = motor.poll_status()
                print(
                    f"position {status.position} (P), I/O 0x{status.io:04X}, status "
                    f"0x{status.status:04X}: mode {status.mode}"
                    + (", error" if status.error else "")
                    + (", power stage on" if status.power_stage_on else "")
                    + (", rotating" if status.rotating else "")
                )
    except (KeyError, ValueError, TypeError) as exc:
        print(f"cobus ec: {exc.args[0] if exc.args else exc}", file=sys.stderr)
        return 2
    except EcMotorError as exc:
        print(f"cobus ec: {exc}", file=sys.stderr)
        return 1
    return 0
