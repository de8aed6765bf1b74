"""``cobus lss set-bitrate KBITS``: a whole bus to another bit rate, as one step.

1. The nodes to move: ``--nodes``, else every node whose heartbeat is heard.
2. Each is asked its identity (1018h sub 1-4, by SDO), selected by it and given the bit
   timing; its answer is checked. A node that cannot be read, does not answer LSS or refuses
   the rate stops the change before anything switches: every node keeps the rate it has.
3. All switch at once (activate bit timing with the switch delay); the interface is opened
   again at the new rate and every node is waited for (its heartbeat): the ones missing are
   named.

SocketCAN's rate is the system's (``ip link``): the command says what to run and waits for
the nodes meanwhile.
"""

from __future__ import annotations

import argparse
import json
import struct
import sys
from typing import Any

from cobus._args import bus_options

__all__ = ["set_bitrate"]


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus: {message}", file=sys.stderr)
    return code


def _heard(net: Any, seconds: float, until: set[int] | None = None) -> set[int]:
    """The node-IDs whose heartbeat (or boot-up) comes within ``seconds`` (sooner when every
    node of ``until`` has been heard)."""
    from cobus.proto.connection_set import ERROR_CONTROL_BASE, MAX_NODE_ID

    heard: set[int] = set()

    def beat(frame: Any, now: float) -> None:
        if len(frame.data) == 1 and not frame.rtr:
            heard.add(frame.cob_id - ERROR_CONTROL_BASE)

    subs = [net.subscribe(ERROR_CONTROL_BASE + n, beat) for n in range(1, MAX_NODE_ID + 1)]
    try:
        waited = 0.0
        while waited < seconds and not (until and until <= heard):
            net.sleep(0.05)
            waited += 0.05
    finally:
        for sub in subs:
            sub.cancel()
    return heard


def _identity(net: Any, node: int) -> Any:
    from cobus.proto.lss import LssIdentity

    remote = net.add_remote(node, sdo_timeout=0.5)
    fields = [struct.unpack("<I", remote.sdo.upload(0x1018, sub)[:4])[0] for sub in range(1, 5)]
    return LssIdentity(*fields)


def set_bitrate(args: argparse.Namespace) -> int:
    """Run ``cobus lss set-bitrate`` (see the module docstring)."""
    from cobus.errors import CobusError
    from cobus.proto.lss import LssState
    from cobus.runtime import LssRefusedError, LssTimeoutError, Network

    kbits: int = args.kbits
    options = bus_options(args)
    stage = "nothing was sent"
    try:
        with Network(**options) as net:
            net.lss.timeout = 0.2
            expected = set(args.nodes) if args.nodes else _heard(net, 1.1)
            if not expected:
                return _fail("no heartbeat is heard, so no node to move: name them with --nodes", 3)
            refused: dict[int, str] = {}
            for node in sorted(expected):
                try:
                    identity = _identity(net, node)
                except CobusError as exc:
                    refused[node] = f"its identity (1018h) cannot be read: {exc}"
                    continue
                try:
                    net.lss.select(identity)
                    net.lss.configure_bit_rate(kbits)
                except LssTimeoutError:
                    refused[node] = "it does not answer LSS (no LSS slave?)"
                except LssRefusedError as exc:
                    refused[node] = str(exc)
                finally:
                    net.lss.switch_global(LssState.WAITING)
                stage = "bit timings configured, none activated (every node keeps its rate)"
            if refused:
                for node, why in sorted(refused.items()):
                    print(f"node {node}: {why}", file=sys.stderr)
                return _fail(
                    f"nothing switched: node(s) {', '.join(map(str, sorted(refused)))} cannot "
                    f"take {kbits} kbit/s; every node keeps the rate it has"
                )
            net.lss.switch_global(LssState.CONFIGURATION)
            net.lss.activate_bit_rate(args.delay)
            stage = f"every node was told to switch to {kbits} kbit/s"
            net.sleep(2 * args.delay)
        if options.get("interface") == "socketcan":
            channel = options.get("channel") or "can0"
            print(
                f"cobus: set {channel} to the new rate now: sudo ip link set {channel} down; "
                f"sudo ip link set {channel} type can bitrate {kbits * 1000}; "
                f"sudo ip link set {channel} up",
                file=sys.stderr,
            )
        options["bitrate"] = kbits * 1000
        with Network(**options) as net:
            net.lss.switch_global(LssState.WAITING)
            back = _heard(net, args.wait, expected)
    except KeyboardInterrupt:
        print(f"cobus: interrupted; {stage}", file=sys.stderr)
        return 130
    except CobusError as exc:
        return _fail(f"{exc} ({stage})")
    missing = sorted(expected - back)
    if args.json:
        print(json.dumps({"kbits": kbits, "back": sorted(expected & back), "missing": missing}))
    else:
        print(f"{len(expected & back)} of {len(expected)} node(s) back at {kbits} kbit/s")
    if missing:
        return _fail(
            f"node(s) {', '.join(map(str, missing))} not heard at {kbits} kbit/s within "
            f"{args.wait:g} s: check them (they may have switched late, or not at all)"
        )
    return 0
