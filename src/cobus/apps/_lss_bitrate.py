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
import sys
from typing import Any

from cobus._args import bus_options

__all__ = ["heard_nodes", "set_bitrate"]


def _fail(message: str, code: int = 1) -> int:
    print(f"cobus: {message}", file=sys.stderr)
    return code


def heard_nodes(net: Any, seconds: float, until: set[int] | None = None) -> set[int]:
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
    from cobus.proto.lss import LssError, LssIdentity

    remote = net.add_remote(node, sdo_timeout=0.5)
    fields = []
    for sub in range(1, 5):
        data = remote.sdo.upload(0x1018, sub)
        if len(data) != 4:
            raise LssError(f"1018h sub {sub} is {len(data)} bytes, not an UNSIGNED32")
        fields.append(int.from_bytes(data, "little"))
    return LssIdentity(*fields)


def _listed(nodes: dict[int, Any]) -> str:
    return ", ".join(map(str, sorted(nodes))) or "none"


def _put_back(net: Any, accepted: dict[int, Any], bitrate: int | None) -> str:
    """After a refusal: the nodes that took the new bit timing are given the one they run
    at (``-b``), so that a later activation or store cannot use it; what to say of it."""
    from cobus.errors import CobusError
    from cobus.proto.lss import LssState

    if not accepted:
        return ""
    if not bitrate:
        return (
            f" (node(s) {_listed(accepted)} hold it as pending: run again with -b and the "
            "rate they run at to undo it, before any store or activation)"
        )
    for identity in accepted.values():
        try:
            net.lss.select(identity)
            net.lss.configure_bit_rate(bitrate // 1000)
        except CobusError:
            return f" (putting node(s) {_listed(accepted)} back to {bitrate // 1000} kbit/s failed)"
        finally:
            net.lss.switch_global(LssState.WAITING)
    return f" (node(s) {_listed(accepted)} were given {bitrate // 1000} kbit/s back)"


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
            expected = set(args.nodes) if args.nodes else heard_nodes(net, args.listen)
            if not expected:
                return _fail("no heartbeat is heard, so no node to move: name them with --nodes", 3)
            if not args.nodes and not args.json:
                print(
                    f"moving the nodes heard: {', '.join(map(str, sorted(expected)))} (a node "
                    "not heard is not moved: name every node with --nodes)",
                    file=sys.stderr,
                )
            refused: dict[int, str] = {}
            accepted: dict[int, Any] = {}
            for node in sorted(expected):
                try:
                    identity = _identity(net, node)
                except CobusError as exc:
                    refused[node] = f"its identity (1018h) cannot be read: {exc}"
                    continue
                try:
                    net.lss.select(identity)
                    net.lss.configure_bit_rate(kbits)
                    accepted[node] = identity
                except LssTimeoutError:
                    refused[node] = "it does not answer LSS (no LSS slave?)"
                except LssRefusedError as exc:
                    refused[node] = str(exc)
                finally:
                    net.lss.switch_global(LssState.WAITING)
                stage = f"{kbits} kbit/s configured in node(s) {_listed(accepted)}, not activated"
            if refused:
                for node, why in sorted(refused.items()):
                    print(f"node {node}: {why}", file=sys.stderr)
                kept = _put_back(net, accepted, args.bitrate)
                return _fail(
                    f"nothing switched: node(s) {_listed(refused)} cannot take {kbits} kbit/s; "
                    f"every node keeps the rate it runs at{kept}"
                )
            # only the nodes asked switch: each is selected (a slave of another rate, or one
            # not named, stays in waiting and ignores the activation)
            for identity in accepted.values():
                net.lss.select(identity)
            net.lss.activate_bit_rate(args.delay)
            stage = f"node(s) {_listed(accepted)} were told to switch to {kbits} kbit/s"
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
            back = heard_nodes(net, args.wait, expected)
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
